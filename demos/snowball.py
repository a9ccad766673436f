"""A snowball (snow, Stomakhin et al. 2013) thrown at a wall: it packs where it strikes (J_p < 1, harder) and
breaks apart (J_p > 1, softer) as it spreads along the wall (2D).

    python demos/snowball.py [--set KEY=VALUE]... [--out DIR]

Loads configs/snowball.yaml and writes the outputs of its output section, frames coloured by J_p (blue: packed,
red: torn). At the end it prints how much of the ball packed and how much tore, and the rebound: snow is plastic,
so it keeps little of its speed (tests/test_demos.py::test_snowball_packs_and_breaks_apart).
"""
import sys

import numpy as np

import taichi_mpm as tm
from _common import parse, run


def summary(sim, v0):
    """Fractions of particles packed (J_p < 0.98) and torn (J_p > 1.02), the mean velocity along the throw relative
    to v0, and the ball's extent along the wall relative to its initial diameter."""
    p = sim.particles()
    jp = p["Jp"]
    y = p["x"][:, 1]
    return dict(packed=float(np.mean(jp < 0.98)), torn=float(np.mean(jp > 1.02)),
                rebound=float(np.sum(p["mass"] * p["v"][:, 0]) / np.sum(p["mass"]) / v0),
                spread=float((y.max() - y.min()) / (sim.scene.x[:, 1].max() - sim.scene.x[:, 1].min())))


def main(argv=None):
    cfg, args = parse("snowball", argv, __doc__)
    sim = run(tm.Simulation(cfg), args.out)
    v0 = float(cfg.bodies[0].velocity[0])
    s = summary(sim, v0)
    print(f"snowball: {s['packed']:.0%} of the snow packed (J_p < 0.98), {s['torn']:.0%} torn (J_p > 1.02); "
          f"mean velocity {s['rebound']:+.2f} v0; spread along the wall {s['spread']:.2f} x its diameter", file=sys.stderr)
    sim.snow_summary = s
    return sim


if __name__ == "__main__":
    main(sys.argv[1:])
