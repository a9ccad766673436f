"""The per-material funcs of the step: the material models' stress, energy, volume ratio, viscous power and
return mapping for a particle, selected by its material (materials/: the model registry).

The selection is written once (`by_material`): a single-material scene compiles one model and stores no material
index; otherwise each particle branches on its index among the models, unrolled with `ti.static`.

Physics code only: no CLI, rendering or file I/O here.
"""

from dataclasses import dataclass
from typing import Callable

import taichi as ti

from .. import traced
from ..materials import embed3


@traced.traced
def _assign(out, value):
    """out = value, element by element for a tuple of results (a func's multiple returns)."""
    if isinstance(out, tuple):
        for o, v in zip(out, value):
            o._assign(v)
    else:
        out._assign(value)


def _constant(value):
    @traced.traced
    def constant():
        return value
    return constant


def by_material(mat, fns: list):
    """@ti.func (p, out: template, args: template): out = fns[k](*args) for particle p's material k; fns[k] None
    (a model without that method) leaves out as it was. out is a local variable or a tuple of them, args a tuple."""
    single = len(fns) == 1
    present = [fn is not None for fn in fns]

    @ti.func
    def select(p, out: ti.template(), args: ti.template()):
        for k in ti.static(range(len(fns))):
            if ti.static(present[k]):
                if ti.static(single):
                    _assign(out, fns[k](*args))
                elif mat[p] == k:
                    _assign(out, fns[k](*args))
    return select


def method(mat, builds: list, name: str):
    """by_material over a method of the models' funcs (materials.base.Funcs), e.g. "kirchhoff"."""
    return by_material(mat, [getattr(b, name) for b in builds])


def constant(mat, values: list):
    """by_material over per-material constants (None: out kept)."""
    return by_material(mat, [None if v is None else _constant(v) for v in values])


@dataclass
class MaterialFuncs:
    """@ti.funcs of particle p (F: a deformation gradient, not necessarily F[p])."""
    density: Callable            # (p) -> rho0
    is_fluid: Callable           # (p) -> 1 for a fluid (it keeps only J), else 0
    kirchhoff: Callable          # (p, F) -> the model's stress times its stiffness scale, plus the initial stress
    kirchhoff3: Callable         # (p) -> the full 3x3 Kirchhoff stress at F[p]
    strain_energy: Callable      # (p, F) -> stored energy per reference volume (model only)
    initial_energy: Callable     # (p, F) -> the initial stress's work S0 : E
    volume_ratio: Callable       # (p) -> current / initial volume
    viscous_power: Callable      # (p, F) -> viscous dissipation per reference volume and time
    project: Callable            # (p, F) -> F after the return mapping (writes the state, adds the dissipation)


def make_material_funcs(ctx, velocity_gradient) -> MaterialFuncs:
    """ctx: step.StepContext; velocity_gradient: @ti.func (p) -> grad v of the last step (viscous models)."""
    dim, mats, nq = ctx.dim, ctx.materials, ctx.n_state
    mat, F, vol0, state, stress0 = ctx.mat, ctx.F, ctx.vol0, ctx.state, ctx.stress0
    stiff, work = ctx.stiffness, ctx.work
    has_state, has_stress0, viscosity = state is not None, stress0 is not None, ctx.feat.viscosity
    single = len(mats) == 1
    density_of = constant(mat, [m.density for m in mats])
    fluid_of = constant(mat, [1 if m.fluid else None for m in mats])
    model_kirchhoff, model_kirchhoff3 = method(mat, mats, "kirchhoff"), method(mat, mats, "kirchhoff3")
    model_energy, model_volume_ratio = method(mat, mats, "energy"), method(mat, mats, "volume_ratio")
    model_viscous_power, model_project = method(mat, mats, "viscous_power"), method(mat, mats, "project")

    @ti.func
    def scale(p):
        """The material's stiffness scale (set_stiffness_scale: every stress parameter, moduli, yield stress,
        viscosity, scaled alike; 1 leaves it bit for bit as it was)."""
        s = stiff[0]
        if ti.static(not single):
            s = stiff[ti.cast(mat[p], ti.i32)]
        return s

    @ti.func
    def density(p):
        rho = 0.0
        density_of(p, rho, ())
        return rho

    @ti.func
    def is_fluid(p):
        # an int, set inside static branches: `res = False; res = ti.static(True)` stays False in Taichi 1.7,
        # which had left fluids keeping their shear F
        res = 0
        fluid_of(p, res, ())
        return res

    @ti.func
    def state_of(p):
        """The particle's material state vector (a dummy when no model of the scene has state)."""
        q = ti.Vector.zero(float, nq)
        if ti.static(has_state):
            q = state[p]
        return q

    @ti.func
    def grad_v(p):
        Lp = ti.Matrix.zero(float, dim, dim)
        if ti.static(viscosity):
            Lp = velocity_gradient(p)
        return Lp

    @ti.func
    def initial_kirchhoff(p, Fp):
        """bodies[].stress: a stored 2nd Piola-Kirchhoff stress S0 (the initial Cauchy stress, F = I at t = 0)
        added to the model's: tau = F S0 F^T, objective, with energy S0 : E (initial_energy). Zero without."""
        tau = ti.Matrix.zero(float, dim, dim)
        if ti.static(has_stress0):
            tau = Fp @ stress0[p] @ Fp.transpose()
        return tau

    @ti.func
    def initial_energy(p, Fp):
        """S0 : E with the Green-Lagrange strain E = (F^T F - I) / 2: the work of the stored stress."""
        psi = 0.0
        if ti.static(has_stress0):
            E = 0.5 * (Fp.transpose() @ Fp - ti.Matrix.identity(float, dim))
            psi = (stress0[p] * E).sum()
        return psi

    @ti.func
    def kirchhoff(p, Fp):
        Lp = grad_v(p)
        tau = ti.Matrix.zero(float, Fp.n, Fp.n)
        model_kirchhoff(p, tau, (Fp, Lp, state_of(p)))
        return scale(p) * tau + initial_kirchhoff(p, Fp)

    @ti.func
    def kirchhoff3(p):
        """The full 3x3 Kirchhoff stress: the 3D model at F with the missing axes held fixed (materials.embed3)."""
        Lp = grad_v(p)
        tau = ti.Matrix.zero(float, 3, 3)
        model_kirchhoff3(p, tau, (F[p], Lp, state_of(p)))
        return scale(p) * tau + embed3(initial_kirchhoff(p, F[p]), 0.0)

    @ti.func
    def strain_energy(p, Fp):
        psi = 0.0
        model_energy(p, psi, (Fp, state_of(p)))
        return scale(p) * psi

    @ti.func
    def volume_ratio(p):
        """Current / initial volume: det F, times J_p where the return mapping changes volume (materials/)."""
        J = F[p].determinant()
        if ti.static(has_state):
            model_volume_ratio(p, J, (F[p], state_of(p)))
        return J

    @ti.func
    def viscous_power(p, Fp):
        """Viscous dissipation per reference volume and time (the models' viscous_power, e.g. the fluid's)."""
        Lp = velocity_gradient(p)
        P = 0.0
        model_viscous_power(p, P, (Fp, Lp, state_of(p)))
        return scale(p) * P

    @ti.func
    def project(p, Fp):
        """After the F update: the model's return mapping (plastic models); writes the particle's state and adds
        its dissipation (the plastic work of the returned stress) to the plastic dissipation (work[2])."""
        q = state_of(p)
        diss = 0.0
        model_project(p, (Fp, q, diss), (Fp, q))
        # the return mapping is the same in strain space at any stiffness scale (yield stress and moduli scale
        # alike); the dissipated energy scales with the stress
        diss *= scale(p)
        if ti.static(has_state):
            state[p] = q
        work[2][None] += vol0[p] * diss
        return Fp

    return MaterialFuncs(density, is_fluid, kirchhoff, kirchhoff3, strain_energy, initial_energy, volume_ratio,
                         viscous_power, project)
