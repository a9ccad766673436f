"""Constitutive models against independent references: numpy's SVD polar decomposition, and the Kirchhoff
stress against finite differences of the strain energy (tau = dpsi/dF F^T), for every model in 2D and 3D."""
import numpy as np
import pytest
import taichi as ti

from taichi_mpm.materials import MODELS, rotation

MU, LAM, VISC = 3.0e3, 2.0e3, 0.0


def _init():
    ti.init(arch=ti.cpu, default_fp=ti.f64, offline_cache=True, log_level=ti.ERROR)


def _random_F(d, n, spread, seed=0):
    rng = np.random.default_rng(seed)
    F = np.eye(d) + rng.normal(0, spread, (n, d, d))
    return F[np.linalg.det(F) > 0.1]


def test_rotation_matches_svd_polar_decomposition_3d():
    _init()
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
    assert np.abs(R.to_numpy() - exact).max() < 1e-12


@pytest.mark.parametrize("d", [2, 3])
def test_kirchhoff_stress_is_the_energy_derivative(d):
    """tau = (dpsi/dF) F^T to 1e-6 relative (central differences, h = 1e-6) for every registered model."""
    _init()
    F = _random_F(d, 20, 0.15, seed=d)
    n = len(F)
    Fm = ti.Matrix.field(d, d, float, n)
    tau = ti.Matrix.field(d, d, float, (len(MODELS), n))
    psi = ti.field(float, (len(MODELS), n))
    Fm.from_numpy(F)
    models = list(MODELS.values())

    @ti.kernel
    def evaluate():
        for i in Fm:
            for k in ti.static(range(len(models))):
                tau[k, i] = models[k].kirchhoff(Fm[i], ti.Matrix.zero(float, d, d), MU, LAM, VISC)
                psi[k, i] = models[k].energy(Fm[i], MU, LAM)

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
    for k, m in enumerate(models):
        scale = np.abs(t_an[k]).max()
        assert np.abs(t_an[k] - t_fd[k]).max() < 1e-6 * scale, m.name
