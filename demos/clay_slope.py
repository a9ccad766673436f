"""A vertical cut in normally consolidated clay (modified Cam-Clay) fails under its own weight (2D).

    python demos/clay_slope.py [--set KEY=VALUE]... [--out DIR]

Loads configs/clay_slope.yaml and writes the outputs of its output section. The clay starts consolidated under its
own weight (bodies[].geostatic: K0 conditions); without cohesion at the surface the 0.4 m face cannot stand: it
slumps and runs out to 0.87 m (2.9 widths), at rest by 1 s (measured at dx 1 cm; docs/materials.md, cam_clay).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("clay_slope", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
