"""Constitutive models: each is a Kirchhoff stress tau(F) = P F^T and a strain energy density psi(F).

Adding a model means writing two `@ti.func`s and one registry line. The solver computes nodal
forces as f_i = -sum_p V0_p tau_p grad w_ip, which is -sum_p V0_p P_p grad_X w_ip.
`L` is the particle's velocity gradient (only fluids with viscosity read it).
"""

from dataclasses import dataclass
from typing import Callable

import numpy as np
import taichi as ti


@dataclass(frozen=True)
class Model:
    name: str
    kirchhoff: Callable   # @ti.func (F, L, mu, lam, visc) -> tau
    energy: Callable      # @ti.func (F, mu, lam) -> psi per reference volume
    fluid: bool = False   # F is reset to J^(1/d) I after each update (no shear memory)


MODELS: dict[str, Model] = {}


def register(name, fluid=False):
    def wrap(cls):
        MODELS[name] = Model(name, cls.kirchhoff, cls.energy, fluid)
        return cls
    return wrap


@ti.func
def rotation(F):
    """Rotation of the polar decomposition F = R S (1D: the identity)."""
    R = ti.Matrix.identity(float, F.n)
    if ti.static(F.n > 1):
        R, _ = ti.polar_decompose(F)
    return R


@register("linear_elastic")
class LinearElastic:
    """Small strain: sigma = lam tr(eps) I + 2 mu eps, eps = sym(F) - I, taken as P (verification model)."""

    @ti.func
    def kirchhoff(F, L, mu, lam, visc):
        I = ti.Matrix.identity(float, F.n)
        eps = 0.5 * (F + F.transpose()) - I
        return (lam * eps.trace() * I + 2.0 * mu * eps) @ F.transpose()

    @ti.func
    def energy(F, mu, lam):
        eps = 0.5 * (F + F.transpose()) - ti.Matrix.identity(float, F.n)
        return mu * (eps * eps).sum() + 0.5 * lam * eps.trace() ** 2


@register("neo_hookean")
class NeoHookean:
    """psi = mu/2 (tr(F^T F) - d) - mu ln J + lam/2 (ln J)^2."""

    @ti.func
    def kirchhoff(F, L, mu, lam, visc):
        J = F.determinant()
        return mu * (F @ F.transpose() - ti.Matrix.identity(float, F.n)) + lam * ti.log(J) * ti.Matrix.identity(float, F.n)

    @ti.func
    def energy(F, mu, lam):
        J = F.determinant()
        return 0.5 * mu * ((F * F).sum() - F.n) - mu * ti.log(J) + 0.5 * lam * ti.log(J) ** 2


@register("fixed_corotated")
class FixedCorotated:
    """psi = mu |F - R|^2 + lam/2 (J - 1)^2 (Stomakhin et al. 2012)."""

    @ti.func
    def kirchhoff(F, L, mu, lam, visc):
        J = F.determinant()
        R = rotation(F)
        return 2.0 * mu * (F - R) @ F.transpose() + lam * (J - 1.0) * J * ti.Matrix.identity(float, F.n)

    @ti.func
    def energy(F, mu, lam):
        J = F.determinant()
        D = F - rotation(F)
        return mu * (D * D).sum() + 0.5 * lam * (J - 1.0) ** 2


@register("fluid", fluid=True)
class Fluid:
    """Weakly compressible: pressure K (1 - J), plus Newtonian viscosity visc (L + L^T). `lam` holds K."""

    @ti.func
    def kirchhoff(F, L, mu, lam, visc):
        J = F.determinant()
        tau = lam * (J - 1.0) * J * ti.Matrix.identity(float, F.n)
        if visc > 0:
            tau += J * visc * (L + L.transpose())
        return tau

    @ti.func
    def energy(F, mu, lam):
        return 0.5 * lam * (F.determinant() - 1.0) ** 2


def wave_speed(mat) -> float:
    """P-wave speed sqrt((lam + 2 mu) / rho) (sqrt(K / rho) for a fluid), for the CFL time step."""
    return float(np.sqrt((mat.lam + 2 * mat.mu) / mat.density))
