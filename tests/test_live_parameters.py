"""Runtime parameters (Simulation.set_gravity, set_stiffness_scale, set_flip_blend): changed between steps without a
recompile, each checked against physics that does not depend on the solver: the piecewise free fall, the vibrating
bar's period, PIC and FLIP runs."""
import math

import numpy as np
import pytest

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm import analytic as an

G = 9.81


def _centre(sim):
    p = sim.particles()
    return p["mass"] @ p["x"] / p["mass"].sum(), p["mass"] @ p["v"] / p["mass"].sum()


def test_gravity_changed_mid_run_follows_the_piecewise_free_fall():
    """A free soft block (no wall reached): g1 until t1, then g2, then 0. Leapfrog is exact for a uniform
    acceleration, advance_to lands on t1 exactly, and the kick after a change takes the old g over its first half
    and the new one over its second, so the centre follows the piecewise parabola to round-off (velocities at
    sim.velocity_time, half a step behind): 1e-9 (relative to the fall) leaves room for round-off only; a change
    that took effect over the whole kick would be off by |g2 - g1| dt/2 in velocity (~0.1 m/s here), one step late
    by g dt t ~ 1e-2 in position. The energy balance's growth is the same just before and after each change (the
    potential jumps, the reference moves with it) and is leapfrog's -M |g|^2 dt^2 / 8 in free fall; the gravity
    term of the time step uses the new |g|."""
    cfg = make_cfg(2, dx=0.1, E=1.0, extent=4.0, lower=[1.8, 3.0], upper=[2.2, 3.4], end_time=1.0,
                   gravity=[0.0, -G])
    sim = tm.Simulation(cfg)
    x0, v0 = _centre(sim)
    g1, g2, t1, t2 = np.array([0.0, -G]), np.array([1.0, -2.0]), 0.2, 0.5
    sim.advance_to(t1)
    x1, v1 = x0 + 0.5 * g1 * t1**2, g1 * t1
    x, v = _centre(sim)
    np.testing.assert_allclose(x, x1, atol=1e-9)
    np.testing.assert_allclose(v, g1 * sim.velocity_time, atol=1e-9)
    growth = sim.energy_balance()["growth"]
    sim.set_gravity(g2)
    np.testing.assert_array_equal(sim.gravity, g2)
    assert sim.energy_balance()["growth"] == pytest.approx(growth, abs=1e-9)
    assert sim.dt_limits()["gravity"] == pytest.approx(0.4 * math.sqrt(0.1 / np.linalg.norm(g2)), rel=1e-12)
    sim.advance_to(t2)
    s = t2 - t1
    x2, v2 = x1 + v1 * s + 0.5 * g2 * s**2, v1 + g2 * s
    x, v = _centre(sim)
    np.testing.assert_allclose(x, x2, atol=1e-9)
    np.testing.assert_allclose(v, v1 + g2 * (sim.velocity_time - t1), atol=1e-9)
    # leapfrog's energy in free fall: -M |g|^2 dt^2 / 8 for the last dt (tests/test_extremes.py)
    M = sim.scene.mass.sum()
    assert sim.energy_balance()["growth"] == pytest.approx(-M * (g2 @ g2) * sim.dt**2 / 8, rel=1e-6)
    # gravity 0: the body stops accelerating (uniform motion) and the time step has no gravity term
    sim.set_gravity([0.0, 0.0])
    assert "gravity" not in sim.dt_limits()
    sim.advance(0.1)
    x, v = _centre(sim)
    np.testing.assert_allclose(v, v2, atol=1e-9)
    np.testing.assert_allclose(x, x2 + 0.1 * v2, atol=1e-9)
    assert abs(sim.energy_balance()["growth"]) < 1e-9 * sim.energy_balance()["scale"]


@pytest.mark.slow
def test_gravity_switched_on_in_a_scene_without_it():
    """The gravity term is compiled whatever the config says, so a scene without gravity can be given some: the
    velocity is then g (t - t_switch) exactly at sim.velocity_time (each kick adds g over the part of it since the
    switch; 1e-12 is round-off)."""
    sim = tm.Simulation(make_cfg(1, dx=0.1, E=1.0, extent=4.0, lower=[3.0], upper=[3.4], end_time=1.0))
    sim.advance(0.05)
    assert np.all(sim.particles()["v"] == 0.0)
    sim.set_gravity([-G])
    sim.advance(0.1)
    np.testing.assert_allclose(sim.particles()["v"][:, 0], -G * (sim.velocity_time - 0.05), rtol=1e-12)
    with pytest.raises(ValueError, match="1 finite numbers"):
        sim.set_gravity([0.0, -G])
    with pytest.raises(ValueError, match="finite"):
        sim.set_gravity([math.nan])


def _half_period(sim, end):
    """Time between the first two zero crossings of the bar's centre-of-mass velocity, v0 cos(omega t) (1 -
    cos kL) / kL: half a period (crossings interpolated linearly between steps)."""
    samples = [(sim.time, sim.momentum()["linear"][0])]
    sim.advance_to(end, on_step=lambda s: samples.append((s.time, s.momentum()["linear"][0])))
    t, m = np.array(samples).T
    k = np.flatnonzero(np.sign(m[1:]) != np.sign(m[:-1]))
    crossings = t[k] - m[k] * (t[k + 1] - t[k]) / (m[k + 1] - m[k])
    assert len(crossings) >= 2
    return crossings[1] - crossings[0]


@pytest.mark.slow
def test_stiffness_scale_shortens_the_vibrating_bar_period_by_its_square_root():
    """Bardenhagen's fixed-fixed bar (period 2 L / c = 5 s at scale 1). Scale 4 must halve the period: measured
    ratio 0.4999983; 1e-3 allows for the discrete bar's dispersion changing a little with dt / period (the CFL step
    is cfl dx / (c + |v|), not exactly halved); a scale applied to the energy but not the stress, or without the
    square root, gives 1 or 0.25. Each period also matches 2 L / (c sqrt(s)) within 2 % (16 cells: measured 0.98 %
    long at both scales). Same simulation,
    same kernels: reset, rescale, rerun. The CFL step uses the scaled wave speed, and the energy balance does not
    jump when the scale changes mid-vibration (the stored energy does; the reference moves with it)."""
    pr = an.VibratingBar(ends="fixed-fixed", end_time=10.0)
    sim = tm.Simulation(tm.load_config(pr.config()))
    pr.setup(sim)
    start = sim.get_state()
    periods = {}
    for scale in (1.0, 4.0):
        sim.set_state(start)
        sim.set_stiffness_scale(scale)
        assert sim.stiffness_scale() == scale
        T = 2 * pr.L / (pr.c * math.sqrt(scale))
        periods[scale] = 2 * _half_period(sim, 0.8 * T)
        assert periods[scale] == pytest.approx(T, rel=0.02)
        cfl, dx = sim.cfg.solver.cfl, sim.dx
        assert sim.dt_limits()["elastic"] == pytest.approx(cfl * dx / (math.sqrt(scale) * pr.c + sim._vmax),
                                                           rel=1e-12)
    assert periods[4.0] / periods[1.0] == pytest.approx(0.5, rel=1e-3)
    # mid-vibration (strain energy ~ half the total): the balance carries over the jump of the stored energy
    sim.set_state(start)
    sim.set_stiffness_scale(1.0)   # the state holds no parameters: the scale stays what it was set to
    sim.advance(1.0)
    before = sim.energy_balance()
    strain = sim.energy()["strain"]
    sim.set_stiffness_scale(2.0, material="bar")
    assert sim.energy()["strain"] == pytest.approx(2.0 * strain, rel=1e-12)
    assert sim.energy_balance()["growth"] == pytest.approx(before["growth"], abs=1e-12 * before["scale"])
    with pytest.raises(ValueError, match="> 0"):
        sim.set_stiffness_scale(0.0)
    with pytest.raises(ValueError, match="no material"):
        sim.set_stiffness_scale(2.0, material="steel")


def _spinning_block(transfer, **solver):
    """A 2D block spinning rigidly, then hitting nothing: PIC loses its rotation energy, FLIP keeps it."""
    cfg = make_cfg(2, transfer=transfer, dx=0.1, E=1e4, dt=2e-3, end_time=1.0, **solver)
    sim = tm.Simulation(cfg)
    x = sim.scene.x - sim.scene.x.mean(axis=0)
    sim.set_particles(v=np.c_[-x[:, 1], x[:, 0]])
    return sim


def _steps(sim, n=25):
    for _ in range(n):
        sim.step()
    return sim.particles()["v"]


@pytest.mark.slow
def test_flip_blend_zero_and_one_equal_the_pic_and_flip_runs():
    """A pure FLIP run (flip_blend 1) rewound and set to blend 0 gives the PIC run's velocities (v = 0 (v + dv) +
    1 v_grid is PIC's update), and set back to 1 the FLIP run again: equal to round-off (rtol 1e-12 in f64), after 25
    steps in which PIC and pure FLIP drift apart by far more (the check that this could fail: > 1e-3)."""
    pic = _steps(_spinning_block("pic"))
    sim = _spinning_block("flip", flip_blend=1.0)
    start = sim.get_state()
    flip = _steps(sim)
    assert np.abs(flip - pic).max() > 1e-3
    sim.set_state(start)
    sim.set_flip_blend(0.0)
    np.testing.assert_allclose(_steps(sim), pic, rtol=1e-12, atol=1e-14)
    sim.set_state(start)
    sim.set_flip_blend(1.0)
    assert sim.flip_blend == 1.0
    np.testing.assert_allclose(_steps(sim), flip, rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        sim.set_flip_blend(1.5)
