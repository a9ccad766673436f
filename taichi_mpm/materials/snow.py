"""Stomakhin et al. 2013, "A material point method for snow simulation" (ACM TOG 32(4), SIGGRAPH).

Fixed-corotated elasticity of the elastic part F_e (the solver's F field) with moduli hardened by the plastic
volume change J_p = det F_p:  mu = mu0 h, lam = lam0 h,  h = exp(hardening (1 - J_p)) (capped at max_hardening),

    psi = mu |F_e - R_e|^2 + lam/2 (J_e - 1)^2

After the update the singular values of F_e are clamped to [1 - critical_compression, 1 + critical_stretch]; what
is clamped away moves into F_p (J_p *= prod(sigma_trial / sigma_clamped)). Snow compacts (J_p < 1) and hardens, and
breaks in tension (J_p > 1: softer). Dissipation (the energy balance's): the plastic work of the returned stress,
tau : ln(sigma_trial / sigma_clamped), plus the stored energy the change of h removes at fixed F_e; the second term
is negative when compaction hardens, so the model can create energy (it is not thermodynamically consistent), and
the balance counts that. In 2D and 1D the held axes keep stretch 1, inside the clamp, so the model
works in d dimensions directly. The crack finder's Rankine damage applies on top (tensile_strength).
"""
from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BeforeValidator

from .base import use_taichi, ElasticParams, Funcs, Model, NonNegative, finish, param, register
from .drucker_prager import JP
from .von_mises import PLASTIC_STRAIN
from ..schema import PositiveFloat, _no_bool

# `ti` and the tensor helpers (materials/tensor.py): bound as globals by build() (base.use_taichi)
ti = embed3 = embed_held = top_left = rotation = eigh = principal_matrix = hencky = rescale_principal = None
hencky_energy = None


@register
class Snow(Model):
    name = "snow"
    order = 12
    summary = "Stomakhin et al. 2013"
    plastic = True

    class Params(ElasticParams):
        model: Literal["snow"]
        critical_compression: PositiveFloat = param(2.5e-2, "1", "theta_c, singular values of F_e stay >= 1 - "
                                                                 "theta_c", lt=1)
        critical_stretch: PositiveFloat = param(7.5e-3, "1", "theta_s, singular values of F_e stay <= 1 + theta_s")
        hardening: NonNegative = param(10.0, "1", "hardening coefficient xi of h = exp(xi (1 - J_p))")
        max_hardening: Annotated[float, BeforeValidator(_no_bool)] = param(10.0, "1", "cap of the hardening factor h (the CFL rule takes the "
                                                        "wave speed of the stiffest snow, sqrt(max_hardening) x)",
                                             ge=1)

    @classmethod
    def state(cls, dim):
        return (JP, PLASTIC_STRAIN)

    @classmethod
    def wave_speed(cls, m) -> float:
        return float(math.sqrt(m.max_hardening * m.modulus / m.density))

    @classmethod
    def build(cls, m, dim, nq):
        use_taichi(globals())


        mu0, lam0 = float(m.mu), float(m.lam)
        lo, hi = 1.0 - float(m.critical_compression), 1.0 + float(m.critical_stretch)
        xi, hmax = float(m.hardening), float(m.max_hardening)
        r23 = math.sqrt(2.0 / 3.0)
        JPS, P = 0, 1  # state slots

        @ti.func
        def hard(q):
            return ti.min(ti.exp(xi * (1.0 - q[JPS])), hmax)

        @ti.func
        def kirchhoff(F, L, q):
            h = hard(q)
            J = F.determinant()
            R = rotation(F)
            return 2.0 * mu0 * h * (F - R) @ F.transpose() + lam0 * h * (J - 1.0) * J * ti.Matrix.identity(float, F.n)

        @ti.func
        def energy(F, q):
            h = hard(q)
            J = F.determinant()
            D = F - rotation(F)
            return h * (mu0 * (D * D).sum() + 0.5 * lam0 * (J - 1.0) ** 2)

        @ti.func
        def singular(F):
            """Singular values of F and the left singular vectors (eigenvectors of F F^T)."""
            sig = ti.Vector.zero(float, F.n)
            Q = ti.Matrix.identity(float, F.n)
            if ti.static(F.n == 1):
                sig[0] = ti.abs(F[0, 0])
            else:
                b, Q = eigh(F @ F.transpose())
                for i in ti.static(range(F.n)):
                    sig[i] = ti.sqrt(ti.max(b[i], 0.0))
            return sig, Q

        @ti.func
        def project(F, q):
            sig, Q = singular(F)
            sc = ti.min(ti.max(sig, lo), hi)
            Fn, qn, diss = F, q, 0.0
            if (sc != sig).any():
                Fn = principal_matrix(Q, sc / sig) @ F
                ratio = sig / sc
                jp = q[JPS]
                for i in ti.static(range(F.n)):
                    jp *= ratio[i]
                qn[JPS] = jp
                qn[P] = q[P] + r23 * ti.log(ratio).norm()
                # plastic work of the returned stress (coaxial: tau : Q diag(ln(sigma_tr / sigma_c)) Q^T), plus the
                # stored energy the change of J_p removes at fixed F_e (negative when compaction hardens)
                diss = (kirchhoff(Fn, ti.Matrix.zero(float, F.n, F.n), qn) * principal_matrix(Q, ti.log(ratio))).sum() \
                    + energy(Fn, q) - energy(Fn, qn)
            return Fn, qn, diss

        @ti.func
        def volume_ratio(F, q):
            return F.determinant() * q[JPS]

        return finish(Funcs(kirchhoff=kirchhoff, energy=energy, project=project, volume_ratio=volume_ratio), m, cls)
