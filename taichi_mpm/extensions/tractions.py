"""Tractions (bodies[].tractions) as a step extension: each step's particle forces, the sum over the tractions of
ramp(t) times the force at ramp 1 on the loaded particles (scene.Load), written into the solver's per-particle
external force (`load`, which P2G adds); the ramps are taken at the middle of the step's leapfrog kick
(t + dt/4 - lag/2: the exact impulse of a linear ramp) and the forces rewritten only when a ramp changed.

Physics code only: no CLI, rendering or file I/O here.
"""
import numpy as np
import taichi as ti

from ..loads import Loads, kick_middle
from ..step.moments import Extension


class Tractions(Extension):
    name = "tractions"
    work_term = "tractions"

    @classmethod
    def adds_in_thread_order(cls, cfg) -> bool:
        return any(b.tractions for b in cfg.bodies)   # their work, summed in P2G

    @classmethod
    def create(cls, setup):
        return cls(setup) if setup.scene.loads else None

    def __init__(self, setup):
        loads = setup.scene.loads
        n_loaded = sum(len(l.particles) for l in loads)
        self._setup = setup
        self.loads = Loads(setup.cfg, setup.scene)   # the ramps' time functions
        self.slot = ti.field(ti.i32, n_loaded)                     # solver slot of each loaded particle,
        self.index = ti.field(ti.i32, n_loaded)                    # its traction,
        self.force = ti.Vector.field(setup.dim, float, n_loaded)   # and its force at ramp 1
        self._ramps = None   # the ramps last applied

    def build(self, ctx):
        load, slot, index, force = self._setup.load, self.slot, self.index, self.force
        dim, n_loads = ctx.dim, len(self._setup.scene.loads)

        @ti.kernel
        def apply_loads(ramps: ti.types.vector(n_loads, float)):
            """Particle forces of the tractions: the sum of ramp x force at ramp 1 (one launch: the loops run
            in order)."""
            for p in load:
                load[p] = ti.Vector.zero(float, dim)
            for e in slot:
                load[slot[e]] += ramps[index[e]] * force[e]
        self._apply = apply_loads

    def upload(self):
        s = self._setup
        slot_of = np.argsort(s.perm())   # creation index -> solver slot
        loads = s.scene.loads
        self.slot.from_numpy(np.concatenate([slot_of[l.particles] for l in loads]).astype(np.int32))
        self.index.from_numpy(np.concatenate([np.full(len(l.particles), k, np.int32) for k, l in enumerate(loads)]))
        self.force.from_numpy(np.concatenate([l.force for l in loads]).astype(np.float64))
        self._ramps = None

    def before_step(self, t, dt, lag):
        ramps = self.loads.ramps(kick_middle(t, dt, lag))
        if ramps != self._ramps:
            self._apply(ti.Vector(list(ramps)))
            self._ramps = ramps
