"""A metal bar (von_mises with linear hardening, 2D plane strain) pulled apart by grips at both ends: it yields
uniformly, the load peaks, and the deformation localises into a neck at the middle (2D).

    python demos/necking.py [--set KEY=VALUE]... [--out DIR]

Loads configs/necking.yaml and writes the outputs of its output section (frames coloured by the plastic strain,
the right grip's force in probes/load_cell.csv). It prints the peak load against Considere's criterion: with
sigma_y + H alpha in plane strain (sigma_xx = 2 / sqrt(3) sigma_eq, alpha = 2 / sqrt(3) eps_xx) the axial true
stress rises at 4 H / 3 in the plastic range, so the load sigma_xx w0 exp(-eps) peaks where sigma_xx = 4 H / 3,
and F_max = 4 H / 3 w0 exp(-eps*) per metre of depth (eps*: the axial Hencky strain there, elastic part included).
"""
import math
import sys
from pathlib import Path

import numpy as np

import taichi_mpm as tm
from taichi_mpm.io.probes import read_probe
from _common import default_out, parse, run


RAMP = 0.005          # the grips' speed-up time in configs/necking.yaml; the load is read after 2 RAMP (inertia)


def considere(metal, width):
    """Plane-strain Considere peak: (eps*, F_max per metre of depth) for yield_stress sigma_y, hardening H > 0."""
    sy, H, E, nu = metal.yield_stress, metal.hardening, metal.E, metal.nu
    s_peak = 4 * H / 3                                          # sigma_xx where d sigma_xx / d eps = sigma_xx
    alpha = s_peak * math.sqrt(3) / 2 / H - sy / H              # sigma_eq = sigma_y + H alpha = sqrt(3)/2 sigma_xx
    eps = alpha * math.sqrt(3) / 2 + s_peak * (1 - nu**2) / E  # plastic + plane-strain elastic axial strain
    return eps, s_peak * width * math.exp(-eps)


def neck(sim):
    """Width of the bar at its thinnest section, its median width and the thinnest section's x (columns dx wide
    between the grips, without the two end columns)."""
    x = sim.particles()["x"]
    dx = sim.cfg.domain.dx
    x0 = sim.scene.x[:, 0]
    free = (x0 > 0.07 + dx) & (x0 < 0.23 - dx)                 # between the grips, a cell off them
    bins = np.floor(x[free, 0] / dx).astype(int)
    cols = np.unique(bins)[1:-1]
    widths = np.array([np.ptp(x[free][bins == b, 1]) for b in cols])
    return float(widths.min()), float(np.median(widths)), float((cols[np.argmin(widths)] + 0.5) * dx)


def main(argv=None):
    cfg, args = parse("necking", argv, __doc__)
    sim = run(tm.Simulation(cfg), args.out)
    out = Path(args.out) if args.out is not None else default_out(cfg)
    loads = read_probe(out / "probes" / "load_cell.csv")
    w0 = cfg.bodies[0].shape.upper[1] - cfg.bodies[0].shape.lower[1]
    eps_c, f_c = considere(cfg.materials["metal"], w0)
    t, f = loads["time [s]"][1:], loads["fx [N/m]"][1:]       # the t = 0 row has no force
    thinnest, typical, where = neck(sim)
    sim.necking = dict(time=t, force=f, considere_force=f_c, considere_strain=eps_c, thinnest=thinnest,
                       typical=typical, neck_x=where, width=w0)
    late = t > 2 * RAMP
    peak = float(f[late].max()) if late.any() else float("nan")
    sim.necking["peak"] = peak
    print(f"necking: peak load {peak:.4g} N/m after the ramp (Considere: {f_c:.4g} N/m at axial "
          f"strain {eps_c:.3f}); thinnest section {thinnest / w0:.2f} w0 at x = {where:.3f} m, median {typical / w0:.2f} w0", file=sys.stderr)
    return sim


if __name__ == "__main__":
    main(sys.argv[1:])
