"""P2G's coloured scatter (scatter.py): the same step as atomic adds, particles binned exactly once per step."""
import numpy as np
import pytest

import taichi_mpm as tm
from conftest import fast_subset, make_cfg


def _run(data, scatter, steps=12, dt=2e-4):
    data = {**data, "solver": {**data["solver"], "scatter": scatter}}
    sim = tm.Simulation(tm.load_config(data))
    for _ in range(steps):
        sim.step(dt)
    out = {k: sim.particles()[k].copy() for k in ("x", "v", "F")}
    return sim, out


def _scene(case):
    dim, basis, extra = case
    data = make_cfg(dim, basis=basis, dx=0.1 if dim < 3 else 0.2, velocity=[1.5, -2.0, 0.5][:dim], E=2e4,
                    boundaries="sticky", lower=[0.05] * dim, upper=[0.55] * dim)
    data["solver"]["gravity"] = [0.0, -9.8, 0.0][:dim] if dim > 1 else [-9.8]
    if extra == "musl flip":
        data["solver"].update(update="musl", transfer="flip")
    if extra == "knots":
        data["domain"]["knots"] = {"x": [0.0] * 3 + [0.05, 0.1, 0.2, 0.35, 0.5, 0.6, 0.7, 0.8, 0.9] + [1.0] * 3}
    if extra == "crack":
        data["crack"] = {}
        # the particle column at x = 0.275 (dx 0.1, two per cell); [0.28, 0.32] held none and the scene was refused
        data["bodies"][0]["damage_regions"] = [{"shape": {"type": "box", "lower": [0.26] + [0.0] * (dim - 1),
                                                          "upper": [0.3] + [1.0] * (dim - 1)}}]
    return data


CASES = {"2d quadratic": (2, "quadratic", ""), "1d linear": (1, "linear", ""), "2d cubic": (2, "cubic", ""),
         "2d gimp": (2, "gimp", ""), "2d ddmp": (2, "ddmp", ""), "3d quadratic": (3, "quadratic", ""),
         "2d musl flip": (2, "quadratic", "musl flip"), "2d knots": (2, "quadratic", "knots"),
         "2d crack": (2, "quadratic", "crack"), "2d ck": (2, "ck", ""), "3d ck": (3, "ck", "")}


@pytest.mark.parametrize("name", fast_subset(list(CASES), ["2d quadratic"]))
def test_coloured_scatter_steps_like_atomic_adds(name):
    """Particles of a block hitting sticky walls under gravity, 12 steps in f64: coloured and atomic P2G add the
    same contributions in another order, so they agree to round-off (1e-12 of the values' scale), far below any
    physical change (a missed or doubled particle shifts the velocities by ~1 / particles per block)."""
    data = _scene(CASES[name])
    sim, coloured = _run(data, "coloured")
    bins = sim.bins
    assert bins is not None
    n, order = sim.n, bins.order.to_numpy()[:sim.n]
    assert np.array_equal(np.sort(order), np.arange(n))          # every particle binned exactly once
    offset = bins.offset.to_numpy()
    lo, hi = bins.lo.to_numpy(), bins.hi.to_numpy()
    home = bins.home.to_numpy()[:n].reshape(n, -1)               # each particle's block
    for c in range(bins.colours):                                # each run: one block, of its colour
        for j in range(offset[c], offset[c + 1]):
            run = order[lo[j]:hi[j]]
            assert np.all(np.diff(run) > 0)                      # in particle order (thread-count independent)
            assert (home[run] == home[run[0]]).all()
            assert sum((home[run[0]][a] & 1) << a for a in range(sim.dim)) == c
    del sim
    _, atomic = _run(data, "atomic")
    for k in ("x", "v", "F"):
        scale = np.abs(atomic[k]).max()
        np.testing.assert_allclose(coloured[k], atomic[k], rtol=0, atol=1e-12 * scale, err_msg=k)
    moved = np.abs(coloured["x"] - _scene_positions(data)).max()
    assert moved > 1e-4     # the scene did move (a frozen run would agree trivially)


def _scene_positions(data):
    from taichi_mpm.scene import build_scene
    return build_scene(tm.load_config(data)).x


def test_auto_scatters_by_colours_from_the_measured_crossover_or_when_deterministic(cfg_factory):
    """solver.scatter auto: atomic adds below scatter.ATOMIC_BELOW[dim] particles (where binning and 2^d colour
    passes cost more than they save: benchmarks/scatter_crossover.py), colours from there and at any size in a
    deterministic run (its sums need one order); budget.py decides from its estimate of the count the same way."""
    from taichi_mpm.extensions import scatter

    for dim, n in scatter.ATOMIC_BELOW.items():
        assert not scatter.applies(False, "tensor", 3, dim, "auto", n - 1) or n == 0
        assert scatter.applies(False, "tensor", 3, dim, "auto", n)
        assert scatter.applies(False, "tensor", 3, dim, "auto", 1, deterministic=True)
        assert not scatter.applies(True, "tensor", 3, dim, "auto", 10 ** 7)        # GPUs add atomically
        assert scatter.applies(False, "tensor", 3, dim, "coloured", 1)             # asked for: at any size
    small = cfg_factory(2)                      # 36 particles
    assert tm.Simulation(small).bins is None
    small["solver"]["deterministic"] = True
    assert tm.Simulation(small).bins is not None


def test_coloured_scatter_is_refused_where_a_stencil_is_unbounded(cfg_factory):
    data = cfg_factory(2, basis="cpdi")
    data["solver"]["scatter"] = "coloured"
    with pytest.raises(tm.ConfigError, match="stencil is a bounded box of nodes") as e:
        tm.load_config(data)
    assert e.value.key == "solver.scatter"


_THREADS_RUN = """
import sys, numpy as np, taichi as ti
_init = ti.init
def init(*a, **k):
    k["cpu_max_num_threads"] = int(sys.argv[1])
    return _init(*a, **k)
ti.init = init
import taichi_mpm as tm
data = {data!r}
sim = tm.Simulation(tm.load_config(data))
for _ in range(30):
    sim.step()
p = sim.particles()
np.savez(sys.argv[2], x=p["x"], v=p["v"], F=p["F"], e=np.array(list(sim.energy().values())))
"""


def _threads_scene():
    data = make_cfg(3, dx=0.1, velocity=[1.5, -2.0, 0.5], E=2e4, boundaries="sticky", lower=[0.05] * 3,
                    upper=[0.55] * 3, precision="f32")
    data["solver"]["gravity"] = [0.0, -9.8, 0.0]
    data["solver"]["scatter"] = "coloured"   # the class under test (auto adds this small scene atomically)
    return data


# deterministic: True (no fast math) under -m slow: the default run keeps the coloured scatter's own case, the class
# (bit-identical for any thread count); each case is two fresh processes compiling the scene (~35 s of a cold run)
@pytest.mark.parametrize("deterministic", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_coloured_scatter_is_bit_identical_for_any_thread_count(deterministic, tmp_path):
    """Every node sums its P2G contributions in the same order whatever the threads (a block's particles in particle
    order by one thread, colours one after another), the diagnostics sum by fixed chunks: a 3D f32 block hitting
    sticky walls under gravity (1000 particles, 30 steps) ends bit-identical with 1 and 2 threads, energies
    included. The same scene with `scatter: atomic` differed between 1 and 2 threads (1.2e-7 in x, 1e-6 in v)
    when this was written (the adds' order is the threads' race). With `solver.deterministic` (no fast math) such a
    scene keeps all threads, which this checks too."""
    import subprocess
    import sys

    data = _threads_scene()
    data["solver"]["deterministic"] = deterministic
    script = tmp_path / "run.py"
    script.write_text(_THREADS_RUN.format(data=data))
    out = {}
    for threads in (1, 2):
        out[threads] = tmp_path / f"t{threads}.npz"
        subprocess.run([sys.executable, str(script), str(threads), str(out[threads])], check=True,
                       capture_output=True, timeout=600)
    one, two = np.load(out[1]), np.load(out[2])
    for k in one.files:
        assert np.array_equal(one[k], two[k]), k
