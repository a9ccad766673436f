"""A step extension from outside the package: a uniform body acceleration added in the grid solve (its GridSolve
part), with the work it does, and a count of every moment the solver calls (tests/test_plugin_extension.py)."""
from collections import Counter

import numpy as np
import taichi as ti

from taichi_mpm.step.extensions import Extension, GridSolve


class UniformPush(Extension):
    name = "uniform_push"
    acceleration = None   # set by the test before the Simulation is built (m/s^2, one per axis)

    @classmethod
    def adds_in_thread_order(cls, cfg):
        return cls.acceleration is not None   # its work's atomic sum

    @classmethod
    def create(cls, setup):
        return cls(setup) if cls.acceleration is not None else None

    def __init__(self, setup):
        self.a = [float(c) for c in self.acceleration][:setup.dim]
        self.calls = Counter(create=1)
        self.n = setup.n

    def grid_fields(self):
        self.calls["grid_fields"] += 1
        return [], []

    def allocate(self, setup):
        self.calls["allocate"] += 1
        self.pushes = ti.field(ti.i32, ())   # steps pushed: its part of a checkpoint

    def bytes_per_particle(self):
        self.calls["bytes_per_particle"] += 1
        return 0

    def prepare(self, ctx):
        self.calls["prepare"] += 1
        self.wall_before_stencil = ctx.wall is not None and ctx.stencil is None   # the walls prepared before it

    def build(self, ctx):
        self.calls["build"] += 1
        a, work = ti.Vector(self.a), ctx.work

        @ti.func
        def accelerate(I, vel, m, kick_before, kick_after):
            dv = (kick_before + kick_after) * a
            work[0][None] += m * dv.dot(vel + 0.5 * dv)   # the kinetic energy it adds to the node
            return vel + dv
        ctx.grid_solve.append(GridSolve(accelerate=accelerate))

    def upload(self):
        self.calls["upload"] += 1

    def before_step(self, t, dt, lag):
        self.calls["before_step"] += 1
        self.clock = getattr(self, "clock", []) + [(t, dt, lag)]

    def before_p2g(self):
        self.calls["before_p2g"] += 1

    def after_p2g(self):
        self.calls["after_p2g"] += 1

    def node_solve_active(self):
        self.calls["node_solve_active"] += 1
        return False

    def after_g2p(self):
        self.calls["after_g2p"] += 1
        self.pushes[None] += 1

    def particles_set(self, names):
        self.calls["particles_set"] += 1

    def outputs(self):
        self.calls["outputs"] += 1
        return {"push": np.full(self.n, float(np.linalg.norm(self.a)))}

    def get_state(self):
        self.calls["get_state"] += 1
        return {"pushes": int(self.pushes[None])}

    def check_state(self, state):
        self.calls["check_state"] += 1
        if int(state.get("pushes", 0)) < 0:
            raise ValueError("state pushes must be >= 0")

    def set_state(self, state):
        self.calls["set_state"] += 1
        self.pushes[None] = int(state.get("pushes", 0))
