"""The particles' normals: the SPH gradient of D where it varies (kept between refreshes, recomputed where the
neighbourhood drifted), and the band middles' normals taken from their neighbours; a near particle marks its
stencil's nodes."""

from typing import Callable, NamedTuple

import taichi as ti

from ...materials import sym_eig
from .constants import DRIFT_LIMIT, DRIFTED, KEEP, MODIFIED, STANDARD


class ParticleNormals(NamedTuple):
    mark_stencil: Callable       # (p): mark the grid nodes of p's stencil
    particle_normals: Callable   # kernel (level): the gradient normals, kept or recomputed
    band_normals: Callable       # func: the band middles' normals (classify calls it)


def particle_normal_funcs(ctx, cl, sph) -> ParticleNormals:
    f, dim, sten = ctx.fields, ctx.fields.dim, ctx.solver.stencil
    x, D, normal, state, pcell, cell_varies = ctx.view.x, f.D, f.normal, f.state, f.pcell, f.cell_varies
    node_mark = ctx.view.grid.scalar["crack_mark"]   # the step's node marks
    cached, radius, dthr, gthr = f.cached, ctx.radius, ctx.dthr, ctx.gthr
    n_cache, s_cache, x_ref, drift, cell_drift, recomputed = (
        (f.n_cache, f.s_cache, f.x_ref, f.drift, f.cell_drift, f.recomputed) if cached else (None,) * 6)
    drift_limit = DRIFT_LIMIT * f.skin
    damage_field = sph.damage_field
    side, by_side = f.side, f.side is not None

    @ti.func
    def own_side(p):
        """The interface side whose particles alone give p's normal (-1: all particles)."""
        s = -1
        if ti.static(by_side):
            s = side[p]
        return s

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
                    _, g = damage_field(x[p], own_side(p))
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

    return ParticleNormals(mark_stencil=mark_stencil, particle_normals=particle_normals,
                           band_normals=band_normals_func(ctx, cl, sph, mark_stencil))


def band_normals_func(ctx, cl, sph, mark_stencil):
    """The func band_normals() (classify calls it)."""
    f, dim = ctx.fields, ctx.fields.dim
    x, D, normal, state, ids, xs = ctx.view.x, f.D, f.normal, f.state, f.ids, f.xs
    radius, inv_r, radius2_cut, rows, dthr = ctx.radius, ctx.inv_r, ctx.radius2_cut, ctx.rows, ctx.dthr
    cell_of, cell_units, row, listed_at = cl.cell_of, cl.cell_units, cl.row, cl.listed_at
    sph_kernel = sph.sph_kernel

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

    return band_normals
