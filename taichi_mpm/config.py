"""Config schema (pydantic) and loading: YAML file or dict -> validated `Config`.

Errors name the dotted key path and, for files, the line of that key.
Unknown keys are errors everywhere (`extra="forbid"`).
"""
from __future__ import annotations

import copy
import math
import os
import reprlib
import re
import warnings
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

import numpy as np
import yaml
from pydantic import (AfterValidator, BaseModel, BeforeValidator, Field, PrivateAttr, TypeAdapter,
                      ValidationError, field_validator, model_serializer, model_validator)

from .errors import ConfigError
from .bases import registry as bases
from .bases.knots import knot_problem
from .expressions import largest_magnitude, parse as parse_expression

from .schema import Located as _Located, OneOf, PositiveFloat, Real, Strict, Vec, _no_bool  # noqa: F401 (re-exported)
from . import fields as field_registry
from . import geometry
from . import materials as material_models
from . import schemes as transfer_schemes
from .schemes import polypic

# the crack finder's node owners hold an interface body's side in 8 bits (extensions/crack/nodes.py MAX_SIDES)
MAX_INTERFACE_BODIES = 255


class ConfigWarning(UserWarning):
    """A setting that does nothing in this config but is legitimately there (docs/reliability.md)."""


SPACE, TIME = ("x", "y", "z"), ("t",)  # the variables of initial fields and of time functions


def _expression(variables, nullable=False):
    """A number, or an expression text of `variables` (taichi_mpm/expressions.py), checked when the config loads."""
    def check(v):
        if v is None and nullable:
            return v
        if isinstance(v, bool) or not isinstance(v, (int, float, str)):
            raise ValueError(f"must be a number or an expression of {', '.join(variables)} in quotes, "
                             f"got {_brief(v)}")
        if isinstance(v, str):
            try:
                parse_expression(v, variables)
            except ConfigError as e:
                raise ValueError(e.message) from None
            return v
        try:
            value = float(v)
        except OverflowError:
            value = math.inf
        if not math.isfinite(value):
            raise ValueError(f"must be a finite number, got {_brief(v)}")
        return value
    return check


SpaceExpr = Annotated[Union[float, str], BeforeValidator(_expression(SPACE))]   # number or expression of x, y, z
TimeExpr = Annotated[Union[float, str], BeforeValidator(_expression(TIME))]     # number or expression of t
FreeTimeExpr = Annotated[Optional[Union[float, str]], BeforeValidator(_expression(TIME, nullable=True))]

SHAPE_TYPES = ("box", "sphere", "ring", "cylinder", "mesh")


def output_fields() -> tuple[str, ...]:
    """The particle fields output.fields accepts: the output-field registry's (fields.REGISTRY), read when a config
    is validated, so a field registered later (fields.register) is accepted. velocity, stress, von_mises, J, body,
    damage and the material models' states are always written (the last ones when present)."""
    return tuple(field_registry.REGISTRY)


def _output_field(name: str) -> str:
    if name not in field_registry.REGISTRY:
        raise ValueError(f"unknown output field {name!r} (choose from {', '.join(output_fields())})")
    return name


OutputField = Annotated[str, AfterValidator(_output_field)]


MAX_NAME = 100
MAX_INDEX = 2**31 - 1   # Taichi indexes fields with i32 (budget.MAX_ELEMENTS): no count of cells may pass it
# samples of a nurbs map's checks: det J at DET_SAMPLES + 1 points per refined cell and axis up to FOLD_SAMPLES
# cells per axis (beyond, per span of the given net: the same map), its faces at 8 points per cell up to
# EDGE_SAMPLES; a check costs at most ~FOLD_SAMPLES^2 DET_SAMPLES^2 evaluations whatever `refine` says
FOLD_SAMPLES, EDGE_SAMPLES = 64, 8192
FOLD_SAMPLES_3D, FACE_SAMPLES_3D = 16, 256     # 3D: cells per axis sampled for folds; face points per axis

# magnitudes an input may have in each precision (0 aside): the solver squares them (norms, energies, the yield
# checks) and multiplies two of them (stress x volume / dx, mass x velocity), so they stay within the square root
# of the float's range; derived sizes (particle volume and mass) within its range over its epsilon
PRECISION_RANGE = {"f32": (1e-18, 1e18), "f64": (1e-150, 1e150)}
DERIVED_RANGE = {"f32": (1e-30, 1e30), "f64": (1e-290, 1e290)}
RANGE_UNITS = ("Pa", "kg/m^3", "Pa s", "J/m^2")   # material keys of these units are range checked


def plain_name(v) -> bool:
    """A name that is safe as one folder name: `runs/{name}` stays inside runs/ (not '.', '..', a path, a hidden
    folder, NUL or other control characters, nor longer than most file systems allow)."""
    return (isinstance(v, str) and 0 < len(v) <= MAX_NAME and not v.startswith((".", " ")) and not v.endswith(" ")
            and not any(c in "/\\" or not c.isprintable() for c in v))


# ---------------------------------------------------------------- shapes
class Box(Strict):
    type: Literal["box"]
    lower: Vec
    upper: Vec
    rotation: Optional[Union[Real, Vec]] = None  # degrees: scalar in 2D, [rx, ry, rz] Euler in 3D

    @model_validator(mode="after")
    def _ordered(self):
        if len(self.lower) != len(self.upper):
            raise _Located("upper", f"lower and upper must have the same length ({len(self.lower)} and "
                                    f"{len(self.upper)})")
        if any(u <= l for l, u in zip(self.lower, self.upper)):
            raise _Located("upper", "upper must exceed lower on every axis")
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
            raise _Located("inner_radius", "inner_radius must be smaller than outer_radius")
        return self


class Cylinder(Strict):
    type: Literal["cylinder"]
    center: Vec
    radius: PositiveFloat
    inner_radius: Annotated[float, Field(ge=0)] = 0.0   # > 0: a tube (a thick-walled cylinder)
    height: PositiveFloat
    axis: Literal["x", "y", "z"] = "y"
    rotation: Optional[Union[Real, Vec]] = None


class Mesh(Strict):
    type: Literal["mesh"]
    file: str
    scale: Union[PositiveFloat, list[PositiveFloat]] = 1.0
    translate: Optional[Vec] = None


Shape = Annotated[Union[Box, Sphere, Ring, Cylinder, Mesh], Field(discriminator="type")]


FACES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")


# ---------------------------------------------------------------- sections
# slip: no flow into the wall, may separate; roller: normal velocity zero both ways (bilateral);
# sticky: velocity zero; free: nothing. Slip and roller faces may carry Coulomb friction.
# velocity: the face's grid nodes get the prescribed velocity components (a moving wall or a driven lid).
WALL_TYPES = ("slip", "roller", "sticky", "free", "velocity")


class Face(Strict):
    """One wall: `slip` (a wall type alone), `{type: slip, friction: 0.3}` or `{type: velocity, velocity: [..]}`."""
    __shorthand__ = "type"  # a plain string stands for {type: <string>}
    type: Literal[WALL_TYPES]  # type: ignore[valid-type]  # the names, built at import
    friction: Annotated[float, BeforeValidator(_no_bool), Field(ge=0)] = 0.0
    # type velocity: per axis a number or an expression of t (m/s), null leaves that component free
    velocity: Optional[list[FreeTimeExpr]] = None
    # type velocity on a mapped grid's face: the face turns about +z through `center` (rad/s, a number or an
    # expression of t): its nodes get omega e_z x (P_i - center) in x and y, added to `velocity`'s
    angular_velocity: Optional[TimeExpr] = None
    center: Optional[Vec] = None

    @model_validator(mode="after")
    def _friction_needs_contact(self):
        if self.friction > 0 and self.type not in ("slip", "roller"):
            raise _Located("friction", f"Coulomb friction needs a slip or roller wall, not {self.type}")
        if self.type == "velocity" and self.velocity is None and self.angular_velocity is None:
            raise _Located("velocity", "a velocity wall needs `velocity`: one number, expression of t or null "
                                       "(free) per axis (or, on a mapped grid's face, `angular_velocity`)")
        for key in ("velocity", "angular_velocity", "center"):
            if self.type != "velocity" and getattr(self, key) is not None:
                raise _Located(key, f"only a wall of type velocity takes `{key}` (this one is {self.type})")
        if self.center is not None and self.angular_velocity is None:
            raise _Located("center", "`center` is the axis of `angular_velocity`: give both")
        return self

    @model_serializer(mode="wrap")
    def _short(self, handler):
        if self.friction == 0 and self.velocity is None and self.angular_velocity is None:
            return self.type
        out = handler(self)
        return {k: v for k, v in out.items() if v is not None and not (k == "friction" and v == 0)}


class Boundaries(Strict):
    default: Face = Face(type="slip")
    x_min: Optional[Face] = None
    x_max: Optional[Face] = None
    y_min: Optional[Face] = None
    y_max: Optional[Face] = None
    z_min: Optional[Face] = None
    z_max: Optional[Face] = None

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, data):
        """`y_min: slip` means `y_min: {type: slip}`."""
        if not isinstance(data, dict):
            return data
        out = dict(data)
        for k, v in data.items():
            if not isinstance(k, str):
                raise _Located(k, "keys must be text (a key here is a number, a boolean or null)")
            if isinstance(v, str):
                if v not in WALL_TYPES:
                    raise _Located(k, f"must be one of {', '.join(WALL_TYPES)} or {{type: ..., friction: ...}} "
                                      f"(got {v!r})")
                out[k] = {"type": v}
            elif v is not None and not isinstance(v, dict):
                raise _Located(k, f"must be one of {', '.join(WALL_TYPES)} or {{type: ..., friction: ...}} (got {v!r})")
        return out

    def _get(self, axis: int, side: int) -> Face:
        v = getattr(self, f"{'xyz'[axis]}_{'min' if side == 0 else 'max'}")
        return v if v is not None else self.default

    def face(self, axis: int, side: int) -> str:
        """The wall type of a face (side 0: min, 1: max)."""
        return self._get(axis, side).type

    def friction(self, axis: int, side: int) -> float:
        """The Coulomb friction coefficient of a face."""
        return self._get(axis, side).friction

    def velocity(self, axis: int, side: int):
        """The prescribed velocity of a velocity face (list: number, expression text or None per axis), else None."""
        return self._get(axis, side).velocity


class Knots(Strict):
    """Knot vectors per axis (m, from domain.lower to domain.upper, open: each end p + 1 times); an axis left out
    keeps the uniform open knot vector of domain.dx (taichi_mpm/bases/knots.py)."""
    x: Optional[list[Real]] = None
    y: Optional[list[Real]] = None
    z: Optional[list[Real]] = None


class AnnulusMap(Strict):
    """domain.map: a curvilinear grid on an annulus (or a sector of one), exact circles through NURBS weights
    (taichi_mpm/bases/mapped.py); the parameter faces are x_min / x_max (the straight edges at angle 0 and `angle`,
    none for a full ring) and y_min / y_max (the inner and outer circles)."""
    type: Literal["annulus"]
    inner_radius: PositiveFloat
    outer_radius: PositiveFloat
    angle: Annotated[float, Field(gt=0, le=360)] = 360.0    # degrees, counter-clockwise from +x
    center: Vec = [0.0, 0.0]
    # [along the angle, across the radius]; sized by the budget (budget.map_size: memory, limits.memory_gb,
    # limits.allow_large) before anything is built, at most what Taichi can index
    cells: list[Annotated[int, Field(gt=0, le=MAX_INDEX)]]


class CylinderMap(Strict):
    """domain.map (3D): a thick-walled cylinder (or a sector of one) about an axis along +z, exact circles through
    NURBS weights (taichi_mpm/bases/mapgeom.py, cylinder_net); the parameter faces are x_min / x_max (the flat
    ends of the sector at angle 0 and `angle`, none for a full cylinder), y_min / y_max (the inner and outer
    cylinders) and z_min / z_max (the flat ends at the base and at base + length)."""
    type: Literal["cylinder"]
    inner_radius: PositiveFloat
    outer_radius: PositiveFloat
    length: PositiveFloat                                   # m along +z from the centre
    angle: Annotated[float, Field(gt=0, le=360)] = 360.0    # degrees, counter-clockwise about +z from +x
    center: Vec = [0.0, 0.0, 0.0]                           # the axis' point at the base
    # [along the angle, across the wall, along the axis]; sized by the budget as the annulus' cells
    cells: list[Annotated[int, Field(gt=0, le=MAX_INDEX)]]


class ShellMap(Strict):
    """domain.map (3D): a spherical shell between two latitudes (the poles left out), exact spheres through NURBS
    weights (taichi_mpm/bases/mapgeom.py, shell_net); the parameter faces are x_min / x_max (the meridian planes
    at longitude 0 and `angle`, none for a full turn), y_min / y_max (the inner and outer spheres) and z_min /
    z_max (the cones at the lower and upper latitude)."""
    type: Literal["shell"]
    inner_radius: PositiveFloat
    outer_radius: PositiveFloat
    angle: Annotated[float, Field(gt=0, le=360)] = 360.0    # degrees of longitude, counter-clockwise about +z
    latitudes: list[Annotated[float, Field(gt=-90, lt=90)]] = [-60.0, 60.0]   # degrees, south to north
    center: Vec = [0.0, 0.0, 0.0]
    # [along the longitude, across the shell, along the latitude]
    cells: list[Annotated[int, Field(gt=0, le=MAX_INDEX)]]


class MapKnots(Strict):
    """The parameter knot vectors of a nurbs map, two in 2D, three in 3D (any scale: they are scaled to cells)."""
    x: list[Real]
    y: list[Real]
    z: Optional[list[Real]] = None


class NurbsPatch(Strict):
    """One patch of a nurbs map given as several (domain.map.patches): its knots, control points and weights as
    for a single patch."""
    knots: MapKnots
    control_points: Union[list[list[Vec]], list[list[list[Vec]]]]
    weights: Optional[Union[list[list[Real]], list[list[list[Real]]]]] = None


class NurbsMap(Strict):
    """domain.map of type nurbs: a quadratic NURBS patch (2D) or volume (3D) given as data (raised to degree 3 for
    solver.basis cubic)
    (taichi_mpm/bases/mapgeom.py): control_points[i][j] = [x, y] (3D: [i][j][k] = [x, y, z]), i along the knots x
    (faces x_min / x_max: i first and last), j along y, k along z. Or `patches`: several such patches joined in
    order along x, each one's last layer of control points the next one's first (a C0 joint)."""
    type: Literal["nurbs"]
    knots: Optional[MapKnots] = None
    control_points: Optional[Union[list[list[Vec]], list[list[list[Vec]]]]] = None
    weights: Optional[Union[list[list[Real]], list[list[list[Real]]]]] = None   # null: all 1 (a B-spline map)
    patches: Optional[list[NurbsPatch]] = None         # instead of knots / control_points / weights
    periodic: bool = False                             # x wraps around: the last layer is the first
    # cells per knot span (knot insertion); the refined net is sized by the budget as the annulus' cells
    refine: list[Annotated[int, Field(gt=0, le=MAX_INDEX)]] = [1, 1]


class Domain(Strict):
    lower: Vec
    upper: Vec
    dx: PositiveFloat
    sparse: bool = True
    boundaries: Boundaries = Boundaries()
    knots: Optional[Knots] = None
    map: Optional[Annotated[Union[AnnulusMap, NurbsMap, CylinderMap, ShellMap], Field(discriminator="type")]] = None


class Cpdi(Strict):
    # cpdi1: parallelogram / parallelepiped domains r_a = F r_a0 (Sadeghirad et al. 2011); cpdi2: quadrilateral /
    # hexahedral domains whose corners are tracked as their own points (Sadeghirad et al. 2013)
    variant: Literal["cpdi1", "cpdi2"] = "cpdi1"


class Ddmp(Strict):
    # a node whose dual domain is filled below this fraction (V_j / V_j^dual, at a free surface or where material
    # enters a cell) shares part of its force with its fullest neighbour: linear weights leave such a node a tiny
    # mass and a full force (extensions/ddmp_fill.py; docs/bases.md, "DDMP's small nodes"); 0: off
    fold_below: Annotated[float, Field(ge=0, lt=1)] = 0.2
    # each particle's weights and gradient averaged over two sub-points per axis, the centres of the halves of its
    # domain stretched by |F_aa| (Dhakal & Zhang 2016's sub-points): the particles' quadrature of the force then
    # converges where one point per particle stalls (docs/bases.md, "DDMP's sub-points"); a 5-node stencil
    sub_points: bool = False


def _basis_name(v):
    """A registered basis (bases/registry.py; read at validation, so a basis registered later is accepted)."""
    if not (isinstance(v, str) and v in bases.names()):
        names = [repr(n) for n in bases.names()]
        raise ValueError(f"must be {bases.listed(names)} (got {_brief(v)})")
    return v


class Asflip(Strict):
    # ASFLIP's parameters (transfer asflip only; Fei et al. 2021): the FLIP part of the velocity update, and the
    # position correction of particles not compressed (J >= 1) and of compressed ones
    flip: Annotated[float, Field(ge=0, le=1)] = 1.0
    position: Annotated[float, Field(ge=0, le=1)] = 1.0
    position_min: Annotated[float, Field(ge=0, le=1)] = 0.0


class Solver(Strict):
    basis: Annotated[str, BeforeValidator(_basis_name), OneOf(bases.names)] = bases.DEFAULT
    transfer: Literal[transfer_schemes.names()] = "apic"  # type: ignore[valid-type]  # the registered schemes
    update: Literal["usl", "musl", "usf"] = "usl"
    flip_blend: Annotated[float, Field(ge=0, le=1)] = 0.99
    # XPIC's order m (transfer xpic only): 1 is PIC; each order one more particle pass (docs/transfers.md)
    xpic_order: Annotated[int, BeforeValidator(_no_bool), Field(ge=1, le=8)] = 2
    asflip: Asflip = Asflip()
    # PolyPIC's modes (transfer polypic only): total (degree <= p in all) or full (degree <= p per axis, interpolating)
    polypic_modes: Literal[polypic.MODE_SETS] = "total"  # type: ignore[valid-type]
    gimp_domain: Literal["uniform", "deforming"] = "uniform"
    # the B-splines' particle quadrature: point (weights and gradients at the particle) or domain (the particle's
    # knot span averaged over its domain of the initial spacing: cubic keeps second order at sticky walls;
    # docs/accuracy.md, "Cubic B-splines at sticky walls")
    quadrature: Literal["point", "domain"] = "point"
    # the nodal force from each particle's stress minus the average stress at the node (the local stress
    # difference, Perez, Barclay & Zhang 2023): the particles' quadrature error under a uniform stress vanishes
    # inside a body (extensions/stress_difference.py; docs/accuracy.md, "The local stress difference")
    stress_difference: bool = False
    cpdi: Cpdi = Cpdi()
    ddmp: Ddmp = Ddmp()
    cfl: PositiveFloat = 0.4
    dt: Optional[PositiveFloat] = None
    end_time: PositiveFloat
    gravity: Optional[Vec] = None
    max_steps: Optional[Annotated[int, Field(gt=0)]] = None
    # unroll the stencil loop: faster steps, slower first compile (docs/performance.md); auto unrolls runs of at
    # least 1e7 particle-steps (stencils.resolve_unroll), stencils of at most 16 nodes whole (all 1D and 2D bases)
    # and the trailing axes of larger tensor stencils, up to 9 nodes per run-time iteration (3D quadratic and gimp:
    # 9 of 27, cubic and ddmp: 4 of 64); cpdi in 3D runs at run time
    unroll: Union[Literal["auto"], bool] = "auto"
    # how P2G adds to the grid: auto (coloured on a CPU with a tensor-product basis, atomic otherwise), coloured
    # (particles binned by grid block each step, blocks of one colour in parallel with plain adds;
    # docs/performance.md) or atomic
    scatter: Literal["auto", "coloured", "atomic"] = "auto"
    # energy balance: stop when total energy exceeds its initial value + body-force work - viscous dissipation by
    # more than this fraction of the largest kinetic + strain energy (checked every few steps and after every
    # advance, see docs/accuracy.md); null turns the check off
    energy_growth_limit: Optional[PositiveFloat] = 0.1
    # volumetric locking: standard (each particle's own J) or fbar (the step's volume change averaged over the
    # grid, for nearly incompressible solids and fluids; see docs/accuracy.md, "Volumetric locking")
    volumetric: Literal["standard", "fbar"] = "standard"
    # bit-identical runs regardless of thread count and load (CPU: no fast math; one thread unless the scene sums in
    # one order on any threads, solver.thread_independent); see docs/reliability.md
    deterministic: bool = False


def _body_ref(v):
    if v is None or isinstance(v, str) or (isinstance(v, int) and not isinstance(v, bool) and v >= 0):
        return v
    raise ValueError(f"must be a body's name or its index (an integer from 0), got {v!r}")


# a body named by its name or its index (YAML's true would otherwise pass as body 1)
BodyRef = Annotated[Union[int, str], BeforeValidator(_body_ref)]


class FrictionPair(Strict):
    """One pair of bodies with a friction coefficient of its own (crack.friction_pairs, contact.friction_pairs)."""
    bodies: Annotated[list[BodyRef], Field(min_length=2, max_length=2)]   # names or indices
    mu: Annotated[float, BeforeValidator(_no_bool), Field(ge=0)]


class Crack(Strict):
    threshold: Real = 0.0
    kernel_radius: PositiveFloat = 2.0
    contact_in_compression: bool = True
    damage_threshold: Annotated[float, Field(ge=0, le=1)] = 0.5
    gradient_threshold: Annotated[float, Field(ge=0)] = 0.1
    # particle normals kept between steps; once a particle has moved half this fraction of the SPH support radius,
    # those whose neighbours moved against each other by that much are recomputed (all if a damage value changed);
    # 0: recomputed every step (docs/crack_finder.md)
    normal_refresh: Annotated[float, Field(ge=0, le=0.5)] = 0.01
    # Coulomb friction coefficient across the crack faces and body interfaces in contact (0: frictionless, as the
    # seed's method): each node near a contact gets a second velocity field, the particles in contact across it,
    # and the two fields' relative tangential velocity loses mu times their normal approach, not beyond sticking
    # (docs/crack_finder.md, "Friction"); not with solver.update musl
    friction: Annotated[float, BeforeValidator(_no_bool), Field(ge=0)] = 0.0
    # pairs of interface bodies with a coefficient of their own instead of `friction` (docs/crack_finder.md)
    friction_pairs: list[FrictionPair] = []
    # between interface bodies, a particle is in contact only while the nearest particle facing it lies within
    # (1 + contact_gap) particle spacings (their domains at most contact_gap spacings apart); null: anywhere within
    # the SPH support, as the seed's method (docs/crack_finder.md, "Contact gap")
    contact_gap: Optional[Annotated[float, BeforeValidator(_no_bool), Field(ge=0)]] = None


class Contact(Strict):
    """Contact between bodies by a method of its own (docs/contact.md); the crack finder keeps its `crack:` section."""
    # multi_field: one velocity field per body or group of bodies (Bardenhagen et al. 2000)
    method: Literal["multi_field"] = "multi_field"
    # Coulomb friction coefficient between the fields (every pair alike but those in friction_pairs)
    friction: Annotated[float, BeforeValidator(_no_bool), Field(ge=0)] = 0.0
    # pairs of bodies in different fields with a coefficient of their own instead of `friction` (docs/contact.md)
    friction_pairs: list[FrictionPair] = []
    # groups of bodies (names or indices) sharing one velocity field; a body in no group gets a field of its own;
    # null: every body its own field
    bodies: Optional[list[Annotated[list[BodyRef], Field(min_length=1)]]] = None


# one material: the schema of its model, picked by `model` (the registry in taichi_mpm/materials/)
AnyMaterial = material_models.schema()
MODEL_NAMES = material_models.names()
_material_adapter = TypeAdapter(AnyMaterial)


def use_registered_materials():
    """Validate against the registry as it is now: after a model was registered (or unregistered) from outside
    the package, so that configs accept its name (docs/materials.md, "Adding a material")."""
    global AnyMaterial, MODEL_NAMES, _material_adapter
    AnyMaterial = material_models.schema()
    MODEL_NAMES = material_models.names()
    _material_adapter = TypeAdapter(AnyMaterial)
    Config.model_fields["materials"].annotation = dict[str, AnyMaterial]
    Config.model_rebuild(force=True)


def Material(**keys):
    """A validated material (the schema of its `model`), e.g. Material(model="neo_hookean", density=1000, E=1e4)."""
    return _material_adapter.validate_python(keys)


class DamageRegion(Strict):
    shape: Shape
    value: Annotated[float, Field(ge=0, le=1)] = 1.0


def _stress_value(v):
    """bodies[].stress: Voigt list (1D [sxx]; 2D [sxx, syy, sxy]; 3D [sxx, syy, szz, syz, sxz, sxy]) or a symmetric
    d x d matrix; each entry a number or an expression of x, y, z. Lengths are checked against dim later."""
    if v is None:
        return v
    if not isinstance(v, list) or not v:
        raise ValueError(f"must be a list of stress components (Voigt) or a d x d matrix, got {_brief(v)}")
    check = _expression(SPACE)
    out = []
    for i, row in enumerate(v):
        if isinstance(row, list):
            items = []
            for j, item in enumerate(row):
                try:
                    items.append(check(item))
                except ValueError as e:
                    raise _Located(f"{i}.{j}", str(e)) from None
            out.append(items)
        else:
            try:
                out.append(check(row))
            except ValueError as e:
                raise _Located(str(i), str(e)) from None
    if any(isinstance(r, list) for r in out) and not all(isinstance(r, list) for r in out):
        raise ValueError("mixes numbers and rows: give a Voigt list or a matrix (a list of rows)")
    return out


class Traction(Strict):
    """A prescribed surface traction or pressure on a body (docs/loads.md): particle forces on the body's exposed
    particle faces inside `region`, force = traction x face area, scaled by `ramp` (a function of t)."""
    region: Optional[Shape] = None               # box or sphere; null: the body's whole surface
    faces: Optional[list[Literal[FACES]]] = None  # type: ignore[valid-type]  # outward normals loaded; null: all
    traction: Optional[list[Real]] = None         # Pa, per axis
    pressure: Optional[Real] = None               # Pa, positive pushes inward (along -n)
    ramp: TimeExpr = 1.0                          # factor of time, e.g. "min(t / 0.01, 1)"
    # particles: forces on the loaded particles, spread by their weights; nodes (placement map): the faces'
    # consistent nodal forces int R_i t dA on the mapped grid's control points, fixed where the faces start
    apply_to: Literal["particles", "nodes"] = "particles"

    @model_validator(mode="after")
    def _one_load(self):
        if (self.traction is None) == (self.pressure is None):
            raise _Located("traction", "give exactly one of `traction` (a vector) and `pressure` (a number)")
        return self


class PrescribedVelocity(Strict):
    """Particles of a body region whose velocity is prescribed (grips): docs/loads.md."""
    region: Optional[Shape] = None               # box or sphere; null: the whole body
    velocity: list[FreeTimeExpr]                 # per axis: number or expression of t (m/s), null: free


class Geostatic(Strict):
    """bodies[].geostatic: a cam_clay body starts consolidated under its own weight (K0 conditions,
    materials.cam_clay.geostatic_state): vertical effective stress rho |g| (surface - height) along the last axis,
    k0 times it across, p_c from ocr."""
    k0: Annotated[Real, Field(gt=0, le=3)]             # sigma_h / sigma_v (Jaky: 1 - sin phi)
    ocr: Annotated[Real, Field(ge=1, le=1e6)] = 1.0     # p_c / the p_c of the yield surface through the stress
    surface: Optional[Real] = None                      # m, the ground's height; null: the body's top


class Body(Strict):
    name: Optional[str] = None
    shape: Shape
    material: str
    # per axis; capped so that dx / particles_per_cell stays a number (10**400 overflowed: tests/test_fuzz.py)
    particles_per_cell: Annotated[int, Field(gt=0, le=1000)] = 2
    # regular / jittered: a lattice of spacing dx / particles_per_cell; map: particles_per_cell per axis in every
    # cell of domain.map's parameter space (volumes |det J| dxi^d), so a body's faces follow the map's (tractions'
    # `faces` then name the map's parameter faces)
    placement: Literal["regular", "jittered", "map"] = "regular"
    velocity: Optional[list[SpaceExpr]] = None    # per axis: a number or an expression of x, y, z
    # initial Cauchy stress (Voigt list or matrix; numbers or expressions of x, y, z), kept as a stored stress
    stress: Annotated[Optional[list[Union[float, str, list[Union[float, str]]]]], BeforeValidator(_stress_value)] = None
    tractions: list[Traction] = []
    prescribed_velocity: list[PrescribedVelocity] = []
    angular_velocity: Optional[Union[Real, Vec]] = None
    interface: bool = False
    damage_regions: list[DamageRegion] = []
    # particles of this body inside an earlier body's shape: error, skip (leave them out), allow (keep both)
    overlap: Literal["error", "skip", "allow"] = "error"
    geostatic: Optional[Geostatic] = None        # cam_clay: a K0 start under the body's own weight


class Render(Strict):
    color_by: str = "speed"
    size: list[Annotated[int, Field(gt=0)]] = [960, 720]
    camera: str = "iso"
    point_size: Optional[PositiveFloat] = None
    colormap: str = "viridis"
    clim: Optional[Vec] = None
    scale: Literal["linear", "log"] = "linear"
    percentiles: list[float] = [1.0, 99.0]
    # what a 3D camera frames: run (the bodies over the whole run: frames rendered at the end), domain, or a box
    # [[x, y, z], [x, y, z]]; domain or a box (with clim, or a label field) lets frames render while the solver steps
    framing: Union[str, list[Vec]] = "run"

    @model_validator(mode="after")
    def _lengths(self):
        from .io.render_options import CAMERAS, color_fields  # (light: the field registry, no pyvista)

        if self.camera not in CAMERAS:
            raise _Located("camera", f"unknown camera {self.camera!r} (choose from {', '.join(CAMERAS)}; "
                                     f"2D and 1D frames are always seen along z)")
        if self.color_by not in color_fields():
            raise _Located("color_by", f"unknown colour field {self.color_by!r} (choose from "
                                       f"{', '.join(color_fields()[:14])}, or sxx, sxy, ..., szz)")
        if self.colormap != "viridis":
            try:
                import matplotlib

                matplotlib.colormaps[self.colormap]
            except ImportError:  # nothing to check against; the renderer is not installed either
                pass
            except (KeyError, ValueError, TypeError):
                raise _Located("colormap", f"unknown colormap {self.colormap!r} (a matplotlib colormap name, "
                                           f"e.g. viridis, plasma, coolwarm, turbo)") from None
        if len(self.size) != 2:
            raise _Located("size", f"must be [width, height] in pixels, got {len(self.size)} numbers")
        if self.clim is not None and (len(self.clim) != 2 or self.clim[0] >= self.clim[1]):
            raise _Located("clim", "must be [min, max] with min < max")
        if self.clim is not None and self.scale == "log" and self.clim[0] <= 0:
            raise _Located("clim", "a log scale needs clim [min, max] with 0 < min")
        f = self.framing
        if f not in ("run", "domain") and (isinstance(f, str) or len(f) != 2 or any(len(c) != 3 for c in f)
                                       or not all(a < b for a, b in zip(*f))):
            raise _Located("framing", f"must be run, domain or a box [[x, y, z], [x, y, z]] (lower, upper) with "
                                      f"lower < upper on every axis, got {f}")
        p = self.percentiles
        if len(p) != 2 or not 0 <= p[0] < p[1] <= 100:
            raise _Located("percentiles", f"must be [low, high] with 0 <= low < high <= 100, got {p}")
        return self


PROBE_TYPES = ("point", "body", "region", "wall", "contact", "grip")
PROBE_NAME = r"^[A-Za-z0-9][A-Za-z0-9_-]*$"  # becomes probes/NAME.csv: no path characters
# the keys each probe type needs (besides name and type); any other key is an error for that type
PROBE_KEYS = {"point": ("point",), "body": ("body",), "region": ("region",), "wall": ("face",), "contact": ("body",),
              "grip": ("grip",)}


def _probe_every(v):
    if v is None or v == "step" or (isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < float("inf")):
        return v
    raise ValueError(f"must be a time > 0 in seconds, step (every step) or null (every output), got {v!r}")


class Probe(Strict):
    """A quantity sampled over time into probes/NAME.csv (taichi_mpm/io/probes.py)."""
    name: str
    type: Literal[PROBE_TYPES]  # type: ignore[valid-type]  # the names, built at import
    point: Optional[Vec] = None                      # point: the particle nearest this point at t = 0
    body: Annotated[Optional[Union[int, str]], BeforeValidator(_body_ref)] = None  # body: a body's name or index
    region: Optional[Shape] = None                   # region: a box or sphere; the particles inside at t = 0
    face: Optional[Literal[FACES]] = None  # type: ignore[valid-type]  # wall: the domain face
    grip: Optional[Annotated[int, Field(ge=0)]] = None  # grip: a bodies[].prescribed_velocity entry, counted over all bodies

    @field_validator("name")
    @classmethod
    def _plain_name(cls, v):
        if not re.match(PROBE_NAME, v):
            raise ValueError(f"a probe name is letters, digits, '_' and '-' (it names probes/NAME.csv), got {v!r}")
        return v

    @model_validator(mode="after")
    def _keys_of_type(self):
        for key in ("point", "body", "region", "face", "grip"):
            wanted = key in PROBE_KEYS[self.type]
            if wanted and getattr(self, key) is None:
                raise _Located(key, f"a {self.type} probe needs '{key}'")
            if not wanted and getattr(self, key) is not None:
                raise _Located(key, f"a {self.type} probe has no '{key}' (it takes {', '.join(PROBE_KEYS[self.type])})")
        return self


class Output(Strict):
    dir: str = "runs/{name}"
    every: PositiveFloat = 0.01
    formats: list[Literal["vtu", "npz", "png", "mp4", "gif"]] = ["vtu", "png"]
    fields: list[OutputField] = ["velocity", "stress"]
    # false: a VTU holds the standard set (fields.ALWAYS) plus `fields`; true: the positions and `fields` only
    only_fields: bool = False
    # a checkpoint every this many outputs (and at the end and on a stop); 1: at every output, as before
    checkpoint_every: Annotated[int, BeforeValidator(_no_bool), Field(ge=1)] = 10
    # thread: files are written by a background thread while the solver steps; inline: by the solver's thread
    writer: Literal["thread", "inline"] = "thread"
    render: Render = Render()
    probes: list[Probe] = []
    # seconds between probe samples (at the first step on or after each multiple); `step`: every step;
    # null: at every output
    probe_every: Annotated[Optional[Union[float, Literal["step"]]], BeforeValidator(_probe_every)] = None


class Limits(Strict):
    """Resource limits checked before anything is allocated (taichi_mpm/budget.py)."""
    memory_gb: Optional[PositiveFloat] = None        # default: half of this machine's physical memory
    particles: Optional[Annotated[int, Field(gt=0)]] = None  # default: only the memory limit
    # estimated steps to solver.end_time above which a run is refused (default 1e8: budget.RUN_STEPS)
    steps: Optional[Annotated[float, BeforeValidator(_no_bool), Field(gt=0)]] = None
    allow_large: bool = False                        # --allow-large: run anyway (the estimate still prints)


class Config(Strict):
    name: str
    dim: Literal[1, 2, 3] = 3
    precision: Literal["f32", "f64"] = "f32"
    arch: Literal["auto", "cpu", "cuda", "vulkan", "metal"] = "auto"
    domain: Domain
    solver: Solver
    crack: Optional[Crack] = None
    contact: Optional[Contact] = None
    materials: dict[str, AnyMaterial]  # type: ignore[valid-type]  # the registered models' union, built at import
    bodies: Annotated[list[Body], Field(min_length=1)]
    output: Output = Output()
    limits: Limits = Limits()
    _source: Optional[str] = PrivateAttr(None)  # the YAML file it came from, for relative paths
    _lines: dict = PrivateAttr(default_factory=dict)  # dotted key -> line in _source
    _overrides: dict = PrivateAttr(default_factory=dict)  # the --set overrides applied

    @field_validator("name")
    @classmethod
    def _name(cls, v):
        if not plain_name(v):
            raise ValueError(f"must be a plain folder name (it names runs/NAME): 1-{MAX_NAME} characters, no '/', "
                             f"'\\', control characters or leading '.' or space")
        return v

    @model_validator(mode="after")
    def _consistent(self):
        """Cross-field checks, in order (the first problem found is the one reported)."""
        self._check_domain_box()
        self._check_basis()
        self._check_knots()
        self._check_map()
        self._check_scatter()
        if self.solver.gravity is not None:
            _need_len("solver.gravity", self.solver.gravity, self.dim)
        for i, b in enumerate(self.bodies):
            self._check_body(i, b)
        self._check_velocity_walls()
        self._check_crack_combinations()
        self._check_contact()
        self._check_transfer()
        self._check_unused_settings()
        self._check_cpdi2()
        self._check_stress_difference()
        self._check_probes()
        self._check_ranges()
        return self

    def _check_domain_box(self):
        """domain.lower / upper of the scene's dimension, ordered, a whole number of cells of dx along each axis."""
        d = self.dim
        _need_len("domain.lower", self.domain.lower, d)
        _need_len("domain.upper", self.domain.upper, d)
        if any(u <= l for l, u in zip(self.domain.lower, self.domain.upper)):
            raise _Located("domain.upper", "must exceed domain.lower on every axis")
        for a, (l, u) in enumerate(zip(self.domain.lower, self.domain.upper)):
            n = (u - l) / self.domain.dx
            if not math.isfinite(n):  # dx = 5e-324 (found by tests/test_fuzz.py)
                raise _Located("domain.dx", f"dx={self.domain.dx:g} is too small: the domain extent {u - l:g} along "
                                            f"{'xyz'[a]} would be more cells than a number can hold")
            if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 1:
                raise _Located("domain.dx", f"the domain extent {u - l:g} along {'xyz'[a]} is not a whole number of "
                                            f"cells of dx={self.domain.dx:g} ({n:.4g} cells); "
                                            f"choose e.g. dx={(u - l) / max(1, round(n)):.6g}")

    def _check_basis(self):
        """What the basis declares beyond the checks of the features themselves: its dimensions and F-bar."""
        spec = bases.get(self.solver.basis)
        if self.dim not in spec.dims:
            raise _Located("solver.basis", f"basis {spec.name} is defined in {bases.listed([f'{d}D' for d in spec.dims])}"
                                           f" only (the scene is {self.dim}D)")
        if self.solver.volumetric == "fbar" and not spec.fbar:
            raise _Located("solver.volumetric", f"fbar is not available with basis {spec.name}: use standard or basis "
                                                f"{bases.listed(bases.names(fbar=True))}")

    def _check_scatter(self):
        spec = bases.get(self.solver.basis)
        if self.solver.scatter == "coloured" and (not spec.coloured_scatter or self.domain.map is not None):
            raise _Located("solver.scatter", f"coloured needs a basis whose stencil is a bounded box of nodes, on a box grid "
                                             f"({', '.join(bases.names(coloured_scatter=True))}): cpdi's particle "
                                             "domains and a mapped grid's stencil can reach any node, so they add "
                                             "atomically (scatter: auto)")

    def _check_body(self, i, b):
        """One body: its material exists, its vectors and shapes fit the dimension, its loads are consistent."""
        d, key = self.dim, f"bodies.{i}"
        if b.material not in self.materials:
            raise _Located(f"{key}.material", f"undefined material '{b.material}' (defined: {', '.join(self.materials) or 'none'})")
        if b.velocity is not None:
            _need_len(f"{key}.velocity", b.velocity, d)
        if b.angular_velocity is not None:
            _check_angular_velocity(f"{key}.angular_velocity", b.angular_velocity, d)
        _check_shape(f"{key}.shape", b.shape, d)
        for j, r in enumerate(b.damage_regions):
            _check_shape(f"{key}.damage_regions.{j}.shape", r.shape, d)
        _check_loads(key, b, d)
        if b.geostatic is not None:
            self._check_geostatic(key, b)
        if b.placement == "map" and self.domain.map is None:
            raise _Located(f"{key}.placement", "map places particles in the cells of domain.map's parameter space: "
                                               "this domain has no map (use regular or jittered)")
        for j, t in enumerate(b.tractions):
            if t.apply_to == "nodes":
                self._check_node_traction(f"{key}.tractions.{j}.apply_to", b)

    def _check_node_traction(self, key, b):
        """apply_to nodes: the loaded faces must be faces of the grid (a map-placed body's faces are the mapped grid's
        parameter faces), and the forces act on the one velocity field."""
        if b.placement != "map":
            raise _Located(key, "nodes puts a traction on the grid's nodes, which needs the loaded faces to be faces "
                                "of the grid: give the body placement: map on a domain.map (or apply_to: particles)")
        if self.crack is not None or self.contact is not None:
            section = "crack" if self.crack is not None else "contact"
            raise _Located(key, f"nodal forces act on the grid's single velocity field, which the {section} section "
                                f"splits near the bodies' surfaces: use apply_to: particles")

    def _check_geostatic(self, key, b):
        """A geostatic start: a cam_clay body (it sets that model's consolidated state), gravity down the last axis,
        no initial stress besides, and a ground surface no lower than the body's particles can be."""
        model = self.materials[b.material].model
        if model != "cam_clay":
            raise _Located(f"{key}.geostatic", f"sets cam_clay's consolidated state; material '{b.material}' is "
                                               f"{model} (give its initial stress with bodies[].stress)")
        if b.stress is not None:
            raise _Located(f"{key}.geostatic", "give either geostatic or stress, not both")
        if not self.gravity[-1] < 0:
            raise _Located(f"{key}.geostatic", f"needs gravity pointing down the last axis (solver.gravity's last "
                                               f"component < 0), got {self.gravity}")
        if b.geostatic.surface is not None and not isinstance(b.shape, Mesh):   # a mesh's: at scene set-up
            top = float(geometry.bounds(b.shape, self.dim)[1][-1])
            if b.geostatic.surface < top:
                raise _Located(f"{key}.geostatic.surface", f"the ground ({b.geostatic.surface:g} m) lies below the "
                                                           f"body's top ({top:g} m): no particle may be above it")

    def _check_velocity_walls(self):
        """A velocity wall's vector has the scene's dimension."""
        for a in range(self.dim):
            for side in (0, 1):
                face = FACES[2 * a + side]
                spec = self.domain.boundaries._get(a, side)
                named = getattr(self.domain.boundaries, face) is not None
                fkey = f"domain.boundaries.{face if named else 'default'}"
                if spec.velocity is not None:
                    _need_len(f"{fkey}.velocity", spec.velocity, self.dim)
                if spec.angular_velocity is not None and self.domain.map is None:
                    raise _Located(f"{fkey}.angular_velocity", "a turning wall needs a mapped grid's face "
                                   "(domain.map): the box's faces are flat (use `velocity`)")
                if spec.center is not None:
                    _need_len(f"{fkey}.center", spec.center, self.dim)

    def _check_crack_combinations(self):
        """Options the crack finder cannot be combined with."""
        why = bases.get(self.solver.basis).crack
        if self.crack is not None and why is not None:
            raise _Located("crack", f"the crack finder does not support basis {self.solver.basis}: {why}; use "
                                    f"{bases.listed(bases.names(crack=None))} with a crack section")

    def contact_fields(self) -> list[int]:
        """Per body (config order): its velocity field under contact.bodies (a body in no group: one of its own)."""
        groups = (self.contact.bodies or []) if self.contact is not None else []
        names = self._body_names()
        out: list = [None] * len(self.bodies)
        for k, group in enumerate(groups):
            for entry in group:
                out[entry if isinstance(entry, int) else names[entry]] = k
        extra = len(groups)
        for i, f in enumerate(out):
            if f is None:
                out[i], extra = extra, extra + 1
        return out

    def _body_names(self) -> dict:
        return {b.name: i for i, b in enumerate(self.bodies) if b.name}

    def _body_index(self, key: str, entry) -> int:
        """The index of a body named by its name or index (contact.bodies, friction_pairs), or a config error at
        `key`."""
        names = self._body_names()
        if isinstance(entry, int) and not 0 <= entry < len(self.bodies):
            raise _Located(key, f"no body {entry} (the scene has {len(self.bodies)}, numbered from 0)")
        if isinstance(entry, str) and entry not in names:
            known = ", ".join(names) or "none (give bodies a name, or use an index)"
            raise _Located(key, f"unknown body '{entry}' (named bodies: {known})")
        return entry if isinstance(entry, int) else names[entry]

    def friction_table(self, section) -> np.ndarray:
        """(bodies, bodies) Coulomb coefficients of a crack or contact section: its `friction`, and each of its
        friction_pairs' own (symmetric)."""
        names = self._body_names()
        table = np.full((len(self.bodies), len(self.bodies)), float(section.friction))
        for pair in section.friction_pairs:
            a, b = (e if isinstance(e, int) else names[e] for e in pair.bodies)
            table[a, b] = table[b, a] = pair.mu
        return table

    def _check_friction_pairs(self, name: str, section, together):
        """Each pair names two bodies (names or indices) that can touch under the section's method (`together`:
        (i, j) -> why not, or None), and no pair twice."""
        seen = set()
        for k, pair in enumerate(section.friction_pairs):
            found = [self._body_index(f"{name}.friction_pairs.{k}.bodies.{j}", entry)
                     for j, entry in enumerate(pair.bodies)]
            key = f"{name}.friction_pairs.{k}.bodies"
            if found[0] == found[1]:
                raise _Located(key, "names one body twice: a pair is two bodies")
            why = together(*found)
            if why:
                raise _Located(key, why)
            if frozenset(found) in seen:
                raise _Located(key, "this pair is given twice")
            seen.add(frozenset(found))

    def _check_contact(self):
        """contact: its groups name bodies once each, at least two fields, and options the method works with;
        crack.friction_pairs: pairs of interface bodies."""
        if self.crack is not None:
            iface = [b.interface for b in self.bodies]
            self._check_friction_pairs("crack", self.crack, lambda i, j: (
                None if iface[i] and iface[j] else "friction between bodies acts between interface bodies: set "
                                                   f"interface: true on bodies {i} and {j}"))
        c = self.contact
        if c is None:
            return
        if self.crack is not None:
            raise _Located("contact", "a contact section cannot be combined with a crack section: both separate "
                                      "bodies (the crack finder inside one velocity field, multi_field with one "
                                      "field per body); keep one (docs/contact.md)")
        seen = {}
        for k, group in enumerate(c.bodies or []):
            for j, entry in enumerate(group):
                key = f"contact.bodies.{k}.{j}"
                i = self._body_index(key, entry)
                if i in seen:
                    raise _Located(key, f"body {i} is in group {seen[i]} already: a body has one velocity field")
                seen[i] = k
        fields = self.contact_fields()
        if len(set(fields)) < 2:
            raise _Located("contact.bodies", "multi_field contact needs at least two velocity fields (two bodies, "
                                             "or two groups)")
        self._check_friction_pairs("contact", c, lambda i, j: (
            f"bodies {i} and {j} share a velocity field (contact.bodies): no contact between them"
            if fields[i] == fields[j] else None))
        s = self.solver
        if s.update != "usl":
            raise _Located("solver.update", f"{s.update} cannot be combined with multi_field contact (section "
                                            "'contact'): its fields are solved in the one grid update of usl")
        if transfer_schemes.get(s.transfer).extended:
            raise _Located("solver.transfer", f"{s.transfer} cannot be combined with multi_field contact: its "
                                              "passes work on the one grid velocity")
        if s.volumetric == "fbar":
            raise _Located("solver.volumetric", "fbar cannot be combined with multi_field contact: its average "
                                                "would mix the volume changes of bodies in contact")
        if self.domain.map is not None:
            raise _Located("domain.map", "domain.map cannot be combined with multi_field contact (not built yet)")
        if any(p.type == "wall" for p in self.output.probes):
            raise _Located("output.probes", "wall probes are not available with multi_field contact: they measure "
                                            "the centre-of-mass field, not the bodies' fields the walls act on")

    def _check_cpdi2(self):
        """cpdi2 moves each particle with its own corners (the centroid of its domain): what would move it
        otherwise is refused (solver.cpdi is refused earlier unless the basis reads it)."""
        if self.solver.cpdi.variant != "cpdi2":
            return
        if self.crack is not None:
            raise _Located("crack", "the crack finder does not work with solver.cpdi.variant cpdi2 (its corners move "
                                    "with one velocity field, not with the side of a crack each corner is on); use "
                                    "cpdi1")
        if self.solver.transfer == "asflip":
            raise _Located("solver.transfer", "asflip's position correction moves particles off their cpdi2 "
                                              "domain's centroid; use apic or flip with cpdi2, or cpdi1")

    def _check_transfer(self):
        """The transfer works with the basis (its declaration in schemes/ tests the basis') and the crack finder."""
        s = self.solver
        scheme = transfer_schemes.get(s.transfer)
        if not transfer_schemes.works_with(s.transfer, s.basis):
            raise _Located("solver.transfer", f"{s.transfer} needs {scheme.basis_why}: it works with the bases "
                                              f"{bases.listed(transfer_schemes.bases_for(s.transfer))} only (the "
                                              f"basis is {s.basis}): {scheme.summary}")
        if s.update == "usf" and (self.crack is not None or s.volumetric == "fbar"):
            what = "the crack finder (section 'crack')" if self.crack is not None else "volumetric: fbar"
            raise _Located("solver.update", f"usf cannot be combined with {what}: it updates F before the forces, "
                                            "in a pass of its own; use usl or musl")
        if s.update == "musl" and self.crack is not None and self.crack.friction > 0:
            raise _Located("solver.update", "musl cannot be combined with crack.friction: friction acts between a "
                                            "node's two velocity fields, which MUSL's remap does not keep; use usl")
        # the newer schemes' own keys (declared in their `parameters`): a value other than the default with another
        # transfer is refused (solver.flip_blend stays unchecked, as before the registry)
        for key, default in (("xpic_order", 2), ("asflip", Asflip()), ("polypic_modes", "total")):
            readers = [n for n in transfer_schemes.names() if f"solver.{key}" in transfer_schemes.get(n).parameters]
            if getattr(s, key) != default and s.transfer not in readers:
                raise _Located(f"solver.{key}", f"is read by solver.transfer {bases.listed(readers)} only (the "
                                                f"transfer is {s.transfer}): remove it or use transfer "
                                                f"{bases.listed(readers)}")
        if scheme.separating and s.update != "usl":
            raise _Located("solver.update", f"transfer {s.transfer} moves particles with its velocity update: usl "
                                            f"only (the update is {s.update})")
        if (scheme.moment_gradient or scheme.extended or scheme.separating or scheme.taylor or scheme.polynomial) \
                and self.crack is not None:
            raise _Located("solver.transfer", f"{s.transfer} cannot be combined with the crack finder (section "
                                              "'crack'): its modified transfers are PIC, FLIP or APIC's")
        if scheme.polynomial:
            self._check_polynomial()

    def _check_polynomial(self):
        """polypic's limits: one velocity polynomial per particle in the box grid's coordinates, at most 27 modes."""
        s = self.solver
        if self.domain.map is not None:
            raise _Located("solver.transfer", "polypic cannot be combined with domain.map: its modes are polynomials "
                                              "of the box grid's coordinates, not the map's")
        n = len(polypic.modes(self.dim, bases.get(s.basis).degree, s.polypic_modes))
        if n > polypic.MAX_MODES:
            raise _Located("solver.polypic_modes", f"{s.polypic_modes} with the {s.basis} basis in {self.dim}D has {n} "
                                                   f"modes per particle ({n * self.dim} floats; at most "
                                                   f"{polypic.MAX_MODES} are built): use total, or the quadratic basis")

    def _check_unused_settings(self):
        """Settings given that nothing would read: an error at validation rather than a run that ignores them."""
        s = self.solver
        # (a default value written out, as Config.to_dict does, is no setting: only other values are refused)
        for key, default in (("cpdi", Cpdi()), ("ddmp", Ddmp()), ("gimp_domain", "uniform"), ("quadrature", "point")):
            readers = [n for n in bases.names() if key in bases.get(n).options]
            if getattr(s, key) != default and s.basis not in readers:
                raise _Located(f"solver.{key}", f"is read by solver.basis {bases.listed(readers)} only (the basis is "
                                                f"{s.basis}): remove it or use basis {bases.listed(readers)}")
        interfaces = [i for i, b in enumerate(self.bodies) if b.interface]
        if self.crack is not None and len(interfaces) > MAX_INTERFACE_BODIES:
            raise _Located(f"bodies.{interfaces[MAX_INTERFACE_BODIES]}.interface",
                           f"the crack finder tells at most {MAX_INTERFACE_BODIES} interface bodies apart (this config "
                           f"marks {len(interfaces)}): merge bodies of one material that never touch into one")
        if self.crack is not None and self.crack.contact_gap is not None and len(interfaces) < 2:
            raise _Located("crack.contact_gap", "is read between interface bodies only (two or more bodies with "
                                                "interface: true; a crack's faces keep the SPH reach): remove it or "
                                                "mark the bodies in contact as interface bodies")
        if self.crack is None:
            why = "acts through the crack finder only: add a `crack:` section (docs/crack_finder.md) or remove it"
            for name, m in self.materials.items():
                if getattr(m, "tensile_strength", None) is not None:
                    raise _Located(f"materials.{name}.tensile_strength", f"material '{name}': the damage law {why}")
            for i, b in enumerate(self.bodies):   # harmless (a crack section switched off to compare): warned
                for key, what in (("damage_regions", "initial damage"), ("interface", "an interface body")):
                    if getattr(b, key):
                        warnings.warn(f"key 'bodies.{i}.{key}': {what} acts through the crack finder only, and "
                                      "the config has no `crack:` section: it is ignored in this run",
                                      ConfigWarning, stacklevel=2)
        for name, m in self.materials.items():
            if getattr(m, "volume_correction", False) and getattr(m, "dilatancy", 0.0) > 0:
                # the return corrects volume-preserving flow only (materials/drucker_prager.py): ignored otherwise
                raise _Located(f"materials.{name}.volume_correction", f"material '{name}': the volume correction "
                               f"takes dilatancy 0 only (J_p - 1 is then all loosening; with dilatancy "
                               f"{m.dilatancy:g} it is also the shear dilation, which stays): set dilatancy: 0 or "
                               "volume_correction: false")
            if getattr(m, "fracture_energy", None) is not None and getattr(m, "tensile_strength", None) is None:
                raise _Located(f"materials.{name}.fracture_energy", f"material '{name}': the softening needs "
                                                                    "tensile_strength (where damage starts)")

    def _check_stress_difference(self):
        """solver.stress_difference needs the standard transfers of a tensor-product basis on the box grid."""
        if not self.solver.stress_difference:
            return
        spec = bases.get(self.solver.basis)
        why = None
        if spec.stress_difference is not None:
            why = f"refuses basis {self.solver.basis}: {spec.stress_difference}"
        elif self.domain.map is not None:
            why = "takes the box grid (or domain.knots), not domain.map"
        elif self.crack is not None:
            why = ("cannot be combined with the crack finder (section 'crack'): its modified transfers sum their "
                   "own forces")
        elif self.contact is not None:
            why = "cannot be combined with multi-field contact (section 'contact'): each body field gets its own force"
        if why:
            raise _Located("solver.stress_difference", f"the local stress difference {why}")

    def _check_knots(self):
        if self.domain.knots is None:
            return
        if not bases.get(self.solver.basis).knots:
            raise _Located("domain.knots", f"knot vectors need a B-spline basis ({bases.listed(bases.names(knots=True))}"
                                           f"), not solver.basis {self.solver.basis}")
        p = bases.get(self.solver.basis).degree
        for a, axis in enumerate("xyz"):
            t = getattr(self.domain.knots, axis)
            if t is None:
                continue
            if a >= self.dim:
                raise _Located(f"domain.knots.{axis}", f"the scene is {self.dim}D: it has no {axis} axis")
            problem = knot_problem(t, p, self.domain.lower[a], self.domain.upper[a])
            if problem:
                raise _Located(f"domain.knots.{axis}", f"{problem} (solver.basis {self.solver.basis}: p = {p})")

    def _check_map(self):
        m = self.domain.map
        if m is None:
            return
        solid = m.type in ("cylinder", "shell")
        if self.dim == 1 or (m.type != "nurbs" and self.dim != (3 if solid else 2)):
            raise _Located("domain.map.type", f"a{'' if self.dim == 1 else ' ' + m.type} map is not {self.dim}D "
                           f"(2D maps: annulus, nurbs; 3D maps: cylinder, shell, nurbs)")
        if not bases.get(self.solver.basis).map:
            mapped = bases.listed(bases.names(map=True))
            raise _Located("domain.map", f"mapped grids are {mapped}: use solver.basis {mapped}, not "
                                         f"{self.solver.basis}")
        if self.domain.knots is not None:
            raise _Located("domain.knots", "give either domain.knots or domain.map (the map has its own knots)")
        if self.solver.quadrature != "point":
            raise _Located("solver.quadrature", "domain quadrature averages the B-splines of the box grid (or of "
                                                "domain.knots); a mapped grid's rational basis takes point only")
        if m.type == "nurbs":
            self._check_nurbs_map(m)
        elif solid:
            self._check_solid_map(m)
        else:
            self._check_annulus_map(m)
        for a in range(self.dim):
            for side in (0, 1):
                spec = self.domain.boundaries._get(a, side)
                if spec.type == "velocity" and spec.angular_velocity is not None and m.type == "nurbs" and \
                        spec.center is None:
                    face = FACES[2 * a + side]
                    named = getattr(self.domain.boundaries, face) is not None
                    raise _Located(f"domain.boundaries.{face if named else 'default'}.center", "a nurbs map has no "
                                   "centre of its own: give the axis of angular_velocity as `center`")

    def _check_annulus_map(self, m):
        _need_len("domain.map.center", m.center, 2)
        _need_len("domain.map.cells", m.cells, 2)
        from .bases import mapgeom
        if m.outer_radius <= m.inner_radius:
            raise _Located("domain.map.outer_radius", "must exceed inner_radius")
        pieces = mapgeom.arc_pieces(m.angle)
        if m.cells[0] % pieces:
            raise _Located("domain.map.cells", f"an annulus of {m.angle:g} degrees is {pieces} rational pieces: "
                                               f"the cells along the angle must be a multiple of {pieces}")
        for a in range(2):
            lo, hi = m.center[a] - m.outer_radius, m.center[a] + m.outer_radius
            if self.domain.lower[a] > lo or self.domain.upper[a] < hi:
                raise _Located("domain.upper", f"the domain box must hold the annulus: [{lo:g}, {hi:g}] along "
                                               f"{'xy'[a]}")

    def _check_solid_map(self, m):
        from .bases import mapgeom
        _need_len("domain.map.center", m.center, 3)
        _need_len("domain.map.cells", m.cells, 3)
        if m.outer_radius <= m.inner_radius:
            raise _Located("domain.map.outer_radius", "must exceed inner_radius")
        arcs = [("the angle", m.angle, 0)]
        if m.type == "shell":
            _need_len("domain.map.latitudes", m.latitudes, 2)
            if m.latitudes[1] <= m.latitudes[0]:
                raise _Located("domain.map.latitudes", "the upper latitude must exceed the lower")
            arcs.append(("the latitude", m.latitudes[1] - m.latitudes[0], 2))
        for what, degrees, a in arcs:
            pieces = mapgeom.arc_pieces(degrees)
            if m.cells[a] % pieces:
                raise _Located("domain.map.cells", f"an arc of {degrees:g} degrees is {pieces} rational pieces: "
                                                   f"the cells along {what} must be a multiple of {pieces}")
        ctrl = mapgeom.solid_map_shape(m, bases.get(self.solver.basis).degree)[0]
        if math.prod(ctrl) > MAX_INDEX:
            raise _Located("domain.map.cells", f"{math.prod(ctrl)} control points: more than Taichi can index")
        r, c = m.outer_radius, m.center
        lo = [c[0] - r, c[1] - r, c[2] + (0.0 if m.type == "cylinder" else -r)]
        hi = [c[0] + r, c[1] + r, c[2] + (m.length if m.type == "cylinder" else r)]
        for a in range(3):
            if self.domain.lower[a] > lo[a] or self.domain.upper[a] < hi[a]:
                raise _Located("domain.upper", f"the domain box must hold the {m.type}: [{lo[a]:g}, {hi[a]:g}] "
                                               f"along {'xyz'[a]}")

    def _check_nurbs_map(self, m):
        from .bases import mapgeom
        d = self.dim
        knots, P, w = self._nurbs_net(m)
        if m.periodic:
            size = np.ptp(P.reshape(-1, d), axis=0).max()
            if np.abs(P[0] - P[-1]).max() > 1e-12 * size or np.abs(w[0] - w[-1]).max() > 1e-12 * w.max():
                raise _Located("domain.map.periodic", "a periodic map closes on itself: its last row of control "
                               "points and weights must equal the first")
        _need_len("domain.map.refine", m.refine, d)
        # the refined map is the given one (knot insertion changes the grid, not the map): checked on the given
        # net with its knots scaled to the refined cells, so the check costs the same at any `refine` (the
        # refined net's size is budget.py's to estimate and refuse, before anything is built)
        _, cells = mapgeom.refined_shape(knots, m.refine)
        scaled = [mapgeom.scaled_knots(t, n) for t, n in zip(knots, cells)]
        most = FOLD_SAMPLES if d == 2 else FOLD_SAMPLES_3D
        det, where = mapgeom.fold(scaled, [2] * d, P, w, [mapgeom.DET_SAMPLES * min(k, max(1, most * k // n))
                                                          for k, n in zip(m.refine, cells)])
        if det <= 1e-9:
            raise _Located("domain.map.control_points", f"the map folds or pinches: det J = {det:.3g} (relative) at "
                           f"parameters ({', '.join(f'{v:g}' for v in where)}) cells; control points must keep "
                           "each cell turning the same way (det J of one sign everywhere)")
        # a map that does not fold is one-to-one, so its extremes lie on its boundary: sample its faces
        per = EDGE_SAMPLES if d == 2 else FACE_SAMPLES_3D
        pts = mapgeom.surface(scaled, [2] * d, P, w, mapgeom.face_samples(cells, per))[0]
        for a in range(d):
            lo, hi = pts[:, a].min(), pts[:, a].max()
            if self.domain.lower[a] > lo or self.domain.upper[a] < hi:
                raise _Located("domain.upper", f"the domain box must hold the map: [{lo:g}, {hi:g}] along "
                                               f"{'xyz'[a]}")

    def _nurbs_net(self, m):
        """(knots per axis, control points, weights) of a nurbs map: its one patch, or its patches joined (each
        checked under its own key)."""
        from .bases import mapgeom
        single = m.knots is not None or m.control_points is not None or m.weights is not None
        if (m.patches is None) == (not single) or (single and (m.knots is None or m.control_points is None)):
            raise _Located("domain.map", "give a nurbs map's knots and control_points (and optionally weights), "
                                         "or its `patches`, not both")
        if m.patches is None:
            return self._nurbs_patch("domain.map", m)
        nets = [self._nurbs_patch(f"domain.map.patches.{i}", p) for i, p in enumerate(m.patches)]
        try:
            return mapgeom.join_patches(nets)
        except mapgeom.JoinError as e:
            raise _Located(f"domain.map.patches.{e.patch}{e.where}", str(e)) from None

    def _nurbs_patch(self, key, m):
        d = self.dim
        for a, axis in enumerate("xyz"):
            t = getattr(m.knots, axis)
            if a >= d:
                if t is not None:
                    raise _Located(f"{key}.knots.{axis}", f"the scene is {d}D: a map has {d} knot vectors")
                continue
            problem = knot_problem(t, 2, t[0], t[-1]) if t else "is empty"
            if problem:
                raise _Located(f"{key}.knots.{axis}", f"{problem} (a nurbs map is quadratic: p = 2)")
        shape = tuple(len(getattr(m.knots, axis)) - 3 for axis in "xyz"[:d])
        _need_table(f"{key}.control_points", m.control_points, shape,
                    lambda k, p: _need_len(k, p, d))
        P = np.asarray(m.control_points, float)
        if m.weights is not None:
            def positive(k, wk):
                if not wk > 0:
                    raise _Located(k, f"NURBS weights must be positive, got {wk:g} (control point "
                                      f"[{']['.join(k.split('.')[-d:])}])")
            _need_table(f"{key}.weights", m.weights, shape, positive)
        w = np.ones(shape) if m.weights is None else np.asarray(m.weights, float)
        return [np.asarray(getattr(m.knots, axis), float) for axis in "xyz"[:d]], P, w

    def _check_ranges(self):
        """Inputs (and the sizes they give) whose magnitude the precision cannot carry through a step: a density
        of 1e-300 is 0 in f32 (a body that never moves), a stress of 1e40 is infinite, a velocity of 1e30 squared
        overflows. ConfigError naming the key and the precision."""
        check = _InRange(self.precision)
        for name, m in self.materials.items():
            _check_material_range(check, name, m)
        for a, g in enumerate(self.solver.gravity or []):
            check(f"solver.gravity.{a}", g, "m/s^2")
        for i, b in enumerate(self.bodies):
            self._check_body_range(check, i, b)
        for a in range(self.dim):
            for side in (0, 1):
                face = FACES[2 * a + side]
                fkey = f"domain.boundaries.{face if getattr(self.domain.boundaries, face) is not None else 'default'}"
                for c, v in enumerate(self.domain.boundaries.velocity(a, side) or []):
                    check(f"{fkey}.velocity.{c}", largest_magnitude(v, TIME, t=self._time_samples), "m/s")
                w = self.domain.boundaries._get(a, side).angular_velocity
                if w is not None:
                    check(f"{fkey}.angular_velocity", largest_magnitude(w, TIME, t=self._time_samples), "1/s")

    def _check_body_range(self, check, i, b):
        """A body's initial fields (expressions sampled over its box), loads, grips, particle volume and mass."""
        key, at = f"bodies.{i}", self._space_samples(b.shape)
        for a, v in enumerate(b.velocity or []):
            check(f"{key}.velocity.{a}", largest_magnitude(v, SPACE, **at), "m/s")
        w = b.angular_velocity
        for a, wa in enumerate(np.atleast_1d(w if w is not None else [])):
            check(f"{key}.angular_velocity" + (f".{a}" if isinstance(w, list) else ""), wa, "1/s")
        for idx, v in _flat(b.stress or []):
            check(f"{key}.stress.{idx}", largest_magnitude(v, SPACE, **at), "Pa")
        for j, t in enumerate(b.tractions):
            tkey, ramp = f"{key}.tractions.{j}", max(largest_magnitude(t.ramp, TIME, t=self._time_samples), 1e-300)
            for a, v in enumerate(t.traction or []):
                check(f"{tkey}.traction.{a}", v, "Pa")
            check(f"{tkey}.pressure", t.pressure, "Pa")
            for v, what in [(v, "traction") for v in t.traction or []] + [(t.pressure or 0.0, "pressure")]:
                check(f"{tkey}.ramp", v * ramp, "Pa", f"{what} x ramp, {v * ramp:.3g}")
        for j, g in enumerate(b.prescribed_velocity):
            for a, v in enumerate(g.velocity):
                check(f"{key}.prescribed_velocity.{j}.velocity.{a}", largest_magnitude(v, TIME, t=self._time_samples),
                      "m/s")
        with np.errstate(all="ignore"):
            volume = float(np.float64(self.domain.dx / b.particles_per_cell) ** self.dim)
        check(f"{key}.particles_per_cell", volume, "m^3", f"the particle volume (domain.dx / particles_per_cell)"
              f"^{self.dim} = {volume:.3g}", derived=True)
        if b.material in self.materials:
            with np.errstate(all="ignore"):
                mass = float(np.float64(volume) * self.materials[b.material].density)
            check(f"materials.{b.material}.density", mass, "kg", f"the particle mass of body {i} (density x "
                  f"volume {volume:.3g}), {mass:.3g}", derived=True)

    @property
    def _time_samples(self) -> np.ndarray:
        return np.linspace(0.0, self.solver.end_time, 65)

    def _space_samples(self, shape) -> dict:
        """x, y, z at 5 points per axis over a shape's bounding box (the domain's for a mesh)."""
        lo, hi = np.asarray(self.domain.lower, float), np.asarray(self.domain.upper, float)
        if not isinstance(shape, Mesh):
            try:
                lo, hi = geometry.bounds(shape, self.dim)
            except Exception:   # a shape of the wrong dimension: its own check reports it
                pass
        axes = [np.linspace(l, h, 5) for l, h in zip(lo, hi)]
        grid = np.meshgrid(*axes, indexing="ij")
        return {SPACE[a]: g.ravel() for a, g in enumerate(grid)}

    def _check_probes(self):
        d, names = self.dim, set()
        for i, p in enumerate(self.output.probes):
            key = f"output.probes.{i}"
            if p.name in names:
                raise _Located(f"{key}.name", f"a second probe named '{p.name}' (probe names must be unique)")
            names.add(p.name)
            if p.point is not None:
                _need_len(f"{key}.point", p.point, d)
            if p.region is not None:
                if not isinstance(p.region, (Box, Sphere)):
                    raise _Located(f"{key}.region.type", f"a probe region is a box or a sphere, not a {p.region.type}")
                _check_shape(f"{key}.region", p.region, d)
            if p.body is not None:
                self._body_index(f"{key}.body", p.body)
            n_grips = sum(len(b.prescribed_velocity) for b in self.bodies)
            if p.grip is not None and p.grip >= n_grips:
                raise _Located(f"{key}.grip", f"no grip {p.grip}: the bodies have {n_grips} prescribed_velocity "
                                              "entries (numbered from 0 over all bodies in order)")
            if p.face is not None and "xyz".index(p.face[0]) >= d:
                raise _Located(f"{key}.face", f"no face {p.face} in {d}D (faces: {', '.join(FACES[:2 * d])})")
            self._check_probe_reach(key, p)

    def _check_probe_reach(self, key, p):
        """A point probe inside the domain; a region probe that meets some body's box (a region beside every body
        selects no particle: found at validation, not when the run starts)."""
        lo, hi = np.asarray(self.domain.lower, float), np.asarray(self.domain.upper, float)
        if p.point is not None and (np.any(np.asarray(p.point) < lo) or np.any(np.asarray(p.point) > hi)):
            raise _Located(f"{key}.point", f"the point {p.point} lies outside the domain {lo.tolist()}..{hi.tolist()}")
        if p.region is None:
            return
        r_lo, r_hi = geometry.bounds(p.region, self.dim)
        for b in self.bodies:
            if isinstance(b.shape, Mesh):
                return   # its box needs the file: the probe's own selection reports an empty region
            b_lo, b_hi = geometry.bounds(b.shape, self.dim)
            if np.all(r_lo <= b_hi) and np.all(b_lo <= r_hi):
                return
        raise _Located(f"{key}.region", f"the probe '{p.name}' selects no particle: its region (box "
                                        f"{r_lo.tolist()}..{r_hi.tolist()}) meets no body's bounding box")

    # resolved values --------------------------------------------------
    @property
    def gravity(self) -> list[float]:
        return self.solver.gravity or [0.0] * self.dim

    def to_dict(self) -> dict:
        """Plain dict that loads back to the same config: unset optional keys are left out, but an explicit
        null whose default is not null (solver.energy_growth_limit: null) is kept, or reloading would turn
        the default back on."""
        return _keep_explicit_nulls(self, self.model_dump(mode="json", exclude_none=True))


def _keep_explicit_nulls(model: BaseModel, out: dict) -> dict:
    for name, field in type(model).model_fields.items():
        value = getattr(model, name)
        if value is None and field.default is not None and name in model.model_fields_set:
            out[name] = None
        elif isinstance(value, BaseModel) and isinstance(out.get(name), dict):
            _keep_explicit_nulls(value, out[name])
    return out


def _need_table(key, table, shape, entry):
    """A nurbs map's per-control-point table: nested lists of `shape` (knots - 3 per axis), the counts refused
    under `key`; then entry(key.i.j[.k], value) checks each entry."""
    def counts(node, level):
        if level == len(shape):
            return
        if not isinstance(node, list) or len(node) != shape[level]:
            got = len(node) if isinstance(node, list) else repr(node)
            raise _Located(key, f"the knots give {' x '.join(map(str, shape))} control points (number of knots - 3 "
                                f"per axis): {shape[level]} entries at depth {level + 1}, got {got}")
        for c in node:
            counts(c, level + 1)
    counts(table, 0)
    for index in np.ndindex(*shape):
        value = table
        for i in index:
            value = value[i]
        entry(key + "".join(f".{i}" for i in index), value)


def _need_len(key, v, d):
    if not isinstance(v, (list, tuple)):
        raise _Located(key, f"must be a list of {d} numbers for dim {d}, got {v!r}")
    if len(v) != d:
        raise _Located(key, f"must have {d} components for dim {d}, got {len(v)}")


def _check_names(key, value, d):
    """An expression may use only the axes the dimension has."""
    if isinstance(value, str):
        from .expressions import Expression
        extra = [n for n in Expression(value, SPACE, key).names if n not in SPACE[:d]]
        if extra:
            raise _Located(key, f"expression {_brief(value)} uses {', '.join(extra)}, which {d}D does not have "
                                f"(axes: {', '.join(SPACE[:d])})")


class _InRange:
    """check(key, value, unit, what): a ConfigError naming the key and the precision when a nonzero value's
    magnitude is outside PRECISION_RANGE (DERIVED_RANGE for derived sizes)."""

    def __init__(self, precision):
        self.precision = precision
        self.fix = "use precision: f64 or check the units" if precision == "f32" else "check the units"

    def __call__(self, key, value, unit="", what="", derived=False):
        if value is None or value == 0:
            return
        lo, hi = (DERIVED_RANGE if derived else PRECISION_RANGE)[self.precision]
        if not lo <= abs(value) <= hi:
            raise _Located(key, f"{what or _brief(value)}{' ' + unit if unit else ''} is outside what precision "
                                f"{self.precision} carries through a step (magnitudes {lo:g} to {hi:g}, or 0): "
                                f"{self.fix}")


def _check_material_range(check, name, m):
    """Material keys in RANGE_UNITS, and the stiffest modulus (snow: max_hardening x the P-wave modulus)."""
    for field, info in type(m).model_fields.items():
        unit = (info.json_schema_extra or {}).get("unit")
        if unit in RANGE_UNITS:
            check(f"materials.{name}.{field}", getattr(m, field), unit)
    c = material_models.wave_speed(m)
    stiffest = c * c * m.density
    if stiffest > PRECISION_RANGE[check.precision][1]:
        key = f"materials.{name}.{'max_hardening' if hasattr(m, 'max_hardening') else 'density'}"
        check(key, stiffest, "Pa", f"the stiffest modulus of material '{name}', {stiffest:.3g}")


def _flat(stress):
    """(index text, value) of a Voigt list or a matrix of stress components."""
    for i, row in enumerate(stress):
        if isinstance(row, list):
            for j, v in enumerate(row):
                yield f"{i}.{j}", v
        else:
            yield str(i), row


def _check_region(key, region, d):
    if region is None:
        return
    if not isinstance(region, (Box, Sphere)):
        raise _Located(f"{key}.type", f"a region is a box or a sphere, not a {region.type}")
    _check_shape(key, region, d)


def _check_loads(key, b, d):
    """Lengths and dimensions of a body's initial fields, tractions and prescribed velocities."""
    if b.velocity is not None:
        _need_len(f"{key}.velocity", b.velocity, d)
        for a, v in enumerate(b.velocity):
            _check_names(f"{key}.velocity.{a}", v, d)
    if b.stress is not None:
        voigt = {1: 1, 2: 3, 3: 6}[d]
        if isinstance(b.stress[0], list):
            if len(b.stress) != d or any(len(row) != d for row in b.stress):
                raise _Located(f"{key}.stress", f"a stress matrix must be {d} x {d} in {d}D")
            for i in range(d):
                for j in range(d):
                    _check_names(f"{key}.stress.{i}.{j}", b.stress[i][j], d)
                    if j > i and b.stress[i][j] != b.stress[j][i]:
                        raise _Located(f"{key}.stress.{i}.{j}", f"the stress must be symmetric: entry {i},{j} is "
                                       f"{b.stress[i][j]!r} but {j},{i} is {b.stress[j][i]!r}")
        else:
            if len(b.stress) != voigt:
                order = {1: "[sxx]", 2: "[sxx, syy, sxy]", 3: "[sxx, syy, szz, syz, sxz, sxy]"}[d]
                raise _Located(f"{key}.stress", f"must have {voigt} Voigt components {order} in {d}D (or be a "
                                                f"{d} x {d} matrix), got {len(b.stress)}")
            for i, v in enumerate(b.stress):
                _check_names(f"{key}.stress.{i}", v, d)
    for j, t in enumerate(b.tractions):
        tkey = f"{key}.tractions.{j}"
        _check_region(f"{tkey}.region", t.region, d)
        if t.traction is not None:
            _need_len(f"{tkey}.traction", t.traction, d)
        for face in t.faces or []:
            if "xyz".index(face[0]) >= d:
                raise _Located(f"{tkey}.faces", f"no face {face} in {d}D (faces: {', '.join(FACES[:2 * d])})")
    for j, g in enumerate(b.prescribed_velocity):
        gkey = f"{key}.prescribed_velocity.{j}"
        _check_region(f"{gkey}.region", g.region, d)
        _need_len(f"{gkey}.velocity", g.velocity, d)
        if all(v is None for v in g.velocity):
            raise _Located(f"{gkey}.velocity", "prescribes no component (every one is null)")


def _check_angular_velocity(key, w, d):
    if d == 1:
        raise _Located(key, "has no meaning in 1D")
    if d == 2 and not isinstance(w, (int, float)):
        raise _Located(key, "must be a scalar in 2D")
    if d == 3 and isinstance(w, (int, float)):
        raise _Located(key, "must be a vector [wx, wy, wz] in 3D")
    if d == 3:
        _need_len(key, w, 3)


def _check_shape(key, s, d):
    for attr in ("center", "lower", "upper", "translate"):
        v = getattr(s, attr, None)
        if v is not None:
            _need_len(f"{key}.{attr}", v, d if attr != "translate" or d > 1 else 1)
    if isinstance(s, Ring) and d == 1:
        raise _Located(f"{key}.type", "a ring needs dim 2 or 3")
    if isinstance(s, Cylinder) and d != 3:
        raise _Located(f"{key}.type", "a cylinder needs dim 3 (use box or sphere in 1D/2D)")
    if isinstance(s, Cylinder) and s.inner_radius >= s.radius:
        raise _Located(f"{key}.inner_radius", "inner_radius must be smaller than radius")
    if isinstance(s, Mesh) and d == 1:
        raise _Located(f"{key}.type", "a mesh needs dim 2 or 3")
    if isinstance(s, Mesh) and isinstance(s.scale, list) and len(s.scale) not in (d, 3):
        raise _Located(f"{key}.scale", f"must be a number or {d} numbers, got {len(s.scale)}")
    rot = getattr(s, "rotation", None)
    if rot is not None:
        if d == 1:
            raise _Located(f"{key}.rotation", "has no meaning in 1D")
        if d == 2 and not isinstance(rot, (int, float)):
            raise _Located(f"{key}.rotation", "must be a scalar angle in degrees in 2D")
        if d == 3 and not isinstance(rot, (int, float)):
            _need_len(f"{key}.rotation", rot, 3)


# ---------------------------------------------------------------- overrides
def parse_value(text: str) -> Any:
    """`--set` values are YAML scalars or flow lists: 0.01, cubic, [0,-2,0], true, null."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def parse_overrides(pairs) -> dict[str, Any]:
    """["solver.basis=cubic", "bodies.0.velocity=[0,-2,0]"] -> {"solver.basis": "cubic", ...} (values still text)."""
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        key = key.strip()
        if not sep or not key or any(not part for part in key.split(".")):
            raise ConfigError(f"--set expects KEY=VALUE with a dotted KEY (e.g. solver.basis=cubic), got {pair!r}")
        out[key] = value
    return out


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
            here = ".".join(parts[: i + 1])
            if isinstance(node, list):
                try:
                    idx = int(part)
                    node[idx]
                except (ValueError, IndexError):
                    raise ConfigError(f"--set {dotted}: no list item '{part}' (the list has {len(node)} items, "
                                      f"numbered from 0)", key=here) from None
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
                raise ConfigError(f"--set {dotted}: cannot set a key inside the value {node!r}",
                                  key=".".join(parts[:i])) from None
    return data


# ---------------------------------------------------------------- loading
def _line_index(node, path=(), out=None, file=None, seen_nodes=None):
    """Map dotted key paths to 1-based line numbers from a composed YAML node tree; duplicate keys are errors."""
    out = {} if out is None else out
    seen_nodes = set() if seen_nodes is None else seen_nodes
    if isinstance(node, (yaml.MappingNode, yaml.SequenceNode)):
        if id(node) in seen_nodes:  # an alias: its lines are those of its anchor (walking it again can explode)
            return out
        seen_nodes.add(id(node))
    if isinstance(node, yaml.MappingNode):
        seen = set()
        for k, v in node.value:
            p = path + (str(k.value),)
            key = ".".join(p)
            if key in seen:
                raise ConfigError("duplicate key", key=key, line=k.start_mark.line + 1, file=file)
            seen.add(key)
            out[key] = k.start_mark.line + 1
            _line_index(v, p, out, file, seen_nodes)
    elif isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            p = path + (str(i),)
            out[".".join(p)] = v.start_mark.line + 1
            _line_index(v, p, out, file, seen_nodes)
    return out


MAX_VALUES = 100_000  # values (after alias expansion) in one YAML file; configs and studies hold hundreds


def _small(data, limit) -> bool:
    """Whether nested lists/dicts hold at most `limit` values, counting shared (aliased) ones each time."""
    stack, n = [data], 0
    while stack:
        v = stack.pop()
        n += 1
        if n > limit:
            return False
        if isinstance(v, dict):
            stack.extend(v.keys())
            stack.extend(v.values())
        elif isinstance(v, list):
            stack.extend(v)
    return True


def read_yaml(path) -> tuple[dict, dict]:
    """Return (data, line index) of a YAML file; ConfigError for a missing, empty or non-YAML file."""
    path = Path(path)
    try:  # (exists() raises for a name too long: tests/test_fuzz.py)
        found, is_file = path.exists(), path.is_file()
    except (OSError, ValueError) as e:
        raise ConfigError(f"cannot read the file: {e}") from None
    if not found:
        raise ConfigError(f"config file not found: {path}")
    if not is_file:
        raise ConfigError(f"not a file: {path}")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read the file: {e}", file=path) from None
    loader = None
    try:  # parse once: the node tree gives the lines, the same tree gives the data (what yaml.safe_load does)
        loader = yaml.SafeLoader(text)
        node = loader.get_single_node()
        data = loader.construct_document(node) if node is not None else None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        problem = getattr(e, "problem", None) or str(e)
        raise ConfigError(f"not valid YAML: {problem}", file=path, line=mark.line + 1 if mark else None) from None
    except RecursionError:  # the parser recurses per nesting level (found by tests/test_fuzz.py)
        raise ConfigError("not valid YAML: nested too deeply", file=path) from None
    finally:
        if loader is not None:
            loader.dispose()
    if not _small(data, MAX_VALUES):  # aliases (&a / *a) can expand a short file to billions of values
        raise ConfigError(f"the file expands to more than {MAX_VALUES} values (through YAML aliases?)", file=path)
    if data is None:
        raise ConfigError("the file is empty (expected a YAML mapping of keys)", file=path)
    if not isinstance(data, dict):
        raise ConfigError(f"the top level must be a mapping of keys (name, dim, domain, ...), got a {type(data).__name__}",
                          file=path, line=1)
    return data, _line_index(node, file=path)


def _nearest_line(lines: dict, key: str):
    parts = (key or "").split(".")
    while parts and parts[0]:
        k = ".".join(parts)
        if k in lines:
            return lines[k]
        parts.pop()
    return None


def _walk(data, loc, missing: bool):
    """Dotted key of a pydantic error location, without the union/discriminator tags pydantic inserts
    (they are the location items that are not keys of the data); also returns the value there and
    whether a tag was skipped."""
    out, node, skipped = [], data, []
    for i, item in enumerate(loc):
        if isinstance(node, dict) and item not in node and not isinstance(item, (list, dict)):
            # pydantic names a key that is not text (null, 1.5) by its str() (found by tests/test_fuzz.py)
            item = next((k for k in node if str(k) == str(item)), item)
        if isinstance(node, dict) and item in node:
            node = node[item]
        elif isinstance(node, list) and isinstance(item, int) and 0 <= item < len(node):
            node = node[item]
        elif missing and i == len(loc) - 1:
            node = None
        else:
            skipped.append(item)
            continue
        out.append(str(item))
    return ".".join(out), node, skipped


def _describe(err, data) -> tuple[str, str]:
    ctx_err = (err.get("ctx") or {}).get("error")
    key, value, skipped = _walk(data, err["loc"], err["type"] == "missing")
    if isinstance(ctx_err, _Located):
        return ".".join(p for p in (key, ctx_err.key) if p), str(ctx_err)
    kind, msg = err["type"], err["msg"]
    if kind == "extra_forbidden":
        return key, "unknown key" + (" '' (an empty name)" if err["loc"][-1] == "" else "")
    if kind == "invalid_key" or "[key]" in err["loc"]:
        return key, "keys must be text (a key here is a number, a boolean or null)"
    if kind == "missing":
        return key, "required key is missing"
    if kind in ("union_tag_invalid", "union_tag_not_found"):
        tag = str((err.get("ctx") or {}).get("discriminator", "")).strip("'")
        what, names = ("model", MODEL_NAMES) if tag == "model" else ("shape type", SHAPE_TYPES)
        if kind == "union_tag_invalid":
            return key + "." + tag, (f"unknown {what} {err['ctx'].get('tag')!r} (expected one of {', '.join(names)})")
        return key, f"a {'material' if tag == 'model' else 'shape'} needs a '{tag}' (one of {', '.join(names)})"
    if any(s not in SHAPE_TYPES and s not in MODEL_NAMES for s in skipped):  # a number-or-list union: one message
        return key, f"must be a number or a list of numbers (got {_brief(value)})"
    if kind == "value_error":
        return key, msg[len("Value error, "):] if msg.startswith("Value error, ") else msg
    if kind == "too_short":
        n = (err.get("ctx") or {}).get("min_length", 1)
        return key, f"needs at least {n} item{'s' if n != 1 else ''}"
    msg = msg.replace("Input should be", "must be")
    if "input" in err and not isinstance(err["input"], dict):
        msg += f" (got {_brief(err['input'])})"
    return key, msg


_short = reprlib.Repr()  # a bad value in a message, cut short (it may be huge, or aliased YAML)
_short.maxlevel, _short.maxlist, _short.maxdict, _short.maxstring, _short.maxother = 3, 6, 6, 60, 60
_brief = _short.repr


def _from_override(key: str, overrides: dict | None):
    for k in overrides or {}:
        if key == k or key.startswith(k + ".") or k.startswith(key + "."):
            return k
    return None


def validate(data: dict, lines: dict | None = None, file=None, overrides: dict | None = None) -> Config:
    """Validate a config dict; on failure raise one ConfigError naming the key path and the file line."""
    lines = lines or {}
    try:
        return Config.model_validate(data)
    except ValidationError as e:
        try:
            key, msg = _describe(e.errors()[0], data)
        except Exception:  # formatting a strange input must never end in a traceback: fall back to pydantic's words
            first = e.errors()[0]
            key, msg = ".".join(str(p) for p in first["loc"]), str(first["msg"])
        n_more = len({str(err["loc"][:1]) + err["type"] for err in e.errors()[1:]})
        if n_more and not msg.startswith("must be a number or a list"):
            msg += f" (and {n_more} more problem{'s' if n_more > 1 else ''})"
        source = _from_override(key, overrides)
        if source is not None and overrides is not None:
            raise ConfigError(f"{msg} (from --set {source}={overrides[source]})", key=key or None) from None
        raise ConfigError(msg, key=key or None, line=_nearest_line(lines, key), file=file) from None


def locate(err: ConfigError, cfg: Config) -> ConfigError:
    """Give a ConfigError raised after validation (e.g. by the scene builder: body outside the domain)
    the file and line of its key in the config the Config came from."""
    if err.line is not None or err.file is not None or not err.key or not isinstance(cfg, Config):
        return err
    prefix = f"key '{err.key}': "
    message = str(err)[len(prefix):] if str(err).startswith(prefix) else str(err)
    source = _from_override(err.key, cfg._overrides)
    if source is not None:
        return ConfigError(f"{message} (from --set {source}={cfg._overrides[source]})", key=err.key)
    if cfg._source is None:
        return err
    return ConfigError(message, key=err.key, line=_nearest_line(cfg._lines, err.key), file=cfg._source)


def load_config(source, overrides: dict[str, Any] | None = None) -> Config:
    """Load and validate a config from a YAML path, a dict or a `Config`; apply dotted overrides first."""
    file: str | Path | None = None
    lines: dict = {}
    if isinstance(source, Config):
        file, lines = source._source, source._lines
        source = source.to_dict()
    if isinstance(source, dict):
        data = source
    elif isinstance(source, (str, os.PathLike)):
        data, lines = read_yaml(source)
        file = Path(source)
    else:  # None, a list, a number (found by tests/test_fuzz.py): not a config
        raise ConfigError(f"a config must be a mapping of keys (name, dim, domain, ...), got a {type(source).__name__}")
    data = apply_overrides(data, overrides)
    cfg = validate(data, lines, file, overrides)
    cfg._source = str(file) if file else None
    cfg._lines = lines
    cfg._overrides = dict(overrides or {})
    return cfg
