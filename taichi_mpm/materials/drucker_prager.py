"""frictional granular material (sand), after Klar et al. 2016, "Drucker-Prager elastoplasticity for
sand animation" (ACM TOG 35(4), SIGGRAPH), with cohesion and optional dilatancy.

Elasticity as von_mises: quadratic in the Hencky strain eps = ln V_e of the elastic left stretch (the solver's F
field holds F_e). The yield surface in Kirchhoff stress (tension positive) is the cone

    f(tau) = |dev tau| + a tr(tau) - k <= 0,   a = sqrt(2/3) 2 sin(phi) / (3 - sin(phi)),
                                              k = sqrt(2/3) 6 c cos(phi) / (3 - sin(phi))

(the Drucker-Prager cone through the compression meridian of Mohr-Coulomb with friction angle phi and cohesion c;
Klar's alpha is a, and k = 0 there; `fit: plane_strain` takes instead the cone with Mohr-Coulomb's limit loads in
plane strain, a weaker one: a = 0.236 against 0.327 at phi = 30 deg). The plastic potential has the dilatancy angle psi in place of phi
(b = sqrt(2/3) 2 sin(psi) / (3 - sin(psi)); psi = 0, the default, is Klar's volume-preserving flow). Return
mapping in principal Hencky strains, after the update (K = lam + 2 mu / 3):

    inside (f <= 0):       nothing changes
    cone:  dgamma = f / (2 mu + 9 K a b);  eps = eps_tr - dgamma (dev(eps_tr) / |dev(eps_tr)| + b I)
    apex (tension cut-off: the cone return would pass the apex, e.g. any tr(eps_tr) > 0 without cohesion):
           eps = k / (9 K a) (1, 1, 1)  (c = 0: eps = 0, F_e = the rotation of F_e^trial: Klar's case II)

`fit: simple_shear` takes the cone whose steady isochoric simple shear has shear stress = c + tan(phi) x normal
stress on the shear plane (a = sqrt(2) tan(phi) / 3, k = sqrt(2) c): phi is then the angle at which a slope stops
flowing, the angle of repose (the plane-strain fit's slopes stop at atan(sin phi)). `volume_correction: true`
(Tampubolon et al. 2017; psi = 0 only, where J_p - 1 is all loosening by the tension cut-off): the return starts
from eps_tr + ln(J_p) / 3 (1, 1, 1), the trial strain measured from the packed state, so loosened sand compacts at
no stress (apex, J_p falls) and bears load only past its packed volume (J_p = 1).

Klar's hardening of the friction angle is not modelled (phi is fixed). The equivalent plastic strain
(`plastic_strain`) accumulates sqrt(2/3) |d eps_p| and the plastic volume ratio J_p (`Jp`) the volume the
return mapping adds (apex projections, dilatancy): the particle's volume is V0 det(F_e) J_p. The plastic dissipation
is the plastic work of the returned stress, tau : deps_p (zero at the apex without cohesion: sand torn apart does no
work; >= 0 for dilatancy <= friction_angle). Sand carries no
tension beyond the apex, so the crack finder's Rankine damage does not apply (no tensile_strength key).
"""
from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BeforeValidator, model_validator

from ..schema import Located, _no_bool
from .base import use_taichi, ElasticModuli, Funcs, Model, NonNegative, State, finish, param, register
from .von_mises import HELD_STRETCH, PLASTIC_STRAIN

JP = State("Jp", 1.0, "1", "plastic volume ratio J_p = det F_p (drucker_prager, mohr_coulomb, mu_i: dilation and "
                           "tension cut-off, at most 1e6; snow: compaction below 1); the particle volume is V0 det(F_e) "
                           "J_p")
Angle = Annotated[float, BeforeValidator(_no_bool)]

def cone(angle_deg: float) -> float:
    """a (or b) of the cone for a friction (or dilatancy) angle in degrees."""
    s = math.sin(math.radians(angle_deg))
    return math.sqrt(2.0 / 3.0) * 2.0 * s / (3.0 - s)

# `ti` and the tensor helpers (materials/tensor.py): bound as globals by build() (base.use_taichi)
ti = embed3 = embed_held = top_left = rotation = eigh = principal_matrix = hencky = rescale_principal = None
hencky_energy = hencky_elasticity = None


# J_p's bound (drucker_prager, mohr_coulomb). A grain torn from the flow at the apex keeps, alone under APIC, the
# affine velocity it left with (its nodes carry v_p + C (x_i - x_p), and G2P returns the same gradient), so its
# stress-free volume grows by exp(dt tr(grad v)) every step: in a 2D silo (dx 0.5 mm, f32) a lone grain with
# tr(grad v) = 7400 / s went from J_p 4e7 to f32's overflow in 1 000 steps, and the run stopped on a non-finite
# value. Past a million times its packed volume a grain's J_p means nothing; bounded there, it stays finite.
JP_MAX = 1.0e6

# shared with mohr_coulomb: the granular gas of sand loosened by the tension cut-off
VOLUME_CORRECTION = param(
    False, "", "true: sand loosened by the tension cut-off (J_p > 1) compacts back to its packed volume at no stress "
               "before it bears load again (Tampubolon et al. 2017; with dilatancy 0 only); false: Klar et al.'s "
               "return, where the loosened volume stays")


@register
class DruckerPrager(Model):
    name = "drucker_prager"
    order = 11
    summary = "granular: friction angle, cohesion, dilatancy (Klar et al. 2016)"
    plastic = True
    damage = False

    class Params(ElasticModuli):
        model: Literal["drucker_prager"]
        friction_angle: Angle = param(..., "deg", "internal friction angle phi", gt=0, lt=90)
        cohesion: NonNegative = param(0.0, "Pa", "cohesion c (0: dry sand, no tensile strength)")
        dilatancy: Angle = param(0.0, "deg", "dilatancy angle psi <= friction_angle of the plastic "
                                             "flow (0: volume-preserving flow)", ge=0, lt=90)

        fit: Literal["compression", "plane_strain", "simple_shear"] = param(
            "compression", "", "how the cone matches Mohr-Coulomb of friction_angle and cohesion: compression (its "
                               "compression meridian, as Klar et al.), plane_strain (the same limit loads in plane "
                               "strain; a weaker cone, for 2D geomechanics) or simple_shear (shear stress = cohesion + "
                               "tan(friction_angle) x normal stress on the plane of a steady simple shear: a slope "
                               "flows above and stands below friction_angle, the angle of repose; mu(I)'s mu_s)")

        volume_correction: bool = VOLUME_CORRECTION

        @model_validator(mode="after")
        def _dilatancy_below_friction(self):
            if self.dilatancy > self.friction_angle:
                raise Located("dilatancy", f"dilatancy {self.dilatancy:g} must not exceed friction_angle "
                                           f"{self.friction_angle:g}")
            return self

        @property
        def cone(self) -> tuple[float, float, float]:
            """(a, k, b) of the yield cone |dev tau| + a tr(tau) <= k and of the plastic potential."""
            phi, psi = math.radians(self.friction_angle), math.radians(self.dilatancy)
            r = math.sqrt(2.0 / 3.0)
            if self.fit == "compression":
                return cone(self.friction_angle), r * 6.0 * self.cohesion * math.cos(phi) / (3.0 - math.sin(phi)), \
                    cone(self.dilatancy)
            if self.fit == "simple_shear":
                # isochoric steady simple shear (psi = 0) has dev tau pure shear: |dev tau| = sqrt(2) tau_xy and
                # tr(tau) = -3 p = 3 sigma_n, so f = 0 is tau_xy = c + tan(phi) sigma_n on the shear plane
                r2 = math.sqrt(2.0)
                return r2 * math.tan(phi) / 3.0, r2 * self.cohesion, r2 * math.tan(psi) / 3.0
            # plane strain (e.g. the Abaqus manual, "Matching Mohr-Coulomb in plane strain"): in p-q form
            # tan(beta) = sqrt(3) sin(phi) / sqrt(1 + sin(psi)^2 / 3), d = sqrt(3) c cos(phi) / sqrt(...), and
            # tan(psi_dp) = sqrt(3) sin(psi) / sqrt(...); |dev tau| = sqrt(2/3) q, tr(tau) = -3 p
            root = math.sqrt(1.0 + math.sin(psi) ** 2 / 3.0)
            tan_beta = math.sqrt(3.0) * math.sin(phi) / root
            d = math.sqrt(3.0) * self.cohesion * math.cos(phi) / root
            tan_psi = math.sqrt(3.0) * math.sin(psi) / root
            return r * tan_beta / 3.0, r * d, r * tan_psi / 3.0

    @classmethod
    def state(cls, dim):
        return (PLASTIC_STRAIN, JP) + ((HELD_STRETCH,) if dim < 3 else ())

    @classmethod
    def build(cls, m, dim, nq):
        use_taichi(globals())


        mu, lam = float(m.mu), float(m.lam)
        K = lam + 2.0 * mu / 3.0
        a, k, b = m.cone
        eps_apex = k / (9.0 * K * a)
        r23 = math.sqrt(2.0 / 3.0)
        P, JPS, Z = 0, 1, 2  # state slots: plastic strain, J_p, held stretch

        full, kirchhoff3, kirchhoff, energy = hencky_elasticity(mu, lam, dim, Z)
        # with dilatancy, J_p > 1 is also the volume shear dilation added under load, which must stay: the volume
        # correction would undo it, so it applies to volume-preserving flow only (all of J_p - 1 is then loosening)
        correct = bool(m.volume_correction) and b == 0.0

        @ti.func
        def project(F, q):
            F3 = full(F, q)
            eps, Q = hencky(F3)
            loose = 0.0
            if ti.static(correct):
                loose = ti.max(ti.log(q[JPS]), 0.0)   # volume the tension cut-off added: it closes before load
            eps_s = eps + loose / 3.0                 # the trial strain measured from the packed state
            tr = eps_s.sum()
            e = eps - eps.sum() / 3.0
            en = e.norm()
            f = 2.0 * mu * en + a * 3.0 * K * tr - k
            Fn, qn, diss = F, q, 0.0
            if f > 0 or loose > 0:
                dg = f / (2.0 * mu + 9.0 * K * a * b)
                eps_n = ti.Vector([eps_apex, eps_apex, eps_apex])   # apex (tension cut-off)
                if f <= 0:                                          # loose sand compacted into load: elastic
                    eps_n = eps_s
                elif 2.0 * mu * (en - dg) > 0:                      # the cone return stays on the cone
                    eps_n = eps_s - dg * (e / en + b)
                F3n = rescale_principal(F3, Q, eps, eps_n)
                qn[P] = q[P] + r23 * (eps - eps_n).norm()           # the equivalent plastic strain of the return
                qn[JPS] = ti.min(q[JPS] * ti.exp(eps.sum() - eps_n.sum()), JP_MAX)   # det F_e J_p is kept
                if ti.static(dim < 3):
                    qn[Z] = F3n[2, 2]
                Fn = top_left(F3n, dim)
                diss = (2.0 * mu * eps_n + lam * eps_n.sum()).dot(eps - eps_n)  # plastic work of the returned stress
            return Fn, qn, diss

        @ti.func
        def volume_ratio(F, q):
            return full(F, q).determinant() * q[JPS]

        return finish(Funcs(kirchhoff=kirchhoff, kirchhoff3=kirchhoff3, energy=energy, project=project,
                            volume_ratio=volume_ratio), m, cls)
