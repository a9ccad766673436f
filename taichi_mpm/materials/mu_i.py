"""The mu(I) rheology of dense granular flow (Jop, Forterre & Pouliquen 2006) with the granular-gas limit of
Dunatunga & Kamrin 2015: stress-free when the packing is looser than critical, the density tracked.

Friction coefficient against the inertial number I = gamma_dot d / sqrt(p / rho_s) (d: grain diameter, rho_s: grain
density = density / solid_fraction, gamma_dot = sqrt(2 dev D : dev D) the equivalent shear rate, p the Cauchy
pressure):

    mu(I) = mu_s + (mu_2 - mu_s) / (I0 / I + 1),     tau_bar = |dev sigma| / sqrt(2) = mu(I) p while flowing

(in simple shear tau_bar is the shear stress on the shear plane and p the normal stress on it, so tau / p = mu(I)).

The dense phase is split as mu(I) p = mu_s p + (mu(I) - mu_s) p:

- the rate-independent part is drucker_prager's return with `fit: simple_shear` at tan(phi) = mu_s, volume-
  preserving flow and the volume correction (materials/drucker_prager.py): elasticity quadratic in the Hencky
  strain (E, nu), yield tau_bar <= mu_s p. Its tension cut-off and volume correction are Dunatunga & Kamrin's
  granular gas: a packing looser than the one it started at (J_p > 1, the critical density rho_c = density) is
  stress-free (F_e a rotation) and compacts back at no stress before it bears load again; the particle's density
  is density / (det F_e J_p) (`Jp`, `volume`);
- the rate-dependent excess is a viscous stress along the deviatoric rate, applied while the particle is on the
  yield surface (tau_bar >= mu_s p of F_e, p > 0): sigma_ex = 2 eta dev D with
  eta = (mu(I) - mu_s) p / gamma_dot = (mu_2 - mu_s) d sqrt(rho_s p) / (I0 + I), finite as gamma_dot -> 0 and
  bounded by eta_max = (mu_2 - mu_s) d sqrt(rho_s max_pressure) / I0 (the cap, and the viscosity of the explicit
  time step's diffusion limit, `viscosity` of the solver). The Kirchhoff stress is J sigma_ex.

In steady flow (F_e steady, the plastic rate the whole rate) the two give tau_bar = mu(I) p exactly. The difference
from Dunatunga & Kamrin's return, which solves tau_bar_tr - G dt gamma_dot_p = mu(I(gamma_dot_p)) p for the plastic
rate of the step, is in transients: here the excess follows the total rate and is explicit (hence the viscous time
step); the return map of the model interface (`project(F, q)`) has no dt. The dissipation is the plastic work of the
mu_s return (project) plus the excess stress power sigma_ex : D (viscous_power).
"""
from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BeforeValidator, model_validator

from ..schema import Located, PositiveFloat, _no_bool
from .base import use_taichi, ElasticModuli, Funcs, Model, finish, param, register
from .drucker_prager import JP, DruckerPrager
from .von_mises import HELD_STRETCH, PLASTIC_STRAIN

# `ti` and the tensor helpers (materials/tensor.py): bound as globals by build() (base.use_taichi)
ti = embed3 = embed_held = top_left = rotation = eigh = principal_matrix = hencky = rescale_principal = None
hencky_energy = hencky_elasticity = None

Real = Annotated[float, BeforeValidator(_no_bool)]


def friction(inertial: float, mu_s: float, mu_2: float, i0: float) -> float:
    """mu(I) of Jop et al. 2006 (pure Python, the tests' reference)."""
    return mu_s + (mu_2 - mu_s) / (i0 / inertial + 1.0) if inertial > 0 else mu_s


@register
class MuI(Model):
    name = "mu_i"
    order = 15
    summary = "dense granular flow: mu(I) rheology (Jop et al. 2006), stress-free granular gas when loose " \
              "(Dunatunga & Kamrin 2015)"
    plastic = True
    damage = False

    class Params(ElasticModuli):
        model: Literal["mu_i"]
        mu_s: Real = param(..., "1", "static friction coefficient mu_s = tan(angle of repose), 0 < mu_s < mu_2 "
                                     "(Jop et al.'s glass beads: 0.38)", gt=0, lt=5)
        mu_2: Real = param(..., "1", "limiting friction coefficient at large I, mu_2 > mu_s (glass beads: 0.64)",
                           gt=0, lt=5)
        I0: Real = param(0.279, "1", "inertial number scale I0 of mu(I) (glass beads: 0.279)", gt=0, le=10)
        grain_diameter: Real = param(..., "m", "grain diameter d of the inertial number", gt=0, le=1)
        solid_fraction: Real = param(0.6, "1", "solid volume fraction phi of the packing: the grain density of "
                                               "I is density / phi", gt=0, le=1)
        max_pressure: PositiveFloat = param(..., "Pa", "the largest pressure of the flow (~ density g depth): caps "
                                                       "the excess viscosity (mu_2 - mu_s) d sqrt(rho_s p) / I0 "
                                                       "and sets the viscous time step")

        @model_validator(mode="after")
        def _mu2_above_mus(self):
            if self.mu_2 <= self.mu_s:
                raise Located("mu_2", f"mu_2 {self.mu_2:g} must exceed mu_s {self.mu_s:g}")
            return self

        @property
        def grain_density(self) -> float:
            return self.density / self.solid_fraction

        @property
        def viscosity(self) -> float:
            """eta_max: the excess viscosity's bound (the solver's viscous time step reads `viscosity`)."""
            return (self.mu_2 - self.mu_s) * self.grain_diameter * math.sqrt(
                self.grain_density * self.max_pressure) / self.I0

        def drucker_prager(self):
            """The rate-independent part: drucker_prager at tan(phi) = mu_s, simple_shear fit, volume correction."""
            return DruckerPrager.Params(model="drucker_prager", density=self.density, E=self.E, nu=self.nu,
                                        friction_angle=math.degrees(math.atan(self.mu_s)), fit="simple_shear",
                                        volume_correction=True)

    @classmethod
    def state(cls, dim):
        return (PLASTIC_STRAIN, JP) + ((HELD_STRETCH,) if dim < 3 else ())

    @classmethod
    def build(cls, m, dim, nq):
        base = DruckerPrager.build(m.drucker_prager(), dim, nq)
        use_taichi(globals())
        mu_s, dmu, i0 = float(m.mu_s), float(m.mu_2 - m.mu_s), float(m.I0)
        d, rho_s, eta_max = float(m.grain_diameter), float(m.grain_density), float(m.viscosity)
        tol = 1e-4 if ti.lang.impl.get_runtime().default_fp == ti.f32 else 1e-9
        JPS = 1   # state slot of J_p (state() above)
        elastic3, volume_ratio = base.kirchhoff3, base.volume_ratio

        @ti.func
        def excess(t, F, L, q):
            """The Kirchhoff excess stress J 2 eta dev D (3x3) of a flowing particle (t: its elastic stress, the
            3x3 Kirchhoff stress of F_e); zero off the yield surface and in the granular gas. The gas (J_p > 1, sand
            loosened at the apex) is stress-free: its p is round-off there and J (with J_p) can be huge, so J eta
            would turn that round-off into a stress."""
            p = -t.trace() / 3.0
            out = ti.Matrix.zero(float, 3, 3)
            if p > 0 and q[JPS] <= 1.0 + tol:
                s = t + p * ti.Matrix.identity(float, 3)
                if ti.sqrt(0.5 * s.norm_sqr()) >= (1.0 - tol) * mu_s * p:
                    L3 = embed3(L, 0.0)
                    D = 0.5 * (L3 + L3.transpose())
                    Dd = D - D.trace() / 3.0 * ti.Matrix.identity(float, 3)
                    J = volume_ratio(F, q)
                    pc = p / J                                         # Cauchy pressure
                    inertial = ti.sqrt(2.0 * Dd.norm_sqr()) * d * ti.sqrt(rho_s / pc)
                    eta = ti.min(dmu * d * ti.sqrt(rho_s * pc) / (i0 + inertial), eta_max)
                    out = 2.0 * J * eta * Dd
            return out

        @ti.func
        def kirchhoff3(F, L, q):
            t = elastic3(F, L, q)
            return t + excess(t, F, L, q)

        @ti.func
        def kirchhoff(F, L, q):
            return top_left(kirchhoff3(F, L, q), dim)

        @ti.func
        def viscous_power(F, L, q):
            return (excess(elastic3(F, L, q), F, L, q) * embed3(L, 0.0)).sum()   # tau_ex : D (tau_ex symmetric)

        return finish(Funcs(kirchhoff=kirchhoff, kirchhoff3=kirchhoff3, energy=base.energy, project=base.project,
                            volume_ratio=volume_ratio, viscous_power=viscous_power), m, cls)
