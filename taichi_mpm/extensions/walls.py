"""The domain's walls as a step extension: the condition of every face (grid.make_wall_condition: sticky, slip,
roller with Coulomb friction, velocity walls, along a mapped grid's normals), in the grid solve's chain after the
accelerations and before the grips; the velocity walls' values in time (loads.py), the impulse each face gives the
material for wall probes (`impulse`), and the work velocity walls do in the energy balance.

Every scene has walls (a face left out is `domain.boundaries.default`), so `create` always makes one.

Physics code only: no CLI, rendering or file I/O here.
"""
import numpy as np
import taichi as ti

from ..bases.compact_kernel import make_ghost_images
from ..grid import make_wall_condition
from ..loads import Loads
from ..step.moments import Extension, GridSolve


def has_velocity_walls(cfg) -> bool:
    walls = cfg.domain.boundaries
    return any(walls.face(a, side) == "velocity" for a in range(cfg.dim) for side in (0, 1))


def has_wall_probes(cfg) -> bool:
    return any(p.type == "wall" for p in cfg.output.probes)


class Walls(Extension):
    name = "walls"
    work_term = "prescribed velocities"   # velocity walls'

    @classmethod
    def adds_in_thread_order(cls, cfg) -> bool:
        return has_velocity_walls(cfg) or has_wall_probes(cfg)   # the work and the wall impulses

    @classmethod
    def create(cls, setup):
        return cls(setup)

    def __init__(self, setup):
        cfg, d = setup.cfg, setup.dim
        self.dim = d
        self.loads = Loads(cfg, setup.scene)   # the velocity walls' time functions
        self.moving = bool(self.loads.walls)
        if not self.moving:
            self.work_term = ""
        self.wall_v = ti.Vector.field(d, float, 2 * d) if self.moving else None
        self.wall_w = ti.field(float, 2 * d) if self.loads.spins else None   # turning faces' angular velocities
        # impulse per face (x_min, x_max, y_min, ...), summed by the grid update; only for wall probes
        self.reaction = ti.Vector.field(d, ti.f64, 2 * d) if has_wall_probes(cfg) else None
        self._setup = setup
        self._values_time = None   # when the wall velocities were last uploaded

    def prepare(self, ctx):
        s, walls, d = self._setup, self._setup.cfg.domain.boundaries, self.dim
        faces = [(walls.face(a, 0), walls.face(a, 1)) for a in range(d)]
        friction = [(walls.friction(a, 0), walls.friction(a, 1)) for a in range(d)]
        spin = (self.wall_w, self.loads.wall_axes()) if self.wall_w is not None else None
        moving = (self.loads.wall_given(), self.wall_v, s.work, spin) if self.moving else None
        # a mapped grid's walls act on its parameter faces, along their normals
        ctx.wall = make_wall_condition(d, s.n_cells, faces, s.basis, friction, self.reaction, moving, s.mapped)
        ctx.grid_solve.append(GridSolve(condition=self._condition(ctx.wall)))
        images = make_ghost_images(d, s.n_cells, faces, self.reaction) if s.basis.kind == "staggered" else None
        if images is not None:   # ck: B's ghost nodes beyond the faces as images of the nodes inside
            ctx.grid_solve.append(GridSolve(images=images))
        self._set_values = self._values_kernel() if self.moving else None

    @staticmethod
    def _condition(wall):
        @ti.func
        def condition(I, vel, m, measure: ti.template()):
            if ti.static(measure):
                vel = wall.measured(I, vel, m)   # adds m dv per face to the reaction (wall probes only)
            else:
                vel = wall(I, vel)
            return vel
        return condition

    def _values_kernel(self):
        wall_v, wall_w, d = self.wall_v, self.wall_w, self.dim
        turning = wall_w is not None

        @ti.kernel
        def set_values(values: ti.types.matrix(2 * d, d, float), spins: ti.types.vector(2 * d, float)):
            """This step's velocities of the velocity faces (per face slot) and of the turning faces' spins."""
            for slot in ti.static(range(2 * d)):   # top-level statements: no parallel task of one iteration
                for c in ti.static(range(d)):
                    wall_v[slot][c] = values[slot, c]
                if ti.static(turning):
                    wall_w[slot] = spins[slot]
        return set_values

    def upload(self):
        self._values_time = None
        if self.reaction is not None:
            self.reaction.fill(0)

    def before_step(self, t, dt, lag):
        """The velocity walls' velocities at t + dt/2 (the velocity that moves the positions over the step:
        exact displacement for a linear motion); uploaded once when they are constant."""
        if not self.moving or (self._values_time is not None and self.loads.motion_constant):
            return
        t_mid = t + 0.5 * dt
        self._set_values(ti.Matrix(self.loads.wall_velocities(t_mid).tolist()),
                         ti.Vector(self.loads.wall_spins(t_mid).tolist()))
        self._values_time = t_mid

    def impulse(self, reset: bool = True) -> np.ndarray:
        """(2 dim, dim) impulse each face gave the material since the last reset (Simulation.wall_impulse)."""
        if self.reaction is None:
            raise RuntimeError("no wall reaction is accumulated: the config has no wall probe in output.probes")
        out = self.reaction.to_numpy().reshape(2 * self.dim, self.dim)
        if reset:
            self.reaction.fill(0)
        return out
