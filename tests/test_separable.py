"""bases/separable.py: sums by factorisation equal the node-by-node sums (numpy, f64) for every split of the stencil
loop solver.unroll makes (all unrolled, trailing axes unrolled, all at run time), in 2D and 3D; G2P with them (3D,
unrolled) against the run-time loop."""
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


def _state_after(cfg, steps=6):
    import taichi_mpm as tm
    sim = tm.Simulation(cfg)
    for _ in range(steps):
        sim.step()
    return sim.get_state()


CASES = [("xpic", {"basis": "linear", "update": "musl"})]   # v*, and MUSL's remapped velocities for grad v
SLOW_CASES = [("apic", {}), ("pic", {}), ("mls", {}), ("tpic", {}), ("asflip", {}), ("xpic", {}),
              ("flip", {"update": "musl"}), ("apic", {"basis": "gimp"}), ("flip", {"basis": "linear"})]


@pytest.mark.parametrize("transfer,extra", CASES + [pytest.param(*c, marks=pytest.mark.slow) for c in SLOW_CASES])
def test_unrolled_g2p_sums_match_the_run_time_loop(cfg_factory, transfer, extra):
    """The factorised G2P sums (3D, stencil unrolled) against the node-by-node loop (solver.unroll false), f64, a
    moving block after six steps: the same up to the order of the additions (relative 1e-12, round-off ~1e-16).
    XPIC's v* and MUSL's remapped velocities are the sums' other node values."""
    extra = dict(extra)
    basis = extra.pop("basis", "quadratic")
    states = []
    for unroll in (True, False):
        cfg = cfg_factory(3, basis=basis, transfer=transfer, velocity=[0.5, -0.3, 0.2], dx=0.125, unroll=unroll,
                          **extra)
        states.append(_state_after(cfg))
    for key in ("x", "v", "F"):
        a, b = np.asarray(states[0][key]), np.asarray(states[1][key])
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max(), err_msg=key)
