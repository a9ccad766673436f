"""Mapped (curvilinear) grids, `domain.map` (issue 12, step 3): the grid lives in the parameter space of a NURBS
map x(xi) (nurbs.py), its nodes are the map's control points, and each particle keeps its parametric coordinates
xi_p next to its physical position x_p.

A particle's stencil is the rational basis R_i at xi_p, with physical gradients through the map's Jacobian,
    grad_x R_i = J^-T grad_xi R_i,   J = sum_i P_i (x) grad_xi R_i,
and node offsets P_i - x_p (control points are the nodes: sum R_i P_i = x_p and sum P_i (x) grad_x R_i = I, so
APIC, linear reproduction and the F update hold as on the Cartesian grid). After every position update xi_p is
found again by Newton's method on x(xi) = x_p from the old xi_p (`locate`); a particle that leaves the mapped
region or whose iteration fails stops the run (InstabilityError, cause "particle left the mapped grid"). The
stencil itself is built in stencils.py (kind `mapped`); this module holds the grid, xi_p and `locate`.

The map is 2D or 3D: the built-in annulus, cylinder or shell, or a `nurbs` patch (or several joined along x) given
as data (`build_map`; host geometry in mapgeom.py); with solver.basis cubic its net is raised to degree 3 before
it is refined. A full turn (or a `periodic` patch) wraps in its first parameter: its last control-point layer
coincides with the first and is stored as that same node (the seam is a C0 joint, like the rational pieces').

Walls (grid.make_wall_condition) act on the control points of the parameter faces along their outward normals
(`normal`, from mapgeom.face_normals; on a circle, cylinder or sphere radial, so a slip or roller wall gives every
node an impulse through the axis or centre and no torque): sticky v = 0, slip: no outward normal velocity, roller:
no normal velocity, Coulomb friction on slip and roller faces, velocity walls (which may turn about +z). Bodies
are given in physical space.
Physics code only: no CLI, rendering or file I/O here.
"""

import itertools
import math

import numpy as np
import taichi as ti

from . import registry
from .shape_functions import Basis, make_bspline
from . import mapgeom
from .nurbs import Map, annulus, cylinder, shell

LOCATE_TOL = {"f32": 1e-4, "f64": 1e-13}      # Newton's residual |x(xi) - x_p|, relative to the smallest cell (f32: sums of 9 terms of ~|x| carry ~1e-7 |x| of round-off)


def build_map(m, degree: int = 2):
    """(nurbs.Map, periodic) of a `domain.map` config: the built-in annulus, cylinder or shell, or a `nurbs` map
    given as knots, control points and weights (degree 2 per axis), refined by knot insertion (`refine`), knots
    scaled to cells. degree 3 (solver.basis cubic): the same map, its coarse net raised to degree 3 first
    (`mapgeom.elevate`) and then refined, so it is C2 inside each piece (k-refinement)."""
    periodic = m.periodic if m.type == "nurbs" else m.angle >= 360.0
    if degree == 2 and m.type != "nurbs":
        return _built_in(m, m.cells), periodic
    if m.type == "nurbs":
        knots, P, w = mapgeom.config_net(m)
        per_span = m.refine
    else:
        pieces = [mapgeom.arc_pieces(m.angle), 1]
        if m.type != "annulus":
            pieces.append(mapgeom.arc_pieces(np.ptp(m.latitudes)) if m.type == "shell" else 1)
        coarse = _built_in(m, pieces)
        knots, P, w = coarse.knots, coarse.P, coarse.w
        per_span = [n // k for n, k in zip(m.cells, pieces)]
    if degree != 2:
        knots, P, w = mapgeom.elevate(knots, P, w, degree)
    knots, P, w = mapgeom.refine(knots, P, w, per_span, degree)
    return Map(knots, [degree] * len(knots), P, w), periodic


def _built_in(m, cells) -> Map:
    """The built-in map of config `m` (quadratic) at `cells`."""
    angle = math.radians(m.angle)
    if m.type == "annulus":
        return annulus(m.inner_radius, m.outer_radius, angle, cells[0], cells[1], tuple(m.center))
    if m.type == "cylinder":
        return cylinder(m.inner_radius, m.outer_radius, angle, m.length, cells, m.center)
    return shell(m.inner_radius, m.outer_radius, angle, np.radians(m.latitudes), cells, m.center)


class MappedGrid:
    """Host side of a mapped grid: the NURBS map, node count, wall normals and the smallest cell (for the CFL
    rule). `materialize()` allocates its fields after ti.init."""

    def __init__(self, cfg):
        m = cfg.domain.map
        self.cfg = cfg
        self.degree = registry.get(cfg.solver.basis).degree
        self.map, self.periodic = build_map(m, self.degree)
        self.map.periodic = self.periodic
        n0, *rest = self.map.w.shape
        self.dim = self.map.dim
        self.shape = [n0 - 1 if self.periodic else n0] + rest   # the seam column is the first one
        mp = self.map
        if m.type in ("cylinder", "shell"):
            self.h_min, self.h_max = mapgeom.solid_map_cell_sizes(m)
        elif m.type == "annulus":
            # an inner arc of one angular cell, or one radial cell (the annulus' own sizes, as the CFL rule used
            # before the generic map: its measured runs keep their steps)
            angle = math.radians(m.angle)
            n_angle, n_radial = m.cells
            self.h_max = max(m.outer_radius * 2 * math.sin(0.5 * angle / n_angle),
                             (m.outer_radius - m.inner_radius) / n_radial)
            self.h_min = min(m.inner_radius * 2 * math.sin(0.5 * angle / n_angle),
                             (m.outer_radius - m.inner_radius) / n_radial)
        else:
            self.h_min, self.h_max = mapgeom.cell_sizes(mp.knots, mp.degrees, mp.P, mp.w)
        self.normals = mapgeom.face_normals(mp.knots, mp.degrees, mp.P, mp.w, self.periodic)[: self.shape[0]]
        self.xi = None

    def basis(self) -> Basis:
        """The solver's view: the basis that declares `map` (quadratic: 3 nodes per axis, APIC with B_p D_p^-1),
        contributions built here."""
        from dataclasses import replace
        spec = registry.get(self.cfg.solver.basis)
        return replace(make_bspline(spec.degree, spec.name), kind="mapped")

    def materialize(self):
        self.map.materialize()
        self.normal = ti.Vector.field(self.dim, float, tuple(self.shape) + (2 * self.dim,))
        self.normal.from_numpy(self.normals)

    def allocate_particles(self, n: int):
        from ..layout import MAPPED_XI   # its declaration (budget counts the same)
        self.xi = MAPPED_XI(self.dim).allocate(max(n, 1))

    def field_floats(self) -> int:
        """Floats of the map's own fields: control points (d) and weights (1) per control point, the wall normals
        (2 d faces x d per node); the knot vectors' few floats are left out. budget.py counts them."""
        d = self.dim
        return (d + 1) * int(np.prod(self.map.w.shape)) + 2 * d * d * int(np.prod(self.shape))

    def initial_guess(self, x: np.ndarray) -> np.ndarray:
        """Per physical point, the parameters of the nearest of 3^d samples per cell (Newton starts there, within
        a third of a cell of the answer). Points are sorted into the cells of a coarse box grid first, and each is
        compared with the samples of its own box cell and the neighbouring ones only."""
        d, k = self.dim, 3
        s = [(np.arange(int(k * n)) + 0.5) / k for n in self.map.n_cells]
        xi = np.stack(np.meshgrid(*s, indexing="ij"), -1).reshape(-1, d)
        pts = self.map.evaluate(xi)
        lo = np.minimum(pts.min(axis=0), x.min(axis=0)) if len(x) else pts.min(axis=0)
        h = 2.0 * self.h_max
        key = lambda q: np.floor((q - lo) / h).astype(np.int64)
        buckets = {}
        for i, c in enumerate(map(tuple, key(pts))):
            buckets.setdefault(c, []).append(i)
        out = np.empty((len(x), d))
        cells = key(x)
        around = list(itertools.product((-1, 0, 1), repeat=d))
        for c in set(map(tuple, cells)):
            mine = np.nonzero((cells == c).all(axis=1))[0]
            near = [i for o in around for i in buckets.get(tuple(a + b for a, b in zip(c, o)), [])]
            if not near:        # far from the map: any start; Newton will report it
                out[mine] = xi[0]
                continue
            near = np.asarray(near)
            dist = ((x[mine, None, :] - pts[None, near]) ** 2).sum(-1)
            out[mine] = xi[near[dist.argmin(axis=1)]]
        return out


def make_locate(ctx, mapped: MappedGrid, fail, n_codes: int, code: int):
    """Kernels: `locate()` finds every particle's xi again after its position update (Newton from the old xi);
    a failure sets the fail flag with `code`. `start(guess)` does it from host guesses at upload and returns
    how many particles were not found."""
    mp, xi, x, d = mapped.map, mapped.xi, ctx.x, mapped.dim
    tol = LOCATE_TOL[ctx.precision] * mapped.h_min
    missed = ti.field(ti.i32, ())

    @ti.kernel
    def locate():
        for p in x:
            q, ok = mp.invert(x[p], xi[p], tol)
            xi[p] = q
            if not ok:
                ti.atomic_min(fail[None], p * n_codes + code)

    @ti.kernel
    def start_kernel(guess: ti.types.ndarray()):
        for p in x:
            g = ti.Vector.zero(ti.f64, d)      # the host's f64 guess as it is (f32 runs start Newton from it)
            for a in ti.static(range(d)):
                g[a] = guess[p, a]
            q, ok = mp.invert(x[p], g, tol)
            xi[p] = q
            if not ok:
                missed[None] += 1

    def start(guess: np.ndarray) -> int:
        missed[None] = 0
        start_kernel(np.ascontiguousarray(guess, np.float64))
        return int(missed[None])

    return locate, start
