"""States the Simulation API refuses (states.py, docs/contract.md "API states"): particles set outside the domain or
with J <= 0, stepping a simulation that failed, and time steps the kernels or the clock cannot represent."""
import math

import numpy as np
import pytest

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm.solver import FAIL_CAUSES


def leaving_block():
    """A block flying out through a free wall: the step after it crosses fails (particle left the domain)."""
    return tm.Simulation(make_cfg(2, basis="linear", transfer="pic", dx=0.1, E=1e4, velocity=[20.0, 0.0],
                                  boundaries="free", end_time=1.0))


# ---------------------------------------------------------------- set_particles
def test_set_particles_refuses_positions_outside_the_domain_and_inverted_particles():
    sim = tm.Simulation(make_cfg(2))
    p0 = sim.particles()
    x = p0["x"].copy()
    x[7] = [1.2, 0.5]
    with pytest.raises(ValueError, match=r"^x: particle 7 lies outside the domain \(x = \[1.2, 0.5\]"):
        sim.set_particles(x=x)
    x[7] = [0.5, -1e-3]
    x[9] = [-0.5, 0.5]
    with pytest.raises(ValueError, match=r"x: particle 7 lies outside the domain.*2 particles outside"):
        sim.set_particles(x=x)
    F = p0["F"].copy()
    F[3] = [[-1.0, 0.0], [0.0, 1.0]]
    with pytest.raises(ValueError, match=r"^F: particle 3 has J = det F = -1 <= 0"):
        sim.set_particles(F=F)
    F[3] = 0.0
    with pytest.raises(ValueError, match=r"^F: particle 3 has J = det F = 0 <= 0"):
        sim.set_particles(F=F, v=np.ones_like(p0["v"]))
    after = sim.particles()   # nothing half-applied
    for k in ("x", "v", "F"):
        np.testing.assert_array_equal(after[k], p0[k])
    # on the walls (and round-off beyond them, as a step may leave a particle) is inside
    x = p0["x"].copy()
    x[0], x[1] = [0.0, 1.0], [1.0 + 1e-9, 0.0]
    sim.set_particles(x=x, F=p0["F"] * 1.1)
    state = sim.get_state()
    state["x"][2] = [2.0, 0.5]
    with pytest.raises(ValueError, match="x: particle 2 lies outside the domain"):
        sim.set_state(state)   # set_state checks the same


def test_set_particles_refuses_j_le_0_in_1d_and_3d():
    for dim in (1, 3):
        sim = tm.Simulation(make_cfg(dim, dx=0.1 if dim == 1 else 0.2))
        F = sim.particles()["F"].copy()
        F[-1] *= -1.0
        with pytest.raises(ValueError, match=f"F: particle {sim.n - 1} has J = det F = -1 <= 0"):
            sim.set_particles(F=F)


# ---------------------------------------------------------------- a failed simulation
def test_step_after_an_instability_is_refused_until_a_good_state_is_restored():
    sim = leaving_block()
    good = sim.get_state()
    with pytest.raises(tm.InstabilityError) as info:
        sim.advance(1.0)
    first = info.value
    assert first.cause == FAIL_CAUSES[3]
    t, n, x = sim.time, sim.n_steps, sim.particles()["x"]
    for call in (lambda: sim.step(), lambda: sim.step(1e-4), lambda: sim.advance(0.01), lambda: sim.advance_to(1.0)):
        with pytest.raises(tm.InstabilityError) as again:
            call()
        e = again.value
        assert (e.cause, e.step, e.time, e.particle) == (first.cause, first.step, first.time, first.particle)
        assert "does not step it again: restore a good state first" in str(e)
        assert (sim.time, sim.n_steps) == (t, n)                      # nothing stepped
        np.testing.assert_array_equal(sim.particles()["x"], x)
    # a set_particles that leaves the bad positions in place keeps it failed; one that fixes them, or set_state
    # with a good state (a checkpoint), makes it steppable again
    sim.set_particles(v=np.zeros_like(x))
    with pytest.raises(ValueError, match="outside the domain"):
        sim.set_particles(x=x)   # the failed positions themselves are refused
    with pytest.raises(tm.InstabilityError, match="restore a good state first"):
        sim.step(1e-4)
    sim.set_state(good)
    sim.step(1e-4)
    assert sim.n_steps == good["n_steps"] + 1


def test_a_state_made_good_by_set_particles_steps_again():
    sim = leaving_block()
    start = sim.particles()
    with pytest.raises(tm.InstabilityError):
        sim.advance(1.0)
    sim.set_particles(x=start["x"], v=start["v"], F=start["F"])
    sim.step(1e-4)


# ---------------------------------------------------------------- dt
@pytest.mark.parametrize("precision, dt, says", [
    ("f32", 1e-300, "below the smallest normal f32 number"),
    ("f32", 1e-39, "below the smallest normal f32 number"),
    ("f64", 1e-310, "below the smallest normal f64 number"),
    ("f64", math.inf, "finite number > 0"),
    ("f32", -0.0, "finite number > 0"),
    ("f32", True, "finite number > 0"),
])
def test_step_refuses_a_dt_the_kernels_cannot_represent(precision, dt, says):
    sim = tm.Simulation(make_cfg(2, precision=precision, velocity=[0.3, 0.1]))
    with pytest.raises(ValueError, match=says):
        sim.step(dt)
    assert (sim.time, sim.n_steps) == (0.0, 0)


def test_step_refuses_a_dt_below_the_clocks_resolution():
    sim = tm.Simulation(make_cfg(2, precision="f64", velocity=[0.3, 0.1]))
    sim.step(1e-300)            # at t = 0 the clock can move by it, and f64 holds it
    assert sim.time == 1e-300
    sim.advance(0.002)
    t, n = sim.time, sim.n_steps
    with pytest.raises(ValueError, match=r"below the clock's resolution at t = .* the clock cannot advance by it"):
        sim.step(1e-300)
    with pytest.raises(ValueError, match="clock's resolution"):
        sim.step(0.5 * np.spacing(t))
    assert (sim.time, sim.n_steps) == (t, n)
    sim.step(np.spacing(t))     # one unit of the clock's last place: it moves
    assert sim.time > t
