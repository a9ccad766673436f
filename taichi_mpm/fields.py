"""The per-particle output fields: one registry (name -> unit, meaning, how computed) that config validation
(output.fields, output.render.color_by), the VTU/NPZ writers (io/files.py), the frame renderer (io/render.py) and
the interactive window (tools/gui.py) all read; `register` adds a field to every one of them.

Every field is a function of a particle dict: `Simulation.particles()` (x, v, F, C, stress, stress3, mass, volume,
body, damage, and the material models' states such as plastic_strain and Jp), optionally completed by `with_scene` (x0, material, interface, the scene's damage), or a state read
back from a VTU file. Stress-derived fields use the full 3x3 Cauchy stress `stress3`: 2D is plane strain, so
sigma_zz is not zero; 1D is uniaxial strain, so sigma_yy = sigma_zz is the lateral stress.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import materials as material_models

# written to every VTU snapshot (damage and the material states such as plastic_strain only when the state has them)
ALWAYS = ("velocity", "stress", "von_mises", "J", "body", "damage", *material_models.output_states())


@dataclass(frozen=True)
class Field:
    name: str
    unit: str               # SI; "1" for dimensionless, "" for labels and flags
    meaning: str
    compute: Callable[[dict], np.ndarray]
    kind: str = "scalar"    # scalar | vector (N, d) | tensor (N, 3, 3) | label (integer)
    needs: tuple = ()       # particle-dict keys it reads; the field is absent when one is missing


def stress3(p: dict) -> np.ndarray:
    """The full (N, 3, 3) Cauchy stress of a particle dict (`stress` itself in 3D)."""
    if "stress3" in p:
        return np.asarray(p["stress3"], float)
    s = np.asarray(p["stress"], float)
    if s.shape[1] == 3:
        return s
    raise KeyError("stress3: a 1D or 2D state needs its full 3x3 stress (Simulation.particles()['stress3']); "
                   "the out-of-plane stresses are not zero in plane strain or uniaxial strain")


def von_mises(stress: np.ndarray) -> np.ndarray:
    """von Mises stress sqrt(3/2 s:s), s the deviator of the (N, k, k) Cauchy stress with the components beyond k
    taken as zero: give it the full 3x3 stress (`stress3`) of 1D and 2D states."""
    s = np.asarray(stress, float)
    s3 = np.zeros((len(s), 3, 3))
    k = s.shape[1]
    s3[:, :k, :k] = s
    dev = s3 - np.trace(s3, axis1=1, axis2=2)[:, None, None] / 3.0 * np.eye(3)
    return np.sqrt(1.5 * np.einsum("nij,nij->n", dev, dev))


def pressure(stress: np.ndarray) -> np.ndarray:
    """Mean compressive stress -tr(sigma) / 3 of the full 3x3 stress."""
    return -np.trace(np.asarray(stress, float), axis1=1, axis2=2) / 3.0


def embed3(a: np.ndarray, fill: float) -> np.ndarray:
    """(N, d, d) -> (N, 3, 3): `fill` on the missing diagonal (1 for F: the held axes do not stretch; 0 for rates)."""
    a = np.asarray(a, float)
    n, d = a.shape[0], a.shape[1]
    out = np.broadcast_to(np.eye(3) * fill, (n, 3, 3)).copy()
    out[:, :d, :d] = a
    return out


KINDS = ("scalar", "vector", "tensor", "label")


def register(name: str, unit: str, meaning: str, compute: Callable[[dict], np.ndarray], kind: str = "scalar",
             needs=()) -> Field:
    """Add an output field: output.fields accepts it, the VTU and NPZ writers write it when asked, and a scalar or
    label field is a colour field of frames (output.render.color_by, --color-by) and of the window. `compute` maps
    a particle dict to (N,) values (vector: (N, d); tensor: (N, 3, 3)); `needs`: the particle-dict keys it reads
    (without one of them the field is absent). docs/architecture.md, "Adding an output field"."""
    if name in REGISTRY:
        raise ValueError(f"output field '{name}' is already registered")
    if kind not in KINDS:
        raise ValueError(f"output field kind '{kind}' is not one of {', '.join(KINDS)}")
    REGISTRY[name] = field = Field(name, unit, meaning, compute, kind, tuple(needs))
    return field


def unregister(name: str):
    """Remove a field added by `register` (the built-in fields stay)."""
    if name in BUILTIN:
        raise ValueError(f"'{name}' is a built-in output field")
    del REGISTRY[name]


_field = register
REGISTRY: dict[str, Field] = {}
_field("velocity", "m/s", "particle velocity, at the time `velocity_time` (leapfrog: half the last step before the "
       "output time)", lambda p: np.asarray(p["v"], float), "vector", ["v"])
_field("stress", "Pa", "full 3x3 Cauchy stress, tension positive (sigma_zz of plane strain in 2D, the lateral "
       "stress sigma_yy = sigma_zz of uniaxial strain in 1D)", stress3, "tensor", ["stress"])
_field("von_mises", "Pa", "von Mises stress sqrt(3/2 s:s) of the full 3x3 stress", lambda p: von_mises(stress3(p)),
       needs=["stress"])
_field("J", "1", "volume ratio det F (current / initial volume)", lambda p: np.linalg.det(np.asarray(p["F"], float)),
       needs=["F"])
_field("body", "", "index of the body (order of the config's bodies list)", lambda p: np.asarray(p["body"]), "label",
       ["body"])
_field("damage", "1", "damage d in [0, 1] (1: fully cracked); only in scenes with damage",
       lambda p: np.asarray(p["damage"], float), needs=["damage"])
_field("speed", "m/s", "particle speed |v|", lambda p: np.linalg.norm(np.asarray(p["v"], float), axis=1), needs=["v"])
_field("pressure", "Pa", "pressure -tr(sigma) / 3 of the full 3x3 stress (compression positive)",
       lambda p: pressure(stress3(p)), needs=["stress"])
_field("displacement", "m", "displacement x - X from the initial position", lambda p: np.asarray(p["x"]) - p["x0"],
       "vector", ["x", "x0"])
_field("F", "1", "deformation gradient (3x3; F_zz = 1 in 2D, F_yy = F_zz = 1 in 1D)",
       lambda p: embed3(p["F"], 1.0), "tensor", ["F"])
_field("C", "1/s or m^2/s", "the solver's affine matrix: APIC's B_p (quadratic, cubic, gimp) or the velocity gradient "
       "(linear basis with APIC, TPIC, and viscous materials under PIC or FLIP)", lambda p: embed3(p["C"], 0.0), "tensor", ["C"])
_field("mass", "kg", "particle mass", lambda p: np.asarray(p["mass"], float), needs=["mass"])
_field("volume", "m^3 (m^2 per m in 2D, m per m^2 in 1D)", "current particle volume J V0",
       lambda p: np.asarray(p["volume"], float), needs=["volume"])
_field("material", "", "index of the particle's material (materials numbered in order of first use by the bodies)",
       lambda p: np.asarray(p["material"]), "label", ["material"])
_field("interface", "", "1 for interface (surface) particles of bodies with interface: true, else 0",
       lambda p: np.asarray(p["interface"]).astype(np.int32), "label", ["interface"])


# the material models' per-particle state (taichi_mpm/materials/: plastic_strain, Jp, ...), present in scenes whose
# models have it
for _state in material_models.output_states().values():
    _field(_state.name, _state.unit, _state.meaning, lambda p, n=_state.name: np.asarray(p[n], float), needs=[_state.name])
STATES = tuple(material_models.output_states())  # in ALWAYS: written with every snapshot when present, like damage
BUILTIN = frozenset(REGISTRY)    # the fields above; `register` adds more


def with_scene(p: dict, scene) -> dict:
    """A particles() dict completed with what only the scene knows: x0, material, interface (and damage)."""
    out = dict(p)
    out["x0"] = np.asarray(scene.x)
    out["material"] = np.asarray(scene.material)
    out["interface"] = np.asarray(scene.interface)
    if "damage" not in out and getattr(scene, "damage", None) is not None and np.any(scene.damage):
        out["damage"] = np.asarray(scene.damage, float)
    return out


def available(p: dict, name: str) -> bool:
    return all(k in p for k in REGISTRY[name].needs)


def values(p: dict, name: str) -> np.ndarray:
    """The field `name` of a particle dict; values stored under that name (e.g. read from a file) come first."""
    if name in p and name not in ("stress", "F", "C"):  # tensors are stored as (N, d, d) in particle dicts
        return np.asarray(p[name])
    return REGISTRY[name].compute(p)


def label(name: str) -> str:
    f = REGISTRY[name]
    return f"{name.replace('_', ' ')} [{f.unit}]" if f.unit and f.unit != "1" else name.replace("_", " ")
