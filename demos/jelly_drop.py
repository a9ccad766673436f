"""A tilted jelly cube falls, bounces and wobbles (3D).

    python demos/jelly_drop.py [--set KEY=VALUE]... [--out DIR]

Loads configs/jelly_drop.yaml and writes the outputs of its output section (try --set solver.transfer=pic to see PIC's damping).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("jelly_drop", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
