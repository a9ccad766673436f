"""Weakly compressible Newtonian fluid."""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BeforeValidator

from ..schema import PositiveFloat, _no_bool
from .base import use_taichi, Funcs, MaterialParams, Model, finish, param, register

# `ti` and the tensor helpers (materials/tensor.py): bound as globals by build() (base.use_taichi)
ti = embed3 = embed_held = top_left = rotation = eigh = principal_matrix = hencky = rescale_principal = None
hencky_energy = None


@register
class Fluid(Model):
    """Pressure K (1 - J), plus Newtonian viscosity: tau = K (J - 1) J I + J visc (L + L^T). The solver resets F to
    J^(1/d) I after every update (`fluid`), so a fluid keeps no shear memory."""
    name = "fluid"
    order = 3
    summary = "weakly compressible"
    fluid = True
    damage = False

    class Params(MaterialParams):
        model: Literal["fluid"]
        K: PositiveFloat = param(..., "Pa", "bulk modulus of a fluid (pressure K (1 - J))")
        viscosity: Annotated[float, BeforeValidator(_no_bool)] = param(0.0, "Pa s", "dynamic viscosity of a fluid",
                                                                       ge=0)
        @property
        def lam(self) -> float:
            return self.K

    @classmethod
    def build(cls, m, dim, nq):
        use_taichi(globals())

        K, visc = float(m.K), float(m.viscosity)

        @ti.func
        def kirchhoff(F, L, q):
            J = F.determinant()
            tau = K * (J - 1.0) * J * ti.Matrix.identity(float, F.n)
            if ti.static(visc > 0):
                tau += J * visc * (L + L.transpose())
            return tau

        @ti.func
        def energy(F, q):
            return 0.5 * K * (F.determinant() - 1.0) ** 2

        @ti.func
        def viscous_power(F, L, q):
            """tau_visc : L = J visc (L + L^T) : L per reference volume."""
            return F.determinant() * visc * ((L + L.transpose()) * L).sum()

        return finish(Funcs(kirchhoff=kirchhoff, energy=energy, viscous_power=viscous_power if visc > 0 else None),
                      m, cls)
