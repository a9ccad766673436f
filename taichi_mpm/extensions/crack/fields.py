"""The crack finder's fields: the node fields it adds to the solver's grid, its own per-particle, cell-list and
kept-normal fields (allocated only with a crack section), and their bytes per particle (budget.py reads them)."""

import math

import numpy as np
import taichi as ti

from ...errors import ConfigError
from ...grid import Grid
from ...materials import rankine_params
from .constants import ALL, CELL_SPLIT, MAX_CELLS


def grid_fields(dim: int) -> tuple[list[str], list[str]]:
    """The crack finder's fields in the solver's grid (cleared with it each step): vectors (the rows of the
    anisotropic node mass A_i, the node normal) and scalars (the node's mark: 1 in a near particle's stencil,
    2 on the discontinuity)."""
    return [f"A{a}" for a in range(dim)] + ["crack_n"], ["crack_mark"]


def particle_bytes(d: int, precision: str, apic: bool, has_law: bool, stencil_nodes: int, cc) -> int:
    """Bytes per particle of the finder's fields (CrackFields; budget.py estimates with it)."""
    size = 8 if precision == "f64" else 4
    floats = 2 + d + 2 + 2 * d + (2 * d if apic else 0) + (1 if has_law else 0)   # d, D, normal, sums, gsum, cent
    floats += d + 2                                # xs, vs: positions and SPH weights in cell order
    floats += d if cc.contact_in_compression else 0   # ns: normals in cell order (contact searches)
    ints = 4 + 4 + (8 if stencil_nodes > 32 else 4) + 4 + 4   # iface, state, mask, pcell, ids
    if cc.normal_refresh > 0:   # kept normals, positions at the last refresh, drift; their state, masks found
        floats += 2 * d + 1
        ints += 4 + 8 + 4 + (8 if cc.contact_in_compression else 0)   # (+ the contact list's count and start)
    return floats * size + ints


class CrackFields:
    """The SPH support and cell list's geometry, the damage laws, and the fields the finder's kernels share."""

    def __init__(self, view, cc):
        if view.dim == 1:
            raise ConfigError("the crack finder needs dim 2 or 3", key="crack")
        d, n = view.dim, view.n
        self.dim = d
        self.spacing = float(np.min(view.spacing))
        # a particle whose stencil reaches across the discontinuity must see it: the support radius is at
        # least the stencil reach (S/2 cells) plus one particle spacing (cpdi: its undeformed domains' reach,
        # 1.5 cells; a domain stretched beyond it sees the discontinuity only once it is within that reach)
        self.reach = 0.5 * view.basis.stencil * view.dx
        self.radius = max(cc.kernel_radius * self.spacing, self.reach + self.spacing)
        extent = view.upper - view.lower
        self.cells = [max(1, int(math.ceil(e * CELL_SPLIT / self.radius))) for e in extent]  # cell = r / CELL_SPLIT
        self.n_cell_total = int(np.prod(self.cells))
        if self.n_cell_total > MAX_CELLS:
            raise ConfigError(f"the crack finder's cell list would need {self.n_cell_total} cells; "
                              "raise crack.kernel_radius or shrink the domain", key="crack.kernel_radius")
        self.laws = [rankine_params(m, view.dx) for m in view.materials]
        self.has_law = any(law is not None for law in self.laws)
        self.n_nodes = view.basis.contributions(d)       # contributions per particle (stencils.py)
        self.apic = view.apic
        self._particle_fields(d, n, cc)
        self._cell_list(d, n, cc)
        # normals kept between steps (crack.normal_refresh). Once a particle has moved half the skin since the last
        # refresh, each particle's neighbourhood is checked: a normal is recomputed where the particles around it
        # have moved against each other by the skin (summed over refreshes; a body moving as a whole keeps its
        # normals), all of them where D changed; the cache is part of the state (checkpoints)
        self.skin = float(cc.normal_refresh) * self.radius
        self.cached = self.skin > 0
        self.listed = False
        if self.cached:
            self._kept_normals(d, n, cc, view.grid.shape)

    def _particle_fields(self, d, n, cc):
        self.d = ti.field(float, n)                     # damage d_p
        self.D = ti.field(float, n)                     # D_p = max(d_p, I_p)
        self.iface = ti.field(ti.f32, n)                # I_p
        self.kappa = ti.field(float, n) if self.has_law else None
        self.normal = ti.Vector.field(d, float, n)      # n_p (zero when not near a discontinuity)
        self.state = ti.field(ti.i32, n)
        self.contacts = ti.field(ti.i32, ())            # particles in contact this step (CONTACT)
        self.mask_t = ti.u64 if self.n_nodes > 32 else ti.u32
        self.mask = ti.field(self.mask_t, n)            # bit k: stencil node k lies across the discontinuity
        self.sums = ti.Vector.field(2, float, n)        # S_t = sum_j Nt*_j, S_n = sum_j Nn*_j
        self.gsum = ti.Matrix.field(2, d, float, n)     # rows: sum_j grad Nt*_j, sum_j grad Nn*_j
        self.cent = ti.Matrix.field(2, d, float, n) if self.apic else None  # rows: sum_i N~ (x_i - x_p)

    def _cell_list(self, d, n, cc):
        nc = self.n_cell_total
        self.cell_count = ti.field(ti.i32, nc)
        self.cell_fill = ti.field(ti.i32, nc)
        self.cell_start = ti.field(ti.i32, nc)
        self.cell_lo = ti.field(float, nc)              # min / max of D in the cell
        self.cell_hi = ti.field(float, nc)
        self.cell_varies = ti.field(ti.i32, nc)         # D varies within the cell's 5^d block (prepare)
        self.d_range = ti.field(float, 2)               # min / max of D over all particles
        self.pcell = ti.field(ti.i32, n)
        self.ids = ti.field(ti.i32, n)
        self.xs = ti.Vector.field(d, float, n)          # x[ids[j]]: positions in cell order, so searches stream
        self.vs = ti.Vector.field(2, float, n)          # (V, V D) of particle ids[j]: the SPH sums' weights
        # normals in cell order, so the contact lists' searches stream (only with contact in compression)
        self.ns = ti.Vector.field(d, float, n) if cc.contact_in_compression else None

    def _kept_normals(self, d, n, cc, grid_shape):
        self.n_cache = ti.Vector.field(d, float, n)    # n_p as the gradient sums gave it (before band normals)
        self.s_cache = ti.field(ti.i32, n)             # and the state they gave
        self.x_ref = ti.Vector.field(d, float, n)      # positions at the last refresh
        self.drift = ti.field(float, n)                # bound on the neighbours' motion against p since n_p was
        self.stale = ti.field(ti.i32, ())              # KEEP, DRIFTED (a particle moved) or ALL (D changed)
        self.stale[None] = ALL
        self.recomputed = ti.field(ti.i64, ())         # normals recomputed in all (diagnostics, tests)
        # per cell: the box of its particles' motion since the last refresh, and the box's size over its 5^d block
        self.cell_dlo = ti.Vector.field(d, float, self.n_cell_total)
        self.cell_dhi = ti.Vector.field(d, float, self.n_cell_total)
        self.cell_drift = ti.field(float, self.n_cell_total)
        # contact list: per particle, the particles that could face it within reach until the next refresh,
        # found when the normals are computed; the contact test sums over them instead of searching each step.
        # count -1: search each step (a band particle: its normal follows its neighbours); ids: a growing pool
        self.listed = bool(cc.contact_in_compression)
        if self.listed:
            self.contact_count = ti.field(ti.i32, n)
            self.contact_start = ti.field(ti.i32, n)
            self.contact_fill = ti.field(ti.i32, ())
            self.contact_over = ti.field(ti.i32, ())   # slots the lists that outgrew theirs need
            self.cell_dir = ti.Vector.field(d, float, self.n_cell_total)   # the cells' normal cones (build)
            self.cell_spread = ti.field(float, self.n_cell_total)
        # each mask's stencil origin (+1, flat) and period of kept normals (`epoch`) when it was found; same
        # origin and period: the same mask (a node's side depends only on the kept node and particle normals)
        self.mask_at = ti.field(ti.i64, n)
        self.mask_epoch = ti.field(ti.i32, n)
        # node normals computed since: m = 1 (normal in n) or 2 (on the discontinuity); 0: not yet
        self.node_cache = Grid(d, grid_shape, True, ["n"])
        self.node_cache_fill = ti.field(ti.i32, ())
