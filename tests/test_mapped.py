"""Mapped grids (`domain.map: annulus`, issue 12 step 3) in the solver, f64: a uniform stretch reproduced exactly
on the curved grid (the patch test), slip walls on the circles conserving a spinning fluid ring's angular
momentum to round-off, and config errors."""
import math

import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm.errors import ConfigError


def ring_cfg(angle=360.0, cells=(24, 4), walls="slip", model="fluid", body=(0.55, 0.95), **solver):
    mat = dict(model=model, density=1000.0)
    mat.update(dict(K=1e4) if model == "fluid" else dict(E=1e4, nu=0.3))
    return dict(
        name="ring", dim=2, precision="f64", arch="cpu",
        domain=dict(lower=[-1.1, -1.1], upper=[1.1, 1.1], dx=0.05, boundaries=dict(default=walls),
                    map=dict(type="annulus", inner_radius=0.5, outer_radius=1.0, angle=angle, cells=list(cells))),
        solver=dict(basis="quadratic", transfer="apic", end_time=0.1, **solver),
        materials=dict(m=mat),
        bodies=[dict(name="ring", shape=dict(type="ring", center=[0.0, 0.0], inner_radius=body[0],
                                             outer_radius=body[1]), material="m")])


def test_uniform_stretch_is_reproduced_exactly():
    """An affine velocity v = L x (stretch + shear + spin) on a solid inside the ring, APIC (C_p = L): P2G gives
    every node v_i = L P_i, so G2P returns v_p = L x_p and grad v = sum v_i (x) grad_x R_i = L exactly (the
    isoparametric identity sum P_i (x) grad_x R_i = I). One step, tiny dt so that stress changes nothing
    measurable: F = I + dt L to round-off (1e-12), positions x + dt L x."""
    cfg = ring_cfg(walls="free", model="neo_hookean")
    sim = tm.Simulation(cfg)
    X = sim.scene.x
    L = np.array([[0.3, 0.2], [-0.1, -0.2]])
    v = X @ L.T
    # APIC stores B_p = L D_p for the affine field (D_p = sum R_i (P_i - x_p)(P_i - x_p)^T, host evaluation)
    mp = sim.mapped.map
    xi = np.empty((len(X), 2))
    xi[sim._perm] = sim.mapped.xi.to_numpy()
    R = mp.rational_host(xi)
    r = mp.P[None] - X[:, None, None, :]
    D = np.einsum("mij,mijc,mijd->mcd", R, r, r)
    sim.set_particles(v=v, C=L @ D)
    dt = 1e-3
    sim.step(dt)   # F = I: no stress, so the grid velocities are exactly the transferred ones
    p = sim.particles()
    assert np.abs((p["F"] - np.eye(2)) / dt - L).max() < 1e-12     # grad v = L: round-off of F (1e-16) / dt
    assert np.abs(p["v"] - v).max() < 1e-13     # sum R_i P_i = x_p up to Newton's residual (1e-13 h)
    assert np.abs(p["x"] - (X + dt * v)).max() < 1e-14


def test_a_particle_leaving_the_map_is_an_instability():
    """The stretch test's scene (same kernels) flung outward at 2 m/s through free circles: the outer particles
    cross r = 1, where the map ends; Newton cannot find them and the run stops with the cause, step and
    particle instead of extrapolating the grid."""
    sim = tm.Simulation(ring_cfg(walls="free", model="neo_hookean"))
    X = sim.scene.x
    sim.set_particles(v=2.0 * X / np.linalg.norm(X, axis=1, keepdims=True))
    with pytest.raises(tm.InstabilityError) as e:
        for _ in range(40):
            sim.step(0.005)
    assert "particle left the mapped grid" in str(e.value.cause)
    assert e.value.step >= 2 and np.linalg.norm(X[e.value.particle]) > 0.9   # one of the outer particles


@pytest.mark.slow  # a second kernel set (fluid, slip circles; ~47 s cold): the default run keeps the stretch scene
def test_slip_circles_conserve_angular_momentum_of_a_spinning_fluid_ring():
    """A fluid ring spinning rigidly (1 rad/s) in the full annulus with slip walls: centrifugal pressure pushes it
    onto the outer circle. Every wall impulse is radial (through the centre) and APIC carries the affine part, so
    the angular momentum about the centre changes by round-off only: 1e-10 of |L| per step (measured below)."""
    cfg = ring_cfg()
    cfg["bodies"][0]["angular_velocity"] = 1.0
    sim = tm.Simulation(cfg)
    L = [sim.momentum()["angular"][2]]
    for _ in range(40):
        sim.step()
        L.append(sim.momentum()["angular"][2])
    L = np.array(L)
    assert L[0] > 0
    assert np.abs(np.diff(L)).max() < 1e-10 * abs(L[0])
    r = np.linalg.norm(sim.particles()["x"], axis=1)
    assert r.max() <= 1.0 + 1e-9 and r.min() >= 0.5 - 1e-9    # inside the circles


def test_map_config_errors():
    cfg = ring_cfg(angle=180.0, cells=(9, 4))
    with pytest.raises(ConfigError) as e:
        tm.load_config(cfg)
    assert e.value.key == "domain.map.cells"
    cfg = ring_cfg()
    cfg["solver"]["basis"] = "cubic"
    with pytest.raises(ConfigError, match="quadratic"):
        tm.load_config(cfg)
    cfg = ring_cfg(body=(0.3, 0.9))     # a body reaching inside the inner circle
    with pytest.raises(ConfigError, match="outside the mapped grid"):
        tm.Simulation(cfg)


def test_ring_channel_demo_config_validates():
    from pathlib import Path
    cfg = tm.load_config(Path(__file__).resolve().parents[1] / "configs" / "ring_channel.yaml")
    assert cfg.domain.map.type == "annulus" and cfg.solver.basis == "quadratic"


@pytest.mark.slow
def test_generalized_vortex_on_the_polar_grid():
    """The generalized vortex (analytic.py) on the body-fitted polar grid: RMS position error 0.0187, 0.00251,
    0.000871 at cells 24, 48, 96 (least-squares rate 2.2; the Cartesian grid: 0.0188, 0.00248, 0.000814).
    Bars: rate >= 1.8 (the issue's), and at 48 cells (1400 stored nodes) an error below the Cartesian grid's at
    36 cells (1444 nodes, measured 0.00322): the same storage buys a finer polar grid. ~10 min on 2 cores."""
    from taichi_mpm import analytic as an

    def rms(grid, cells):
        return an.run_problem(an.GeneralizedVortex(cells=cells, grid=grid))[1]["error_rms"]

    cells = [24, 48, 96]
    errs = [rms("polar", c) for c in cells]
    assert -np.polyfit(np.log(cells), np.log(errs), 1)[0] >= 1.8, errs
    assert errs[1] < rms("cartesian", 36)
