"""Node normals: at each node a near particle marked, grad D from the same SPH sums (a node on the discontinuity
itself is marked 2), kept in the node cache until the particle normals are next recomputed; and the kernels that
read and write that cache for checkpoints."""

from typing import Callable, NamedTuple

import taichi as ti


class NodeCache(NamedTuple):
    size: Callable    # kernel () -> nodes held
    read: Callable    # kernel (idx, nrm, flag): the held nodes, in thread order
    write: Callable   # kernel (idx, nrm, flag, k)


def node_position(ctx):
    """@ti.func (I) -> node I's position: on the box, each axis's node coordinate (its knot vector's Greville
    abscissa with domain.knots); on a mapped grid (domain.map), its control point."""
    dim, basis, lower, dx, n_cells_grid = ctx.fields.dim, ctx.solver.basis, ctx.lower, ctx.view.dx, ctx.view.n_cells
    mapped = ctx.solver.extra.get("mapped") if basis.kind == "mapped" else None
    on_map = mapped is not None
    ctrl = mapped.map.ctrl if on_map else None
    coords = [basis.axis(a).coord for a in range(dim)] if not on_map else None

    @ti.func
    def position(I):
        y = ti.Vector.zero(float, dim)
        if ti.static(on_map):
            y = ctrl[I]
        else:
            for a in ti.static(range(dim)):
                y[a] = lower[a] + coords[a](I[a], n_cells_grid[a]) * dx
        return y
    return position


def node_normals_func(ctx, sph):
    """The func node_normals() (classify calls it)."""
    f, dim = ctx.fields, ctx.fields.dim
    radius, dthr, gthr, cached = ctx.radius, ctx.dthr, ctx.gthr, f.cached
    node_mark, node_n = ctx.view.grid.scalar["crack_mark"], ctx.view.grid.vec["crack_n"]
    cache_m, cache_n = (f.node_cache.m, f.node_cache.vec["n"]) if cached else (None, None)
    damage_field = sph.damage_field
    position = node_position(ctx)

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
                    val, g = damage_field(position(I), -1)
                    gn = g.norm() * radius
                    if gn > 1e-6:
                        nn = g / g.norm()
                    on = gn < gthr and val >= dthr
                    if ti.static(cached):
                        cache_n[I], cache_m[I] = nn, ti.select(on, 2.0, 1.0)
                node_n[I] = nn
                if on:
                    node_mark[I] = 2.0

    return node_normals


SIDE_BITS = 8   # the owner key's low bits: the side + 1 of its particle (at most MAX_SIDES interface bodies)
MAX_SIDES = (1 << SIDE_BITS) - 1


def owner_key_funcs(precision: str):
    """(key(w, side), side_of(key)): a node's claim by an interface particle as one i64, so that one atomic max
    keeps the largest weight and, among equal weights, the larger side (the same result in every thread order).
    A weight w >= 0 orders as its bits do; f32: all 32 of them above the side; f64: its bits with the lowest
    SIDE_BITS mantissa bits replaced by the side (weights within 2^-44 of each other count as equal)."""
    f32 = precision == "f32"

    @ti.func
    def key(w, side):
        k = ti.cast(0, ti.i64)
        if ti.static(f32):
            k = (ti.cast(ti.bit_cast(w, ti.i32), ti.i64) << SIDE_BITS) | ti.cast(side + 1, ti.i64)
        else:
            k = (ti.bit_cast(w, ti.i64) & ~ti.cast(MAX_SIDES, ti.i64)) | ti.cast(side + 1, ti.i64)
        return k

    @ti.func
    def side_of(k):
        """The owner's side + 1 (0: no interface particle claimed the node)."""
        return ti.cast(k & MAX_SIDES, ti.i32)

    return key, side_of


def node_owner_funcs(ctx):
    """(claim_nodes, owned_by_another(p, I)): with two or more interface bodies, each marked node's owner, and
    whether a node belongs to another interface body than particle p's (no-ops otherwise)."""
    f, sten, node_mark = ctx.fields, ctx.solver.stencil, ctx.view.grid.scalar["crack_mark"]
    x, sides, side = ctx.view.x, f.sides, f.side
    owner = ctx.view.grid.scalar["crack_owner"] if sides else None
    key, side_of = owner_key_funcs(ctx.view.precision)

    @ti.func
    def claim_nodes():
        """With two or more interface bodies, each marked node's owner: the side (+1) of the interface particle
        with the largest weight there (ties: the larger side, so that the result is the same in every thread
        order), in one pass: both are one key (owner_key_funcs). A node between two bodies' surfaces then
        belongs to one of them; the other's particles count it across whatever the normals say, which the edges
        of a contact face need: there the nodes outside both bodies have normals out of the free surface, which
        neither body's particles face away from."""
        if ti.static(sides):
            for p in x:
                if side[p] >= 0:
                    sd = sten.at(p)
                    for o in ti.grouped(ti.ndrange(*sten.outer)):
                      for k in ti.static(range(len(sten.inner))):  # noqa: E111 (the solver's split)
                        I, w, gw, r = sten.node(sd, o + sten.inner[k])
                        if node_mark[I] > 0:
                            kp = key(w, side[p])
                            # read first: a key only grows, so a smaller one changes nothing, and the atomic (a
                            # compare-and-swap loop) is what made this pass cost as much as G2P
                            if kp > owner[I]:
                                ti.atomic_max(owner[I], kp)

    @ti.func
    def owned_by_another(p, I):
        res = False
        if ti.static(sides):
            o = side_of(owner[I])
            res = side[p] >= 0 and o > 0 and o != side[p] + 1
        return res

    return claim_nodes, owned_by_another


def node_cache_kernels(ctx) -> NodeCache:
    f, dim, cached = ctx.fields, ctx.fields.dim, ctx.fields.cached
    cache_m, cache_n, cache_fill = ((f.node_cache.m, f.node_cache.vec["n"], f.node_cache_fill)
                                    if cached else (None,) * 3)

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

    return NodeCache(size=node_cache_size, read=node_cache_read, write=node_cache_write)
