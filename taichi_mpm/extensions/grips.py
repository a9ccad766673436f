"""Grips (bodies[].prescribed_velocity) as a step extension: after each P2G scatter every node in the support of a
gripped particle is marked with its grip (`after_p2g`); in the grid solve's chain, after the walls, such a node
takes the grip's prescribed velocity components (their values in time: loads.py, at t + dt/2). The impulse each
grip gives the material (`impulse`: the reaction a testing machine measures) and the work it does (ctx.work slot 0)
are summed in the step's update.

Physics code only: no CLI, rendering or file I/O here.
"""
import numpy as np
import taichi as ti

from ..loads import Loads
from ..step.moments import Extension, GridSolve


def grip_setter(dim: int, given, grip_v, indices):
    """@ti.func (flag, vel) -> (vel, held) for other extensions' own velocity fields (multi-field contact's body
    fields, the crack finder's second fields): vel with the prescribed components of grip `flag` (numbered from 1,
    as the nodes' grip flags) when it is one of `indices` (from 0), and held 1 for those components."""

    @ti.func
    def setter(flag, vel):
        held = ti.Vector.zero(float, dim)
        for j in ti.static(indices):
            if flag == j + 1:
                for c in ti.static(range(dim)):
                    if ti.static(given[j][c]):
                        vel[c] = grip_v[j][c]
                        held[c] = 1.0
        return vel, held
    return setter


class Grips(Extension):
    name = "grips"
    work_term = "prescribed velocities"

    @classmethod
    def adds_in_thread_order(cls, cfg) -> bool:
        return any(b.prescribed_velocity for b in cfg.bodies)   # the impulses, the nodes' marks

    @classmethod
    def create(cls, setup):
        return cls(setup) if setup.scene.grips else None

    def __init__(self, setup):
        d, grips = setup.dim, setup.scene.grips
        self.dim, self._setup = d, setup
        self.loads = Loads(setup.cfg, setup.scene)   # the grips' time functions
        self.given = self.loads.grip_given()          # per grip: which components it prescribes (static)
        n_gripped = sum(len(g.particles) for g in grips)
        self.slot = ti.field(ti.i32, n_gripped)        # solver slot of each gripped particle
        self.index = ti.field(ti.i32, n_gripped)       # its grip, from 1
        self.velocity = ti.Vector.field(d, float, len(grips))
        self.reaction = ti.Vector.field(d, ti.f64, len(grips))
        self._values_time = None   # when the grip velocities were last uploaded

    def prepare(self, ctx):
        # what other extensions' own node solves read (multi-field contact holds each body's grips)
        ctx.extra["grip_given"], ctx.extra["grip_v"] = self.given, self.velocity

    def build(self, ctx):
        ctx.grid_solve.append(GridSolve(condition=self._condition(ctx)))
        self._flag_nodes = self._flag_kernel(ctx)
        self._set_values = self._values_kernel()

    def _condition(self, ctx):
        dim, grid, given, grip_v, impulse, work = ctx.dim, ctx.grid, self.given, self.velocity, self.reaction, \
            ctx.work

        @ti.func
        def condition(I, vel, m, measure: ti.template()):
            """A node touched by a gripped particle takes the grip's prescribed components; measured: the impulse
            m dv goes to the grip's reaction and m dv . v to the work."""
            g = ti.cast(grid.vec["grip"][I][0], ti.i32)
            if g > 0:
                before = vel
                for k in ti.static(range(len(given))):
                    if g == k + 1:
                        for c in ti.static(range(dim)):
                            if ti.static(given[k][c]):
                                vel[c] = grip_v[k][c]
                        if ti.static(measure):
                            impulse[k] += m * (vel - before)
                if ti.static(measure):
                    work[0][None] += m * (vel - before).dot(vel)
            return vel
        return condition

    def _flag_kernel(self, ctx):
        grid, sten, slot, index = ctx.grid, ctx.stencil, self.slot, self.index
        outer, inner = sten.outer, sten.inner
        pt = ctx.particle_transfer
        own_side = pt.own_side if pt is not None else None
        sided = own_side is not None
        second_field = pt.second_field if pt is not None and ctx.dim > 1 else None
        two_fields = second_field is not None

        @ti.func
        def holds(p, off):
            keep = True
            if ti.static(sided):   # the crack finder: not a node across the particle's crack
                keep = own_side(p, off)
            return keep

        @ti.func
        def second(p, off, I):
            res = False
            if ti.static(two_fields):
                res = second_field(p, off, I)
            return res

        @ti.kernel
        def flag_grip_nodes():
            """Mark every node in the support (w > 0) of a gripped particle on its side (ParticleTransfer.own_side)
            with its grip (the largest wins); component 1, a node that holds the particle in a second velocity
            field (ParticleTransfer.second_field: the crack finder's friction), for that field."""
            for e in slot:
                p = slot[e]
                st = sten.at(p)
                for o in ti.grouped(ti.ndrange(*outer)):
                  for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil, see `unroll`)
                    I, w, gw, r = sten.node(st, o + inner[k])
                    if w > 0:
                        if holds(p, o + inner[k]):
                            ti.atomic_max(grid.vec["grip"][I][0], ti.cast(index[e], float))
                        elif second(p, o + inner[k], I):
                            ti.atomic_max(grid.vec["grip"][I][1], ti.cast(index[e], float))
        return flag_grip_nodes

    def _values_kernel(self):
        velocity, d, k_grips = self.velocity, self.dim, len(self.given)

        @ti.kernel
        def set_values(values: ti.types.matrix(k_grips, d, float)):
            """This step's grip velocities (row k: grip k)."""
            for k in ti.static(range(k_grips)):   # top-level statements: no parallel task of one iteration
                for c in ti.static(range(d)):
                    velocity[k][c] = values[k, c]
        return set_values

    def upload(self):
        s = self._setup
        slot_of = np.argsort(s.perm())   # creation index -> solver slot
        grips = s.scene.grips
        self.slot.from_numpy(np.concatenate([slot_of[g.particles] for g in grips]).astype(np.int32))
        self.index.from_numpy(np.concatenate([np.full(len(g.particles), k + 1, np.int32)
                                              for k, g in enumerate(grips)]))
        self.reaction.fill(0)
        self._values_time = None

    def before_step(self, t, dt, lag):
        """The grip velocities at t + dt/2 (the velocity that moves the positions over the step: exact
        displacement for a linear motion); uploaded once when they are constant."""
        if self._values_time is not None and self.loads.motion_constant:
            return
        t_mid = t + 0.5 * dt
        self._set_values(ti.Matrix(self.loads.grip_velocities(t_mid).tolist()))
        self._values_time = t_mid

    def after_p2g(self):
        self._flag_nodes()

    def impulse(self, reset: bool = True) -> np.ndarray:
        """(K, dim) impulse each grip gave the material since the last reset (Simulation.prescribed_impulse)."""
        out = self.reaction.to_numpy().reshape(-1, self.dim)
        if reset:
            self.reaction.fill(0)
        return out
