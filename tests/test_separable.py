"""bases/separable.py: sums by factorisation equal the node-by-node sums (numpy, f64) for every split of the stencil
loop solver.unroll makes (all unrolled, trailing axes unrolled, all at run time), in 2D and 3D."""
import itertools

import numpy as np
import pytest
import taichi as ti

from taichi_mpm import traced
from taichi_mpm.bases import separable
from taichi_mpm.bases.stencil_parts import loops
from taichi_mpm.solver import init_taichi


@pytest.mark.parametrize("dim,S,unroll", [(3, 3, True), (3, 3, "auto"), (3, 3, False), (2, 4, True),
                                          (3, 4, "auto")])
def test_factorised_sums_equal_node_by_node_sums(dim, S, unroll):
    init_taichi("cpu", "f64")
    rng = np.random.default_rng(7)
    rows = rng.normal(size=(dim, 3, S))             # per axis: rows WEIGHT, MOMENT, SLOPE at its S nodes
    values = rng.normal(size=(2,) + (S,) * dim + (dim,))
    rows_f = ti.field(float, rows.shape)
    vals_f = [ti.Vector.field(dim, float, (S,) * dim) for _ in range(2)]
    rows_f.from_numpy(rows)
    for f, v in zip(vals_f, values):
        f.from_numpy(v)
    every = (separable.WEIGHT,) * dim
    requests = [(0, every), (1, every)] + [(0, separable.unit_rows(dim, a, r)) for r in
                                          (separable.MOMENT, separable.SLOPE) for a in range(dim)]
    outer, inner = loops([S] * dim, unroll, auto_inner=9)
    out = ti.Vector.field(dim, float, len(requests))

    @traced.traced
    def factor(st, a, row, i):
        return traced.at(rows_f, a, row, i)

    reads = [lambda off, f=f: traced.at(f, off) for f in vals_f]

    @traced.traced
    def sums(o):
        return separable.contract(factor, None, o, outer, inner, reads, requests)

    @ti.kernel
    def run():
        for _ in range(1):
            for o in ti.grouped(ti.ndrange(*outer)):
                parts = sums(o)
                for k in ti.static(range(len(requests))):
                    out[k] += parts[k]

    run()
    got = out.to_numpy()
    for k, (value, rs) in enumerate(requests):
        want = np.zeros(dim)
        for node in itertools.product(range(S), repeat=dim):
            w = np.prod([rows[a, rs[a], node[a]] for a in range(dim)])
            want += w * values[value][node]
        np.testing.assert_allclose(got[k], want, rtol=1e-12, atol=1e-12)   # f64 sums of ~27 terms of size ~1
