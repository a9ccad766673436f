"""Verification against closed-form results (issue 2, items 2-4), f64.

- cell-crossing quadrature: nodal internal force of a uniformly stretched, uniformly stressed 1D body
  translated rigidly across the grid, read back from the solver's P2G;
- Bardenhagen's vibrating bar (fixed-fixed, FLIP, dt = 0.1 dx/c, 2 particles per cell, t = 2.5);
- the 1D axis-aligned manufactured solution (neo-Hookean) at small and large amplitude.
Fast cases use 8/16/32 cells; the full 8..64 sweeps run under `-m slow`.
"""
import math

import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm import analytic as an


def lsq_rate(cells, errors):
    return -np.polyfit(np.log(cells), np.log(errors), 1)[0]


# ---------------------------------------------------------------- 2. cell-crossing quadrature
def crossing_force(basis, *, gimp_domain="uniform", F=1.1, ppc=2, n_particles=24, shifts=41):
    """max over shifts and interior nodes of |f_i| / sigma, with f_i from the solver's P2G:
    particles at rest, one step of tiny dt, f_i = m_i v_i / dt."""
    E, dt, n_cells = 2.0e4, 1.0e-9, 40
    h = 1.0 / ppc
    cfg = dict(name="crossing", dim=1, precision="f64", arch="cpu",
               domain=dict(lower=[0.0], upper=[float(n_cells)], dx=1.0, sparse=False, boundaries=dict(default="free")),
               solver=dict(basis=basis, transfer="pic", end_time=1.0, gimp_domain=gimp_domain),
               materials=dict(m=dict(model="neo_hookean", E=E, nu=0.0, density=1.0)),
               bodies=[dict(shape=dict(type="box", lower=[10.0], upper=[10.0 + n_particles * h]), material="m",
                            particles_per_cell=ppc)])
    sim = tm.Simulation(cfg)
    mu = E / 2
    sigma = mu * (F * F - 1) / F                      # Cauchy stress of the stretched bar (lam = 0)
    b = sim.basis
    xi = np.array([b.coord_py(i, n_cells) for i in range(b.nodes(n_cells))])
    lp = min(0.5 * h * (F if gimp_domain == "deforming" else 1.0), 0.5)
    reach = {"linear": 1.0, "quadratic": 1.5, "cubic": 2.0, "gimp": 1.0 + lp}[basis]
    worst = 0.0
    for s in np.linspace(0.0, 1.0, shifts):
        x = 10.0 + s + F * h * (np.arange(n_particles) + 0.5)
        sim.set_particles(x=x[:, None], v=np.zeros((n_particles, 1)), F=np.full((n_particles, 1, 1), F))
        sim.step(dt)
        m = sim.grid.m.to_numpy()
        v = sim.grid.vec["v"].to_numpy()[:, 0]
        f = np.where(m > 0, m * v / (0.5 * dt), 0.0)  # set_particles gave v: the step kicks over dt/2
        lo, hi = 10.0 + s, 10.0 + s + F * h * n_particles
        interior = (xi - reach >= lo - 1e-9) & (xi + reach <= hi + 1e-9)
        assert interior.sum() >= 8
        worst = max(worst, np.abs(f[interior]).max() / sigma)
    return worst


@pytest.mark.parametrize("basis,gimp_domain,expected", [
    ("linear", "uniform", 1.1 / 2),              # F / ppc
    ("quadratic", "uniform", 0.1 * 1.1 / 2),     # (F - 1) F / ppc
    pytest.param("cubic", "uniform", 0.0036644, marks=pytest.mark.slow),   # measured; an order below quadratic
    pytest.param("gimp", "uniform", 0.1 * 1.1 / 2, marks=pytest.mark.slow),  # fixed domains: gaps/overlaps of (F - 1) h
])
def test_cell_crossing_force(basis, gimp_domain, expected):
    assert crossing_force(basis, gimp_domain=gimp_domain) == pytest.approx(expected, rel=0.1)


def test_cell_crossing_gimp_deforming_domains_is_exact():
    """uGIMP domains that stretch with F tile the body: the interior force vanishes to round-off."""
    assert crossing_force("gimp", gimp_domain="deforming") < 1e-9


# ---------------------------------------------------------------- 3. vibrating bar
def bar_errors(basis, cells):
    errs = []
    for n in cells:
        pr = an.make_problem({"type": "vibrating_bar"})
        dx = pr.L / n
        _, e = an.run_problem(pr, {"domain.dx": dx, "solver.basis": basis, "solver.transfer": "flip",
                                   "solver.flip_blend": 1.0, "solver.dt": 0.1 * dx / pr.c})
        errs.append(e["error_rms"])
    return errs


# measured rms errors at t = 2.5 (8, 16, 32, 64 cells):
#   linear 4.46e-3 1.04e-3 2.53e-4 6.77e-5 (rate 2.02)   gimp  4.63e-3 1.13e-3 2.94e-4 8.21e-5 (1.94)
#   quadratic 6.37e-3 1.72e-3 4.36e-4 1.09e-4 (1.96)     cubic see the report
BAR_RATE = {"linear": 1.7, "gimp": 1.7, "quadratic": 1.7, "cubic": 1.5}


@pytest.mark.slow
@pytest.mark.parametrize("basis", ["linear", "gimp", "quadratic", "cubic"])
def test_vibrating_bar_converges(basis):
    cells = [8, 16, 32]
    errs = bar_errors(basis, cells)
    assert all(e1 > e2 for e1, e2 in zip(errs, errs[1:]))
    assert lsq_rate(cells, errs) >= BAR_RATE[basis]
    assert errs[-1] < 1e-3   # amplitude v0/w = 0.08


@pytest.mark.slow
@pytest.mark.parametrize("basis", ["linear", "gimp", "quadratic", "cubic"])
def test_vibrating_bar_converges_8_to_64(basis):
    cells = [8, 16, 32, 64]
    errs = bar_errors(basis, cells)
    assert all(e1 > e2 for e1, e2 in zip(errs, errs[1:]))
    assert lsq_rate(cells, errs) >= BAR_RATE[basis]


# ---------------------------------------------------------------- 4. 1D manufactured solution
def mms_errors(basis, amplitude, cells, **overrides):
    errs = []
    for n in cells:
        pr = an.make_problem({"type": "mms_axis_aligned", "dim": 1, "amplitude": amplitude})
        _, e = an.run_problem(pr, {"domain.dx": 1.0 / n, "solver.basis": basis, **overrides})
        errs.append(e["error_rms"])
    return errs


# G = 1e-4, 2 particles per cell, FLIP, cfl 0.2; rms error at 8/16/32/64 cells (measured):
#   linear 1.08e-5 2.56e-6 6.09e-7 1.48e-7 (2.06)    gimp 1.08e-5 2.57e-6 6.13e-7 1.50e-7 (2.06)
#   quadratic 1.56e-5 4.29e-6 1.09e-6 2.75e-7 (1.95) cubic 1.69e-5 5.47e-6 1.75e-6 5.32e-7 (1.66)
# cubic with 2 particles per cell is quadrature-limited (the error is spread over the interior, not at
# the walls); with 4 per cell it converges at 1.93 (16..128 cells).
MMS_RATE = {"linear": 1.8, "gimp": 1.8, "quadratic": 1.8, "cubic": 1.55}


@pytest.mark.parametrize("basis", [pytest.param("linear", marks=pytest.mark.slow), pytest.param("gimp", marks=pytest.mark.slow), "quadratic",
                                   pytest.param("cubic", marks=pytest.mark.slow)])
@pytest.mark.slow
def test_mms_small_amplitude_converges(basis):
    cells = [8, 16, 32]
    errs = mms_errors(basis, 1e-4, cells)
    assert lsq_rate(cells, errs) >= MMS_RATE[basis]
    assert errs[-1] < 2.5e-6


@pytest.mark.slow
def test_time_integration_is_second_order_between_periods():
    """The one-period instant (exact displacement zero) hides a first-order time integration; at 3/4 period
    (displacement at its extreme) it shows. cpdi at G = 0.05 (small spatial error), 16 and 32 cells, CFL 0.2:
    leapfrog measured 1.236e-4, 2.928e-5 (rate 2.08). The schemes it replaced fail both bounds: the trapezoidal
    positions 9.51e-4, 4.22e-4 (rate 1.17), symplectic Euler's full first kick 1.98e-4, 6.16e-5 (1.68)."""
    cells = [16, 32]
    errs = mms_errors("cpdi", 0.05, cells, **{"solver.end_time": 0.015})
    assert lsq_rate(cells, errs) >= 1.9
    assert errs[-1] < 4e-5


@pytest.mark.slow
@pytest.mark.parametrize("basis,ppc,rate", [("linear", 2, 1.8), ("gimp", 2, 1.8), ("quadratic", 2, 1.8),
                                            ("cubic", 2, 1.55), ("cubic", 4, 1.8)])
def test_mms_small_amplitude_converges_8_to_64(basis, ppc, rate):
    cells = [8, 16, 32, 64]
    errs = mms_errors(basis, 1e-4, cells, **{"bodies.0.particles_per_cell": ppc})
    assert lsq_rate(cells, errs) >= rate


@pytest.mark.slow
def test_mms_large_amplitude_cell_crossing():
    """G = 0.05: linear MPM's error grows under refinement (cell-crossing noise; measured 2.3e-3 at 16
    cells, 6.7e-3 at 64) while quadratic and cubic stay below 1e-3 at 64 cells (1.7e-4, 3.4e-4)."""
    lin = mms_errors("linear", 0.05, [16, 64])
    assert lin[1] > 2.0 * lin[0]
    for basis in ("quadratic", "cubic"):
        assert mms_errors(basis, 0.05, [64])[0] < 1e-3


# ---------------------------------------------------------------- multi-D manufactured solution
# Free-surface layout (body [0.5, 1.5]^d, nu = 0: traction free). G = 1e-4, rms error (measured):
#   2D 8/16/32 cells per unit: linear 1.26e-5 3.22e-6 8.09e-7 (1.98)  gimp 1.45e-5 3.55e-6 8.58e-7 (2.04)
#                              quadratic 2.41e-5 6.25e-6 1.57e-6 (1.97)  cubic 3.02e-5 7.95e-6 2.00e-6 (1.96)
#   3D 4/8/16: linear 5.40e-5 1.54e-5 3.95e-6 (1.89)  gimp 6.15e-5 1.78e-5 4.35e-6 (1.91)
#              quadratic 8.73e-5 2.95e-5 7.66e-6 (1.76)
def mms_md_errors(dim, basis, cells):
    errs = []
    for n in cells:
        pr = an.make_problem({"type": "mms_axis_aligned", "dim": dim, "amplitude": 1e-4})
        _, e = an.run_problem(pr, {"domain.dx": 1.0 / n, "solver.basis": basis})
        errs.append(e["error_rms"])
    return errs


@pytest.mark.slow
def test_mms_2d_quadratic_converges():
    cells = [8, 16]
    errs = mms_md_errors(2, "quadratic", cells)
    assert lsq_rate(cells, errs) >= 1.8
    assert errs[-1] < 8e-6


@pytest.mark.slow
@pytest.mark.parametrize("dim,basis,cells,rate", [
    (2, "linear", [8, 16, 32], 1.8), (2, "gimp", [8, 16, 32], 1.8), (2, "quadratic", [8, 16, 32], 1.8),
    (2, "cubic", [8, 16, 32], 1.8),
    (3, "linear", [4, 8, 16], 1.7), (3, "quadratic", [4, 8, 16], 1.6)])
def test_mms_multi_d_converges(dim, basis, cells, rate):
    assert lsq_rate(cells, mms_md_errors(dim, basis, cells)) >= rate
