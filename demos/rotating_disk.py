"""A spinning disk with a radial crack: hoop tension opens the crack and it stays open while the disk turns (2D).

    python demos/rotating_disk.py [--set KEY=VALUE]... [--out DIR]

Loads configs/rotating_disk.yaml and writes the outputs of its output section (the crack's faces rotate with the disk without welding back together).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("rotating_disk", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
