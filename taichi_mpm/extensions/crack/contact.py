"""The contact test's sums: how fast the material across a particle's discontinuity closes on it (over its contact
list, or a search of the cell list), and the particle's impedance rho c for the trial normal traction."""

from typing import Callable, NamedTuple

import numpy as np
import taichi as ti


@ti.func
def _first(a, b):
    """ti.min's stand-in where no distance is tracked: keeps a (inlined, no code of its own)."""
    return a


class ContactTest(NamedTuple):
    sort_normals: Callable    # func: the normals in cell order, so the searches stream (classify calls it)
    # (p, n, pool) -> (kernel-weighted closing speed, whether any q is in reach (with crack.contact_gap: that
    # close), the kernel-weighted sums of the normals of the facing particles of heavier bodies and of bodies of p's
    # mass: zero without interface bodies)
    closing_speed: Callable
    impedance: Callable       # (p) -> rho c of p's material


def contact_test_funcs(ctx, cl, sph) -> ContactTest:
    f = ctx.fields
    x, v, normal, ids, ns, mat = ctx.view.x, ctx.view.v, f.normal, f.ids, f.ns, ctx.solver.mat
    radius, inv_r, radius2_cut, contact_thr = ctx.radius, ctx.inv_r, ctx.radius2_cut, ctx.contact_thr
    rows_wide, wide_span, wide_reach2 = ctx.rows_wide, ctx.wide_span, ctx.wide_reach2
    listed, contact = f.listed, ctx.contact
    sides, side = f.sides, f.side
    side_mass = f.side_mass if sides else [0.0]
    contact_count, contact_start = (f.contact_count, f.contact_start) if listed else (None, None)
    imped = [float(np.sqrt(m.density * (m.lam + 2 * m.mu))) for m in ctx.view.materials]  # rho c
    single_mat = len(f.laws) == 1
    cell_of, cell_units, row_cells, cells_slice, listed_at = (
        cl.cell_of, cl.cell_units, cl.row_cells, cl.cells_slice, cl.listed_at)
    sph_kernel = sph.sph_kernel
    # crack.contact_gap (interface bodies): in contact only while the nearest facing particle is this close (its
    # distance, not along p's normal: a corner's diagonal normal sees the particles beside it as close); without
    # it, anywhere within the SPH reach
    gap = ctx.cc.contact_gap if sides else None
    gap_reach2 = 0.0 if gap is None else (f.spacing * (1.0 + float(gap))) ** 2
    gap_check = gap is not None
    nearest = ti.min if gap_check else _first   # without the check no distance is tracked in the search

    @ti.func
    def sort_normals():
        if ti.static(contact):
            for j in ids:
                ns[j] = normal[ids[j]]

    @ti.func
    def mass_of(s):
        """The mass of interface side s's body (0 for a particle of no interface body)."""
        r = 0.0
        for k in ti.static(range(len(side_mass))):
            if s == k:
                r = side_mass[k]
        return r

    @ti.func
    def contact_term(n, vp, q, d2, mass_p):
        """A facing neighbour q at squared distance d2 (< r^2, up to rounding): its kernel weight, that times its
        closing speed (v_q - v_p) . n, and that times its normal as a heavier body's or one of p's mass (interface
        bodies)."""
        wk = 0.0
        dist = ti.sqrt(d2)
        if dist < radius:
            wk, _ = sph_kernel(dist * inv_r)
        heavy, peer = ti.Vector.zero(float, n.n), ti.Vector.zero(float, n.n)
        if ti.static(sides):
            mq = mass_of(side[q])
            if mq > 1.001 * mass_p:
                heavy = wk * normal[q]
            elif mq >= 0.999 * mass_p:
                peer = wk * normal[q]
        return wk, wk * (v[q] - vp).dot(n), heavy, peer

    @ti.func
    def closing_speed(p, n, pool: ti.template()):
        """Kernel-weighted mean of (v_q - v_p) . n_p over neighbours q within r across the discontinuity
        (n_p . n_q < -threshold): negative when the other side approaches p; and whether any q is in reach.
        Sums over p's contact list where it has one (the candidates in the order the search met them when it
        was built), else searches the cell list."""
        xp, vp = x[p], v[p]   # read once: the loops below are the contact test's cost
        sw, sv = 0.0, 0.0
        sn, se = ti.Vector.zero(float, n.n), ti.Vector.zero(float, n.n)
        mass_p = 0.0
        d2_min = ti.cast(1e30, float)   # the nearest facing particle's squared distance (crack.contact_gap)
        if ti.static(sides):
            mass_p = mass_of(side[p])
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
                        wk, wv, wn, we = contact_term(n, vp, q, d2, mass_p)
                        d2_min = nearest(d2_min, d2)
                        sw += wk
                        sv += wv
                        sn += wn
                        se += we
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
                            wk, wv, wn, we = contact_term(n, vp, q, d2, mass_p)
                            d2_min = nearest(d2_min, d2)
                            sw += wk
                            sv += wv
                            sn += wn
                            se += we
        res = 0.0
        if sw > 0:
            res = sv / sw
        touching = sw > 0
        if ti.static(gap_check):
            touching = touching and d2_min < gap_reach2
        return res, touching, sn, se

    @ti.func
    def impedance(p):
        z = ti.cast(imped[0], float)
        if ti.static(not single_mat):
            for k in ti.static(range(1, len(imped))):
                if mat[p] == k:
                    z = imped[k]
        return z

    return ContactTest(sort_normals=sort_normals, closing_speed=closing_speed, impedance=impedance)
