"""A material model registered from the test folder (tests/plugins/saint_venant.py) through the registry
(materials.register, config.use_registered_materials): configs accept its name, the solver builds it, its stress
under a uniaxial stress state matches the closed form, a step runs with it; unregistered, configs refuse it."""
import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm import config, materials
from taichi_mpm.config import ConfigError, load_config
from conftest import make_cfg
from plugins.saint_venant import SaintVenantKirchhoff

E_YOUNG, NU = 1.0e4, 0.3


@pytest.fixture
def svk():
    materials.register(SaintVenantKirchhoff)
    config.use_registered_materials()
    yield SaintVenantKirchhoff
    materials.unregister(SaintVenantKirchhoff.name)
    config.use_registered_materials()


def test_registered_material_gives_the_closed_form_uniaxial_stress(svk):
    """Plane strain (2D), F = diag(s1, s2) with s2 chosen so that sigma_22 = 0: the Green strain E11 = (s1^2-1)/2,
    E22 = -lam E11 / (lam + 2 mu), and S11 = E/(1 - nu^2) E11 (the plane-strain modulus), sigma_11 = s1 S11 / s2,
    sigma_33 = lam (E11 + E22) / (s1 s2); the stored energy is V (mu E:E + lam/2 tr(E)^2)."""
    cfg = load_config(make_cfg(2, model="saint_venant_kirchhoff", E=E_YOUNG, nu=NU, boundaries="free",
                               gravity=[0.0, 0.0]))
    assert cfg.materials["m"].model == "saint_venant_kirchhoff"
    sim = tm.Simulation(cfg)
    mu, lam = E_YOUNG / (2 * (1 + NU)), E_YOUNG * NU / ((1 + NU) * (1 - 2 * NU))
    s1 = 1.02
    E11 = 0.5 * (s1 * s1 - 1)
    E22 = -lam * E11 / (lam + 2 * mu)
    s2 = np.sqrt(1 + 2 * E22)
    sim.set_particles(F=np.broadcast_to(np.diag([s1, s2]), (sim.n, 2, 2)).copy())
    p = sim.particles()
    S11 = E_YOUNG / (1 - NU * NU) * E11
    np.testing.assert_allclose(p["stress"][:, 0, 0], s1 * S11 / s2, rtol=1e-12)
    np.testing.assert_allclose(p["stress"][:, 1, 1], 0.0, atol=1e-9 * abs(S11))
    np.testing.assert_allclose(p["stress3"][:, 2, 2], lam * (E11 + E22) / (s1 * s2), rtol=1e-12)
    psi = mu * (E11 ** 2 + E22 ** 2) + 0.5 * lam * (E11 + E22) ** 2
    assert sim.energy()["strain"] == pytest.approx(psi * sim.scene.volume.sum(), rel=1e-12)
    for _ in range(3):   # the stretched block springs back: strain energy into motion, none created, no net push
        sim.step()
    assert sim.energy()["kinetic"] > 1e-3 * psi * sim.scene.volume.sum()
    assert sim.energy_balance()["ratio"] < 1e-9
    np.testing.assert_allclose(sim.momentum()["linear"], 0.0, atol=1e-10)


def test_unregistered_material_is_refused():
    with pytest.raises(ConfigError, match="saint_venant_kirchhoff"):
        load_config(make_cfg(2, model="saint_venant_kirchhoff"))
    assert "saint_venant_kirchhoff" not in materials.MODELS
