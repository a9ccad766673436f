"""Three blocks on an inclined body with a friction coefficient per pair (the crack finder's friction, 2D).

    python demos/friction_incline.py [--set KEY=VALUE]... [--out DIR]

Loads configs/friction_incline.yaml, writes its outputs and prints each block's acceleration along the slope (a
line fitted to its velocity after 0.05 s) against Coulomb's law, g (sin t - mu cos t), or rest where mu > tan t.
"""
import sys

import numpy as np

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("friction_incline", argv, __doc__)
    sim = tm.Simulation(cfg)
    g = np.asarray(cfg.solver.gravity, float)
    slope = np.arctan2(g[0], -g[1])   # the tilt of gravity from the body's normal
    mu = cfg.friction_table(cfg.crack)[0]   # each block's coefficient with the incline (body 0)
    blocks = range(1, len(cfg.bodies))
    history = {b: [] for b in blocks}
    times = []

    def record(s):
        p = s.particles()
        times.append(s.time)
        for b in blocks:
            sel = p["body"] == b
            history[b].append(float(np.average(p["v"][sel, 0], weights=p["mass"][sel])))

    run(sim, args.out, on_step=record)
    t = np.array(times)
    late = t > 0.05
    for b in blocks:
        accel = np.polyfit(t[late], np.array(history[b])[late], 1)[0]
        coulomb = max(0.0, np.linalg.norm(g) * (np.sin(slope) - mu[b] * np.cos(slope)))
        print(f"{cfg.bodies[b].name}: mu {mu[b]:g}, acceleration {accel:.3f} m/s^2, Coulomb's law {coulomb:.3f}")
    return sim


if __name__ == "__main__":
    main(sys.argv[1:])
