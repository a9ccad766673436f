"""An elastic rubber sphere strikes a soft plate on a sticky floor (3D).

    python demos/sphere_impact.py [--set KEY=VALUE]... [--out DIR]

Loads configs/sphere_impact.yaml and writes the outputs of its output section (color by von Mises stress; movie in runs/sphere_impact_python/movie.mp4).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("sphere_impact", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
