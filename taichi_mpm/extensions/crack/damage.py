"""The damage law and what damage does to a particle: the Rankine law updates d_p from the undamaged stress each
step (with D_p = max(d_p, I_p)), and the damaged particle's stress and stored energy lose their tensile part."""

from typing import Callable, NamedTuple

import taichi as ti

from ...materials import degrade_tension, rankine_damage, sym_eig
from .constants import ALL, DRIFTED


class Damage(NamedTuple):
    effective_stress: Callable   # (p) -> undamaged Cauchy stress
    prepare: Callable            # kernel: the damage law, D, and whether the kept normals are due
    degrade: Callable            # (p, tau) -> damaged stress
    degrade_energy: Callable     # (p, F, psi, tau) -> damaged strain energy density


def damage_funcs(ctx) -> Damage:
    f, dim = ctx.fields, ctx.fields.dim
    x, F, mat, kirchhoff = ctx.view.x, ctx.view.F, ctx.solver.mat, ctx.solver.kirchhoff
    d_f, D, iface, kappa, cached, has_law = f.d, f.D, f.iface, f.kappa, f.cached, f.has_law
    x_ref, stale = (f.x_ref, f.stale) if cached else (None, None)
    moved2 = (0.5 * f.skin) ** 2   # a particle this far (squared) from where its normal was computed: refresh
    law_on = [law is not None for law in f.laws]
    laws = [law if law is not None else (1.0, 0.0, 0.0) for law in f.laws]
    single_mat = len(laws) == 1

    @ti.func
    def effective_stress(p):
        """Undamaged Cauchy stress of the particle (the damage law and the contact test read it)."""
        Fp = F[p]
        return kirchhoff(p, Fp) / Fp.determinant()

    @ti.kernel
    def prepare():
        """The damage law and D; whether the kept normals are due (raises `stale`)."""
        for p in x:
            if ti.static(has_law):
                sig = effective_stress(p)
                for k in ti.static(range(len(laws))):
                    if ti.static(law_on[k]):
                        hit = True
                        if ti.static(not single_mat):
                            hit = mat[p] == k
                        if hit:
                            dn, kap = rankine_damage(sig, kappa[p], laws[k][0], laws[k][1], laws[k][2])
                            kappa[p] = kap
                            if dn > d_f[p]:
                                d_f[p] = dn
                                if ti.static(cached):   # D grew: the normals move with it
                                    ti.atomic_max(stale[None], ALL)
            if ti.static(cached):
                if (x[p] - x_ref[p]).norm_sqr() > moved2:
                    ti.atomic_max(stale[None], DRIFTED)
            D[p] = ti.max(d_f[p], ti.cast(iface[p], float))

    @ti.func
    def degrade(p, tau):
        out = tau
        if d_f[p] > 0:
            out = degrade_tension(tau, d_f[p])
        return out

    @ti.func
    def degrade_energy(p, Fp, psi, tau):
        """Strain energy the damaged particle still stores: psi scaled by tau_d : eps / tau : eps with the
        Hencky strain eps = ln(V) (coaxial with tau for isotropic models). Isotropic damage gives (1 - d) psi,
        closed cracks (all principal stresses compressive) keep psi, matching `degrade`'s split; the rest was
        released by the damage law (a loss, which the solver's energy balance allows)."""
        out = psi
        if d_f[p] > 0:
            ev, Q = sym_eig(Fp @ Fp.transpose())
            eps = ti.Matrix.zero(float, dim, dim)
            for k in ti.static(range(dim)):
                q = ti.Vector([Q[a, k] for a in ti.static(range(dim))])
                eps += 0.5 * ti.log(ti.max(ev[k], 1e-30)) * q.outer_product(q)
            full = (tau * eps).sum()
            share = 1.0 - d_f[p]
            if full > 0:
                share = ti.min(ti.max((degrade_tension(tau, d_f[p]) * eps).sum() / full, 0.0), 1.0)
            out = psi * share
        return out

    return Damage(effective_stress=effective_stress, prepare=prepare, degrade=degrade, degrade_energy=degrade_energy)
