"""The velocity field a particle carries besides v_p: APIC's affine part C_p, and the velocity gradient of the
last step that viscous stresses read: the particle's C field, or with an affine transfer its grad_v field (APIC's
C_p = B_p D_p^-1 is a least-squares fit of the grid velocities, not their gradient: a viscous stress read from it
does not dissipate what the grid's forces take out, measured 30 % apart in a Couette flow).

Physics code only: no CLI, rendering or file I/O here.
"""

from dataclasses import dataclass
from typing import Callable, Optional

import taichi as ti

from .polynomial import PolynomialFuncs, make_polynomial


@dataclass
class AffineFuncs:
    store_B: bool                 # the C field holds APIC's B_p (C_p = B_p D_p^-1 at the current position)
    affine: Callable              # @ti.func (p, st) -> C_p (zero without APIC)
    node_momentum: Callable       # @ti.func (p, vp, Ap, r) -> the particle velocity a node at offset r sees
    velocity_gradient: Callable   # @ti.func (p) -> grad v of the last step
    spin: Callable                # @ti.func (p) -> B with eps : B the carried field's angular momentum per unit mass
    speed2: Callable              # @ti.func (p) -> twice the kinetic energy per unit mass P2G maps
    polynomial: Optional[PolynomialFuncs] = None   # polypic's velocity polynomial (step/polynomial.py), or None

    def make_fit(self, read_v, density) -> Callable:
        """@ti.func (p, st): what G2P keeps of the node velocities read_v(p, I) besides APIC's B_p: polypic's fit
        of the stencil (density(p): the material's, for its light nodes), nothing for the other transfers."""
        if self.polynomial is not None:
            return self.polynomial.make_record(read_v, density)

        @ti.func
        def nothing(p, st):
            pass
        return nothing


def gradient_affine(ctx) -> bool:
    """The affine C_p is the velocity gradient sum v_i grad w^T, stored as is: TPIC (schemes/tpic.py) on every
    basis, APIC on multilinear weights (where it equals B_p D_p^-1)."""
    return ctx.feat.taylor or ctx.basis.apic_gradient


def make_affine(ctx) -> AffineFuncs:
    """ctx: step.StepContext with its stencil."""
    dim, C, v, sten, own = ctx.dim, ctx.C, ctx.v, ctx.stencil, ctx.grad_v
    has_own = own is not None
    apic = ctx.feat.apic
    store_B = apic and not gradient_affine(ctx)
    poly = make_polynomial(ctx, *ctx.extra["polynomial"]) if ctx.feat.polynomial else None   # (poly_c, poly_g, modes)
    has_poly = poly is not None
    velocity_at = poly.velocity_at if has_poly else None

    @ti.func
    def affine(p, st):
        """APIC's C_p at the particle's current position. Where D_p varies with position (GIMP, B-splines
        next to walls) the field stores B_p and C_p = B_p D_p^-1 uses the current D_p: the affine part's
        angular momentum, eps : B_p, is then carried exactly when the particle moves (Jiang et al. 2015).
        polypic: its polynomial's constant shift at this position (polynomial.py), in column 0."""
        A = ti.Matrix.zero(float, dim, dim)
        if ti.static(has_poly):
            offset = poly.shift(p, st)
            for a in ti.static(range(dim)):
                A[a, 0] = offset[a]
        elif ti.static(store_B):
            A = C[p] @ sten.inertia_inverse(st)
        elif ti.static(apic):
            A = C[p]
        return A

    @ti.func
    def node_momentum(p, vp, Ap, r):
        """Particle velocity seen by a node at r = x_i - x_p: v_p, plus C_p r with APIC; polypic's polynomial."""
        mom = vp
        if ti.static(has_poly):
            mom = velocity_at(p, r, Ap[:, 0])
        elif ti.static(apic):
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

    @ti.func
    def spin(p):
        """APIC's B_p (sum w v_i r^T, stored or as C_p D_p), or polypic's sum w f(r) r^T: the angular momentum
        about x_p the affine part or the modes carry is m eps : B."""
        B = ti.Matrix.zero(float, dim, dim)
        if ti.static(has_poly):
            B = poly.moment(p, sten.at(p))
        elif ti.static(store_B):
            B = C[p]
        elif ti.static(apic):   # sum_i w (x_i - x_p) x C (x_i - x_p) = eps : (C D)^T
            B = C[p] @ sten.inertia(sten.at(p))
        return B

    @ti.func
    def speed2(p):
        """|v_p|^2, or with polypic sum w |f(r)|^2: the kinetic energy its higher modes carry counts too (APIC's
        affine part's is left out, as before)."""
        out = 0.0
        if ti.static(has_poly):
            out = poly.speed2(p, sten.at(p))
        else:
            out = v[p].norm_sqr()
        return out

    return AffineFuncs(store_B, affine, node_momentum, velocity_gradient, spin, speed2, poly)
