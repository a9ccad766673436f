"""A flat-bottomed silo discharges through a slot (2D mu(I) rheology with the granular gas).

    python demos/silo.py [--set KEY=VALUE]... [--out DIR]

Loads configs/silo.yaml and writes the outputs of its output section. The beads funnel to the 4 cm slot between
dead zones in the corners, fall 0.2 m and heap on the floor; the discharge is steady from 0.2 s at 25.8 kg/m/s
(the mass below the slot, 0.2 to 1.0 s, measured at this dx of 4 mm; docs/materials.md, mu_i, has its dependence
on the slot's width and on dx against Beverloo's law).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("silo", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
