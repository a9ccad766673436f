"""The local stress difference (`solver.stress_difference`), a step extension (step.moments): the internal force at
node i from each particle's stress minus the average stress at the node,

    f_i = - sum_p V_p (sigma_p - sigma_i) grad S_ip - sigma_i G_i,   sigma_i = sum_p V_p sigma_p S_ip / sum_p V_p S_ip,

after Perez, Barclay & Zhang, "Nodal force error and its reduction for material point methods", J. Comput. Phys.
(2023), 112681 (their local stress difference, LSD, with the volume-weighted nodal stress). G_i = int grad S_i dV is
the exact integral the particles' sum g_i = sum_p V_p grad S_ip stands in for: 0 for a node whose support lies
inside the material, the box's walls' term S_i(upper) - S_i(lower) per axis where the support meets them. The
particles integrate grad S_i with an error that does not shrink with dx once they are unevenly spaced (the stall
of every point-integrated basis in the 1D manufactured solution, docs/bases.md); multiplied by sigma_p - sigma_i,
O(dx), instead of sigma_p, it does (docs/accuracy.md, "The local stress difference").

Written as a correction of the standard force: P2G sums, per node, sum V sigma S (by rows), g_i and the node's
volume V_i = sum V_p S_ip (step.moments.ForceSums); the grid solve adds c_i sigma_i (g_i - G_i) times the kick
(GridSolve.accelerate). G_i needs the material around the node: the correction is weighted by c_i, 0 near a free
surface and 1 where every node within the stencil's reach is filled by its particles (FILL_LOW, FILL_HIGH below),
so a node whose support a free surface crosses keeps the standard force, which has no term to drop there.
Linear momentum is kept only approximately: sum_i sigma_i g_i is not zero where sigma varies.

Physics code only: no CLI, rendering or file I/O here.
"""

import taichi as ti

from ..layout import STRESS_DIFFERENCE_ROWS
from ..step.moments import Extension, ForceSums, GridSolve

# how full the nodes within the stencil's reach, (stencil + 1) // 2 nodes each way, must be (their particle volume over
# their support's volume inside the box) for the correction to start and to be whole. A node at or beyond a free
# surface is at most half full; if every node in the reach is 0.7 full, the nearest surface lies beyond the node's
# own support (quadratic: >= 2.16 cells away, support 1.5; cubic 2.24 against 2; linear 1.1 against 1). Interior
# nodes stay above 0.85 with particles moved off their lattice by 0.2 spacings (tests/test_stress_difference.py).
FILL_LOW, FILL_HIGH = 0.7, 0.85
SAMPLES = 16   # midpoint samples per cell for a node's support volume (it only sets the ramp)
# a node whose function has less than this integral inside the box (grid units, per axis) is a ghost beyond a wall
# (gimp's: about lp^2 / 12); the smallest real one is cubic's wall control point, 1/4
GHOST_SUPPORT = 0.2
# gimp's functions at the walls: its hats' values, which the particles' averaged gradients telescope to (a particle
# half-width this small; B-splines ignore it)
END_HALF_WIDTH = 1e-6


class StressDifference(Extension):
    name = "stress_difference"

    @classmethod
    def create(cls, setup):
        return cls(setup) if setup.cfg.solver.stress_difference else None

    def __init__(self, setup):
        self.dim, self.dx, self.n_cells = setup.dim, setup.dx, list(setup.n_cells)

    def allocate(self, setup):
        g, d = setup.grid, self.dim
        self.rows = [g.vec[name] for name in STRESS_DIFFERENCE_ROWS[:d]]
        self.g_sum, self.v_sum = g.vec["lsd_g"], g.scalar["lsd_v"]
        shape = g.m.shape
        self.support = [ti.field(float, shape[a]) for a in range(d)]   # int_box S_i du per axis (grid units)
        self.ends = [ti.field(float, shape[a]) for a in range(d)]      # S_i(upper wall) - S_i(lower wall)

    def build(self, ctx):
        self._tables = [self._table_kernel(ctx, a) for a in range(self.dim)]
        ctx.contribute("force_sums", ForceSums(scatter=self._scatter(ctx)))
        ctx.grid_solve.append(GridSolve(accelerate=self._correction(ctx)))

    def upload(self):
        for a, table in enumerate(self._tables):
            self.support[a].fill(0)
            self.ends[a].fill(0)
            table()

    def _table_kernel(self, ctx, a: int):
        """A kernel that fills axis a's tables from the basis' 1D functions: the support integral by the midpoint
        rule (SAMPLES per cell), the end values exactly."""
        basis, n, lp = ctx.basis.axis(a), int(self.n_cells[a]), ctx.domain_lp0
        support, ends, S = self.support[a], self.ends[a], ctx.basis.stencil

        @ti.kernel
        def fill():
            ti.loop_config(serialize=True)   # a fixed order of the sums
            for k in range(n * SAMPLES):
                first, W, _ = basis.weights_1d((k + 0.5) / SAMPLES, n, lp)
                for j in ti.static(range(S)):
                    support[first + j] += W[j] / SAMPLES
            for side in ti.static(range(2)):   # the functions themselves at the walls (gimp: not averaged)
                first, W, _ = basis.weights_1d(ti.cast(side * n, float), n, END_HALF_WIDTH)
                for j in ti.static(range(S)):
                    ends[first + j] += (2 * side - 1) * W[j]
        return fill

    def _scatter(self, ctx):
        d, add, rows, g_sum, v_sum = self.dim, ctx.add, self.rows, self.g_sum, self.v_sum

        @ti.func
        def scatter(p, I, w, force_gradient, stress_volume, volume):
            for a in ti.static(range(d)):
                add(rows[a], I, w * ti.Vector([stress_volume[a, b] for b in ti.static(range(d))]))
            add(g_sum, I, volume * force_gradient)
            add(v_sum, I, w * volume)
        return scatter

    def _correction(self, ctx):
        d, dx, rows, g_sum, v_sum = self.dim, self.dx, self.rows, self.g_sum, self.v_sum
        support, ends = self.support, self.ends
        # ck: a node's neighbours on its own grid lie `stride` storage nodes apart, and its function is 1/grids of
        # the axes' product
        stride, scale = ctx.basis.spec.nodes_per_cell, 1.0 / ctx.basis.grids
        ramp, reach = 1.0 / (FILL_HIGH - FILL_LOW), (ctx.basis.stencil // stride + 1) // 2
        shape = tuple(self.v_sum.shape)

        @ti.func
        def full_volume(J):
            full = scale
            for a in ti.static(range(d)):
                full *= support[a][J[a]] * dx
            return full

        @ti.func
        def inside(I):
            """1 where every node within the stencil's reach is (nearly) filled by particles (then node I's own
            support lies inside the material or the box), 0 near a free surface, a ramp between (also one between
            a body and a wall, whose wall node is then short of particles). A ghost node beyond a wall, whose
            function hardly reaches into the box, does not count."""
            c = 1.0
            for o in ti.grouped(ti.ndrange(*([(-reach, reach + 1)] * d))):
                J = I + stride * o
                within = True
                for a in ti.static(range(d)):
                    within = within and 0 <= J[a] < shape[a]
                    if within:
                        within = support[a][J[a]] >= GHOST_SUPPORT
                if within:
                    full = full_volume(J)
                    if full > 0:
                        c = ti.min(c, ti.math.clamp((v_sum[J] / full - FILL_LOW) * ramp, 0.0, 1.0))
            return c

        @ti.func
        def correction(I, vel, m, kick_before, kick_after):
            c = inside(I)
            if c > 0:
                V, full = v_sum[I], full_volume(I)
                G = ti.Vector.zero(float, d)   # int grad S_i over the box: the walls' terms
                if full > 0:   # (a node whose support the samples miss inside the box has no walls' term)
                    for a in ti.static(range(d)):
                        G[a] = ends[a][I[a]] * full / (support[a][I[a]] * dx)
                sigma = ti.Matrix.rows([rows[a][I] for a in ti.static(range(d))]) / V
                vel += (kick_before + kick_after) * c * (sigma @ (g_sum[I] - G)) / m
            return vel
        return correction
