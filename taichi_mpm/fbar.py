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

Only the step's increment is averaged: a body at rest keeps its J field (averaging the total J every step
would smooth it once per step, so the result would depend on the number of steps). Total volume is kept
exactly: sum_p V0_p J_p after = sum_p V0_p det F_p before (partition of unity). In 1D all deformation is
volumetric, there is no locking, and averaging would leave the odd-even velocity mode without stiffness:
`create` returns None there, and the option changes nothing.

Created by the Simulation only when the option is on; fields and kernels exist only then.
Physics code only: no CLI, rendering or file I/O here.
"""

import taichi as ti

from .grid import Grid


def create(sim):
    """The F-bar object for `sim`, or None (option off, or 1D where it is the identity)."""
    if sim.cfg.solver.volumetric != "fbar" or sim.dim == 1:
        return None
    return FBar(sim)


class FBar:
    def __init__(self, sim):
        self.sim = sim
        self.J_start = ti.field(float, sim.n)        # J^n_p = det F_p at the start of the step
        self.J_start.fill(1.0)                       # the scene starts undeformed (F = I)
        # node volumes at the end and at the start of the step, sum w V0 det F and sum w V0 J^n: two scalar grids
        # (their `m`), so the scatter costs two atomic adds per node
        self.grids = [Grid(sim.dim, sim.grid.shape, sim.cfg.domain.sparse, []) for _ in range(2)]

    def bytes_per_particle(self) -> int:
        return 8 if self.sim.cfg.precision == "f64" else 4

    def build(self, ctx):
        """Compile the kernels with the solver's stencil (stencils.KernelContext)."""
        sim = self.sim
        dim = sim.dim
        x, F, vol0, J_start = sim.x, sim.F, sim.vol0, self.J_start
        vol_new, vol_old = self.grids[0].m, self.grids[1].m
        sten = ctx.stencil
        outer, inner = sten.outer, sten.inner     # the solver's stencil loop (see Simulation.unroll)

        @ti.kernel
        def scatter():
            for p in x:
                st = sten.at(p)
                Vn = vol0[p] * J_start[p]
                new = vol0[p] * F[p].determinant()
                for o in ti.grouped(ti.ndrange(*outer)):
                  for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil)
                    I, w, gw, r = sten.node(st, o + inner[k])
                    vol_new[I] += w * new
                    vol_old[I] += w * Vn

        @ti.kernel
        def gather():
            for p in x:
                st = sten.at(p)
                dJbar = 0.0
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
