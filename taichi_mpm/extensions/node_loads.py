"""Tractions applied as nodal forces (bodies[].tractions[].apply_to: nodes) as a step extension: the consistent
load of a loaded face, f_i = int R_i t dA, on the mapped grid's control points (scene.NodeLoad, computed on the host
from the map's faces), where the particle form spreads the face's force from the loaded particles by their weights.
Each step the grid solve adds ramp(t) f_i over the leapfrog kick to node i's velocity (GridSolve.accelerate, before
the walls' and grips' conditions), with the ramps at the middle of the kick as for particle tractions. Its work is
counted after the step at each loaded node, which stays where it is, by the trapezoid of its velocities of the last
step and this one, kick ramp f_i . (v_i^(n-1/2) + v_i^(n+1/2)) / 2, as a particle traction's is by its particle's.

The nodes stay where the faces started: the load suits faces that move less than a cell (a pressurised vessel, a
loaded foundation); a node without mass takes no force.

Physics code only: no CLI, rendering or file I/O here.
"""
import numpy as np
import taichi as ti

from ..loads import kick_middle, ramp_functions
from ..step.moments import Extension, GridSolve


class NodeLoads(Extension):
    name = "node_loads"
    work_term = "tractions"

    @classmethod
    def adds_in_thread_order(cls, cfg) -> bool:
        return any(t.apply_to == "nodes" for b in cfg.bodies for t in b.tractions)   # their work, summed per node

    @classmethod
    def create(cls, setup):
        return cls(setup) if setup.scene.node_loads else None

    def __init__(self, setup):
        loads = setup.scene.node_loads
        self._setup, self.dim = setup, setup.dim
        self._ramps_of = ramp_functions(loads)
        k = sum(len(l.nodes) for l in loads)
        self.node = ti.Vector.field(setup.dim, ti.i32, k)       # each entry's node,
        self.index = ti.field(ti.i32, k)                        # its traction,
        self.force = ti.Vector.field(setup.dim, float, k)       # and its force at ramp 1
        self.total = ti.Vector.field(setup.dim, float, tuple(setup.mapped.shape))   # this step's nodal forces
        self.before = ti.Vector.field(setup.dim, float, k)      # each entry's node velocity of the last step
        self._ramps, self._kick, self._first = None, 0.0, True

    def build(self, ctx):
        node, index, force, total, dim = self.node, self.index, self.force, self.total, self.dim
        n_loads = len(self._ramps_of)

        @ti.kernel
        def apply(ramps: ti.types.vector(n_loads, float)):
            """The nodal forces of the tractions: the sum of ramp x force at ramp 1 (one launch: the loops run in
            order)."""
            for I in ti.grouped(total):
                total[I] = ti.Vector.zero(float, dim)
            for e in node:
                total[node[e]] += ramps[index[e]] * force[e]
        self._apply = apply
        self._work = self._work_kernel(ctx)
        ctx.grid_solve.append(GridSolve(accelerate=self._accelerate()))

    def _accelerate(self):
        total = self.total

        @ti.func
        def accelerate(I, vel, m, kick_before, kick_after):
            return vel + (kick_before + kick_after) / m * total[I]
        return accelerate

    def _work_kernel(self, ctx):
        node, force, index, before, gv, work = self.node, self.force, self.index, self.before, ctx.gv, ctx.work
        n_loads = len(self._ramps_of)

        @ti.kernel
        def count(kick: float, ramps: ti.types.vector(n_loads, float), first: ti.i32):
            """The loads' work over the step's kick, by the trapezoid of each loaded node's last and new velocity
            (the node's velocity the grid solve left, walls' and grips' conditions included; 0 without mass)."""
            for e in node:
                v = gv[node[e]]
                if first:
                    before[e] = v
                work[0][None] += 0.5 * kick * ramps[index[e]] * force[e].dot(before[e] + v)
                before[e] = v
        return count

    def upload(self):
        loads = self._setup.scene.node_loads
        self.node.from_numpy(np.concatenate([l.nodes for l in loads]).astype(np.int32))
        self.index.from_numpy(np.concatenate([np.full(len(l.nodes), k, np.int32) for k, l in enumerate(loads)]))
        self.force.from_numpy(np.concatenate([l.force for l in loads]).astype(np.float64))
        self._ramps, self._first = None, True

    def before_step(self, t, dt, lag):
        ramps = tuple(r(kick_middle(t, dt, lag)) for r in self._ramps_of)
        if ramps != self._ramps:
            self._apply(ti.Vector(list(ramps)))
            self._ramps = ramps
        self._kick = lag + 0.5 * dt   # the step's leapfrog kick (Simulation.step: kick_before + kick_after)

    def after_g2p(self):
        self._work(self._kick, ti.Vector(list(self._ramps)), int(self._first))
        self._first = False

    def particles_set(self, names):
        self._first = True   # velocities given from outside: the next step starts the trapezoid afresh
