"""A notched bar jerked apart at its ends: the tension waves meet at the notch and a crack runs through (2D).

    python demos/load_to_failure.py [--set KEY=VALUE]... [--out DIR]

Loads configs/load_to_failure.yaml and writes the outputs of its output section (colour by damage: the crack grows from the notch tip across the bar).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("load_to_failure", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
