"""ddmp's pre-pass as a step extension: the nodal volumes sum w V_p before P2G, which the smoothed gradient's blend
reads (stencils._dual_domain_fill), and the small-node fold (solver.ddmp.fold_below).

The fold: linear weights give a node whose dual domain the material barely reaches (a free surface, a particle
entering a cell, a body arriving at a wall) a mass that vanishes with the material's share, N_i(x_p) -> 0, while the
force it takes does not (the linear gradient keeps 1/dx, the smoothed one reaches the next node), so its
acceleration f_i / m_i and the strain rate it feeds back have no bound and no time step is stable (measured: linear
and ddmp under impact; docs/bases.md, "DDMP's small nodes"). Each step, a node whose dual domain is filled below
`fold_below` (fill = V_j / V_j^dual, from the pre-pass) and that has a neighbour filled at least that much (the
fullest of the 3^d - 1 around it, face neighbours first) shares the part s = 1 - fill / fold_below of its force
impulse with it: the two take the acceleration (s f_I + f_J) / (s m_I + m_J), each keeping its own momentum, and
the node keeps the rest of its force on its own mass, which that bounds as for a node filled to the threshold. It
shares only along the axes its walls leave free (decided from its own velocity, as the walls would without the
fold): along the others the wall takes its force. Momentum is kept to round-off; a rigid motion is untouched (no
force, nothing shared). Physics code only: no CLI, rendering or file I/O here.
"""
import itertools

import taichi as ti

from ..bases import registry as bases
from ..step.moments import Extension, GridSolve


class DualDomainFill(Extension):
    name = "ddmp"

    @classmethod
    def adds_in_thread_order(cls, cfg) -> bool:
        return bases.get(cfg.solver.basis).prepass_grid   # the nodal volumes' atomic sums

    @classmethod
    def create(cls, setup):
        basis = setup.basis
        return cls() if basis.kind == "tensor" and basis.smooth_1d is not None else None

    def build(self, ctx):
        self.prepare, self.targets = ctx.stencil.prepare, None
        below = ctx.feat.small_node_fold
        if below > 0:
            self.targets, fold = make_small_node_fold(ctx.dim, ctx.stencil.dual, ctx.gv_old, below, ctx.wall)
            ctx.grid_solve.append(GridSolve(images=(fold, None)))   # every node then solves itself: no mirror

    def before_p2g(self):
        self.prepare()
        if self.targets is not None:
            self.targets()


CODES = 32   # a node's fold scalar: its neighbour's number + 1 (< CODES), plus CODES x the bits of its free axes


def make_small_node_fold(dim: int, dual, old, below: float, wall=None):
    """(targets, fold) over the dual domains' grid (stencils.DualDomains): targets() marks each small node with its
    neighbour in the dual grid's `fold` scalar (0: none) from this step's volumes; fold is GridSolve.images' (its
    fold; grid_update.py calls it on the main grid). old: the grid's momentum before forces
    (`v_old`, which P2G fills for the fold); wall: the walls' condition (I, v) -> v (ctx.wall), or None."""
    vol, target, geometry = dual.grid.m, dual.grid.scalar["fold"], dual.geometry
    shared_force, shared_mass = dual.grid.vec["fold_force"], dual.grid.vec["fold_mass"]
    # face neighbours first, then edges, corners: a tie goes to the nearest
    around = sorted(([*o] for o in itertools.product((-1, 0, 1), repeat=dim) if any(o)), key=lambda o: sum(map(abs, o)))
    walled = wall is not None

    @ti.kernel
    def targets():
        for I in ti.grouped(vol):
            geo, real = geometry(I)
            if real and 0 < vol[I] < below * geo:
                best, pick = 0.0, 0
                for k in ti.static(range(len(around))):
                    J = I + ti.Vector(around[k])
                    geo_j, real_j = geometry(J)
                    v = vol[J]
                    if real_j and v >= below * geo_j and v > best:
                        best, pick = v, k + 1
                target[I] = pick

    @ti.func
    def neighbour(I, code):
        J = I
        for k in ti.static(range(len(around))):
            if code == k + 1:
                J = I + ti.Vector(around[k])
        return J

    @ti.func
    def decoded(I):
        """(the neighbour's number + 1, 0: not folded; the axes the node's walls leave free, 1 or 0 per axis)."""
        t = ti.cast(target[I], int)
        free = ti.Vector.zero(float, dim)
        for a in ti.static(range(dim)):
            free[a] = float((t // CODES >> a) & 1)
        return t % CODES, free

    @ti.func
    def strength(I):
        """The part of a small node's force it shares: 1 - fill / fold_below, all of it as its dual domain empties and
        none at the threshold (so a node crossing it changes nothing at once); the rest it keeps, which its mass
        takes at no more than the acceleration of a node filled to the threshold."""
        geo, _ = geometry(I)
        return 1.0 - vol[I] / (below * geo)

    @ti.func
    def acceleration(gm: ti.template(), g: ti.template(), J):
        """The acceleration impulse node J and its small neighbours share, per axis: their force impulses over their
        masses (a small node's only along the axes its walls leave free)."""
        return (g[J] - old[J] + shared_force[J]) / (gm[J] + shared_mass[J])

    @ti.func
    def fold(gm: ti.template(), decide: ti.template(), g: ti.template(), with_mass: ti.template(), gkick,
             measure: ti.template()):
        """In the step's update (the only one with forces): a small node shares its force impulse with its
        neighbour J along the axes its walls leave free (decided from its own velocity, as the walls would have
        without the fold: along the others the wall takes its force), and both take the pair's acceleration
        there, each keeping its own momentum. Three loops: the shares into J's sums; each small node's new sum
        from J's acceleration (J's sum still unchanged); J's."""
        if ti.static(with_mass and measure):
            for I in ti.grouped(target):
                code, _ = decoded(I)
                if code > 0:
                    J = neighbour(I, code)
                    m = gm[I]
                    own = g[I] / m
                    fixed = own
                    if ti.static(walled):
                        fixed = wall(I, own)
                    bits = 0
                    free = ti.Vector.zero(float, dim)
                    for a in ti.static(range(dim)):
                        if fixed[a] == own[a]:
                            bits += 1 << a
                            free[a] = 1.0
                    target[I] = code + CODES * bits
                    s = strength(I)
                    shared_force[J] += s * free * (g[I] - old[I])
                    shared_mass[J] += s * free * m
            for I in ti.grouped(target):
                code, free = decoded(I)
                if code > 0:
                    J = neighbour(I, code)
                    g[I] += strength(I) * free * (gm[I] * acceleration(gm, g, J) - (g[I] - old[I]))
            for J in ti.grouped(shared_mass):
                if shared_mass[J].max() > 0:
                    g[J] = old[J] + gm[J] * acceleration(gm, g, J)

    return targets, fold
