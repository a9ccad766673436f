"""The velocity field a particle carries besides v_p: APIC's affine part C_p, and the velocity gradient of the
last step that viscous stresses read: the particle's C field, or with an affine transfer its grad_v field (APIC's
C_p = B_p D_p^-1 is a least-squares fit of the grid velocities, not their gradient: a viscous stress read from it
does not dissipate what the grid's forces take out, measured 30 % apart in a Couette flow).

Physics code only: no CLI, rendering or file I/O here.
"""

from dataclasses import dataclass
from typing import Callable

import taichi as ti


@dataclass
class AffineFuncs:
    store_B: bool                 # the C field holds APIC's B_p (C_p = B_p D_p^-1 at the current position)
    affine: Callable              # @ti.func (p, st) -> C_p (zero without APIC)
    node_momentum: Callable       # @ti.func (vp, Ap, r) -> the particle velocity a node at offset r sees
    velocity_gradient: Callable   # @ti.func (p) -> grad v of the last step


def gradient_affine(ctx) -> bool:
    """The affine C_p is the velocity gradient sum v_i grad w^T, stored as is: TPIC (schemes/tpic.py) on every
    basis, APIC on multilinear weights (where it equals B_p D_p^-1)."""
    return ctx.feat.taylor or ctx.basis.apic_gradient


def make_affine(ctx) -> AffineFuncs:
    """ctx: step.StepContext with its stencil."""
    dim, C, sten, own = ctx.dim, ctx.C, ctx.stencil, ctx.grad_v
    has_own = own is not None
    apic = ctx.feat.apic
    store_B = apic and not gradient_affine(ctx)

    @ti.func
    def affine(p, st):
        """APIC's C_p at the particle's current position. Where D_p varies with position (GIMP, B-splines
        next to walls) the field stores B_p and C_p = B_p D_p^-1 uses the current D_p: the affine part's
        angular momentum, eps : B_p, is then carried exactly when the particle moves (Jiang et al. 2015)."""
        A = ti.Matrix.zero(float, dim, dim)
        if ti.static(store_B):
            A = C[p] @ sten.inertia_inverse(st)
        elif ti.static(apic):
            A = C[p]
        return A

    @ti.func
    def node_momentum(vp, Ap, r):
        """Particle velocity seen by a node at r = x_i - x_p: v_p, plus C_p r with APIC."""
        mom = vp
        if ti.static(apic):
            mom += Ap @ r
        return mom

    @ti.func
    def velocity_gradient(p):
        """grad v of the last step (viscosity reads it)."""
        L = ti.Matrix.zero(float, dim, dim)
        if ti.static(has_own):
            L = own[p]
        elif ti.static(store_B):
            L = affine(p, sten.at(p))
        else:
            L = C[p]
        return L

    return AffineFuncs(store_B, affine, node_momentum, velocity_gradient)
