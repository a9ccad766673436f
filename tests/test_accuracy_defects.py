"""Accuracy defects of issue 9, each pinned by a measurement (docs/accuracy.md has the tables).

Cubic B-splines on the fixed-free vibrating bar converge at first order with 2 particles per cell. The error is
not at the free surface: split by where the particles are, the free end converges at second order and the first
cells at the sticky wall at first order (docs/accuracy.md, "Cubic B-splines at free surfaces")."""
import math

import numpy as np
import pytest

from taichi_mpm import analytic as an


def bar_errors(cells, ppc, basis="cubic"):
    """rms displacement error of the particles in the first two cells (sticky end) and the last two (free end)."""
    pr = an.VibratingBar(ends="fixed-free", cells=cells, particles_per_cell=ppc, basis=basis, precision="f64")
    sim, _ = an.run_problem(pr)
    X = sim.scene.x[:, 0]
    err = sim.particles()["x"][:, 0] - X - pr.exact_displacement(X, sim.time)
    dx = pr.L / cells
    rms = lambda m: math.sqrt(np.mean(err[m] ** 2))
    return rms(X < 2 * dx), rms(X > pr.L - 2 * dx)


@pytest.mark.slow
def test_cubic_fixed_free_first_order_error_sits_at_the_sticky_wall():
    """Measured (f64): sticky end 5.03e-4 -> 2.65e-4 (rate 0.92), free end 3.97e-5 -> 9.43e-6 (2.07) from 16 to
    32 cells; 4 particles per cell at 32 cells: sticky end 3.94e-5 (6.7x smaller). About 2 minutes (three runs). The bounds leave room for platform
    rounding but fail if the free end were first order (rate < 1.7) or the wall layer second order (> 1.4)."""
    (w16, f16), (w32, f32) = bar_errors(16, 2), bar_errors(32, 2)
    wall_rate, free_rate = math.log2(w16 / w32), math.log2(f16 / f32)
    assert free_rate > 1.7, (f16, f32)
    assert wall_rate < 1.4, (w16, w32)
    assert w32 > 5 * f32                       # the wall cells hold the largest error
    w32_4, _ = bar_errors(32, 4)
    assert w32_4 < 0.5 * w32                   # the advice in docs/accuracy.md: 4 particles per cell at the wall


@pytest.mark.slow
def test_hertz_contact_is_long_on_a_coarse_grid_because_the_wall_acts_a_cell_early():
    """analytic.HertzSphere (R = 0.1 m, E = 1e6 Pa, v = 1 m/s; Hertz: t_c = 30.9 ms, peak force 499 N, largest
    penetration delta = 10.5 mm) at 20 cells (dx = 20 mm = 1.9 delta). Measured: contact 33.8 ms (+9.3 %), force
    above 1 % of its peak from t = 27.2 ms although the surface reaches the wall at 40 ms (0.64 dx early: the wall's
    control points act on every particle within a cell of it), peak force 458 N (softer than Hertz). At 30 cells
    (dx = 1.3 delta) the error was +1.4 % and the peak force 501 N (docs/accuracy.md, "Hertz contact")."""
    pr = an.HertzSphere(cells=20)
    sim, err = an.run_problem(pr)
    h = np.asarray(pr.history)
    force = np.diff(h[:, 1]) / np.diff(h[:, 0])
    peak = int(np.argmax(force))
    on = h[np.nonzero(force > 0.01 * force[peak])[0][0], 0]
    dx = 4 * pr.R / 20
    assert 0.05 < err["error_contact_time"] < 0.15, err
    assert on < pr.gap / pr.speed - 0.4 * dx / pr.speed, on        # the contact starts a fraction of a cell early
    assert force[peak] < 0.97 * 4 / 3 * pr.E / (1 - pr.nu**2) * math.sqrt(pr.R) * (
        15 * pr.mass * pr.speed**2 / (16 * pr.E / (1 - pr.nu**2) * math.sqrt(pr.R))) ** 0.6
