"""Mohr-Coulomb plasticity with an exact return map in principal stress space (non-associated flow, tension
cut-off at the apex).

Elasticity as von_mises and drucker_prager: quadratic in the Hencky strain eps = ln V_e of the elastic left stretch
(the solver's F field holds F_e), tau = 2 mu eps + lam tr(eps) I, coaxial with b_e. With the principal Kirchhoff
stresses sorted s1 >= s2 >= s3 (tension positive) the yield function and the plastic potential are

    f = (s1 - s3) + (s1 + s3) sin(phi) - 2 c cos(phi) <= 0,    g = (s1 - s3) + (s1 + s3) sin(psi)

(a hexagonal pyramid with its apex at s1 = s2 = s3 = c cot(phi); psi <= phi the dilatancy angle, psi = phi
associated). In principal strains the elastic law is linear (D = lam 1 1^T + 2 mu I), so the return after the update
F_e^trial = (I + dt grad v) F_e is the small-strain one of de Souza Neto, Peric & Owen 2008, ch. 8 (box 8.5), in the
form of Clausen, Damkilde & Andersen 2006 (a_j: the yield planes' normals, n_j: their flow directions, both constant):

    face:   eps = eps_tr - dgamma n_main,  dgamma = f_main / (a_main . D n_main); valid while s1 >= s2 >= s3 holds
    edge:   eps = eps_tr - dgamma_a n_main - dgamma_b n_j (j: the face of s2 as the largest stress, the compression
            edge s1 = s2, or of s2 as the smallest, the extension edge s2 = s3): the 2x2 system f_main = f_j = 0;
            valid when both dgamma >= 0 and the stress stays on the edge's side of the apex
    apex:   eps = c cot(phi) / (3 K) (1, 1, 1): stress-free for c = 0 (the tension cut-off)

The three candidates are the KKT points of the sector s1 >= s2 >= s3 (for associated flow the return is the closest
point in the energy norm, which tests/test_mohr_coulomb.py checks by enumerating every active set), then
F_e = Q diag(exp(eps - eps_tr)) Q^T F_e^trial. In 2D (plane strain) and 1D (uniaxial strain) the held axes take part
in the return: their elastic stretch is state (`held_stretch`, as von_mises and drucker_prager), so the out-of-plane
stress is one of the three principal stresses. J_p (`Jp`) takes the volume the return adds (dilatancy, apex);
with `volume_correction` (psi = 0) sand loosened at the apex compacts back at no stress before it bears load, as in
drucker_prager (the trial strain measured from the packed state, eps_tr + ln(J_p) / 3 (1, 1, 1)),
`plastic_strain` accumulates sqrt(2/3) |d eps_p|, and the dissipation is the plastic work of the returned stress,
tau : d eps_p (>= 0 for psi <= phi). No tensile strength beyond the apex: the crack finder's damage does not apply.
"""
from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import model_validator

from ..schema import Located
from .base import use_taichi, ElasticModuli, Funcs, Model, NonNegative, finish, param, register
from .drucker_prager import JP, JP_MAX, VOLUME_CORRECTION, Angle
from .von_mises import HELD_STRETCH, PLASTIC_STRAIN

# `ti` and the tensor helpers (materials/tensor.py): bound as globals by build() (base.use_taichi)
ti = embed3 = embed_held = top_left = rotation = eigh = principal_matrix = hencky = rescale_principal = None
hencky_energy = hencky_elasticity = None


def planes(friction_angle: float, dilatancy: float, cohesion: float):
    """The sector s1 >= s2 >= s3 of the pyramid in principal stresses: the yield planes a_j . s = k and their flow
    directions n_j, j = main (s1, s3), compression partner (s2, s3) and extension partner (s1, s2); and the apex
    stress c cot(phi). Pure numpy (the tests evaluate f with it too)."""
    sf, sp = math.sin(math.radians(friction_angle)), math.sin(math.radians(dilatancy))
    a = {"main": (1 + sf, 0.0, -(1 - sf)), "comp": (0.0, 1 + sf, -(1 - sf)), "ext": (1 + sf, -(1 - sf), 0.0)}
    n = {"main": (1 + sp, 0.0, -(1 - sp)), "comp": (0.0, 1 + sp, -(1 - sp)), "ext": (1 + sp, -(1 - sp), 0.0)}
    phi = math.radians(friction_angle)
    k = 2.0 * cohesion * math.cos(phi)
    apex = cohesion / math.tan(phi)
    return {j: np.array(v) for j, v in a.items()}, {j: np.array(v) for j, v in n.items()}, k, apex


@register
class MohrCoulomb(Model):
    name = "mohr_coulomb"
    order = 13
    summary = "granular and geomaterials: Mohr-Coulomb, exact return to faces, edges and apex, dilatancy"
    plastic = True
    damage = False

    class Params(ElasticModuli):
        model: Literal["mohr_coulomb"]
        friction_angle: Angle = param(..., "deg", "Mohr-Coulomb friction angle phi (triaxial / plane-strain tests)",
                                      gt=0, lt=90)
        cohesion: NonNegative = param(0.0, "Pa", "cohesion c (0: dry sand, no tensile strength; the apex, where the "
                                                 "tension cut-off returns, is at the mean stress c cot(phi))")
        dilatancy: Angle = param(0.0, "deg", "dilatancy angle psi <= friction_angle of the plastic flow "
                                             "(friction_angle: associated; 0: volume-preserving flow)", ge=0, lt=90)
        volume_correction: bool = VOLUME_CORRECTION

        @model_validator(mode="after")
        def _dilatancy_below_friction(self):
            if self.dilatancy > self.friction_angle:
                raise Located("dilatancy", f"dilatancy {self.dilatancy:g} must not exceed friction_angle "
                                           f"{self.friction_angle:g}")
            return self

    @classmethod
    def state(cls, dim):
        return (PLASTIC_STRAIN, JP) + ((HELD_STRETCH,) if dim < 3 else ())

    @classmethod
    def build(cls, m, dim, nq):
        use_taichi(globals())

        mu, lam = float(m.mu), float(m.lam)
        K = lam + 2.0 * mu / 3.0
        a, n, k, apex = planes(m.friction_angle, m.dilatancy, m.cohesion)
        D = lam * np.ones((3, 3)) + 2.0 * mu * np.eye(3)
        Dn = {j: D @ v for j, v in n.items()}
        h_face = float(a["main"] @ Dn["main"])
        inv = {}
        for j in ("comp", "ext"):
            M = np.array([[a["main"] @ Dn["main"], a["main"] @ Dn[j]], [a[j] @ Dn["main"], a[j] @ Dn[j]]])
            inv[j] = [float(x) for x in np.linalg.inv(M).ravel()]
        am, ac, ae = ([float(x) for x in a[j]] for j in ("main", "comp", "ext"))
        nm, nc, ne = ([float(x) for x in n[j]] for j in ("main", "comp", "ext"))
        ic, ie = inv["comp"], inv["ext"]
        eps_apex = apex / (3.0 * K)
        r23 = math.sqrt(2.0 / 3.0)
        P, JPS, Z = 0, 1, 2  # state slots: plastic strain, J_p, held stretch

        full, kirchhoff3, kirchhoff, energy = hencky_elasticity(mu, lam, dim, Z)
        # as drucker_prager's: with dilatancy, J_p > 1 is also volume added under load, which must stay
        correct = bool(m.volume_correction) and m.dilatancy == 0.0

        @ti.func
        def sort3(eps):
            """eps sorted descending and the permutation S with S @ eps = sorted (S^T maps back)."""
            e = eps
            S = ti.Matrix.identity(float, 3)
            for ij in ti.static([(0, 1), (1, 2), (0, 1)]):
                i, j = ti.static(ij[0], ij[1])
                if e[i] < e[j]:
                    t = e[i]
                    e[i] = e[j]
                    e[j] = t
                    for c in ti.static(range(3)):
                        u = S[i, c]
                        S[i, c] = S[j, c]
                        S[j, c] = u
            return e, S

        @ti.func
        def principal_return(e):
            """The returned principal strains of the sorted trial strains e (f > 0)."""
            Am, Ac, Ae = ti.Vector(am), ti.Vector(ac), ti.Vector(ae)
            Nm, Nc, Ne = ti.Vector(nm), ti.Vector(nc), ti.Vector(ne)
            s = 2.0 * mu * e + lam * e.sum()
            fm = Am.dot(s) - k
            out = e - (fm / h_face) * Nm                              # face
            if not (out[0] >= out[1] and out[1] >= out[2]):
                fc = Ac.dot(s) - k                                    # compression edge s1 = s2
                g1 = ic[0] * fm + ic[1] * fc
                g2 = ic[2] * fm + ic[3] * fc
                on_c = e - g1 * Nm - g2 * Nc
                fe = Ae.dot(s) - k                                    # extension edge s2 = s3
                h1 = ie[0] * fm + ie[1] * fe
                h2 = ie[2] * fm + ie[3] * fe
                on_e = e - h1 * Nm - h2 * Ne
                out = ti.Vector([eps_apex, eps_apex, eps_apex])       # apex (tension cut-off)
                if g1 >= 0 and g2 >= 0 and on_c[1] >= on_c[2]:
                    out = on_c
                elif h1 >= 0 and h2 >= 0 and on_e[0] >= on_e[1]:
                    out = on_e
            return out

        @ti.func
        def project(F, q):
            F3 = full(F, q)
            eps, Q = hencky(F3)
            loose = 0.0
            if ti.static(correct):
                loose = ti.max(ti.log(q[JPS]), 0.0)   # volume the tension cut-off added: it closes before load
            eps_s = eps + loose / 3.0                 # the trial strain measured from the packed state
            e, S = sort3(eps_s)
            s = 2.0 * mu * e + lam * e.sum()
            f = ti.Vector(am).dot(s) - k                              # the main plane: the largest f
            Fn, qn, diss = F, q, 0.0
            if f > 0 or loose > 0:
                eps_n = eps_s                                         # loose sand compacted into load: elastic
                if f > 0:
                    eps_n = S.transpose() @ principal_return(e)
                F3n = rescale_principal(F3, Q, eps, eps_n)
                qn[P] = q[P] + r23 * (eps - eps_n).norm()
                qn[JPS] = ti.min(q[JPS] * ti.exp(eps.sum() - eps_n.sum()), JP_MAX)   # det F_e J_p is kept
                if ti.static(dim < 3):
                    qn[Z] = F3n[2, 2]
                Fn = top_left(F3n, dim)
                diss = (2.0 * mu * eps_n + lam * eps_n.sum()).dot(eps - eps_n)  # plastic work of the returned stress
            return Fn, qn, diss

        @ti.func
        def volume_ratio(F, q):
            return full(F, q).determinant() * q[JPS]

        funcs = finish(Funcs(kirchhoff=kirchhoff, kirchhoff3=kirchhoff3, energy=energy, project=project,
                             volume_ratio=volume_ratio), m, cls)
        funcs.extra["principal_return"] = principal_return
        return funcs
