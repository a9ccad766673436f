"""PolyPIC (Fu, Guo, Yang, Jiang & Teran 2017): the particle carries a polynomial velocity field in r = x - x_p, fitted
in G2P to its stencil's node velocities weighted by w_ip, with modes orthogonal under those weights (products of each
axis' orthogonal polynomials of degree <= p, the basis' degree). solver.polypic_modes picks the modes: `total`, the
products of total degree <= p (6 in 2D and 10 in 3D for quadratic B-splines), or `full`, every product of per-axis
degree <= p (9 and 27), with which the fit interpolates the stencil. v_p is the constant mode, sum w v_i (PIC's);
positions and F as PIC. A grid field in the modes' span survives a round trip exactly, where APIC keeps only its
affine part; uniform B-splines of degree p reproduce polynomials of degree p, so the momentum P2G maps, m_p sum w f(r),
is m_p v_p wherever the particle has moved: linear momentum is conserved, angular momentum nearly (its cubic moments
move with the particle). Measured (docs/transfers.md, "PolyPIC"): the stability map's 29 scenarios, 22 stable with
`total` and with `full`, whose 3D step costs 1.5x total's."""
from itertools import product

from .base import Scheme, register

MODE_SETS = ("total", "full")   # solver.polypic_modes
MAX_MODES = 27                  # per particle (3D quadratic full); 3D cubic's 64 full modes are not built


def modes(dim: int, degree: int, which: str) -> list:
    """The modes' per-axis degrees: constant first, then the linear ones (APIC's), then the rest."""
    out = [k for k in product(range(degree + 1), repeat=dim) if which == "full" or sum(k) <= degree]
    return sorted(out, key=lambda k: (sum(k), tuple(reversed(k))))


def lower_terms(degree: int) -> list:
    """(j, l) with l < j <= degree: the monomial coefficients g_jl kept of each axis' orthogonal polynomials."""
    return [(j, l) for j in range(1, degree + 1) for l in range(j)]


POLYPIC = register(Scheme(
    name="polypic", summary="PolyPIC: a polynomial velocity per particle, fitted to its stencil (solver.polypic_modes)",
    reference="Fu, Guo, Yang, Jiang & Teran 2017, ACM TOG 36(6) 230",
    accuracy=3,
    cost="the modes' coefficients per particle (3D quadratic: 30 floats total, 81 full, 9 more for the axis "
         "polynomials); the modes' fit in G2P and their sum at each node in P2G",
    basis_need=lambda spec: (spec.stencil_kind == "tensor" and spec.stencil == spec.degree + 1
                             and not spec.particle_domains and not spec.prepass_grid),
    basis_why="B-spline weights whose stencil is degree + 1 nodes wide (they reproduce the modes' polynomials)",
    parameters=("solver.polypic_modes",), polynomial=True))
