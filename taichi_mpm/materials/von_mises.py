"""J2 plasticity at finite strain with isotropic linear hardening.

Multiplicative split F = F_e F_p; the solver's F field holds F_e. Elasticity is quadratic in the Hencky strain of
the elastic left stretch, eps = ln V_e (psi = mu |eps|^2 + lam/2 (tr eps)^2, tau = 2 mu eps + lam tr(eps) I), so
the return mapping is the small-strain radial return in principal logarithmic strains (Simo 1992; de Souza Neto,
Peric & Owen 2008, ch. 14): after the update F_e^trial = (I + dt grad v) F_e,

    s = 2 mu dev(eps_tr),  f = |s| - sqrt(2/3) (yield_stress + hardening alpha)
    f > 0:  dgamma = f / (2 mu + 2/3 hardening),  eps = eps_tr - dgamma s / |s|,  alpha += sqrt(2/3) dgamma

and F_e = Q diag(exp(eps - eps_tr)) Q^T F_e^trial (Q: principal directions of b_e). Plastic flow is isochoric
(det F_p = 1). alpha is the equivalent plastic strain, output `plastic_strain`. Stored energy: psi + hardening
alpha^2 / 2. Plastic dissipation (the energy balance's): the plastic work of the returned stress minus the hardening
energy stored, tau : deps_p - d(H alpha^2 / 2) = yield_stress dalpha + H dalpha^2 / 2 per step. (The stored energy
the return releases, psi(eps_tr) - psi(eps), is larger by deps_p : C : deps_p / 2: energy the elastic trial step
never took from the motion, since the explicit step's stress power uses the stress at the start of the step.)
In 1D and 2D the particle is a 3D particle with held axes (uniaxial / plane strain): the elastic stretch of the
held axes changes by plastic flow and is kept per particle (`held_stretch`).
"""
from __future__ import annotations

import math
from typing import Literal

from .base import use_taichi, ElasticParams, Funcs, Model, NonNegative, State, finish, param, register
from ..schema import PositiveFloat

PLASTIC_STRAIN = State("plastic_strain", 0.0, "1", "equivalent plastic strain: the integral of sqrt(2/3 dep:dep) "
                                                   "(von_mises, drucker_prager, snow)")
HELD_STRETCH = State("held_stretch", 1.0, "1", "elastic stretch of the held axes (z in 2D, y and z in 1D) of a "
                                               "plastic model", output=False)

# `ti` and the tensor helpers (materials/tensor.py): bound as globals by build() (base.use_taichi)
ti = embed3 = embed_held = top_left = rotation = eigh = principal_matrix = hencky = rescale_principal = None
hencky_energy = hencky_elasticity = None


@register
class VonMises(Model):
    name = "von_mises"
    order = 10
    summary = "J2 plasticity, linear isotropic hardening"
    plastic = True

    class Params(ElasticParams):
        model: Literal["von_mises"]
        yield_stress: PositiveFloat = param(..., "Pa", "initial uniaxial yield stress sigma_y")
        hardening: NonNegative = param(0.0, "Pa", "linear isotropic hardening modulus H: the yield stress is "
                                                  "sigma_y + H alpha (alpha: equivalent plastic strain); uniaxial "
                                                  "plastic slope E H / (E + H)")

    @classmethod
    def state(cls, dim):
        return (PLASTIC_STRAIN,) + ((HELD_STRETCH,) if dim < 3 else ())

    @classmethod
    def build(cls, m, dim, nq):
        use_taichi(globals())


        mu, lam = float(m.mu), float(m.lam)
        sy, H = float(m.yield_stress), float(m.hardening)
        r23 = math.sqrt(2.0 / 3.0)
        A, Z = 0, 1  # state slots: alpha, held stretch

        full, kirchhoff3, kirchhoff, elastic_energy = hencky_elasticity(mu, lam, dim, Z)

        @ti.func
        def energy(F, q):
            return elastic_energy(F, q) + 0.5 * H * q[A] * q[A]

        @ti.func
        def project(F, q):
            F3 = full(F, q)
            eps, Q = hencky(F3)
            e = eps - eps.sum() / 3.0
            en = e.norm()
            alpha = q[A]
            f = 2.0 * mu * en - r23 * (sy + H * alpha)
            Fn, qn, diss = F, q, 0.0
            if f > 0:
                dg = f / (2.0 * mu + 2.0 / 3.0 * H)
                dep = (dg / en) * e                        # plastic strain increment
                eps_n = eps - dep
                F3n = rescale_principal(F3, Q, eps, eps_n)
                alpha_n = alpha + r23 * dg
                qn[A] = alpha_n
                if ti.static(dim < 3):
                    qn[Z] = F3n[2, 2]
                Fn = top_left(F3n, dim)
                # plastic work of the returned stress minus the hardening energy stored: sigma_y dalpha + H dalpha^2 / 2
                diss = (2.0 * mu * eps_n + lam * eps_n.sum()).dot(dep) - 0.5 * H * (alpha_n - alpha) * (alpha_n + alpha)
            return Fn, qn, diss

        @ti.func
        def volume_ratio(F, q):
            return full(F, q).determinant()

        return finish(Funcs(kirchhoff=kirchhoff, kirchhoff3=kirchhoff3, energy=energy, project=project,
                            volume_ratio=volume_ratio), m, cls)
