"""Sand (drucker_prager, phi = 30 deg) drains from a hopper through a narrow orifice and builds a pile on a rough
floor below it, as in an hourglass: the grains arrive slowly, so the pile grows at its angle of repose (2D).

    python demos/sand_pile.py [--set KEY=VALUE]... [--out DIR]

Loads configs/sand_pile.yaml and writes the outputs of its output section. At the end it prints the angle of the
pile's two flanks against the friction angle (a cohesionless slope at rest stands at most at phi: the infinite
slope's limit, tan(beta) = tan(phi)): measured in docs/materials.md, "Angle of repose".
"""
import sys

import numpy as np

import taichi_mpm as tm
from _common import parse, run

ORIFICE_Y = 0.15      # the hopper's outlet height in configs/sand_pile.yaml


def flank_angles(x, dx, axis_x):
    """Angles (degrees) of the left and right flanks of the pile below the hopper: lines fitted to the top of each
    column dx wide where the surface lies between 20 % and 80 % of the pile's height (without the rounded apex and
    the thin toe), on each side of the axis x = axis_x."""
    x = x[x[:, 1] < ORIFICE_Y - 2 * dx]                      # the pile, not the sand still in the hopper
    bins = np.floor(x[:, 0] / dx).astype(int)
    cols = np.unique(bins)
    top = np.array([x[bins == b, 1].max() for b in cols])
    xc = (cols + 0.5) * dx
    out = []
    for side in (xc < axis_x, xc > axis_x):
        sel = side & (top > 0.2 * top.max()) & (top < 0.8 * top.max())
        slope = np.polyfit(xc[sel], top[sel], 1)[0] if sel.sum() >= 3 else np.nan
        out.append(float(np.degrees(np.arctan(abs(slope)))))
    return out


def pile(sim):
    """The pile's flank angles, height and the fraction of the sand that has left the hopper."""
    p = sim.particles()
    sand = p["body"] == 2
    x = p["x"][sand]
    dx = sim.cfg.domain.dx
    left, right = flank_angles(x, dx, 0.2)
    below = x[:, 1] < ORIFICE_Y - 2 * dx
    return dict(left=left, right=right, height=float(x[below, 1].max()) if below.any() else 0.0,
                drained=float(below.mean()))


def main(argv=None):
    cfg, args = parse("sand_pile", argv, __doc__)
    sim = run(tm.Simulation(cfg), args.out)
    r = pile(sim)
    phi = cfg.materials["sand"].friction_angle
    print(f"sand_pile: {r['drained']:.0%} of the sand below the hopper; pile {r['height'] * 100:.1f} cm high, flanks "
          f"{r['left']:.1f} and {r['right']:.1f} deg (friction angle {phi:g} deg)", file=sys.stderr)
    sim.pile = r
    return sim


if __name__ == "__main__":
    main(sys.argv[1:])
