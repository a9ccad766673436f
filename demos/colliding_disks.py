"""Two elastic disks collide and bounce apart (2D; Sulsky, Chen and Schreyer 1994).

    python demos/colliding_disks.py [--set KEY=VALUE]... [--out DIR]

Loads configs/colliding_disks.yaml and writes the outputs of its output section. Theory check, printed at the
end: the disks' total linear momentum (zero: equal disks with opposite velocities, and nothing else pushes them
while they stay off the walls) and the total energy kinetic + strain against its initial value (elastic
disks: conserved, up to the transfer's dissipation).
"""
import sys

import numpy as np

import taichi_mpm as tm
from _common import parse, run


def main(argv=None):
    cfg, args = parse("colliding_disks", argv, __doc__)
    sim = tm.Simulation(cfg)
    e0 = sim.energy()
    p0 = np.abs(sim.particles()["mass"][:, None] * sim.particles()["v"]).sum()   # scale of the momentum
    run(sim, args.out)
    e = sim.energy()
    momentum = sim.momentum()["linear"]
    ratio = (e["kinetic"] + e["strain"]) / (e0["kinetic"] + e0["strain"])
    print(f"theory check at t={sim.time:.3g} s: total momentum {np.array2string(np.asarray(momentum), precision=3)} "
          f"kg m/s (exact 0; |m v| summed: {p0:.3g}), energy kinetic + strain = {ratio:.3f} x initial "
          f"(elastic: 1)", file=sys.stderr)
    sim.theory_check = dict(momentum=np.asarray(momentum), momentum_scale=p0, energy_ratio=ratio)
    return sim


if __name__ == "__main__":
    main(sys.argv[1:])
