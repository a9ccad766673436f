"""Classify: after the particle normals, per near particle and stencil node whether the node lies across the
discontinuity (the mask), the sums of the kept weights and gradients of both families, and the contact test."""

import taichi as ti

from .constants import CONTACT, MODIFIED, S_FLOOR, STANDARD
from .nodes import node_owner_funcs


def classify_kernel(ctx, normals, contact_test, node_normals, effective_stress):
    """classify(epoch, pool): band middles, the normals in cell order (contact searches), node normals, masks and
    contact (three kernels)."""
    f, dim, sten = ctx.fields, ctx.fields.dim, ctx.solver.stencil
    x, normal, state, mask, sums, gsum, cent, contacts = (
        ctx.view.x, f.normal, f.state, f.mask, f.sums, f.gsum, f.cent, f.contacts)
    node_mark, node_n = ctx.view.grid.scalar["crack_mark"], ctx.view.grid.vec["crack_n"]
    mask_t, apic, thr, contact = f.mask_t, f.apic, ctx.thr, ctx.contact
    cnormal = f.cnormal
    own_normals = cnormal is None
    # tensor stencils: the origin fixes the stencil's nodes; a node's owner (below) follows the particles each step
    reuse_masks = f.cached and sten.origin is not None and not f.sides
    claim_nodes, owned_by_another = node_owner_funcs(ctx)
    s_cache, mask_at, mask_epoch = (f.s_cache, f.mask_at, f.mask_epoch) if f.cached else (None,) * 3
    grid_shape = list(ctx.view.grid.shape)
    band_normals, sort_normals = normals.band_normals, contact_test.sort_normals
    closing_speed, impedance = contact_test.closing_speed, contact_test.impedance
    two_fields = f.needs.friction

    @ti.func
    def closes(p, n, vc):
        """Whether particle p, facing material across within reach, is in contact: its trial normal traction is
        compressive; with friction's two fields always (their nodes' contact acts only while the fields approach
        and their surfaces touch, tensor_grid.two_field_contact: with the traction test the particles near a
        resting block's face went in and out of contact as its stress rang, and the block crept)."""
        res = True
        if ti.static(not two_fields):
            res = n.dot(effective_stress(p) @ n) + impedance(p) * vc < 0.0
        return res

    @ti.func
    def origin_key(p):
        """1 + the flat storage index of p's stencil origin (i64: large sparse 3D grids pass 2^31 nodes)."""
        b = sten.origin(p)
        k = ti.cast(0, ti.i64)
        for a in ti.static(range(dim)):
            k = k * grid_shape[a] + ti.cast(b[a], ti.i64)
        return k + 1

    @ti.func
    def contact_normal(n, heavy, peer):
        """The normal of a particle in contact (interface bodies): a heavier body's it faces, else the mean of its own
        and that of a body of its mass (symmetric contact stays symmetric), else its own."""
        res = n
        if heavy.norm() > 0:
            res = -heavy.normalized()
        elif peer.norm() > 0:
            mean = n - peer.normalized()
            if mean.norm() > 1e-6:
                res = mean.normalized()
        return res

    @ti.func
    def particle_masks(epoch, pool: ti.template()):
        contacts[None] = 0
        for p in x:
            key = ti.cast(0, ti.i64)
            known = False   # p's mask is the one found before (no node normals to read)
            if ti.static(reuse_masks):
                # within one period of kept normals a node's side depends only on the node and p's normal
                # (band particles excepted: theirs follow their neighbours each step)
                if state[p] != STANDARD and s_cache[p] != STANDARD:
                    key = origin_key(p)
                    known = mask_epoch[p] == epoch and mask_at[p] == key
            if known and mask[p] == 0:   # still nothing across
                state[p] = STANDARD
            elif state[p] != STANDARD:
                n = normal[p]
                sd = sten.at(p)
                m = ti.cast(0, mask_t)
                m_known = mask[p]
                St, Sx = 0.0, 0.0   # weights of the nodes on p's side / across
                Gt = ti.Vector.zero(float, dim)
                Gx = ti.Vector.zero(float, dim)
                ct = ti.Vector.zero(float, dim)
                cx = ti.Vector.zero(float, dim)
                for o in ti.grouped(ti.ndrange(*sten.outer)):
                  for k in ti.static(range(len(sten.inner))):  # noqa: E111 (the solver's split)
                    off = o + sten.inner[k]
                    I, w, gw, r = sten.node(sd, off)
                    bit = ti.cast(1, mask_t) << ti.cast(sten.index(off), mask_t)
                    across = False
                    if known:
                        across = (m_known & bit) != 0
                    else:
                        across = node_mark[I] > 1.5 or n.dot(node_n[I]) < -thr or owned_by_another(p, I)
                    if across:
                        m |= bit
                        Sx += w
                        Gx += gw
                        cx += w * r
                    else:
                        St += w
                        Gt += gw
                        ct += w * r
                st = STANDARD       # nothing across, or it would lose (almost) every node
                if m != 0 and St >= S_FLOOR:
                    st = MODIFIED
                    if ti.static(contact):  # material across within reach, and trial normal traction < 0
                        vc, touching, heavy, peer = closing_speed(p, n, pool)
                        if touching:   # nested: Taichi's `and` evaluates both sides; the stress costs
                            if closes(p, n, vc):
                                st = CONTACT
                                contacts[None] += 1
                                if ti.static(not own_normals):
                                    cnormal[p] = contact_normal(n, heavy, peer)
                Sn, Gn, cn = St, Gt, ct
                if st == CONTACT:   # the normal family keeps the nodes across
                    Sn, Gn, cn = St + Sx, Gt + Gx, ct + cx
                state[p] = st
                mask[p] = m
                if ti.static(reuse_masks):
                    if key != 0:
                        mask_at[p], mask_epoch[p] = key, epoch
                sums[p] = ti.Vector([St, Sn])
                for a in ti.static(range(dim)):
                    gsum[p][0, a] = Gt[a]
                    gsum[p][1, a] = Gn[a]
                    if ti.static(apic):
                        cent[p][0, a] = ct[a] / St
                        cent[p][1, a] = cn[a] / Sn

    return _as_kernels(band_normals, sort_normals, node_normals, claim_nodes, particle_masks)


def _as_kernels(band_normals, sort_normals, node_normals, claim_nodes, particle_masks):
    """classify(epoch, pool) from the five loops, in three kernels: Taichi's IR passes (store-to-load forwarding)
    grow faster than linearly with a kernel's size, so the five as one kernel compiled 1.35x longer (3D crack
    scene, empty cache: 2.9 against 2.2 s) for a launch or two saved per step (~0.05 ms)."""
    @ti.kernel
    def middles_and_order():
        band_normals()
        sort_normals()

    @ti.kernel
    def node_sides():
        node_normals()
        claim_nodes()

    @ti.kernel
    def masks(epoch: ti.i32, pool: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        particle_masks(epoch, pool)

    def classify(epoch, pool):
        """Steps 4-6 after the particle normals, in turn: band middles, the normals in cell order (contact
        searches), node normals and owners, masks and contact."""
        middles_and_order()
        node_sides()
        masks(epoch, pool)

    return classify
