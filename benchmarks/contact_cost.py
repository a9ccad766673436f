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
- hertz: an elastic disk (r 0.2 m) pressed by its weight onto an elastic base of the same material (plane strain,
  frictionless, PIC), gravity ramped smoothly from 0 over 1 s (a body force: switched on at once it set the disk
  bouncing with the contact load swinging between 0.2 and 4.4 times its weight for the whole run), held to 1.4 s;
  error: the contact half-width against Hertz's a = sqrt(4 P r / (pi E*)), 1/E* = 2 (1 - nu^2) / E, P the disk's
  weight per unit length (a = 0.06 m, 7.7 cells at dx 1/128). Measured from the base's particle rows down to a
  depth of 0.4 a: each row's -sigma_yy less its far-field value (the base's own weight) is the vertical stress
  p(x) the contact causes there, averaged over the last 0.3 s (about one period of the disk's remaining bounce).
  Below an elliptic (Hertz) pressure of half-width a, a half-space carries sigma_yy whose second moment at depth z
  is a^2 / 4 + z^2 (the Flamant solution's is z^2, added over the load), so a = 2 sqrt(<x^2> - z^2) per row; the
  rows' mean is reported, and their mean load against P (1 in equilibrium; single rows swing +-30 % with the
  particle stresses' row-to-row oscillation).
- pile_N (N = 2, 8, 32 by default, `--piles`): N elastic disks (r 0.04 m, 4 cells) on a lattice falling onto a
  sticky floor with alternating sideways speeds, 0.3 s: cost only, against the number of bodies (multi_field keeps
  one node field per body, the crack finder's fields are per particle: the seed's claim is about this growth). The
  first step's time (compile, empty cache) is reported too.

Time: wall and process CPU ms per step over the whole run after the first step (compile excluded), each case in
its own process (the solver keeps one live Simulation per process). Memory: the run's size estimate
(budget.estimate: per-particle fields x particles + grid bytes at the estimated active blocks; the crack finder's
cell list and contact pool are fixed fields the estimate leaves out, docs/architecture.md).

    python benchmarks/contact_cost.py                 # dx 0.02 (disks), 0.025 (block), 1/128 (hertz)
    python benchmarks/contact_cost.py --tiny          # coarser and shorter: seconds (tests/test_benchmarks.py)
    python benchmarks/contact_cost.py --plot docs/images/contact_cost.png   # also the four panels of docs/contact.md
    python benchmarks/contact_cost.py --replot rows.json --plot out.png     # the panels of an earlier run's --json
"""
from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from common import parser, report  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("crack", "multi_field", "crack_gap")   # crack_gap: the crack finder with crack.contact_gap GAP
GAP = 0.3
SCENES = ("disks", "block", "block_friction", "hertz")
MU = 0.3   # block_friction
G = 9.81
# hertz: disk radius, base top, material; gravity chosen for a contact half-width of HERTZ_A
HERTZ_R, HERTZ_TOP, HERTZ_E, HERTZ_NU, HERTZ_RHO, HERTZ_A = 0.2, 0.25, 1.0e5, 0.3, 1000.0, 0.06
HERTZ_ESTAR = HERTZ_E / (2.0 * (1.0 - HERTZ_NU ** 2))            # two bodies of one material, plane strain
HERTZ_P = np.pi * HERTZ_ESTAR * HERTZ_A ** 2 / (4.0 * HERTZ_R)    # load per unit length for HERTZ_A
HERTZ_G = HERTZ_P / (HERTZ_RHO * np.pi * HERTZ_R ** 2)            # the disk's weight gives it
HERTZ_END, HERTZ_RAMP, HERTZ_AVERAGE = 1.4, 1.0, 0.3              # s: run, gravity ramp, stresses averaged over


def with_contact(d: dict, method: str, mu: float = 0.0) -> dict:
    """d with its bodies' contact by `method`: interface bodies and the crack finder's section (threshold 0, a flat
    interface: -0.6 dragged the block 32 %; crack.contact_gap GAP for crack_gap), or multi_field; Coulomb mu."""
    iface = method.startswith("crack")
    for body in d["bodies"]:
        body["interface"] = iface
    if iface:
        d["crack"] = dict(threshold=0.0, contact_in_compression=True, friction=mu,
                          contact_gap=GAP if method == "crack_gap" else None)
    else:
        d["contact"] = {"method": "multi_field", "friction": mu}
    return d


def disks(method: str, dx: float, end: float) -> dict:
    name = "colliding_disks_interface" if method.startswith("crack") else "colliding_disks"
    d = yaml.safe_load((ROOT / "configs" / f"{name}.yaml").read_text())
    d.update(precision="f64", arch="cpu", output={"dir": "unused"})
    d["domain"]["dx"] = dx
    d["solver"]["end_time"] = end
    if method == "multi_field":
        d["contact"] = {"method": "multi_field"}
    if method == "crack_gap":
        d["crack"]["contact_gap"] = GAP
    return d


def block(method: str, dx: float, end: float, mu: float = 0.0) -> dict:
    a = np.radians(30.0)
    mat = dict(model="neo_hookean", E=2.0e5, nu=0.3, density=1000.0)
    d = dict(name="contact_block", dim=2, precision="f64", arch="cpu",
             domain=dict(lower=[0.0, 0.0], upper=[1.0, 0.3], dx=dx,
                         boundaries={"default": "slip", "y_min": "sticky"}),
             solver=dict(basis="quadratic", transfer="pic", end_time=end, gravity=[G * np.sin(a), -G * np.cos(a)]),
             materials=dict(m=mat),
             bodies=[dict(name="base", shape=dict(type="box", lower=[0.0, 0.0], upper=[1.0, 0.1]), material="m"),
                     dict(name="block", shape=dict(type="box", lower=[0.1, 0.1], upper=[0.3, 0.2]), material="m")])
    return with_contact(d, method, mu)


def hertz(method: str, dx: float, end: float) -> dict:
    """The disk resting on the base at one point (their particles' domains touch); its load comes from
    hertz_gravity (a body force, ramped)."""
    mat = dict(model="neo_hookean", E=HERTZ_E, nu=HERTZ_NU, density=HERTZ_RHO)
    centre = [0.5, HERTZ_TOP + HERTZ_R]
    d = dict(name="contact_hertz", dim=2, precision="f64", arch="cpu",
             domain=dict(lower=[0.0, 0.0], upper=[1.0, 0.75], dx=dx,
                         boundaries={"default": "slip", "y_min": "sticky"}),
             solver=dict(basis="quadratic", transfer="pic", end_time=end),
             materials=dict(m=mat),
             bodies=[dict(name="base", shape=dict(type="box", lower=[0.0, 0.0], upper=[1.0, HERTZ_TOP]),
                          material="m"),
                     dict(name="disk", shape=dict(type="sphere", center=centre, radius=HERTZ_R), material="m")])
    return with_contact(d, method)


def pile(method: str, dx: float, end: float, n: int) -> dict:
    """n disks (r 0.04) on a lattice of 0.1 m in [0.1, 0.9] x [0.15, ...], each moving sideways at +-0.2 m/s."""
    cols = min(n, 8)
    bodies = [dict(name=f"disk{k}", shape=dict(type="sphere", center=[0.15 + 0.1 * (k % cols), 0.1 + 0.1 * (k // cols)],
                                               radius=0.04),
                   material="m", velocity=[0.2 * (-1) ** k, 0.0]) for k in range(n)]
    d = dict(name="contact_pile", dim=2, precision="f64", arch="cpu",
             domain=dict(lower=[0.0, 0.0], upper=[1.0, 1.0], dx=dx, boundaries={"default": "slip", "y_min": "sticky"}),
             solver=dict(basis="quadratic", transfer="apic", end_time=end, gravity=[0.0, -G]),
             materials=dict(m=dict(model="neo_hookean", E=1.0e5, nu=0.3, density=1000.0)), bodies=bodies)
    return with_contact(d, method)


def hertz_gravity(ramp: float):
    """Simulation's body_force: gravity HERTZ_G downwards, ramped as (1 - cos(pi t / ramp)) / 2 up to t = ramp."""
    def force(X, t):
        g = np.zeros_like(X)
        g[:, 1] = -HERTZ_G * (0.5 - 0.5 * np.cos(np.pi * min(t / ramp, 1.0)))
        return g
    return force


def base_stress(sim):
    """-sigma_yy of every base particle (body 0), in creation order."""
    return -sim.particles()["stress"][sim.scene.body == 0, 1, 1]


def hertz_error(x0, pressure):
    """From the base particles' reference positions x0 and their mean -sigma_yy: the contact half-width (the mean of
    the rows' 2 sqrt(<x^2> - z^2) down to 0.4 a, tension clipped, within 3 a + 2 z of the centre), its error against
    Hertz, and the rows' mean load (p x particle spacing) against the disk's weight."""
    rows = np.unique(np.round(x0[:, 1], 9))[::-1]
    rows = rows[HERTZ_TOP - rows <= 0.4 * HERTZ_A]
    widths, loads = [], []
    for y in rows:
        row = np.abs(x0[:, 1] - y) < 1e-7
        x, p = x0[row, 0] - 0.5, pressure[row]
        p = p - np.median(p[np.abs(x) > 0.35])      # the base's own weight above the row
        z = HERTZ_TOP - y
        near = np.abs(x) < 3 * HERTZ_A + 2 * z
        q = np.clip(p[near], 0.0, None)
        widths.append(2.0 * np.sqrt(max((x[near] ** 2 * q).sum() / q.sum() - z * z, 0.0)))
        loads.append(p[near].sum() * np.median(np.diff(np.sort(x))) / HERTZ_P)
    a = float(np.mean(widths))
    return a, a / HERTZ_A - 1.0, float(np.mean(loads))


def _mean_v(sim, b):
    p, m = sim.particles(), sim.scene.mass
    sel = sim.scene.body == b
    return (p["v"][sel] * m[sel, None]).sum(0) / m[sel].sum()


def run_case(scene: str, method: str, tiny: bool) -> dict:
    import taichi_mpm as tm
    from taichi_mpm import budget
    from taichi_mpm.config import load_config

    kind = scene.split("_")[0]
    dx = {"disks": (0.04, 0.02), "hertz": (0.025, 1.0 / 128), "pile": (0.02, 0.01)}.get(kind, (0.05, 0.025))
    dx = dx[0 if tiny else 1]
    end = {"disks": 3.0, "hertz": HERTZ_END, "pile": 0.3}.get(kind, 0.25) * (0.1 if tiny else 1.0)
    mu = MU if scene == "block_friction" else 0.0
    data = (disks(method, dx, end) if kind == "disks" else hertz(method, dx, end) if kind == "hertz" else
            pile(method, dx, end, int(scene.split("_")[1])) if kind == "pile" else block(method, dx, end, mu))
    cfg = load_config(data)
    est = budget.estimate(cfg, body_force=kind == "hertz")
    t_first = time.perf_counter()
    scale = end / HERTZ_END   # the hertz run's times, shortened with it by --tiny
    sim = tm.Simulation(cfg, body_force=hertz_gravity(HERTZ_RAMP * scale) if kind == "hertz" else None)
    before = [_mean_v(sim, b) for b in (0, 1)]
    sim.step()
    t_first = time.perf_counter() - t_first
    t, cpu, steps0 = time.perf_counter(), time.process_time(), sim.n_steps
    times, vx, pressures = [], [], []
    x0_base = sim.scene.x[sim.scene.body == 0].copy()
    while sim.time < end - 1e-12:
        sim.step(min(sim.stable_dt(), end - sim.time))
        if scene == "hertz":
            if sim.time > end - HERTZ_AVERAGE * scale and (not times or sim.time > times[-1] + 0.01 * end):
                times.append(sim.time)
                pressures.append(base_stress(sim))
        elif scene != "disks":
            times.append(sim.time)
            vx.append(_mean_v(sim, 1)[0])
    steps = sim.n_steps - steps0
    row = dict(scene=scene, method=method, particles=sim.n, dx=dx, steps=sim.n_steps,
               ms_per_step=(time.perf_counter() - t) / steps * 1e3,
               cpu_ms_per_step=(time.process_time() - cpu) / steps * 1e3,
               memory_mb=(est.device_bytes_per_particle * est.particles + est.grid_bytes) / 2**20,
               bytes_per_particle=est.device_bytes_per_particle, first_step_s=t_first, bodies=len(cfg.bodies))
    if kind == "pile":
        row["error_is"] = "(cost only)"
    elif scene == "disks":
        after = [_mean_v(sim, b) for b in (0, 1)]
        row["error"] = float(np.mean([1 - np.linalg.norm(a) / np.linalg.norm(b) for a, b in zip(after, before)]))
        row["error_is"] = "1 - rebound speed / impact speed"
        row["momentum_left"] = float(np.abs(sim.momentum()["linear"]).max())
    elif scene == "hertz":
        a, err, load = hertz_error(x0_base, np.mean(pressures, axis=0))
        row.update(error=err, half_width=a, hertz_half_width=HERTZ_A, load_carried=load, samples=len(pressures),
                   error_is="contact half-width / Hertz's - 1")
    else:
        t, v = np.array(times), np.array(vx)
        late = t > 0.2 * end
        accel = float(np.polyfit(t[late], v[late], 1)[0])
        a = np.radians(30.0)
        row["error"] = accel / (G * (np.sin(a) - mu * np.cos(a))) - 1
        row["error_is"] = f"acceleration / (g (sin 30 - {mu:g} cos 30)) - 1"
    return row


def worker(scene, method, tiny):
    """One case in a fresh process with an empty kernel cache (first_step_s: the compile a new scene costs)."""
    args = [sys.executable, str(Path(__file__)), "--worker", f"{scene},{method}"] + (["--tiny"] if tiny else [])
    with tempfile.TemporaryDirectory() as cache:
        out = subprocess.run(args, capture_output=True, text=True, cwd=ROOT,
                             env=dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache))
    for line in out.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    return dict(scene=scene, method=method, error_is="failed: " + (out.stderr.strip().splitlines() or ["?"])[-1])


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--scenes", nargs="+", choices=SCENES + ("piles",), default=list(SCENES) + ["piles"])
    p.add_argument("--piles", type=int, nargs="+", default=[2, 8, 32], help="body counts of the pile scenes")
    p.add_argument("--worker", help="internal: scene,method; run one case and print its row")
    p.add_argument("--plot", type=Path, help="also draw time per step, memory and |error| per scene and method here")
    p.add_argument("--replot", type=Path, help="draw --plot from this earlier --json instead of running")
    p.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    a = p.parse_args(argv)
    if a.replot:
        rows = json.loads(a.replot.read_text())
        plot(rows, list(dict.fromkeys(r["scene"] for r in rows)), a.plot)
        return rows
    if a.worker:
        scene, method = a.worker.split(",")
        print("RESULT " + json.dumps(run_case(scene, method, a.tiny)), flush=True)
        return None
    a.scenes = [s for scene in a.scenes for s in ([f"pile_{n}" for n in a.piles] if scene == "piles" else [scene])]
    rows = [worker(scene, method, a.tiny) for scene in a.scenes for method in a.methods]
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
    """Four panels side by side, each a pair of bars per scene (crack finder, multi_field): CPU ms per step, the
    memory estimate, the first step with an empty kernel cache (compile) and the error's magnitude in percent (its
    meaning per scene: the table's error_is; the piles measure cost only)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("cpu_ms_per_step", "CPU ms per step"), ("memory_mb", "memory [MB]"),
              ("first_step_s", "first step, empty cache [s]"), ("error", "|error| [%]")]
    fig, axes = plt.subplots(1, 4, figsize=(17, 4.2))
    x = np.arange(len(scenes))
    for ax, (key, label) in zip(axes, panels):
        methods = [m for m in METHODS if any(r["method"] == m for r in rows)]
        width = 0.8 / len(methods)
        for k, method in enumerate(methods):
            vals = [next((abs(r[key]) * (100 if key == "error" else 1) for r in rows
                          if r["scene"] == s and r["method"] == method and r.get(key) is not None), np.nan)
                    for s in scenes]
            ax.bar(x + (k - (len(methods) - 1) / 2) * width, vals, width, label=method)
        ax.set_xticks(x, scenes, rotation=35, ha="right")
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend()
    fig.suptitle("contact: crack finder (one field; crack_gap: with crack.contact_gap) against multi-velocity-field "
                 "contact (2D, quadratic, f64, CPU)")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
