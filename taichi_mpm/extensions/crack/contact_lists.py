"""Contact lists: per particle, the particles that could face it within reach until the next refresh of the kept
normals, found once per refresh (cells ruled out by their normal cones) in a pool that grows as needed; the
contact test then sums over the list instead of searching the cell list each step."""

import numpy as np
import taichi as ti

from .constants import CONE_MARGIN, FILL, LIST_SLACK, OVERFLOW, SLOTS, STANDARD


def _normal_cone_funcs(ctx):
    """kept_facing(q) and normal_cone(c): the kept normals in cell order and the cells' cones for the search."""
    f, dim = ctx.fields, ctx.fields.dim
    D, ns, cell_start, cell_count, dthr = f.D, f.ns, f.cell_start, f.cell_count, ctx.dthr
    n_cache, s_cache = (f.n_cache, f.s_cache) if f.cached else (None, None)
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

    return kept_facing, normal_cone


def contact_list_kernel(ctx, cl):
    """The kernel contact_list(pool, stage) (ContactPool.build runs its stages)."""
    f = ctx.fields
    x, D, ids, xs, ns, cell_start, cell_count = ctx.view.x, f.D, f.ids, f.xs, f.ns, f.cell_start, f.cell_count
    listed, dthr, contact_thr, wide2 = f.listed, ctx.dthr, ctx.contact_thr, ctx.wide2
    rows_wide, wide_span, wide_reach2 = ctx.rows_wide, ctx.wide_span, ctx.wide_reach2
    n_cache, s_cache = (f.n_cache, f.s_cache) if f.cached else (None, None)
    contact_count, contact_start, contact_fill, contact_over, cell_dir, cell_spread = (
        (f.contact_count, f.contact_start, f.contact_fill, f.contact_over, f.cell_dir, f.cell_spread)
        if listed else (None,) * 6)
    cell_of, cell_units, row_cells, listed_at = cl.cell_of, cl.cell_units, cl.row_cells, cl.listed_at
    kept_facing, normal_cone = _normal_cone_funcs(ctx)

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

    return contact_list


class ContactPool:
    """The contact lists' pool of particle ids (one unused slot without lists), grown as the lists need."""

    def __init__(self):
        self.ids = ti.ndarray(ti.i32, 1)

    def build(self, contact_list):
        """Take each particle's slots in the pool (sized by its last list), write the lists in one search, and
        search again only for those that outgrew their slots; the pool grows when short."""
        taken = contact_list(self.ids, SLOTS)
        self.reserve(taken)
        over = contact_list(self.ids, FILL)
        if over:
            self.reserve(taken + over)
            contact_list(self.ids, OVERFLOW)

    def reserve(self, size: int):
        """A pool of at least `size` slots, keeping what it holds."""
        if size > self.ids.shape[0]:
            held = self.ids.to_numpy()
            grown = np.zeros(size + size // 4, np.int32)
            grown[:len(held)] = held
            self.ids = ti.ndarray(ti.i32, len(grown))
            self.ids.from_numpy(grown)
