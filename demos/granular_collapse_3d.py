"""A cylindrical sand column (drucker_prager, phi = 30 deg) of radius R0 and height a R0 (a = 1) collapses into a
round heap on a rough floor (3D). Lube et al. 2004 (J. Fluid Mech. 508, 175) measured the axisymmetric run-out
(R_inf - R0) / R0 = 1.24 a for a < 1.7 and 1.6 a^(1/2) beyond, and a final height H_inf = a R0 for a < 0.74.

    python demos/granular_collapse_3d.py [--set KEY=VALUE]... [--out DIR]

Loads configs/granular_collapse_3d.yaml, writes the outputs of its output section (frames coloured by the plastic
strain) and prints the run-out (the 99.5th percentile of the particles' distance from the axis, so a few lone
grains do not count) against Lube et al.'s fit, and the deposit's height.
"""
import sys

import numpy as np

import taichi_mpm as tm
from _common import parse, run


def lube_2004(a):
    """Lube et al. 2004's fits of the axisymmetric run-out (R_inf - R0) / R0."""
    return 1.24 * a if a < 1.7 else 1.6 * a ** 0.5


def deposit(sim):
    """Run-out (R_inf - R0) / R0 and height H_inf / R0 of the heap, for the config's cylinder (axis y)."""
    shape = sim.cfg.bodies[0].shape
    x = sim.particles()["x"]
    c = np.asarray(shape.center, float)
    r = np.hypot(x[:, 0] - c[0], x[:, 2] - c[2])
    R0 = shape.radius
    return dict(aspect=shape.height / R0, runout=float((np.percentile(r, 99.5) - R0) / R0),
                height=float(np.percentile(x[r < 0.5 * R0, 1], 99.5) / R0))


def main(argv=None):
    cfg, args = parse("granular_collapse_3d", argv, __doc__)
    sim = run(tm.Simulation(cfg), args.out)
    d = deposit(sim)
    ref = lube_2004(d["aspect"])
    print(f"granular_collapse_3d: a = {d['aspect']:.2f}, run-out (R_inf - R0) / R0 = {d['runout']:.2f} (Lube et al. "
          f"2004: {ref:.2f}, {d['runout'] / ref - 1:+.0%}), height H_inf / R0 = {d['height']:.2f}", file=sys.stderr)
    sim.deposit = d
    return sim


if __name__ == "__main__":
    main(sys.argv[1:])
