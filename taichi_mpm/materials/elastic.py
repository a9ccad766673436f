"""Path-independent elastic solids: linear_elastic (verification), neo_hookean, fixed_corotated. Each is a Kirchhoff
stress tau(F) = P F^T and a strain energy density psi(F) per reference volume, written for any dimension."""
from __future__ import annotations

from typing import Literal

from .base import use_taichi, ElasticParams, Funcs, Model, finish, register

# `ti` and the tensor helpers (materials/tensor.py): bound as globals by build() (base.use_taichi)
ti = embed3 = embed_held = top_left = rotation = eigh = principal_matrix = hencky = rescale_principal = None
hencky_energy = None


class _Elastic(Model):
    kirchhoff_of = None  # (mu, lam) -> (kirchhoff(F, L, q), energy(F, q))

    @classmethod
    def build(cls, m, dim, nq):
        kirchhoff, energy = cls.funcs(float(m.mu), float(m.lam))
        return finish(Funcs(kirchhoff=kirchhoff, energy=energy), m, cls)


@register
class LinearElastic(_Elastic):
    """Small strain: sigma = lam tr(eps) I + 2 mu eps, eps = sym(F) - I, taken as P (verification model)."""
    name = "linear_elastic"
    order = 0
    summary = "small strain"

    class Params(ElasticParams):
        model: Literal["linear_elastic"]

    @staticmethod
    def funcs(mu, lam):
        use_taichi(globals())

        @ti.func
        def kirchhoff(F, L, q):
            I = ti.Matrix.identity(float, F.n)
            eps = 0.5 * (F + F.transpose()) - I
            return (lam * eps.trace() * I + 2.0 * mu * eps) @ F.transpose()

        @ti.func
        def energy(F, q):
            eps = 0.5 * (F + F.transpose()) - ti.Matrix.identity(float, F.n)
            return mu * (eps * eps).sum() + 0.5 * lam * eps.trace() ** 2

        return kirchhoff, energy


@register
class NeoHookean(_Elastic):
    """psi = mu/2 (tr(F^T F) - d) - mu ln J + lam/2 (ln J)^2."""
    name = "neo_hookean"
    order = 1

    class Params(ElasticParams):
        model: Literal["neo_hookean"]

    @staticmethod
    def funcs(mu, lam):
        use_taichi(globals())

        @ti.func
        def kirchhoff(F, L, q):
            J = F.determinant()
            I = ti.Matrix.identity(float, F.n)
            return mu * (F @ F.transpose() - I) + lam * ti.log(J) * I

        @ti.func
        def energy(F, q):
            J = F.determinant()
            return 0.5 * mu * ((F * F).sum() - F.n) - mu * ti.log(J) + 0.5 * lam * ti.log(J) ** 2

        return kirchhoff, energy


@register
class FixedCorotated(_Elastic):
    """psi = mu |F - R|^2 + lam/2 (J - 1)^2 (Stomakhin et al. 2012)."""
    name = "fixed_corotated"
    order = 2

    class Params(ElasticParams):
        model: Literal["fixed_corotated"]

    @staticmethod
    def funcs(mu, lam):
        use_taichi(globals())


        @ti.func
        def kirchhoff(F, L, q):
            J = F.determinant()
            R = rotation(F)
            return 2.0 * mu * (F - R) @ F.transpose() + lam * (J - 1.0) * J * ti.Matrix.identity(float, F.n)

        @ti.func
        def energy(F, q):
            J = F.determinant()
            D = F - rotation(F)
            return mu * (D * D).sum() + 0.5 * lam * (J - 1.0) ** 2

        return kirchhoff, energy
