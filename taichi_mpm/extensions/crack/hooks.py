"""The crack finder's interface to the solver's kernels (what CrackFinder.build returns)."""

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class CrackHooks:
    """The @ti.funcs the solver's kernels call for particles near a discontinuity, and the kernels that replace
    the solver's grid update and MUSL remap (node mass is a tensor there). st: the particle's stencil data."""
    modified: Callable          # (p) -> the particle uses modified functions
    degrade: Callable           # (p, tau) -> damaged stress
    degrade_energy: Callable    # (p, F, psi, tau) -> damaged strain energy density
    p2g: Callable               # (p, st, mp, stress, vp, Ap, force_density, kick)
    p2g_momentum: Callable      # (p, st, mp, vp, Ap): MUSL's remap
    g2p: Callable               # (p, st, deform) -> (v_pic, FLIP increment, APIC B, velocity gradient)
    kernels: dict               # grid_update_tensor, grid_remap_tensor (the solver's own where no particle touches)
