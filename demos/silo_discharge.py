"""A 2D silo's discharge rate against Beverloo's law (issue 29): configs/silo.yaml's beads (mu(I)) and gripped bottom
plates, resized to a silo `--width` wide and `--depth` deep with a slot of each width D of `--outlets`, at `--dx`.
The rate is the slope of the mass that has passed below the plates over the `--window`; Beverloo's 2D law
W = C rho sqrt(g) (D - D0)^(3/2) is fitted (C and the empty annulus D0), and a free power law W ~ D^n beside it.

    python demos/silo_discharge.py --dx 0.002 --outlets 2.4 3.2 4.8              # outlets in cm
    python demos/silo_discharge.py --dx 0.001 --outlets 2.4 3.2 4.8 --json rates.json

Outputs off; prints one row per outlet and the fits. Writes nothing but --json.
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

import taichi_mpm as tm
from _common import CONFIGS
from taichi_mpm.config import parse_overrides

G = 9.81


def silo_config(outlet: float, dx: float, width: float, depth: float, end_time: float, overrides=()):
    """configs/silo.yaml resized: plates two cells thick at the silo's bottom, a centred slot `outlet` wide, a fall of
    `depth` below it (room for the heap), beads filling `depth` above it."""
    import yaml

    raw = yaml.safe_load((CONFIGS / "silo.yaml").read_text())
    raw["output"] = dict(formats=[], checkpoint_every=10**9)
    bottom = depth                                   # the plates' top: the beads lie above, the floor a depth below
    raw["domain"].update(upper=[width, 2 * depth + 2 * dx + 0.02], dx=dx)
    raw["solver"]["end_time"] = end_time
    left, right, beads = raw["bodies"]
    half = 0.5 * (width - outlet)
    left["shape"].update(lower=[0.0, bottom - 2 * dx], upper=[half, bottom])
    right["shape"].update(lower=[width - half, bottom - 2 * dx], upper=[width, bottom])
    beads["shape"].update(lower=[0.0, bottom], upper=[width, bottom + depth])
    cfg = tm.load_config(raw, overrides=parse_overrides(list(overrides)))
    return cfg, bottom - 2 * dx


def discharge(outlet: float, dx: float, width: float, depth: float, window, overrides=(), samples=40) -> dict:
    """Step one silo to the window's end; the mass below the plates against time and its slope over the window."""
    cfg, below = silo_config(outlet, dx, width, depth, window[1], overrides)
    sim = tm.Simulation(cfg)
    beads = sim.scene.body == [b.name for b in cfg.bodies].index("beads")
    mass = sim.scene.mass[beads]
    times, passed = [], []
    for t in np.linspace(window[0], window[1], samples):
        while sim.time < t - 1e-12:
            sim.step(min(sim.stable_dt(), t - sim.time))
        y = sim.particles()["x"][beads, 1]
        times.append(sim.time)
        passed.append(float(mass[y < below].sum()))
    rate, _ = np.polyfit(times, passed, 1)
    return dict(outlet=outlet, dx=dx, particles=int(sim.n), rate=float(rate), passed_end=passed[-1],
                steps=int(sim.n_steps), cells=outlet / dx, density=cfg.materials["beads"].density)


def fits(rows, density: float) -> dict:
    """Beverloo's W = C rho sqrt(g) (D - D0)^1.5 (least squares over D0 on a fine grid, C then linear) and W ~ D^n."""
    D = np.array([r["outlet"] for r in rows])
    W = np.array([r["rate"] for r in rows])
    n, _ = np.polyfit(np.log(D), np.log(W), 1)
    best = None
    for D0 in np.linspace(0.0, 0.95 * D.min(), 400):
        f = density * np.sqrt(G) * (D - D0) ** 1.5
        C = float(f @ W / (f @ f))
        err = float(np.abs(C * f / W - 1).max())
        if best is None or err < best["max_error"]:
            best = dict(C=C, D0=float(D0), max_error=err)
    return dict(power_law_exponent=float(n), beverloo=best)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dx", type=float, default=0.002)
    ap.add_argument("--outlets", type=float, nargs="+", default=[2.4, 3.2, 4.8], help="slot widths, cm")
    ap.add_argument("--width", type=float, default=0.16, help="silo width, m")
    ap.add_argument("--depth", type=float, default=0.1, help="bead layer depth above the slot (and fall below), m")
    ap.add_argument("--window", type=float, nargs=2, default=[0.1, 0.3], help="times the rate is fitted over, s")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    rows = []
    for D in a.outlets:
        rows.append(discharge(D / 100, a.dx, a.width, a.depth, a.window, a.overrides))
        r = rows[-1]
        print(f"D = {D:g} cm ({r['cells']:.0f} cells), {r['particles']} particles, {r['steps']} steps: "
              f"{r['rate']:.2f} kg/m/s", file=sys.stderr, flush=True)
    out = dict(rows=rows, **(fits(rows, rows[0]["density"]) if len(rows) >= 2 else {}))
    if "beverloo" in out:
        b = out["beverloo"]
        print(f"power law: W ~ D^{out['power_law_exponent']:.2f}; Beverloo: C = {b['C']:.3f}, "
              f"D0 = {b['D0'] * 100:.2f} cm ({b['D0'] / a.dx:.1f} dx), largest misfit {100 * b['max_error']:.1f} %")
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
