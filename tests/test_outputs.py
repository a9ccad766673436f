"""Output fields agree with the mechanics: 2D is plane strain and 1D uniaxial strain, so the written stress is the
full 3x3 tensor (sigma_zz != 0 in 2D, lateral sigma_yy = sigma_zz in 1D) and von Mises and pressure come from it.

Each model's out-of-plane stress is checked against a central finite difference of its strain energy written
here in numpy (independent of the Taichi kernels): with F_zz = 1 and no out-of-plane shear, P_zz = dpsi/dF_zz and
sigma_zz = tau_zz / J = P_zz / J."""
import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm import config, fields
from taichi_mpm.io import files as io
from taichi_mpm.io.render import field_values
from conftest import make_cfg

E, NU, K, RHO = 1.0e4, 0.3, 2.0e4, 1000.0
MU, LAM = E / (2 * (1 + NU)), E * NU / ((1 + NU) * (1 - 2 * NU))
MATERIALS = {"linear_elastic": dict(E=E, nu=NU), "neo_hookean": dict(E=E, nu=NU), "fixed_corotated": dict(E=E, nu=NU),
             "fluid": dict(K=K)}


def psi(model, F):
    """Strain energy per reference volume of a 3x3 F (the models of materials.py, in numpy)."""
    J = np.linalg.det(F)
    if model == "linear_elastic":
        eps = 0.5 * (F + F.T) - np.eye(3)
        return MU * np.sum(eps * eps) + 0.5 * LAM * np.trace(eps) ** 2
    if model == "neo_hookean":
        return 0.5 * MU * (np.sum(F * F) - 3) - MU * np.log(J) + 0.5 * LAM * np.log(J) ** 2
    if model == "fixed_corotated":
        U, _, Vt = np.linalg.svd(F)
        return MU * np.sum((F - U @ Vt) ** 2) + 0.5 * LAM * (J - 1) ** 2
    return 0.5 * K * (J - 1) ** 2  # fluid


def fd_stress(model, F3, a):
    """sigma_aa = (dpsi/dF_aa) / J by central differences (h = 1e-6: truncation ~1e-12, round-off ~1e-10 relative)."""
    h = 1e-6
    Fp, Fm = F3.copy(), F3.copy()
    Fp[a, a] += h
    Fm[a, a] -= h
    return (psi(model, Fp) - psi(model, Fm)) / (2 * h) / np.linalg.det(F3)


def four_material_sim(dim):
    """One body per model (one compile for all four), each particle given a random F (J > 0)."""
    cfg = make_cfg(dim, dx=0.1)
    cfg["materials"] = {m: dict(model=m, density=RHO, **kw) for m, kw in MATERIALS.items()}
    cfg["bodies"] = [dict(shape=dict(type="box", lower=[0.1 + 0.2 * i] + [0.1] * (dim - 1),
                                     upper=[0.2 + 0.2 * i] + [0.2] * (dim - 1)), material=m)
                     for i, m in enumerate(MATERIALS)]
    sim = tm.Simulation(cfg)
    rng = np.random.default_rng(3)
    F = np.eye(dim) + 0.15 * rng.standard_normal((sim.n, dim, dim))
    assert np.all(np.linalg.det(F) > 0.2)
    sim.set_particles(F=F)
    return sim, F


@pytest.mark.parametrize("dim", [pytest.param(1, marks=pytest.mark.slow), 2])
def test_every_model_gives_its_out_of_plane_stress(dim):
    sim, F = four_material_sim(dim)
    p = sim.particles()
    s3 = p["stress3"]
    models = list(MATERIALS)
    np.testing.assert_array_equal(s3[:, :dim, :dim], p["stress"])     # the in-plane block is the stress used
    for q in range(sim.n):
        model = models[p["body"][q]]
        F3 = np.eye(3)
        F3[:dim, :dim] = F[q]
        J = np.linalg.det(F3)
        for a in range(dim, 3):  # 2D: zz; 1D: the lateral yy and zz
            assert s3[q, a, a] == pytest.approx(fd_stress(model, F3, a), rel=1e-6, abs=1e-6 * E)
        closed = {"neo_hookean": LAM * np.log(J) / J, "fixed_corotated": LAM * (J - 1), "fluid": K * (J - 1),
                  "linear_elastic": LAM * (np.trace(F3) - 3) / J}[model]
        assert s3[q, 2, 2] == pytest.approx(closed, rel=1e-9, abs=1e-9 * E)
        off = s3[q].copy()
        off[:dim, :dim] = 0
        np.testing.assert_allclose(off, np.diag(np.diag(off)), atol=1e-12 * E)  # no out-of-plane shear
    if dim == 1:
        np.testing.assert_allclose(s3[:, 1, 1], s3[:, 2, 2], rtol=1e-12)  # uniaxial strain: equal lateral stresses


def test_2d_uniaxial_strain_writes_plane_strain_stress(tmp_path):
    """Linear elastic block in 2D uniaxial strain eps_xx = e: sigma_xx = (lam + 2 mu) e, sigma_yy = sigma_zz =
    lam e, so sigma_zz = nu (sigma_xx + sigma_yy) and von Mises = |sigma_xx - sigma_yy| = 2 mu e, not the
    plane-stress value sqrt(sxx^2 - sxx syy + syy^2). Checked on the VTU the runner's functions write."""
    cfg = make_cfg(2, dx=0.1, model="linear_elastic")
    sim = tm.Simulation(cfg)
    e = 1e-4  # small strain: the model's P F^T / J differs from the small-strain law by O(e)
    sim.set_particles(F=np.broadcast_to(np.diag([1 + e, 1.0]), (sim.n, 2, 2)))
    p = io.derived_fields(sim.particles(), sim.scene)
    io.write_vtu(tmp_path / "particles_000000.vtu", p, fields=["pressure"])
    back = io.read_vtu(tmp_path / "particles_000000.vtu", 2)
    s = back["stress3"]
    sxx, syy, szz = s[:, 0, 0], s[:, 1, 1], s[:, 2, 2]
    np.testing.assert_allclose(sxx, (LAM + 2 * MU) * e, rtol=3 * e)
    np.testing.assert_allclose(szz, NU * (sxx + syy), rtol=3 * e)
    full = np.sqrt(0.5 * ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2) + 3 * (s[:, 0, 1] ** 2 + s[:, 1, 0] ** 2) / 2)
    np.testing.assert_allclose(back["von_mises"], full, rtol=1e-12)
    np.testing.assert_allclose(back["von_mises"], 2 * MU * e, rtol=3 * e)
    plane_stress = np.sqrt(sxx**2 - sxx * syy + syy**2)
    assert np.all(plane_stress > 1.4 * back["von_mises"])  # the old formula read ~1.5x too high at nu = 0.3
    np.testing.assert_allclose(back["pressure"], -(sxx + syy + szz) / 3, rtol=1e-12)
    # the renderer colours by the same values, live and from the file
    np.testing.assert_allclose(field_values(sim.particles(), "von_mises", 2), back["von_mises"], rtol=1e-12)
    np.testing.assert_allclose(field_values(back | {"v": back["velocity"]}, "szz", 2), szz, rtol=1e-12)


def test_registry_is_the_config_field_list(tmp_path):
    """output.fields accepts exactly the registry's names; each is written when asked, with a unit and a meaning."""
    assert set(fields.REGISTRY) == set(config.output_fields())
    assert set(fields.ALWAYS) <= set(fields.REGISTRY)
    for f in fields.REGISTRY.values():
        assert f.meaning and f.unit is not None
    sim = tm.Simulation(make_cfg(2, dx=0.1))
    p = io.derived_fields(sim.particles(), sim.scene)
    data = io.point_data(p, config.output_fields())
    # no damage without a crack section or damage regions, no plastic strain without a plastic model
    assert set(data) == set(config.output_fields()) - {"damage", *fields.STATES}
    assert data["stress"].shape == (sim.n, 9) and data["F"].shape == (sim.n, 9)
    np.testing.assert_allclose(data["F"].reshape(-1, 3, 3)[:, 2, 2], 1.0)  # plane strain: F_zz = 1
    io.write_npz(tmp_path / "s.npz", p, config.output_fields())
    with np.load(tmp_path / "s.npz") as z:
        assert z["stress3"].shape == (sim.n, 3, 3) and z["stress"].shape == (sim.n, 2, 2)
