"""The crack finder's view of the scene: what it reads of the extension setup the solver hands every extension
(step.moments.Setup: public constants, particle fields, the grid, the order maps), gathered in one place
(`view_of`); the finder never sees the Simulation."""

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .fields import interface_sides


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
    side: np.ndarray                # per particle, its body's side among interface bodies (fields.interface_sides)
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
    mass: np.ndarray                # the scene's particle masses, creation order
    to_solver: Callable             # per-particle array: creation order -> solver slots
    to_creation: Callable           # and back
    perm: Callable                  # () -> the solver slots' creation indices (set when particles are uploaded)


def view_of(setup) -> SimView:
    """The view of an allocated setup (step.moments.Setup, its grid set)."""
    s, f = setup, setup.feat
    side = np.asarray(interface_sides(s.cfg.bodies), dtype=np.int32)[s.scene.body]
    return SimView(dim=s.dim, n=s.n, dx=s.dx, lower=s.lower, upper=s.upper, n_cells=s.n_cells, crack=s.cfg.crack,
                   precision=s.precision, spacing=s.scene.spacing, damage=s.scene.damage,
                   interface=s.scene.interface, side=side, basis=s.basis, materials=s.materials, apic=f.apic,
                   flip=f.flip, musl=f.musl, grid=s.grid, x=s.x, v=s.v, F=s.F, vol0=s.vol0, mass=s.scene.mass,
                   to_solver=s.to_solver,
                   to_creation=s.to_creation, perm=s.perm)
