"""A stiff sphere strikes a brittle plate on two supports; the plate cracks under the impact (3D).

    python demos/sphere_impact_fracture.py [--set KEY=VALUE]... [--out DIR]

Loads configs/sphere_impact_fracture.yaml and writes the outputs of its output section (colour by damage: the Rankine law nucleates cracks that the crack finder then opens).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("sphere_impact_fracture", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
