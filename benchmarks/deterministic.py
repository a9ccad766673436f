"""Cost of `solver.deterministic: true` (no fast math; one CPU thread unless the scene sums in one order on any
threads, as this one does: solver.thread_independent) against the default (all threads, fast math) on the falling
elastic block, 2D and 3D. `ratio` = deterministic step time / default step time (wall);
`cpu ratio` the same with process CPU time (all threads), which shows the cost of turning fast math off.

    python benchmarks/deterministic.py              # 2D 256^2 and 3D 64^3 grids
"""
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, parser, report, time_steps  # noqa: E402


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--dims", type=int, nargs="+", default=[2, 3])
    a = p.parse_args(argv)
    import taichi as ti

    import taichi_mpm as tm

    rows = []
    for dim in a.dims:
        n_grid = (16 if dim == 3 else 32) if a.tiny else (64 if dim == 3 else 256)
        steps = a.steps or (2 if a.tiny else 20)
        base = None
        for deterministic in (False, True):
            cfg = block_config(dim, n_grid, arch=a.arch)
            cfg["solver"]["deterministic"] = deterministic
            t0 = time.perf_counter()
            sim = tm.Simulation(cfg)
            sim.step()
            first = time.perf_counter() - t0
            wall, cpu = time_steps(sim.step, steps, a.repeats, cpu=True)
            base = base or (wall, cpu)
            rows.append(dict(dim=dim, deterministic=deterministic, particles=sim.n,
                             threads=ti.lang.impl.current_cfg().cpu_max_num_threads,
                             ms_per_step=1e3 * wall, ratio=wall / base[0], cpu_ratio=cpu / base[1],
                             first_step_s=first))
    report(rows, a.json)
    print(f"(machine: {os.cpu_count()} logical CPUs)")
    return rows


if __name__ == "__main__":
    main()
