"""A step extension registered from the test folder (tests/plugins/uniform_push.py) takes part in every moment of
the step and in the one grid-solve chain: its uniform body acceleration moves a free body by exactly a t^2 / 2."""
import numpy as np
import pytest
import taichi as ti

import taichi_mpm as tm
from taichi_mpm.step import extensions
from taichi_mpm.step.extensions import Extension, GridSolve, ParticleTransfer
from conftest import make_cfg
from plugins.uniform_push import UniformPush

A = (1.5, -2.0)


@pytest.fixture
def push():
    UniformPush.acceleration = A
    extensions.register(UniformPush)
    yield UniformPush
    extensions.unregister(UniformPush)
    UniformPush.acceleration = None


def test_registered_extension_moves_a_free_body_by_half_a_t_squared(push):
    """A block at rest, no gravity, free walls far away: after 10 steps of a fixed dt (the first a half kick, as
    leapfrog starts) every particle has moved by a t^2 / 2 to round-off, its velocity is a (t - dt/2), the energy
    balance holds with the extension's work, and every moment was called as often as the solver says."""
    cfg = make_cfg(2, transfer="apic", boundaries="free", dt=1e-3, gravity=[0.0, 0.0])
    sim = tm.Simulation(cfg)
    ext = sim.extension("uniform_push")
    assert isinstance(ext, UniformPush) and sim.extensions[-1] is ext
    x0 = sim.particles()["x"]
    steps, dt = 10, 1e-3
    for _ in range(steps):
        sim.step()
    t = steps * dt
    p = sim.particles()
    a = np.array(A)
    np.testing.assert_allclose(p["x"] - x0, np.broadcast_to(0.5 * a * t * t, x0.shape), rtol=0, atol=1e-13)
    np.testing.assert_allclose(p["v"], np.broadcast_to(a * (t - 0.5 * dt), x0.shape), rtol=0, atol=1e-12)
    np.testing.assert_allclose(p["push"], np.hypot(*A))   # its output joins particles()
    bal = sim.energy_balance()
    assert abs(bal["ratio"]) < 1e-9 and bal["work"] > 0
    c = ext.calls
    assert (c["create"], c["grid_fields"], c["allocate"], c["prepare"], c["build"], c["upload"]) == (1,) * 6
    assert ext.wall_before_stencil   # prepare: the walls' condition exists, the stencil not yet
    assert c["before_step"] == c["before_p2g"] == c["after_p2g"] == c["node_solve_active"] == c["after_g2p"] == steps
    # before_step sees the step's start, its dt and the leapfrog lag (0 on the first step, then dt/2)
    np.testing.assert_allclose(ext.clock, [(k * dt, dt, 0.0 if k == 0 else 0.5 * dt) for k in range(steps)],
                               rtol=0, atol=1e-15)
    assert c["outputs"] == 2 and c["particles_set"] == 1   # particles() twice; the upload's particles set


def test_registered_extension_state_travels_with_a_checkpoint(push):
    sim = tm.Simulation(make_cfg(2, boundaries="free", dt=1e-3, gravity=[0.0, 0.0]))
    for _ in range(3):
        sim.step()
    state = sim.get_state()
    assert state["pushes"] == 3
    with pytest.raises(ValueError, match="pushes"):
        sim.set_state({**state, "pushes": -1})   # refused before anything changes
    sim.step()
    sim.set_state(state)
    assert sim.extension("uniform_push").pushes[None] == 3 and sim.n_steps == 3


def test_unregistered_extension_is_gone():
    sim = tm.Simulation(make_cfg(2, dt=1e-3))
    assert sim.extension("uniform_push") is None
    with pytest.raises(ValueError):
        extensions.unregister(UniformPush)


class _Claims(Extension):
    """Claims what only one extension may have: the particle transfer and the node solve (twice each)."""
    name = "claims"

    @classmethod
    def create(cls, setup):
        return cls()

    def build(self, ctx):
        claim = ParticleTransfer(takes=None, p2g=None, p2g_momentum=None, g2p=None)
        ctx.contribute("particle_transfer", claim)
        ctx.contribute("particle_transfer", claim)


def test_two_claims_on_a_single_contribution_are_refused():
    extensions.register(_Claims)
    try:
        with pytest.raises(ValueError, match="two extensions contribute particle_transfer"):
            tm.Simulation(make_cfg(2, dt=1e-3))
    finally:
        extensions.unregister(_Claims)
    assert _Claims not in extensions.ORDER


class _Rail(Extension):
    """A boundary condition from outside the package: every node's x velocity is zero (a frictionless rail along
    y), joined to the grid solve's chain after the walls and grips (GridSolve.condition)."""
    name = "rail"

    @classmethod
    def create(cls, setup):
        return cls()

    def build(self, ctx):
        @ti.func
        def condition(I, vel, m, measure: ti.template()):
            vel[0] = 0.0
            return vel
        ctx.grid_solve.append(GridSolve(condition=condition))


def test_a_registered_condition_holds_every_node_of_the_chain():
    """Gravity (3, -9.81) on a free block: on the rail the particles never move in x (x_p moves by dt sum w v_i,
    every v_i,x = 0: exactly), and fall freely in y (leapfrog is exact for a uniform acceleration: round-off)."""
    extensions.register(_Rail)
    try:
        sim = tm.Simulation(make_cfg(2, transfer="apic", boundaries="free", dt=1e-3, gravity=[3.0, -9.81]))
        x0 = sim.particles()["x"]
        for _ in range(10):
            sim.step()
        dx = sim.particles()["x"] - x0
    finally:
        extensions.unregister(_Rail)
    assert np.all(dx[:, 0] == 0.0)
    np.testing.assert_allclose(dx[:, 1], -0.5 * 9.81 * 0.01 ** 2, rtol=0, atol=1e-13)
