"""Cost per particle-step of each material model relative to fixed_corotated, measured in the same run.

A block falls onto the floor of a box (benchmarks/common.block_config) with each model in turn; the plastic models
get parameters that make the landing yield, so their return mappings take the plastic branch for part of the
particles. Reports wall and process CPU time per step (the CPU-time ratio is the steadier one on a shared machine).

    python benchmarks/materials.py                     # 2D 128^2 and 3D 32^3 grids, f32
    python benchmarks/materials.py --dims 3 --precisions f32 f64
"""
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, parser, peak_rss_mb, report, time_steps  # noqa: E402

REFERENCE = "fixed_corotated"
# keys besides E, nu and density (block_config's E = 400 Pa, density 1): yield under the landing
EXTRA = {"fluid": {}, "von_mises": {"yield_stress": 2.0, "hardening": 40.0},
         "drucker_prager": {"friction_angle": 30.0}, "snow": {}, "mohr_coulomb": {"friction_angle": 30.0},
         "cam_clay": {"shear_modulus": 150.0, "lambda_star": 0.1, "kappa_star": 0.02, "critical_state_slope": 1.0,
                      "initial_pressure": 20.0},
         "mu_i": {"mu_s": 0.4, "mu_2": 0.6, "grain_diameter": 1e-3, "max_pressure": 10.0}}
NO_MODULI = ("cam_clay",)   # models without E and nu (cam_clay: shear_modulus, K = p / kappa_star)


def material_config(dim, n_grid, model, precision, arch):
    cfg = block_config(dim, n_grid, model="fluid" if model == "fluid" else REFERENCE, precision=precision, arch=arch)
    mat = cfg["materials"]["m"]
    mat["model"] = model
    if model in NO_MODULI:
        mat.pop("E"), mat.pop("nu")
    mat.update(EXTRA.get(model, {}))
    cfg["solver"]["energy_growth_limit"] = None  # a fixed dt for every model: cost, not stability, is measured
    return cfg


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--dims", type=int, nargs="+", default=[2, 3])
    p.add_argument("--precisions", nargs="+", default=["f32"])
    p.add_argument("--models", nargs="+", default=None, help="default: every registered model")
    a = p.parse_args(argv)
    import taichi_mpm as tm
    from taichi_mpm.materials import MODELS

    models = a.models or list(MODELS)
    models = [REFERENCE] + [m for m in models if m != REFERENCE]  # the reference first: ratios within this run
    rows = []
    for dim in a.dims:
        n_grid = (16 if dim == 3 else 32) if a.tiny else (32 if dim == 3 else 128)
        steps = a.steps or (2 if a.tiny else 30)
        for precision in a.precisions:
            ref = None
            for model in models:
                sim = tm.Simulation(material_config(dim, n_grid, model, precision, a.arch))
                t0 = time.perf_counter()
                sim.step()
                first = time.perf_counter() - t0
                wall, cpu = time_steps(sim.step, steps, 1 if a.tiny else a.repeats, cpu=True)
                ref = ref or (wall, cpu)
                rows.append(dict(dim=dim, precision=precision, model=model, particles=sim.n,
                                 ns_per_particle_step=wall / sim.n * 1e9, cost_vs_fixed_corotated=wall / ref[0],
                                 cpu_cost_vs_fixed_corotated=cpu / ref[1], first_step_s=first,
                                 bytes_per_particle=sim.bytes_per_particle))
    report(rows, a.json)
    print(f"peak RSS {peak_rss_mb():.0f} MB")
    return rows


if __name__ == "__main__":
    main()
