"""The kernels of one step, built from a step context (context.StepContext) by small factories, one job each:

    features.py      Features: the scene's compile-time switches (a frozen description)
    context.py       StepContext: what the builders receive (stencil_parts.KernelContext plus the solver's own fields)
    affine.py        APIC's affine part and the velocity gradient a particle carries
    materials.py     the per-material dispatch (written once) and the material funcs: stress, energy, ...
    transfers.py     P2G, G2P, MUSL's momentum remap; the F update and the particle checks
    xpic.py          XPIC(m)'s grid passes (v*, order by order)
    grid_update.py   the grid solve: node velocities, gravity, the extensions' accelerations and conditions
    diagnostics.py   energies, momenta, body moments, stresses, volume ratios
    moments.py       the extension protocol: Extension and its moments, Setup, the contributions extensions make
                     to the kernels (ParticleTransfer, Degradation, GridSolve)
    extensions.py    the ordered list of extensions (taichi_mpm/extensions/: ddmp pre-pass, coloured scatter,
                     mapped coordinates, F-bar, crack finder, tractions, walls, grips) and `register`

`make_funcs` builds the funcs the extensions' kernel builders read from the context; `make_kernels` the solver's
kernels, once the extensions have added their contributions to the context (their `build` moment).

Physics code only: no CLI, rendering or file I/O here.
"""

from dataclasses import dataclass

from .affine import AffineFuncs, make_affine
from .context import StepContext
from .diagnostics import make_diagnostics
from .features import Features
from .grid_update import make_gravity_kick, make_grid_update
from .materials import MaterialFuncs, make_material_funcs
from .transfers import make_add, make_external_force, make_g2p, make_p2g
from .xpic import make_xpic

__all__ = ["Features", "StepContext", "StepFuncs", "make_funcs", "make_gravity_kick", "make_kernels"]


@dataclass
class StepFuncs:
    affine: AffineFuncs
    materials: MaterialFuncs


def make_funcs(ctx: StepContext) -> StepFuncs:
    """The affine and material funcs; sets the context's density, kirchhoff, project and add."""
    af = make_affine(ctx)
    mf = make_material_funcs(ctx, af.velocity_gradient)
    ctx.density, ctx.kirchhoff, ctx.add = mf.density, mf.kirchhoff, make_add(ctx.bins is not None)
    ctx.project = mf.project
    return StepFuncs(af, mf)


def make_kernels(ctx: StepContext, funcs: StepFuncs) -> dict:
    """name -> kernel: p2g, p2g_momentum, grid_update, grid_remap, grid_velocity, g2p, energies, momenta,
    body_moments, cauchy_stress, volume_ratios (and XPIC's passes)."""
    af, mf = funcs.affine, funcs.materials
    external_force = make_external_force(ctx, mf)
    kernels = {}
    kernels.update(make_p2g(ctx, mf, af, external_force))
    kernels.update(make_grid_update(ctx))
    kernels.update(make_g2p(ctx, mf, af, external_force))
    kernels.update(make_diagnostics(ctx, mf, af))
    if ctx.feat.xpic:
        kernels.update(make_xpic(ctx, mf))
    return kernels
