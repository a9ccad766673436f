"""Wall conditions act on the wall control points: slip lets a body leave the wall, roller holds its normal
velocity at zero both ways, sticky holds it entirely."""
import numpy as np
import pytest

import taichi_mpm as tm
from conftest import make_cfg


def pulled_block(wall, steps=20):
    """A block touching x_min, moving away from it at 0.5 m/s; returns the final minimum x and mean y velocity."""
    cfg = make_cfg(2, lower=[0.0, 0.3], upper=[0.3, 0.6], velocity=[0.5, 0.2])
    cfg["domain"]["boundaries"]["x_min"] = wall
    sim = tm.Simulation(cfg)
    for _ in range(steps):
        sim.step()
    p = sim.particles()
    return p["x"][:, 0].min(), p["v"][:, 1].mean(), sim.time


@pytest.mark.parametrize("wall", ["slip", "free"])
def test_body_leaves_a_slip_or_free_wall(wall):
    xmin, vy, t = pulled_block(wall)
    assert xmin == pytest.approx(0.025 + 0.5 * t, rel=1e-6)   # the whole block translates away


def test_roller_wall_holds_normal_velocity_only():
    xmin, vy, t = pulled_block("roller")
    assert xmin < 0.025 + 0.05 * 0.5 * t                      # the wall layer stays (moved < 5 % of free motion)
    assert vy > 0.1                                           # tangential motion is free


def test_sticky_wall_holds_both_components():
    xmin, vy, t = pulled_block("sticky")
    assert xmin < 0.025 + 0.05 * 0.5 * t
    assert vy < 0.15                                          # wall-layer drag slows the tangential motion


@pytest.mark.slow
@pytest.mark.parametrize("wall", ["slip", pytest.param("roller", marks=pytest.mark.slow)])
def test_friction_acts_only_while_the_wall_pushes(wall):
    """Coulomb friction scales with the velocity the wall removes from flow *into* it: a block leaving a slip wall,
    or held back by a roller (tension), moves exactly as on the frictionless wall."""
    assert pulled_block({"type": wall, "friction": 1.0}) == pytest.approx(pulled_block(wall), rel=1e-12)
