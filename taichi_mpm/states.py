"""States the Simulation API refuses (docs/contract.md, "API states"); solver.py calls each check in one line.

- `check_particles`: positions and deformation gradients given to `set_particles` / `set_state` must be ones the
  first step would not reject: every position inside the domain (within the step's own tolerance, 1e-6 dx) and
  every J = det F > 0. ValueError naming the array and the first such particle (creation order).
- `check_dt`: a dt given to `step(dt)` must be a finite number > 0 that the kernels and the clock can represent:
  at least the smallest normal number of the scene's precision (below it the kernels would step with 0 or a
  denormal while the clock moved) and at least the clock's resolution at the current time (below it the clock
  would not move, or move by a rounded amount). ValueError.
- `stepping`: the decorator of `step` and `advance_to`. After an InstabilityError the simulation is failed: its
  state holds the step that failed (NaN, an inverted particle, ...), so a further step or advance raises an
  InstabilityError of the same cause, step and particle, saying so, instead of stepping it again. `set_state` (e.g.
  a checkpoint) or `set_particles` that leaves every position, velocity and F finite, inside the domain and
  with J > 0 makes it steppable again (`restored`).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from .errors import InstabilityError

OUT_TOLERANCE = 1e-6   # in cells: the step's own "left the domain" tolerance (solver.py, out_tol)


def check_particles(sim, arrays: dict):
    """ValueError for positions outside the domain or J = det F <= 0 (`arrays`: checked shapes, creation order)."""
    if "x" in arrays:
        x = arrays["x"]
        tol = OUT_TOLERANCE * sim.dx
        out = np.flatnonzero(((x < sim.lower - tol) | (x > sim.upper + tol)).any(axis=1))
        if len(out):
            p = int(out[0])
            raise ValueError(f"x: particle {p} lies outside the domain (x = {x[p].tolist()}, domain "
                             f"{sim.lower.tolist()}..{sim.upper.tolist()}; {len(out)} particle"
                             f"{'s' if len(out) > 1 else ''} outside)")
    if "F" in arrays:
        J = np.linalg.det(arrays["F"]) if len(arrays["F"]) else np.zeros(0)
        bad = np.flatnonzero(~(J > 0))
        if len(bad):
            p = int(bad[0])
            raise ValueError(f"F: particle {p} has J = det F = {J[p]:.6g} <= 0 (an inverted or collapsed particle; "
                             f"{len(bad)} particle{'s' if len(bad) > 1 else ''} with J <= 0)")


def check_dt(sim, dt) -> float:
    """The dt a caller gave step(dt), as a float; ValueError where it cannot be stepped (module docstring)."""
    if not (_is_real(dt) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"step(dt): dt must be a finite number > 0, got {dt!r}")
    dt = float(dt)
    precision = sim.cfg.precision
    tiny = float(np.finfo(np.float32 if precision == "f32" else np.float64).tiny)
    if dt < tiny:
        raise ValueError(f"step(dt): dt = {dt!r} is below the smallest normal {precision} number ({tiny:.3g}): the "
                         f"kernels would step with zero or a denormal while the clock moves")
    resolution = float(np.spacing(sim.time))
    if dt < resolution:
        raise ValueError(f"step(dt): dt = {dt!r} is below the clock's resolution at t = {sim.time!r} "
                         f"({resolution:.3g} s): the clock cannot advance by it")
    return dt


def stepping(method):
    """Refuse to step a failed simulation; mark it failed when the method raises an InstabilityError."""
    @functools.wraps(method)
    def wrapper(sim, *args, **kwargs):
        failed = getattr(sim, "_failed", None)
        if failed is not None:
            raise InstabilityError(
                failed.cause, failed.step, failed.time, particle=failed.particle,
                detail=(f"the simulation failed there and holds the failed step's state; {method.__name__}() does "
                        "not step it again: restore a good state first (set_state, e.g. a checkpoint's, or "
                        "set_particles)"))
        try:
            return method(sim, *args, **kwargs)
        except InstabilityError as e:
            if getattr(sim, "_failed", None) is None:
                sim._failed = e
            raise
    return wrapper


def restored(sim):
    """After set_particles / set_state: a failed simulation whose whole state is good again may step."""
    if getattr(sim, "_failed", None) is None:
        return
    p = sim._read_all()   # x, v, F (and C where stored)
    good = all(np.isfinite(a).all() for a in p.values())
    if good:
        try:
            check_particles(sim, {"x": p["x"], "F": p["F"]})
        except ValueError:
            good = False
    if good:
        sim._failed = None


def _is_real(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
