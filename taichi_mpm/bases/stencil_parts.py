"""What every stencil is built from: the kernel context its builders share, the Stencil record, the split of the
contribution loop (solver.unroll) and the particle domain's half-width. stencils.py builds the tensor, ddmp and
mapped stencils, corners.py the CPDI ones. Physics code only: no CLI, rendering or file I/O here."""

import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import taichi as ti


@dataclass
class KernelContext:
    """What a kernel builder (solver, F-bar, crack finder) may use: compile-time constants, the particle and grid
    fields, the stencil, and the solver's material and wall funcs. Built once by `Simulation._build_kernels`."""
    dim: int
    dx: float
    lower: Any                       # ti.Vector, domain lower corner
    upper: Any
    n_cells: list
    basis: Any                       # basis.Basis
    feat: Any                        # step.Features: the scene's compile-time switches
    precision: str
    # particle fields
    x: Any
    v: Any
    F: Any
    C: Any
    vol0: Any
    mat: Any
    half_width: Any                  # per-particle domain half-width (grid units) or None
    domain_lp0: float                # domain half-width (grid units) when every particle has the same one
    gimp_deforming: bool
    unroll: Any                      # solver.unroll: "auto", True or False (_loops)
    # grid
    grid: Any
    stencil: "Stencil" = None
    # solver funcs (@ti.func), set once the solver has defined them
    density: Optional[Callable] = None
    kirchhoff: Optional[Callable] = None       # (p, F) -> Kirchhoff stress
    wall: Optional[Callable] = None            # (I, v) -> v with wall conditions
    gravity_kick: Any = None    # ti.func (kick_before, kick_after) -> the velocity gravity adds over a leapfrog kick
    add: Optional[Callable] = None   # @ti.func (g, I, value): g[I] += value, plain where P2G scatters by colours
    extra: dict = field(default_factory=dict)

    @property
    def gm(self):
        return self.grid.m

    @property
    def gv(self):
        return self.grid.vec["v"]

    @property
    def gv_old(self):
        return self.grid.vec.get("v_old")

    @property
    def gv2(self):
        return self.grid.vec.get("v2")

    @property
    def vgrad(self):
        """The grid velocity F's update reads: MUSL's remapped one, else the updated one."""
        return self.gv2 if self.feat.musl else self.gv


@dataclass
class Stencil:
    span: list                  # extents of the contribution index (ti.ndrange(*span) visits every contribution)
    outer: list                 # the loop split by `unroll`: ndrange(*outer) at run time, `inner` unrolled
    inner: list
    at: Callable                # @ti.func (p) -> per-particle stencil data st
    node: Callable              # @ti.func (st, off) -> (storage index I, w, grad w, x_i - x_p)
    inertia: Callable           # @ti.func (st) -> APIC's D_p = sum w (x_i - x_p)(x_i - x_p)^T
    inertia_inverse: Callable   # @ti.func (st) -> D_p^-1 (zero along an axis where D_p vanishes)
    index: Callable             # @ti.func (off) -> flat contribution number 0..count-1
    count: int
    prepare: Optional[Callable] = None   # per step before P2G, for stencils that read grid state (ddmp)
    origin: Optional[Callable] = None    # @ti.func (p) -> the first node of a tensor stencil (scatter.BlockBins)
    # cpdi2: (read_v) -> @ti.func (p, st, dt) -> new x_p, moving the particle's own corners with the node velocities
    advance: Optional[Callable] = None
    dual: Optional[Any] = None   # ddmp: its dual domains (stencils.DualDomains: node volumes and their geometry)
    # tensor stencils whose node functions are per-axis products: (st, axis, row, i) -> that axis's row at node i
    # (separable.py sums by factorisation); None where they are not (ddmp's blended gradient, cpdi, ck, mapped)
    factor: Optional[Callable] = None


AUTO_FULL = 16   # solver.unroll auto: stencils of at most this many contributions are unrolled whole
AUTO_INNER = 9   # and larger tensor stencils their trailing axes, up to this many nodes per run-time iteration


def loops(span: list, unroll, auto_inner: int = 1):
    """Split the contribution index into a run-time loop `outer` and a statically unrolled `inner` list (the
    trailing axes, as many as fit in `n` contributions). Unrolled nodes keep the weights in registers but each adds
    its code to the compile: true unrolls everything, false nothing, auto stencils of at most AUTO_FULL
    contributions whole and larger ones up to `auto_inner` per run-time iteration (tensor stencils: their
    trailing axes, 3D quadratic 9 of 27, cubic 4 of 64)."""
    n = math.prod(span) if unroll is True or (unroll == "auto" and math.prod(span) <= AUTO_FULL) else 1
    if unroll == "auto" and n == 1:
        n = auto_inner
    d = len(span)
    while d > 0 and math.prod(span[d - 1:]) <= n:
        d -= 1
    outer = list(span[:d]) + [1] * (len(span) - d)
    inner = [ti.Vector([0] * d + list(o)) for o in itertools.product(*[range(s) for s in span[d:]])]
    return outer, inner


def flat_index(span):
    @ti.func
    def index(off):
        k = 0
        for a in ti.static(range(len(span))):
            k = k * span[a] + off[a]
        return k
    return index


def domain_half_width(ctx: KernelContext):
    """@ti.func (p) -> the particle's initial domain half-width in grid units."""
    half_width, lp0 = ctx.half_width, ctx.domain_lp0
    per_particle = half_width is not None

    @ti.func
    def lp(p):
        res = ti.cast(lp0, float)
        if ti.static(per_particle):
            res = half_width[p]
        return res
    return lp
