"""Sand (drucker_prager, phi = 30 deg) drains from a hopper through a narrow orifice and builds a pile on a rough
floor 8 cm below it, as in an hourglass: the grains arrive slowly and land gently, so the pile grows at its angle
of repose (2D).

    python demos/sand_pile.py [--set KEY=VALUE]... [--out DIR] [--plot docs/images/angle_of_repose.png]

Loads configs/sand_pile.yaml and writes the outputs of its output section. At the end it prints the angle of the
pile's two flanks against the friction angle (with `fit: simple_shear` a slope flows above phi and stands below
it: tan(beta) = tan(phi) on the plane of its shear): measured in docs/materials.md, "Angle of repose".
"""
import sys

import numpy as np

import taichi_mpm as tm
from _common import parse, run

AT_REST = 0.05        # m/s: slower than this a grain belongs to the pile (grains still falling are ~1 m/s)


def flank_angles(x, dx, axis_x, orifice_y):
    """Angles (degrees) of the left and right flanks of the pile below the hopper: lines fitted to the top of each
    column dx wide where the surface lies between 20 % and 80 % of the pile's height (without the rounded apex and
    the thin toe), on each side of the axis x = axis_x. x: the grains at rest."""
    x = x[x[:, 1] < orifice_y - 2 * dx]                      # the pile, not the sand still in the hopper
    if len(x) == 0:
        return [float("nan"), float("nan")]
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
    orifice_y = float(p["x"][~sand, 1].min())               # the hopper walls' lowest point
    x, speed = p["x"][sand], np.linalg.norm(p["v"][sand], axis=1)
    dx = sim.cfg.domain.dx
    rest = x[speed < AT_REST]
    left, right = flank_angles(rest, dx, 0.2, orifice_y)
    below = x[:, 1] < orifice_y - 2 * dx
    pile_top = rest[rest[:, 1] < orifice_y - 2 * dx, 1]
    return dict(left=left, right=right, height=float(pile_top.max()) if len(pile_top) else 0.0,
                drained=float(below.mean()))


def plot(x, body, r, phi, path):
    """The final particles (hopper walls grey, sand by height) with the pile's fitted flank angles and the friction
    angle drawn from its apex."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.scatter(*x[body < 2].T, s=1, c="0.6")
    ax.scatter(*x[body == 2].T, s=1, c="C1")
    top, s = r["height"], np.linspace(0, 0.2, 50)
    for sign in (-1, 1):
        ax.plot(0.2 + sign * s, top - s * np.tan(np.radians(phi)), "k--", lw=1,
                label=f"friction angle {phi:g} deg" if sign < 0 else None)
    ax.set(xlim=(0, 0.4), ylim=(0, 0.24), aspect=1, xlabel="x [m]", ylabel="y [m]",
           title=f"flanks {r['left']:.1f} and {r['right']:.1f} deg")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None):
    import argparse

    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--plot", default=None)
    extra, argv = pre.parse_known_args(argv)
    cfg, args = parse("sand_pile", argv, __doc__)
    sim = run(tm.Simulation(cfg), args.out)
    r = pile(sim)
    phi = cfg.materials["sand"].friction_angle
    print(f"sand_pile: {r['drained']:.0%} of the sand below the hopper; pile {r['height'] * 100:.1f} cm high, flanks "
          f"{r['left']:.1f} and {r['right']:.1f} deg (friction angle {phi:g} deg)", file=sys.stderr)
    sim.pile = r
    if extra.plot:
        p = sim.particles()
        plot(p["x"], p["body"], r, phi, extra.plot)
    return sim


if __name__ == "__main__":
    main(sys.argv[1:])
