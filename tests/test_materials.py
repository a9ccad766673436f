"""Constitutive models against independent references: numpy's SVD polar decomposition, and the Kirchhoff
stress against finite differences of the strain energy (tau = dpsi/dF F^T), for every registered model in 2D and 3D
(plastic models at their initial state: the elastic law of F_e)."""
import numpy as np
import pytest
import taichi as ti

from taichi_mpm.config import Material
from taichi_mpm.materials import MODELS, rotation

MU, LAM = 3.0e3, 2.0e3
E, NU = MU * (3 * LAM + 2 * MU) / (LAM + MU), LAM / (2 * (LAM + MU))
# each model's keys besides the moduli (plastic ones: far from yield, so the stress is the elastic law's)
EXTRA = {"fluid": dict(K=LAM), "von_mises": dict(yield_stress=1e9), "drucker_prager": dict(friction_angle=30.0),
         "snow": dict(hardening=3.0), "mohr_coulomb": dict(friction_angle=30.0),
         "cam_clay": dict(shear_modulus=MU, lambda_star=0.2, kappa_star=0.05, critical_state_slope=1.0,
                          initial_pressure=LAM),
         "mu_i": dict(mu_s=0.4, mu_2=0.6, grain_diameter=1e-3, max_pressure=1e3)}
NO_MODULI = ("fluid", "cam_clay")   # models without E and nu


def material(name):
    keys = EXTRA.get(name, {})
    moduli = {} if name in NO_MODULI else dict(E=E, nu=NU)
    return Material(model=name, density=1000.0, **moduli, **keys)


def _init(fp=ti.f64):
    ti.init(arch=ti.cpu, default_fp=fp, offline_cache=True, log_level=ti.ERROR)


def _random_F(d, n, spread, seed=0):
    rng = np.random.default_rng(seed)
    F = np.eye(d) + rng.normal(0, spread, (n, d, d))
    return F[np.linalg.det(F) > 0.1]


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_rotation_matches_svd_polar_decomposition_3d(precision):
    """Newton stops once its step is below sqrt(epsilon): quadratic convergence leaves R within round-off of the
    SVD's polar factor (f64: 1e-12; f32: 1e-6, measured 1.5e-7; one Newton step fewer leaves ~1e-4)."""
    _init(ti.f64 if precision == "f64" else ti.f32)
    F = _random_F(3, 2000, 0.5)
    Fm = ti.Matrix.field(3, 3, float, len(F))
    R = ti.Matrix.field(3, 3, float, len(F))
    Fm.from_numpy(F)

    @ti.kernel
    def polar():
        for i in Fm:
            R[i] = rotation(Fm[i])

    polar()
    U, _, Vt = np.linalg.svd(F)
    exact = U @ Vt
    cond = np.linalg.cond(F)
    assert cond.max() > 50                                   # the sample includes strongly stretched F
    assert np.abs(R.to_numpy() - exact).max() < (1e-12 if precision == "f64" else 1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("d", [2, pytest.param(3, marks=pytest.mark.slow)])
def test_kirchhoff_stress_is_the_energy_derivative(d):
    """tau = (dpsi/dF) F^T to 1e-6 relative (central differences, h = 1e-6) for every registered model."""
    _init()
    F = _random_F(d, 20, 0.15, seed=d)
    n = len(F)
    Fm = ti.Matrix.field(d, d, float, n)
    tau = ti.Matrix.field(d, d, float, (len(MODELS), n))
    psi = ti.field(float, (len(MODELS), n))
    Fm.from_numpy(F)
    names = list(MODELS)
    nq = 4
    models = [MODELS[name].build(material(name), d, nq) for name in names]
    q0 = [[s.init for s in MODELS[name].state(d)] + [0.0] * (nq - len(MODELS[name].state(d))) for name in names]

    @ti.kernel
    def evaluate():
        for i in Fm:
            for k in ti.static(range(len(models))):
                q = ti.Vector(q0[k], float)
                tau[k, i] = models[k].kirchhoff(Fm[i], ti.Matrix.zero(float, d, d), q)
                psi[k, i] = models[k].energy(Fm[i], q)

    evaluate()
    t_an = tau.to_numpy()
    h = 1e-6
    for a in range(d):
        for b in range(d):
            E = np.zeros((d, d))
            E[a, b] = h
            Fm.from_numpy(F + E)
            evaluate()
            plus = psi.to_numpy()
            Fm.from_numpy(F - E)
            evaluate()
            minus = psi.to_numpy()
            if a == 0 and b == 0:
                P = np.zeros((len(models), n, d, d))
            P[:, :, a, b] = (plus - minus) / (2 * h)
    t_fd = P @ np.swapaxes(F, 1, 2)[None]
    for k, name in enumerate(names):
        scale = np.abs(t_an[k]).max()
        assert np.abs(t_an[k] - t_fd[k]).max() < 1e-6 * scale, name
