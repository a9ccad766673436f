"""PolyPIC's particle velocity field (schemes/polypic.py; Fu et al. 2017): in G2P the node velocities of the particle's
stencil are fitted, weighted by w_ip, with polynomial modes s_r(x - x_p) = prod_a phi_{r_a}(x_a - x_pa), where
phi_0..phi_p are each axis' polynomials orthogonal under the particle's 1D weights (Gram-Schmidt on the monomials):
c_r = sum w v_i s_r / sum w s_r^2, the modes being orthogonal under the tensor weights. P2G evaluates the particle's
polynomial at the offsets of the nodes it touches after the move. With every mode (per-axis degree <= p on a stencil
of p + 1 nodes) the fit interpolates the stencil's velocities; `total` keeps the modes of total degree <= p.

A particle keeps its modes' coefficients (poly_c: one row per mode) and each axis' orthogonal polynomials as their
monomial coefficients below the leading one (poly_g: phi_j = rho^j + sum_{l<j} g_jl rho^l).

Physics code only: no CLI, rendering or file I/O here.
"""
from dataclasses import dataclass
from typing import Callable

import taichi as ti

from ..schemes.polypic import lower_terms, modes


# A node with less than this fraction of a full node's mass (the particle's density times dx^d) gives the fit the
# particle's own last polynomial there, moved to its new v_p, instead of the node's velocity: a light node's
# velocity, momentum and the force's impulse over a small mass, is the least reliable value on the grid, and the top
# modes, which the fit weights toward the stencil's low-weight nodes, would carry it at full size into the next P2G.
# Measured (docs/transfers.md, "PolyPIC"): without it the stability map's impact blew up at step 68 and the
# compression from J = 0.5 at step 22; at 0.01 both finish and the a = 1 collapse keeps its run-out (1.371 L0 at
# L0/20 against 1.374 without); at 0.1 it lost a third of the gain over APIC (1.284; APIC 0.914).
FIT_MASS_FRACTION = 0.01

# The top modes (a per-axis degree of p, the basis' degree; quadratic and cubic only) are fitted with a ridge,
# c = sum w v s / (N + TOP_MODE_RIDGE / N) in place of / N (N = sum w s^2, in cells): a top mode lives on the
# stencil's low-weight nodes, and where the particle sits so that its norm nears zero (a quadratic's x^2 mode, 0.01
# cells from the position where the third node's weight vanishes), 1 / N carries one node's error into the next P2G
# without bound; the ridge bounds the gain at 1 / (2 sqrt(TOP_MODE_RIDGE)). Measured (docs/transfers.md, "PolyPIC"):
# without it the a = 10 collapse at L0/40 blew up as it came to rest (1 360 m/s; in two runs, at steps 30 031 and
# 30 032); with 1e-8, 1e-7 or 1e-6 it comes to rest; a wave the modes resolve loses 1e-4 of its amplitude in 100
# round trips at 1e-7 (1e-3 at 1e-6), and the sliding layer keeps 0.419 m/s at 0.1 s against 0.421 without (0.406
# at 1e-6).
TOP_MODE_RIDGE = 1e-7


@dataclass
class PolynomialFuncs:
    shift: Callable         # @ti.func (p, st) -> the constant that makes sum w f(r) = v_p at the particle's position
    velocity_at: Callable   # @ti.func (p, r, shift) -> the particle's velocity polynomial at offset r from it
    moment: Callable        # @ti.func (p, st) -> sum w f(r) r^T over its stencil (its modes' angular momentum / m)
    speed2: Callable        # @ti.func (p, st) -> sum w |f(r)|^2 over its stencil (twice its kinetic energy / m)
    make_record: Callable   # (read_v, density) -> @ti.func (p, st): fit the node velocities read_v(p, I) of the stencil


def make_axis_values(S: int):
    """@ti.func (G, a, rho) -> phi_0..phi_p of axis a at rho (cells), from poly_g's row a."""
    at = {t: i for i, t in enumerate(lower_terms(S - 1))}

    @ti.func
    def axis_values(G, a, rho):
        """phi_0..phi_p of axis a at rho."""
        phi = ti.Vector.zero(float, S)
        power = ti.Vector.zero(float, S)
        power[0] = 1.0
        for j in ti.static(range(1, S)):
            power[j] = power[j - 1] * rho
        for j in ti.static(range(S)):
            v = power[j]
            for l in ti.static(range(j)):
                v += G[a, at[(j, l)]] * power[l]
            phi[j] = v
        return phi
    return axis_values


def make_orthogonalise(dim: int, S: int, tiny: float):
    """@ti.func (W, R) -> (poly_g's coefficients, squared norms) of each axis' orthogonal polynomials."""
    terms = lower_terms(S - 1)
    n_terms = max(len(terms), 1)

    @ti.func
    def orthogonalise(W, R):
        """Each axis' polynomials orthogonal under its 1D weights W[a, k] at offsets R[a, k] (cells; Gram-Schmidt on
        1, rho, rho^2, ... by the weighted moments), as poly_g's coefficients, and their squared norms."""
        G = ti.Matrix.zero(float, dim, n_terms)
        N = ti.Matrix.zero(float, dim, S)
        for a in ti.static(range(dim)):
            mom = ti.Vector.zero(float, 2 * S - 1)   # sum w rho^k, k = 0 .. 2p
            for k in ti.static(range(S)):
                pw = W[a, k]
                for e in ti.static(range(2 * S - 1)):
                    mom[e] += pw
                    pw *= R[a, k]
            coef = ti.Matrix.zero(float, S, S)   # row j: phi_j's monomial coefficients
            for j in ti.static(range(S)):
                coef[j, j] = 1.0
                for i in ti.static(range(j)):   # subtract the projection of rho^j on phi_i
                    dot = 0.0
                    for l in ti.static(range(i + 1)):
                        dot += coef[i, l] * mom[j + l]
                    f = 0.0
                    if N[a, i] > tiny:
                        f = dot / N[a, i]
                    for l in ti.static(range(i + 1)):
                        coef[j, l] -= f * coef[i, l]
                norm = 0.0
                for k, l in ti.static(ti.ndrange(j + 1, j + 1)):
                    norm += coef[j, k] * coef[j, l] * mom[k + l]
                N[a, j] = norm
            for t in ti.static(range(len(terms))):
                G[a, t] = coef[terms[t][0], terms[t][1]]
        return G, N
    return orthogonalise


def make_polynomial(ctx, poly_c, poly_g, which: str) -> PolynomialFuncs:
    """poly_c: per particle (modes, d) coefficients; poly_g: per particle (d, len(lower_terms)) axis polynomials."""
    dim, S, sten, inv_dx, v, gm = ctx.dim, ctx.basis.stencil, ctx.stencil, 1.0 / ctx.dx, ctx.v, ctx.gm
    cell = ctx.dx ** dim
    mode_list = modes(dim, S - 1, which)
    n_nodes, n_modes = S ** dim, len(mode_list)
    tiny = 1e-12 if ctx.precision == "f64" else 1e-6   # a norm below this (in cells) is a mode the weights lack
    top = [S > 2 and max(k) == S - 1 for k in mode_list]   # in Python: Taichi scope's max is another function
    axis_values = make_axis_values(S)
    orthogonalise = make_orthogonalise(dim, S, tiny)

    @ti.func
    def node_offset(n):
        """Stencil node n's offset, the first axis fastest."""
        off = ti.Vector.zero(int, dim)
        q = n
        for a in ti.static(range(dim)):
            off[a] = q % S
            q //= S
        return off

    @ti.func
    def mode_values(T):
        """Each mode's value from per-axis tables T[a, j] (phi_j on axis a): prod_a T[a, r_a]."""
        out = ti.Vector.zero(float, n_modes)
        for m in ti.static(range(n_modes)):
            s = T[0, mode_list[m][0]]
            for a in ti.static(range(1, dim)):
                s *= T[a, mode_list[m][a]]
            out[m] = s
        return out

    @ti.func
    def axis_table(G, r):
        """phi_j(r_a / dx) of every axis a."""
        T = ti.Matrix.zero(float, dim, S)
        for a in ti.static(range(dim)):
            phi = axis_values(G, a, r[a] * inv_dx)
            for j in ti.static(range(S)):
                T[a, j] = phi[j]
        return T

    @ti.func
    def evaluate(C, G, r):
        """The polynomial of coefficients C and axis polynomials G at offset r (m)."""
        return C.transpose() @ mode_values(axis_table(G, r))

    @ti.func
    def shift(p, st):
        """v_p - sum w f(r) over the stencil, by each axis' weighted sums of its polynomials (the tensor weights
        factor). Round-off inside the domain, where uniform B-splines of degree p give every polynomial of degree
        <= p the same weighted sums wherever the particle is; beside a wall the open knot vector's splines do not, and
        without it the particle's P2G momentum would differ from m v_p there."""
        W, R = st[1], st[3]   # the tensor stencil's 1D weights and node offsets per axis
        G = poly_g[p]
        T = ti.Matrix.zero(float, dim, S)
        for k in ti.static(range(S)):
            Tk = axis_table(G, R[:, k])
            for a, j in ti.static(ti.ndrange(dim, S)):
                T[a, j] += W[a, k] * Tk[a, j]
        return v[p] - poly_c[p].transpose() @ mode_values(T)

    @ti.func
    def velocity_at(p, r, offset):
        return evaluate(poly_c[p], poly_g[p], r) + offset

    def make_record(read_v, density):
        @ti.func
        def record(p, st):
            G, N = orthogonalise(st[1], st[3] * inv_dx)   # the tensor stencil's 1D weights and offsets per axis
            C = ti.Matrix.zero(float, n_modes, dim)
            light = FIT_MASS_FRACTION * density(p) * cell   # a node lighter than this: the particle's own field
            C_old, G_old, offset = poly_c[p], poly_g[p], shift(p, st)   # (v_p is the new one already)
            for n in range(n_nodes):   # at run time: unrolled, 3D quadratic compiled for 319 s against 6 s
                I, w, _, r = sten.node(st, node_offset(n))
                vi = read_v(p, I)
                if gm[I] < light:
                    vi = evaluate(C_old, G_old, r) + offset
                C += (w * mode_values(axis_table(G, r))).outer_product(vi)
            norms = mode_values(N)
            for m in ti.static(range(n_modes)):
                scale = 0.0
                if ti.static(top[m]):
                    scale = norms[m] / (norms[m] ** 2 + TOP_MODE_RIDGE)
                elif norms[m] > tiny ** dim:
                    scale = 1.0 / norms[m]
                for b in ti.static(range(dim)):
                    C[m, b] *= scale
            poly_c[p] = C
            poly_g[p] = G
        return record

    moment, speed2 = make_stencil_sums(dim, sten, n_nodes, node_offset, poly_c, poly_g, evaluate, shift)
    return PolynomialFuncs(shift, velocity_at, moment, speed2, make_record)


def make_stencil_sums(dim, sten, n_nodes, node_offset, poly_c, poly_g, evaluate, shift):
    """The diagnostics' sums over a particle's stencil of what P2G maps: moment(p, st) = sum w f(r) r^T and
    speed2(p, st) = sum w |f(r)|^2."""
    @ti.func
    def moment(p, st):
        """Its modes' angular momentum per unit mass, eps : this (step/diagnostics.py)."""
        B = ti.Matrix.zero(float, dim, dim)
        C, G, offset = poly_c[p], poly_g[p], shift(p, st)
        for n in range(n_nodes):
            _, w, _, r = sten.node(st, node_offset(n))
            B += w * (evaluate(C, G, r) + offset).outer_product(r)
        return B

    @ti.func
    def speed2(p, st):
        """The kinetic energy P2G maps (per unit mass, doubled): at least |v_p|^2, the rest in the higher modes. A
        G2P fit, a weighted least-squares projection, never raises it above the grid's."""
        out = 0.0
        C, G, offset = poly_c[p], poly_g[p], shift(p, st)
        for n in range(n_nodes):
            _, w, _, r = sten.node(st, node_offset(n))
            out += w * (evaluate(C, G, r) + offset).norm_sqr()
        return out
    return moment, speed2
