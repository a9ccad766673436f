"""NURBS and the annulus map (issue 12, step 2 and the map half of step 3), through the kernel functions the
solver would use, in f64: exact circles from weights, rational partition of unity and exact gradients for random
weights, knot insertion that leaves the geometry unchanged, the Jacobian, Newton inversion, and the isoparametric
patch identities sum R_i P_i = x and sum P_i (x) grad_x R_i = I at physical points."""
import math

import numpy as np
import pytest
import taichi as ti

from taichi_mpm.bases.nurbs import Map, annulus, arc, bspline_values


def init():
    ti.init(arch=ti.cpu, default_fp=ti.f64, log_level=ti.ERROR, offline_cache=True)


def evaluate(mp: Map, xi: np.ndarray):
    """Per parameter point: the dense rational basis R (n0, n1), its parameter derivatives, x and J."""
    mp.materialize()
    n0, n1 = mp.w.shape
    S0, S1 = mp.degrees[0] + 1, mp.degrees[1] + 1
    M = len(xi)
    R, D0, D1 = (np.zeros((M, n0, n1)) for _ in range(3))
    X, J = np.zeros((M, 2)), np.zeros((M, 2, 2))

    @ti.kernel
    def run(xi: ti.types.ndarray(), R: ti.types.ndarray(), D0: ti.types.ndarray(), D1: ti.types.ndarray(),
            X: ti.types.ndarray(), J: ti.types.ndarray()):
        for m in range(xi.shape[0]):
            q = ti.Vector([xi[m, 0], xi[m, 1]])
            b, r, g = mp.rational(q)
            for i, j in ti.static(ti.ndrange(S0, S1)):
                R[m, b[0] + i, b[1] + j] = r[i * S1 + j]
                D0[m, b[0] + i, b[1] + j] = g[i * S1 + j, 0]
                D1[m, b[0] + i, b[1] + j] = g[i * S1 + j, 1]
            x, Jm = mp.point(q)
            for c in ti.static(range(2)):
                X[m, c] = x[c]
                for d in ti.static(range(2)):
                    J[m, c, d] = Jm[c, d]

    run(np.ascontiguousarray(xi, float), R, D0, D1, X, J)
    return R, D0, D1, X, J


def invert(mp: Map, x: np.ndarray, xi0: np.ndarray, tol=1e-13):
    mp.materialize()
    M = len(x)
    xi, ok = np.zeros((M, 2)), np.zeros(M, np.int32)

    @ti.kernel
    def run(x: ti.types.ndarray(), xi0: ti.types.ndarray(), xi: ti.types.ndarray(), ok: ti.types.ndarray()):
        for m in range(x.shape[0]):
            q, good = mp.invert(ti.Vector([x[m, 0], x[m, 1]]), ti.Vector([xi0[m, 0], xi0[m, 1]]), tol)
            xi[m, 0], xi[m, 1] = q[0], q[1]
            ok[m] = 1 if good else 0

    run(np.ascontiguousarray(x, float), np.ascontiguousarray(xi0, float), xi, ok)
    return xi, ok.astype(bool)


def test_quarter_circles_are_exact_and_knot_insertion_keeps_them():
    """A full ring of four rational quarter pieces, each the seed's quarter circle (control points (1, 0),
    (1, 1), (0, 1) rotated, weights (1, 1/sqrt 2, 1)): |C| = 1 to 1e-14 on the inner edge and 2 on the outer
    edge through the kernel (a polynomial B-spline through the same points misses by up to 0.06). Knot
    insertion up to 24 cells leaves the curve unchanged (1e-14, host evaluation of both)."""
    init()
    mp = annulus(1.0, 2.0, 2 * math.pi, n_angle=4, n_radial=1)
    assert np.allclose(mp.w[:3, 0], [1, 1 / math.sqrt(2), 1], rtol=0, atol=1e-15)
    assert np.allclose(mp.P[:3, 0], [[1, 0], [1, 1], [0, 1]], rtol=0, atol=1e-15)
    s = np.linspace(0, 4, 401)
    xi = np.concatenate([np.stack([s, 0 * s], 1), np.stack([s, 0 * s + 1], 1)])
    _, _, _, X, _ = evaluate(mp, xi)
    r = np.linalg.norm(X, axis=1)
    assert np.abs(r[:401] - 1).max() < 1e-14
    assert np.abs(r[401:] - 2).max() < 2e-14
    poly = bspline_values(mp.knots[0], 2, s) @ mp.P[:, 0]   # the same points without weights
    assert np.abs(np.linalg.norm(poly, axis=1) - 1).max() > 0.05
    t, P, w = arc(2 * math.pi, 4)
    t2, P2, w2 = arc(2 * math.pi, 24)
    u = np.random.default_rng(4).uniform(0, 1, 200)
    N, N2 = bspline_values(t, 2, 4 * u), bspline_values(t2, 2, 24 * u)
    c1 = (N * w) @ P / (N @ w)[:, None]
    c2 = (N2 * w2) @ P2 / (N2 @ w2)[:, None]
    assert np.abs(c1 - c2).max() < 1e-14
    assert np.abs(np.linalg.norm(c2, axis=1) - 1).max() < 1e-14
    with pytest.raises(ValueError, match="multiple of 4"):
        arc(2 * math.pi, 10)


def random_map(rng):
    """Non-uniform knots with a double knot, degrees 2 and 3, random control points and weights in [0.2, 5]."""
    t0 = np.array([0, 0, 0, 0.7, 1.9, 1.9, 3, 4, 4, 4], float)
    t1 = np.array([0, 0, 0, 0, 1.3, 2, 3, 3, 3, 3], float)
    n0, n1 = len(t0) - 3, len(t1) - 4
    P = rng.uniform(-1, 1, (n0, n1, 2))
    w = rng.uniform(0.2, 5.0, (n0, n1))
    return Map([t0, t1], [2, 3], P, w)


@pytest.mark.slow
def test_rational_basis_identities_and_exact_gradients_for_random_weights():
    """sum R = 1 (1e-14) and sum grad R = 0 for random weights; the analytic quotient-rule gradients against
    central differences of R (h = 1e-6: truncation ~h^2 |R'''| < 1e-9, round-off ~1e-16 / h = 1e-10; 1e-7
    fails for a gradient missing the -R grad W / W term, which is O(1))."""
    init()
    rng = np.random.default_rng(3)
    mp = random_map(rng)
    M = 300
    xi = np.stack([rng.uniform(0, 4, M), rng.uniform(0, 3, M)], 1)
    h = 1e-6
    e0, e1 = np.array([h, 0]), np.array([0, h])
    # points within h of a knot would difference across a kink: keep those a little away
    for a, t in enumerate(mp.knots):
        for k in np.unique(t):
            near = np.abs(xi[:, a] - k) < 2 * h
            xi[near, a] += 4 * h * (1 if k < t[-1] else -1)
    R, D0, D1, X, J = evaluate(mp, np.concatenate([xi, xi + e0, xi - e0, xi + e1, xi - e1]))
    R, Rp0, Rm0, Rp1, Rm1 = np.split(R, 5)
    D0, D1 = D0[:M], D1[:M]
    assert np.abs(R.sum(axis=(1, 2)) - 1).max() < 1e-14
    assert np.abs(D0.sum(axis=(1, 2))).max() < 1e-12 and np.abs(D1.sum(axis=(1, 2))).max() < 1e-12
    assert np.abs(D0 - (Rp0 - Rm0) / (2 * h)).max() < 1e-7
    assert np.abs(D1 - (Rp1 - Rm1) / (2 * h)).max() < 1e-7
    assert np.abs(D0).max() > 0.1          # the gradients are not trivially small
    # x from the kernel equals the host's independent evaluation (numpy Cox-de Boor over all functions)
    assert np.abs(X[:M] - mp.evaluate(xi)).max() < 1e-13
    # the Jacobian is the derivative of x
    Xp0, Xm0, Xp1, Xm1 = np.split(X[M:], 4)
    assert np.abs(J[:M, :, 0] - (Xp0 - Xm0) / (2 * h)).max() < 1e-7
    assert np.abs(J[:M, :, 1] - (Xp1 - Xm1) / (2 * h)).max() < 1e-7


@pytest.mark.slow
def test_newton_inversion_and_patch_identities_on_the_annulus():
    """Random physical points of a 3/4 annulus: Newton from the middle of the parameter box finds xi with
    x(xi) = x to 1e-13 and the exact radial parameter eta = 4 (r - 1) (independent: r is linear in eta);
    there sum R_i P_i = x and sum_i P_i (x) grad_x R_i = I to 1e-12 (grad_x R = J^-T grad_xi R), the identity
    that makes a uniform stretch exact. A point outside the annulus is reported as not converged."""
    init()
    mp = annulus(1.0, 2.0, 1.5 * math.pi, n_angle=12, n_radial=4)
    rng = np.random.default_rng(5)
    M = 300
    r, th = rng.uniform(1, 2, M), rng.uniform(0, 1.5 * math.pi, M)
    x = np.stack([r * np.cos(th), r * np.sin(th)], 1)
    xi, ok = invert(mp, np.concatenate([x, [[2.5, 0.3]]]), np.tile([6.0, 2.0], (M + 1, 1)))
    assert ok[:M].all() and not ok[M]
    xi = xi[:M]
    assert np.abs(xi[:, 1] - 4 * (r - 1)).max() < 1e-12
    R, D0, D1, X, J = evaluate(mp, xi)
    assert np.abs(X - x).max() < 1e-13
    Jinv_T = np.transpose(np.linalg.inv(J), (0, 2, 1))
    G = np.einsum("mcd,mdij->mijc", Jinv_T, np.stack([D0, D1], 1))      # grad_x R_ij, (M, n0, n1, 2)
    assert np.abs(np.einsum("mij,ijc->mc", R, mp.P) - x).max() < 1e-13
    identity = np.einsum("ijc,mijd->mcd", mp.P, G)
    assert np.abs(identity - np.eye(2)).max() < 1e-12
    assert np.abs(G.sum(axis=(1, 2))).max() < 1e-12


def test_host_geometry_derivatives_normals_and_refinement():
    """mapgeom (numpy, used by config validation and the wall normals): B-spline derivatives equal scipy's
    (1e-12, a double knot included); the Jacobian of a random rational map equals central differences of x
    (h = 1e-6: 1e-7 as above); refinement by knot insertion leaves x(xi) unchanged at random points (1e-14);
    the face normals of a rotated rectangle with a bumpy interior net are its four edge normals (1e-14); the
    plain rectangle refined to 8 x 4 has cells of 0.25."""
    from scipy.interpolate import BSpline
    from taichi_mpm.bases import mapgeom

    rng = np.random.default_rng(7)
    t = np.array([0, 0, 0, 0, 1.3, 2, 2, 3, 3, 3, 3], float)
    u = rng.uniform(0, 3, 200)
    for p in (2, 3):
        tp = t[1:-1] if p == 2 else t
        n = len(tp) - p - 1
        dN = mapgeom.bspline_derivatives(tp, p, u)
        ref = np.stack([BSpline(tp, np.eye(n)[i], p).derivative()(u) for i in range(n)], 1)
        assert np.abs(dN - ref).max() < 1e-12
    mp = random_map(rng)
    xi = np.stack([rng.uniform(0.01, 3.99, 100), rng.uniform(0.01, 2.99, 100)], 1)
    x, J = mp.surface_host(xi)
    h = 1e-6
    for a in range(2):
        e = np.zeros(2)
        e[a] = h
        fd = (mp.surface_host(xi + e)[0] - mp.surface_host(xi - e)[0]) / (2 * h)
        assert np.abs(J[:, :, a] - fd).max() < 1e-7
    # a 2 x 1 rectangle rotated by 0.4 rad, quadratic x quadratic on one span, interior point moved, random weights
    c, s = math.cos(0.4), math.sin(0.4)
    R = np.array([[c, -s], [s, c]])
    g = np.stack(np.meshgrid([0.0, 1.0, 2.0], [0.0, 0.5, 1.0], indexing="ij"), -1)
    g[1, 1] += [0.2, -0.1]
    P = g @ R.T
    w = np.ones((3, 3))
    w[1, 1] = 1.7
    knots = [np.array([0, 0, 0, 1, 1, 1.0])] * 2
    kr, Pr, wr = mapgeom.refine(knots, P, w, [4, 4])
    q = rng.uniform(0, 1, (200, 2))
    assert np.abs(mapgeom.surface(knots, [2, 2], P, w, q)[0] - mapgeom.surface(kr, [2, 2], Pr, wr, 4 * q)[0]).max() < 1e-14
    N = mapgeom.face_normals(kr, [2, 2], Pr, wr)
    for k, n in enumerate([[-1, 0], [1, 0], [0, -1], [0, 1]]):
        rows = N[0, :, 0] if k == 0 else N[-1, :, 1] if k == 1 else N[:, 0, 2] if k == 2 else N[:, -1, 3]
        assert np.abs(rows - R @ np.array(n, float)).max() < 1e-14
    g[1, 1] -= [0.2, -0.1]                # the plain rectangle, weights 1: 8 x 4 cells of 0.25 x 0.25
    kr, Pr, wr = mapgeom.refine(knots, g @ R.T, np.ones((3, 3)), [8, 4])
    assert np.allclose(mapgeom.cell_sizes(kr, [2, 2], Pr, wr), (0.25, 0.25), rtol=0, atol=1e-14)
