"""The material registry's parts: a model is one class registered once (`@register`), holding

- `Params`: its config schema, a pydantic model whose fields carry unit and meaning (`param(...)`); config.py
  validates `materials.<name>` against the union of every registered schema, picked by the `model` key;
- `state(dim)`: its per-particle history variables (`State`: name, initial value, unit, meaning), allocated by the
  solver only when a scene uses a model that has them, written to outputs and checkpoints by name;
- `build(params, dim, nq)`: its Taichi functions, with the parameters as compile-time constants (a `Funcs`):
  the Kirchhoff stress, the stored energy, and the projection of F after the update (return mapping);
- class flags the solver and diagnostics read (`fluid`, `plastic`, `damage`) and the wave speed for the CFL rule.

Nothing here imports Taichi: config validation and the CLI's checks stay Taichi-free. `build` imports it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated, Any, Callable, ClassVar, Optional

from pydantic import BeforeValidator, Field

from ..schema import PositiveFloat, Strict, _no_bool

NonNegative = Annotated[float, BeforeValidator(_no_bool), Field(ge=0)]


def param(default: Any = ..., unit: str = "", meaning: str = "", **constraints):
    """A schema field with its unit (SI; "1" dimensionless) and meaning, read by the config reference."""
    return Field(default, description=meaning, json_schema_extra={"unit": unit}, **constraints)


@dataclass(frozen=True)
class State:
    """One per-particle history variable of a model (a float in the solver's state vector)."""
    name: str
    init: float
    unit: str = "1"
    meaning: str = ""
    output: bool = True     # an output field (VTU/NPZ, render, GUI); internal ones only travel in checkpoints


# ---------------------------------------------------------------- schemas shared by several models
class MaterialParams(Strict):
    """Keys every material has."""
    model: str
    density: PositiveFloat = param(..., "kg/m^3", "initial mass density")

    @property
    def mu(self) -> float:
        return 0.0

    @property
    def lam(self) -> float:
        return 0.0

    @property
    def modulus(self) -> float:
        """P-wave modulus lam + 2 mu (K for a fluid): the stiffness of the CFL rule and of the energy round-off floor."""
        return self.lam + 2.0 * self.mu


class DamageParams(MaterialParams):
    """Rankine damage (crack finder, materials/damage.py): models where tension can open a crack."""
    tensile_strength: Optional[PositiveFloat] = param(
        None, "Pa", "Rankine damage: principal stress at which damage starts (needs a crack section); null: no damage law")
    fracture_energy: Optional[PositiveFloat] = param(
        None, "J/m^2", "energy per crack area of the linear softening (crack band); null: brittle")


class ElasticModuli(MaterialParams):
    """Isotropic elasticity from Young's modulus and Poisson's ratio."""
    E: PositiveFloat = param(..., "Pa", "Young's modulus")
    nu: Annotated[float, BeforeValidator(_no_bool)] = param(0.3, "1", "Poisson's ratio", ge=0, lt=0.5)

    @property
    def mu(self) -> float:
        return self.E / (2 * (1 + self.nu))

    @property
    def lam(self) -> float:
        return self.E * self.nu / ((1 + self.nu) * (1 - 2 * self.nu))

    @property
    def K(self) -> float:
        """Bulk modulus lam + 2 mu / 3."""
        return self.lam + 2.0 * self.mu / 3.0


class ElasticParams(DamageParams, ElasticModuli):
    """Elastic moduli and the damage keys."""


# ---------------------------------------------------------------- the Taichi side of a model
@dataclass
class Funcs:
    """A model's Taichi functions for one material (parameters baked in as constants). q is the particle's state
    vector (length nq >= 1, the scene's largest; a model reads its own slots 0.. in `state(dim)` order).

    kirchhoff(F, L, q) -> tau (d x d)       Kirchhoff stress tau = P F^T of the d-dimensional state
    kirchhoff3(F, L, q) -> tau (3 x 3)      the full 3x3 stress (plane strain / uniaxial strain axes included)
    energy(F, q) -> psi                     stored energy per reference volume (elastic + hardening)
    project(F, q) -> (F, q, dissipated)     after the F update: the return mapping; dissipated per reference volume
    volume_ratio(F, q) -> J                 current / initial volume (det F unless plastic flow changes volume)
    viscous_power(F, L, q) -> P             viscous dissipation per reference volume and time (viscous models)
    """
    kirchhoff: Callable
    energy: Callable
    kirchhoff3: Callable = None
    project: Optional[Callable] = None
    volume_ratio: Callable = None
    viscous_power: Optional[Callable] = None
    density: float = 0.0
    fluid: bool = False
    params: Any = None
    extra: dict = field(default_factory=dict)


# `ti` and the tensor helpers (materials/tensor.py): bound as globals by build() (base.use_taichi)
ti = embed3 = embed_held = top_left = rotation = eigh = principal_matrix = hencky = rescale_principal = None
hencky_energy = None

TENSOR_NAMES = ("embed3", "embed_held", "top_left", "rotation", "eigh", "principal_matrix", "hencky",
                "rescale_principal", "hencky_energy", "hencky_elasticity", "elastic_full")


def use_taichi(namespace: dict):
    """Bind `ti` and the tensor helpers (materials/tensor.py) as globals of a model module, called by its build():
    Taichi resolves the names a func uses through its module's globals (closure variables of a build() have been
    seen to go missing when one process builds many models), and importing Taichi only in build() keeps config
    validation Taichi-free."""
    import taichi

    import taichi_mpm.materials.tensor as tensor   # the submodule alone (`from . import` names the package)

    namespace["ti"] = taichi
    for name in TENSOR_NAMES:
        namespace[name] = getattr(tensor, name)


def finish(funcs: Funcs, params, model) -> Funcs:
    """Fill a Funcs' defaults: kirchhoff3 as the model's own stress at embed3(F, 1) (dimension-generic models),
    volume_ratio = det F."""
    use_taichi(globals())

    if funcs.kirchhoff3 is None:
        kirchhoff = funcs.kirchhoff

        @ti.func
        def kirchhoff3(F, L, q):
            return kirchhoff(embed3(F, 1.0), embed3(L, 0.0), q)

        funcs.kirchhoff3 = kirchhoff3
    if funcs.volume_ratio is None:
        @ti.func
        def volume_ratio(F, q):
            return F.determinant()

        funcs.volume_ratio = volume_ratio
    funcs.density = float(params.density)
    funcs.fluid = model.fluid
    funcs.params = params
    return funcs


class Model:
    """Base of every registered model (see the module docstring)."""
    name: ClassVar[str] = ""
    Params: ClassVar[type] = MaterialParams
    fluid: ClassVar[bool] = False     # F is reset to J^(1/d) I after each update (no shear memory)
    plastic: ClassVar[bool] = False   # project() moves F beyond the update: the F field holds the elastic part,
                                      # which no longer predicts the body's shape (the solver's fracture check skips it)
    damage: ClassVar[bool] = True     # the crack finder's Rankine damage applies (tensile_strength)
    summary: ClassVar[str] = ""       # one line for the config reference
    order: ClassVar[int] = 100        # place in listings (the config reference, docs)

    @classmethod
    def state(cls, dim: int) -> tuple[State, ...]:
        return ()

    @classmethod
    def wave_speed(cls, m) -> float:
        """P-wave speed sqrt(modulus / rho) for the CFL rule."""
        return float(math.sqrt(m.modulus / m.density))

    @classmethod
    def build(cls, m, dim: int, nq: int) -> Funcs:
        raise NotImplementedError


MODELS: dict[str, type[Model]] = {}


def register(cls):
    """Class decorator: add a model to the registry under cls.name (once)."""
    if not cls.name or cls.name in MODELS:
        raise ValueError(f"material model name {cls.name!r} is empty or registered twice")
    tag = cls.Params.model_fields.get("model")
    if tag is None or getattr(tag.annotation, "__args__", None) != (cls.name,):
        raise TypeError(f"{cls.__name__}.Params must declare `model: Literal[{cls.name!r}]`")
    cls.Params.__name__ = cls.Params.__qualname__ = f"{cls.__name__}Params"  # in reprs and messages
    MODELS[cls.name] = cls
    return cls


def unregister(name: str):
    """Remove a model registered from outside the package (a plug-in, a test); config.use_registered_materials()
    then stops accepting its name."""
    MODELS.pop(name)
