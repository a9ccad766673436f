"""With crack.friction, a particle in contact moves in its normal functions Nn in every direction, on two velocity
fields per node: the node's own (particles on its side) and its second field (the particles in contact across it:
`crack_mf`, `crack_pf`, `crack_nf`, `crack_of`), between which the grid solve applies Coulomb contact
(tensor_grid.two_field_contact). These are the node-by-node P2G and G2P of such a particle (transfer.py calls them)."""

from typing import Callable, NamedTuple

import taichi as ti

from .constants import CONTACT
from .nodes import node_owner_funcs


class TwoFields(NamedTuple):
    holds: Callable   # (p, off, I) -> node I holds particle p in its second field (ParticleTransfer.second_field)
    p2g: Callable   # (p, I, mp, wn, gn, r, node momentum, stress, force density, kick, vp, n, across)
    standard_moment: Callable   # NodeFields.scatter: a standard particle's mass moment about the node
    g2p: Callable   # (p, I, wn, gn, v, v_old, n, across) -> (v_pic, FLIP increment, velocity gradient) terms


def two_field_funcs(ctx, own_side) -> TwoFields:
    grid, flip, add = ctx.view.grid, ctx.view.flip, ctx.solver.add
    gm, gv, gv_old = grid.m, grid.vec["v"], grid.vec.get("v_old")
    gpf, gnf, gmf, gof = grid.vec["crack_pf"], grid.vec["crack_nf"], grid.scalar["crack_mf"], grid.vec.get("crack_of")
    gxm, gxf = grid.vec["crack_xm"], grid.vec["crack_xf"]
    node_mark, node_n = grid.scalar["crack_mark"], grid.vec["crack_n"]
    sides = ctx.fields.sides > 0
    pairs, side = ctx.fields.needs.pairs, ctx.fields.side
    gsf = grid.scalar.get("crack_sf")
    state, normal = ctx.fields.state, ctx.fields.normal if ctx.fields.cnormal is None else ctx.fields.cnormal
    _, owned_by_another = node_owner_funcs(ctx)

    @ti.func
    def second_field(p, I, n):
        """Whether node I, across particle p in contact (its mask), takes p in its second field. Between interface
        bodies: a node another body owns (a node of p's own body that its normals put across stays in p's field:
        the top of a thin block facing the base below within the SPH reach). Across a crack: every node across but
        one on the discontinuity itself (both sides leave it), which takes the side its normal points from in its
        own field (n: the particle's contact normal, each side's opposite)."""
        res = False
        if ti.static(sides):
            res = owned_by_another(p, I)
        else:
            res = node_mark[I] < 1.5 or n.dot(node_n[I]) < 0
        return res

    @ti.func
    def p2g(p, I, mp, wn, gn, r, mom_n, stress, force_density, kick, vp, n, across):
        """A particle in contact with friction: all of it in its normal function, to the node's own field or, at a
        node across, to its second field (with the particle's normal, for the contact's direction)."""
        mv = mp * wn * mom_n + kick * (stress @ gn + wn * force_density)
        if across and second_field(p, I, n):
            add(gmf, I, mp * wn)
            add(gpf, I, mv)
            add(gnf, I, mp * wn * n)
            add(gxf, I, -wn * mp * r)   # mass moments about the node (r = x_i - x_p): the gap's surfaces
            if ti.static(pairs):   # the second field's body, for its friction coefficient with the node's owner
                ti.atomic_max(gsf[I], ti.cast(side[p] + 1, float))
            if ti.static(flip):
                add(gof, I, mp * wn * vp)
        else:
            add(gm, I, wn * mp)
            add(gv, I, mv)
            add(gxm, I, -wn * mp * r)
            if ti.static(flip):
                add(gv_old, I, mp * wn * vp)

    @ti.func
    def g2p(p, I, wn, gn, vi, vo, n, across):
        """A particle in contact with friction reads, in its normal function, the node's own field or, at a node
        across, the second field (tensor_grid.two_field_contact has made them contact by Coulomb's law):
        (velocity, FLIP's old velocity)."""
        if across and second_field(p, I, n):
            vi = gpf[I]
            if ti.static(flip):
                vo = gof[I]
        return wn * vi, wn * (vi - vo), vi.outer_product(gn)

    @ti.func
    def holds(p, off, I):
        return state[p] == CONTACT and not own_side(p, off) and second_field(p, I, normal[p])

    @ti.func
    def standard_moment(p, I, w, gw, r, mp, momentum, momentum_old):
        """A particle with standard functions: its mass moment about the node, to the node's own field's
        (NodeFields.scatter)."""
        add(gxm, I, -w * mp * r)

    return TwoFields(holds=holds, p2g=p2g, g2p=g2p, standard_moment=standard_moment)
