"""A water column collapses along the floor of a tank (2D weakly compressible fluid).

    python demos/dam_break.py [--set KEY=VALUE]... [--out DIR]

Loads configs/dam_break.yaml and writes the outputs of its output section (the front reaches the far wall in about
0.6 s). Theory check, printed at the end: the surge front against Martin & Moyce (1952), in their dimensionless
form Z = x_front / a against T = t sqrt(2 g / a) (a: the column's width); their experiment has the front at about
Z = 2 when T = 2.1. The script prints the front's Z when T passes 2.1 (t = 0.30 s for a = 0.4 m).
"""
import math
import sys

import taichi_mpm as tm
from _common import parse, run

T_CHECK, Z_MARTIN_MOYCE = 2.1, 2.0   # Martin & Moyce (1952): Z ~ 2 at T = 2.1 (the check of tests/test_demos.py)


def main(argv=None):
    cfg, args = parse("dam_break", argv, __doc__)
    sim = tm.Simulation(cfg)
    body = cfg.bodies[0].shape
    a = body.upper[0] - body.lower[0]
    g = abs(cfg.solver.gravity[1])
    scale = math.sqrt(2 * g / a)
    seen = {}

    def front(s):   # the first step on or after T = 2.1: record the front
        if "Z" not in seen and s.time * scale >= T_CHECK - 1e-9:
            seen.update(Z=(float(s.particles()["x"][:, 0].max()) - body.lower[0]) / a, T=s.time * scale)

    run(sim, args.out, on_step=front)
    if seen:
        print(f"surge front: Z = x/a = {seen['Z']:.2f} at T = t sqrt(2g/a) = {seen['T']:.2f} "
              f"(Martin & Moyce 1952: about {Z_MARTIN_MOYCE:g} at T = {T_CHECK:g})", file=sys.stderr)
    else:
        print(f"surge front: the run ended at T = {sim.time * scale:.2f}, before the check at T = {T_CHECK:g}",
              file=sys.stderr)
    sim.front_check = seen
    return sim


if __name__ == "__main__":
    main(sys.argv[1:])
