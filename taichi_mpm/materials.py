"""Constitutive models: each is a Kirchhoff stress tau(F) = P F^T and a strain energy density psi(F).

Adding a model means writing two `@ti.func`s and one registry line. The solver computes nodal
forces as f_i = -sum_p V0_p tau_p grad w_ip, which is -sum_p V0_p P_p grad_X w_ip.
`L` is the particle's velocity gradient (only fluids with viscosity read it).

Every model is written for any dimension d, and a d-dimensional state is the 3D state with the missing
axes held fixed: 2D is plane strain (F_zz = 1, no velocity along z), 1D is uniaxial strain (F_yy = F_zz = 1).
So the full 3x3 stress of a 1D or 2D particle, out-of-plane normal stresses included, is the model's own
3D stress at `embed3(F, 1)` (with `embed3(L, 0)`); its in-plane block equals the d-dimensional stress.
"""

from dataclasses import dataclass
from typing import Callable

import numpy as np
import taichi as ti


@dataclass(frozen=True)
class Model:
    name: str
    kirchhoff: Callable   # @ti.func (F, L, mu, lam, visc) -> tau
    energy: Callable      # @ti.func (F, mu, lam) -> psi per reference volume
    fluid: bool = False   # F is reset to J^(1/d) I after each update (no shear memory)


MODELS: dict[str, Model] = {}


def register(name, fluid=False):
    def wrap(cls):
        MODELS[name] = Model(name, cls.kirchhoff, cls.energy, fluid)
        return cls
    return wrap


@ti.func
def embed3(A, fill):
    """The 3x3 matrix with A (d x d) in its upper-left block and `fill` on the rest of the diagonal: F or L of a
    plane-strain (2D) or uniaxial-strain (1D) state as a 3D tensor (fill 1 for F, 0 for L)."""
    out = ti.Matrix.identity(float, 3) * fill
    for a, b in ti.static(ti.ndrange(A.n, A.n)):
        out[a, b] = A[a, b]
    return out


POLAR_ITERATIONS = 8  # scaled Newton: quadratic convergence; 8 reach f64 round-off for stretches up to ~1e3


@ti.func
def rotation(F):
    """Rotation of the polar decomposition F = R S (J > 0; 1D: the identity).

    2D: Taichi's closed form. 3D: Newton's iteration X <- (g X + X^-T / g) / 2 with determinant scaling
    g = |det X|^(-1/3) (Higham 1986), which costs a third of the SVD behind ti.polar_decompose."""
    R = ti.Matrix.identity(float, F.n)
    if ti.static(F.n == 2):
        R, _ = ti.polar_decompose(F)
    elif ti.static(F.n == 3):
        R = F
        for _ in range(POLAR_ITERATIONS):
            g = ti.pow(ti.abs(R.determinant()), -1.0 / 3.0)
            R = 0.5 * (g * R + R.inverse().transpose() / g)
    return R


@register("linear_elastic")
class LinearElastic:
    """Small strain: sigma = lam tr(eps) I + 2 mu eps, eps = sym(F) - I, taken as P (verification model)."""

    @ti.func
    def kirchhoff(F, L, mu, lam, visc):
        I = ti.Matrix.identity(float, F.n)
        eps = 0.5 * (F + F.transpose()) - I
        return (lam * eps.trace() * I + 2.0 * mu * eps) @ F.transpose()

    @ti.func
    def energy(F, mu, lam):
        eps = 0.5 * (F + F.transpose()) - ti.Matrix.identity(float, F.n)
        return mu * (eps * eps).sum() + 0.5 * lam * eps.trace() ** 2


@register("neo_hookean")
class NeoHookean:
    """psi = mu/2 (tr(F^T F) - d) - mu ln J + lam/2 (ln J)^2."""

    @ti.func
    def kirchhoff(F, L, mu, lam, visc):
        J = F.determinant()
        return mu * (F @ F.transpose() - ti.Matrix.identity(float, F.n)) + lam * ti.log(J) * ti.Matrix.identity(float, F.n)

    @ti.func
    def energy(F, mu, lam):
        J = F.determinant()
        return 0.5 * mu * ((F * F).sum() - F.n) - mu * ti.log(J) + 0.5 * lam * ti.log(J) ** 2


@register("fixed_corotated")
class FixedCorotated:
    """psi = mu |F - R|^2 + lam/2 (J - 1)^2 (Stomakhin et al. 2012)."""

    @ti.func
    def kirchhoff(F, L, mu, lam, visc):
        J = F.determinant()
        R = rotation(F)
        return 2.0 * mu * (F - R) @ F.transpose() + lam * (J - 1.0) * J * ti.Matrix.identity(float, F.n)

    @ti.func
    def energy(F, mu, lam):
        J = F.determinant()
        D = F - rotation(F)
        return mu * (D * D).sum() + 0.5 * lam * (J - 1.0) ** 2


@register("fluid", fluid=True)
class Fluid:
    """Weakly compressible: pressure K (1 - J), plus Newtonian viscosity visc (L + L^T). `lam` holds K."""

    @ti.func
    def kirchhoff(F, L, mu, lam, visc):
        J = F.determinant()
        tau = lam * (J - 1.0) * J * ti.Matrix.identity(float, F.n)
        if visc > 0:
            tau += J * visc * (L + L.transpose())
        return tau

    @ti.func
    def energy(F, mu, lam):
        return 0.5 * lam * (F.determinant() - 1.0) ** 2


def wave_speed(mat) -> float:
    """P-wave speed sqrt((lam + 2 mu) / rho) (sqrt(K / rho) for a fluid), for the CFL time step."""
    return float(np.sqrt((mat.lam + 2 * mat.mu) / mat.density))


# ---------------------------------------------------------------- damage law (crack growth, crack.py)
def rankine_params(mat, dx: float):
    """(E, eps0, eps_f) of the Rankine law with linear softening, or None when the material has no
    tensile_strength. The softening is regularised by the grid spacing (crack band, Bazant & Oh 1983):
    eps_f = 2 G_f / (f_t dx), so the energy dissipated per unit crack area is G_f at any dx.
    Without fracture_energy the material is brittle (damage jumps to 1 at f_t)."""
    if mat.tensile_strength is None or mat.model == "fluid":
        return None
    eps0 = mat.tensile_strength / mat.E
    eps_f = eps0 if mat.fracture_energy is None else 2.0 * mat.fracture_energy / (mat.tensile_strength * dx)
    if mat.fracture_energy is not None and eps_f <= eps0:
        from .errors import ConfigError
        raise ConfigError(f"fracture_energy {mat.fracture_energy:g} is too small for dx={dx:g}: softening would snap back; "
                          f"need fracture_energy > tensile_strength^2 dx / (2 E) = {mat.tensile_strength * eps0 * dx / 2:.4g}",
                          key="materials.fracture_energy")
    return (float(mat.E), float(eps0), float(eps_f))


@ti.func
def sym_eig(A):
    """Eigenvalues and eigenvectors (columns) of a symmetric 2x2 or 3x3 matrix by cyclic Jacobi rotations
    (ti.sym_eig in Taichi 1.7 returns NaN for some diagonal 2x2 matrices)."""
    n = ti.static(A.n)
    V = ti.Matrix.identity(float, n)
    M = A
    for _ in range(1 if n == 2 else 8):
        for pq in ti.static([(0, 1), (0, 2), (1, 2)] if n == 3 else [(0, 1)]):
            i, j = ti.static(pq[0], pq[1])
            if M[i, j] != 0:
                theta = (M[j, j] - M[i, i]) / (2.0 * M[i, j])
                t = 1.0 / (ti.abs(theta) + ti.sqrt(theta * theta + 1.0))
                if theta < 0:
                    t = -t
                c = 1.0 / ti.sqrt(t * t + 1.0)
                s = t * c
                J = ti.Matrix.identity(float, n)
                J[i, i] = c
                J[j, j] = c
                J[i, j] = s
                J[j, i] = -s
                M = J.transpose() @ M @ J
                V = V @ J
    ev = ti.Vector([M[k, k] for k in ti.static(range(n))])
    return ev, V


@ti.func
def rankine_damage(sigma, kappa, E, eps0, eps_f):
    """Rankine criterion with linear softening: kappa = max over time of (max principal stress / E);
    d = eps_f (kappa - eps0) / (kappa (eps_f - eps0)), so the stress (1 - d) E kappa falls linearly from
    f_t at eps0 to 0 at eps_f. Returns (d, kappa)."""
    ev, _ = sym_eig(0.5 * (sigma + sigma.transpose()))
    k = ti.max(kappa, ev.max() / E)
    d = 0.0
    if k > eps0:
        d = 1.0
        if eps_f > eps0:
            d = ti.min(1.0, eps_f * (k - eps0) / (k * (eps_f - eps0)))
    return d, k


@ti.func
def degrade_tension(tau, d):
    """Damaged stress: tensile principal stresses scaled by (1 - d), compressive ones kept, so a damaged
    particle still carries compression (closed cracks) but not tension."""
    sym = 0.5 * (tau + tau.transpose())
    ev, Q = sym_eig(sym)
    for k in ti.static(range(tau.n)):
        if ev[k] > 0:
            ev[k] *= 1.0 - d
    out = (1.0 - d) * (tau - sym)
    for k in ti.static(range(tau.n)):
        q = ti.Vector([Q[a, k] for a in ti.static(range(tau.n))])
        out += ev[k] * q.outer_product(q)
    return out
