"""ddmp's gradient in a particle's tensor stencil: the per-axis arrays and the gradient at a node that
stencils._tensor_stencil takes for ddmp only.

Plain ddmp: linear weights with the gradient blended with its dual-domain average (shape_functions.make_ddmp),

    grad_a S_i = alpha dN_a prod_{b != a} N_b + (1 - alpha) Ds_a prod_{b != a} Ns_b,   alpha = prod_b 4 t_b (1 - t_b),

moved to the linear gradient where a dual domain of the stencil is partly empty: alpha_p = max(alpha_p, 1 - min fill).

With sub-points (solver.ddmp.sub_points; the idea of Dhakal & Zhang 2016, "dual domain material point method with
sub-points", J. Comput. Phys. 325): every function of the particle is averaged over two sub-points per axis, so that
the particles' quadrature of the force converges where one point per particle stalls (docs/bases.md, "DDMP's
sub-points"). Along axis a they lie at u -+ d, d = lp |F_aa| / 2 (grid units, lp the particle's initial half-width):
the centres of the two halves of its domain stretched by F_aa, at most half a cell and cut at the walls so that the
pair stays symmetric about u (then sum_i S_i x_i = x_p). The shear of F is not followed: the sub-points of an axis
keep that axis's coordinate. The weights are the mean of the linear weights at the sub-points, and the gradient the
mean of ddmp's: with alpha = prod_b alpha_b expanded, the gradient at a point is a sum of three products of per-axis
factors,

    grad_a S_i = (alpha_a dN_a) prod (alpha_b N_b) - (alpha_a Ds_a) prod (alpha_b Ns_b) + Ds_a prod Ns_b,

and its mean over the 2^d sub-points of a tensor pattern is the same sum with every per-axis factor replaced by its
mean over the axis's two sub-points (exact: the mean of a product of independent factors). Where a dual domain of the
stencil is partly empty the mean linear gradient mean(dN_a) prod mean(N_b) takes over by the particle's fill blend
beta = 1 - min(1, fill / 0.9) (plain ddmp: 1 - min fill). It touches only the nodes the particle's own weights give
mass to: with the weights at the particle itself instead, a sub-point in the cell beyond a free surface sent force
to a node without mass and momentum was lost (measured); with the particle's own linear gradient as the fallback,
the surface particles kept linear's cell-crossing error (2D free-surface MMS at dx 1/64: 1.20e-3 against 5.1e-4).
Each sub-point's weights sum to 1 and its gradient to 0, and sum_i x_i (x) grad S_i = I, so their means and the blend
keep these (momentum; a linear velocity's exact gradient). The two sub-points can lie in neighbouring cells: the
stencil starts at the left one's cell and is one node wider than ddmp's (5 per axis).

Physics code only: no CLI, rendering or file I/O here.
"""

from typing import Callable, NamedTuple

import taichi as ti

from .. import traced

FACTORS = 5   # sub-points: the per-axis means kept besides Ds's (alpha N, alpha dN, alpha Ns, alpha Ds, Ns)
FULL = 0.9    # sub-points: a stencil whose dual domains are all filled this much keeps the whole mean (see blend)


class DdmpParts(NamedTuple):
    width: int          # entries per axis of the smoothed arrays WS
    axis: Callable      # (p, a, uw, b, W, DW, R) -> (base_a, W, DW, R, WS, DS, alpha_a): axis a's arrays
    blend: Callable     # (alpha, base, with_fill) -> the particle's weight of the linear gradient
    factors: Callable   # (WS, o, pick) -> what `gradient` reads of every axis at node o
    # (g, a, o, pick, DW, factors, DS, alpha) -> grad_a S_i at node o (g: dN_a times the other axes' weights)
    gradient: Callable


def ddmp_parts(basis, axes, n_cells, S, dx, half_width, F, fill) -> DdmpParts:
    """The plain blend, or the sub-points' (basis.sub_points). S: the stencil's nodes per axis."""
    if basis.sub_points:
        return _sub_point_parts(basis, axes, n_cells, S, dx, half_width, F, fill)
    inv_dx = 1.0 / dx

    def axis(p, a, uw, b, W, DW, R):
        ws, ds, al = (traced.local(v) for v in basis.smooth_1d(uw, n_cells[a]))
        return (b, W, DW, R, [traced.at(ws, k) for k in range(S)], [traced.at(ds, k) * inv_dx for k in range(S)],
                al)

    def blend(alpha, base, with_fill):
        return ti.max(alpha, 1.0 - fill(base)) if with_fill else alpha

    def factors(WS, o, pick):
        return WS

    def gradient(g, a, o, pick, DW, WS, DS, alpha):
        gs = pick(DS, a, o[a])
        for b in range(len(o)):
            if b != a:
                gs = gs * pick(WS, b, o[b])
        return alpha * g + (1.0 - alpha) * gs

    return DdmpParts(S, axis, blend, factors, gradient)


def _place(S, vec, shift):
    """A 4-entry list starting at the stencil's base + shift (0 or 1), as S entries."""
    return [traced.select(shift == 0, vec[k] if k < S - 1 else 0.0, vec[k - 1] if k >= 1 else 0.0) for k in range(S)]


def _entries(vec, n, scale=1.0):
    return [traced.at(vec, k) * scale for k in range(n)]


def _mean(lo, hi, c_lo=1.0, c_hi=1.0):
    return [0.5 * (c_lo * u + c_hi * v) for u, v in zip(lo, hi)]


def _sub_point_pair(half_width, F, n_cells):
    """(p, a, uw) -> the sub-points' coordinates along axis a (grid units; uw inside the domain). The half-width
    follows |F_aa|, as gimp's deforming domains do (solver.gimp_domain): a rotated particle's pair draws together
    (at a quarter turn it coincides: plain ddmp's quadrature for that particle)."""
    def pair(p, a, uw):
        n = n_cells[a]
        d = ti.min(0.5 * half_width(p) * ti.abs(traced.at(traced.at(F, p), a, a)), 0.5)
        d = traced.local(ti.min(d, uw, n - uw))   # symmetric about uw at the walls too
        return traced.local(uw - d), traced.local(uw + d)
    return pair


def _sub_point_linear(axes, n_cells, pair):
    """(p, a, uw) -> (the left sub-point's cell, the right one's cell minus it, (w, dw) at the left one, (w, dw) at
    the right one): the linear 1D functions at the two sub-points of axis a."""
    def linear(p, a, uw):
        um, up = pair(p, a, uw)
        bm, nm, dnm = (traced.local(v) for v in axes[a].weights_1d(um, n_cells[a], 0.0))
        bp, np_, dnp = (traced.local(v) for v in axes[a].weights_1d(up, n_cells[a], 0.0))
        return bm, traced.local(bp - bm), (nm, dnm), (np_, dnp), um, up
    return linear


def volume_weights(basis, axes, n_cells, S, half_width, F):
    """(p, a, u) -> (first node, S weights): how the nodal-volume pre-pass spreads a particle's volume along axis a,
    as its mass goes: its linear weights at u, or with sub-points their mean (u in grid units)."""
    if not basis.sub_points:
        @traced.traced
        def own(p, a, u):
            b, w, _ = axes[a].weights_1d(u, n_cells[a], 0.0)
            return b, _entries(w, S)
        return own
    linear = _sub_point_linear(axes, n_cells, _sub_point_pair(half_width, F, n_cells))

    @traced.traced
    def sub(p, a, u):
        uw = traced.local(ti.min(ti.max(u, 0.0), ti.cast(n_cells[a], float)))
        bm, shift, (nm, _), (np_, _), _, _ = linear(p, a, uw)
        return bm, _mean(_place(S, _entries(nm, S - 1), 0), _place(S, _entries(np_, S - 1), shift))
    return sub


def _sub_point_parts(basis, axes, n_cells, S, dx, half_width, F, fill) -> DdmpParts:
    """axis: S-entry lists over the nodes from the left sub-point's cell: W and DW the mean linear weights and
    derivatives, R the node offsets, WS the FACTORS means side by side, DS the mean Ds."""
    inv_dx = 1.0 / dx
    linear = _sub_point_linear(axes, n_cells, _sub_point_pair(half_width, F, n_cells))

    def place(vec, shift, scale=1.0):
        return _place(S, _entries(vec, S - 1, scale), shift)

    def axis(p, a, uw, b, W, DW, R):
        n = n_cells[a]
        bm, shift, (nm, dnm), (np_, dnp), um, up = linear(p, a, uw)
        sm, dsm, am = (traced.local(v) for v in basis.smooth_1d(um, n))
        sp, dsp, ap = (traced.local(v) for v in basis.smooth_1d(up, n))
        N = (place(nm, 0), place(np_, shift))
        dN = (place(dnm, 0, inv_dx), place(dnp, shift, inv_dx))
        Ns = (place(sm, 0), place(sp, shift))
        Ds = (place(dsm, 0, inv_dx), place(dsp, shift, inv_dx))
        means = [_mean(*N, am, ap), _mean(*dN, am, ap), _mean(*Ns, am, ap), _mean(*Ds, am, ap), _mean(*Ns)]
        R = [(axes[a].coord(bm + k, n) - uw) * dx for k in range(S)]
        return bm, _mean(*N), _mean(*dN), R, sum(means, []), _mean(*Ds), 1.0

    def blend(alpha, base, with_fill):
        """beta = 1 - min(1, fill / FULL): 1 where a node of the stencil is empty (no force to a node without
        mass), 0 where every dual domain is at least 0.9 full. Inside a body the fill departs from 1 only by the
        particles' quadrature of the node volumes (a few per cent as they move), which `1 - fill` turned into a
        share of the linear gradient's cell-crossing error: 1D G = 0.05 at 256 cells 9.46e-6 against 5.07e-6."""
        return 1.0 - ti.min(fill(base) / FULL, 1.0) if with_fill else 0.0

    def factors(WS, o, pick):
        return [[traced.local(pick(WS, b, o[b], j * S)) for j in range(FACTORS)] for b in range(len(o))]

    def gradient(g, a, o, pick, DW, blocks, DS, beta):
        """The mean of the sub-points' gradients at a node blended with their mean linear one, g (module docstring):
        blocks[b] holds axis b's means there."""
        g1, g2, g3 = blocks[a][1], blocks[a][3], pick(DS, a, o[a])
        for b in range(len(blocks)):
            if b != a:
                g1 = g1 * blocks[b][0]
                g2 = g2 * blocks[b][2]
                g3 = g3 * blocks[b][4]
        return (1.0 - beta) * (g1 - g2 + g3) + beta * g

    return DdmpParts(S * FACTORS, axis, blend, factors, gradient)
