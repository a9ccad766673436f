"""A soft beam clamped to the left wall sags and swings under gravity (2D).

    python demos/cantilever.py [--set KEY=VALUE]... [--out DIR]

Loads configs/cantilever.yaml and writes the outputs of its output section (the tip swings down past its static deflection and back).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("cantilever", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
