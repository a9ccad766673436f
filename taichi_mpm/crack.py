"""Crack finder: cracks and body interfaces inside one velocity field (seed talk, Part II).

Per step, before P2G (`CrackFinder.update`: kernels prepare, particle_normals, classify; at a refresh of the kept
normals also bin_cells and contact_list; details and reasons in docs/crack_finder.md):
  1. damage law (Rankine, materials.py) updates d_p; D_p = max(d_p, I_p) (I_p: interface flag);
     a cell list (cells of r/2, r = SPH support radius) bins the particles: counting sort, linear in N.
  2. particles whose neighbourhood holds varying D get the Shepard-normalised SPH gradient of D;
     a particle is *near* a discontinuity when D_p >= damage_threshold or |grad D_p| r >= gradient_threshold.
     Its normal is n_p = grad D_p / |grad D_p|, and it marks the grid nodes of its stencil.
  3. a damaged particle without a gradient (middle of an odd-width band) takes its neighbours' normal.
  4. marked nodes y_g get grad D(y_g) from the same SPH sums.
  5. per near particle and stencil node: across when n_p . n_g < -threshold, or when the node lies on
     the discontinuity itself (|grad D(y_g)| r < gradient_threshold with D(y_g) >= damage_threshold).
     The tangential functions drop nodes across; the normal ones keep them while the particle is in
     contact (trial normal traction n.sigma.n + rho c v_close < 0). Both families are rescaled to a
     partition of unity; their sums are stored per particle so P2G/G2P modify weights node by node.

Direction-dependent coupling: particle p couples to node i through the tensor
  W_ip = Nt_ip (I - n n^T) + Nn_ip n n^T        (Nt, Nn: rescaled tangential / normal functions)
so the node mass becomes a tensor M_i = sum_p m_p W_ip = m_i I + A_i (m_i scalar as usual; A_i from
particles in contact) and v_i = M_i^+ p_i. Linear momentum is conserved (docs/crack_finder.md).

Only built when the config has a `crack` section: a scene without one allocates and compiles nothing here.
"""

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import taichi as ti

from .errors import ConfigError
from .grid import Grid
from .materials import degrade_tension, rankine_damage, rankine_params, sym_eig

STANDARD, MODIFIED, CONTACT = 0, 1, 2   # particle states: unmodified, cut (tension), cut with normal contact
S_FLOOR = 1e-3                          # a family whose kept weights sum below this keeps standard functions
MAX_CELLS = 1 << 26
CACHE_KEYS = ("crack_normals", "crack_normal_states", "crack_normal_positions", "crack_normals_stale",
              "crack_normal_drift")
KEEP, DRIFTED, ALL = 0, 1, 2            # normals this step: kept / recomputed where they drifted / all recomputed
BIG = 1e30
SLOTS, FILL, OVERFLOW = 0, 1, 2         # the contact lists' build stages (CrackFinder._build_contact_list)
LIST_SLACK = 8                          # slots a contact list gets beyond its last length (+25 %)
DRIFT_LIMIT = 0.5                       # skins: a normal is recomputed once its neighbours may have moved against
                                        # it by this much (the bound a particle's own motion triggers refreshes at)
NODE_CACHE_KEYS = ("crack_node_cache_index", "crack_node_cache_normal", "crack_node_cache_flag")
CELL_SPLIT = 2                          # cell list cells of r/2: a query scans 5^d cells, (2.5 r)^d, not (3 r)^d
ROW_MARGIN = 1e-2                       # cell units: a cell is cut from a search only beyond r + this (rounding)
CONE_MARGIN = 1e-4                      # a cell's normals are ruled out as facing only beyond this (rounding)


@dataclass(frozen=True)
class CrackHooks:
    """The @ti.funcs the solver's kernels call for particles near a discontinuity, and the kernels that replace
    the solver's grid update and MUSL remap (node mass is a tensor there). st: the particle's stencil data."""
    modified: Callable          # (p) -> the particle uses modified functions
    degrade: Callable           # (p, tau) -> damaged stress
    degrade_energy: Callable    # (p, F, psi, tau) -> damaged strain energy density
    p2g: Callable               # (p, st, mp, stress, vp, Ap, force_density, kick)
    p2g_momentum: Callable      # (p, st, mp, vp, Ap): MUSL's remap
    g2p: Callable               # (p, st, deform) -> (v_pic, FLIP increment, APIC B, velocity gradient)
    kernels: dict               # grid_update_tensor, grid_remap_tensor (the solver's own where no particle touches)


def grid_fields(dim: int) -> tuple[list[str], list[str]]:
    """The crack finder's fields in the solver's grid (cleared with it each step): vectors (the rows of the
    anisotropic node mass A_i, the node normal) and scalars (the node's mark: 1 in a near particle's stencil,
    2 on the discontinuity)."""
    return [f"A{a}" for a in range(dim)] + ["crack_n"], ["crack_mark"]


def particle_bytes(d: int, precision: str, apic: bool, has_law: bool, stencil_nodes: int, cc) -> int:
    """Bytes per particle of the finder's fields (CrackFinder.__init__; budget.py estimates with it)."""
    size = 8 if precision == "f64" else 4
    floats = 2 + d + 2 + 2 * d + (2 * d if apic else 0) + (1 if has_law else 0)   # d, D, normal, sums, gsum, cent
    floats += d + 2                                # xs, vs: positions and SPH weights in cell order
    floats += d if cc.contact_in_compression else 0   # ns: normals in cell order (contact searches)
    ints = 4 + 4 + (8 if stencil_nodes > 32 else 4) + 4 + 4   # iface, state, mask, pcell, ids
    if cc.normal_refresh > 0:   # kept normals, positions at the last refresh, drift; their state, masks found
        floats += 2 * d + 1
        ints += 4 + 8 + 4 + (8 if cc.contact_in_compression else 0)   # (+ the contact list's count and start)
    return floats * size + ints


class CrackFinder:
    def __init__(self, sim):
        cfg, cc = sim.cfg, sim.cfg.crack
        if sim.dim == 1:
            raise ConfigError("the crack finder needs dim 2 or 3", key="crack")
        self.sim, self.cc = sim, cc
        d, n = sim.dim, sim.n
        self.dim = d
        self.spacing = float(np.min(sim.scene.spacing))
        # a particle whose stencil reaches across the discontinuity must see it: the support radius is at
        # least the stencil reach (S/2 cells) plus one particle spacing (cpdi: its undeformed domains' reach,
        # 1.5 cells; a domain stretched beyond it sees the discontinuity only once it is within that reach)
        self.reach = 0.5 * sim.basis.stencil * sim.dx
        self.radius = max(cc.kernel_radius * self.spacing, self.reach + self.spacing)
        extent = sim.upper - sim.lower
        self.cells = [max(1, int(math.ceil(e * CELL_SPLIT / self.radius))) for e in extent]  # cell = r / CELL_SPLIT
        self.n_cell_total = int(np.prod(self.cells))
        if self.n_cell_total > MAX_CELLS:
            raise ConfigError(f"the crack finder's cell list would need {self.n_cell_total} cells; "
                              "raise crack.kernel_radius or shrink the domain", key="crack.kernel_radius")
        self.laws = [rankine_params(m, sim.dx) for m in sim._materials]
        self.has_law = any(law is not None for law in self.laws)
        self.n_nodes = sim.basis.contributions(d)       # contributions per particle (stencils.py)
        self.apic = sim.feat["apic"]
        # per particle
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
        # cell list
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
        # normals kept between steps (crack.normal_refresh). Once a particle has moved half the skin since the last
        # refresh, each particle's neighbourhood is checked: a normal is recomputed where the particles around it
        # have moved against each other by the skin (summed over refreshes; a body moving as a whole keeps its
        # normals), all of them where D changed; the cache is part of the state (checkpoints)
        self.skin = float(cc.normal_refresh) * self.radius
        self.cached = self.skin > 0
        self.listed, self.epoch = False, 0
        self._cells_due = True   # the cell list must be built before the next step's searches
        self.contact_ids = ti.ndarray(ti.i32, 1)   # the contact lists' pool (one unused slot without lists)
        if self.cached:
            self.n_cache = ti.Vector.field(d, float, n)    # n_p as the gradient sums gave it (before band normals)
            self.s_cache = ti.field(ti.i32, n)             # and the state they gave
            self.x_ref = ti.Vector.field(d, float, n)      # positions at the last refresh
            self.drift = ti.field(float, n)                # bound on the neighbours' motion against p since n_p was
            self.stale = ti.field(ti.i32, ())              # KEEP, DRIFTED (a particle moved) or ALL (D changed)
            self.stale[None] = ALL
            self.refreshes = 0                             # steps that refreshed them (diagnostics, tests)
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
                self._list_due = True
            # each mask's stencil origin (+1, flat) and period of kept normals (`epoch`) when it was found; same
            # origin and period: the same mask (a node's side depends only on the kept node and particle normals)
            self.mask_at = ti.field(ti.i64, n)
            self.mask_epoch = ti.field(ti.i32, n)
            # node normals computed since: m = 1 (normal in n) or 2 (on the discontinuity); 0: not yet
            self.node_cache = Grid(d, sim.grid.shape, True, ["n"])
            self.node_cache_fill = ti.field(ti.i32, ())

    def bytes_per_particle(self) -> int:
        return particle_bytes(self.dim, self.sim.cfg.precision, self.apic, self.has_law, self.n_nodes, self.cc)

    def upload(self):
        s, sim = self.sim.scene, self.sim
        self.d.from_numpy(sim._to_solver(s.damage).astype(np.float64))
        self.iface.from_numpy(sim._to_solver(s.interface).astype(np.float32))
        if self.kappa is not None:
            self.kappa.fill(0)

    def damage(self) -> np.ndarray:
        return self.sim._to_creation(self.d.to_numpy())

    def get_state(self) -> dict:
        state = {"damage": self.damage()}
        if self.kappa is not None:
            state["damage_kappa"] = self.sim._to_creation(self.kappa.to_numpy())
        if self.cached:   # a run continued from this state reuses the same normals as the one that goes on
            state.update(crack_normals=self.sim._to_creation(self.n_cache.to_numpy().astype(np.float64)),
                         crack_normal_states=self.sim._to_creation(self.s_cache.to_numpy()),
                         crack_normal_positions=self.sim._to_creation(self.x_ref.to_numpy().astype(np.float64)),
                         crack_normals_stale=int(self.stale[None]),
                         crack_normal_drift=self.sim._to_creation(self.drift.to_numpy().astype(np.float64)))
            state.update(zip(NODE_CACHE_KEYS, self._node_cache_arrays()))
        return state

    def _node_cache_arrays(self):
        """The node cache as (storage indices, normals, flags), sorted by index (the same file for any threads)."""
        k = self._k["node_cache_size"]()
        idx, nrm, flag = np.zeros((k, self.dim), np.int32), np.zeros((k, self.dim)), np.zeros(k)
        if k:
            self.node_cache_fill[None] = 0
            self._k["node_cache_read"](idx, nrm, flag)
            order = np.lexsort(idx.T[::-1])
            idx, nrm, flag = idx[order], nrm[order], flag[order]
        return idx, nrm, flag

    def invalidate(self):
        """Recompute the normals at the next step (particles were set from outside)."""
        if self.cached:
            self.stale[None] = ALL
            self._list_due = self._cells_due = True
            self.epoch += 1   # masks found before belong to other normals

    def set_state(self, state: dict):
        if "damage" in state:
            self.d.from_numpy(self.sim._to_solver(np.asarray(state["damage"], np.float64)))
        if self.kappa is not None and "damage_kappa" in state:
            self.kappa.from_numpy(self.sim._to_solver(np.asarray(state["damage_kappa"], np.float64)))
        self.invalidate()
        if self.cached and all(k in state for k in CACHE_KEYS):   # the contact list is derived: rebuilt next step
            n, d = self.sim.n, self.dim
            arrays = [np.asarray(state[k]) for k in CACHE_KEYS[:3] + CACHE_KEYS[4:]]
            if [a.shape for a in arrays] == [(n, d), (n,), (n, d), (n,)] and all(np.isfinite(a).all() for a in arrays):
                self.n_cache.from_numpy(self.sim._to_solver(arrays[0].astype(np.float64)))
                self.s_cache.from_numpy(self.sim._to_solver(arrays[1].astype(np.int32)))
                self.x_ref.from_numpy(self.sim._to_solver(arrays[2].astype(np.float64)))
                self.drift.from_numpy(self.sim._to_solver(arrays[3].astype(np.float64)))
                self.stale[None] = min(max(int(np.asarray(state[CACHE_KEYS[3]])), KEEP), ALL)
                self.node_cache.clear()
                idx, nrm, flag = (np.asarray(state.get(k, ())) for k in NODE_CACHE_KEYS)
                k = len(flag)
                if k and idx.shape == (k, d) and nrm.shape == (k, d) and np.isfinite(nrm).all() and \
                        (idx >= 0).all() and (idx < np.array(self.sim.grid.shape)).all():
                    self._k["node_cache_write"](idx.astype(np.int32), nrm.astype(np.float64),
                                                flag.astype(np.float64), k)
                elif k:
                    self.stale[None] = ALL   # not a cache this scene can use: recompute all

    def update(self):
        """The crack finder's per-step work, before P2G."""
        self._k["prepare"]()
        level = ALL
        if self.cached:
            level = int(self.stale[None])   # prepare raised it if a particle moved too far or D grew
            if level != KEEP:
                self.node_cache.clear()     # node normals are recomputed with the particles'
                self.refreshes += 1
                self.epoch += 1
        fresh = level != KEEP
        if fresh or self._cells_due:   # between refreshes: rebuilt as it was at the last one (after set_state)
            self._k["bin_cells"](int(not fresh))
            self._cells_due = False
        self._k["particle_normals"](level)
        if self.cached:
            if fresh:
                self.stale[None] = KEEP
            if self.listed and (fresh or self._list_due):
                self._build_contact_list()
        self._k["classify"](self.epoch, self.contact_ids)

    def in_contact(self) -> bool:
        """Whether a particle is in contact this step (after `update`): only then is a node mass a tensor."""
        return self.cc.contact_in_compression and self.contacts[None] > 0

    def _build_contact_list(self):
        """Take each particle's slots in the pool (sized by its last list), write the lists in one search, and
        search again only for those that outgrew their slots; the pool grows when short."""
        build = self._k["contact_list"]
        taken = build(self.contact_ids, SLOTS)
        self._reserve_pool(taken)
        over = build(self.contact_ids, FILL)
        if over:
            self._reserve_pool(taken + over)
            build(self.contact_ids, OVERFLOW)
        self._list_due = False

    def _reserve_pool(self, size: int):
        """A pool of at least `size` slots, keeping what it holds."""
        if size > self.contact_ids.shape[0]:
            held = self.contact_ids.to_numpy()
            grown = np.zeros(size + size // 4, np.int32)
            grown[:len(held)] = held
            self.contact_ids = ti.ndarray(ti.i32, len(grown))
            self.contact_ids.from_numpy(grown)

    def contact_lists(self) -> list:
        """Per particle in creation order: the creation indices its contact test sums over until the next refresh,
        or None where it searches each step (inspection, tests)."""
        count, start = self.contact_count.to_numpy(), self.contact_start.to_numpy()
        ids, perm = self.contact_ids.to_numpy(), self.sim._perm
        lists = [None if k < 0 else perm[ids[s:s + k]] for k, s in zip(count, start)]
        return [lists[slot] for slot in np.argsort(perm)]

    # ------------------------------------------------------------------ kernels
    def build(self, ctx) -> CrackHooks:
        """Build the crack finder's funcs and kernels from the solver's kernel context (stencils.KernelContext):
        its stencil of (node, weight, gradient, offset) contributions, material funcs and wall conditions.
        Returns the hooks the solver calls (CrackHooks)."""
        sim, cc = self.sim, self.cc
        dim = self.dim
        sten = ctx.stencil
        span = sten.span
        kirchhoff, wall, gravity_kick = ctx.kirchhoff, ctx.wall, ctx.gravity_kick  # runtime gravity (solver)
        add = ctx.add
        vgrad, basis, mat = ctx.vgrad, ctx.basis, ctx.mat
        grid = sim.grid
        gm, gv = grid.m, grid.vec["v"]
        gv_old, gv2 = grid.vec.get("v_old"), grid.vec.get("v2")
        Arows = [grid.vec[f"A{a}"] for a in range(dim)]
        flip, apic, musl = sim.feat["flip"], sim.feat["apic"], sim.feat["musl"]
        x, v, F, vol0 = sim.x, sim.v, sim.F, sim.vol0
        d_f, D, iface, kappa, contacts = self.d, self.D, self.iface, self.kappa, self.contacts
        normal, state, mask, sums, gsum, cent = self.normal, self.state, self.mask, self.sums, self.gsum, self.cent
        mask_t = self.mask_t
        cell_count, cell_fill, cell_start = self.cell_count, self.cell_fill, self.cell_start
        cell_lo, cell_hi, pcell, ids, xs = self.cell_lo, self.cell_hi, self.pcell, self.ids, self.xs
        cell_varies, vs, d_range = self.cell_varies, self.vs, self.d_range
        ns = self.ns
        node_mark, node_n = grid.scalar["crack_mark"], grid.vec["crack_n"]   # the step's node marks and normals
        cached = self.cached
        n_cache, s_cache, x_ref, stale = (self.n_cache, self.s_cache, self.x_ref, self.stale) if cached else (None,) * 4
        drift, cell_dlo, cell_dhi, cell_drift, recomputed = (
            (self.drift, self.cell_dlo, self.cell_dhi, self.cell_drift, self.recomputed) if cached else (None,) * 5)
        drift_limit = DRIFT_LIMIT * self.skin
        listed = self.listed
        contact_count, contact_start, contact_fill, contact_over = (
            (self.contact_count, self.contact_start, self.contact_fill, self.contact_over) if listed else (None,) * 4)
        cell_dir, cell_spread = (self.cell_dir, self.cell_spread) if listed else (None, None)
        mask_at, mask_epoch = (self.mask_at, self.mask_epoch) if cached else (None, None)
        reuse_masks = cached and sten.origin is not None   # tensor stencils: the origin fixes the stencil's nodes
        grid_shape = list(sim.grid.shape)

        @ti.func
        def origin_key(p):
            """1 + the flat storage index of p's stencil origin (i64: large sparse 3D grids pass 2^31 nodes)."""
            b = sten.origin(p)
            k = ti.cast(0, ti.i64)
            for a in ti.static(range(dim)):
                k = k * grid_shape[a] + ti.cast(b[a], ti.i64)
            return k + 1

        cache_m, cache_n, cache_fill = ((self.node_cache.m, self.node_cache.vec["n"], self.node_cache_fill)
                                        if cached else (None,) * 3)
        moved2 = (0.5 * self.skin) ** 2   # a particle this far (squared) from where its normal was computed: refresh
        lower = ti.Vector(sim.lower.tolist())
        dx = sim.dx
        n_cells_grid = sim.n_cells
        cells = self.cells
        cells_v = ti.Vector(cells)
        n_cell_total = self.n_cell_total
        radius = self.radius
        inv_r = 1.0 / radius
        radius2 = radius * radius
        radius2_cut = radius2 * (1 + 1e-4)   # a cheap d2 test before sqrt(d2) < r: never drops a neighbour
        thr, dthr, gthr = float(cc.threshold), float(cc.damage_threshold), float(cc.gradient_threshold)
        contact_thr = max(thr, 0.0)   # particles facing each other for contact: never merely non-aligned ones
        contact = bool(cc.contact_in_compression)
        laws = self.laws
        has_law = self.has_law
        law_on = [law is not None for law in laws]
        laws = [law if law is not None else (1.0, 0.0, 0.0) for law in laws]
        single_mat = len(laws) == 1
        imped = [float(np.sqrt(m.density * (m.lam + 2 * m.mu))) for m in sim._materials]  # rho c
        tol = 1e-12 if sim.cfg.precision == "f64" else 1e-6   # pseudo-inverse cut-off, relative
        nbr = [(-CELL_SPLIT, CELL_SPLIT + 1)] * dim
        rows = nbr[:-1]   # a neighbour search walks rows of cells along the last axis
        inv_cell = CELL_SPLIT / radius

        # ---- SPH on a cell list ------------------------------------------------
        @ti.func
        def cell_of(xq):
            c = ti.Vector.zero(int, dim)
            for a in ti.static(range(dim)):
                c[a] = ti.min(ti.max(int(ti.floor((xq[a] - lower[a]) * inv_cell)), 0), cells[a] - 1)
            return c

        @ti.func
        def flat(c):
            k = 0
            for a in ti.static(range(dim)):
                k = k * cells[a] + c[a]
            return k

        @ti.func
        def unflat(k):
            c = ti.Vector.zero(int, dim)
            for a in ti.static(range(dim)):
                c[dim - 1 - a] = k % cells[dim - 1 - a]
                k //= cells[dim - 1 - a]
            return c

        @ti.func
        def row_cells(c, u, o, span: ti.template(), reach2: ti.template()):
            """One row (along the last axis) of the (2 span + 1)^d cells around cell c, as the flat indices of its first
            and last cell (first > last: none). o: the row's offsets on the other axes; u: the query point in cell
            units. Cells that cannot hold a particle within sqrt(reach2) cells of u are cut (their particles would
            fail the distance test anyway), so sums keep their terms and their order."""
            rem = float(reach2)   # the reach squared in cell units, less the row's squared gap
            base, inside = 0, True
            for a in ti.static(range(dim - 1)):
                k = c[a] + o[a]
                if k < 0 or k >= cells[a]:
                    inside = False
                gap = 0.0   # edge cells hold the particles beyond the domain too: no gap outwards there
                if u[a] < k and k > 0:
                    gap = k - u[a]
                elif u[a] > k + 1 and k < cells[a] - 1:
                    gap = u[a] - (k + 1)
                rem -= ti.max(gap - ROW_MARGIN, 0.0) ** 2
                base = base * cells[a] + k
            first, last = 0, -1
            if inside and rem > 0:
                z = ti.static(dim - 1)
                reach = ti.sqrt(rem) + ROW_MARGIN
                lo = ti.max(ti.min(int(ti.floor(u[z] - reach)), cells[z] - 1), 0, c[z] - span)
                hi = ti.min(ti.max(int(ti.floor(u[z] + reach)), 0), cells[z] - 1, c[z] + span)
                if lo <= hi:
                    first, last = base * cells[z] + lo, base * cells[z] + hi
            return first, last

        @ti.func
        def cells_slice(cells_range):
            """The particles of cells first..last: a slice [j0, j1) of `ids` (consecutive cells are consecutive in
            the sorted order)."""
            first, last = cells_range
            j0, j1 = 0, 0
            if first <= last:
                j0, j1 = cell_start[first], cell_start[last] + cell_count[last]
            return j0, j1

        @ti.func
        def row(c, u, o):
            """The SPH searches' candidates in one row of cells (reach r)."""
            return cells_slice(row_cells(c, u, o, CELL_SPLIT, float(CELL_SPLIT * CELL_SPLIT)))

        @ti.func
        def listed_at(p):
            """Where the cell list holds p (from the particle normals on): with kept normals, its position at the
            last refresh; the node normals and band middles of the steps until the next are found there."""
            xp = x[p]
            if ti.static(cached):
                xp = x_ref[p]
            return xp

        # the contact list's search: as far as two particles can come closer until the next refresh (each moves at
        # most skin / 2 from where the normals were computed, so 2 skin from where the list is built)
        wide_cells = CELL_SPLIT * (1.0 + 2.0 * float(cc.normal_refresh))
        wide_span = int(math.ceil(wide_cells))
        wide_reach2 = wide_cells * wide_cells
        rows_wide = [(-wide_span, wide_span + 1)] * (dim - 1)
        wide2 = (wide_cells / inv_cell) ** 2 * (1 + 1e-4)

        @ti.func
        def cell_units(xq):
            return (xq - lower) * inv_cell

        @ti.func
        def damage_field(xq):
            """Shepard-normalised SPH value and gradient of D at xq (cubic spline kernel of support r)."""
            c = cell_of(xq)
            u = cell_units(xq)
            Sw, SD = 0.0, 0.0
            gS = ti.Vector.zero(float, dim)
            gSD = ti.Vector.zero(float, dim)
            for o in ti.grouped(ti.ndrange(*rows)):
                j0, j1 = row(c, u, o)
                for j in range(j0, j1):
                    rv = xq - xs[j]
                    d2 = rv.norm_sqr()
                    if d2 < radius2:   # most candidates fall outside: no sqrt for them
                        dist = ti.sqrt(d2)
                        s = dist * inv_r
                        wk, dk = sph_kernel(s)
                        gw = ti.Vector.zero(float, dim)
                        if dist > 0:
                            gw = (dk * inv_r / dist) * rv
                        Vq, VDq = vs[j][0], vs[j][1]
                        Sw += Vq * wk
                        SD += VDq * wk
                        gS += Vq * gw
                        gSD += VDq * gw
            val = 0.0
            grad = ti.Vector.zero(float, dim)
            if Sw > 0:
                val = SD / Sw
                grad = gSD / Sw - SD * gS / (Sw * Sw)
            return val, grad

        @ti.func
        def sph_kernel(s):
            """Cubic spline kernel (unnormalised; Shepard normalisation divides it out) and d/ds, s = r / support."""
            wk, dk = 2.0 * (1.0 - s) ** 3, -6.0 * (1.0 - s) ** 2
            if s < 0.5:
                wk, dk = 1.0 - 6.0 * s * s + 6.0 * s * s * s, -12.0 * s + 18.0 * s * s
            return wk, dk

        @ti.func
        def contact_term(n, vp, q, d2):
            """A facing neighbour q at squared distance d2 (< r^2, up to rounding): its kernel weight, and that times
            its closing speed (v_q - v_p) . n."""
            wk = 0.0
            dist = ti.sqrt(d2)
            if dist < radius:
                wk, _ = sph_kernel(dist * inv_r)
            return wk, wk * (v[q] - vp).dot(n)

        @ti.func
        def closing_speed(p, n, pool: ti.template()):
            """Kernel-weighted mean of (v_q - v_p) . n_p over neighbours q within r across the discontinuity
            (n_p . n_q < -threshold): negative when the other side approaches p; and whether any q is in reach.
            Sums over p's contact list where it has one (the candidates in the order the search met them when it
            was built), else searches the cell list."""
            xp, vp = x[p], v[p]   # read once: the loops below are the contact test's cost
            sw, sv = 0.0, 0.0
            k = -1
            if ti.static(listed):
                k = contact_count[p]
            if k >= 0:
                s0 = 0
                if ti.static(listed):
                    s0 = contact_start[p]
                for i in range(s0, s0 + k):
                    q = pool[i]
                    d2 = (xp - x[q]).norm_sqr()
                    if d2 < radius2_cut:
                        if n.dot(normal[q]) < -contact_thr:
                            wk, wv = contact_term(n, vp, q, d2)
                            sw += wk
                            sv += wv
            else:   # the cell list holds the last refresh's positions: search the reach they can close to
                xl = listed_at(p)
                c = cell_of(xl)
                u = cell_units(xl)
                for o in ti.grouped(ti.ndrange(*rows_wide)):
                    j0, j1 = cells_slice(row_cells(c, u, o, wide_span, wide_reach2))
                    for j in range(j0, j1):
                        q = ids[j]
                        d2 = (xp - x[q]).norm_sqr()
                        if d2 < radius2_cut:
                            if n.dot(ns[j]) < -contact_thr:   # few neighbours face p: test before the sqrt
                                wk, wv = contact_term(n, vp, q, d2)
                                sw += wk
                                sv += wv
            res = 0.0
            if sw > 0:
                res = sv / sw
            return res, sw > 0

        @ti.func
        def impedance(p):
            z = ti.cast(imped[0], float)
            if ti.static(not single_mat):
                for k in ti.static(range(1, len(imped))):
                    if mat[p] == k:
                        z = imped[k]
            return z

        @ti.func
        def effective_stress(p):
            """Undamaged Cauchy stress of the particle (the damage law and the contact test read it)."""
            Fp = F[p]
            return kirchhoff(p, Fp) / Fp.determinant()

        @ti.func
        def rescan():
            """Whether this step recomputes the normals, so needs where D varies (the gradient sums read it only)."""
            scan = True
            if ti.static(cached):
                scan = stale[None] != 0
            return scan

        @ti.kernel
        def prepare():
            """The damage law and D; whether the kept normals are due (raises `stale`)."""
            for p in x:
                if ti.static(has_law):
                    sig = effective_stress(p)
                    for k in ti.static(range(len(laws))):
                        if ti.static(law_on[k]):
                            hit = True
                            if ti.static(not single_mat):
                                hit = mat[p] == k
                            if hit:
                                dn, kap = rankine_damage(sig, kappa[p], laws[k][0], laws[k][1], laws[k][2])
                                kappa[p] = kap
                                if dn > d_f[p]:
                                    d_f[p] = dn
                                    if ti.static(cached):   # D grew: the normals move with it
                                        ti.atomic_max(stale[None], ALL)
                if ti.static(cached):
                    if (x[p] - x_ref[p]).norm_sqr() > moved2:
                        ti.atomic_max(stale[None], DRIFTED)
                D[p] = ti.max(d_f[p], ti.cast(iface[p], float))

        @ti.func
        def binned_position(p, at_refresh):
            """Where bin_cells puts p: its position, or where the list held it (`at_refresh`: rebuilt between
            refreshes, after set_state)."""
            xp = x[p]
            if at_refresh:
                xp = listed_at(p)
            return xp

        @ti.kernel
        def bin_cells(at_refresh: ti.i32):
            """The cell list (a counting sort), with positions and SPH weights in cell order, and on refreshes
            where D varies and how far particles within reach moved against each other. With kept normals it is
            built at refreshes only: until the next one, node normals and band middles are found in the
            configuration the particle normals were (particles have moved at most half the skin since)."""
            for c in cell_count:
                cell_count[c] = 0
                cell_fill[c] = 0
            for p in x:
                c = flat(cell_of(binned_position(p, at_refresh)))
                pcell[p] = c
                ti.atomic_add(cell_count[c], 1)
            ti.loop_config(serialize=True)
            for c in range(1, n_cell_total):
                cell_start[c] = cell_start[c - 1] + cell_count[c - 1]
            for p in x:
                c = pcell[p]
                ids[cell_start[c] + ti.atomic_add(cell_fill[c], 1)] = p
            for c in cell_count:  # insertion sort within each cell: sums in a fixed order, runs reproducible
                s0 = cell_start[c]
                for i in range(1, cell_count[c]):
                    key = ids[s0 + i]
                    j = i - 1
                    while j >= 0:
                        if ids[s0 + j] > key:
                            ids[s0 + j + 1] = ids[s0 + j]
                            j -= 1
                        else:
                            break
                    ids[s0 + j + 1] = key
            for j in ids:
                q = ids[j]
                xs[j] = binned_position(q, at_refresh)
                vs[j] = ti.Vector([vol0[q], vol0[q] * D[q]])
            # refresh steps only: the cells' min / max of D and box of motion since the last refresh, then over each
            # occupied cell's 5^d block (where D varies; how far particles that reach each other moved apart)
            d_range[0], d_range[1] = 1.0, 0.0
            for c in cell_count:
                if rescan():
                    lo, hi = 1.0, 0.0
                    dlo = ti.Vector([BIG] * dim)
                    dhi = ti.Vector([-BIG] * dim)
                    for j in range(cell_start[c], cell_start[c] + cell_count[c]):
                        q = ids[j]
                        lo, hi = ti.min(lo, D[q]), ti.max(hi, D[q])
                        if ti.static(cached):
                            dq = xs[j] - x_ref[q]
                            dlo, dhi = ti.min(dlo, dq), ti.max(dhi, dq)
                    cell_lo[c], cell_hi[c] = lo, hi
                    if ti.static(cached):
                        cell_dlo[c], cell_dhi[c] = dlo, dhi
                    if cell_count[c] > 0:
                        ti.atomic_min(d_range[0], lo)
                        ti.atomic_max(d_range[1], hi)
            for c in cell_count:
                if rescan():
                    cell_varies[c] = 0
                    if ti.static(cached):
                        cell_drift[c] = 0.0
                    if cell_count[c] > 0 and d_range[1] > d_range[0]:   # nothing to scan where D is one value
                        lo, hi = 1.0, 0.0
                        dlo = ti.Vector([BIG] * dim)
                        dhi = ti.Vector([-BIG] * dim)
                        cc = unflat(c)
                        for off in ti.grouped(ti.ndrange(*nbr)):
                            cn = cc + off
                            if (cn >= 0).all() and (cn < cells_v).all():
                                cid = flat(cn)
                                if cell_count[cid] > 0:
                                    lo = ti.min(lo, cell_lo[cid])
                                    hi = ti.max(hi, cell_hi[cid])
                                    if ti.static(cached):
                                        dlo, dhi = ti.min(dlo, cell_dlo[cid]), ti.max(dhi, cell_dhi[cid])
                        cell_varies[c] = ti.cast(hi > lo, ti.i32)
                        if ti.static(cached):
                            cell_drift[c] = (dhi - dlo).norm()

        @ti.func
        def mark_stencil(p):
            sd = sten.at(p)
            for o in ti.grouped(ti.ndrange(*sten.outer)):
              for k in ti.static(range(len(sten.inner))):  # noqa: E111 (the solver's split)
                I, w, gw, r = sten.node(sd, o + sten.inner[k])
                node_mark[I] = 1.0

        @ti.kernel
        def particle_normals(level: ti.i32):
            """The particles' normals: kept (KEEP), recomputed where the neighbours moved against each other by the
            skin since they were (DRIFTED; the normal is the same for a neighbourhood moved as a whole), or all."""
            for p in x:
                st = STANDARD
                nrm = ti.Vector.zero(float, dim)
                redo = level != KEEP
                if ti.static(cached):
                    if level == DRIFTED:   # bound on the neighbours' motion against p since n_p was computed
                        moved = drift[p] + cell_drift[pcell[p]]
                        redo = moved > drift_limit
                        drift[p] = moved
                if redo:
                    if cell_varies[pcell[p]]:  # D varies within reach: p may sit near a discontinuity
                        _, g = damage_field(x[p])
                        gn = g.norm() * radius
                        if (D[p] >= dthr or gn >= gthr) and gn > 1e-6:
                            nrm = g / g.norm()
                            st = MODIFIED
                    if ti.static(cached):
                        n_cache[p], s_cache[p], drift[p] = nrm, st, 0.0
                        recomputed[None] += 1
                elif ti.static(cached):
                    nrm, st = n_cache[p], s_cache[p]
                if ti.static(cached):
                    if level != KEEP:
                        x_ref[p] = x[p]
                normal[p] = nrm
                state[p] = st
                if st != STANDARD:
                    mark_stencil(p)

        @ti.func
        def band_normals():
            """A damaged particle without a gradient (the middle of an odd-width damage band) joins one side:
            its normal is the principal direction of its undamaged neighbours' normals, signed so that its
            largest component is positive. Otherwise it would couple both faces through its own mass."""
            for p in x:
                if state[p] == STANDARD and D[p] >= dthr:
                    T = ti.Matrix.zero(float, dim, dim)
                    xp = listed_at(p)   # in the configuration of the cell list, as the kept normals
                    c = cell_of(xp)
                    u = cell_units(xp)
                    for o in ti.grouped(ti.ndrange(*rows)):
                        j0, j1 = row(c, u, o)
                        for j in range(j0, j1):
                            q = ids[j]
                            d2 = (xp - xs[j]).norm_sqr()
                            if d2 < radius2_cut and D[q] < dthr and state[q] == MODIFIED:
                                dist = ti.sqrt(d2)
                                if dist < radius:
                                    s = dist * inv_r
                                    wk, _ = sph_kernel(s)
                                    T += wk * normal[q].outer_product(normal[q])
                    if T.trace() > 0:
                        ev, Q = sym_eig(T)
                        e = ti.Vector([Q[a, 0] for a in ti.static(range(dim))])
                        big = ev[0]
                        for k in ti.static(range(1, dim)):
                            if ev[k] > big:
                                big = ev[k]
                                e = ti.Vector([Q[a, k] for a in ti.static(range(dim))])
                        lead = e[0]
                        for a in ti.static(range(1, dim)):
                            if ti.abs(e[a]) > ti.abs(lead):
                                lead = e[a]
                        if lead < 0:
                            e = -e
                        normal[p] = e
                        state[p] = MODIFIED
                        mark_stencil(p)

        @ti.func
        def node_normals():
            for I in ti.grouped(node_mark):
                if node_mark[I] > 0:
                    nn = ti.Vector.zero(float, dim)
                    on = False   # the node lies on the discontinuity: both sides leave it
                    known = False
                    if ti.static(cached):   # computed since the particle normals were
                        known = cache_m[I] > 0
                        if known:
                            nn, on = cache_n[I], cache_m[I] > 1.5
                    if not known:
                        y = ti.Vector.zero(float, dim)
                        for a in ti.static(range(dim)):
                            y[a] = lower[a] + basis.coord(I[a], n_cells_grid[a]) * dx
                        val, g = damage_field(y)
                        gn = g.norm() * radius
                        if gn > 1e-6:
                            nn = g / g.norm()
                        on = gn < gthr and val >= dthr
                        if ti.static(cached):
                            cache_n[I], cache_m[I] = nn, ti.select(on, 2.0, 1.0)
                    node_n[I] = nn
                    if on:
                        node_mark[I] = 2.0

        @ti.kernel
        def node_cache_size() -> ti.i32:
            k = 0
            if ti.static(cached):
                for I in ti.grouped(cache_m):
                    if cache_m[I] > 0:
                        k += 1
            return k

        @ti.kernel
        def node_cache_read(idx: ti.types.ndarray(), nrm: ti.types.ndarray(), flag: ti.types.ndarray()):
            if ti.static(cached):
                for I in ti.grouped(cache_m):
                    if cache_m[I] > 0:
                        k = ti.atomic_add(cache_fill[None], 1)
                        for a in ti.static(range(dim)):
                            idx[k, a], nrm[k, a] = I[a], cache_n[I][a]
                        flag[k] = cache_m[I]

        @ti.kernel
        def node_cache_write(idx: ti.types.ndarray(), nrm: ti.types.ndarray(), flag: ti.types.ndarray(), k: ti.i32):
            if ti.static(cached):
                for j in range(k):
                    I = ti.Vector([idx[j, a] for a in ti.static(range(dim))])
                    cache_m[I] = flag[j]
                    cache_n[I] = ti.Vector([nrm[j, a] for a in ti.static(range(dim))])

        @ti.func
        def sort_normals():
            if ti.static(contact):
                for j in ids:
                    ns[j] = normal[ids[j]]

        @ti.func
        def kept_facing(q):
            """q's kept normal for the contact list's search; a band particle, which counts as facing any p, as a
            vector of length 2 (no normal has it)."""
            nq = n_cache[q]
            if s_cache[q] == STANDARD and D[q] >= dthr:
                nq = ti.Vector.zero(float, dim)
                nq[0] = 2.0
            return nq

        @ti.func
        def normal_cone(c):
            """A cone holding the kept normals of cell c (cell order, `kept_facing`): a unit direction u and a spread
            s >= |n_q - u| for every q, so n_p . n_q >= n_p . u - s: no particle of the cell faces p where that bound
            is >= -threshold. No normal in the cell: s = -2 (nothing faces); a band particle: s = 4 (anything may)."""
            total = ti.Vector.zero(float, dim)
            band = False
            for j in range(cell_start[c], cell_start[c] + cell_count[c]):
                nq = ns[j]
                if nq.norm_sqr() > 2.0:
                    band = True
                else:
                    total += nq
            u = ti.Vector.zero(float, dim)
            if total.norm_sqr() > 0:
                u = total.normalized()
            spread = -2.0
            if band:
                spread = 4.0
            else:
                for j in range(cell_start[c], cell_start[c] + cell_count[c]):
                    if ns[j].norm_sqr() > 0:
                        spread = ti.max(spread, (ns[j] - u).norm())
            return u, spread

        @ti.func
        def facing_scan(p, pool: ti.template(), s0, cap):
            """The particles within the reach two particles can close to before the normals are recomputed whose
            kept normal faces p's (band particles, whose normals follow their neighbours every step, count as
            facing), in the order the search meets them: the first `cap` written to pool[s0:], all counted."""
            k = 0
            n, xp = n_cache[p], listed_at(p)
            c = cell_of(xp)
            u = cell_units(xp)
            for o in ti.grouped(ti.ndrange(*rows_wide)):
                first, last = row_cells(c, u, o, wide_span, wide_reach2)
                for cell in range(first, last + 1):
                    if n.dot(cell_dir[cell]) - cell_spread[cell] < CONE_MARGIN - contact_thr:
                        for j in range(cell_start[cell], cell_start[cell] + cell_count[cell]):
                            if (xp - xs[j]).norm_sqr() < wide2:
                                nq = ns[j]
                                if n.dot(nq) < -contact_thr or nq.norm_sqr() > 2.0:
                                    if k < cap:
                                        pool[s0 + k] = ids[j]
                                    k += 1
            return k

        @ti.kernel
        def contact_list(pool: ti.types.ndarray(dtype=ti.i32, ndim=1), stage: ti.template()) -> ti.i32:
            """Each particle's contact list (`facing_scan`), in one search: SLOTS takes each particle's slots in
            the pool, its last count + 25 % + LIST_SLACK (returns the slots taken); FILL writes and counts the
            lists, and marks one that outgrew its slots (start -1; returns the slots those need); OVERFLOW gives
            those their exact slots and searches again. A band particle itself searches each step (count -1)."""
            if ti.static(listed):
                if ti.static(stage == SLOTS):
                    contact_fill[None] = 0
                    for j in ids:   # the kept normals in cell order, so the searches stream
                        ns[j] = kept_facing(ids[j])
                    for c in cell_count:
                        cell_dir[c], cell_spread[c] = normal_cone(c)
                    for p in x:
                        cap = 0
                        if s_cache[p] != STANDARD:   # p may be near before the next refresh
                            last = ti.max(contact_count[p], 0)
                            cap = last + last // 4 + LIST_SLACK
                        elif D[p] >= dthr:   # a band particle
                            cap = -1
                        contact_count[p] = cap
                        contact_start[p] = 0
                        if cap > 0:
                            contact_start[p] = ti.atomic_add(contact_fill[None], cap)
                elif ti.static(stage == FILL):
                    contact_over[None] = 0
                    for p in x:
                        cap = contact_count[p]
                        if cap > 0:
                            k = facing_scan(p, pool, contact_start[p], cap)
                            contact_count[p] = k
                            if k > cap:
                                contact_start[p] = -1
                                ti.atomic_add(contact_over[None], k)
                else:
                    for p in x:
                        if contact_start[p] < 0:
                            k = contact_count[p]
                            contact_start[p] = ti.atomic_add(contact_fill[None], k)
                            facing_scan(p, pool, contact_start[p], k)
            out = 0
            if ti.static(listed):
                out = contact_over[None] if ti.static(stage == FILL) else contact_fill[None]
            return out

        @ti.func
        def particle_masks(epoch, pool: ti.template()):
            contacts[None] = 0
            for p in x:
                key = ti.cast(0, ti.i64)
                known = False   # p's mask is the one found before (no node normals to read)
                if ti.static(reuse_masks):
                    # within one period of kept normals a node's side depends only on the node and p's normal
                    # (band particles excepted: theirs follow their neighbours each step)
                    if state[p] != STANDARD and s_cache[p] != STANDARD:
                        key = origin_key(p)
                        known = mask_epoch[p] == epoch and mask_at[p] == key
                if known and mask[p] == 0:   # still nothing across
                    state[p] = STANDARD
                elif state[p] != STANDARD:
                    n = normal[p]
                    sd = sten.at(p)
                    m = ti.cast(0, mask_t)
                    m_known = mask[p]
                    St, Sx = 0.0, 0.0   # weights of the nodes on p's side / across
                    Gt = ti.Vector.zero(float, dim)
                    Gx = ti.Vector.zero(float, dim)
                    ct = ti.Vector.zero(float, dim)
                    cx = ti.Vector.zero(float, dim)
                    for o in ti.grouped(ti.ndrange(*sten.outer)):
                      for k in ti.static(range(len(sten.inner))):  # noqa: E111 (the solver's split)
                        off = o + sten.inner[k]
                        I, w, gw, r = sten.node(sd, off)
                        bit = ti.cast(1, mask_t) << ti.cast(sten.index(off), mask_t)
                        across = False
                        if known:
                            across = (m_known & bit) != 0
                        else:
                            across = node_mark[I] > 1.5 or n.dot(node_n[I]) < -thr
                        if across:
                            m |= bit
                            Sx += w
                            Gx += gw
                            cx += w * r
                        else:
                            St += w
                            Gt += gw
                            ct += w * r
                    st = STANDARD       # nothing across, or it would lose (almost) every node
                    if m != 0 and St >= S_FLOOR:
                        st = MODIFIED
                        if ti.static(contact):  # material across within reach, and trial normal traction < 0
                            vc, touching = closing_speed(p, n, pool)
                            if touching:   # nested: Taichi's `and` evaluates both sides; the stress costs
                                if n.dot(effective_stress(p) @ n) + impedance(p) * vc < 0.0:
                                    st = CONTACT
                                    contacts[None] += 1
                    Sn, Gn, cn = St, Gt, ct
                    if st == CONTACT:   # the normal family keeps the nodes across
                        Sn, Gn, cn = St + Sx, Gt + Gx, ct + cx
                    state[p] = st
                    mask[p] = m
                    if ti.static(reuse_masks):
                        if key != 0:
                            mask_at[p], mask_epoch[p] = key, epoch
                    sums[p] = ti.Vector([St, Sn])
                    for a in ti.static(range(dim)):
                        gsum[p][0, a] = Gt[a]
                        gsum[p][1, a] = Gn[a]
                        if ti.static(apic):
                            cent[p][0, a] = ct[a] / St
                            cent[p][1, a] = cn[a] / Sn

        @ti.kernel
        def classify(epoch: ti.i32, pool: ti.types.ndarray(dtype=ti.i32, ndim=1)):
            """Steps 4-6 after the particle normals, one launch (each loop still runs in parallel, in turn): band
            middles, the normals in cell order (contact searches), node normals, masks and contact."""
            band_normals()
            sort_normals()
            node_normals()
            particle_masks(epoch, pool)

        # ---- funcs used inside the solver's kernels -----------------------------
        @ti.func
        def modified(p):
            return state[p] != STANDARD

        @ti.func
        def degrade(p, tau):
            out = tau
            if d_f[p] > 0:
                out = degrade_tension(tau, d_f[p])
            return out

        @ti.func
        def degrade_energy(p, Fp, psi, tau):
            """Strain energy the damaged particle still stores: psi scaled by tau_d : eps / tau : eps with the
            Hencky strain eps = ln(V) (coaxial with tau for isotropic models). Isotropic damage gives (1 - d) psi,
            closed cracks (all principal stresses compressive) keep psi, matching `degrade`'s split; the rest was
            released by the damage law (a loss, which the solver's energy balance allows)."""
            out = psi
            if d_f[p] > 0:
                ev, Q = sym_eig(Fp @ Fp.transpose())
                eps = ti.Matrix.zero(float, dim, dim)
                for k in ti.static(range(dim)):
                    q = ti.Vector([Q[a, k] for a in ti.static(range(dim))])
                    eps += 0.5 * ti.log(ti.max(ev[k], 1e-30)) * q.outer_product(q)
                full = (tau * eps).sum()
                share = 1.0 - d_f[p]
                if full > 0:
                    share = ti.min(ti.max((degrade_tension(tau, d_f[p]) * eps).sum() / full, 0.0), 1.0)
                out = psi * share
            return out

        @ti.func
        def family(p):
            """A modified particle's mask, contact flag, the reciprocals of its sums and its gradient sums, read once
            per particle (a multiply per node instead of a divide)."""
            Gt = ti.Vector([gsum[p][0, a] for a in ti.static(range(dim))])
            Gn = ti.Vector([gsum[p][1, a] for a in ti.static(range(dim))])
            return mask[p], state[p] == CONTACT, 1.0 / sums[p][0], 1.0 / sums[p][1], Gt, Gn

        @ti.func
        def tangential(fam, off, w, gw):
            """The rescaled tangential function of one node and its gradient: Nt = N*_t / S_t and
            grad Nt = (grad N*_t - Nt grad S_t) / S_t, N*_t = 0 for a node across. W_ip = Nt I + (Nn - Nt) n n^T;
            a particle not in contact has Nn = Nt (same nodes, sums and centroids): a scalar weight."""
            m, _, iSt, _, Gt, _ = fam
            across = (m >> ti.cast(sten.index(off), mask_t)) & ti.cast(1, mask_t)
            wt, gt = w, gw
            if across != 0:
                wt, gt = 0.0, ti.Vector.zero(float, dim)
            wt *= iSt
            return wt, (gt - wt * Gt) * iSt

        @ti.func
        def normal_family(fam, w, gw):
            """The rescaled normal function of a particle in contact (it keeps the nodes across) and its gradient."""
            _, _, _, iSn, _, Gn = fam
            wn = w * iSn
            return wn, (gw - wn * Gn) * iSn

        @ti.func
        def momentum_origins(p, vp, Ap):
            """APIC about each family's centroid c: a node sees vp + Ap (r - c) = (vp - Ap c) + Ap r, so
            sum_i W_ip mom_i = v_p exactly; returns vp - Ap c of the tangential and the normal family."""
            vt, vn = vp, vp
            if ti.static(apic):
                ct = ti.Vector([cent[p][0, a] for a in ti.static(range(dim))])
                cn = ti.Vector([cent[p][1, a] for a in ti.static(range(dim))])
                vt, vn = vp - Ap @ ct, vp - Ap @ cn
            return vt, vn

        @ti.func
        def node_momentum(v0, Ap, r):
            mom = v0
            if ti.static(apic):
                mom = v0 + Ap @ r
            return mom

        @ti.func
        def p2g(p, st, mp, stress, vp, Ap, force_density, kick):
            """P2G of a particle near a discontinuity: mass, momentum (APIC about each family's centroid), stress
            force and body force through W_ip; the normal family's terms only for a particle in contact."""
            n = normal[p]
            fam = family(p)
            vt, vn = momentum_origins(p, vp, Ap)
            for o in ti.grouped(ti.ndrange(*sten.outer)):
              for k in ti.static(range(len(sten.inner))):  # noqa: E111 (the solver's split of the stencil loop)
                off = o + sten.inner[k]
                I, w, gw, r = sten.node(st, off)
                wt, gt = tangential(fam, off, w, gw)
                mom_t = node_momentum(vt, Ap, r)
                f_t = stress @ gt + wt * force_density
                mv = mp * wt * mom_t + kick * f_t
                dw = 0.0   # Nn - Nt
                if fam[1]:
                    wn, gn = normal_family(fam, w, gw)
                    dw = wn - wt
                    f_n = stress @ gn + wn * force_density
                    mom_n = node_momentum(vn, Ap, r)
                    mv += (mp * (wn * n.dot(mom_n) - wt * n.dot(mom_t)) + kick * n.dot(f_n - f_t)) * n
                    for a in ti.static(range(dim)):
                        add(Arows[a], I, mp * dw * n[a] * n)
                add(gm, I, wt * mp)   # plain adds inside the solver's colour loop (no other thread at this node)
                add(gv, I, mv)
                if ti.static(flip):
                    add(gv_old, I, mp * (wt * vp + dw * n.dot(vp) * n))

        @ti.func
        def p2g_momentum(p, st, mp, vp, Ap):
            n = normal[p]
            fam = family(p)
            vt, vn = momentum_origins(p, vp, Ap)
            for o in ti.grouped(ti.ndrange(*sten.outer)):
              for k in ti.static(range(len(sten.inner))):  # noqa: E111
                off = o + sten.inner[k]
                I, w, gw, r = sten.node(st, off)
                wt, _ = tangential(fam, off, w, gw)
                mom_t = node_momentum(vt, Ap, r)
                mv = mp * wt * mom_t
                if fam[1]:
                    wn, _ = normal_family(fam, w, gw)
                    mv += mp * (wn * n.dot(node_momentum(vn, Ap, r)) - wt * n.dot(mom_t)) * n
                add(gv2, I, mv)

        @ti.func
        def g2p(p, st, deform: ti.template()):
            """(v_pic, FLIP increment, APIC B, velocity gradient G) with the modified functions.
            APIC's affine C of such a particle is its velocity gradient: B = G D_p makes the solver's
            C = B D_p^-1 equal G."""
            n = normal[p]
            fam = family(p)
            v_pic = ti.Vector.zero(float, dim)
            dv = ti.Vector.zero(float, dim)
            G = ti.Matrix.zero(float, dim, dim)
            for o in ti.grouped(ti.ndrange(*sten.outer)):
              for k in ti.static(range(len(sten.inner))):  # noqa: E111 (the solver's split of the stencil loop)
                off = o + sten.inner[k]
                I, w, gw, r = sten.node(st, off)
                wt, gt = tangential(fam, off, w, gw)
                vi = gv[I]
                vg = vi
                if ti.static(deform):  # MUSL's deform pass reads the remapped velocities
                    vg = vgrad[I]
                dvi = ti.Vector.zero(float, dim)
                if ti.static(flip):
                    dvi = vi - gv_old[I]
                v_pic += wt * vi
                dv += wt * dvi
                G += vg.outer_product(gt)
                if fam[1]:   # (Pt vg) gt^T + (Pn vg) gn^T
                    wn, gn = normal_family(fam, w, gw)
                    v_pic += (wn - wt) * n.dot(vi) * n
                    dv += (wn - wt) * n.dot(dvi) * n
                    G += (n.dot(vg) * n).outer_product(gn - gt)
            return v_pic, dv, G @ sten.inertia(st), G

        # ---- grid update with tensor node mass ----------------------------------
        @ti.func
        def node_mass(I):
            A = ti.Matrix.zero(float, dim, dim)
            if node_mark[I] > 0:   # only particles in contact add to A, and their stencils are marked
                for a in ti.static(range(dim)):
                    for b in ti.static(range(dim)):
                        A[a, b] = Arows[a][I][b]
            return gm[I], A

        @ti.func
        def solve(m, A, vec):
            """M^+ vec for M = m I + A (symmetric positive semi-definite)."""
            res = ti.Vector.zero(float, dim)
            if A.norm_sqr() == 0:
                if m > 0:
                    res = vec / m
            else:
                M = m * ti.Matrix.identity(float, dim) + A
                M = 0.5 * (M + M.transpose())
                ev, Q = sym_eig(M)
                cut = tol * ev.max()
                for k in ti.static(range(dim)):
                    if ev[k] > cut:
                        q = ti.Vector([Q[a, k] for a in ti.static(range(dim))])
                        res += q.dot(vec) / ev[k] * q
            return res

        @ti.kernel
        def grid_update(kick_before: float, kick_after: float):
            for I in ti.grouped(gm):
                m, A = node_mass(I)
                if m > 0 or A.norm_sqr() > 0:
                    vel = solve(m, A, gv[I]) + gravity_kick(kick_before, kick_after)
                    gv[I] = wall(I, vel)
                    if ti.static(flip):
                        gv_old[I] = solve(m, A, gv_old[I])

        @ti.kernel
        def grid_remap():
            for I in ti.grouped(gm):
                m, A = node_mass(I)
                if m > 0 or A.norm_sqr() > 0:
                    gv2[I] = wall(I, solve(m, A, gv2[I]))

        # ---- inspection (tests) -------------------------------------------------
        @ti.kernel
        def partition_check(out: ti.types.ndarray()):
            """Per particle: state, sum Nt, sum Nn, |sum grad Nt|_inf, |sum grad Nn|_inf, |sum W_ip - I|_inf."""
            for p in x:
                st = sten.at(p)
                st_ = state[p]
                swt, swn = 0.0, 0.0
                sgt = ti.Vector.zero(float, dim)
                sgn = ti.Vector.zero(float, dim)
                Wsum = ti.Matrix.zero(float, dim, dim)
                for off in ti.grouped(ti.ndrange(*span)):
                    I, w, gw, r = sten.node(st, off)
                    wt, wn, gt, gn = w, w, gw, gw
                    if st_ != STANDARD:
                        fam = family(p)
                        wt, gt = tangential(fam, off, w, gw)
                        wn, gn = wt, gt
                        if fam[1]:
                            wn, gn = normal_family(fam, w, gw)
                    swt += wt
                    swn += wn
                    sgt += gt
                    sgn += gn
                    if st_ != STANDARD:
                        Pn = normal[p].outer_product(normal[p])   # W_ip = Nt (I - n n^T) + Nn n n^T
                        Wsum += wt * (ti.Matrix.identity(float, dim) - Pn) + wn * Pn
                    else:
                        Wsum += w * ti.Matrix.identity(float, dim)
                out[p, 0] = st_
                out[p, 1] = swt
                out[p, 2] = swn
                out[p, 3] = ti.abs(sgt).max()
                out[p, 4] = ti.abs(sgn).max()
                out[p, 5] = ti.abs(Wsum - ti.Matrix.identity(float, dim)).max()
                out[p, 6] = ti.cast(mask[p] != 0, float)

        self._k = dict(prepare=prepare, bin_cells=bin_cells, particle_normals=particle_normals,
                       contact_list=contact_list, classify=classify, grid_update=grid_update, grid_remap=grid_remap,
                       partition_check=partition_check, node_cache_size=node_cache_size,
                       node_cache_read=node_cache_read, node_cache_write=node_cache_write)
        return CrackHooks(modified=modified, degrade=degrade, degrade_energy=degrade_energy, p2g=p2g,
                          p2g_momentum=p2g_momentum, g2p=g2p, kernels={"grid_update_tensor": grid_update,
                                                                       "grid_remap_tensor": grid_remap})

    def partition_check(self) -> np.ndarray:
        """(N, 7) per particle in creation order: state, sum Nt, sum Nn, max|sum grad Nt|, max|sum grad Nn|,
        max|sum_i W_ip - I|, any node across. Runs the crack finder on the current state first."""
        self.update()
        out = np.zeros((self.sim.n, 7), dtype=np.float64)
        self._k["partition_check"](out)
        return self.sim._to_creation(out)
