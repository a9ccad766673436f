"""The size of a run, estimated from the config alone before anything is allocated or generated.

`estimate(cfg)` counts particles (shape volume x (particles_per_cell / dx)^dim per body), their memory (the
solver's fields, as in `Simulation._bytes_per_particle`, plus the scene's host arrays), the grid's memory (dense:
every node; sparse: the pointer arrays, which are dense, plus the leaf blocks around the bodies), the steps
(end_time / dt, dt from the CFL rule unless solver.dt is given) and the outputs (end_time / output.every).
A mapped grid (`domain.map`) is sized from its map: nodes are its control points in parameter space, each
particle keeps its parametric coordinates, the map keeps its control points, weights and wall normals, and the CFL
rule uses its smallest cell.
`check(cfg)` refuses a run that does not fit (ConfigError, exit 2) and warns about absurd step or output counts,
which are usually a unit slip (E in Pa given as GPa x 1e9 twice, dt = 1e-12, output.every = 1e-9).
See docs/reliability.md.
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass

import numpy as np

from .extensions import scatter
from .backend import resolve_arch
from .bases import registry as bases
from .bases.shape_functions import configured_basis
from .bases.knots import grid_knots, smallest_span
from .bases import mapgeom
from .config import Config, ConfigError
from .grid import LEAF, MAX_TOP_POINTERS, _pow2
from . import layout
from .materials import wave_speed
from .scene import base_dir_of, shape_bounds, shape_volume

# explicit viscous diffusion: dt <= cfl rho dx^2 / (VISCOUS_DIFFUSION d mu), the finite-difference bound
# dx^2 / (2 d nu). Measured (2D, dx 0.05, APIC, fixed dt, 100 steps): blow-up above 0.25-0.35 rho dx^2 / mu
# for linear and 0.35-0.5 for quadratic, against 0.25 here at cfl 1 (0.1 at the default cfl 0.4)
VISCOUS_DIFFUSION = 2.0


MEMORY_FRACTION = 0.5      # default limit: this share of the machine's physical memory (also on GPUs)
MAX_STEPS = 1e7            # warn above: a unit slip, or a run of days
RUN_STEPS = 1e8            # refuse above (limits.steps, the opt-in): days of steps at the smallest scenes' ~1 ms a step
MAX_OUTPUTS = 1e4          # warn above: tens of thousands of files
MAX_ELEMENTS = 2**31 - 1   # Taichi indexes fields with i32: not overridable
POINTER_SLOT_BYTES = 16    # a Taichi pointer SNode keeps a pointer and a lock per slot (measured 16.5 B/slot, CPU)
# building a mapped grid (host, numpy): the refined net (homogeneous copies) per control point, and per cell the
# parameter samples the solver's first particle location starts from (9 a cell: points, parameters, their local
# basis evaluation and the sort into buckets)
MAP_BYTES_PER_CONTROL_POINT, MAP_BYTES_PER_CELL = 72, 9 * 700
EXACT_CORNERS = 1_000_000  # a nurbs map's smallest cell from every refined corner up to this many, else sampled
HOST_FLOATS, HOST_INTS = 4, 5  # scene arrays per particle besides x and v: volume, mass, damage, spacing (f64);
#                                body, material, interface (i32) and the solver's sort permutation (i64)


class SizeWarning(UserWarning):
    """A run that fits but looks wrong: absurdly many steps or outputs, or a refused size run anyway."""


@dataclass
class Estimate:
    particles: int                 # all bodies
    per_body: list[int]
    device_bytes_per_particle: int  # the solver's particle fields
    host_bytes_per_particle: int    # the scene's numpy arrays
    grid_cells: list[int]
    grid_bytes: int
    grid_detail: str
    lattice_bytes: int             # transient: the largest body's bounding-box lattice while its particles are made
    dt: float
    dt_source: str
    steps: float
    outputs: float
    limit_bytes: float | None
    limit_source: str
    map_build_bytes: int = 0       # transient: building a mapped grid's net and its first particle location
    dt_limits: dict = None         # rate -> (dt, keys that set it), as Simulation.dt_limits at t = 0
    grid_key: str = "domain.dx"    # the key that sets the grid's size
    grids: list = None             # each grid's size (GridSize), the main one first

    @property
    def particle_bytes(self) -> int:
        return self.particles * (self.device_bytes_per_particle + self.host_bytes_per_particle)

    @property
    def total_bytes(self) -> int:
        """Peak: the scene's arrays plus either the lattice being filled or the solver's fields and grid."""
        host = self.particles * self.host_bytes_per_particle
        return host + max(self.lattice_bytes, self.particles * self.device_bytes_per_particle + self.grid_bytes
                          + self.map_build_bytes)

    def summary(self) -> str:
        limit = f" of {_gb(self.limit_bytes)} allowed ({self.limit_source})" if self.limit_bytes else ""
        return (f"estimate: {self.particles:,} particles ({_gb(self.particle_bytes)}), grid "
                f"{'x'.join(map(str, self.grid_cells))} cells {self.grid_detail} ({_gb(self.grid_bytes)}); "
                f"memory {_gb(self.total_bytes)}{limit}; {self.steps:.3g} steps (dt {self.dt:.3g} {self.dt_source}), "
                f"{self.outputs:.3g} outputs")


def _gb(n) -> str:
    return f"{n / 1e9:.3g} GB" if n >= 1e8 else f"{n / 1e6:.3g} MB"


def physical_memory() -> float | None:
    """Bytes of physical memory (os.sysconf), or None where the platform does not say."""
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def _limit(cfg: Config) -> tuple[float | None, str]:
    if cfg.limits.memory_gb is not None:
        return cfg.limits.memory_gb * 1e9, "limits.memory_gb"
    phys = physical_memory()
    if phys is None:
        return None, "no limit: physical memory unknown"
    return MEMORY_FRACTION * phys, f"{MEMORY_FRACTION:.0%} of this machine's {phys / 1e9:.3g} GB"


def needs(cfg: Config, body_force: bool = False) -> layout.Needs:
    """The scene's optional fields, from the config alone (layout.Needs.of_config; the solver's of_simulation
    agrees: tests/test_layout_budget.py)."""
    return layout.Needs.of_config(cfg, body_force, _coloured_scatter(cfg), configured_basis(cfg))


def device_bytes_per_particle(cfg: Config, body_force: bool = False) -> int:
    """The per-particle fields the solver, the crack finder and the extensions allocate: their declaration
    (layout.particle_fields), so the estimate is what Simulation.bytes_per_particle reports."""
    return layout.nbytes(layout.particle_fields(needs(cfg, body_force)), cfg.precision)


def _coloured_scatter(cfg: Config) -> bool:
    """Whether the solver bins particles for P2G's coloured scatter, on the arch a run gets, for the particle count
    estimated here (the solver decides on its count: near scatter.ATOMIC_BELOW the two may differ by the bins'
    8 bytes a particle)."""
    return scatter.coloured(cfg, gpu=resolve_arch(cfg.arch) != "cpu", particles=sum(body_particles(cfg)[0]))


@dataclass
class MapSize:
    """A mapped grid's sizes from its config alone (nothing built; mapgeom.refined_shape / annulus_shape): control
    points and cells per axis, the nodes stored (a full ring or a periodic patch stores its seam column once),
    the smallest cell (the CFL rule's) and the key that sets the size."""
    ctrl: list[int]
    cells: list[int]
    shape: list[int]
    h_min: float
    key: str
    degree: int = 2

    def field_floats(self) -> int:
        """As MappedGrid.field_floats: control points (d) and weights (1) per control point, wall normals (2 d x d)
        per node."""
        d = len(self.ctrl)
        return (d + 1) * math.prod(self.ctrl) + 2 * d * d * math.prod(self.shape)

    def knot_floats(self) -> int:
        """Per axis, the knot vector (control points + p + 1 knots) and its Greville abscissae (one per control point:
        bases.shape_functions.KnotData), which MappedGrid.field_floats leaves out."""
        return sum(2 * c + self.degree + 1 for c in self.ctrl)

    def build_bytes(self) -> int:
        return MAP_BYTES_PER_CONTROL_POINT * math.prod(self.ctrl) + MAP_BYTES_PER_CELL * math.prod(self.cells)


def map_size(cfg: Config) -> MapSize | None:
    """The size of `domain.map` (None without one), estimated before anything is built."""
    m = cfg.domain.map
    if m is None:
        return None
    degree = bases.get(cfg.solver.basis).degree      # the map is raised to the basis' degree
    if m.type == "annulus":
        ctrl, cells = mapgeom.annulus_shape(m.angle, m.cells, degree)
        periodic, key = m.angle >= 360.0, "domain.map.cells"
        angle, (n_angle, n_radial) = math.radians(m.angle), m.cells
        h_min = min(m.inner_radius * 2 * math.sin(0.5 * angle / n_angle), (m.outer_radius - m.inner_radius) / n_radial)
    elif m.type in ("cylinder", "shell"):
        ctrl, cells = mapgeom.solid_map_shape(m, degree)
        periodic, key = m.angle >= 360.0, "domain.map.cells"
        h_min = mapgeom.solid_map_cell_sizes(m)[0]
    else:
        net = mapgeom.config_net(m)
        ctrl, cells = mapgeom.refined_shape(net[0], m.refine, degree)
        periodic, key = m.periodic, "domain.map.refine"
        h_min = _nurbs_h_min(m, net, cells)
    shape = [ctrl[0] - 1 if periodic else ctrl[0]] + list(ctrl[1:])
    return MapSize(ctrl=ctrl, cells=cells, shape=shape, h_min=h_min, key=key, degree=degree)


def _nurbs_h_min(m, net, cells) -> float:
    """The smallest refined cell edge (MappedGrid's h_min) on the given net: the chords between the refined
    corners (the same points: refinement does not change the map) up to EXACT_CORNERS of them; beyond, cells
    are so fine that a chord is |dx/dxi| x its parameter width, sampled at FOLD_SAMPLES points per axis."""
    from .config import FOLD_SAMPLES

    given, P, w = net
    d = len(given)
    knots = [mapgeom.scaled_knots(t, n) for t, n in zip(given, cells)]
    if math.prod(n + 1 for n in cells) <= EXACT_CORNERS:
        breaks = []
        for t, k in zip(knots, m.refine):
            b = np.unique(t)
            breaks.append(np.unique(np.concatenate([np.linspace(lo, hi, k + 1) for lo, hi in zip(b[:-1], b[1:])])))
        return mapgeom.cell_sizes(knots, [2] * d, P, w, breaks)[0]
    s = [np.linspace(0.0, n, (FOLD_SAMPLES if d == 2 else 16) + 1) for n in cells]
    xi = np.stack(np.meshgrid(*s, indexing="ij"), -1).reshape(-1, d)
    _, J = mapgeom.surface(knots, [2] * d, P, w, xi)
    width = [float(np.diff(np.unique(t)).min()) / k for t, k in zip(knots, m.refine)]   # the narrowest refined span
    return float(min((np.linalg.norm(J[:, :, a], axis=1) * width[a]).min() for a in range(d)))


def grid_layout(cfg: Config, mapped: MapSize | None = None) -> dict:
    """Nodes per axis and, for a sparse grid, the pointer levels as `grid.Grid` builds them. A mapped grid's
    nodes are its control points (parameter space), not the box divided by domain.dx."""
    basis = configured_basis(cfg)
    mapped = mapped if mapped is not None else map_size(cfg)
    if mapped is not None:
        cells, nodes = list(mapped.cells), list(mapped.shape)
    else:
        cells = [round((u - l) / cfg.domain.dx) for l, u in zip(cfg.domain.lower, cfg.domain.upper)]
        nodes = [basis.axis(a).nodes(c) for a, c in enumerate(cells)]
    out = dict(cells=cells, nodes=nodes, stencil=basis.stencil)
    if cfg.domain.sparse:
        out.update(sparse_levels(nodes))
    return out


def sparse_levels(nodes: list[int], leaf: int = 0) -> dict:
    """The pointer levels grid.Grid builds over a sparse grid of these nodes per axis (leaf: nodes per axis of a
    leaf block, 0: LEAF[d]): the levels' extents, the second level's extent per axis (1: none), the leaf block's
    nodes per axis and the blocks per axis."""
    d = len(nodes)
    leaf = leaf or LEAF[d]
    blocks = [_pow2(math.ceil(s / leaf)) for s in nodes]
    if math.prod(blocks) <= MAX_TOP_POINTERS:
        return dict(levels=[blocks], mid=1, leaf=leaf, blocks=blocks)
    mid = 8 if d == 3 else 64  # grid.Grid's second level
    return dict(levels=[[_pow2(math.ceil(b / mid)) for b in blocks], [mid] * d], mid=mid, leaf=leaf, blocks=blocks)


def _active_blocks(cfg: Config, layout: dict, base_dir) -> tuple[int, int]:
    """(leaf blocks, top pointer slots) the bodies' stencils touch, each body's bounding box grown by a stencil."""
    d, leaf, per_cell = cfg.dim, layout["leaf"], bases.get(cfg.solver.basis).nodes_per_cell
    dx = cfg.domain.dx / per_cell   # the storage nodes' spacing (ck: half a cell)
    lower = np.asarray(cfg.domain.lower, float)
    reach = layout["stencil"] - (per_cell - 1)   # ck: its window of 4 storage nodes spans 3 half cells
    leaves = tops = 0
    for i, b in enumerate(cfg.bodies):
        lo, hi = shape_bounds(b.shape, d, base_dir, f"bodies.{i}.shape")
        n0 = np.floor((lo - lower) / dx) - reach
        n1 = np.ceil((hi - lower) / dx) + reach
        per_axis = [min(nb, int(v1 // leaf) - int(max(v0, 0) // leaf) + 1)
                    for v0, v1, nb in zip(n0, n1, layout["blocks"])]
        leaves += math.prod(per_axis)
        tops += math.prod(math.ceil(n / layout["mid"]) + 1 for n in per_axis)
    return min(leaves, math.prod(layout["blocks"])), min(tops, math.prod(layout["levels"][0]))


@dataclass
class GridSize:
    """One grid's estimated size (layout.GridDecl): nodes per axis, bytes per node and per leaf block (the
    block fields), and, sparse, the top pointer slots, the active top slots and leaf blocks (the bodies'
    stencils' blocks: an estimate; the rest follows from the declaration exactly)."""
    name: str
    nodes: list
    sparse: bool
    node_bytes: int
    block_bytes: int
    top_slots: int = 0
    mid: int = 1
    leaf: int = 1
    tops: int = 0
    leaves: int = 0

    @property
    def bytes(self) -> int:
        d = len(self.nodes)
        if not self.sparse:
            blocks = math.prod(math.ceil(n / self.leaf) for n in self.nodes)
            return math.prod(self.nodes) * self.node_bytes + blocks * self.block_bytes
        pointers = self.top_slots + (self.tops * self.mid ** d if self.mid > 1 else 0)
        return pointers * POINTER_SLOT_BYTES + self.leaves * (self.leaf ** d * self.node_bytes + self.block_bytes)


def grid_sizes(cfg: Config, base_dir, mapped: MapSize | None = None, body_force: bool = False) -> list[GridSize]:
    """Every grid the scene allocates (layout.grids), sized."""
    d, lay = cfg.dim, grid_layout(cfg, mapped)
    out = []
    for g in layout.grids(needs(cfg, body_force)):
        linear = g.extent == "linear"
        nodes = [c + 1 for c in lay["cells"]] if linear else list(lay["nodes"])
        size = GridSize(g.name, nodes, cfg.domain.sparse or g.always_sparse, g.node_bytes(d, cfg.precision),
                        4 * g.block_ints, leaf=_leaf(cfg, g))
        if size.sparse:
            levels = sparse_levels(nodes, size.leaf)
            size.top_slots, size.mid, size.leaf = math.prod(levels["levels"][0]), levels["mid"], levels["leaf"]
            if mapped is not None:
                # bodies are given in physical space: the parameter blocks they touch are not known without
                # inverting the map, so count every block (a map's grid is small: the bound costs little)
                size.leaves, size.tops = math.prod(levels["blocks"]), size.top_slots
            else:
                reach = 2 if linear else lay["stencil"]
                size.leaves, size.tops = _active_blocks(cfg, dict(levels, stencil=reach), base_dir)
        out.append(size)
    return out


def _bin_list_bytes(cfg: Config, particles: int, nodes: list[int], body_force: bool) -> int:
    """The coloured scatter's list of occupied blocks (one entry per leaf block, at most one per particle) and its
    colour tables."""
    if not needs(cfg, body_force).coloured:
        return 0
    blocks = math.prod(math.ceil(n / _main_leaf(cfg)) for n in nodes)
    return layout.scatter_fixed_bytes(cfg.dim, max(1, min(particles, blocks)))


def _main_leaf(cfg: Config) -> int:
    """Nodes per axis of the main grid's leaf blocks: LEAF[d], twice that on ck's half-spacing grid (solver.py)."""
    return LEAF[cfg.dim] * bases.get(cfg.solver.basis).nodes_per_cell


def _leaf(cfg: Config, decl) -> int:
    """Nodes per axis of a grid's leaf blocks: the main grid's (layout.main_grid), LEAF[d] for the others."""
    return _main_leaf(cfg) if decl.name == "grid" else LEAF[cfg.dim]


def _grid_bytes(cfg: Config, base_dir, mapped: MapSize | None = None, particles: int = 0,
                body_force: bool = False) -> tuple[int, str, list[int], list[GridSize]]:
    size = 8 if cfg.precision == "f64" else 4
    grids = grid_sizes(cfg, base_dir, mapped, body_force)
    total = sum(g.bytes for g in grids) + _bin_list_bytes(cfg, particles, grids[0].nodes, body_force)
    total += (mapped.field_floats() + mapped.knot_floats()) * size if mapped is not None else 0
    if mapped is not None and any(t.apply_to == "nodes" for b in cfg.bodies for t in b.tractions):
        total += cfg.dim * math.prod(mapped.shape) * size   # the nodal tractions' forces (extensions/node_loads.py)
    cells = grid_layout(cfg, mapped)["cells"]
    main = grids[0]
    if not main.sparse:
        return total, f"dense, {math.prod(main.nodes):.3g} nodes", cells, grids
    return total, f"sparse, {main.top_slots:.3g} top pointers, ~{main.leaves:,} active blocks", cells, grids


def _modulus_key(m) -> str:
    return "E" if "E" in type(m).model_fields else "K"


def _initial_speed(cfg: Config, base_dir) -> tuple[float, str | None]:
    """The largest initial particle speed the config states (velocity, spin about the body's centre, numeric grip
    velocities) and its key; an expression of position counts with its largest magnitude over 5 points per axis
    of the body's box (expressions.largest_magnitude), grip expressions of time as 0."""
    from .config import SPACE
    from .expressions import largest_magnitude

    vmax, key = 0.0, None
    for i, b in enumerate(cfg.bodies):
        at = {}
        if b.velocity is not None and any(isinstance(c, str) for c in b.velocity):
            lo, hi = shape_bounds(b.shape, cfg.dim, base_dir, f"bodies.{i}.shape")
            grid = np.meshgrid(*[np.linspace(l, h, 5) for l, h in zip(lo, hi)], indexing="ij")
            at = {SPACE[a]: g.ravel() for a, g in enumerate(grid)}
        with np.errstate(over="ignore"):
            v = float(np.linalg.norm([largest_magnitude(c, SPACE, **at) for c in b.velocity] or [0.0])) \
                if b.velocity is not None else 0.0
            if b.angular_velocity is not None:
                lo, hi = shape_bounds(b.shape, cfg.dim, base_dir, f"bodies.{i}.shape")
                v += float(np.linalg.norm(np.atleast_1d(b.angular_velocity))) * 0.5 * float(np.linalg.norm(hi - lo))
        if v > vmax or key is None:
            vmax, key = v, f"bodies.{i}.{'velocity' if b.velocity is not None else 'angular_velocity'}"
        for j, g in enumerate(b.prescribed_velocity):
            with np.errstate(over="ignore"):
                vg = float(np.linalg.norm([c for c in g.velocity if isinstance(c, (int, float))] or [0.0]))
            if vg > vmax:
                vmax, key = vg, f"bodies.{i}.prescribed_velocity.{j}.velocity"
    return vmax, key


def _cell(cfg: Config, mapped: MapSize | None) -> tuple[float, str]:
    """The CFL rule's cell size (Simulation.h_cfl) and its key: a map's smallest cell, else dx or the shortest
    knot span of domain.knots."""
    if mapped is not None:
        return mapped.h_min, mapped.key
    h = smallest_span(cfg)
    if h < cfg.domain.dx:
        spans = [(smallest_span_axis(cfg, a), a) for a in range(cfg.dim)]
        return h, f"domain.knots.{'xyz'[min(spans)[1]]}"
    return h, "domain.dx"


def smallest_span_axis(cfg: Config, a: int) -> float:
    t = (grid_knots(cfg) or [None] * cfg.dim)[a]
    if t is None:
        return cfg.domain.dx
    spans = np.diff(t)
    return float(spans[spans > 0].min()) * cfg.domain.dx


def dt_limits(cfg: Config, base_dir=None, mapped: MapSize | None = None) -> dict:
    """The time-step bound of every rate at t = 0 (seconds), with the keys that set it, from the config alone: the
    rule of Simulation.dt_limits (solver.py) with the config's values. elastic / speed: cfl h / (c + |v|max), c the
    fastest P-wave speed (snow: hardened to max_hardening); gravity: cfl sqrt(h / |g|); viscosity:
    cfl rho h^2 / (VISCOUS_DIFFUSION d mu). h: the smallest cell (domain.dx, a knot span, a map's cell)."""

    base_dir = base_dir_of(cfg) if base_dir is None else base_dir
    mapped = map_size(cfg) if mapped is None and cfg.domain.map is not None else mapped
    cfl, (h, h_key) = cfg.solver.cfl * bases.get(cfg.solver.basis).cfl_factor, _cell(cfg, mapped)
    used = dict.fromkeys(b.material for b in cfg.bodies)
    with np.errstate(over="ignore", invalid="ignore"):
        c, which = max((wave_speed(cfg.materials[name]), name) for name in used)
    v, v_key = _initial_speed(cfg, base_dir)
    mat = cfg.materials[which]
    keys = (f"materials.{which}.{_modulus_key(mat)}", f"materials.{which}.density", h_key)
    if h_key.startswith("domain.knots"):   # a knot span shorter than dx: the unusual one of the three
        keys = (h_key,) + keys[:2]
    out = {}
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        if c >= v:
            out["elastic"] = (cfl * h / (c + v) if c + v > 0 else math.inf, keys)
        else:
            out["speed"] = (cfl * h / (c + v), (v_key, h_key))
        g = float(np.linalg.norm(cfg.gravity))
        if g > 0:
            out["gravity"] = (cfl * math.sqrt(h / g), ("solver.gravity", h_key))
        for name in used:
            m = cfg.materials[name]
            mu = getattr(m, "viscosity", 0.0)
            if mu > 0:
                dt_v = cfl * m.density * h * h / (VISCOUS_DIFFUSION * cfg.dim * mu)
                if dt_v < out.get("viscosity", (math.inf,))[0]:
                    out["viscosity"] = (dt_v, (f"materials.{name}.viscosity", f"materials.{name}.density", h_key))
    return out


def _time_step(cfg: Config, base_dir, mapped: MapSize | None = None) -> tuple[float, str, dict]:
    limits = dt_limits(cfg, base_dir, mapped)
    s = cfg.solver
    if s.dt is not None:
        return s.dt, "from solver.dt", limits
    rate = min(limits, key=lambda k: limits[k][0])
    dt, keys = limits[rate]
    if not dt > 0 or not math.isfinite(dt):   # so fast a rate that the step underflows (found by tests/test_fuzz.py)
        c = max(wave_speed(cfg.materials[b.material]) for b in cfg.bodies)
        raise ConfigError(f"the time step underflows to zero ({rate} limit: wave speed {c:.3g} m/s, "
                          f"domain.dx = {cfg.domain.dx:g}; set by {', '.join(keys)}): check the units", key=keys[0])
    if rate == "elastic":
        which = next(k.split(".")[1] for k in keys if k.startswith("materials."))
        c = wave_speed(cfg.materials[which])
        return dt, f"from the CFL rule: wave speed {c:.3g} m/s of material '{which}'", limits
    return dt, f"from the CFL rule: {rate} limit ({', '.join(keys[:-1])})", limits


def body_particles(cfg: Config) -> tuple[list[int], int]:
    """Each body's particle count (shape volume x (particles_per_cell / dx)^dim) and the largest body's lattice
    bytes while its particles are made."""
    d, dx = cfg.dim, cfg.domain.dx
    base_dir = base_dir_of(cfg)
    per_body, lattice = [], 0
    for i, b in enumerate(cfg.bodies):
        key = f"bodies.{i}.shape"
        h = dx / b.particles_per_cell
        count = shape_volume(b.shape, d, base_dir, key) / h**d if h**d > 0 else math.inf
        if not math.isfinite(count):  # dx so small that h^d underflows (found by tests/test_fuzz.py)
            raise ConfigError(f"domain.dx = {dx:g} gives body {i} more particles than can be counted: check the units",
                              key="domain.dx")
        per_body.append(int(round(count)))
        lo, hi = shape_bounds(b.shape, d, base_dir, key)
        lattice = max(lattice, math.prod(int(math.ceil(e / h)) + 1 for e in hi - lo) * d * 8 * 3)
    return per_body, lattice


def estimate(cfg: Config, body_force: bool = False) -> Estimate:
    """Sizes of a run from its config; reads mesh files (cached) but allocates and generates nothing."""
    base_dir = base_dir_of(cfg)
    per_body, lattice = body_particles(cfg)
    mapped = map_size(cfg)
    grid_bytes, grid_detail, cells, grids = _grid_bytes(cfg, base_dir, mapped, sum(per_body), body_force)
    dt, dt_source, limits = _time_step(cfg, base_dir, mapped)
    steps = cfg.solver.end_time / dt
    if cfg.solver.max_steps is not None and cfg.solver.max_steps < steps:
        steps, dt_source = float(cfg.solver.max_steps), dt_source + "; capped by solver.max_steps"
    limit, source = _limit(cfg)
    return Estimate(particles=sum(per_body), per_body=per_body,
                    device_bytes_per_particle=device_bytes_per_particle(cfg, body_force),
                    host_bytes_per_particle=16 * cfg.dim + 8 * HOST_FLOATS + 4 * HOST_INTS + 8,
                    grid_cells=cells, grid_bytes=grid_bytes, grid_detail=grid_detail, lattice_bytes=lattice,
                    dt=dt, dt_source=dt_source, steps=steps,
                    outputs=math.floor(cfg.solver.end_time / cfg.output.every) + 1.0,
                    limit_bytes=limit, limit_source=source,
                    map_build_bytes=mapped.build_bytes() if mapped is not None else 0, dt_limits=limits,
                    grid_key=mapped.key if mapped is not None else "domain.dx", grids=grids)


def check(cfg: Config, body_force: bool = False, warn: bool = True) -> Estimate:
    """Refuse a run that does not fit or would not end (ConfigError naming the key that drives its size or
    length, and the override); with `warn`, SizeWarning for absurdly many steps or outputs. Returns the estimate."""
    est = estimate(cfg, body_force)
    big = int(np.argmax(est.per_body))
    ppc_key = f"bodies.{big}.particles_per_cell"
    grid_key = est.grid_key
    sizes = (f"particles: {est.particles:.3g} ({_gb(est.particle_bytes)}); grid: {_gb(est.grid_bytes)}, "
             f"{est.grid_detail}")
    if est.map_build_bytes:
        sizes += f"; building the mapped grid: {_gb(est.map_build_bytes)}"
    grid_size = (f"{grid_key} = {_value(cfg, grid_key)}" if grid_key != "domain.dx"
                 else f"domain.dx = {cfg.domain.dx:g}")
    drivers = (f"the size follows {grid_size}, domain.sparse = {str(cfg.domain.sparse).lower()} "
               f"and {ppc_key} = {cfg.bodies[big].particles_per_cell}")

    def fix(grid_led: bool) -> str:
        if grid_led:
            if grid_key != "domain.dx":
                return f"a smaller {grid_key}"
            return "a coarser domain.dx" + (" or domain.sparse: true" if not cfg.domain.sparse else "")
        return f"fewer {ppc_key}, a coarser domain.dx or smaller bodies"

    layout = grid_layout(cfg)
    top = math.prod(layout["levels"][0] if cfg.domain.sparse else layout["nodes"])
    grid_led = top > MAX_ELEMENTS or (grid_key != "domain.dx" and math.prod(layout["nodes"]) > MAX_ELEMENTS)
    if est.particles > MAX_ELEMENTS or grid_led:
        raise ConfigError(f"{'the grid' if grid_led else 'the particles'} would need more than 2^31 elements in one "
                          f"field, more than Taichi can index ({sizes}); {drivers}: use {fix(grid_led)}",
                          key=grid_key if grid_led else ppc_key)
    grid_led = est.grid_bytes + est.map_build_bytes >= est.particles * est.device_bytes_per_particle
    key = grid_key if grid_led else ppc_key
    problems = []
    if est.limit_bytes is not None and est.total_bytes > est.limit_bytes:
        problems.append(f"the run needs about {_gb(est.total_bytes)} of memory ({sizes}), more than the limit of "
                        f"{_gb(est.limit_bytes)} ({est.limit_source})")
    if cfg.limits.particles is not None and est.particles > cfg.limits.particles:
        problems.append(f"about {est.particles:,} particles, more than limits.particles = {cfg.limits.particles:,}")
    for message in problems:
        if not cfg.limits.allow_large:
            raise ConfigError(f"{message}; {drivers}: use {fix(grid_led)}, raise limits.memory_gb / limits.particles, or pass "
                              "--allow-large (limits.allow_large: true) to run anyway", key=key)
        if warn:
            warnings.warn(f"key '{key}': {message}; running anyway (limits.allow_large)", SizeWarning, stacklevel=2)
    _check_length(cfg, est, warn)
    if warn:
        for message in size_warnings(cfg, est):
            warnings.warn(message, SizeWarning, stacklevel=2)
    return est


def _value(cfg: Config, key: str):
    node = cfg
    for part in key.split("."):
        node = node[int(part)] if isinstance(node, list) else getattr(node, part, None)
    return node


def _check_length(cfg: Config, est: Estimate, warn: bool):
    """Refuse a run of more steps than limits.steps (default RUN_STEPS): a rate far beyond the scene's (a unit slip
    in E, a viscosity, a knot span, an initial speed) would otherwise run until killed. The message names the keys
    of the rate that sets dt."""
    allowed = cfg.limits.steps if cfg.limits.steps is not None else RUN_STEPS
    if not est.steps > allowed:
        return
    limits = est.dt_limits or {}
    if cfg.solver.dt is not None:
        keys, why = ("solver.dt", "solver.end_time"), f"solver.dt = {cfg.solver.dt:g}"
    else:
        rate = min(limits, key=lambda k: limits[k][0])
        keys = limits[rate][1] + ("solver.end_time",)
        why = f"the {rate} limit of the time step (set by {', '.join(limits[rate][1])})"
    message = (f"about {est.steps:.3g} steps to solver.end_time = {cfg.solver.end_time:g} (dt {est.dt:.3g} from "
               f"{why}), more than {'limits.steps' if cfg.limits.steps is not None else 'the limit'} of "
               f"{allowed:.3g}: check the units of {', '.join(k for k in keys if k != 'solver.end_time')}")
    if not cfg.limits.allow_large:
        raise ConfigError(f"{message}; a shorter solver.end_time, solver.max_steps (stops the run there), "
                          f"limits.steps or --allow-large (limits.allow_large: true) runs it anyway", key=keys[0])
    if warn:
        warnings.warn(f"key '{keys[0]}': {message}; running anyway (limits.allow_large)", SizeWarning, stacklevel=3)


def size_warnings(cfg: Config, est: Estimate) -> list[str]:
    """Messages for runs that fit but are probably not what was meant."""
    out = []
    if est.steps > MAX_STEPS:
        out.append(f"about {est.steps:.3g} steps to solver.end_time = {cfg.solver.end_time:g} (dt {est.dt:.3g} "
                   f"{est.dt_source}, domain.dx = {cfg.domain.dx:g}): check the units of solver.dt, solver.end_time "
                   "and the materials' E/K and density; solver.max_steps caps a run")
    if est.outputs > MAX_OUTPUTS:
        out.append(f"output.every = {cfg.output.every:g} with solver.end_time = {cfg.solver.end_time:g} writes about "
                   f"{est.outputs:.3g} outputs (files for each of output.formats {', '.join(cfg.output.formats)})")
    return out
