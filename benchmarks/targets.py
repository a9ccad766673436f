"""Issue 31's speed targets in one run: each measured by the benchmark that owns it, run here in turn, and reported
against its target (met or not). Ratios are taken within one benchmark run (the machines are shared and noisy).

| target | measured by |
| --- | --- |
| >= 2x Taichi's mpm3d on its own particles at n_grid 32, 64, 128 (median of the rounds' ratios) | scaling.py |
| >= 6x taichi_elements on its elastic cube (medians, alternating) | here, with --taichi-elements DIR |
| the crack finder <= 1.3x a plain step (3D interface blocks) | crack_cost.py --scenes blocks |
| P2G and G2P each within 1.5x of their roofline bound | roofline.py |
| 3D quadratic first step: cold <= 5 s, warm <= 1 s (short and long run) | compile_time.py |
| the main demo with frames and VTU: total <= 1.4x (first step + stepping), folder <= 75 MB (half of 150) | outputs.py |

    python benchmarks/targets.py                                  # all but taichi_elements (~15 min on 2 cores)
    python benchmarks/targets.py --taichi-elements PATH/taichi_elements --only elements
    python benchmarks/targets.py --only mpm3d crack --rounds 1    # some of them, quicker

taichi_elements is not on the package index: give the folder that holds its `engine` package. Writes nothing outside
temporary folders (and --json, if given).
"""
import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
KINDS = ("mpm3d", "elements", "crack", "roofline", "compile", "demo")

# taichi_elements' benchmark scene (its own MPMSolver; elastic cube 0.4^3 falling in a unit box, 8 particles per
# cell, its default dt) and ours on the same particles' spacing, material and dt: each prints "RESULT <json>"
_ELEMENTS = """
import contextlib, io, json, sys, time
sys.path.insert(0, sys.argv[1])
import taichi as ti
ti.init(arch=ti.cpu, offline_cache=True)
from engine.mpm_solver import MPMSolver
res, steps = int(sys.argv[2]), int(sys.argv[3])
mpm = MPMSolver(res=(res,) * 3, size=1, unbounded=False, use_voxelizer=False, max_num_particles=2**24)
mpm.add_cube(lower_corner=(0.3,) * 3, cube_size=(0.4,) * 3, material=MPMSolver.material_elastic, sample_density=8)
n, dt = mpm.n_particles[None], mpm.default_dt
with contextlib.redirect_stdout(io.StringIO()):
    mpm.step(dt * 2)
    ti.sync()
    t = time.perf_counter()
    for _ in range(steps):
        mpm.step(dt * 0.999)   # one substep each
    ti.sync()
print("RESULT " + json.dumps(dict(particles=int(n), rate=n * steps / (time.perf_counter() - t))))
"""
_OURS = """
import json, sys
sys.path.insert(0, sys.argv[3])
import taichi_mpm as tm
from common import time_steps
res, steps = int(sys.argv[1]), int(sys.argv[2])
dx = 1.0 / res
cfg = {"name": "elements_scene", "dim": 3, "precision": "f32", "arch": "cpu",
       "domain": {"lower": [0, 0, 0], "upper": [1, 1, 1], "dx": dx},
       "solver": {"basis": "quadratic", "transfer": "apic", "dt": 2e-2 * dx, "end_time": 10.0,
                  "gravity": [0, -9.8, 0]},
       "materials": {"e": {"model": "fixed_corotated", "E": 1e6, "nu": 0.2, "density": 1000.0}},
       "bodies": [{"name": "cube", "shape": {"type": "box", "lower": [0.3] * 3, "upper": [0.7] * 3},
                   "material": "e", "particles_per_cell": 2}]}
sim = tm.Simulation(tm.load_config(cfg))
sim.step()
print("RESULT " + json.dumps(dict(particles=sim.n, rate=sim.n / time_steps(sim.step, steps, 1))))
"""


def _run(args: list, timeout: float = 3600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *map(str, args)], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout, check=True)


def _benchmark(script: str, args: list, tmp: Path):
    """Run benchmarks/<script> with --json into tmp; its rows."""
    out = tmp / f"{script}.json"
    _run([HERE / script, *args, "--json", out])
    return json.loads(out.read_text())


def _row(target: str, measured: float, goal: float, better: str, note: str = "") -> dict:
    met = measured >= goal if better == "higher" else measured <= goal
    sign = ">=" if better == "higher" else "<="
    return dict(target=target, goal=f"{sign} {goal:g}", measured=round(measured, 3), met="yes" if met else "no",
                note=note)


def mpm3d(a, tmp) -> list:
    runs = _benchmark("scaling.py", ["--grids", "32,64,128", "--rounds", a.rounds, "--steps", a.steps], tmp)
    rows = []
    for grid, r in sorted(runs.items(), key=lambda kv: int(kv[0])):
        ratios = [x["ours"] / x["mpm3d"] for x in r]
        rows.append(_row(f"ours / mpm3d, n_grid {grid} ({r[0]['particles']} particles)", statistics.median(ratios),
                         2.0, "higher", "rounds: " + " ".join(f"{x:.2f}" for x in ratios)))
    return rows


def elements(a, tmp) -> list:
    if not a.taichi_elements:
        return [dict(target="ours / taichi_elements", goal=">= 6", measured=None, met="not measured",
                     note="needs --taichi-elements DIR (the folder holding its engine package)")]
    peer, ours = tmp / "elements_peer.py", tmp / "elements_ours.py"
    peer.write_text(_ELEMENTS)
    ours.write_text(_OURS)

    def rate(args):
        line = next(x for x in _run(args).stdout.splitlines() if x.startswith("RESULT "))
        return json.loads(line[7:])

    ratios = []
    for _ in range(a.rounds):   # alternating: a load change hits both alike
        theirs = rate([peer, Path(a.taichi_elements).resolve(), 64, a.steps])
        mine = rate([ours, 64, a.steps, HERE])
        ratios.append(mine["rate"] / theirs["rate"])
    return [_row(f"ours / taichi_elements, res 64 ({mine['particles']} particles)", statistics.median(ratios), 6.0,
                 "higher", "rounds: " + " ".join(f"{x:.2f}" for x in ratios))]


def crack(a, tmp) -> list:
    rows = _benchmark("crack_cost.py", ["--scenes", "blocks", "--repeats", a.rounds, *(["--tiny"] if a.tiny else [])],
                      tmp)
    r = rows[0]
    return [_row(f"crack finder / plain step, 3D interface blocks ({r['particles']} particles)", r["ratio"], 1.3,
                 "lower", f"rounds: {r['ratios']}; CPU-time ratio {r['cpu_ratio']:.2f}")]


def roofline(a, tmp) -> list:
    rows = _benchmark("roofline.py", ["--tiny"] if a.tiny else [], tmp)
    out = []
    for r in rows:
        if r["kernel"] in ("p2g", "g2p") and r["x_of_bound"]:
            out.append(_row(f"{r['kernel']} / its roofline bound ({r['limit']})", r["x_of_bound"], 1.5, "lower",
                            f"{r['ms_per_step']:.2f} ms against {r['bound_ms']:.2f} ms"))
    return out


def compile_times(a, tmp) -> list:
    rows = _benchmark("compile_time.py", ["--bases", "quadratic"], tmp)
    goals = {"cold": 5.0, "warm": 1.0}
    return [_row(f"first step, {r['scene']}, {r['cache']} cache", r["first_step_s"], goals[r["cache"]], "lower",
                 f"import {r['import_s']:.2f} s included") for r in rows]


def demo(a, tmp) -> list:
    rows = _benchmark("outputs.py", ["--modes", "live", "--rounds", a.rounds], tmp)
    ratios, sizes = [r["total_over_solver"] for r in rows], [r["folder_mb"] for r in rows]
    loads = " ".join(f"{r['load_avg']:.1f}" for r in rows)
    return [_row("main demo: total / (first step + stepping)", statistics.median(ratios), 1.4, "lower",
                 "rounds: " + " ".join(f"{x:.2f}" for x in ratios) + f"; load average {loads}"),
            _row("main demo: run folder MB", statistics.median(sizes), 75.0, "lower", "default fields")]


MEASURE = dict(mpm3d=mpm3d, elements=elements, crack=crack, roofline=roofline, compile=compile_times, demo=demo)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--only", nargs="+", choices=KINDS, default=list(KINDS))
    p.add_argument("--rounds", type=int, default=3, help="rounds (medians reported) where a benchmark alternates")
    p.add_argument("--steps", type=int, default=20, help="timed steps per round (mpm3d, taichi_elements)")
    p.add_argument("--taichi-elements", help="the folder holding taichi_elements' engine package")
    p.add_argument("--json", type=Path, help="also write the table here")
    p.add_argument("--tiny", action="store_true", help="the crack and roofline benchmarks in their seconds-long setup")
    a = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind in a.only:
            print(f"measuring {kind} ...", file=sys.stderr, flush=True)
            rows += MEASURE[kind](a, Path(tmp))
    print("| target | goal | measured | met | note |")
    print("| --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['target']} | {r['goal']} | {r['measured']} | {r['met']} | {r['note']} |")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    main()
