"""Inspection for tests: whether the modified functions of each particle still form a partition of unity."""

import taichi as ti

from .constants import STANDARD


def partition_check_kernel(ctx, sf):
    """The kernel partition_check(out): per particle, state, sum Nt, sum Nn, |sum grad Nt|_inf, |sum grad Nn|_inf,
    |sum W_ip - I|_inf and whether any node lies across."""
    f, dim, sten = ctx.fields, ctx.fields.dim, ctx.solver.stencil
    x, state, normal, mask, span = ctx.view.x, f.state, f.normal, f.mask, sten.span
    family, tangential, normal_family = sf.family, sf.tangential, sf.normal_family

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

    return partition_check
