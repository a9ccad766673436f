"""Config schema (pydantic) and loading: YAML file or dict -> validated `Config`.

Errors name the dotted key path and, for files, the line of that key.
Unknown keys are errors everywhere (`extra="forbid"`).
"""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

import yaml
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, field_validator, model_validator

from .errors import ConfigError

PositiveFloat = Annotated[float, Field(gt=0)]
Vec = list[float]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=False)


# ---------------------------------------------------------------- shapes
class Box(Strict):
    type: Literal["box"]
    lower: Vec
    upper: Vec
    rotation: Optional[Union[float, Vec]] = None  # degrees: scalar in 2D, [rx, ry, rz] Euler in 3D

    @model_validator(mode="after")
    def _ordered(self):
        if len(self.lower) != len(self.upper):
            raise ValueError("lower and upper must have the same length")
        if any(u <= l for l, u in zip(self.lower, self.upper)):
            raise ValueError("upper must exceed lower on every axis")
        return self


class Sphere(Strict):
    type: Literal["sphere"]
    center: Vec
    radius: PositiveFloat


class Ring(Strict):
    type: Literal["ring"]
    center: Vec
    inner_radius: Annotated[float, Field(ge=0)]
    outer_radius: PositiveFloat

    @model_validator(mode="after")
    def _radii(self):
        if self.inner_radius >= self.outer_radius:
            raise ValueError("inner_radius must be smaller than outer_radius")
        return self


class Cylinder(Strict):
    type: Literal["cylinder"]
    center: Vec
    radius: PositiveFloat
    height: PositiveFloat
    axis: Literal["x", "y", "z"] = "y"
    rotation: Optional[Union[float, Vec]] = None


class Mesh(Strict):
    type: Literal["mesh"]
    file: str
    scale: Union[float, Vec] = 1.0
    translate: Optional[Vec] = None


Shape = Annotated[Union[Box, Sphere, Ring, Cylinder, Mesh], Field(discriminator="type")]


# ---------------------------------------------------------------- sections
class Boundaries(Strict):
    default: Literal["slip", "sticky", "free"] = "slip"
    x_min: Optional[Literal["slip", "sticky", "free"]] = None
    x_max: Optional[Literal["slip", "sticky", "free"]] = None
    y_min: Optional[Literal["slip", "sticky", "free"]] = None
    y_max: Optional[Literal["slip", "sticky", "free"]] = None
    z_min: Optional[Literal["slip", "sticky", "free"]] = None
    z_max: Optional[Literal["slip", "sticky", "free"]] = None

    def face(self, axis: int, side: int) -> str:
        v = getattr(self, f"{'xyz'[axis]}_{'min' if side == 0 else 'max'}")
        return v if v is not None else self.default


class Domain(Strict):
    lower: Vec
    upper: Vec
    dx: PositiveFloat
    sparse: bool = True
    boundaries: Boundaries = Boundaries()


class Solver(Strict):
    basis: Literal["linear", "gimp", "quadratic", "cubic"] = "quadratic"
    transfer: Literal["pic", "flip", "apic"] = "apic"
    update: Literal["usl", "musl"] = "usl"
    flip_blend: Annotated[float, Field(ge=0, le=1)] = 0.99
    gimp_domain: Literal["uniform", "deforming"] = "uniform"
    cfl: PositiveFloat = 0.4
    dt: Optional[PositiveFloat] = None
    end_time: PositiveFloat
    gravity: Optional[Vec] = None
    max_steps: Optional[Annotated[int, Field(gt=0)]] = None


class Crack(Strict):
    threshold: float = 0.0
    kernel_radius: PositiveFloat = 2.0
    contact_in_compression: bool = True
    damage_threshold: Annotated[float, Field(ge=0, le=1)] = 0.5
    gradient_threshold: Annotated[float, Field(ge=0)] = 0.1


class Material(Strict):
    model: Literal["linear_elastic", "neo_hookean", "fixed_corotated", "fluid"]
    density: PositiveFloat
    E: Optional[PositiveFloat] = None
    nu: Annotated[float, Field(ge=0, lt=0.5)] = 0.3
    K: Optional[PositiveFloat] = None
    viscosity: Annotated[float, Field(ge=0)] = 0.0
    # damage law (crack growth); unused unless the scene has a crack section
    tensile_strength: Optional[PositiveFloat] = None
    fracture_energy: Optional[PositiveFloat] = None

    @model_validator(mode="after")
    def _moduli(self):
        if self.model == "fluid":
            if self.K is None:
                raise ValueError("a fluid needs a bulk modulus K")
        elif self.E is None:
            raise ValueError(f"model {self.model} needs Young's modulus E")
        return self

    @property
    def mu(self) -> float:
        return 0.0 if self.model == "fluid" else self.E / (2 * (1 + self.nu))

    @property
    def lam(self) -> float:
        if self.model == "fluid":
            return self.K
        return self.E * self.nu / ((1 + self.nu) * (1 - 2 * self.nu))


class DamageRegion(Strict):
    shape: Shape
    value: Annotated[float, Field(ge=0, le=1)] = 1.0


class Body(Strict):
    name: Optional[str] = None
    shape: Shape
    material: str
    particles_per_cell: Annotated[int, Field(gt=0)] = 2
    placement: Literal["regular", "jittered"] = "regular"
    velocity: Optional[Vec] = None
    angular_velocity: Optional[Union[float, Vec]] = None
    interface: bool = False
    damage_regions: list[DamageRegion] = []


class Render(Strict):
    color_by: str = "speed"
    size: list[Annotated[int, Field(gt=0)]] = [960, 720]
    camera: str = "iso"
    point_size: Optional[PositiveFloat] = None
    colormap: str = "viridis"
    clim: Optional[list[float]] = None


class Output(Strict):
    dir: str = "runs/{name}"
    every: PositiveFloat = 0.01
    formats: list[Literal["vtu", "npz", "png", "mp4", "gif"]] = ["vtu", "png"]
    fields: list[str] = ["velocity", "stress"]
    render: Render = Render()


class Config(Strict):
    name: str
    dim: Literal[1, 2, 3] = 3
    precision: Literal["f32", "f64"] = "f32"
    arch: Literal["auto", "cpu", "cuda", "vulkan", "metal"] = "auto"
    domain: Domain
    solver: Solver
    crack: Optional[Crack] = None
    materials: dict[str, Material]
    bodies: Annotated[list[Body], Field(min_length=1)]
    output: Output = Output()
    _source: Optional[str] = PrivateAttr(None)  # the YAML file it came from, for relative paths

    @field_validator("name")
    @classmethod
    def _name(cls, v):
        if not v or "/" in v:
            raise ValueError("name must be a non-empty string without '/'")
        return v

    @model_validator(mode="after")
    def _consistent(self):
        d = self.dim
        _need_len("domain.lower", self.domain.lower, d)
        _need_len("domain.upper", self.domain.upper, d)
        if any(u <= l for l, u in zip(self.domain.lower, self.domain.upper)):
            raise _Located("domain.upper", "must exceed domain.lower on every axis")
        if self.solver.gravity is not None:
            _need_len("solver.gravity", self.solver.gravity, d)
        for i, b in enumerate(self.bodies):
            key = f"bodies.{i}"
            if b.material not in self.materials:
                raise _Located(f"{key}.material", f"undefined material '{b.material}' (defined: {', '.join(self.materials) or 'none'})")
            if b.velocity is not None:
                _need_len(f"{key}.velocity", b.velocity, d)
            if b.angular_velocity is not None:
                if d == 1:
                    raise _Located(f"{key}.angular_velocity", "has no meaning in 1D")
                if d == 2 and not isinstance(b.angular_velocity, (int, float)):
                    raise _Located(f"{key}.angular_velocity", "must be a scalar in 2D")
                if d == 3:
                    _need_len(f"{key}.angular_velocity", b.angular_velocity, 3)
            _check_shape(f"{key}.shape", b.shape, d)
            for j, r in enumerate(b.damage_regions):
                _check_shape(f"{key}.damage_regions.{j}.shape", r.shape, d)
        if self.crack is None and any(b.interface or b.damage_regions for b in self.bodies):
            pass  # allowed: damage/interface flags are stored but only act with a crack section
        return self

    # resolved values --------------------------------------------------
    @property
    def gravity(self) -> list[float]:
        return self.solver.gravity or [0.0] * self.dim

    def to_dict(self) -> dict:
        return self.model_dump(mode="json", exclude_none=True)


class _Located(ValueError):
    """A cross-field error that knows its key path."""

    def __init__(self, key, message):
        self.key = key
        super().__init__(message)


def _need_len(key, v, d):
    if v is None or len(v) != d:
        raise _Located(key, f"must have {d} components for dim {d}, got {0 if v is None else len(v)}")


def _check_shape(key, s, d):
    for attr in ("center", "lower", "upper", "translate"):
        v = getattr(s, attr, None)
        if v is not None:
            _need_len(f"{key}.{attr}", v, d)
    if isinstance(s, Ring) and d == 1:
        raise _Located(f"{key}.type", "a ring needs dim 2 or 3")
    if isinstance(s, Cylinder) and d != 3:
        raise _Located(f"{key}.type", "a cylinder needs dim 3 (use box or sphere in 1D/2D)")


# ---------------------------------------------------------------- overrides
def parse_value(text: str) -> Any:
    """`--set` values are YAML scalars or flow lists: 0.01, cubic, [0,-2,0], true, null."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def apply_overrides(data: dict, overrides: dict[str, Any] | None) -> dict:
    """Set dotted keys (`solver.basis`, `bodies.0.velocity`) in a copy of `data`."""
    data = copy.deepcopy(data)
    for dotted, value in (overrides or {}).items():
        if isinstance(value, str):
            value = parse_value(value)
        parts = dotted.split(".")
        node = data
        for i, part in enumerate(parts):
            last = i == len(parts) - 1
            if isinstance(node, list):
                try:
                    idx = int(part)
                    node[idx]
                except (ValueError, IndexError):
                    raise ConfigError(f"no list item '{part}' (list has {len(node)} items)", key=".".join(parts[: i + 1]))
                if last:
                    node[idx] = value
                else:
                    node = node[idx]
            elif isinstance(node, dict):
                if last:
                    node[part] = value
                else:
                    if node.get(part) is None:
                        node[part] = {}
                    node = node[part]
            else:
                raise ConfigError("cannot set a key inside a scalar value", key=".".join(parts[:i]))
    return data


# ---------------------------------------------------------------- loading
def _line_index(node, path=(), out=None):
    """Map dotted key paths to 1-based line numbers from a composed YAML node tree."""
    out = {} if out is None else out
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            p = path + (str(k.value),)
            out[".".join(p)] = k.start_mark.line + 1
            _line_index(v, p, out)
    elif isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            p = path + (str(i),)
            out[".".join(p)] = v.start_mark.line + 1
            _line_index(v, p, out)
    return out


def read_yaml(path) -> tuple[dict, dict]:
    """Return (data, line index) of a YAML file; ConfigError for a missing, empty or non-YAML file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    text = path.read_text()
    try:
        node = yaml.compose(text)
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        raise ConfigError(f"not valid YAML: {getattr(e, 'problem', e)}", file=path, line=mark.line + 1 if mark else None)
    if data is None:
        raise ConfigError("the file is empty", file=path)
    if not isinstance(data, dict):
        raise ConfigError("the top level must be a mapping of keys (name, dim, domain, ...)", file=path, line=1)
    return data, _line_index(node)


def _nearest_line(lines: dict, key: str):
    parts = key.split(".")
    while parts:
        k = ".".join(parts)
        if k in lines:
            return lines[k]
        parts.pop()
    return None


def _error_key(loc) -> str:
    # pydantic puts the discriminator tag in the location ("shape.box.lower"): drop it
    out = []
    for item in loc:
        if isinstance(item, str) and item in ("box", "sphere", "ring", "cylinder", "mesh") and out and out[-1] == "shape":
            continue
        out.append(str(item))
    return ".".join(out)


def validate(data: dict, lines: dict | None = None, file=None) -> Config:
    lines = lines or {}
    try:
        return Config.model_validate(data)
    except ValidationError as e:
        err = e.errors()[0]
        ctx_err = (err.get("ctx") or {}).get("error")
        if isinstance(ctx_err, _Located):
            key = ctx_err.key
            msg = str(ctx_err)
        else:
            key = _error_key(err["loc"])
            msg = err["msg"]
            if err["type"] == "extra_forbidden":
                msg = "unknown key"
            elif err["type"] == "missing":
                msg = "required key is missing"
            if "input" in err and err["type"] not in ("missing", "extra_forbidden") and not isinstance(err["input"], dict):
                msg += f" (got {err['input']!r})"
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        raise ConfigError(msg, key=key or None, line=_nearest_line(lines, key), file=file) from None


def load_config(source, overrides: dict[str, Any] | None = None) -> Config:
    """Load and validate a config from a YAML path, a dict or a `Config`; apply dotted overrides first."""
    if isinstance(source, Config):
        source = source.to_dict()
    if isinstance(source, dict):
        data, lines, file = source, {}, None
    else:
        data, lines = read_yaml(source)
        file = Path(source)
    data = apply_overrides(data, overrides)
    cfg = validate(data, lines, file)
    cfg._source = str(file) if file else None
    return cfg
