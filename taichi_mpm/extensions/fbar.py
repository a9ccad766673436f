"""F-bar against volumetric locking (`solver.volumetric: fbar`): an assumed deformation gradient whose
volume change is averaged over the grid.

With many particles per cell every particle's J is a separate incompressibility constraint, more than the
grid's velocity unknowns can satisfy: a nearly incompressible body locks (too stiff) and its pressure
oscillates from particle row to row. F-bar keeps each particle's isochoric part and replaces the volume change
of the step by its grid average, so there is about one volumetric constraint per node instead of one per
particle. The incremental form (Coombs et al. 2018, CMAME 333; the average taken through the ordinary
particle-grid transfer as in Zhao et al. 2023, IJNME 124), after G2P has updated F:

    dJ_p    = det F_p / J^n_p                      volume change of this step (J^n_p: det F at the step start)
    dJbar_i = sum_p w_ip V^n_p dJ_p / sum_p w_ip V^n_p,   V^n_p = V0_p J^n_p   (weights at the new positions)
    dJbar_p = sum_i w_ip dJbar_i
    F_p    <- (J^n_p dJbar_p / det F_p)^(1/d) F_p   (fluids: J_p <- J^n_p dJbar_p, F stays J^(1/d) I)

The weights w_ip of the average are one degree below the velocity space where that exists: quadratic and cubic
B-splines average on the linear grid (multilinear hats on the cell corners), as the B-bar / F-bar projections
of Moutsanidis et al. (2020) project the volumetric strain onto degree p - 1. Averaged with the
velocity basis itself (equal order, not inf-sup stable), a block at rest at nu = 0.4999 kept a pressure that
zig-zagged by 9 % of rho g H from row to row; on the linear grid 1.4 % (docs/accuracy.md). Linear, GIMP, CPDI and
DDMP average with their own stencil (their velocity space is already of degree 1).

Only the step's increment is averaged: a body at rest keeps its J field (averaging the total J every step
would smooth it once per step, so the result would depend on the number of steps). Total volume is kept
exactly: sum_p V0_p J_p after = sum_p V0_p det F_p before (partition of unity). In 1D all deformation is
volumetric, there is no locking, and averaging would leave the odd-even velocity mode without stiffness:
`create` returns None there, and the option changes nothing.

Created by the Simulation only when the option is on; fields and kernels exist only then.
Physics code only: no CLI, rendering or file I/O here.
"""

import taichi as ti

from .. import layout
from ..grid import Grid


def create(sim):
    """The F-bar object for `sim`, or None (option off, or 1D where it is the identity)."""
    if sim.cfg.solver.volumetric != "fbar" or sim.dim == 1:
        return None
    return FBar(sim)


class FBar:
    def __init__(self, sim):
        self.sim = sim
        self.J_start = layout.FBAR_J.allocate(sim.n)   # J^n_p = det F_p at the start of the step
        self.J_start.fill(1.0)                       # the scene starts undeformed (F = I)
        # node volumes at the end and at the start of the step, sum w V0 det F and sum w V0 J^n: two scalar grids
        # (their `m`), so the scatter costs two atomic adds per node
        # quadratic and cubic B-splines: the average lives on the linear grid (cell corners), one degree below the
        # velocity space (see `build`); the other bases average with their own stencil
        decl = layout.fbar_grid(sim.needs)   # two of these: layout.grids
        self.linear = decl.extent == "linear"
        shape = [n + 1 for n in sim.n_cells] if self.linear else sim.grid.shape
        self.grids = [Grid(sim.dim, shape, sim.grid.sparse, list(decl.vectors)) for _ in range(2)]

    def bytes_per_particle(self) -> int:
        return layout.FBAR_J.nbytes(self.sim.cfg.precision)

    def build(self, ctx):
        """Compile the kernels with the solver's stencil (stencil_parts.KernelContext)."""
        sim = self.sim
        dim = sim.dim
        x, F, vol0, J_start = sim.x, sim.F, sim.vol0, self.J_start
        vol_new, vol_old = self.grids[0].m, self.grids[1].m
        sten = ctx.stencil
        outer, inner = sten.outer, sten.inner     # the solver's stencil loop (see Simulation.unroll)
        linear = self.linear
        lower, inv_dx = ctx.lower, 1.0 / ctx.dx
        last_cell = ti.Vector([n - 1 for n in sim.n_cells])
        corners = [tuple((k >> a) & 1 for a in range(dim)) for k in range(2 ** dim)]
        near = ctx.particle_transfer   # the crack finder's: its particles near a discontinuity keep their own dJ
        some_kept = near is not None

        @ti.func
        def averaged(p):
            """Whether the particle takes part in the average. One the crack finder takes (near a crack or a body
            interface, its stencil reaching across) would mix the two sides' volume changes: it keeps its own, and
            the others' averages hold only particles of their own side (those are 1.5 cells or more from the
            discontinuity, their average's reach one cell)."""
            res = True
            if ti.static(some_kept):
                res = not near.takes(p)
            return res

        @ti.func
        def tent(p, c: ti.template()):
            """Node and weight of corner c of the particle's cell on the linear grid (multilinear hat)."""
            u = (x[p] - lower) * inv_dx
            base = ti.min(ti.max(ti.floor(u, int), 0), last_cell)  # a particle on the upper wall: the last cell
            fx = u - base
            w = 1.0
            for a in ti.static(range(dim)):
                if ti.static(c[a] == 1):
                    w *= fx[a]
                else:
                    w *= 1.0 - fx[a]
            return base + ti.Vector(c), w

        @ti.kernel
        def scatter():
            for p in x:
                if not averaged(p):
                    continue
                Vn = vol0[p] * J_start[p]
                new = vol0[p] * F[p].determinant()
                if ti.static(linear):
                    for c in ti.static(corners):
                        I, w = tent(p, c)
                        vol_new[I] += w * new
                        vol_old[I] += w * Vn
                    continue
                st = sten.at(p)
                for o in ti.grouped(ti.ndrange(*outer)):
                  for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil)
                    I, w, gw, r = sten.node(st, o + inner[k])
                    vol_new[I] += w * new
                    vol_old[I] += w * Vn

        @ti.kernel
        def gather():
            for p in x:
                if not averaged(p):
                    J_start[p] = F[p].determinant()
                    continue
                dJbar = 0.0
                if ti.static(linear):
                    for c in ti.static(corners):
                        I, w = tent(p, c)
                        old = vol_old[I]
                        if old > 0:
                            dJbar += w * vol_new[I] / old
                else:
                    st = sten.at(p)
                    for o in ti.grouped(ti.ndrange(*outer)):
                      for k in ti.static(range(len(inner))):  # noqa: E111
                        I, w, gw, r = sten.node(st, o + inner[k])
                        old = vol_old[I]
                        if old > 0:                      # w > 0 implies old > 0; w = 0 at a support's edge
                            dJbar += w * vol_new[I] / old
                Fp = F[p]
                Fp *= ti.pow(J_start[p] * dJbar / Fp.determinant(), 1.0 / dim)
                F[p] = Fp
                J_start[p] = Fp.determinant()

        @ti.kernel
        def sync():
            for p in x:
                J_start[p] = F[p].determinant()

        self._k = dict(scatter=scatter, gather=gather, sync=sync)

    def apply(self):
        """After G2P: replace each particle's volume change of this step by its grid average."""
        for g in self.grids:
            g.clear()
        self._k["scatter"]()
        self._k["gather"]()

    def sync(self):
        """F was set from outside (set_particles, set_state): the next step starts from its J."""
        self._k["sync"]()
