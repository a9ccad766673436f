"""Step cost of bases side by side: a neo-Hookean block moving in a box with slip walls (APIC, f32, default
settings of a long run: solver.unroll auto keeps its unrolled nodes), ms per step after the first steps, the bases
alternating in one process, medians of the rounds; and each one's first step (compile, cold or from the kernel
cache). Ratios against the first basis named.

    python benchmarks/basis_cost.py                       # ck against quadratic, 2D and 3D
    python benchmarks/basis_cost.py --bases quadratic,cubic,ck --rounds 5
    python benchmarks/basis_cost.py --bases ddmp,ddmp:ddmp.sub_points=true   # a basis with solver options

Writes nothing outside temporary folders.
"""
import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENES = {2: 1 / 128, 3: 1 / 40}   # dx: 16 384 and 64 000 particles
STEPS = 30


def solver_options(variant):
    """'ddmp:ddmp.sub_points=true' -> ('ddmp', {'ddmp': {'sub_points': True}}): a basis and solver keys."""
    import yaml

    name, *sets = variant.split(":")
    options = {}
    for item in sets:
        key, _, value = item.partition("=")
        *path, last = key.split(".")
        node = options
        for k in path:
            node = node.setdefault(k, {})
        node[last] = yaml.safe_load(value)
    return name, options


def block(dim, variant, dx):
    basis, options = solver_options(variant)
    body = dict(name="block", shape=dict(type="box", lower=[0.2] * dim, upper=[0.7] * dim), material="m",
                velocity=[0.3, -0.2, 0.1][:dim])
    return dict(name="cost", dim=dim, precision="f32", arch="cpu",
                domain=dict(lower=[0.0] * dim, upper=[1.0] * dim, dx=dx, boundaries=dict(default="slip")),
                solver=dict(basis=basis, transfer="apic", end_time=100.0, **options),
                output=dict(every=100.0),   # (a Simulation writes nothing; this only quiets the size check)
                materials=dict(m=dict(model="neo_hookean", E=1e5, nu=0.3, density=1000.0)), bodies=[body])


def measure(dim, basis, dx):
    import taichi_mpm as tm

    sim = tm.Simulation(block(dim, basis, dx))
    t = time.perf_counter()
    sim.step()
    first = time.perf_counter() - t
    for _ in range(2):
        sim.step()
    t = time.perf_counter()
    for _ in range(STEPS):
        sim.step()
    return sim.n, first, (time.perf_counter() - t) / STEPS * 1e3


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bases", default="quadratic,ck")
    p.add_argument("--dims", default="2,3")
    p.add_argument("--rounds", type=int, default=3)
    a = p.parse_args(argv)
    bases = a.bases.split(",")
    for dim in map(int, a.dims.split(",")):
        rows = {b: [] for b in bases}
        for _ in range(a.rounds):
            for b in bases:
                rows[b].append(measure(dim, b, SCENES[dim]))
        ref = statistics.median(r[2] for r in rows[bases[0]])
        for b in bases:
            ms = statistics.median(r[2] for r in rows[b])
            print(f"{dim}D {b:30s} {rows[b][0][0]:7d} particles  {ms:7.1f} ms/step ({ms / ref:.2f}x {bases[0]})  "
                  f"rounds {', '.join(f'{r[2]:.1f}' for r in rows[b])}  first steps "
                  f"{', '.join(f'{r[1]:.2f}' for r in rows[b])} s")


if __name__ == "__main__":
    main()
