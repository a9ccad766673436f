"""A sand column (drucker_prager, plane-strain fit) collapses and spreads along a rough floor (2D, aspect ratio 2).

    python demos/granular_collapse.py [--set KEY=VALUE]... [--out DIR]

Loads configs/granular_collapse.yaml and writes the outputs of its output section, frames coloured by the plastic
strain. The sand comes to rest at about 0.55 s with a run-out of 3.2 column widths beyond the column (measured at
this dx = L0 / 20; Lube et al. 2005: between 1.2 a = 2.4 and 1.9 a^(2/3) = 3.0 for aspect ratio a = 2);
demos/column_collapse_lube.py sweeps the aspect ratio (docs/materials.md).
"""
import sys

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("granular_collapse", argv, __doc__)
    return run(tm.Simulation(cfg), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
