"""Modified Cam-Clay (Roscoe & Burland 1968) at finite strain: hyperelastic-plastic in the Hencky strain of the
elastic left stretch, after Borja & Tamagnini 1998 (with their alpha = 0: a constant shear modulus), in the
"ln v - ln p'" form of the critical-state lines (Butterfield 1979), where the compressibility indices lambda*, kappa*
are the slopes of ln(v) against ln(p'). Since ln det F = tr(eps_e) + ln J_p holds exactly for eps_e = ln V_e, every
critical-state relation of this model is exact at any strain, not only to first order.

Invariants (Kirchhoff stress tau, tension positive; p compression positive): p = -tr(tau) / 3, q = sqrt(3/2) |dev
tau|, eps_v = tr(eps_e), eps_s = sqrt(2/3) |dev eps_e|.

Elasticity (the energy psi = kappa* p0 exp(-eps_v / kappa*) + G |dev eps_e|^2 = kappa* p + G |dev eps_e|^2: the
work the skeleton would give back swelling to p = 0, so psi > 0 and the energy balance's scale is that of the
prestressed body; kappa* p0 at F_e = I):

    p = p0 exp(-eps_v / kappa*)                (bulk modulus K = p / kappa*: the swelling line ln v = -kappa* ln p')
    dev tau = 2 G dev eps_e,  q = 3 G eps_s

p0 (`initial_pressure`) is the mean effective stress of an undeformed particle (F_e = I): the body starts
isotropically consolidated at p0 (a state the solver's F = I at t = 0 gives), with preconsolidation pressure
p_c0 = OCR p0 (`ocr`, the isotropic overconsolidation ratio R_p of Wood 1990).

Yield surface (the ellipse of modified Cam-Clay, critical-state slope M) and associated flow:

    f = q^2 / M^2 + p (p - p_c) <= 0;   d eps_p = dgamma df/dtau:  d eps_v^p = -dgamma (2p - p_c),
                                                                    d eps_s^p = dgamma 2 q / M^2

Hardening with the plastic volume (the normal compression line ln v = -lambda* ln p' less the swelling line):

    p_c = p_c0 J_p^(-1 / (lambda* - kappa*)),  i.e. ln J_p = eps_v^p = -(lambda* - kappa*) ln(p_c / p_c0)

so the state is J_p alone (`Jp`, also the particle's plastic volume ratio). Return mapping in principal Hencky
strains after the update (as in Borja & Tamagnini 1998; Simo 1992): with x = -d eps_v^p (plastic compaction) and
the deviatoric strain scaled radially,

    p = p_tr exp(-x / kappa*),  p_c = p_c,n exp(x / (lambda* - kappa*)),  q = q_tr / (1 + 6 G dgamma / M^2)
    R1 = x - dgamma (2p - p_c) = 0,  R2 = f(p, q, p_c) = 0           (Newton in (x, dgamma), exact Jacobian)

and F_e = Q diag(exp(eps - eps_tr)) Q^T F_e^trial. The integration is exact in the sense that the discrete state
satisfies the hardening law and f = 0 identically (no sub-stepping error in p_c(J_p)); only the flow direction is
backward Euler. Dissipation: the plastic work of the returned stress, tau : d eps_p = dgamma p p_c >= 0 on f = 0.

Closed-form critical-state solutions (Wood 1990, ch. 6-7; in this ln v - ln p' form, exact), Lambda = 1 - kappa* /
lambda*, checked to round-off by tests/test_cam_clay.py on one material point:

- undrained (det F = 1: eps_v^e = -eps_v^p): kappa* ln(p / p0) + (lambda* - kappa*) ln(p_c / p_c0) = 0, so on the
  yield surface q = M p sqrt(p_c / p - 1) with p_c = p_c0 (p0 / p)^(kappa* / (lambda* - kappa*)); the elastic part
  of an over-consolidated path is p = p0; at the critical state (p_c = 2 p) p_f = p0 (OCR / 2)^Lambda, q_f = M p_f.
- drained (the lateral stress held at p0, dq/dp = 3): q_f = M p_f, p_f = 3 p0 / (3 - M), and the volume at the
  critical state ln J_f = -kappa* ln(p_f / p0) - (lambda* - kappa*) ln(2 p_f / p_c0).

In 2D (plane strain) and 1D (uniaxial strain) the held axes' elastic stretch is state (`held_stretch`, as
mohr_coulomb), so the out-of-plane stress takes part in p and q. The effective stress is the whole stress (a drained
skeleton, no pore pressure; an undrained response is the isochoric motion). Clay has no tensile effective stress:
p > 0 always (p -> 0 as the skeleton swells), so the crack finder's damage does not apply.

K0 geostatic start: `geostatic_state` (below) gives the elastic F and the state of particles at a given vertical
effective stress with sigma_h = K0 sigma_v, on (or, with its `ocr`, inside) the yield surface; a scene sets them
with `Simulation.get_state` / `set_state` (the config has no per-particle initial material state: `State.init` is
one constant per model).
"""
from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import BeforeValidator, model_validator

from ..schema import Located, PositiveFloat, _no_bool
from .base import use_taichi, Funcs, MaterialParams, Model, finish, param, register
from .drucker_prager import JP
from .von_mises import HELD_STRETCH, PLASTIC_STRAIN

# `ti` and the tensor helpers (materials/tensor.py): bound as globals by build() (base.use_taichi)
ti = embed3 = embed_held = top_left = rotation = eigh = principal_matrix = hencky = rescale_principal = None
hencky_energy = hencky_elasticity = elastic_full = None

Index = Annotated[float, BeforeValidator(_no_bool)]
EXP_LIMIT = 80.0       # exponents of the elastic law clamped to +-80 (f32 overflows at 88): strains of 80 kappa*
NEWTON_ITERATIONS = 30


@register
class CamClay(Model):
    name = "cam_clay"
    order = 14
    summary = "clays: modified Cam-Clay, critical state, hardening with plastic volume, OCR (Borja & Tamagnini 1998)"
    plastic = True
    damage = False

    class Params(MaterialParams):
        model: Literal["cam_clay"]
        shear_modulus: PositiveFloat = param(..., "Pa", "elastic shear modulus G (constant)")
        lambda_star: Index = param(..., "1", "modified compression index lambda*: slope of ln(v) against ln(p') on "
                                             "the normal compression line (~ lambda / v of Wood's v - ln p' lines), "
                                             "0 < lambda* < 1", gt=0, lt=1)
        kappa_star: Index = param(..., "1", "modified swelling index kappa* < lambda*: slope of ln(v) against "
                                            "ln(p') on unloading (bulk modulus p' / kappa*)", gt=0, lt=1)
        critical_state_slope: Annotated[float, BeforeValidator(_no_bool)] = param(
            ..., "1", "M = q / p' at the critical state (triaxial compression: 6 sin(phi) / (3 - sin(phi))), "
                      "0 < M < 3", gt=0, lt=3)
        initial_pressure: PositiveFloat = param(..., "Pa", "mean effective stress p0 of an undeformed particle "
                                                           "(F_e = I): the body starts isotropically consolidated at p0")
        ocr: Annotated[float, BeforeValidator(_no_bool)] = param(
            1.0, "1", "isotropic overconsolidation ratio p_c0 / p0 >= 1 (1: normally consolidated)", ge=1, le=1e6)

        @model_validator(mode="after")
        def _kappa_below_lambda(self):
            if self.kappa_star >= self.lambda_star:
                raise Located("kappa_star", f"kappa_star {self.kappa_star:g} must be below lambda_star "
                                            f"{self.lambda_star:g} (plastic compaction hardens at lambda* - kappa*)")
            return self

        @property
        def pressure_scale(self) -> float:
            """The pressure of the elastic moduli the CFL rule and the energy floor use: twice the initial p_c."""
            return 2.0 * self.ocr * self.initial_pressure

        @property
        def mu(self) -> float:
            return self.shear_modulus

        @property
        def lam(self) -> float:
            """K - 2 G / 3 at pressure_scale (K = p / kappa*)."""
            return self.pressure_scale / self.kappa_star - 2.0 * self.shear_modulus / 3.0

    @classmethod
    def state(cls, dim):
        return (PLASTIC_STRAIN, JP) + ((HELD_STRETCH,) if dim < 3 else ())

    @classmethod
    def build(cls, m, dim, nq):
        use_taichi(globals())
        G, ks, ld = float(m.shear_modulus), float(m.kappa_star), float(m.lambda_star - m.kappa_star)
        M2, p0 = float(m.critical_state_slope) ** 2, float(m.initial_pressure)
        pc0 = float(m.ocr * m.initial_pressure)
        r23, r32 = math.sqrt(2.0 / 3.0), math.sqrt(1.5)
        P, JPS, Z = 0, 1, 2  # state slots: plastic strain, J_p, held stretch

        full = elastic_full(dim, Z)   # the 3D elastic F (materials/tensor.py)

        @ti.func
        def principal_stress(eps):
            tr = eps.sum()
            p = p0 * ti.exp(ti.min(ti.max(-tr / ks, -EXP_LIMIT), EXP_LIMIT))
            return 2.0 * G * (eps - tr / 3.0) - p

        @ti.func
        def kirchhoff3(F, L, q):
            eps, Q = hencky(full(F, q))
            return principal_matrix(Q, principal_stress(eps))

        @ti.func
        def kirchhoff(F, L, q):
            return top_left(kirchhoff3(F, L, q), dim)

        @ti.func
        def energy(F, q):
            eps, Q = hencky(full(F, q))
            tr = eps.sum()
            e = eps - tr / 3.0
            return ks * p0 * ti.exp(ti.min(ti.max(-tr / ks, -EXP_LIMIT), EXP_LIMIT)) + G * e.dot(e)

        return_map = make_return_map(G, ks, ld, M2)

        @ti.func
        def project(F, q):
            F3 = full(F, q)
            eps, Q = hencky(F3)
            tr = eps.sum()
            e = eps - tr / 3.0
            p_tr = p0 * ti.exp(ti.min(ti.max(-tr / ks, -EXP_LIMIT), EXP_LIMIT))
            q_tr = r32 * 2.0 * G * e.norm()
            pc = pc0 * ti.exp(-ti.log(q[JPS]) / ld)
            Fn, qn, diss = F, q, 0.0
            if q_tr * q_tr / M2 + p_tr * (p_tr - pc) > 0:
                x, scale, p, pcn = return_map(p_tr, q_tr, pc)
                eps_n = scale * e + (tr + x) / 3.0
                F3n = rescale_principal(F3, Q, eps, eps_n)
                qn[P] = q[P] + r23 * (eps - eps_n).norm()
                qn[JPS] = q[JPS] * ti.exp(-x)                         # eps_v^p -= x; det F_e J_p is kept
                if ti.static(dim < 3):
                    qn[Z] = F3n[2, 2]
                Fn = top_left(F3n, dim)
                diss = principal_stress(eps_n).dot(eps - eps_n)       # plastic work of the returned stress
            return Fn, qn, diss

        @ti.func
        def volume_ratio(F, q):
            return full(F, q).determinant() * q[JPS]

        funcs = finish(Funcs(kirchhoff=kirchhoff, kirchhoff3=kirchhoff3, energy=energy, project=project,
                             volume_ratio=volume_ratio), m, cls)
        funcs.extra["return_map"] = return_map
        return funcs

    @classmethod
    def wave_speed(cls, m) -> float:
        """P-wave speed at pressure_scale, sqrt((K + 4 G / 3) / rho), K = p / kappa*: a clay loaded past twice its
        initial preconsolidation pressure is stiffer (lower solver.cfl then)."""
        return float(math.sqrt(m.modulus / m.density))


def make_return_map(G: float, ks: float, ld: float, M2: float):
    """The Taichi func (p_tr, q_tr, p_c,n) -> (x, q / q_tr, p, p_c) of a yielded trial: Newton in the plastic
    compaction x = -d eps_v^p and g = dgamma p_c,n (both dimensionless), R1 = x - g (2p - p_c) / p_c,n and
    R2 = f / p_c,n^2, each step's x limited to min(kappa*, lambda* - kappa*) (the exponentials change by e at
    most), dgamma kept >= 0. From x = g = 0 it converges quadratically for the small increments of an explicit step
    (3-6 iterations); 30 at most."""
    tol = 1e-5 if ti.lang.impl.get_runtime().default_fp == ti.f32 else 1e-13
    cap = min(ks, ld)

    @ti.func
    def return_map(p_tr, q_tr, pcn):
        x, g = 0.0, 0.0
        p, pc, scale = p_tr, pcn, 1.0
        c = 6.0 * G / (M2 * pcn)
        for _ in range(NEWTON_ITERATIONS):
            p = p_tr * ti.exp(-x / ks)
            pc = pcn * ti.exp(x / ld)
            scale = 1.0 / (1.0 + c * g)
            qq = q_tr * scale
            r1 = x - g * (2.0 * p - pc) / pcn
            r2 = (qq * qq / M2 + p * (p - pc)) / (pcn * pcn)
            if ti.abs(r1) < tol and ti.abs(r2) < tol:
                break
            dp, dpc = -p / ks, pc / ld
            j11 = 1.0 - g * (2.0 * dp - dpc) / pcn
            j12 = -(2.0 * p - pc) / pcn
            j21 = (dp * (2.0 * p - pc) - p * dpc) / (pcn * pcn)
            j22 = -2.0 * qq * qq * c * scale / (M2 * pcn * pcn)
            det = j11 * j22 - j12 * j21
            dx = -(j22 * r1 - j12 * r2) / det
            dg = -(-j21 * r1 + j11 * r2) / det
            x += ti.min(ti.max(dx, -cap), cap)
            g = ti.max(g + dg, 0.0)
        scale = 1.0 / (1.0 + c * g)            # of the last iterate (the loop's are of the one before)
        return x, scale, p_tr * ti.exp(-x / ks), pcn * ti.exp(x / ld)

    return return_map


def geostatic_state(m, dim: int, sigma_v, k0: float, ocr: float = 1.0):
    """K0 geostatic start of cam_clay particles (numpy, f64): for vertical effective stresses sigma_v (N,) > 0
    (compression positive; the vertical axis is the last one of dim) and sigma_h = k0 sigma_v on the other axes
    (the out-of-plane one included), the elastic F (N, dim, dim) of that stress and the material state (N, nq of
    the model): plastic strain 0, J_p with p_c = ocr x the p_c of the yield surface through the stress (ocr 1:
    normally consolidated, on the surface), the held stretch. Pass them to Simulation.set_state
    (`F`, `material_state`); the Kirchhoff stress of a particle is then sigma_v, sigma_h exactly at t = 0 (the
    solver's force is V0 tau: this is the stress in equilibrium with the particles where they are; the Cauchy
    output is tau / J)."""
    sv = np.asarray(sigma_v, dtype=np.float64)
    if not (np.all(sv > 0) and k0 > 0 and ocr >= 1):
        raise ValueError("geostatic_state needs sigma_v > 0, k0 > 0 and ocr >= 1")
    sh = k0 * sv
    p = (sv + 2.0 * sh) / 3.0
    qd = np.abs(sv - sh)
    eps_v = -m.kappa_star * np.log(p / m.initial_pressure)
    e_v = eps_v / 3.0 - (sv - p) / (2.0 * m.shear_modulus)    # dev tau = 2 G dev eps (tension positive)
    e_h = eps_v / 3.0 - (sh - p) / (2.0 * m.shear_modulus)
    F = np.zeros((len(sv), dim, dim))
    for a in range(dim - 1):
        F[:, a, a] = np.exp(e_h)
    F[:, dim - 1, dim - 1] = np.exp(e_v)
    pc = ocr * (p + qd ** 2 / (m.critical_state_slope ** 2 * p))
    jp = (pc / (m.ocr * m.initial_pressure)) ** -(m.lambda_star - m.kappa_star)
    q = np.zeros((len(sv), 3 if dim < 3 else 2))
    q[:, 1] = jp
    if dim < 3:
        q[:, 2] = np.exp(e_h)
    return F, q
