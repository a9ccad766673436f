import numpy as np
import pytest

import taichi_mpm as tm
from conftest import make_cfg


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_free_block_moves_rigidly(dim):
    """A stress-free block with uniform velocity translates: every particle moves by v t."""
    cfg = make_cfg(dim, velocity=[0.5] * dim)
    sim = tm.Simulation(cfg)
    x0 = sim.particles()["x"]
    sim.advance(0.02)
    p = sim.particles()
    assert np.allclose(p["x"] - x0, 0.5 * sim.time, atol=1e-12)
    assert np.allclose(p["F"], np.eye(dim), atol=1e-12)


def test_run_stops_at_max_steps():
    cfg = make_cfg(2, end_time=1.0, max_steps=7)
    sim = tm.Simulation(cfg)
    sim.run(on_output=lambda s: None, every=0.05)
    assert sim.n_steps == 7 and sim.time < 1.0
    assert sim.advance(0.1) == 0  # no further steps past the limit
