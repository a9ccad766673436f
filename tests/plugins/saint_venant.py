"""A material model from outside the package: Saint Venant-Kirchhoff, S = lam tr(E) I + 2 mu E with the Green strain
E = (F^T F - I) / 2, tau = F S F^T, psi = mu E:E + lam/2 tr(E)^2 (tests/test_plugin_material.py). One class: its
schema, its Taichi funcs (parameters as compile-time constants); the registry's defaults give kirchhoff3 (the
model at the held axes' F = 1) and J = det F."""
from typing import Literal

from taichi_mpm.materials import ElasticParams, Funcs, Model
from taichi_mpm.materials.base import finish


class SaintVenantKirchhoff(Model):
    name = "saint_venant_kirchhoff"
    summary = "Green strain, linear S(E) (a plug-in of the tests)"

    class Params(ElasticParams):
        model: Literal["saint_venant_kirchhoff"]

    @classmethod
    def build(cls, m, dim, nq):
        import taichi as ti
        mu, lam = float(m.mu), float(m.lam)

        @ti.func
        def green(F):
            return 0.5 * (F.transpose() @ F - ti.Matrix.identity(float, F.n))

        @ti.func
        def kirchhoff(F, L, q):
            E = green(F)
            S = lam * E.trace() * ti.Matrix.identity(float, F.n) + 2.0 * mu * E
            return F @ S @ F.transpose()

        @ti.func
        def energy(F, q):
            E = green(F)
            return mu * (E * E).sum() + 0.5 * lam * E.trace() ** 2

        return finish(Funcs(kirchhoff=kirchhoff, energy=energy), m, cls)
