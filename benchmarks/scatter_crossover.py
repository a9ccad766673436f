"""Where the coloured scatter starts to beat atomic adds (solver.scatter auto's threshold, scatter.py): the
benchmark block (quadratic APIC elastic, f32, stencil unrolled) at growing particle counts, P2G by colours and by
atomic adds, each in a fresh process, the two alternating, rounds repeated and medians reported; the crossover is
the count where the median ratio coloured / atomic crosses 1 (log-linear between the sizes around it).

    python benchmarks/scatter_crossover.py [--dims 2 3] [--grids N ...] [--rounds 3] [--steps 20] [--threads N]
        [--json PATH]
"""
import json
import math
import os
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, parser, report, time_steps  # noqa: E402

GRIDS = {1: [512, 2048, 8192, 32768], 2: [48, 96, 160, 256, 400], 3: [16, 24, 32, 40, 48, 64]}


def one(dim: int, grid: int, scatter: str, steps: int, repeats: int) -> dict:
    import taichi_mpm as tm

    cfg = block_config(dim, grid)
    cfg["solver"].update(scatter=scatter, unroll=True)
    sim = tm.Simulation(cfg)
    assert (sim.bins is not None) == (scatter == "coloured")
    return dict(particles=sim.n, ms=time_steps(sim.step, steps, repeats) * 1e3)


def _worker(dim, grid, scatter, steps, repeats, threads):
    env = dict(os.environ)
    if threads:
        env["TI_CPU_MAX_NUM_THREADS"] = str(threads)
    cmd = [sys.executable, __file__, "--worker", str(dim), str(grid), scatter, "--steps", str(steps),
           "--repeats", str(repeats)]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    return json.loads(next(line for line in out.stdout.splitlines() if line.startswith("RESULT "))[7:])


def crossover(rows: list[dict]) -> float | None:
    """The particle count where coloured / atomic falls through 1 (None when it does not within the sizes)."""
    for a, b in zip(rows, rows[1:]):
        if a["ratio"] >= 1.0 > b["ratio"]:
            la, lb = math.log(a["ratio"]), math.log(b["ratio"])
            t = la / (la - lb)
            return math.exp(math.log(a["particles"]) + t * (math.log(b["particles"]) - math.log(a["particles"])))
    return None


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--dims", type=int, nargs="+", default=[2, 3])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--grids", type=int, nargs="+", help="n_grid values to run (default: GRIDS of each dim)")
    p.add_argument("--threads", type=int, default=0, help="TI_CPU_MAX_NUM_THREADS (default: all cores)")
    p.add_argument("--worker", nargs=3, help="internal: dim grid scatter")
    a = p.parse_args(argv)
    steps = a.steps or (2 if a.tiny else 20)
    repeats = 1 if a.tiny else a.repeats
    if a.worker:
        dim, grid, scatter = int(a.worker[0]), int(a.worker[1]), a.worker[2]
        print("RESULT " + json.dumps(one(dim, grid, scatter, steps, repeats)))
        return None
    rows, found = [], {}
    for dim in a.dims:
        grids = a.grids or (GRIDS[dim][:2] if a.tiny else GRIDS[dim])
        runs = {g: {"coloured": [], "atomic": []} for g in grids}
        for _ in range(1 if a.tiny else a.rounds):
            for g in grids:
                for scatter in ("coloured", "atomic"):
                    r = _worker(dim, g, scatter, steps, repeats, a.threads)
                    runs[g][scatter].append(r)
                    print(f"{dim}D n_grid {g} {scatter}: {r}", file=sys.stderr, flush=True)
        dim_rows = []
        for g in grids:
            col, atom = runs[g]["coloured"], runs[g]["atomic"]
            dim_rows.append(dict(dim=dim, grid=g, particles=col[0]["particles"],
                                 coloured_ms=statistics.median(r["ms"] for r in col),
                                 atomic_ms=statistics.median(r["ms"] for r in atom),
                                 ratio=statistics.median(c["ms"] / t["ms"] for c, t in zip(col, atom))))
        found[dim] = crossover(dim_rows)
        rows += dim_rows
    report(rows, a.json)
    for dim, n in found.items():
        print(f"{dim}D: coloured faster than atomic from about {n:,.0f} particles" if n else
              f"{dim}D: no crossover within the sizes run")
    return rows, found


if __name__ == "__main__":
    main()
