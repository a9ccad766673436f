"""SPH on the cell list: the cubic spline kernel and the Shepard-normalised value and gradient of D."""

from typing import Callable, NamedTuple

import taichi as ti


class Sph(NamedTuple):
    sph_kernel: Callable     # (s) -> (W, dW/ds), s = distance / support
    damage_field: Callable   # (x, side) -> (D(x), grad D(x)) over the particles of that interface side (-1: all)


def sph_funcs(ctx, cl) -> Sph:
    dim, xs, vs = ctx.fields.dim, ctx.fields.xs, ctx.fields.vs
    rows, radius2, inv_r = ctx.rows, ctx.radius2, ctx.inv_r
    cell_of, cell_units, row = cl.cell_of, cl.cell_units, cl.row
    sides, ss = ctx.fields.sides, ctx.fields.ss

    @ti.func
    def damage_field(xq, own):
        """Shepard-normalised SPH value and gradient of D at xq (cubic spline kernel of support r). With two or
        more interface bodies and own >= 0, over the particles of interface side `own` alone: an interface body's
        normal is then its own surface's, which the D of a body lying on it does not tilt (docs/crack_finder.md,
        "The contact normal between two bodies")."""
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
                keep = d2 < radius2   # most candidates fall outside: no sqrt for them
                if ti.static(sides):
                    if own >= 0 and ss[j] != own:
                        keep = False
                if keep:
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

    return Sph(sph_kernel=sph_kernel, damage_field=damage_field)
