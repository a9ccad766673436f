"""A 1D elastic bar fixed at both ends vibrates in its first mode (Bardenhagen's vibrating bar).

    python demos/vibrating_bar.py [--set KEY=VALUE]... [--out DIR] [--v0 0.1]

The initial velocity v(X, 0) = v0 sin(pi X / L) comes from the config (configs/vibrating_bar.yaml,
bodies[0].velocity, an expression of x); --v0 rewrites its amplitude. The exact solution is
u = v0/omega sin(omega t) sin(pi X / L), omega = pi/L sqrt(E/rho): the script prints the centre-of-mass velocity
against it at the end.
"""
import math
import sys

import numpy as np

import taichi_mpm as tm
from _common import parse, run


def main(argv=None, v0=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--v0" in argv:
        i = argv.index("--v0")
        v0 = float(argv[i + 1])
        del argv[i:i + 2]
    cfg, args = parse("vibrating_bar", argv, __doc__)
    L = cfg.domain.upper[0] - cfg.domain.lower[0]
    if v0 is not None:
        cfg = tm.load_config(cfg, overrides={"bodies.0.velocity": [f"{v0!r} * sin(pi * x / {L!r})"]})
    sim = tm.Simulation(cfg)
    mat = next(iter(cfg.materials.values()))
    k = math.pi / L
    omega = k * math.sqrt(mat.E / mat.density)
    X = sim.scene.x[:, 0] - cfg.domain.lower[0]
    amplitude = float(np.max(np.abs(sim.scene.v[:, 0])) / np.max(np.sin(k * X)))  # v0 as the config gives it
    run(sim, args.out)
    p = sim.particles()
    vcm = float(np.sum(p["mass"] * p["v"][:, 0]) / np.sum(p["mass"]))
    exact = amplitude * math.cos(omega * sim.time) * 2 / math.pi
    print(f"centre-of-mass velocity at t={sim.time:.4g}: {vcm:.6f} (exact {exact:.6f}, period {2 * math.pi / omega:.4g} s)",
          file=sys.stderr)
    return sim


if __name__ == "__main__":
    main()
