"""Every benchmark on one device (CUDA by default), in one table: the script a GPU session runs first.

Each case runs in its own process (a fresh Taichi runtime, so one case's compile cache, memory pool or crash cannot
touch the next) and prints one JSON row; the parent prints the table. Sections:

- mpm3d: Taichi's bundled mpm3d kernel and this project on the same particles, grid and dt (fluid and elastic).
- elements: this project on taichi_elements' elastic-cube scene; with --te-path DIR (a checkout holding
  taichi_elements' `engine/` package, which is not on the package index) also taichi_elements itself.
- bases: 3D APIC elastic block, every basis, cost relative to quadratic.
- crack: the crack finder's cost in 3D (same block with and without a crack section).
- long: throughput of a 3D dam break after many steps against its first steps (particle order decay).
- fill (--fill-memory GB): the largest elastic cube that fits in GB of device memory, by doubling the particle
  count; prints particle-steps/s per size.
- capacity (--capacity GB): no run; the particle count each feature set fits in GB, from the solver's field sizes.

    python benchmarks/device.py                         # CUDA, full sizes (about 3-5 minutes on one GPU)
    python benchmarks/device.py --arch cpu --quick      # the same cases, seconds-long sizes (tested on CPU)
    python benchmarks/device.py --fill-memory 120 --sections fill
    python benchmarks/device.py --capacity 140 --sections capacity
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, parser, report, te_scene_config, time_steps  # noqa: E402

SECTIONS = ("mpm3d", "elements", "bases", "crack", "long", "fill", "capacity")
DEFAULT_SECTIONS = ("mpm3d", "elements", "bases", "crack", "long")
BASES = ("linear", "gimp", "quadratic", "cubic", "cpdi", "ddmp")
FEATURE_SETS = {  # name -> (transfer, model, precision, extra config): what a 140 GB device holds per feature set
    "PIC elastic f32": ("pic", "fixed_corotated", "f32", {}),
    "APIC elastic f32": ("apic", "fixed_corotated", "f32", {}),
    "APIC elastic f64": ("apic", "fixed_corotated", "f64", {}),
    "APIC fluid f32": ("apic", "fluid", "f32", {}),
    "APIC von_mises f32": ("apic", "von_mises", "f32", {}),
    "APIC elastic f32 + crack": ("apic", "fixed_corotated", "f32", {"crack": {}}),
}


# ---------------------------------------------------------------- the cases (each runs in a worker process)

def case_mpm3d(a):
    import reference

    n_grid = 16 if a.quick else 64
    rows = reference.main(["--grid", str(n_grid), "--sparse", "true", "--unroll", "auto", "--arch", a.arch,
                           "--steps", str(3 if a.quick else 50), "--repeats", str(1 if a.quick else 3)])
    return [dict(section="mpm3d", case=r["case"], particles=r["particles"], ms_per_step=r["ms_per_step"],
                 particle_steps_per_s=r["particle_steps_per_s"], vs_mpm3d=r["ratio"], first_step_s=r["first_step_s"])
            for r in rows]


def _run_ours(cfg, steps, repeats, scene=None):
    import taichi_mpm as tm
    from taichi_mpm.budget import estimate
    from taichi_mpm.config import load_config

    cfg = load_config(cfg)
    t0 = time.perf_counter()
    sim = tm.Simulation(cfg, scene=scene)
    sim.step()
    first = time.perf_counter() - t0
    t = time_steps(sim.step, steps, repeats)
    est = estimate(cfg)
    memory = sim.n * sim.bytes_per_particle + est.grid_bytes
    return dict(particles=sim.n, ms_per_step=t * 1e3, particle_steps_per_s=sim.n / t, first_step_s=first,
                est_memory_mb=memory / 2**20), sim


def case_elements_ours(a):
    row, _ = _run_ours(te_scene_config(16 if a.quick else 64, a.arch), 3 if a.quick else 50, 1 if a.quick else 3)
    return [dict(section="elements", case="taichi_mpm on taichi_elements' elastic cube", **row)]


def case_elements_peer(a):
    """taichi_elements' own solver on its elastic cube (fixed-corotated, 8 particles per cell, its default dt)."""
    import contextlib
    import io

    import taichi as ti

    sys.path.insert(0, str(Path(a.te_path).resolve()))
    ti.init(arch=getattr(ti, a.arch), offline_cache=True, random_seed=0)
    from engine.mpm_solver import MPMSolver  # noqa: the peer, imported from the checkout named by --te-path

    res = 16 if a.quick else 64
    mpm = MPMSolver(res=(res,) * 3, size=1, unbounded=False, use_voxelizer=False, max_num_particles=2**24)
    mpm.add_cube(lower_corner=(0.3,) * 3, cube_size=(0.4,) * 3, material=MPMSolver.material_elastic,
                 sample_density=8)
    n, dt = mpm.n_particles[None], mpm.default_dt
    quiet = contextlib.redirect_stdout(io.StringIO())
    with quiet:
        t0 = time.perf_counter()
        mpm.step(dt * 2)  # two substeps: compile and warm up
        ti.sync()
        first = time.perf_counter() - t0
        t = time_steps(lambda: mpm.step(dt * 0.999), 3 if a.quick else 50, 1 if a.quick else 3)
    return [dict(section="elements", case="taichi_elements (peer)", particles=n, ms_per_step=t * 1e3,
                 particle_steps_per_s=n / t, first_step_s=first)]


def case_bases(a):
    rows, reference = [], None
    n_grid = 16 if a.quick else 64
    # quadratic first: every ratio is against a time measured in this process
    for basis in sorted(a.bases, key=lambda b: b != "quadratic"):
        row, _ = _run_ours(block_config(3, n_grid, basis=basis, arch=a.arch), 2 if a.quick else 20,
                           1 if a.quick else 3)
        reference = reference or row["ms_per_step"]
        rows.append(dict(section="bases", case=f"3D {basis} APIC elastic", vs_quadratic=row["ms_per_step"] / reference,
                         **row))
    return rows


def case_crack(a):
    rows = []
    n_grid = 16 if a.quick else 48
    for crack in (False, True):
        cfg = block_config(3, n_grid, arch=a.arch)
        if crack:
            cfg["crack"] = {}
        row, _ = _run_ours(cfg, 2 if a.quick else 20, 1 if a.quick else 3)
        rows.append(dict(section="crack", case=f"3D quadratic APIC elastic{' + crack finder' if crack else ''}",
                         **row))
    rows[1]["vs_plain"] = rows[1]["ms_per_step"] / rows[0]["ms_per_step"]
    return rows


def case_long(a):
    """A 3D dam break: particle-steps/s over the last `window` steps of a long run against the first `window`."""
    n_grid, total, window = (16, 60, 20) if a.quick else (a.long_grid, 2000, 100)
    cfg = block_config(3, n_grid, model="fluid", arch=a.arch, body=(0.05, 0.5), E=1e6)  # K >= 100 rho g H
    cfg["bodies"][0]["shape"]["upper"] = [0.4, 0.6, 0.95]  # a column against the x = 0 wall that collapses along x
    cfg["bodies"][0]["shape"]["lower"] = [0.02, 0.02, 0.05]
    cfg["solver"].pop("dt")  # the CFL rule's step, as a user gets it
    import taichi as ti
    import taichi_mpm as tm
    from taichi_mpm.config import load_config

    sim = tm.Simulation(load_config(cfg))
    sim.step()

    def rate(k):
        ti.sync()
        t = time.perf_counter()
        for _ in range(k):
            sim.step()
        ti.sync()
        return sim.n * k / (time.perf_counter() - t)

    first = rate(window)
    for _ in range(total - 2 * window):
        sim.step()
    last = rate(window)
    return [dict(section="long", case=f"3D dam break, steps {total - window}-{total} vs 1-{window}",
                 particles=sim.n, particle_steps_per_s=last, vs_first_steps=last / first)]


def fill_config(res, arch):
    cfg = te_scene_config(res, arch)
    cfg["bodies"][0]["shape"].update(lower=[0.1] * 3, upper=[0.9] * 3)
    cfg["limits"] = {"allow_large": True}
    return cfg


def case_fill(a):
    row, _ = _run_ours(fill_config(a.res, a.arch), 3, 1)
    return [dict(section="fill", case=f"elastic cube, {a.res}^3 cells", **row)]


def capacity_rows(gb: float, arch: str):
    """Particles that fit in `gb` per feature set: particle fields plus the sparse grid around a cube that fills
    80 % of the domain at 8 particles per cell, from the solver's own size estimate (nothing is allocated)."""
    from taichi_mpm.budget import estimate
    from taichi_mpm.config import load_config

    rows = []
    for name, (transfer, model, precision, extra) in FEATURE_SETS.items():
        cfg = fill_config(64, arch)
        cfg.update(precision=precision, **extra)
        cfg["solver"]["transfer"] = transfer
        mat = {"model": model, "density": 1000.0, **({"K": 1e6} if model == "fluid" else {"E": 1e6, "nu": 0.2})}
        if model == "von_mises":
            mat["yield_stress"] = 1e4
        cfg["materials"] = {"e": mat}
        est = estimate(load_config(cfg))
        per_particle = est.device_bytes_per_particle + est.grid_bytes / est.particles
        count = int(gb * 1e9 / per_particle)
        rows.append(dict(section="capacity", case=name, bytes_per_particle=round(per_particle, 1),
                         particles=min(count, 2**31 - 1), limited_by="i32 index" if count >= 2**31 else "memory"))
    return rows


CASES = {"mpm3d": [case_mpm3d], "elements": [case_elements_ours, case_elements_peer], "bases": [case_bases],
         "crack": [case_crack], "long": [case_long], "fill": [case_fill]}


# ---------------------------------------------------------------- the parent: run the workers, print one table

def run_worker(section, name, a, extra=(), timeout=None):
    cmd = [sys.executable, __file__, "--worker", name, "--arch", a.arch, "--bases", *a.bases,
           "--long-grid", str(a.long_grid), *extra]
    cmd += ["--quick"] if a.quick else []
    cmd += ["--te-path", str(a.te_path)] if a.te_path else []
    env = dict(os.environ)
    if a.fill_memory and name == "case_fill" and a.arch == "cuda":
        env["TI_DEVICE_MEMORY_GB"] = str(a.fill_memory)  # Taichi reads any ti.init option from TI_<NAME>
    t = time.perf_counter()
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return [dict(section=section, case=name, error=f"timed out: no result within {timeout:.0f} s")]
    rows = [json.loads(line[7:]) for line in out.stdout.splitlines() if line.startswith("RESULT ")]
    if out.returncode or not rows:
        tail = (out.stderr.strip().splitlines() or ["no output"])[-1]
        return rows + [dict(section=section, case=name, error=f"exit {out.returncode}: {tail[:200]}")]
    for r in rows:
        r["case_wall_s"] = time.perf_counter() - t
    return rows


def add_ratios(rows):
    """Ratios to the peers measured on this device in this run (> 1: this project is faster)."""
    measured = [r for r in rows if "particle_steps_per_s" in r]   # a case that failed has an error instead
    mpm3d = next((r for r in measured if r.get("case", "").startswith("mpm3d reference")), None)
    peer = next((r for r in measured if r.get("case") == "taichi_elements (peer)"), None)
    for r in measured:
        if r.get("section") == "elements" and peer and r is not peer:
            r["vs_taichi_elements"] = r["particle_steps_per_s"] / peer["particle_steps_per_s"]
        if r.get("section") == "mpm3d" and mpm3d:
            r["vs_mpm3d"] = r["particle_steps_per_s"] / mpm3d["particle_steps_per_s"]
    return rows


def main(argv=None):
    p = parser(__doc__)
    p.set_defaults(arch="cuda")
    p.add_argument("--quick", action="store_true", help="seconds-long sizes, e.g. with --arch cpu to test the script")
    p.add_argument("--sections", nargs="+", choices=SECTIONS, default=None,
                   help=f"default: {' '.join(DEFAULT_SECTIONS)}, plus fill/capacity when their sizes are given")
    p.add_argument("--bases", nargs="+", choices=BASES, default=list(BASES))
    p.add_argument("--long-grid", type=int, default=64, help="cells per axis of the long dam-break run (a CPU: 32)")
    p.add_argument("--te-path", type=Path, default=None, help="directory holding taichi_elements' engine/ package")
    p.add_argument("--fill-memory", type=float, default=None, metavar="GB",
                   help="scaling run: double the particle count until the estimate exceeds GB of device memory")
    p.add_argument("--capacity", type=float, default=None, metavar="GB",
                   help="print the particle count each feature set fits in GB (no run)")
    p.add_argument("--budget-s", type=float, default=600.0, help="skip the remaining sections after this many seconds")
    p.add_argument("--worker", help="internal: run one case and print its rows")
    p.add_argument("--res", type=int, default=64, help="internal: the fill case's cells per axis")
    a = p.parse_args(argv)
    if a.worker:
        for row in globals()[a.worker](a):
            print("RESULT " + json.dumps(row), flush=True)
        return None

    sections = list(a.sections or DEFAULT_SECTIONS)
    if a.sections is None:
        sections += ["fill"] if a.fill_memory else []
        sections += ["capacity"] if a.capacity else []
    if a.arch != "cpu":
        from taichi_mpm.solver import available_archs

        if a.arch not in available_archs():
            sys.exit(f"device.py: arch {a.arch} is not available here ({', '.join(available_archs())}); "
                     "use --arch cpu --quick to test the script")
    start, rows = time.perf_counter(), []
    for section in sections:
        left = a.budget_s - (time.perf_counter() - start)
        if left <= 0:
            rows.append(dict(section=section, case="skipped", error=f"--budget-s {a.budget_s:g} spent"))
            continue
        if section == "capacity":
            rows += capacity_rows(a.capacity or 140.0, a.arch)
        elif section == "fill":
            rows += fill_ladder(a, start)
        else:
            for case in CASES[section]:
                if case is case_elements_peer and not a.te_path:
                    rows.append(dict(section=section, case="taichi_elements (peer)", error="no --te-path given"))
                    continue
                rows += run_worker(section, case.__name__, a, timeout=left)
    rows = add_ratios(rows)
    columns = ["section", "case", "particles", "particle_steps_per_s", "ms_per_step", "vs_mpm3d", "vs_taichi_elements",
               "vs_quadratic", "vs_plain", "vs_first_steps", "first_step_s", "est_memory_mb", "bytes_per_particle",
               "limited_by", "error"]
    columns = [c for c in columns if any(c in r for r in rows)]
    report([{c: r.get(c, "") for c in columns} for r in rows], a.json)
    print(f"device.py: arch {a.arch}, {'quick' if a.quick else 'full'} sizes, {time.perf_counter() - start:.0f} s in all")
    return rows


def fill_ladder(a, start):
    """Grow the cube (cells per axis x 1.26, about 2x particles) while its estimate fits in --fill-memory GB."""
    from taichi_mpm.budget import estimate
    from taichi_mpm.config import load_config

    gb = a.fill_memory or (0.05 if a.quick else 1.0)
    res, rows = 16 if a.quick else 64, []
    while True:
        est = estimate(load_config(fill_config(res, a.arch)))
        if est.particles * est.device_bytes_per_particle + est.grid_bytes > 0.9 * gb * 1e9 or est.particles >= 2**31:
            break
        left = a.budget_s - (time.perf_counter() - start)
        if left <= 0:
            break
        got = run_worker("fill", "case_fill", a, extra=["--res", str(res)], timeout=left)
        rows += got
        if any("error" in r for r in got):
            break
        res = int(round(res * 1.26))
    if not rows:
        rows.append(dict(section="fill", case="none", error=f"not even {res}^3 cells fit in {gb:g} GB"))
    return rows


if __name__ == "__main__":
    main()
