"""Two elastic disks collide and bounce apart (2D; Sulsky, Chen and Schreyer 1994).

    python demos/colliding_disks.py [--set KEY=VALUE]... [--out DIR]

Loads configs/colliding_disks.yaml and writes the outputs of its output section (total energy is nearly conserved through the impact).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("colliding_disks", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
