"""Host side of prescribed loads and motions (docs/loads.md): the time functions of tractions, grips
(bodies[].prescribed_velocity) and velocity walls, evaluated once per step and handed to the solver's fields.

The particles and forces come from the scene (scene.Load, scene.Grip); here only their values in time:
- a traction's particle forces are its force at ramp 1 times ramp(t), taken at the middle of the step's leapfrog
  kick, t + dt/4 - dt_prev/4 (t itself at constant steps);
- a grip's or a velocity wall's velocity is taken at t + dt/2, the time the grid update's new (half-step) velocity
  belongs to: the one that moves the positions from t to t + dt.

Physics only: no I/O.
"""
from __future__ import annotations

import numpy as np

from .config import FACES, TIME, Config
from .expressions import Expression


class _TimeValue:
    """A number or an expression of t; `constant` when it cannot change."""

    def __init__(self, value, key):
        self.expr = Expression(value, TIME, key) if isinstance(value, str) else None
        self.value = None if self.expr is not None else float(value)
        self.constant = self.expr is None or not self.expr.names

    def __call__(self, t: float) -> float:
        return self.value if self.expr is None else float(self.expr.evaluate(t=t))


def _vector(spec, key, dim):
    """(given, values): which components are prescribed (static), and their time values."""
    given = tuple(c is not None for c in spec)
    values = [_TimeValue(c, f"{key}.{a}") if c is not None else None for a, c in enumerate(spec)]
    return given, values


def kick_middle(t: float, dt: float, lag: float) -> float:
    """The time a traction's ramp is taken at for a step from t by dt whose velocities lag by `lag`: the middle of
    its leapfrog kick, t + dt/4 - lag/2 (the exact impulse of a linear ramp)."""
    return t + 0.25 * dt - 0.5 * lag


def ramp_functions(loads) -> list:
    """The ramp, a function of t, of each traction entry (scene.Load or scene.NodeLoad)."""
    return [_TimeValue(load.ramp, f"{load.key}.ramp") for load in loads]


class Loads:
    """Tractions, grips and velocity walls of a scene; each part is None/empty when the scene has none."""

    def __init__(self, cfg: Config, scene):
        self.dim, self.n = cfg.dim, scene.n
        self.tractions = list(zip(scene.loads, ramp_functions(scene.loads)))
        self.grips = [(grip, *_vector(grip.velocity, f"{grip.key}.velocity", cfg.dim)) for grip in scene.grips]
        walls = cfg.domain.boundaries
        self.walls = []  # (slot, given, values) of each velocity face
        self.spins = {}  # slot -> (angular velocity, axis point) of each turning face (mapped grids)
        for a in range(cfg.dim):
            for side in (0, 1):
                face = walls._get(a, side)
                if face.type != "velocity":
                    continue
                name = FACES[2 * a + side]
                key = f"domain.boundaries.{name if getattr(walls, name) is not None else 'default'}"
                given, values = _vector(face.velocity or [None] * cfg.dim, f"{key}.velocity", cfg.dim)
                if face.angular_velocity is not None:
                    # the config requires a mapped grid here, and `center` where the map has none (nurbs)
                    centre = face.center if face.center is not None else getattr(cfg.domain.map, "center")
                    self.spins[2 * a + side] = (_TimeValue(face.angular_velocity, f"{key}.angular_velocity"),
                                                tuple(float(c) for c in centre))
                    given = (True, True) + given[2:]        # the turn sets x and y
                self.walls.append((2 * a + side, given, values))

    # ------------------------------------------------------------------ tractions
    @property
    def has_tractions(self) -> bool:
        return bool(self.tractions)

    def ramps(self, t: float) -> tuple:
        return tuple(ramp(t) for _, ramp in self.tractions)

    def traction_forces(self, t: float) -> np.ndarray:
        """(N, d) particle forces in creation order at time t (what the solver's apply_loads kernel forms)."""
        f = np.zeros((self.n, self.dim))
        for (load, _), r in zip(self.tractions, self.ramps(t)):
            np.add.at(f, load.particles, r * load.force)
        return f

    def max_force(self) -> float:
        """Largest particle force a traction gives at ramp 1 (for messages)."""
        return max((float(np.abs(l.force).max()) for l, _ in self.tractions), default=0.0)

    # ------------------------------------------------------------------ prescribed velocities
    def grip_given(self) -> list[tuple]:
        return [given for _, given, _ in self.grips]

    def grip_velocities(self, t: float) -> np.ndarray:
        """(K, d) prescribed velocities of the grips at time t (free components 0)."""
        return np.array([[v(t) if v is not None else 0.0 for v in values] for _, _, values in self.grips],
                        dtype=np.float64).reshape(len(self.grips), self.dim)

    def wall_given(self) -> list[tuple]:
        """Per face slot (x_min, x_max, ...), the prescribed components (all False for other faces)."""
        out = [(False,) * self.dim for _ in range(2 * self.dim)]
        for slot, given, _ in self.walls:
            out[slot] = given
        return out

    def wall_velocities(self, t: float) -> np.ndarray:
        """(2 d, d) velocities of the velocity faces at time t (zero for other faces and free components)."""
        out = np.zeros((2 * self.dim, self.dim))
        for slot, _, values in self.walls:
            out[slot] = [v(t) if v is not None else 0.0 for v in values]
        return out

    def wall_spins(self, t: float) -> np.ndarray:
        """(2 d,) angular velocities of the turning faces at time t (zero for the others)."""
        out = np.zeros(2 * self.dim)
        for slot, (w, _) in self.spins.items():
            out[slot] = w(t)
        return out

    def wall_axes(self) -> list:
        """Per face slot, the point the turning face turns about (its axis is +z), or None."""
        return [self.spins[slot][1] if slot in self.spins else None for slot in range(2 * self.dim)]

    @property
    def motion_constant(self) -> bool:
        """Whether grip and wall velocities never change (then they are uploaded once)."""
        spins = [w for w, _ in self.spins.values()]
        return all(v is None or v.constant for _, _, vals in self.grips + self.walls for v in vals) and \
            all(w.constant for w in spins)
