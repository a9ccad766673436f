"""Contact by the crack finder (one velocity field, interface particles: configs/colliding_disks_interface.yaml)
against multi-velocity-field contact (`contact: {method: multi_field}`, one field per body): error, time per step
and memory, on two scenes (2D, quadratic, f64, CPU):

- disks: Sulsky's two elastic disks (configs/colliding_disks.yaml) meeting at 0.1 m/s per axis each, run to
  t = 3 s (the impact is over by 2.6 s); error: 1 - |v_after| / |v_before| of each disk's mean velocity (an
  elastic collision gives 0), and the total momentum left (0 at the start).
- block: a 0.2 x 0.1 m block on a 1 m long body lying on a sticky floor, gravity tilted by 30 degrees,
  frictionless, 0.25 s; error: the block's acceleration against g sin 30.
- block_friction: the same with Coulomb friction mu = 0.3 at the interface (crack.friction, contact.friction);
  error: the acceleration against g (sin 30 - mu cos 30).

Time: wall and process CPU ms per step over the whole run after the first step (compile excluded), each case in
its own process (the solver keeps one live Simulation per process). Memory: the run's size estimate
(budget.estimate: per-particle fields x particles + grid bytes at the estimated active blocks; the crack finder's
cell list and contact pool are fixed fields the estimate leaves out, docs/architecture.md).

    python benchmarks/contact_cost.py                 # dx 0.02 (disks) and 0.025 (block)
    python benchmarks/contact_cost.py --tiny          # coarser and shorter: seconds (tests/test_benchmarks.py)
    python benchmarks/contact_cost.py --plot docs/images/contact_cost.png   # also the three panels of docs/contact.md
"""
from __future__ import annotations

import copy
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from common import parser, report  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("crack", "multi_field")
SCENES = ("disks", "block", "block_friction")
MU = 0.3   # block_friction
G = 9.81


def disks(method: str, dx: float, end: float) -> dict:
    name = "colliding_disks_interface" if method == "crack" else "colliding_disks"
    d = yaml.safe_load((ROOT / "configs" / f"{name}.yaml").read_text())
    d.update(precision="f64", arch="cpu", output={"dir": "unused"})
    d["domain"]["dx"] = dx
    d["solver"]["end_time"] = end
    if method == "multi_field":
        d["contact"] = {"method": "multi_field"}
    return d


def block(method: str, dx: float, end: float, mu: float = 0.0) -> dict:
    a = np.radians(30.0)
    mat = dict(model="neo_hookean", E=2.0e5, nu=0.3, density=1000.0)
    iface = method == "crack"
    d = dict(name="contact_block", dim=2, precision="f64", arch="cpu",
             domain=dict(lower=[0.0, 0.0], upper=[1.0, 0.3], dx=dx,
                         boundaries={"default": "slip", "y_min": "sticky"}),
             solver=dict(basis="quadratic", transfer="pic", end_time=end, gravity=[G * np.sin(a), -G * np.cos(a)]),
             materials=dict(m=mat),
             bodies=[dict(name="base", shape=dict(type="box", lower=[0.0, 0.0], upper=[1.0, 0.1]), material="m",
                          interface=iface),
                     dict(name="block", shape=dict(type="box", lower=[0.1, 0.1], upper=[0.3, 0.2]), material="m",
                          interface=iface)])
    if method == "crack":
        d["crack"] = dict(threshold=0.0, contact_in_compression=True, friction=mu)   # -0.6 dragged it 32 %
    else:
        d["contact"] = {"method": "multi_field", "friction": mu}
    return d


def _mean_v(sim, b):
    p, m = sim.particles(), sim.scene.mass
    sel = sim.scene.body == b
    return (p["v"][sel] * m[sel, None]).sum(0) / m[sel].sum()


def run_case(scene: str, method: str, tiny: bool) -> dict:
    import taichi_mpm as tm
    from taichi_mpm import budget
    from taichi_mpm.config import load_config

    dx = (0.04 if tiny else 0.02) if scene == "disks" else (0.05 if tiny else 0.025)
    end = (3.0 if scene == "disks" else 0.25) * (0.1 if tiny else 1.0)
    mu = MU if scene == "block_friction" else 0.0
    cfg = load_config(disks(method, dx, end) if scene == "disks" else block(method, dx, end, mu))
    est = budget.estimate(cfg)
    sim = tm.Simulation(cfg)
    before = [_mean_v(sim, b) for b in (0, 1)]
    sim.step()
    t, cpu, steps0 = time.perf_counter(), time.process_time(), sim.n_steps
    times, vx = [], []
    while sim.time < end - 1e-12:
        sim.step(min(sim.stable_dt(), end - sim.time))
        if scene != "disks":
            times.append(sim.time)
            vx.append(_mean_v(sim, 1)[0])
    steps = sim.n_steps - steps0
    row = dict(scene=scene, method=method, particles=sim.n, dx=dx, steps=sim.n_steps,
               ms_per_step=(time.perf_counter() - t) / steps * 1e3,
               cpu_ms_per_step=(time.process_time() - cpu) / steps * 1e3,
               memory_mb=(est.device_bytes_per_particle * est.particles + est.grid_bytes) / 2**20,
               bytes_per_particle=est.device_bytes_per_particle)
    if scene == "disks":
        after = [_mean_v(sim, b) for b in (0, 1)]
        row["error"] = float(np.mean([1 - np.linalg.norm(a) / np.linalg.norm(b) for a, b in zip(after, before)]))
        row["error_is"] = "1 - rebound speed / impact speed"
        row["momentum_left"] = float(np.abs(sim.momentum()["linear"]).max())
    else:
        t, v = np.array(times), np.array(vx)
        late = t > 0.2 * end
        accel = float(np.polyfit(t[late], v[late], 1)[0])
        a = np.radians(30.0)
        row["error"] = accel / (G * (np.sin(a) - mu * np.cos(a))) - 1
        row["error_is"] = f"acceleration / (g (sin 30 - {mu:g} cos 30)) - 1"
    return row


def worker(scene, method, tiny):
    args = [sys.executable, str(Path(__file__)), "--worker", f"{scene},{method}"] + (["--tiny"] if tiny else [])
    out = subprocess.run(args, capture_output=True, text=True, cwd=ROOT)
    for line in out.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    return dict(scene=scene, method=method, error_is="failed: " + (out.stderr.strip().splitlines() or ["?"])[-1])


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    p.add_argument("--worker", help="internal: scene,method; run one case and print its row")
    p.add_argument("--plot", type=Path, help="also draw time per step, memory and |error| per scene and method here")
    a = p.parse_args(argv)
    if a.worker:
        scene, method = a.worker.split(",")
        print("RESULT " + json.dumps(run_case(scene, method, a.tiny)), flush=True)
        return None
    rows = [worker(scene, method, a.tiny) for scene in a.scenes for method in METHODS]
    for scene in a.scenes:   # each method's cost against the crack finder's
        ref = next((r for r in rows if r["scene"] == scene and r["method"] == "crack" and "ms_per_step" in r), None)
        for r in rows:
            if r["scene"] == scene and ref is not None and "ms_per_step" in r:
                r["time_vs_crack"] = r["ms_per_step"] / ref["ms_per_step"]
                r["memory_vs_crack"] = r["memory_mb"] / ref["memory_mb"]
    report([copy.copy(r) for r in rows], a.json)
    if a.plot:
        plot(rows, a.scenes, a.plot)
    return rows


def plot(rows, scenes, path):
    """Three panels side by side, each a pair of bars per scene (crack finder, multi_field): CPU ms per step, the
    memory estimate and the error's magnitude in percent (its meaning per scene: the table's error_is)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("cpu_ms_per_step", "CPU ms per step"), ("memory_mb", "memory [MB]"), ("error", "|error| [%]")]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    x = np.arange(len(scenes))
    for ax, (key, label) in zip(axes, panels):
        for k, method in enumerate(METHODS):
            vals = [next((abs(r[key]) * (100 if key == "error" else 1) for r in rows
                          if r["scene"] == s and r["method"] == method and key in r), np.nan) for s in scenes]
            ax.bar(x + (k - 0.5) * 0.38, vals, 0.38, label=method)
        ax.set_xticks(x, scenes, rotation=15)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend()
    fig.suptitle("contact: crack finder (one field) against multi-velocity-field contact (2D, quadratic, f64, CPU)")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
