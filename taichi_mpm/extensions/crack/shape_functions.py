"""The modified shape functions of a particle near a discontinuity, node by node: the tangential family drops the
nodes across, the normal family (a particle in contact) keeps them; both rescaled to a partition of unity by the
sums classify stored."""

from typing import Callable, NamedTuple

import taichi as ti

from .constants import CONTACT, STANDARD


class ShapeFunctions(NamedTuple):
    modified: Callable        # (p) -> p uses modified functions
    family: Callable          # (p) -> p's mask, contact flag, reciprocal sums and gradient sums
    tangential: Callable      # (fam, off, w, gw) -> (Nt, grad Nt) of one node
    normal_family: Callable   # (fam, w, gw) -> (Nn, grad Nn) of one node
    own_side: Callable        # (p, off) -> node off of p's stencil is not across p's discontinuity


def shape_function_funcs(ctx) -> ShapeFunctions:
    f, dim, sten = ctx.fields, ctx.fields.dim, ctx.solver.stencil
    state, mask, sums, gsum, mask_t = f.state, f.mask, f.sums, f.gsum, f.mask_t

    @ti.func
    def across(m, off):
        """Whether stencil node `off` lies across the discontinuity by mask m (bit k: stencil node k)."""
        return (m >> ti.cast(sten.index(off), mask_t)) & ti.cast(1, mask_t) != 0

    @ti.func
    def modified(p):
        return state[p] != STANDARD

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
        wt, gt = w, gw
        if across(m, off):
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
    def own_side(p, off):
        own = True
        if state[p] != STANDARD:
            own = not across(mask[p], off)
        return own

    return ShapeFunctions(modified=modified, family=family, tangential=tangential, normal_family=normal_family,
                          own_side=own_side)
