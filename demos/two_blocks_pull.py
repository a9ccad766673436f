"""Two interface blocks pressed together, then pulled apart: contact pushes, the interface never pulls (2D).

    python demos/two_blocks_pull.py [--set KEY=VALUE]... [--out DIR] [--pull ACCEL] [--after T]

Loads configs/two_blocks_pull.yaml (the blocks approach and press together) and, from time T on, pulls each
block outwards with a body acceleration ACCEL; without the crack finder (`--set crack=null`) the blocks
weld on contact and the pull only stretches them.
"""
import argparse
import sys

import numpy as np

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    ap = argparse.ArgumentParser(add_help=False)
    ap.add_argument("--pull", type=float, default=4.0, help="outward acceleration of each block [m/s^2]")
    ap.add_argument("--after", type=float, default=0.15, help="time at which the pull starts [s]")
    extra, rest = ap.parse_known_args(argv)
    cfg, args = parse("two_blocks_pull", rest, __doc__)
    mid = 0.5 * (cfg.domain.lower[0] + cfg.domain.upper[0])

    def pull(X0, t):
        a = np.zeros_like(X0)
        if t >= extra.after:
            a[:, 0] = np.where(X0[:, 0] < mid, -extra.pull, extra.pull)
        return a

    return run(tm.Simulation(cfg, body_force=pull), args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
