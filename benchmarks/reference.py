"""Throughput against Taichi's own mpm3d kernel, measured in the same run.

Both run the same particles (the reference's own random cube), grid (n^3 cells on the unit cube) and dt.
Ours: quadratic APIC weakly compressible fluid (mpm3d's model), sparse grid, f32; plus the fixed-corotated elastic
version of the same scene. Reports particle-steps per second and ratios (ours / reference, > 1 is faster).

    python benchmarks/reference.py            # 64^3 cells, 65 536 particles
    python benchmarks/reference.py --tiny     # 16^3, for the test suite
"""
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, mpm3d_reference, parser, peak_rss_mb, positions_scene, report, time_steps  # noqa: E402


UNROLL_LABEL = {True: " unrolled", False: " run-time loop", "auto": ""}   # "": the default


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--grid", type=int, default=64)
    p.add_argument("--models", default="fluid,fixed_corotated", help="our material models to run (comma-separated)")
    p.add_argument("--sparse", choices=["true", "false", "both"], default="both")
    p.add_argument("--unroll", choices=["auto", "true", "false", "both"], default=None,
                   help="stencil unrolling (solver.unroll); default both (auto and true), --tiny: false "
                        "(unrolled 3D compiles ~30 s)")
    a = p.parse_args(argv)
    n_grid = 16 if a.tiny else a.grid
    steps = a.steps or (3 if a.tiny else 50)
    repeats = 1 if a.tiny else a.repeats

    substep, x, n, dt = mpm3d_reference(n_grid, a.arch)
    t_ref, c_ref = time_steps(substep, steps, repeats, cpu=True)
    rows = [dict(case="mpm3d reference (dense, MLS fluid)", particles=n, ms_per_step=t_ref * 1e3,
                 cpu_ms_per_step=c_ref * 1e3, particle_steps_per_s=n / t_ref, ratio=1.0, cpu_ratio=1.0,
                 first_step_s=None)]

    import taichi_mpm as tm

    sparse_opts = {"both": [True, False], "true": [True], "false": [False]}[a.sparse]
    for model in a.models.split(","):
        for unroll in {"both": [True, "auto"], "auto": ["auto"], "true": [True], "false": [False]}[
                a.unroll or ("false" if a.tiny else "both")]:
            for sparse in sparse_opts:
                cfg = block_config(3, n_grid, model=model, sparse=sparse, arch=a.arch)
                cfg["solver"].update(dt=dt, unroll=unroll)
                cfg, scene = positions_scene(cfg, x)
                t0 = time.perf_counter()
                sim = tm.Simulation(cfg, scene=scene)
                sim.step()
                compile_s = time.perf_counter() - t0
                t, c = time_steps(sim.step, steps, repeats, cpu=True)
                rows.append(dict(case=f"quadratic APIC {model} {'sparse' if sparse else 'dense'}"
                                      f"{UNROLL_LABEL[unroll]}",
                                 particles=sim.n, ms_per_step=t * 1e3, cpu_ms_per_step=c * 1e3,
                                 particle_steps_per_s=sim.n / t, ratio=t_ref / t, cpu_ratio=c_ref / c,
                                 first_step_s=compile_s))
    print(f"grid {n_grid}^3, dt {dt}, {steps} steps x {repeats} repeats (median), arch {a.arch}, "
          f"peak RSS {peak_rss_mb():.0f} MB")
    report(rows, a.json)
    return rows


if __name__ == "__main__":
    main()
