"""mohr_coulomb (materials/mohr_coulomb.py) against independent results: the returned stresses on the pyramid
(evaluated in numpy from the returned F), the return region (face, compression edge, extension edge, apex) read off
the returned principal stresses, the closest point in the energy norm for associated flow (every active set of the
six planes enumerated in numpy), the flow direction against the dilatancy angle, the plane-strain friction of a
material point in steady simple shear (Davis 1968), and drucker_prager's compression cone on its meridian. f64,
driven by small Taichi kernels."""
import itertools
import math

import numpy as np
import pytest
import taichi as ti

from taichi_mpm.config import Material
from taichi_mpm.materials import MODELS
from taichi_mpm.materials.mohr_coulomb import planes

from conftest import fast_subset

E, NU = 1.0e6, 0.3
MU, LAM = E / (2 * (1 + NU)), E * NU / ((1 + NU) * (1 - 2 * NU))
K = LAM + 2 * MU / 3
D = LAM * np.ones((3, 3)) + 2 * MU * np.eye(3)
PHI, C, PSI = 30.0, 2.0e3, 10.0


def material(model="mohr_coulomb", **over):
    keys = dict(friction_angle=PHI, cohesion=C, dilatancy=PSI)
    keys.update(over)
    return Material(model=model, density=1000.0, E=E, nu=NU, **keys)


def _init(fp=ti.f64):
    ti.init(arch=ti.cpu, default_fp=fp, offline_cache=True, log_level=ti.ERROR)


def run_projection(dim, F, q0, model="mohr_coulomb", fp=ti.f64, **over):
    """Each sample through the model's return mapping: (F_new, q_new, dissipated, tau3 trial, tau3 returned)."""
    _init(fp)
    m = material(model, **over)
    cls = MODELS[model]
    nq = len(cls.state(dim))
    funcs = cls.build(m, dim, nq)
    n = len(F)
    Fin, Fout = ti.Matrix.field(dim, dim, float, n), ti.Matrix.field(dim, dim, float, n)
    qin, qout = ti.Vector.field(nq, float, n), ti.Vector.field(nq, float, n)
    diss = ti.field(float, n)
    t_tr, t_new = ti.Matrix.field(3, 3, float, n), ti.Matrix.field(3, 3, float, n)
    Fin.from_numpy(F.reshape(n, 1) if dim == 1 else F)
    qin.from_numpy(q0)

    @ti.kernel
    def go():
        for i in Fin:
            Z = ti.Matrix.zero(float, dim, dim)
            Fn, qn, d = funcs.project(Fin[i], qin[i])
            Fout[i], qout[i], diss[i] = Fn, qn, d
            t_tr[i] = funcs.kirchhoff3(Fin[i], Z, qin[i])
            t_new[i] = funcs.kirchhoff3(Fn, Z, qn)

    go()
    return Fout.to_numpy().reshape(n, dim, dim), qout.to_numpy(), diss.to_numpy(), t_tr.to_numpy(), t_new.to_numpy()


def rotation(rng, d):
    Q, R = np.linalg.qr(rng.normal(size=(d, d)))
    Q = Q * np.sign(np.diag(R))
    if np.linalg.det(Q) < 0:
        Q[:, 0] *= -1
    return Q


def trials(dim, n, seed=0):
    """Trial elastic F with principal Hencky strains spread over every return region: a mean strain from tension
    (the apex region) to compression and a deviatoric part up to ~10 yield strains, in random principal frames
    (2D: the out-of-plane strain is the held stretch; 1D: uniaxial strain, both lateral strains the held one).
    Returns F (n, dim, dim) and the initial state (plastic strain 0, J_p 1, held stretch)."""
    rng = np.random.default_rng(seed)
    scale = 10 ** rng.uniform(-3.5, -1.5, n)           # yield strains ~ c / E = 2e-3 and the pressure's
    eps = scale[:, None] * rng.normal(size=(n, 3)) + scale[:, None] * rng.uniform(-3, 1, n)[:, None]
    if dim == 1:
        eps[:, 2] = eps[:, 1]
    F = np.empty((n, dim, dim))
    for i in range(n):
        F[i] = rotation(rng, dim) @ np.diag(np.exp(eps[i, :dim])) @ rotation(rng, dim)
    q = np.zeros((n, 3 if dim < 3 else 2))
    q[:, 1] = 1.0
    if dim < 3:
        q[:, 2] = np.exp(eps[:, 2])
    return F, q


def principal(t):
    """Principal stresses of 3x3 symmetric stresses, sorted s1 >= s2 >= s3."""
    return np.linalg.eigvalsh(0.5 * (t + np.swapaxes(t, 1, 2)))[:, ::-1]


def f_mc(s, phi=PHI, c=C):
    """Mohr-Coulomb's f of sorted principal stresses (tension positive)."""
    sf = math.sin(math.radians(phi))
    return (s[:, 0] - s[:, 2]) + (s[:, 0] + s[:, 2]) * sf - 2 * c * math.cos(math.radians(phi))


def region(s, scale, phi=PHI, c=C):
    """Where a returned stress lies, from its principal stresses alone: apex, comp (s1 = s2), ext (s2 = s3), face."""
    apex = c / math.tan(math.radians(phi))
    tol = 1e-9 * scale
    at_apex = (np.abs(s - apex) <= tol[:, None]).all(1)
    comp = ~at_apex & (s[:, 0] - s[:, 1] <= tol)
    ext = ~at_apex & (s[:, 1] - s[:, 2] <= tol)
    return np.where(at_apex, "apex", np.where(comp, "comp", np.where(ext, "ext", "face")))


def full3(F, q):
    """The 3D elastic F of (F, held stretch)."""
    n, d = F.shape[:2]
    out = np.repeat(np.eye(3)[None], n, 0)
    if d < 3:
        out *= q[:, 2][:, None, None]
    out[:, :d, :d] = F
    return out


def log_principal(F3):
    """Sorted principal Hencky strains of 3x3 F's (descending)."""
    return 0.5 * np.log(np.linalg.eigvalsh(F3 @ np.swapaxes(F3, 1, 2)))[:, ::-1]


@pytest.mark.parametrize("dim", fast_subset([1, 2, 3], [3]))
def test_return_lands_on_the_pyramid_in_every_region(dim):
    """2000 trials in random frames: inside ones unchanged bit for bit; every yielded one on f = 0 to 1e-10 of the
    stress scale (f evaluated in numpy from the principal stresses of the returned F); all four returns occur
    (face and both edges: 1D has its two lateral stresses equal, so only the edges and the apex); the flow of the face
    and edge returns has tr(d eps_p) / sum |d eps_p,i| = sin(psi) (the potential's normal, or a positive combination
    of two: (1 + sin psi) on the stretched axes, -(1 - sin psi) on the compressed ones); det F_e J_p is kept;
    dissipation >= 0."""
    n = 2000
    F, q = trials(dim, n, seed=dim)
    Fn, qn, diss, t_tr, t_new = run_projection(dim, F, q)
    s_tr, s_new = principal(t_tr), principal(t_new)
    scale = np.maximum(np.abs(s_tr).max(1), C)
    f_tr, f_new = f_mc(s_tr), f_mc(s_new)
    inside, out = f_tr <= 0, f_tr > 0
    assert 0.1 * n < inside.sum() < 0.9 * n
    assert (Fn[inside] == F[inside]).all() and (qn[inside] == q[inside]).all() and (diss[inside] == 0).all()
    assert (np.abs(f_new[out]) <= 1e-10 * scale[out]).all(), np.abs(f_new[out] / scale[out]).max()
    reg = region(s_new[out], scale[out])
    counts = {r: int((reg == r).sum()) for r in ("face", "comp", "ext", "apex")}
    expect = ("comp", "ext", "apex") if dim == 1 else ("face", "comp", "ext", "apex")
    assert all(counts[r] >= 0.03 * out.sum() for r in expect), counts
    if dim == 1:
        assert counts["face"] == 0
    # flow direction: principal plastic strain increments (coaxial: the trial's and the returned principal axes agree)
    deps = log_principal(full3(F, q))[out] - log_principal(full3(Fn, qn))[out]
    total = np.abs(deps).sum(1)
    flowing = (reg != "apex") & (total > 1e-6)
    ratio = deps[flowing].sum(1) / total[flowing]
    err = np.abs(ratio - math.sin(math.radians(PSI)))
    assert err.max() <= 1e-7, err.max()                 # measured 4e-11 (3D), 2e-11 (2D, 1D)
    J = np.linalg.det(full3(F, q)) * q[:, 1]
    assert np.allclose(np.linalg.det(full3(Fn, qn)) * qn[:, 1], J, rtol=1e-12)
    assert (diss >= -1e-12 * scale).all() and (diss[out][reg != "apex"] > 0).all()


def closest_point(sB, phi, c):
    """The closest point of the Mohr-Coulomb pyramid (all six planes) to the trial principal stresses sB in the
    energy norm (s - sB) D^-1 (s - sB), by brute force: the equality-constrained minimum for every active set of one,
    two or three planes, the feasible one of least distance."""
    sf = math.sin(math.radians(phi))
    k = 2 * c * math.cos(math.radians(phi))
    A = []
    for i, j in itertools.permutations(range(3), 2):      # (1 + sin phi) s_i - (1 - sin phi) s_j <= k
        a = np.zeros(3)
        a[i], a[j] = 1 + sf, -(1 - sf)
        A.append(a)
    A = np.array(A)
    Dinv = np.linalg.inv(D)
    best, best_d = None, np.inf
    for size in (1, 2, 3):
        for act in itertools.combinations(range(6), size):
            Aa = A[list(act)]
            M = Aa @ D @ Aa.T
            if np.linalg.cond(M) > 1e12:
                continue
            lam = np.linalg.solve(M, Aa @ sB - k)
            s = sB - D @ Aa.T @ lam
            if (A @ s - k <= 1e-9 * np.abs(sB).max()).all():
                d = (s - sB) @ Dinv @ (s - sB)
                if d < best_d:
                    best, best_d = s, d
    return best


@pytest.mark.slow
def test_associated_return_is_the_closest_point_in_the_energy_norm():
    """Associated flow (psi = phi): the return of 48 yielded 3D trials (12 in each region) equals the brute-force
    closest point of the six-plane pyramid in the energy norm to 1e-9 of the stress scale (f64; the enumeration's
    own round-off is ~1e-13)."""
    F, q = trials(3, 1000, seed=7)
    Fn, qn, diss, t_tr, t_new = run_projection(3, F, q, dilatancy=PHI)
    s_tr, s_new = principal(t_tr), principal(t_new)
    out = np.flatnonzero(f_mc(s_tr) > 0)
    scale = np.maximum(np.abs(s_tr).max(1), C)
    reg = region(s_new[out], scale[out])
    picked = np.concatenate([out[reg == r][:12] for r in ("face", "comp", "ext", "apex")])
    assert len(picked) == 48
    for i in picked:
        ref = closest_point(s_tr[i], PHI, C)
        assert np.abs(s_new[i] - ref).max() <= 1e-9 * scale[i], (i, s_new[i], ref)


@pytest.mark.parametrize("psi", fast_subset([PSI, 0.0], []))
def test_drucker_prager_compression_cone_coincides_on_the_compression_meridian(psi):
    """drucker_prager with fit: compression is the cone through Mohr-Coulomb's compression meridian
    (s1 = s2 > s3): for trials on that meridian (triaxial compression, in random frames) both models return to the
    same stress to 1e-10 of the stress scale, along the meridian (MC: the compression edge, with equal multipliers;
    DP: its cone) or to the apex, with the same dilatancy. On the extension meridian they differ (the cone is
    outside the pyramid there), which the last assert shows for the returns off the apex."""
    rng = np.random.default_rng(3)
    n = 300
    mean = 1e-3 * rng.uniform(-3, 4, n)           # the apex: a mean strain of 1.4e-3
    dev = 1e-3 * 10 ** rng.uniform(-1, 1.2, n)
    F = np.empty((n, 3, 3))
    Fx = np.empty((n, 3, 3))
    for i in range(n):
        R = rotation(rng, 3)
        F[i] = R @ np.diag(np.exp(mean[i] + dev[i] * np.array([1, 1, -2]))) @ R.T     # compression meridian
        Fx[i] = R @ np.diag(np.exp(mean[i] + dev[i] * np.array([2, -1, -1]))) @ R.T    # extension meridian
    q = np.tile([0.0, 1.0], (n, 1))
    _, _, _, t_tr, t_mc = run_projection(3, np.concatenate([F, Fx]), np.concatenate([q, q]), dilatancy=psi)
    _, _, _, _, t_dp = run_projection(3, np.concatenate([F, Fx]), np.concatenate([q, q]), model="drucker_prager",
                                      dilatancy=psi, fit="compression")
    scale = np.maximum(np.abs(t_tr).max((1, 2)), C)
    yielded = f_mc(principal(t_tr)) > 0
    comp, ext = np.arange(2 * n) < n, np.arange(2 * n) >= n
    assert yielded[comp].sum() > 0.25 * n
    s_mc = principal(t_mc)
    at_apex = region(s_mc, scale) == "apex"
    assert 0 < (at_apex & comp & yielded).sum() < (comp & yielded).sum()     # edge and apex returns both occur
    diff = np.abs(t_mc - t_dp).max((1, 2)) / scale
    assert (diff[comp] <= 1e-10).all(), diff[comp].max()
    # off the apex (where both are stress-free: with psi = 0 every trial past the apex's mean stress goes there,
    # over half of the yielded extension trials), the cone returns elsewhere than the pyramid
    assert np.median(diff[ext & yielded & ~at_apex]) > 1e-2


def simple_shear(dim_psi, steps=2000, rate=1e-4, p0=1.0e3, phi=PHI):
    """A plane-strain mohr_coulomb point (c = 0) under the constant normal stress sigma_yy = -p0 (Kirchhoff), first
    compressed isotropically, then sheared: each step F <- (I + rate e_x e_y + x e_y e_y) F with the vertical
    stretch rate x found by the secant method so that the returned tau_yy = -p0 (dilation under load, as in a
    direct shear test). The final Kirchhoff stress (3x3)."""
    _init()
    m = material(friction_angle=phi, cohesion=0.0, dilatancy=dim_psi)
    funcs = MODELS["mohr_coulomb"].build(m, 2, 3)
    out = ti.Matrix.field(3, 3, float, ())
    e0 = -p0 / (3 * K)

    @ti.func
    def step(F, q, x):
        Ft = (ti.Matrix.identity(float, 2) + ti.Matrix([[0.0, rate], [0.0, x]])) @ F
        return funcs.project(Ft, q)

    @ti.kernel
    def go():
        F = ti.Matrix([[ti.exp(e0), 0.0], [0.0, ti.exp(e0)]])
        q = ti.Vector([0.0, 1.0, ti.exp(e0)])
        zero = ti.Matrix.zero(float, 2, 2)
        for _ in range(1):                      # serial
            for s in range(steps):
                # secant iterations on x from 0 and rate; one call site of the return map (each inlined copy
                # compiles anew: four of them took ~19 s with an empty cache)
                x_prev, g_prev, x = 0.0, 0.0, 0.0
                Fn, qn = F, q
                for it in range(33):
                    Fn, qn, d = step(F, q, x)
                    g = funcs.kirchhoff3(Fn, zero, qn)[1, 1] + p0
                    if it == 0:
                        x_prev = x
                        g_prev = g
                        x = rate
                    elif ti.abs(g) > 1e-12 * p0 and g != g_prev:
                        x_next = x - g * (x - x_prev) / (g - g_prev)
                        x_prev = x
                        g_prev = g
                        x = x_next
                    else:
                        break
                F = Fn
                q = qn
        out[None] = funcs.kirchhoff3(F, ti.Matrix.zero(float, 2, 2), q)

    go()
    return out.to_numpy()


@pytest.mark.parametrize("psi", fast_subset([30.0, 0.0, 15.0], [30.0]))
def test_plane_strain_simple_shear_friction(psi):
    """Steady plane-strain simple shear under a constant normal stress: the horizontal planes are the zero-extension
    planes, where tau / sigma_n = sin(phi) cos(psi) / (1 - sin(phi) sin(psi)) (Davis 1968): tan(phi) for associated
    flow (the failure plane is then the shear plane), sin(phi) for psi = 0 (what drucker_prager's plane_strain fit
    gives in the same test, test_plasticity). Sheared to 0.2 (~200 yield strains) in 2000 steps; the out-of-plane
    stress ends as the intermediate principal stress. Tolerance 0.5 %: the elastic strain (p0 / E = 1e-3) turns with
    the material in simple shear, an error of its order."""
    t = simple_shear(psi)
    p, s = math.radians(PHI), math.radians(psi)
    davis = math.sin(p) * math.cos(s) / (1 - math.sin(p) * math.sin(s))
    assert t[1, 1] == pytest.approx(-1.0e3, rel=1e-9)
    assert t[0, 1] / -t[1, 1] == pytest.approx(davis, rel=5e-3)
    s3 = np.sort(np.linalg.eigvalsh(t))
    assert s3[0] < t[2, 2] < s3[2]


@pytest.mark.slow
def test_simple_shear_friction_does_not_depend_on_the_increment():
    """The same shear of 0.2 in 500 and in 8000 increments (psi = 0): tau / sigma_n 0.49962 and 0.49967 (measured;
    0.49966 in 2000). The return is rate independent, so the increment (the time step in a scene) does not move the
    friction: the granular columns' dependence on solver.cfl is the transfers' (docs/materials.md, "Why the low
    columns' run-out moves with dx"). Bound 1e-3 relative, ten times the measured difference."""
    coarse = simple_shear(0.0, steps=500, rate=4e-4)
    fine = simple_shear(0.0, steps=8000, rate=2.5e-5)
    assert coarse[0, 1] / coarse[1, 1] == pytest.approx(fine[0, 1] / fine[1, 1], rel=1e-3)


@pytest.mark.slow
def test_return_mapping_in_f32():
    """f32: the random 3D trials land inside the pyramid to 1e-5 of the stress scale plus the stress resolution of
    f32 (5e-6 E, as test_plasticity's f32 test)."""
    F, q = trials(3, 500, seed=5)
    Fn, qn, diss, t_tr, t_new = run_projection(3, F, q, fp=ti.f32)
    assert np.isfinite(Fn).all() and np.isfinite(t_new).all()
    s_tr, s_new = principal(t_tr.astype(float)), principal(t_new.astype(float))
    assert (f_mc(s_new) <= 1e-5 * np.abs(s_tr).max(1) + 5e-6 * E).all()


def test_schema_rejects_dilatancy_above_friction():
    with pytest.raises(ValueError, match="dilatancy"):
        material(dilatancy=35.0)
    with pytest.raises(ValueError):
        material(friction_angle=0.0)
    a, n, k, apex = planes(PHI, PSI, C)
    assert apex == pytest.approx(C * math.sqrt(3)) and k == pytest.approx(2 * C * math.cos(math.radians(PHI)))
