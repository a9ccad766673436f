"""P2G and G2P of a particle near a discontinuity through the tensor weights W_ip = Nt I + (Nn - Nt) n n^T: the
@ti.funcs the solver's transfer kernels call for such particles (its ParticleTransfer: p2g, p2g_momentum, g2p).
With crack.friction, a particle in contact moves with its normal functions Nn in every direction, on two velocity
fields: the node's own (the nodes on its side) and the node's second field (the nodes across it: `crack_mf`,
`crack_pf`, ...), between which the grid solve applies Coulomb contact (tensor_grid.two_field_contact)."""

from typing import Callable, NamedTuple, Optional

import taichi as ti

from .two_fields import two_field_funcs


class Transfers(NamedTuple):
    p2g: Callable            # (p, st, mp, stress, vp, Ap, force_density, kick)
    p2g_momentum: Callable   # (p, st, mp, vp, Ap): MUSL's remap
    g2p: Callable            # (p, st, deform) -> (v_pic, FLIP increment, APIC B, velocity gradient)
    second_field: Optional[Callable]   # (p, off, I) -> node I holds p in its second field (friction), or None
    standard_moment: Optional[Callable]   # with friction, NodeFields.scatter: a standard particle's mass moment


def transfer_funcs(ctx, sf) -> Transfers:
    f, dim, sten, add, vgrad = ctx.fields, ctx.fields.dim, ctx.solver.stencil, ctx.solver.add, ctx.solver.vgrad
    normal, cent = f.normal if f.cnormal is None else f.cnormal, f.cent   # the normal of a particle in contact
    grid, flip, apic = ctx.view.grid, ctx.view.flip, ctx.view.apic
    gm, gv = grid.m, grid.vec["v"]
    gv_old, gv2 = grid.vec.get("v_old"), grid.vec.get("v2")
    Arows = [grid.vec[f"A{a}"] for a in range(dim)]
    family, tangential, normal_family = sf.family, sf.tangential, sf.normal_family
    friction = f.needs.friction
    two = two_field_funcs(ctx, sf.own_side) if friction else None
    gxm = grid.vec.get("crack_xm")

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
    def p2g_node(I, fam, w, gw, wt, gt, r, mp, stress, vt, vn, vp, Ap, force_density, kick, n):
        """One node's P2G through W_ip (the normal family's terms for a particle in contact)."""
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
        if ti.static(friction):   # the own field's mass moment (the two fields' gap, tensor_grid)
            add(gxm, I, -wt * mp * r)

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
            if ti.static(friction):   # a particle in contact moves on the nodes' two fields
                if fam[1]:
                    wn, gn = normal_family(fam, w, gw)
                    two.p2g(p, I, mp, wn, gn, r, node_momentum(vn, Ap, r), stress, force_density, kick, vp, n,
                            wt == 0)
                else:
                    p2g_node(I, fam, w, gw, wt, gt, r, mp, stress, vt, vn, vp, Ap, force_density, kick, n)
            else:
                p2g_node(I, fam, w, gw, wt, gt, r, mp, stress, vt, vn, vp, Ap, force_density, kick, n)

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
    def g2p_node(I, fam, w, gw, wt, gt, vi, vo, n, deform: ti.template(), v_pic, dv, G):
        """One node's G2P terms through W_ip added to the sums: velocity, FLIP increment, velocity gradient
        (Pt vg) gt^T + (Pn vg) gn^T."""
        vg = vi
        if ti.static(deform):  # MUSL's deform pass reads the remapped velocities
            vg = vgrad[I]
        v_pic += wt * vi
        dv += wt * (vi - vo)
        G += vg.outer_product(gt)
        if fam[1]:
            wn, gn = normal_family(fam, w, gw)
            v_pic += (wn - wt) * n.dot(vi) * n
            dv += (wn - wt) * n.dot(vi - vo) * n
            G += (n.dot(vg) * n).outer_product(gn - gt)
        return v_pic, dv, G

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
            vo = vi
            if ti.static(flip):
                vo = gv_old[I]
            if ti.static(friction):   # a particle in contact moves on the nodes' two fields
                if fam[1]:
                    wn, gn = normal_family(fam, w, gw)
                    v_i, dv_i, G_i = two.g2p(p, I, wn, gn, vi, vo, n, wt == 0)
                    v_pic += v_i
                    dv += dv_i
                    G += G_i
                else:
                    v_pic, dv, G = g2p_node(I, fam, w, gw, wt, gt, vi, vo, n, deform, v_pic, dv, G)
            else:
                v_pic, dv, G = g2p_node(I, fam, w, gw, wt, gt, vi, vo, n, deform, v_pic, dv, G)
        return v_pic, dv, G @ sten.inertia(st), G

    return Transfers(p2g=p2g, p2g_momentum=p2g_momentum, g2p=g2p, second_field=two.holds if friction else None,
                     standard_moment=two.standard_moment if friction else None)
