"""Where a body's surface lies at a node, from its particles' centroid there (multi-field contact's gap check,
docs/contact.md "Gap"). A body filling everything behind a flat surface at offset s (cells, along the surface's
outward normal n from node I) has its node-weighted centroid (sum_p w_ip m_p (x_p - x_i) / m_k) . n = C(s) dx,
C(s) = int_{-h}^{s} u N(u) du / int_{-h}^{s} N(u) du for the node's 1D weight N (half-width h), increasing from -h
to 0; `surface_offset` inverts it from a table. N is the cardinal B-spline of the basis degree: exact for the
uniform B-splines away from walls, a model of GIMP's and CPDI's smoothed hats and of graded knots.
Physics code only."""

from math import comb, factorial

import numpy as np
import taichi as ti


def centroid_curve(degree: int, samples: int = 20001):
    """(s, C(s)) on [-h, h] for the cardinal B-spline of `degree` (cells)."""
    h = 0.5 * (degree + 1)
    u = np.linspace(-h, h, samples)
    N = sum((-1) ** k * comb(degree + 1, k) * np.maximum(u + h - k, 0.0) ** degree
            for k in range(degree + 2)) / factorial(degree)
    du = u[1] - u[0]
    mass = np.concatenate([[0.0], np.cumsum(0.5 * (N[1:] + N[:-1]) * du)])
    moment = np.concatenate([[0.0], np.cumsum(0.5 * (u[1:] * N[1:] + u[:-1] * N[:-1]) * du)])
    keep = mass > 1e-9   # the first samples hold no mass: C is the limit -h there
    return u[keep], moment[keep] / mass[keep]


def surface_offset(degree: int, size: int = 513):
    """@ti.func (c) -> s: the surface offset (cells) of a body behind it whose centroid is at c (cells) along its
    outward normal; c is clamped to [-h, 0] (s to [-h, h])."""
    h = 0.5 * (degree + 1)
    s, C = centroid_curve(degree)
    c = np.linspace(-h, 0.0, size)
    table = ti.field(float, size)
    values = np.interp(c, C, s)
    table.from_numpy(values.astype(table.to_numpy().dtype))
    scale = (size - 1) / h

    @ti.func
    def offset(c):
        t = (ti.min(ti.max(c, -h), 0.0) + h) * scale
        i = ti.min(ti.cast(ti.floor(t), ti.i32), size - 2)
        f = t - i
        return (1.0 - f) * table[i] + f * table[i + 1]
    return offset
