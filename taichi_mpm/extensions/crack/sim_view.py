"""The crack finder's view of the Simulation: every Simulation member the finder reads, gathered in one place
(`view_of`), so that a later step can hand the finder such a view instead of the Simulation itself."""

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np


@dataclass(frozen=True)
class SimView:
    dim: int
    n: int                          # particles
    dx: float
    lower: np.ndarray               # domain corners
    upper: np.ndarray
    n_cells: Any                    # grid cells per axis
    crack: Any                      # the config's crack section
    precision: str                  # "f32" or "f64"
    spacing: np.ndarray             # the scene's particle spacing
    damage: np.ndarray              # the scene's initial damage and interface flags, creation order
    interface: np.ndarray
    basis: Any                      # basis.Basis
    materials: list                 # the scene's materials (config), by material index
    apic: bool
    flip: bool
    musl: bool
    grid: Any                       # the solver's grid (grid.Grid), with the finder's node fields (grid_fields)
    x: Any                          # particle fields
    v: Any
    F: Any
    vol0: Any
    to_solver: Callable             # per-particle array: creation order -> solver slots
    to_creation: Callable           # and back
    perm: Callable                  # () -> the solver slots' creation indices (set when particles are uploaded)


def view_of(sim) -> SimView:
    """The view of `sim` (a solver.Simulation whose particle fields and grid are allocated)."""
    return SimView(dim=sim.dim, n=sim.n, dx=sim.dx, lower=sim.lower, upper=sim.upper, n_cells=sim.n_cells,
                   crack=sim.cfg.crack,
                   precision=sim.cfg.precision, spacing=sim.scene.spacing, damage=sim.scene.damage,
                   interface=sim.scene.interface, basis=sim.basis, materials=sim._materials,
                   apic=sim.feat["apic"], flip=sim.feat["flip"], musl=sim.feat["musl"], grid=sim.grid,
                   x=sim.x, v=sim.v, F=sim.F, vol0=sim.vol0, to_solver=sim._to_solver,
                   to_creation=sim._to_creation, perm=lambda: sim._perm)
