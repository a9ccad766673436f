"""traced.py: trace-time matrix helpers compute what Taichi's own do (against numpy in f64), only inside kernels,
and keep a 3D first step's syntax-tree walk small (a count, the same on every machine)."""
import numpy as np
import pytest
import taichi as ti
from taichi.lang import matrix_ops

import taichi_mpm as tm
from taichi_mpm.solver import init_taichi
from taichi_mpm import traced


def test_matrix_helpers_match_numpy_in_f64():
    init_taichi("cpu", "f64")
    assert all(getattr(getattr(matrix_ops, name), "_traced", False) for name in traced._OPS)
    rng = np.random.default_rng(3)
    A3, B3 = rng.normal(size=(3, 3)) + 3 * np.eye(3), rng.normal(size=(3, 3))
    A2, v3, w3, v2 = rng.normal(size=(2, 2)) + 2 * np.eye(2), rng.normal(size=3), rng.normal(size=3), rng.normal(size=2)
    a3, b3 = ti.Matrix.field(3, 3, float, ()), ti.Matrix.field(3, 3, float, ())
    a2 = ti.Matrix.field(2, 2, float, ())
    x3, y3, x2 = ti.Vector.field(3, float, ()), ti.Vector.field(3, float, ()), ti.Vector.field(2, float, ())
    for f, value in [(a3, A3), (b3, B3), (a2, A2), (x3, v3), (y3, w3), (x2, v2)]:
        f.from_numpy(value)
    m33 = {k: ti.Matrix.field(3, 3, float, ()) for k in ("mm", "T", "inv", "outer", "zero", "eye")}
    v = {k: ti.Vector.field(3, float, ()) for k in ("mv", "vm")}
    s = ti.field(float, 8)
    inv2 = ti.Matrix.field(2, 2, float, ())

    @ti.kernel
    def run():
        A, B, x, y = a3[None], b3[None], x3[None], y3[None]
        m33["mm"][None] = A @ B
        m33["T"][None] = A.transpose()
        m33["inv"][None] = A.inverse()
        m33["outer"][None] = x.outer_product(y)
        m33["zero"][None] = ti.Matrix.zero(float, 3, 3) + 1.5
        m33["eye"][None] = ti.Matrix.identity(float, 3)
        v["mv"][None] = A @ x
        v["vm"][None] = x @ A
        s[0] = A.determinant()
        s[1] = x.dot(y)
        s[2] = A.trace()
        s[3] = A.sum()
        s[4] = x.norm_sqr()
        s[5] = x.norm()
        s[6] = a2[None].determinant()
        s[7] = (A @ B @ A).determinant()          # an expression argument, evaluated once
        inv2[None] = a2[None].inverse()

    run()
    tol = dict(rtol=1e-13, atol=1e-13)   # f64: a few roundings of O(1) entries
    np.testing.assert_allclose(m33["mm"].to_numpy(), A3 @ B3, **tol)
    np.testing.assert_allclose(m33["T"].to_numpy(), A3.T, **tol)
    np.testing.assert_allclose(m33["inv"].to_numpy(), np.linalg.inv(A3), **tol)
    np.testing.assert_allclose(m33["outer"].to_numpy(), np.outer(v3, w3), **tol)
    np.testing.assert_array_equal(m33["zero"].to_numpy(), np.full((3, 3), 1.5))
    np.testing.assert_array_equal(m33["eye"].to_numpy(), np.eye(3))
    np.testing.assert_allclose(v["mv"].to_numpy(), A3 @ v3, **tol)
    np.testing.assert_allclose(v["vm"].to_numpy(), v3 @ A3, **tol)
    expect = [np.linalg.det(A3), v3 @ w3, np.trace(A3), A3.sum(), v3 @ v3, np.linalg.norm(v3), np.linalg.det(A2),
              np.linalg.det(A3 @ B3 @ A3)]
    np.testing.assert_allclose(s.to_numpy(), expect, **tol)
    np.testing.assert_allclose(inv2.to_numpy(), np.linalg.inv(A2), **tol)
    # outside kernels Taichi's own helpers run (Python-scope matrices)
    M = ti.Matrix(A3.tolist())
    np.testing.assert_allclose((M @ M).to_numpy(), A3 @ A3, **tol)
    np.testing.assert_allclose(M.inverse().to_numpy(), np.linalg.inv(A3), **tol)


def test_shapes_the_helpers_do_not_handle_get_taichis_own_messages():
    init_taichi("cpu", "f64")
    a = ti.Matrix.field(3, 2, float, ())

    @ti.kernel
    def bad() -> float:
        return a[None].determinant()

    with pytest.raises(Exception, match="square"):
        bad()


def test_a_3d_first_step_walks_few_syntax_nodes(monkeypatch, cfg_factory):
    """Taichi's transformer visits each node of every func at every call and unrolled iteration; the stencil and
    matrix helpers built at trace time keep a 3D quadratic APIC first step (P2G, G2P, grid update, binning,
    energies) near 7 000 visits (it was 32 000, 2/3 of a warm first step). A func put back in the stencil's
    unrolled node loop adds thousands."""
    from taichi.lang.ast import ast_transformer_utils

    visits = {"n": 0}
    original = ast_transformer_utils.Builder.__call__

    def counted(self, ctx, node):
        visits["n"] += 1
        return original(self, ctx, node)

    monkeypatch.setattr(ast_transformer_utils.Builder, "__call__", counted)
    sim = tm.Simulation(tm.load_config(cfg_factory(3, dx=0.25, precision="f32")))
    sim.step()
    assert 2000 < visits["n"] < 10000, visits
