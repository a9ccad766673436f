"""Throughput of each basis, transfer, precision and grid layout on a falling elastic block (2D and 3D).

Prints particle-steps per second, step time, first-step (compile) time, bytes per particle and peak memory, with
each case's ratio to the quadratic APIC f32 sparse case of the same dimension, measured in the same run.

    python benchmarks/throughput.py                 # 2D 256^2 and 3D 64^3 grids
    python benchmarks/throughput.py --dims 3 --bases quadratic cubic
"""
import itertools
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, parser, peak_rss_mb, report, time_steps  # noqa: E402


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--dims", type=int, nargs="+", default=[2, 3])
    p.add_argument("--bases", nargs="+", default=["linear", "gimp", "quadratic", "cubic"])
    p.add_argument("--transfers", nargs="+", default=["pic", "flip", "apic"])
    p.add_argument("--precisions", nargs="+", default=["f32", "f64"])
    p.add_argument("--layouts", nargs="+", default=["sparse", "dense"])
    a = p.parse_args(argv)
    import taichi_mpm as tm

    rows = []
    for dim in a.dims:
        n_grid = (16 if dim == 3 else 32) if a.tiny else (64 if dim == 3 else 256)
        steps = a.steps or (2 if a.tiny else 20)
        reference = None
        cases = itertools.product(a.bases, a.transfers, a.precisions, a.layouts)
        # the reference case first, so every ratio is against a time measured in this run
        cases = sorted(cases, key=lambda c: c != ("quadratic", "apic", "f32", "sparse"))
        for basis, transfer, precision, layout in cases:
            cfg = block_config(dim, n_grid, basis=basis, transfer=transfer, precision=precision,
                               sparse=layout == "sparse", arch=a.arch)
            t0 = time.perf_counter()
            sim = tm.Simulation(cfg)
            sim.step()
            first = time.perf_counter() - t0
            t = time_steps(sim.step, steps, 1 if a.tiny else a.repeats)
            reference = reference or t
            rows.append(dict(dim=dim, basis=basis, transfer=transfer, precision=precision, grid=layout,
                             particles=sim.n, ms_per_step=t * 1e3, particle_steps_per_s=sim.n / t,
                             cost_vs_quadratic_apic=t / reference, first_step_s=first,
                             bytes_per_particle=sim.bytes_per_particle))
    report(rows, a.json)
    print(f"peak RSS {peak_rss_mb():.0f} MB")
    return rows


if __name__ == "__main__":
    main()
