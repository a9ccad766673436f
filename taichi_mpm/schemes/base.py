"""The transfer-scheme registry itself: `Scheme`, the declaration each scheme module registers, and the lookups
(package docstring: schemes/__init__.py)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

from ..bases import registry as bases   # the bases' declarations (no Taichi)


@dataclass(frozen=True)
class Scheme:
    name: str
    summary: str                   # one line for the config reference, the GUI and the docs
    reference: str                 # where the scheme is from
    cost: str                      # what it costs beside PIC (the measured figures: docs/transfers.md)
    # the bases it works with, as a test of a basis' declaration (bases/registry.py's Spec); None: every basis
    basis_need: Optional[Callable] = None
    basis_why: str = ""            # what basis_need asks of a basis, for messages
    parameters: tuple = ()         # solver.* keys it reads
    accuracy: int = 1              # rank in advise's tie-break among equally cheap candidates (higher: preferred)
    affine: bool = False           # carries APIC's affine part (the C field: B_p, or C_p for multilinear weights)
    keeps_old_grid: bool = False   # the grid keeps v before forces (FLIP's increment, XPIC's v)
    separating: bool = False       # ASFLIP: a FLIP part on APIC, and the position correction (solver.asflip)
    extended: bool = False         # XPIC: v_p = S (v_L - v + v*), v* to order solver.xpic_order (step/xpic.py)
    grid_vectors: tuple = ()       # the node vectors it adds to the main grid beside v_old (layout.main_grid)
    # the force and the velocity gradient through the affine moment matrix, w D_p^-1 (x_i - x_p), instead of
    # grad w (MLS-MPM; schemes/gradient.py)
    moment_gradient: bool = False
    # TPIC: the affine part is the particle's velocity gradient sum v_i grad w^T (a Taylor expansion about x_p)
    # for every basis, not B_p D_p^-1 (multilinear weights use the gradient anyway: Stencil.apic_gradient)
    taylor: bool = False
    # PolyPIC: the particle carries a polynomial velocity fitted to its stencil's node velocities (the modes of
    # solver.polypic_modes), mapped to the nodes it touches next step (step/polynomial.py)
    polynomial: bool = False


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
    """Scheme `name` works with the registered basis `basis` (read from the basis' declaration, not its name)."""
    need = SCHEMES[name].basis_need
    return need is None or bool(need(bases.get(basis)))


def bases_for(name: str) -> tuple:
    """The registered bases scheme `name` works with, in registration order."""
    return tuple(b for b in bases.names() if works_with(name, b))
