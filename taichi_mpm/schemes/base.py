"""The transfer-scheme registry itself: `Scheme`, the declaration each scheme module registers, and the lookups
(package docstring: schemes/__init__.py)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional


@dataclass(frozen=True)
class Scheme:
    name: str
    summary: str                   # one line for the config reference, the GUI and the docs
    reference: str                 # where the scheme is from
    cost: str                      # what it costs beside PIC (the measured figures: docs/transfers.md)
    bases: Optional[tuple] = None  # the bases it works with; None: every basis
    parameters: tuple = ()         # solver.* keys it reads
    affine: bool = False           # carries APIC's affine part (the C field: B_p, or C_p for multilinear weights)
    keeps_old_grid: bool = False   # the grid keeps v before forces (FLIP's increment, XPIC's v)
    separating: bool = False       # ASFLIP: a FLIP part on APIC, and the position correction (solver.asflip)
    extended: bool = False         # XPIC: v_p = S (v_L - v + v*), v* to order solver.xpic_order (step/xpic.py)
    # the force and the velocity gradient through the affine moment matrix, w D_p^-1 (x_i - x_p), instead of
    # grad w (MLS-MPM; schemes/gradient.py)
    moment_gradient: bool = False


SCHEMES: dict[str, Scheme] = {}


def register(scheme: Scheme) -> Scheme:
    if scheme.name in SCHEMES:
        raise ValueError(f"transfer scheme {scheme.name!r} registered twice")
    SCHEMES[scheme.name] = scheme
    return scheme


def get(name: str) -> Scheme:
    return SCHEMES[name]


def names() -> tuple:
    """The registered transfers in registration order (PIC, FLIP, APIC, then the newer schemes)."""
    return tuple(SCHEMES)


def works_with(name: str, basis: str) -> bool:
    s = SCHEMES[name]
    return s.bases is None or basis in s.bases
