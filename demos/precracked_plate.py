"""A plate with a central crack thinner than a cell, pulled at its top and bottom edges: the crack opens (2D).

    python demos/precracked_plate.py [--set KEY=VALUE]... [--out DIR]

Loads configs/precracked_plate.yaml and writes the outputs of its output section (the faces of the crack separate while the stress flows around its tips).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("precracked_plate", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
