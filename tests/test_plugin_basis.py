"""A basis registered from the test folder (docs/bases.md, "Adding a basis"): linear hats written here, with a CFL
factor of 0.5 and 1D/2D only. Config validation, the solver, budget, advise, compare and the config reference take
it through its declaration alone; it is unregistered afterwards."""
import math

import numpy as np
import pytest
import taichi as ti
import yaml

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm import budget
from taichi_mpm.bases import registry
from taichi_mpm.bases.shape_functions import Basis, make_basis
from taichi_mpm.tools import compare
from taichi_mpm.tools import config_reference as ref
from taichi_mpm.tools.advise import advise

NAME = "hat_test"


def make_hat(spec, knots=None) -> Basis:
    """Linear hats on nodes 0..n (node i at i): a particle in cell c weights nodes c, c + 1 by 1 - t and t."""

    @ti.func
    def coord(i, n):
        return ti.cast(i, float)

    @ti.func
    def weights_1d(u, n: ti.template(), lp):
        uu = ti.cast(u, float)
        c = ti.min(ti.max(int(ti.floor(uu)), 0), n - 1)
        t = uu - ti.cast(c, float)
        return c, ti.Vector([1.0 - t, t]), ti.Vector([-1.0, 1.0])

    return Basis(spec.name, 2, 0, True, lambda n: n + 1, coord, lambda i, n: float(i), weights_1d)


SPEC = registry.Spec(NAME, "linear hats written in tests/test_plugin_basis.py", make_hat, degree=1, stencil=2,
                     grid="bspline", dims=(1, 2), crack="not tried with the crack finder", cfl_factor=0.5,
                     accuracy=0)


@pytest.fixture
def hat():
    registry.register(SPEC)
    try:
        yield SPEC
    finally:
        registry.unregister(NAME)


def block(basis, cfl=0.4, dim=2):
    cfg = make_cfg(dim, basis=basis, cfl=cfl, velocity=[0.3, -0.2][:dim], boundaries="free")
    cfg["solver"]["gravity"] = [0.0] * dim
    return cfg


def test_partition_of_unity_and_linear_reproduction(hat):
    ti.init(arch=ti.cpu, default_fp=ti.f64, log_level=ti.ERROR, offline_cache=True)
    basis, n = make_basis(NAME), 8
    u = np.linspace(0.0, n, 97)
    out = np.zeros((len(u), 4))

    @ti.kernel
    def run(u: ti.types.ndarray(), out: ti.types.ndarray()):
        for i in range(u.shape[0]):
            b, w, dw = basis.weights_1d(u[i], n, 0.0)
            for k in ti.static(range(2)):
                x = basis.coord(b + k, n)
                out[i, 0] += w[k]
                out[i, 1] += w[k] * x
                out[i, 2] += dw[k]
                out[i, 3] += dw[k] * x

    run(u, out)
    np.testing.assert_allclose(out[:, 0], 1.0, atol=1e-14)   # sum w = 1
    np.testing.assert_allclose(out[:, 1], u, atol=1e-13)     # sum w x_i = u
    np.testing.assert_allclose(out[:, 2], 0.0, atol=1e-14)   # sum dw = 0
    np.testing.assert_allclose(out[:, 3], 1.0, atol=1e-13)   # sum dw x_i = 1


def test_config_takes_its_name_and_its_declared_limits(hat):
    assert tm.load_config(block(NAME)).solver.basis == NAME
    rows = {r[0]: r for r in ref.walk()}
    assert rows["solver.basis"][3].endswith(r"cpdi \| ddmp \| ck \| hat_test")     # the config reference lists it
    with pytest.raises(tm.ConfigError, match=r"basis hat_test is defined in 1D or 2D only \(the scene is 3D\)"):
        tm.load_config(make_cfg(3, basis=NAME))
    knots = block(NAME)
    knots["domain"]["knots"] = dict(x=[0.0, 0.0, 0.5, 1.0, 1.0])
    with pytest.raises(tm.ConfigError, match=r"B-spline basis \(linear, quadratic or cubic\), not solver.basis "
                                             r"hat_test"):
        tm.load_config(knots)
    cracked = block(NAME)
    cracked["crack"] = {}
    with pytest.raises(tm.ConfigError, match="the crack finder does not support basis hat_test: not tried"):
        tm.load_config(cracked)


def run(basis, cfl, steps=10):
    """(dt rule's elastic step, momentum before, momentum after, positions after, time, sim) of `steps` steps
    (one Simulation is live at a time)."""
    sim = tm.Simulation(block(basis, cfl=cfl))
    dt, p0 = sim.dt_limits()["elastic"], sim.momentum()["linear"]
    for _ in range(steps):
        sim.step()
    return dt, p0, sim.momentum()["linear"], sim.particles()["x"], sim.time, sim


def test_steps_conserve_momentum_and_match_linear_at_half_the_cfl(hat):
    full = run("linear", 0.4, steps=0)[0]
    dt_lin, _, _, x_lin, t_lin, _ = run("linear", 0.2)   # the linear B-spline's hats are these, at the same dt
    dt, p0, p1, x, t, sim = run(NAME, 0.4)
    assert dt == dt_lin == pytest.approx(0.5 * full, rel=1e-15)
    mass = np.sum(sim.scene.mass)
    assert p0 == pytest.approx([0.3 * mass, -0.2 * mass], rel=1e-12)
    assert np.abs(p1 - p0).max() < 1e-12 * 0.5 * mass   # to round-off of sum m |v|
    assert t == t_lin > 0
    assert np.abs(x - sim.scene.x).max() > 0.01          # it moved
    assert np.abs(x - x_lin).max() < 1e-12               # as the linear B-spline moves it


def test_advise_and_compare_list_it(hat, tmp_path):
    assert registry.swept()[0] == NAME   # stencil 2 and rank 0: the cheapest
    path = tmp_path / "block.yaml"
    path.write_text(yaml.safe_dump(block(NAME)))
    with pytest.raises(tm.ConfigError, match=r"--bases: expected some of hat_test, linear, gimp, quadratic, cubic, "
                                             r"got nope"):
        advise(str(path), observe="kinetic_energy", tolerance=0.01, bases=("nope",))
    key, values = compare.parse_vary(f"solver.basis={NAME},linear")
    variants = [compare.Variant(key, v, tm.load_config(block(v))) for v in values]
    compare.estimate_work(variants[0].cfg, key, variants)   # compare's size check takes it
    steps = [budget.check(v.cfg).steps for v in variants]
    assert steps[0] == pytest.approx(2 * steps[1], rel=0.05)   # half the CFL step: twice the steps
    compare.run_variant(variants[0], "speed")
    assert variants[0].status == "ok" and variants[0].steps == math.ceil(steps[0])   # the last step is shorter


def test_unregistered_afterwards():
    assert NAME not in registry.names()
    with pytest.raises(tm.ConfigError, match=r"must be 'linear', 'gimp', 'quadratic', 'cubic', 'cpdi', 'ddmp' or 'ck' "
                                             r"\(got 'hat_test'\)"):
        tm.load_config(block(NAME))
    with pytest.raises(ValueError, match="built in"):
        registry.unregister("linear")
