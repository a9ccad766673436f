"""Basis functions: partition of unity, zero gradient sum and linear reproduction (node positions at the
Greville abscissae) in 1D/2D/3D, in the interior and next to the walls, to 1e-12 in f64.

Each basis @ti.func is evaluated through one small kernel over many points at once."""
import itertools

import numpy as np
import pytest
import taichi as ti

from taichi_mpm.bases import registry
from taichi_mpm.bases.shape_functions import make_basis

BASES = registry.names(stencil_kind="tensor")   # per-axis weights: the tensor-product fast path

N_CELLS = 8


def evaluate(name, u, lp, n_cells=N_CELLS):
    """(first node, w, dw) of basis `name` at grid coordinates u (M,) on a grid of n_cells cells,
    half-widths lp (M,) (GIMP only)."""
    ti.init(arch=ti.cpu, default_fp=ti.f64, log_level=ti.ERROR, offline_cache=True)
    basis = make_basis(name)
    S = basis.stencil
    M = len(u)
    first = np.zeros(M, np.int32)
    w = np.zeros((M, S))
    dw = np.zeros((M, S))

    @ti.kernel
    def run(u: ti.types.ndarray(), lp: ti.types.ndarray(), first: ti.types.ndarray(),
            w: ti.types.ndarray(), dw: ti.types.ndarray()):
        for i in range(u.shape[0]):
            b, W, DW = basis.weights_1d(u[i], n_cells, lp[i])
            first[i] = b
            for k in ti.static(range(S)):
                w[i, k] = W[k]
                dw[i, k] = DW[k]

    run(np.asarray(u, np.float64), np.asarray(lp, np.float64), first, w, dw)
    return basis, first, w, dw


def sample_points(rng, m):
    """Interior points plus points on and next to both walls and on cell boundaries."""
    walls = [0.0, 1e-13, 1e-3, 0.1, 0.25, 0.49, 0.5, 0.999, 1.0, 1.5, 2.0]
    near = walls + [N_CELLS - v for v in walls]
    return np.concatenate([rng.uniform(0, N_CELLS, m), near, np.arange(N_CELLS + 1, dtype=float)])


@pytest.mark.parametrize("name", BASES)
def test_basis_identities_1d_2d_3d(name):
    rng = np.random.default_rng(0)
    u = sample_points(rng, 400)
    lp = np.full(len(u), 0.25) if name == "gimp" else np.zeros(len(u))
    if name == "gimp":
        lp[::3] = rng.uniform(0.05, 0.5, len(lp[::3]))   # deformed / per-particle domain sizes too
    basis, first, w, dw = evaluate(name, u, lp)
    S = basis.stencil
    nodes = first[:, None] + np.arange(S)[None, :]
    assert nodes.min() >= 0 and nodes.max() < basis.nodes(N_CELLS)   # stays in the stored node range
    xi = np.vectorize(lambda i: basis.coord_py(int(i), N_CELLS))(nodes)

    # 1D
    assert np.abs(w.sum(1) - 1).max() < 1e-12
    assert np.abs(dw.sum(1)).max() < 1e-12
    assert np.abs((w * xi).sum(1) - u).max() < 1e-12
    assert np.abs((dw * xi).sum(1) - 1).max() < 1e-12   # gradient of x reproduced too
    assert w.min() > -1e-14                               # non-negative weights

    # 2D and 3D: tensor products of points drawn from the 1D samples (walls and corners included)
    for dim in (2, 3):
        idx = rng.integers(0, len(u), (300, dim))
        idx[:len(u) // 4, :] = np.arange(len(u) // 4)[:, None] % len(u)  # diagonal: corners/edges
        idx[-20:, 0] = len(u) - 1 - np.arange(20)
        for row in idx:
            W = np.ones([S] * dim)
            G = [np.ones([S] * dim) for _ in range(dim)]
            for a, p in enumerate(row):
                shape = [1] * dim
                shape[a] = S
                W = W * w[p].reshape(shape)
                for b in range(dim):
                    G[b] = G[b] * (dw[p] if a == b else w[p]).reshape(shape)
            assert abs(W.sum() - 1) < 1e-12
            for a, p in enumerate(row):
                shape = [1] * dim
                shape[a] = S
                assert abs(G[a].sum()) < 1e-12
                assert abs((W * xi[p].reshape(shape)).sum() - u[p]) < 1e-12


def test_bspline_boundary_nodes_lie_on_walls():
    """Clamped knots: the first and last control points sit on the walls, interior ones at cell
    centres (quadratic) or nodes (linear, cubic)."""
    for name, interior in (("linear", 0.0), ("quadratic", 0.5), ("cubic", 0.0)):
        b = make_basis(name)
        n = b.nodes(N_CELLS)
        coords = [b.coord_py(i, N_CELLS) for i in range(n)]
        assert coords[0] == 0.0 and coords[-1] == float(N_CELLS)
        assert all(c2 > c1 for c1, c2 in zip(coords, coords[1:]))
        assert coords[n // 2] % 1.0 == interior


def test_interior_matches_uniform_bsplines():
    """Away from the walls the clamped B-splines are the uniform ones: w_i = B(u - x_i) with x_i the
    control point (cell centre for quadratic, node for cubic)."""
    def b2(r):
        r = np.abs(r)
        return np.where(r < 0.5, 0.75 - r**2, np.where(r < 1.5, 0.5 * (1.5 - r) ** 2, 0.0))

    def b3(r):
        r = np.abs(r)
        return np.where(r < 1, 0.5 * r**3 - r**2 + 2 / 3, np.where(r < 2, (2 - r) ** 3 / 6, 0.0))

    u = np.linspace(3.0, 5.0, 41)
    for name, ref in (("quadratic", b2), ("cubic", b3)):
        basis, first, w, dw = evaluate(name, u, np.zeros_like(u))
        xi = np.vectorize(lambda i: basis.coord_py(int(i), N_CELLS))(first[:, None] + np.arange(basis.stencil))
        assert np.abs(w - ref(u[:, None] - xi)).max() < 1e-12
        h = 1e-6
        assert np.abs(dw - (ref(u[:, None] + h - xi) - ref(u[:, None] - h - xi)) / (2 * h)).max() < 1e-5  # FD error at the knots


def test_gimp_domain_cut_at_a_wall_is_the_linear_hat_with_no_ghost_weight():
    """A GIMP domain cut at a wall (half-width min(lp, u, n - u), as stencils.py does) lies inside the cell: its
    weights are the linear hats at u with gradients -1, +1, and the ghost node beyond the wall gets nothing. On the
    wall (l = 0) that is the formulas' limit, taken exactly; the earlier floor l >= 1e-6 put l/4 on the ghost and on
    the interior node (a particle on a sticky wall crept out) and a gradient of 1/2 on the ghost."""
    near = np.array([0.0, 1e-13, 1e-7, 1e-6, 1e-3, 0.1, 0.2])
    u = np.concatenate([near, N_CELLS - near])
    lp = np.minimum(0.25, np.minimum(u, N_CELLS - u))
    basis, first, w, dw = evaluate("gimp", u, lp)
    nodes = first[:, None] + np.arange(3)[None, :] - 1          # storage index i holds node i - 1
    hat = np.clip(1 - np.abs(u[:, None] - nodes), 0, None)
    assert np.abs(w - hat).max() < 1e-9                          # the formula at l = u equals it to round-off
    ghost = (nodes < 0) | (nodes > N_CELLS)
    assert np.abs(w[ghost]).max() < 1e-12 and np.abs(dw[ghost]).max() < 1e-9
    assert np.abs(dw.sum(1)).max() < 1e-9 and np.abs((dw * nodes).sum(1) - 1).max() < 1e-9
    on_wall = np.isin(u, [0.0, N_CELLS])
    assert np.all(w[on_wall].max(1) == 1.0)                      # exactly on the wall node: it moves with it


def test_open_knot_wall_functions_have_weight_zero_and_gradient_p_on_the_first_interior_point():
    """The cause of the cubic inversion for particles on a sticky wall (docs/bases.md, "Bodies flush against
    walls"): on the wall N_0 = 1, N_1 = 0 but N_1' = p (grid units), and N_1 ~ p u next to it, so a particle there
    pushes control point 1 while giving it no mass."""
    for name, p in (("linear", 1), ("quadratic", 2), ("cubic", 3)):
        basis, first, w, dw = evaluate(name, np.array([0.0, 1e-4]), np.zeros(2))
        assert first[0] == 0 and w[0, 0] == 1.0 and w[0, 1] == 0.0
        assert dw[0, 1] == pytest.approx(p, rel=1e-12) and dw[0, 0] == pytest.approx(-p, rel=1e-12)
        assert w[1, 1] == pytest.approx(p * 1e-4, rel=1e-3)
