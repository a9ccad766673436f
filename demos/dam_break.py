"""A water column collapses along the floor of a tank (2D weakly compressible fluid).

    python demos/dam_break.py [--set KEY=VALUE]... [--out DIR]

Loads configs/dam_break.yaml and writes the outputs of its output section (the front reaches the far wall in about 0.6 s).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("dam_break", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
