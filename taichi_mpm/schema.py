"""Building blocks of the config schema shared by config.py and the material registry (materials/): strict models,
numbers that refuse YAML booleans, and an error that knows its key path. No Taichi here: validating a config never
starts (or imports) Taichi."""
from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field


def _no_bool(v):
    if isinstance(v, bool):  # YAML `true` would otherwise pass as 1.0
        raise ValueError(f"expected a number, got {str(v).lower()}")
    return v


Real = Annotated[float, BeforeValidator(_no_bool)]
PositiveFloat = Annotated[float, BeforeValidator(_no_bool), Field(gt=0)]
Vec = list[Real]


class OneOf:
    """Annotated metadata of a string field whose values come from a registry when a config is validated (a value
    registered later is accepted; its BeforeValidator checks): `values()` lists them for the config reference."""

    def __init__(self, values):
        self.values = values


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=False, allow_inf_nan=False)


class Located(ValueError):
    """A cross-field error that knows its key path."""

    def __init__(self, key, message):
        self.key = str(key)  # a YAML key may be a number or a boolean
        super().__init__(message)
