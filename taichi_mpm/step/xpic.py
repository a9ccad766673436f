"""XPIC(m)'s grid passes (schemes/xpic.py; Hammerquist & Nairn 2017): after the grid update, with v the lumped
grid velocity of the particles before forces (FLIP's v_old), the estimate v* = sum_{k=1..m} dv_k of the part of
the particle velocities the grid represents, by the increments dv_1 = v, dv_k = dv_(k-1) - S+S dv_(k-1)
(S: grid to particles, S+: back, mass-weighted). Each order is one particle pass (xpic_pass: interpolate dv at
the particle, scatter m_p w times it) and one grid pass (xpic_update). G2P then sets v_p = S (v_L - v + v*).

Physics code only: no CLI, rendering or file I/O here.
"""

import taichi as ti

from ..schemes.xpic import XPIC
from .transfers import colour_loop

XPIC_VECTORS = XPIC.grid_vectors   # v*, the current increment dv_k, S+ S dv_k's sums (declared: layout.main_grid)


def make_xpic(ctx, mf) -> dict:
    """Kernels xpic_start(), xpic_pass(colour), xpic_update()."""
    dim, vol0 = ctx.dim, ctx.vol0
    sten, add = ctx.stencil, ctx.add
    outer, inner = sten.outer, sten.inner
    gm, gv_old = ctx.gm, ctx.gv_old
    xs, xd, xm = (ctx.grid.vec[name] for name in XPIC_VECTORS)
    density = mf.density

    @ti.kernel
    def xpic_start():
        """v* = dv_1 = v, the lumped velocity before forces."""
        for I in ti.grouped(gm):
            if gm[I] > 0:
                xs[I] = gv_old[I]
                xd[I] = gv_old[I]
                xm[I] = ti.Vector.zero(float, dim)

    @ti.func
    def particle(p, unused):
        """S+ S dv's numerator at the particle's nodes: m_p w_i (sum_j w_j dv_j)."""
        st = sten.at(p)
        mp = density(p) * vol0[p]
        s = ti.Vector.zero(float, dim)
        for o in ti.grouped(ti.ndrange(*outer)):
          for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil, see `unroll`)
            I, w, gw, r = sten.node(st, o + inner[k])
            s += w * xd[I]
        for o in ti.grouped(ti.ndrange(*outer)):
          for k in ti.static(range(len(inner))):  # noqa: E111
            I, w, gw, r = sten.node(st, o + inner[k])
            add(xm, I, w * mp * s)

    loop = colour_loop(ctx, particle)

    @ti.kernel
    def xpic_pass(colour: int):
        loop(colour, 0.0)

    @ti.kernel
    def xpic_update():
        """dv_k = dv_(k-1) - S+ S dv_(k-1); v* += dv_k."""
        for I in ti.grouped(gm):
            m = gm[I]
            if m > 0:
                d = xd[I] - xm[I] / m
                xd[I] = d
                xs[I] += d
                xm[I] = ti.Vector.zero(float, dim)

    return dict(xpic_start=xpic_start, xpic_pass=xpic_pass, xpic_update=xpic_update)
