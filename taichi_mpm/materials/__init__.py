"""Constitutive models: a registry of self-contained units, one class per model (materials/base.py says what a unit
holds). Every module of this package that is not one of the shared ones (base, tensor, damage) is imported here,
and its `@register`ed classes join `MODELS`; so adding a model means adding one module (and its tests).

Config validation (config.py) takes the union of the models' schemas; the solver builds each scene material's
Taichi functions with `MODELS[name].build(params, dim, nq)`, allocates the per-particle state the scene's models
declare, and reads the flags (fluid, plastic); outputs (fields.py) and checkpoints pick up the state by name.

Every model is written for any dimension d, and a d-dimensional state is the 3D state with the missing axes held
fixed: 2D is plane strain (F_zz = 1), 1D is uniaxial strain (F_yy = F_zz = 1); the full 3x3 stress of a 1D or 2D
particle is the model's 3D stress (`kirchhoff3`). Plastic models keep the elastic stretch of the held axes as state.

The Taichi helpers (embed3, rotation, sym_eig, rankine_damage, degrade_tension) are re-exported lazily, so that
importing this package does not import Taichi.
"""
from __future__ import annotations

import importlib
import pkgutil
from typing import Annotated, Union

from pydantic import Field

from .base import MODELS, ElasticParams, Funcs, MaterialParams, Model, State, param, register, unregister  # noqa: F401
from .damage import rankine_params  # noqa: F401 (pure Python; the Taichi funcs are lazy below)

SHARED = ("base", "tensor", "damage")

for _info in pkgutil.iter_modules(__path__):
    if _info.name not in SHARED:
        importlib.import_module(f"{__name__}.{_info.name}")
_sorted = sorted(MODELS.items(), key=lambda kv: (kv[1].order, kv[0]))
MODELS.clear()
MODELS.update(_sorted)


def names() -> tuple[str, ...]:
    return tuple(MODELS)


def schema():
    """The config type of one material: the registered schemas, told apart by `model`."""
    variants = tuple(m.Params for m in MODELS.values())
    return Annotated[Union[variants], Field(discriminator="model")]


def model_of(params) -> type[Model]:
    return MODELS[params.model]


def wave_speed(mat) -> float:
    """P-wave speed of a material (sqrt((lam + 2 mu) / rho); sqrt(K / rho) for a fluid), for the CFL rule."""
    return MODELS[mat.model].wave_speed(mat)


def state_layout(materials, dim: int) -> list[tuple[State, ...]]:
    """Per material (in the scene's order): its state variables; slot j of the state vector is the j-th."""
    return [MODELS[m.model].state(dim) for m in materials]


def state_size(materials, dim: int) -> int:
    """Floats of per-particle state the scene needs: the largest model's (0: no state field at all)."""
    return max((len(s) for s in state_layout(materials, dim)), default=0)


def output_states() -> dict[str, State]:
    """Every output state variable of every registered model, by name (the first model's definition)."""
    out: dict[str, State] = {}
    for m in MODELS.values():
        for dim in (3, 2, 1):
            for s in m.state(dim):
                if s.output:
                    out.setdefault(s.name, s)
    return out


def key_descriptions(prefix: str = "materials.<name>.") -> dict[str, tuple[str, str]]:
    """Dotted key -> (unit, meaning) of every schema key, from the fields' metadata (the config reference). A key
    that several models define differently (hardening) gets each model's unit and meaning."""
    seen: dict[str, dict[tuple[str, str], list[str]]] = {}
    for name, m in MODELS.items():
        for key, f in m.Params.model_fields.items():
            if key != "model":
                extra = f.json_schema_extra or {}
                seen.setdefault(key, {}).setdefault((extra.get("unit", ""), f.description or ""), []).append(name)
    out = {prefix + "model": ("", "constitutive model: " + ", ".join(
        f"{name} ({m.summary})" if m.summary else name for name, m in MODELS.items()) + " (docs/materials.md)")}
    for key, variants in seen.items():
        if len(variants) == 1:
            out[prefix + key] = next(iter(variants))
        else:
            units = dict.fromkeys(u for u, _ in variants)
            unit = next(iter(units)) if len(units) == 1 else "; ".join(f"{u} ({', '.join(ms)})"
                                                                      for (u, _), ms in variants.items())
            out[prefix + key] = (unit, "; ".join(f"{', '.join(ms)}: {meaning}" for (_, meaning), ms in variants.items()))
    return out


_LAZY = {"embed3": "tensor", "rotation": "tensor", "sym_eig": "tensor", "POLAR_ITERATIONS": "tensor",
         "hencky": "tensor", "rankine_damage": "tensor", "degrade_tension": "tensor"}


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
