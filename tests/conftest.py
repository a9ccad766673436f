"""Shared test helpers. Taichi's offline cache stays on, so kernels compiled by one test are reused."""
import copy
import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _checkout_first():
    """The checkout under test is the taichi_mpm every test imports, in this process and in every process a test
    launches (GUI scripts, study cases, `python -m taichi_mpm`, the console script), however pytest was started
    (`pytest` or `python -m pytest`, from any folder) and wherever an editable install of the environment points."""
    if sys.path[:1] != [str(REPO)]:
        sys.path.insert(0, str(REPO))
    rest = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and p != str(REPO)]
    os.environ["PYTHONPATH"] = os.pathsep.join([str(REPO), *rest])


_checkout_first()


def make_cfg(dim=2, *, basis="quadratic", transfer="apic", precision="f64", dx=0.1, extent=1.0,
             model="neo_hookean", E=1.0e4, nu=0.3, density=1000.0, lower=None, upper=None,
             velocity=None, end_time=0.01, boundaries="slip", **solver):
    """A small valid config dict: one box body in a cube domain. Override anything afterwards."""
    lower = lower if lower is not None else [0.3 * extent] * dim
    upper = upper if upper is not None else [0.6 * extent] * dim
    body = dict(name="block", shape=dict(type="box", lower=lower, upper=upper), material="m")
    if velocity is not None:
        body["velocity"] = velocity
    mat = dict(model=model, density=density)
    mat.update(dict(K=E) if model == "fluid" else dict(E=E, nu=nu))
    return dict(name="test", dim=dim, precision=precision, arch="cpu",
                domain=dict(lower=[0.0] * dim, upper=[extent] * dim, dx=dx, boundaries=dict(default=boundaries)),
                solver=dict(basis=basis, transfer=transfer, end_time=end_time, **solver),
                materials=dict(m=mat), bodies=[body])


@pytest.fixture
def cfg_factory():
    return lambda *a, **k: copy.deepcopy(make_cfg(*a, **k))


def body_motion(sim, body, end_time, axis=0):
    """Step `sim` to end_time at its stable step: the times, and body `body`'s mass-weighted velocity and
    displacement along `axis` after each step."""
    import numpy as np

    sel = sim.scene.body == body
    m = sim.scene.mass[sel]
    x0 = (sim.scene.x[sel, axis] * m).sum() / m.sum()
    t, v, x = [], [], []
    while sim.time < end_time - 1e-12:
        sim.step(min(sim.stable_dt(), end_time - sim.time))
        p = sim.particles()
        t.append(sim.time)
        v.append((p["v"][sel, axis] * m).sum() / m.sum())
        x.append((p["x"][sel, axis] * m).sum() / m.sum() - x0)
    return np.array(t), np.array(v), np.array(x)


def velocity_along(sim, direction, end_time):
    """Step `sim` to end_time at its stable step: the times and the centre-of-mass velocity along `direction`
    (a unit vector) after each step."""
    import numpy as np

    mass = sim.scene.mass.sum()
    t, v = [], []
    while sim.time < end_time - 1e-12:
        sim.step(min(sim.stable_dt(), end_time - sim.time))
        t.append(sim.time)
        v.append(float(np.dot(sim.momentum()["linear"][:len(direction)], direction)) / mass)
    return np.array(t), np.array(v)


def fast_subset(cases, fast):
    """Parameters for a test matrix: every case runs under `pytest -m slow`; the default run keeps only `fast`
    (chosen so that each option still appears once). Each case compiles its own kernel set, and cold JIT time is
    what makes the default suite slow."""
    return [c if c in fast else pytest.param(*(c if isinstance(c, tuple) else (c,)), marks=pytest.mark.slow)
            for c in cases]


def spin_free(sim, steps: int = 10):
    """Set a free body spinning about z at 1 rad/s, drifting and deformed by a sine field (in x and y), step it
    and return (linear momentum change / sum m |v|, angular momentum change / sum m |x| |v|, largest |F - I|):
    the mapped grids' conservation checks."""
    import numpy as np

    X = sim.scene.x
    d = X.shape[1]
    v = np.zeros_like(X)
    v[:, 0], v[:, 1] = -X[:, 1], X[:, 0]
    v[:, :2] += np.array([0.03, -0.02]) + 0.05 * np.sin(5 * X[:, :2])
    sim.set_particles(v=v)
    m = sim.scene.mass
    scale = np.sum(m[:, None] * np.abs(v))
    L_scale = np.sum(m * np.linalg.norm(X, axis=1) * np.linalg.norm(v, axis=1))
    m0 = sim.momentum()
    for _ in range(steps):
        sim.step()
    m1 = sim.momentum()
    return (np.abs(m1["linear"] - m0["linear"]).max() / scale,
            np.abs(np.asarray(m1["angular"]) - np.asarray(m0["angular"])).max() / L_scale,
            np.abs(sim.particles()["F"] - np.eye(d)).max())
