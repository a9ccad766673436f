"""Water dropped into a round-bottomed tank whose grid is the tank itself (2D, domain.map type nurbs).

    python demos/round_tank.py [--set KEY=VALUE]... [--out DIR]

Loads configs/round_tank.yaml (a generic NURBS patch: the bottom an exact circle of radius 1 m, vertical side
walls, a flat lid) and writes the outputs of its output section: the drop lands on the slope, runs along the
curved wall and sloshes. Theory check, printed at the end: every particle is still inside the tank (r <= 1 from
the circle's centre, |x| <= 0.94 between the side walls, y <= 0.5 under the lid: slip walls let nothing
through), and the energy balance (kinetic + pressure + gravity, plus viscous dissipation) has not grown: walls
and transfers only remove energy.
"""
import sys

import numpy as np

import taichi_mpm as tm
from _common import parse, run

RADIUS, SIDE, LID = 1.0, 0.9396926207859084, 0.5    # the bottom's circle, the side walls (cos 200 deg), the lid


def main(argv=None):
    cfg, args = parse("round_tank", argv, __doc__)
    sim = tm.Simulation(cfg)
    run(sim, args.out)
    x = sim.particles()["x"]
    outside = float(max(np.linalg.norm(x, axis=1).max() - RADIUS, np.abs(x[:, 0]).max() - SIDE, x[:, 1].max() - LID))
    balance = sim.energy_balance()
    print(f"theory check at t={sim.time:.3g} s: furthest particle {outside:+.2e} m beyond the tank's walls "
          f"(<= 0: inside), lowest at y = {x[:, 1].min():.3f} m (bottom -1), energy growth "
          f"{balance['ratio']:+.2e} of the largest kinetic + strain energy (<= 0: nothing created)", file=sys.stderr)
    sim.theory_check = dict(outside=outside, growth=balance["ratio"], lowest=float(x[:, 1].min()))
    return sim


if __name__ == "__main__":
    main(sys.argv[1:])
