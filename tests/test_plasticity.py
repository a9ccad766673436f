"""Plastic models (materials/von_mises.py, drucker_prager.py, snow.py): return mappings driven by numpy through
small Taichi kernels (f64), the J2 uniaxial stress-strain curve against its closed form, and full MPM runs
(energy bookkeeping with plastic dissipation, momentum, checkpoints)."""
import math

import numpy as np
import pytest
import taichi as ti

import taichi_mpm as tm
from taichi_mpm.config import Material
from taichi_mpm.materials import MODELS

from conftest import make_cfg

E, NU = 1.0e6, 0.3
MU, LAM = E / (2 * (1 + NU)), E * NU / ((1 + NU) * (1 - 2 * NU))
K = LAM + 2 * MU / 3
PARAMS = {
    "von_mises": dict(yield_stress=1.0e4, hardening=2.0e5),
    "drucker_prager": dict(friction_angle=30.0, cohesion=2.0e3, dilatancy=10.0),
    "snow": dict(critical_compression=2.5e-2, critical_stretch=7.5e-3, hardening=10.0),
}
PLASTIC = list(PARAMS)


def material(model, **over):
    return Material(model=model, density=1000.0, E=E, nu=NU, **{**PARAMS[model], **over})


def _init():
    ti.init(arch=ti.cpu, default_fp=ti.f64, offline_cache=True, log_level=ti.ERROR)


def random_F(dim, n, seed=0, lo=-3.0, hi=-0.3):
    """Random rotations times stretches exp(s g), g ~ N(0, 1) per principal axis, s log-uniform in [10^lo, 10^hi]:
    from well inside the yield surface to far outside (stretches up to ~ e^1.5)."""
    rng = np.random.default_rng(seed)
    def rot():
        Q, R = np.linalg.qr(rng.normal(size=(dim, dim)))
        Q = Q * np.sign(np.diag(R))
        if np.linalg.det(Q) < 0:
            Q[:, 0] *= -1
        return Q
    scale = 10 ** rng.uniform(lo, hi, n)
    out = np.empty((n, dim, dim))
    for i in range(n):
        out[i] = rot() @ np.diag(np.exp(scale[i] * rng.normal(size=dim))) @ rot()
    return out


def run_projection(model, dim, F, q0, **over):
    """Each sample through the model's projection: (F_new, q_new, dissipated, tau3 trial, tau3 returned)."""
    _init()
    m = material(model, **over)
    cls = MODELS[model]
    nq = max(1, len(cls.state(dim)))
    funcs = cls.build(m, dim, nq)
    n = len(F)
    Fin = ti.Matrix.field(dim, dim, float, n)
    qin = ti.Vector.field(nq, float, n)
    Fout = ti.Matrix.field(dim, dim, float, n)
    qout = ti.Vector.field(nq, float, n)
    diss = ti.field(float, n)
    t_tr = ti.Matrix.field(3, 3, float, n)
    t_new = ti.Matrix.field(3, 3, float, n)
    Fin.from_numpy(F.reshape(n, 1) if dim == 1 else F)  # a 1x1 matrix field reads and writes (n, 1)
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


def initial_state(model, dim, n, rng):
    layout = MODELS[model].state(dim)
    q = np.array([[s.init for s in layout]] * n, float).reshape(n, max(1, len(layout)))
    names = [s.name for s in layout]
    if "plastic_strain" in names:  # hardened already: the yield stress depends on it
        q[:, names.index("plastic_strain")] = rng.uniform(0, 0.2, n)
    if "held_stretch" in names:    # earlier plastic flow out of the plane
        q[:, names.index("held_stretch")] = np.exp(rng.uniform(-0.02, 0.02, n))
    return q, names


def dev_norm(t):
    dev = t - np.trace(t, axis1=1, axis2=2)[:, None, None] / 3 * np.eye(3)
    return np.sqrt(np.einsum("nij,nij->n", dev, dev))


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("model", PLASTIC)
def test_return_mapping_lands_on_or_inside_the_yield_surface(model, dim):
    """1500 random F from far inside to far outside: the returned state is admissible to 1e-10 relative; a trial
    inside is returned unchanged (bit for bit); a trial outside lands on the surface; the dissipation is >= 0
    (von_mises, drucker_prager)."""
    n = 1500
    rng = np.random.default_rng(dim)
    F = random_F(dim, n, seed=dim)
    q, names = initial_state(model, dim, n, rng)
    Fn, qn, diss, t_tr, t_new = run_projection(model, dim, F, q)
    p = PARAMS[model]
    if model == "snow":
        # the admissible set: singular values of F_e in [1 - theta_c, 1 + theta_s]
        lo, hi = 1 - p["critical_compression"], 1 + p["critical_stretch"]
        s_tr, s_new = np.linalg.svd(F, compute_uv=False), np.linalg.svd(Fn, compute_uv=False)
        f_tr = np.maximum(s_tr.max(1) - hi, lo - s_tr.min(1))
        f_new = np.maximum(s_new.max(1) - hi, lo - s_new.min(1))
        on_surface = np.isclose(s_new, lo, rtol=0, atol=1e-12).any(1) | np.isclose(s_new, hi, rtol=0, atol=1e-12).any(1)
        scale = np.ones(n)
        Jp = qn[:, names.index("Jp")]
        assert np.allclose(Jp * np.linalg.det(Fn), np.linalg.det(F), rtol=1e-12)   # det F_e J_p is kept
    else:
        if model == "von_mises":
            alpha_tr, alpha_new = q[:, 0], qn[:, 0]
            k_tr = math.sqrt(2 / 3) * (p["yield_stress"] + p["hardening"] * alpha_tr)
            k_new = math.sqrt(2 / 3) * (p["yield_stress"] + p["hardening"] * alpha_new)
            f_tr = dev_norm(t_tr) - k_tr
            f_new = dev_norm(t_new) - k_new
            scale = k_new
        else:
            a, k, b = material(model).cone
            f_tr = dev_norm(t_tr) + a * np.trace(t_tr, axis1=1, axis2=2) - k
            f_new = dev_norm(t_new) + a * np.trace(t_new, axis1=1, axis2=2) - k
            scale = np.maximum(np.abs(t_tr).max((1, 2)), k)
            at_apex = dev_norm(t_new) <= 1e-10 * scale
        on_surface = np.abs(f_new) <= 1e-10 * scale
        assert (diss >= -1e-12 * scale).all()
    inside, outside = f_tr <= 0, f_tr > 0
    assert 0.1 * n < inside.sum() < 0.9 * n                           # both kinds are sampled
    assert (f_new <= 1e-10 * scale).all(), np.max(f_new / scale)      # admissible
    assert on_surface[outside].all()                                  # a yielded state is on the surface
    assert (Fn[inside] == F[inside]).all() and (qn[inside] == q[inside]).all() and (diss[inside] == 0).all()
    if model != "snow":
        assert (diss[outside] > 0).all() or model == "drucker_prager"
        if model == "drucker_prager":
            assert 0 < at_apex[outside].sum() < outside.sum()         # both the cone and the apex returns occur
