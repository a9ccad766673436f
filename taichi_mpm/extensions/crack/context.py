"""What the crack finder's kernel factories receive: its fields, its view of the scene (view.SimView), the crack
section, the step context (stencil and material funcs) and the compile-time constants several factories share."""

import math
from dataclasses import dataclass
from typing import Any

import taichi as ti

from .constants import CELL_SPLIT


@dataclass(frozen=True)
class CrackContext:
    fields: Any             # fields.CrackFields
    view: Any               # view.SimView
    cc: Any                 # the config's crack section
    solver: Any             # step.StepContext: the solver's stencil and material funcs
    lower: Any              # ti.Vector: the domain's lower corner
    radius: float           # SPH support radius r
    inv_r: float
    radius2: float
    radius2_cut: float      # a cheap d2 test before sqrt(d2) < r: never drops a neighbour
    inv_cell: float         # cell list cells per unit length
    thr: float              # crack.threshold, damage_threshold, gradient_threshold
    dthr: float
    gthr: float
    contact_thr: float      # particles facing each other for contact: never merely non-aligned ones
    contact: bool           # crack.contact_in_compression
    rows: list              # a neighbour search (reach r) walks rows of cells along the last axis
    nbr: list               # the 5^d block of cells around a cell
    # the contact list's search: as far as two particles can come closer until the next refresh (each moves at
    # most skin / 2 from where the normals were computed, so 2 skin from where the list is built)
    wide_span: int
    wide_reach2: float
    rows_wide: list
    wide2: float
    friction_lost: Any      # sums.Slots(1): the energy friction dissipated (crack.friction), or None
    pair_mu: Any = None     # with crack.friction_pairs: (sides, sides) coefficients between interface bodies


def crack_context(fields, view, cc, kernel_ctx, friction_lost=None, pair_mu=None) -> CrackContext:
    dim, radius = fields.dim, fields.radius
    radius2 = radius * radius
    inv_cell = CELL_SPLIT / radius
    nbr = [(-CELL_SPLIT, CELL_SPLIT + 1)] * dim
    wide_cells = CELL_SPLIT * (1.0 + 2.0 * float(cc.normal_refresh))
    wide_span = int(math.ceil(wide_cells))
    thr = float(cc.threshold)
    return CrackContext(fields=fields, view=view, cc=cc, solver=kernel_ctx, lower=ti.Vector(view.lower.tolist()),
                        radius=radius, inv_r=1.0 / radius, radius2=radius2, radius2_cut=radius2 * (1 + 1e-4),
                        inv_cell=inv_cell, thr=thr, dthr=float(cc.damage_threshold),
                        gthr=float(cc.gradient_threshold), contact_thr=max(thr, 0.0),
                        contact=bool(cc.contact_in_compression), rows=nbr[:-1], nbr=nbr, wide_span=wide_span,
                        wide_reach2=wide_cells * wide_cells, rows_wide=[(-wide_span, wide_span + 1)] * (dim - 1),
                        wide2=(wide_cells / inv_cell) ** 2 * (1 + 1e-4), friction_lost=friction_lost,
                        pair_mu=pair_mu)
