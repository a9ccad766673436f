"""The gradient a transfer uses for the internal force in P2G and for the velocity gradient in G2P, as @ti.func
pieces the step's kernels call once per particle (`prepare`) and once per stencil node (`force`, `term`):

    grad w            the shape function's gradient (PIC, FLIP, APIC)
    w D_p^-1 r        MLS-MPM's, from the affine moment matrix D_p = sum w r r^T (r = x_i - x_p): the force and
                      the F update then use the same affine field as the momentum (Hu et al. 2018)

Physics code only: no CLI, rendering or file I/O here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import taichi as ti


@dataclass(frozen=True)
class Gradient:
    moment_matrix: bool   # the pieces read D_p^-1: `prepare` returns it, else a dummy the compiler removes
    prepare: Callable     # @ti.func (st) -> per-particle data for the other two
    force: Callable       # @ti.func (M, w, gw, r) -> the vector the stress multiplies in P2G: f_i = -V tau (this)
    term: Callable        # @ti.func (M, v_i, w, gw, r) -> node i's term of the velocity gradient sum in G2P
    finish: Callable      # @ti.func (M, G) -> the velocity gradient from the sum of the terms


def make_gradient(sten, moment_matrix: bool) -> Gradient:
    """sten: the context's stencil (its inertia_inverse gives D_p^-1)."""
    return _moment_gradient(sten) if moment_matrix else _shape_gradient()


def _shape_gradient() -> Gradient:
    """grad w itself; the unused per-particle value is removed by the compiler."""
    @ti.func
    def prepare(st):
        return 0.0

    @ti.func
    def force(M, w, gw, r):
        return gw

    @ti.func
    def term(M, vi, w, gw, r):
        return vi.outer_product(gw)

    @ti.func
    def finish(M, G):
        return G

    return Gradient(False, prepare, force, term, finish)


def _moment_gradient(sten) -> Gradient:
    """MLS-MPM: grad w_i ~ w_i D_p^-1 (x_i - x_p), exact for linear fields (sum w D^-1 r r^T = I)."""
    @ti.func
    def prepare(st):
        return sten.inertia_inverse(st)

    @ti.func
    def force(M, w, gw, r):
        return w * (M @ r)

    @ti.func
    def term(M, vi, w, gw, r):
        return w * vi.outer_product(r)

    @ti.func
    def finish(M, G):
        return G @ M

    return Gradient(True, prepare, force, term, finish)
