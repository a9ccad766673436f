"""Diagnostics over the particles: energies, linear and angular momenta, per-body moments (the fracture check),
Cauchy stresses and volume ratios. Sums go through sums.ChunkSums: each chunk of particles summed in order into
its own row, no atomics, so the totals have the same bits for any thread count (see sums.py).

Physics code only: no CLI, rendering or file I/O here.
"""

import taichi as ti

from ..materials.tensor import rotation


def make_diagnostics(ctx, mf, af):
    """Kernels energies(), momenta(), body_moments(), cauchy_stress(out), volume_ratios(out)."""
    dim, x, v, F, vol0 = ctx.dim, ctx.x, ctx.v, ctx.F, ctx.vol0
    gravity, dg = ctx.gravity, ctx.degradation
    acc, moments, body_id = ctx.diag, ctx.moments, ctx.body_id
    n_moments = moments.shape[1]
    degraded, carried = dg is not None, ctx.feat.apic or af.polynomial is not None
    speed2, spin = af.speed2, af.spin
    has_stress0, has_body_id = ctx.stress0 is not None, body_id is not None
    density, kirchhoff, kirchhoff3 = mf.density, mf.kirchhoff, mf.kirchhoff3
    strain_energy, initial_energy, volume_ratio = mf.strain_energy, mf.initial_energy, mf.volume_ratio

    work = ctx.work

    @ti.kernel
    def energies(rows: ti.types.ndarray(), work_out: ti.types.ndarray()):
        """Kinetic, strain (degraded where damaged), gravity potential; slot 3: sum m |g| |x| (the
        potential's round-off scale); slot 4: the initial stress's energy. Hands the chunks' rows and the work
        slots (sums.Slots) to the host in the same launch: rows (chunks, slots), work_out (work slots,)."""
        for c in range(acc.chunks):
            acc.clear(c)
            for p in range(acc.begin(c), acc.end(c)):
                mp = density(p) * vol0[p]
                psi = strain_energy(p, F[p])
                if ti.static(has_stress0):
                    acc.add(c, 4, vol0[p] * initial_energy(p, F[p]))  # apart: it can be negative
                if ti.static(degraded):
                    psi = dg.energy(p, F[p], psi, kirchhoff(p, F[p]))
                acc.add(c, 0, 0.5 * mp * speed2(p))
                acc.add(c, 1, vol0[p] * psi)
                acc.add(c, 2, -mp * gravity[None].dot(x[p]))
                acc.add(c, 3, mp * gravity[None].norm() * x[p].norm())
        acc.copy_rows(rows)
        for k in ti.static(range(work.shape[0])):
            work_out[k] = work[k][None]

    @ti.kernel
    def body_moments():
        """Per body: mass, first and second moments of position, the mass-weighted stretch U = R^T F of F's polar
        decomposition (the fracture check: rotation-free, so that a body bent or twisted, its rotations varying
        over it, is not taken for one that shrank)."""
        for c in range(moments.chunks):
            moments.clear(c)
            for p in range(moments.begin(c), moments.end(c)):
                b = 0
                if ti.static(has_body_id):
                    b = body_id[p]
                row = b * n_moments
                mp = density(p) * vol0[p]
                U = rotation(F[p]).transpose() @ F[p]
                moments.add(c, row, mp)
                for a in ti.static(range(dim)):
                    moments.add(c, row + 1 + a, mp * x[p][a])
                    for e in ti.static(range(dim)):
                        moments.add(c, row + 1 + dim + a * dim + e, mp * x[p][a] * x[p][e])
                        moments.add(c, row + 1 + dim + dim * dim + a * dim + e, mp * U[a, e])

    @ti.func
    def angular_momentum(p, mp):
        """m x_p x v_p about the origin, plus APIC's affine part or polypic's modes (3 components): the angular
        momentum P2G maps, m sum w x_i x v(x_i)."""
        x3 = ti.Vector.zero(float, 3)
        v3 = ti.Vector.zero(float, 3)
        for a in ti.static(range(dim)):
            x3[a] = x[p][a]
            v3[a] = v[p][a]
        Lp = mp * x3.cross(v3)
        if ti.static(carried):
            B = spin(p)
            B3 = ti.Matrix.zero(float, 3, 3)
            for a, b in ti.static(ti.ndrange(dim, dim)):
                B3[a, b] = B[a, b]
            Lp += mp * ti.Vector([B3[2, 1] - B3[1, 2], B3[0, 2] - B3[2, 0], B3[1, 0] - B3[0, 1]])
        return Lp

    @ti.kernel
    def momenta():
        """Linear momentum (dim) and angular momentum about the origin (3), APIC's affine part (polypic's modes)
        included."""
        for c in range(acc.chunks):
            acc.clear(c)
            for p in range(acc.begin(c), acc.end(c)):
                mp = density(p) * vol0[p]
                for a in ti.static(range(dim)):
                    acc.add(c, a, mp * v[p][a])
                if ti.static(dim > 1):
                    Lp = angular_momentum(p, mp)
                    for a in ti.static(range(3)):
                        acc.add(c, dim + a, Lp[a])

    @ti.kernel
    def cauchy_stress(out: ti.types.ndarray()):
        """(N, 3, 3) Cauchy stress, out-of-plane normal stresses included (plane strain in 2D, uniaxial strain
        in 1D); the upper-left d x d block is the stress the step uses."""
        for p in x:
            tau = kirchhoff3(p) / volume_ratio(p)
            if ti.static(degraded):
                tau = dg.stress(p, tau)
            for a, b in ti.static(ti.ndrange(3, 3)):
                out[p, a, b] = tau[a, b]

    @ti.kernel
    def volume_ratios(out: ti.types.ndarray()):
        for p in x:
            out[p] = volume_ratio(p)

    return dict(energies=energies, momenta=momenta, body_moments=body_moments, cauchy_stress=cauchy_stress,
                volume_ratios=volume_ratios)
