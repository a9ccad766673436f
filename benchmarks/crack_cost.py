"""The crack finder's cost in 3D: step time of a scene with a `crack` section over the same scene without one.

Scenes (3D, quadratic APIC, f32, sparse grid, 2 particles per cell per axis, dt fixed; no gravity and no
energy-balance watch, see scene_config):
- blocks: two interface blocks in contact, pulled apart (the interface is a discontinuity from step 0).
- notch: one block with a damaged slab reaching half way through it (a notch; a pre-cracked body).
- intact: one block, nothing damaged and no interface (the finder's floor: what it costs when it finds nothing).

Each (scene, crack on/off) run is its own process (the solver keeps one live Simulation per process); the runs
alternate plain, crack, plain, ... `--repeats` times and the median of each is reported: wall time per step and
process CPU time per step (all threads; steadier than wall time on a shared machine). A crack run then times each
crack-finder kernel alone (ti.sync around it, CPU time) over a few more steps.

    python benchmarks/crack_cost.py                       # 32^3 grid, all three scenes, median of 3
    python benchmarks/crack_cost.py --scenes blocks --grid 24 --repeats 1
"""
from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, kernel_timer, parser, report  # noqa: E402

SCENES = ("blocks", "notch", "intact")


def scene_config(scene: str, n_grid: int, crack: bool, arch: str = "cpu"):
    cfg = block_config(3, n_grid, arch=arch, body=(0.1, 0.5), E=1e4)
    cfg["domain"]["boundaries"] = {"default": "slip"}
    # no gravity: no body-force terms in either variant (the time integration of body forces has differed between
    # scenes with and without a crack section), only the motions below
    cfg["solver"]["gravity"] = [0.0, 0.0, 0.0]
    # no energy-balance watch: its periodic check runs a numerical-fracture test in scenes without a crack
    # section only (up to 40 % of a plain step here); the step's own kernels are what is compared
    cfg["solver"]["energy_growth_limit"] = None
    body = cfg["bodies"][0]
    body["velocity"] = [0.0, -0.2, 0.0]
    if scene == "blocks":   # [0.2, 0.8] x [0.1, 0.5]^2 split at x = 0.5, moving apart at 0.2 m/s
        a = dict(body, shape=dict(type="box", lower=[0.2, 0.1, 0.1], upper=[0.5, 0.5, 0.5]),
                 velocity=[-0.2, 0.0, 0.0], interface=True)
        b = dict(body, shape=dict(type="box", lower=[0.5, 0.1, 0.1], upper=[0.8, 0.5, 0.5]),
                 velocity=[0.2, 0.0, 0.0], interface=True)
        cfg["bodies"] = [a, b]
    elif scene == "notch":  # a slab of damaged particles one cell thick, half way down from the top
        body["shape"] = dict(type="box", lower=[0.2, 0.1, 0.1], upper=[0.8, 0.5, 0.5])
        dx = 1.0 / n_grid
        body["damage_regions"] = [dict(shape=dict(type="box", lower=[0.5 - 0.5 * dx, 0.3, 0.0],
                                                  upper=[0.5 + 0.5 * dx, 0.6, 0.6]))]
    else:
        body["shape"] = dict(type="box", lower=[0.2, 0.1, 0.1], upper=[0.8, 0.5, 0.5])
    if crack:
        cfg["crack"] = {}
    return cfg


def run_case(scene, n_grid, crack, steps, arch, kernel_steps):
    """One process: build, warm up, time `steps` steps; with crack, then time each finder kernel alone."""
    import taichi as ti

    import taichi_mpm as tm
    from taichi_mpm.config import load_config

    sim = tm.Simulation(load_config(scene_config(scene, n_grid, crack, arch)))
    for _ in range(2):
        sim.step()
    ti.sync()
    t, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        sim.step()
    ti.sync()
    row = dict(scene=scene, crack=crack, particles=sim.n, ms_per_step=(time.perf_counter() - t) / steps * 1e3,
               cpu_ms_per_step=(time.process_time() - cpu) / steps * 1e3)
    if crack:
        row["near_fraction"] = float((sim.extension("crack").state.to_numpy() != 0).mean())
        row["kernels_ms"] = kernel_times(sim, kernel_steps)
    return row


def kernel_times(sim, steps):
    """Mean CPU ms (all threads) per step of each crack-finder kernel, each between two
    ti.sync(): CPU time, not wall time, since other jobs on a shared machine move wall time far more."""
    crack, spent = sim.extension("crack"), {}
    timed = kernel_timer(spent, time.process_time)

    saved_k = dict(crack._k)
    for name in ("prepare", "bin_cells", "particle_normals", "contact_list", "classify"):
        if name in crack._k:
            crack._k[name] = timed(name, crack._k[name])
    try:
        for _ in range(steps):
            sim.step()
    finally:
        crack._k.update(saved_k)
    return {k: v / steps * 1e3 for k, v in spent.items()}


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    p.add_argument("--grid", type=int, default=32, help="cells per axis of the unit domain")
    p.add_argument("--kernel-steps", type=int, default=5, help="steps over which each finder kernel is timed")
    p.add_argument("--worker", help="internal: scene,crack; run one case and print its row")
    a = p.parse_args(argv)
    if a.tiny:
        a.grid, a.repeats, a.steps, a.kernel_steps = 12, 1, 2, 1
    steps = a.steps or 10
    if a.worker:
        scene, crack = a.worker.split(",")
        row = run_case(scene, a.grid, crack == "1", steps, a.arch, a.kernel_steps)
        print("RESULT " + json.dumps(row), flush=True)
        return None

    rows = []
    for scene in a.scenes:
        runs = {False: [], True: []}
        for _ in range(a.repeats):
            for crack in (False, True):   # alternate: a load change on the machine hits both alike
                runs[crack].append(worker(a, scene, crack, steps))
        med = {(crack, key): statistics.median(r[key] for r in runs[crack])
               for crack in (False, True) for key in ("ms_per_step", "cpu_ms_per_step")}
        kernels = {k: statistics.median(r["kernels_ms"][k] for r in runs[True]) for k in runs[True][0]["kernels_ms"]}
        rows.append(dict(scene=scene, particles=runs[True][0]["particles"],
                         near_fraction=runs[True][0]["near_fraction"],
                         plain_ms=med[False, "ms_per_step"], crack_ms=med[True, "ms_per_step"],
                         ratio=med[True, "ms_per_step"] / med[False, "ms_per_step"],
                         cpu_ratio=med[True, "cpu_ms_per_step"] / med[False, "cpu_ms_per_step"],
                         ratios=" ".join(f"{c['ms_per_step'] / q['ms_per_step']:.2f}"
                                         for q, c in zip(runs[False], runs[True])),
                         plain_cpu_ms=med[False, "cpu_ms_per_step"], finder_cpu_ms=sum(kernels.values()),
                         **{f"{k}_cpu_ms": v for k, v in kernels.items()}))
    report(rows, a.json)
    return rows


def worker(a, scene, crack, steps):
    cmd = [sys.executable, __file__, "--worker", f"{scene},{int(crack)}", "--grid", str(a.grid), "--arch", a.arch,
           "--steps", str(steps), "--kernel-steps", str(a.kernel_steps)]
    out = subprocess.run(cmd, capture_output=True, text=True)
    rows = [json.loads(line[7:]) for line in out.stdout.splitlines() if line.startswith("RESULT ")]
    if out.returncode or not rows:
        raise RuntimeError(f"crack_cost worker {scene} crack={crack} failed: {out.stderr.strip()[-2000:]}")
    return rows[0]


if __name__ == "__main__":
    main()
