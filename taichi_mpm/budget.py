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

from . import scatter
from .backend import resolve_arch
from .basis import make_basis
from .crack import grid_fields as crack_grid_fields
from .crack import particle_bytes as crack_particle_bytes
from .knots import grid_knots, smallest_span
from .mapped import MappedGrid
from .config import Config, ConfigError
from .grid import LEAF, MAX_TOP_POINTERS, _pow2
from . import materials as material_models
from .materials import wave_speed
from .scene import base_dir_of, shape_bounds, shape_volume

MEMORY_FRACTION = 0.5      # default limit: this share of the machine's physical memory (also on GPUs)
MAX_STEPS = 1e7            # warn above: a unit slip, or a run of days
MAX_OUTPUTS = 1e4          # warn above: tens of thousands of files
MAX_ELEMENTS = 2**31 - 1   # Taichi indexes fields with i32: not overridable
POINTER_SLOT_BYTES = 16    # a Taichi pointer SNode keeps a pointer and a lock per slot (measured 16.5 B/slot, CPU)
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

    @property
    def particle_bytes(self) -> int:
        return self.particles * (self.device_bytes_per_particle + self.host_bytes_per_particle)

    @property
    def total_bytes(self) -> int:
        """Peak: the scene's arrays plus either the lattice being filled or the solver's fields and grid."""
        host = self.particles * self.host_bytes_per_particle
        return host + max(self.lattice_bytes, self.particles * self.device_bytes_per_particle + self.grid_bytes)

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


def _used_materials(cfg: Config) -> list:
    return [cfg.materials[name] for name in dict.fromkeys(b.material for b in cfg.bodies)]


def device_bytes_per_particle(cfg: Config, body_force: bool = False) -> int:
    """The solver's particle fields (mirrors Simulation._bytes_per_particle and CrackFinder.bytes_per_particle;
    tests/test_budget.py holds them equal)."""
    d, size = cfg.dim, 8 if cfg.precision == "f64" else 4
    mats = _used_materials(cfg)
    apic = cfg.solver.transfer == "apic"
    viscous = any(getattr(m, "viscosity", 0.0) > 0 for m in mats)
    spacings = {cfg.domain.dx / b.particles_per_cell for b in cfg.bodies}
    floats = 2 * d + d * d + 1                                   # x, v, F, vol0
    floats += d * d if apic or viscous else 0                    # C (APIC's B_p or C_p, or grad v)
    floats += d if body_force else 0
    floats += 1 if cfg.solver.basis in ("gimp", "cpdi") and len(spacings) > 1 else 0   # domain half-widths
    floats += material_models.state_size(mats, d)                 # plastic strain, J_p, ... (materials/)
    floats += MappedGrid.PARTICLE_FLOATS if cfg.domain.map is not None else 0   # parametric coordinates xi_p
    n = floats * size + (1 if len(mats) > 1 else 0)
    if cfg.crack is not None:
        has_law = any(getattr(m, "tensile_strength", None) is not None and material_models.MODELS[m.model].damage
                      for m in mats)
        stencil_nodes = make_basis(cfg.solver.basis).contributions(d)
        n += crack_particle_bytes(d, cfg.precision, apic, has_law, stencil_nodes, cfg.crack)
    if _coloured_scatter(cfg):
        n += 4 + 4 * d   # scatter.BlockBins: order, home
    return n


def _coloured_scatter(cfg: Config) -> bool:
    """Whether the solver bins particles for P2G's coloured scatter, on the arch a run gets."""
    return scatter.coloured(cfg, gpu=resolve_arch(cfg.arch) != "cpu")


def _mapped(cfg: Config) -> MappedGrid | None:
    """The host side of a mapped grid (numpy only: allocates no Taichi field), or None."""
    return MappedGrid(cfg) if cfg.domain.map is not None else None


def grid_layout(cfg: Config, mapped: MappedGrid | None = None) -> dict:
    """Nodes per axis and, for a sparse grid, the pointer levels as `grid.Grid` builds them. A mapped grid's
    nodes are its control points (parameter space), not the box divided by domain.dx."""
    d = cfg.dim
    basis = make_basis(cfg.solver.basis, grid_knots(cfg))
    mapped = mapped if mapped is not None else _mapped(cfg)
    if mapped is not None:
        cells, nodes = [int(c) for c in mapped.map.n_cells], list(mapped.shape)
    else:
        cells = [round((u - l) / cfg.domain.dx) for l, u in zip(cfg.domain.lower, cfg.domain.upper)]
        nodes = [basis.axis(a).nodes(c) for a, c in enumerate(cells)]
    out = dict(cells=cells, nodes=nodes, stencil=basis.stencil)
    if cfg.domain.sparse:
        leaf = LEAF[d]
        blocks = [_pow2(math.ceil(s / leaf)) for s in nodes]
        if math.prod(blocks) <= MAX_TOP_POINTERS:
            out.update(levels=[blocks], mid=1)
        else:
            mid = 8 if d == 3 else 64  # grid.Grid's second level
            out.update(levels=[[_pow2(math.ceil(b / mid)) for b in blocks], [mid] * d], mid=mid)
        out.update(leaf=leaf, blocks=blocks)
    return out


def _active_blocks(cfg: Config, layout: dict, base_dir) -> tuple[int, int]:
    """(leaf blocks, top pointer slots) the bodies' stencils touch, each body's bounding box grown by a stencil."""
    d, dx, leaf = cfg.dim, cfg.domain.dx, layout["leaf"]
    lower = np.asarray(cfg.domain.lower, float)
    reach = layout["stencil"]
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


def _grid_bytes(cfg: Config, base_dir, mapped: MappedGrid | None = None) -> tuple[int, str, list[int]]:
    d, size = cfg.dim, 8 if cfg.precision == "f64" else 4
    layout = grid_layout(cfg, mapped)
    map_bytes = mapped.field_floats() * size if mapped is not None else 0
    crack_vectors, crack_scalars = crack_grid_fields(d) if cfg.crack else ([], [])
    vectors = 1 + (cfg.solver.transfer == "flip") + (cfg.solver.update == "musl") + len(crack_vectors)
    node_bytes = size * (1 + d * vectors + len(crack_scalars))
    nodes = math.prod(layout["nodes"])
    ddmp = cfg.solver.basis == "ddmp"   # its nodal volumes live on a grid of their own, one scalar per node
    if not cfg.domain.sparse:
        return (nodes * (node_bytes + (size if ddmp else 0)) + map_bytes, f"dense, {nodes:.3g} nodes",
                layout["cells"])
    if mapped is not None:
        # bodies are given in physical space: the parameter blocks they touch are not known without inverting
        # the map, so count every block (a map's grid is small: the bound costs little)
        leaves = math.prod(layout["blocks"])
        tops = math.prod(layout["levels"][0])
    else:
        leaves, tops = _active_blocks(cfg, layout, base_dir)
    # the crack finder keeps the node normals kept between steps on a second sparse grid
    grids = 2 if cfg.crack is not None and cfg.crack.normal_refresh > 0 else 1
    top_slots = math.prod(layout["levels"][0])
    pointers = top_slots + (tops * layout["mid"] ** d if len(layout["levels"]) > 1 else 0)
    leaf_nodes = leaves * layout["leaf"] ** d
    total = grids * pointers * POINTER_SLOT_BYTES + leaf_nodes * (node_bytes + size * (1 + d) * (grids - 1))
    if ddmp:
        total += pointers * POINTER_SLOT_BYTES + leaf_nodes * size
    total += map_bytes
    return total, f"sparse, {top_slots:.3g} top pointers, ~{leaves:,} active blocks", layout["cells"]


def _time_step(cfg: Config, base_dir, mapped: MappedGrid | None = None) -> tuple[float, str]:
    s = cfg.solver
    if s.dt is not None:
        return s.dt, "from solver.dt"
    c, which = max((wave_speed(cfg.materials[b.material]), b.material) for b in cfg.bodies)
    vmax, fastest = 0.0, None
    for i, b in enumerate(cfg.bodies):
        # expression components (functions of position) are not known before the particles exist: counted as 0
        with np.errstate(over="ignore"):
            v = float(np.linalg.norm([c for c in b.velocity if not isinstance(c, str)] or [0.0])) \
                if b.velocity is not None else 0.0
            if b.angular_velocity is not None:
                lo, hi = shape_bounds(b.shape, cfg.dim, base_dir, f"bodies.{i}.shape")
                v += float(np.linalg.norm(np.atleast_1d(b.angular_velocity))) * 0.5 * float(np.linalg.norm(hi - lo))
        if fastest is None or v > vmax:
            vmax, fastest = v, i
    h = mapped.h_min if mapped is not None else smallest_span(cfg)   # the map's smallest cell, else dx or a knot span
    dt = s.cfl * h / (c + vmax)
    if not dt > 0:  # a speed (or wave speed) so large that the step underflows: found by tests/test_fuzz.py
        key = f"bodies.{fastest}.velocity" if vmax >= c else f"materials.{which}"
        raise ConfigError(f"the CFL time step underflows to zero (wave speed {c:.3g} m/s, body speed {vmax:.3g} m/s, "
                          f"domain.dx = {cfg.domain.dx:g}): check the units", key=key)
    return dt, f"from the CFL rule: wave speed {c:.3g} m/s of material '{which}'"


def estimate(cfg: Config, body_force: bool = False) -> Estimate:
    """Sizes of a run from its config; reads mesh files (cached) but allocates and generates nothing."""
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
    mapped = _mapped(cfg)
    grid_bytes, grid_detail, cells = _grid_bytes(cfg, base_dir, mapped)
    dt, dt_source = _time_step(cfg, base_dir, mapped)
    steps = cfg.solver.end_time / dt
    if cfg.solver.max_steps is not None and cfg.solver.max_steps < steps:
        steps, dt_source = float(cfg.solver.max_steps), dt_source + "; capped by solver.max_steps"
    limit, source = _limit(cfg)
    return Estimate(particles=sum(per_body), per_body=per_body,
                    device_bytes_per_particle=device_bytes_per_particle(cfg, body_force),
                    host_bytes_per_particle=16 * d + 8 * HOST_FLOATS + 4 * HOST_INTS + 8,
                    grid_cells=cells, grid_bytes=grid_bytes, grid_detail=grid_detail, lattice_bytes=lattice,
                    dt=dt, dt_source=dt_source, steps=steps,
                    outputs=math.floor(cfg.solver.end_time / cfg.output.every) + 1.0,
                    limit_bytes=limit, limit_source=source)


def check(cfg: Config, body_force: bool = False, warn: bool = True) -> Estimate:
    """Refuse a run that does not fit (ConfigError naming the key that drives its size and the override);
    with `warn`, SizeWarning for absurdly many steps or outputs. Returns the estimate."""
    est = estimate(cfg, body_force)
    big = int(np.argmax(est.per_body))
    ppc_key = f"bodies.{big}.particles_per_cell"
    sizes = (f"particles: {est.particles:.3g} ({_gb(est.particle_bytes)}); grid: {_gb(est.grid_bytes)}, "
             f"{est.grid_detail}")
    drivers = (f"the size follows domain.dx = {cfg.domain.dx:g}, domain.sparse = {str(cfg.domain.sparse).lower()} "
               f"and {ppc_key} = {cfg.bodies[big].particles_per_cell}")

    def fix(grid_led: bool) -> str:
        if grid_led:
            return "a coarser domain.dx" + (" or domain.sparse: true" if not cfg.domain.sparse else "")
        return f"fewer {ppc_key}, a coarser domain.dx or smaller bodies"

    layout = grid_layout(cfg)
    top = math.prod(layout["levels"][0] if cfg.domain.sparse else layout["nodes"])
    if est.particles > MAX_ELEMENTS or top > MAX_ELEMENTS:
        grid_led = top > MAX_ELEMENTS
        raise ConfigError(f"{'the grid' if grid_led else 'the particles'} would need more than 2^31 elements in one "
                          f"field, more than Taichi can index ({sizes}); {drivers}: use {fix(grid_led)}",
                          key="domain.dx" if grid_led else ppc_key)
    grid_led = est.grid_bytes >= est.particles * est.device_bytes_per_particle
    key = "domain.dx" if grid_led else ppc_key
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
    if warn:
        for message in size_warnings(cfg, est):
            warnings.warn(message, SizeWarning, stacklevel=2)
    return est


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
