"""Analytic problems: body forces against a finite-difference evaluation of rho0 x_tt - Div P, the exact
solutions' own consistency, and short runs of each problem through run_problem."""
import math

import numpy as np
import pytest

from taichi_mpm import analytic as an


def residual_body_force(displacement, X, t, mu, lam, rho, h=1e-5, ht=1e-6):
    """b = x_tt - Div P / rho0 by central differences of the motion u(X, t) = x - X only: F from u,
    P from the solver's neo-Hookean model, Div P from P."""
    d = X.shape[1]
    x_tt = (displacement(X, t + ht) - 2 * displacement(X, t) + displacement(X, t - ht)) / ht**2
    position = lambda Y, s: Y + displacement(Y, s)

    def deformation_gradient(Y):
        F = np.zeros((len(Y), d, d))
        for b in range(d):
            e = np.zeros(d)
            e[b] = h
            F[:, :, b] = (position(Y + e, t) - position(Y - e, t)) / (2 * h)
        return F

    div = np.zeros((len(X), d))
    H = 10 * h  # outer difference step
    for b in range(d):
        e = np.zeros(d)
        e[b] = H
        Pp = an.neo_hookean_pk1(deformation_gradient(X + e), mu, lam)
        Pm = an.neo_hookean_pk1(deformation_gradient(X - e), mu, lam)
        div += (Pp[:, :, b] - Pm[:, :, b]) / (2 * H)
    return x_tt - div / rho


def test_vortex_body_force_matches_finite_differences():
    pr = an.GeneralizedVortex(amplitude=1.0, period=1.0, E=1e3, nu=0.3, density=100.0)
    rng = np.random.default_rng(1)
    R = rng.uniform(0.78, 1.22, 200)
    th = rng.uniform(0, 2 * np.pi, 200)
    X = np.stack([R * np.cos(th), R * np.sin(th)], axis=1)
    for t in (0.13, 0.41, 0.77):
        b = pr.body_force(X, t)
        ref = residual_body_force(lambda Y, s: pr.exact_position(Y, s) - Y, X, t, pr.mu, pr.lam, pr.rho)
        scale = np.abs(ref).max()
        assert scale > 10.0   # the check is not vacuous
        assert np.abs(b - ref).max() < 5e-5 * scale


def test_vortex_circulated_sign_error_is_detected():
    """The circulated closed form (in the reference polar basis) has +R (h dg/dt)^2 sin(alpha) in the
    tangential component; the finite-difference residual tells it apart from the right sign."""
    pr = an.GeneralizedVortex(amplitude=1.0, period=1.0, E=1e3, nu=0.3, density=100.0)
    X = np.array([[0.9, 0.3], [-0.2, 1.1], [0.6, -0.7]])
    t = 0.3
    R = np.linalg.norm(X, axis=1)
    g, dg, d2g = pr.g(t)
    h, dh, d2h = pr.h(R)
    a = g * h
    k = pr.mu / pr.rho
    ref = residual_body_force(lambda Y, s: pr.exact_position(Y, s) - Y, X, t, pr.mu, pr.lam, pr.rho)
    ER = X / R[:, None]
    ET = np.stack([-ER[:, 1], ER[:, 0]], axis=1)
    ref_T = np.sum(ref * ET, axis=1)   # tangential component in the reference basis
    b_r = -R * (h * dg) ** 2 + k * R * g**2 * dh**2
    b_t = R * h * d2g - k * g * (3 * dh + R * d2h)
    right = b_r * np.sin(a) + b_t * np.cos(a)
    wrong = right + 2 * R * (h * dg) ** 2 * np.sin(a)
    assert np.allclose(right, ref_T, rtol=1e-4, atol=1e-4 * np.abs(ref).max())
    assert np.abs(wrong - ref_T).max() > 1e-2 * np.abs(ref_T).max()


@pytest.mark.parametrize("dim,nu", [(1, 0.0), (2, 0.3), (3, 0.25)])
def test_mms_body_force_matches_finite_differences(dim, nu):
    """The multi-D body force has ln J where the 1D form has ln F; for nu != 0 the 1D form is wrong."""
    pr = an.AxisAlignedMMS(dim=dim, amplitude=0.05, E=1e7, nu=nu, density=1000.0)
    rng = np.random.default_rng(2)
    X = rng.uniform(0.05, 0.95, (100, dim))
    for t in (0.0031, 0.0117):
        b = pr.body_force(X, t)
        ref = residual_body_force(pr.exact_displacement, X, t, pr.mu, pr.lam, pr.rho)
        scale = np.abs(ref).max()
        assert scale > 100.0
        assert np.abs(b - ref).max() < 5e-5 * scale
        if nu > 0:
            Fi = 1 + math.pi * pr.G * np.cos(math.pi * X) * math.sin(pr.c * math.pi * t)
            u = pr.exact_displacement(X, t)
            b_1d_form = (math.pi**2 * u / pr.rho) * (pr.lam * (1 - np.log(Fi)) / Fi**2 + pr.mu * (1 + 1 / Fi**2) - pr.E)
            assert np.abs(b_1d_form - ref).max() > 0.05 * scale


def test_mms_multi_d_layouts():
    with pytest.raises(ValueError, match="traction free only for nu = 0"):
        an.AxisAlignedMMS(dim=2, nu=0.3).config()
    cfg = an.AxisAlignedMMS(dim=2).config()
    assert cfg["bodies"][0]["shape"]["lower"] == [0.5, 0.5] and cfg["domain"]["boundaries"]["default"] == "free"
    assert an.AxisAlignedMMS(dim=1).config()["domain"]["boundaries"]["default"] == "sticky"


def test_problem_registry_and_config_overrides():
    assert set(an.PROBLEMS) == {"vibrating_bar", "mms_axis_aligned", "generalized_vortex", "colliding_disks", "hertz"}
    with pytest.raises(ValueError, match="unknown analytic problem"):
        an.make_problem({"type": "nope"})
    import taichi_mpm as tm
    for spec in ({"type": "vibrating_bar", "ends": "fixed-free"}, {"type": "mms_axis_aligned", "dim": 3},
                 {"type": "generalized_vortex"}, {"type": "colliding_disks"}, {"type": "hertz"}):
        cfg = tm.load_config(an.make_problem(spec).config(), {"domain.dx": None} if False else {"solver.basis": "cubic"})
        assert cfg.solver.basis == "cubic" and cfg.precision == "f64"


@pytest.mark.slow
def test_vortex_converges():
    """G = 0.05 vortex, quadratic FLIP, 2 particles per cell: error at 48 cells (dx = 1/16) measured 2.5e-3,
    at 24 cells 1.9e-2."""
    errs = [an.run_problem(an.make_problem({"type": "generalized_vortex", "cells": n}))[1]["error_rms"] for n in (24, 48)]
    assert errs[1] < 4e-3
    assert errs[0] / errs[1] > 4.0


@pytest.mark.slow
def test_vibrating_bar_fixed_free_centre_of_mass():
    """Fixed-free bar over one period (t = 10): displacement and centre-of-mass velocity follow the exact
    solution (measured at 16 cells, quadratic: rms 8.6e-4 at t = 5 against an amplitude of 0.16)."""
    pr = an.make_problem({"type": "vibrating_bar", "ends": "fixed-free", "end_time": 10.0})
    sim, err = an.run_problem(pr)
    amplitude = pr.v0 / pr.omega
    assert err["error_rms"] < 0.02 * amplitude
    assert err["error_com_velocity"] < 0.02 * pr.v0


@pytest.mark.slow
def test_colliding_disks_energy_measures():
    """No exact solution: the disks bounce apart, total energy never grows, APIC keeps most of it."""
    pr = an.make_problem({"type": "colliding_disks"})
    sim, err = an.run_problem(pr)
    assert 0.6 < err["energy_ratio_end"] <= 1.0 + 1e-9
    assert err["energy_ratio_min"] <= err["energy_ratio_end"]
    x = sim.particles()["x"]
    body = sim.scene.body
    # after the collision the disks move apart again: disk 0 back towards the lower-left corner
    assert np.mean(x[body == 0], axis=0).sum() < np.mean(sim.scene.x[body == 0], axis=0).sum() + 0.3


@pytest.mark.slow
def test_hertz_contact_duration():
    """3D sphere (R = 0.1, E = 1e6, nu = 0.3, v = 1) on the rigid slip wall, 20 cells across 4R:
    Hertz t_c = 0.0309 s; measured 0.0338 s (9 % long; 0.0351 s, 13 % long, at 32 cells)."""
    pr = an.make_problem({"type": "hertz"})
    sim, err = an.run_problem(pr)
    assert err["contact_time_hertz"] == pytest.approx(0.0309, rel=0.01)
    assert err["error_contact_time"] < 0.15
    # it bounced: the sphere moves up again at the end
    assert sim.momentum()["linear"][1] > 0
