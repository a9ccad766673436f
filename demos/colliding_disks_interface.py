"""Sulsky's colliding disks with interface particles: the crack finder separates them after impact (2D).

    python demos/colliding_disks_interface.py [--set KEY=VALUE]... [--out DIR]

Loads configs/colliding_disks_interface.yaml and writes the outputs of its output section (the disks push through contact and never weld; colour by body to see the two fields).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("colliding_disks_interface", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
