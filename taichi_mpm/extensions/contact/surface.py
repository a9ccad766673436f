"""Where a body's surface lies at a node, from its particles' centroid there (multi-field contact's gap check,
docs/contact.md "Gap"). A body filling everything behind a flat surface at offset s (cells, along the surface's
outward normal n from node I) has its node-weighted centroid (sum_p w_ip m_p (x_p - x_i) / m_k) . n = C(s) dx,
C(s) = int_{-h}^{s} u N(u) du / int_{-h}^{s} N(u) du for the node's 1D weight N (half-width h), increasing from -h
to 0; `surface_offset` inverts it from a table. N is the cardinal B-spline of the basis degree (exact for the
uniform B-splines away from walls, a model of graded knots), averaged over a particle's domain for GIMP and CPDI
(their weight of an undeformed domain).
Physics code only."""

from math import comb, factorial

import numpy as np
import taichi as ti

# cells of gap still taken as touching: the surfaces' estimates from a few particles at a stencil's tail err by
# about this much on a flat contact (at 0.05 a block resting on an incline crept 1.5e-3 of g t^2/2, 3.7e-4 at 0.1;
# a rolling disk lost 5 % of its acceleration at 0.2, docs/contact.md "Gap")
TOUCH = 0.1


def node_weight(degree: int, half_width: float = 0.0, samples: int = 20001):
    """(u, N(u)) on [-h, h] (cells): the cardinal B-spline of `degree`, or with half_width > 0 its average over a
    particle's domain of that half-width (GIMP's and CPDI's weight of a particle centred at u, h grown by it)."""
    h = 0.5 * (degree + 1)
    if half_width <= 0.0:
        u = np.linspace(-h, h, samples)
        return u, _bspline(degree, u)
    v = np.linspace(-h, h, samples)
    F = np.concatenate([[0.0], np.cumsum(0.5 * (_bspline(degree, v[1:]) + _bspline(degree, v[:-1])) * (v[1] - v[0]))])
    u = np.linspace(-h - half_width, h + half_width, samples)
    N = (np.interp(u + half_width, v, F) - np.interp(u - half_width, v, F)) / (2.0 * half_width)
    return u, N


def _bspline(degree: int, u):
    h = 0.5 * (degree + 1)
    return sum((-1) ** k * comb(degree + 1, k) * np.maximum(u + h - k, 0.0) ** degree
               for k in range(degree + 2)) / factorial(degree)


def centroid_curve(degree: int, half_width: float = 0.0, samples: int = 20001):
    """(s, C(s)) on [-h, h] for the node weight of `degree` (node_weight; cells). A body's particles at spacing
    2 half_width whose domains fill everything behind s sum like the integral of N over their centres to s."""
    u, N = node_weight(degree, half_width, samples)
    du = u[1] - u[0]
    mass = np.concatenate([[0.0], np.cumsum(0.5 * (N[1:] + N[:-1]) * du)])
    moment = np.concatenate([[0.0], np.cumsum(0.5 * (u[1:] * N[1:] + u[:-1] * N[:-1]) * du)])
    keep = mass > 1e-9   # the first samples hold no mass: C is the limit -h there
    return u[keep], moment[keep] / mass[keep]


def particle_half_width(spec, spacing) -> float:
    """The half-width (cells) a basis with particle domains (GIMP, CPDI) averages its weights over: half the
    particles' spacing (in cells; their mean); 0 for the B-splines."""
    return 0.5 * float(np.mean(spacing)) if spec.particle_domains else 0.0


def surface_offset(degree: int, half_width: float = 0.0, size: int = 513):
    """@ti.func (c) -> s: the surface offset (cells) of a body behind it whose centroid is at c (cells) along its
    outward normal; c is clamped to [-h, 0] (s to [-h, h]); h grows by half_width with particle domains."""
    h = 0.5 * (degree + 1) + half_width
    s, C = centroid_curve(degree, half_width)
    c = np.linspace(-h, 0.0, size)
    table = ti.field(float, size)
    values = np.interp(c, C, s)
    table.from_numpy(values)   # (Taichi casts to the field's precision)
    scale = (size - 1) / h

    @ti.func
    def offset(c):
        t = (ti.min(ti.max(c, -h), 0.0) + h) * scale
        i = ti.min(ti.cast(ti.floor(t), ti.i32), size - 2)
        f = t - i
        return (1.0 - f) * table[i] + f * table[i + 1]
    return offset


def surface_gap(surface, inv_dx: float):
    """@ti.func (n, moment, mass, rest_moment, rest_mass) -> the cells between a field's surface and the rest's along
    n, the field's outward normal (< 0: overlap), each placed by `surface` (surface_offset) from its centroid at the
    node (moment / mass: the mass moment sum w m_p (x_p - x_i) over its particles) as if flat."""

    @ti.func
    def gap(n, moment, mass, rest_moment, rest_mass):
        own = moment.dot(n) * inv_dx / mass
        rest = rest_moment.dot(n) * inv_dx / rest_mass
        return -surface(-rest) - surface(own)
    return gap
