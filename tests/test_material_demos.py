"""The plastic-material demos (issue 11): sand_pile, snowball, necking, granular_collapse_3d. Each has a quick
smoke test with a physical check of what it shows at that early time (default run), and a slow test of the physics
of the full demo (-m slow; measured values in docs/materials.md)."""
import math

import numpy as np
import pytest

from test_demos import load_demo, quick


# ---------------------------------------------------------------- snowball
@pytest.mark.slow
def test_snowball_quick_free_flight(tmp_path):
    """Before it reaches the wall (t = 0.02 s < 0.027 s) the ball flies freely: the centre of mass moves v0 t along
    x and drops g t^2 / 2 (symplectic Euler: x_n = g dt^2 n (n + 1) / 2), and a rigid translation leaves J_p = 1
    and no plastic strain (f32 round-off: 1e-5)."""
    demo = load_demo("snowball")
    sim = demo.main(quick(tmp_path, 0.01, 0.02))
    p = sim.particles()
    x0 = sim.scene.x
    m = p["mass"] / p["mass"].sum()
    assert float(m @ (p["x"][:, 0] - x0[:, 0])) == pytest.approx(6 * 0.02, rel=1e-3)
    assert float(m @ (x0[:, 1] - p["x"][:, 1])) == pytest.approx(0.5 * 9.81 * 0.02**2 * (1 + 1 / sim.n_steps), rel=0.01)
    assert np.abs(p["Jp"] - 1).max() < 1e-5 and p["plastic_strain"].max() < 1e-5


# ---------------------------------------------------------------- necking
@pytest.mark.slow
def test_necking_quick_carries_the_plane_strain_yield_load(tmp_path):
    """A coarse bar (4 cells across) pulled for 12 ms (nominal strain 3 %, past the yield strain of 1 %): the load
    cell reads the plane-strain yield load of the cross-section, 2 / sqrt(3) (sigma_y + H alpha) w0 exp(-eps)
    (sigma_yy = 0, eps_zz = 0: sigma_xx = 2 / sqrt(3) sigma_eq), which varies by < 1 % over this strain range. 3 %
    covers the inertia of the ramped pull and the grips' held ends; the uniaxial yield load sigma_y w0 (no plane
    strain) is 13 % lower and a still elastic bar would carry E eps w0 = 3x more, both outside the band."""
    demo = load_demo("necking")
    sim = demo.main(quick(tmp_path, 0.005, 0.012, "output.probe_every=0.0005"))
    n = sim.necking
    yield_load = 2 / math.sqrt(3) * 1.0e5 * n["width"]
    assert n["force"][-1] == pytest.approx(yield_load, rel=0.03)
    assert sim.particles()["plastic_strain"].max() > 0.01


# ---------------------------------------------------------------- sand pile (hopper)
@pytest.mark.slow
def test_sand_pile_quick_hopper_holds_and_drains(tmp_path):
    """A coarser hopper (dx 5 mm: the 3 cm orifice is 6 cells; at 1 cm the walls' held nodes close it) for 0.15 s:
    the gripped walls do not move, and the sand starts to drain through the orifice: it comes down, but slower
    than free fall (the hopper holds most of it back)."""
    sim = load_demo("sand_pile").main(quick(tmp_path, 0.005, 0.15))
    p = sim.particles()
    walls = p["body"] < 2
    assert np.abs(p["x"][walls] - sim.scene.x[walls]).max() < 1e-6
    sand = ~walls
    drop = float((sim.scene.x[sand, 1] - p["x"][sand, 1]).mean())
    assert 0.002 < drop < 0.5 * 0.5 * 9.81 * 0.15**2
    assert p["x"][sand, 1].min() < 0.08 - 0.01                 # the first grains are through the orifice (y = 0.08)


# ---------------------------------------------------------------- 3D granular collapse
@pytest.mark.slow
def test_granular_collapse_3d_quick_is_axisymmetric(tmp_path):
    """A coarse column (dx 2 cm: R0 = 3 cells) for 0.15 s: it slumps and spreads, yielding, and the spreading is
    the same along x and z (the scene is symmetric under swapping the grid's two horizontal axes; the fronts may
    differ by round-off grown in the plastic flow, so a quarter cell is allowed: a wrong axis in the 3D return
    mapping or the stencil moves a front by whole cells)."""
    sim = load_demo("granular_collapse_3d").main(quick(tmp_path, 0.02, 0.15))
    p = sim.particles()
    x, c = p["x"], np.array([0.17, 0.03, 0.17])
    assert np.all(np.isfinite(x)) and x[:, 1].min() > -1e-6
    front_x, front_z = (np.abs(x[:, a] - c[a]).max() for a in (0, 2))
    front0 = np.abs(sim.scene.x[:, 0] - c[0]).max()
    assert front_x > front0 + 0.005, (front_x, front0)    # spreading (measured 1 cm beyond the initial front)
    assert abs(front_x - front_z) < 0.25 * 0.02
    assert x[:, 1].max() < 0.95 * 0.06 and p["plastic_strain"].max() > 0.05


@pytest.mark.slow
def test_snowball_packs_and_breaks_apart(tmp_path):
    """The full demo (dx 4 mm, 0.12 s): where the ball strikes the wall the snow packs (J_p < 0.98: measured 72 %
    of the particles), elsewhere it tears (J_p > 1.02: 27 %), and, snow being nearly plastic, the ball keeps little
    of its momentum (measured mean velocity -0.13 v0; an elastic ball would come back at about -v0)."""
    sim = load_demo("snowball").main(["--set", "arch=cpu", "--set", "output.formats=[]", "--out", str(tmp_path / "run")])
    s = sim.snow_summary
    assert s["packed"] > 0.5 and s["torn"] > 0.1, s
    assert abs(s["rebound"]) < 0.3, s
    assert np.all(np.isfinite(sim.particles()["x"]))


@pytest.mark.slow
def test_necking_peak_load_matches_considere_and_the_neck_localises(tmp_path):
    """The full bar (dx 2.5 mm, 8 cells across) pulled to t = 0.04 s (nominal strain 23 %).
    - Peak load against the plane-strain Considere load 4 H / 3 w0 exp(-eps*) (demos/necking.py): 2 %, the size
      of the pull's inertia and of the grips' end effect; a uniaxial-stress bar (no plane strain) would peak 13 %
      lower.
    - After the peak the load drops below 0.9 of it (measured 0.82): a bar deforming uniformly would still carry the peak load
      within 1 % at this strain (its load curve is flat around eps*), so the drop is the neck carrying less.
    - The thinnest section is below 0.6 of the median width and lies at the weakened middle (0.15 +- 0.02 m)."""
    sim = load_demo("necking").main(["--set", "arch=cpu", "--set", "output.formats=[]", "--set", "solver.end_time=0.04",
                                     "--out", str(tmp_path / "run")])
    n = sim.necking
    peak = n["peak"]          # after the grips' speed-up (its inertia adds 2 % for a moment)
    assert peak == pytest.approx(n["considere_force"], rel=0.02), (peak, n["considere_force"])
    assert n["force"][-1] < 0.9 * peak
    assert n["thinnest"] < 0.6 * n["typical"]
    assert abs(n["neck_x"] - 0.15) < 0.02



@pytest.fixture(scope="module", params=[30.0, 25.0], ids=["phi30", "phi25"])
def sand_pile(request, tmp_path_factory):
    """The full hopper demo (dx 4 mm, 1.5 s; friction angle 30 deg, its config, and 25 deg), run once per angle for
    the tests below."""
    out = tmp_path_factory.mktemp("sand_pile") / "run"
    return load_demo("sand_pile").main(["--set", "arch=cpu", "--set", "output.formats=[]", "--out", str(out),
                                        "--set", f"materials.sand.friction_angle={request.param}"])


@pytest.mark.slow
def test_sand_pile_drains_into_a_symmetric_pile_at_rest(sand_pile):
    """The hopper empties (measured 94 % of the sand below it at 1.5 s at phi = 30 deg, 98 % at 25; the rest clings
    to the gripped plates) into one pile at rest, whose two flanks stand at the same angle (the scene is
    mirror-symmetric; measured 28.3 and 28.3 deg, 23.2 and 23.2 deg): 2 deg allows the asymmetry of the unordered atomics grown in the flow, a lopsided pile differs by
    much more."""
    r = sand_pile.pile
    assert r["drained"] > 0.9, r
    assert abs(r["left"] - r["right"]) < 2.0, r
    p, x0 = sand_pile.particles(), sand_pile.scene.x
    released = float(np.sum(p["mass"] * 9.81 * (x0[:, 1] - p["x"][:, 1])))   # the sand's loss of height (J/m)
    assert sand_pile.energy()["kinetic"] < 1e-3 * released, released           # at rest


@pytest.mark.slow
def test_sand_pile_stands_at_the_angle_of_repose(sand_pile):
    """Issue 11: a pile poured slowly stands within 5 deg of the friction angle. With the simple_shear fit a slope
    flows above phi and stands below it (test_plasticity: test_drucker_prager_friction_in_steady_simple_shear), so
    the grains that land on the pile roll down to phi; they land with some speed and carry a little further
    (measured: 28.3 / 28.3 deg at phi = 30, 23.2 / 23.2 deg at 25; with the plane-strain fit, whose slopes flow
    down to atan(sin phi) = 26.6 deg, 24.4 deg; from the first hopper 15 cm up, 22.5 deg: docs/materials.md).
    5 deg is the issue's bar; a wrong fit (plane strain: 3.4 deg lower in theory) or the first hopper fail it."""
    r = sand_pile.pile
    phi = sand_pile.cfg.materials["sand"].friction_angle
    assert abs(r["left"] - phi) < 5 and abs(r["right"] - phi) < 5, r


@pytest.fixture(scope="module")
def collapse_3d(tmp_path_factory):
    """The full 3D demo (dx = R0 / 6, 0.6 s), run once for the tests below."""
    out = tmp_path_factory.mktemp("collapse_3d") / "run"
    return load_demo("granular_collapse_3d").main(["--set", "arch=cpu", "--set", "output.formats=[]", "--out", str(out)])


@pytest.mark.slow
def test_granular_collapse_3d_comes_to_rest_round(collapse_3d):
    """The column ends as a round heap at rest: the run-out along x and z agree within a cell (the scene is symmetric
    under swapping them), the heap is lower than the column and wider, and the kinetic energy is gone (below 1e-4 of
    the potential energy released; measured 9.4e-7 J against 0.14 J)."""
    x = collapse_3d.particles()["x"]
    c = np.array([0.17, 0.03, 0.17])
    fx, fz = (np.percentile(np.abs(x[:, a] - c[a]), 99.5) for a in (0, 2))
    assert abs(fx - fz) < 0.01
    d = collapse_3d.deposit
    assert 0 < d["height"] < 1.0 and d["runout"] > 0.3, d
    assert collapse_3d.energy()["kinetic"] < 1e-4 * 0.14


@pytest.mark.slow
def test_tall_cylinder_collapse_within_15_percent_of_lube_2004(tmp_path):
    """A 3D column of aspect ratio 6 (mu(I), the 2D columns' parameters) on a quarter of the cylinder at dx = R0/8
    (tools/quarter_collapse_3d.py) runs out (R_inf - R0) / R0 = 3.47 (-11.5 %) against Lube et al. 2004's
    1.6 a^(1/2) = 3.92, the issue's 15 %; 3.70 (-5.6 %) at R0/12 (docs/materials.md "3D columns"). A column that
    stopped as it fell (no spreading) or a sheet with nothing to stop it (mu(I) lost) fails the band; at rest by
    1.47 s (fastest particle 2.4 mm/s)."""
    r = load_demo("quarter_collapse_3d", "tools").main(["8", "--aspect", "6", "--out", str(tmp_path)])
    assert abs(r["runout"] / r["expected"] - 1) < 0.15, r
    assert r["speed"] < 0.05, r


@pytest.mark.slow   # about 3 minutes
def test_low_cylinder_collapse_with_polypic_within_15_percent_of_lube_2004(tmp_path):
    """Lube et al. 2004 (axisymmetric columns): (R_inf - R0) / R0 = 1.24 a for a < 1.7. The column of a = 1 on a
    quarter of the cylinder at dx = R0/12 with Mohr-Coulomb at the 2D columns' angle (35.26 deg, volume correction)
    and PolyPIC runs out 1.09 (-12 %; 0.95 at R0/8, 1.17 at R0/18: docs/materials.md "3D columns"). With APIC the same
    column ran 0.70 (-43 %; mu(I) 0.77, the demo's drucker_prager at R0/6 0.64): the shear band under the toe loses
    momentum at every transfer, as in 2D. A column that stopped as it fell fails the band; at rest by 0.6 s."""
    mc = ("materials.sand={model: mohr_coulomb, E: 3.0e5, nu: 0.3, density: 1500, friction_angle: 35.26, "
          "volume_correction: true}")
    r = load_demo("quarter_collapse_3d", "tools").main(["12", "--aspect", "1", "--out", str(tmp_path),
                                                         "--set", mc, "--set", "solver.transfer=polypic"])
    assert abs(r["runout"] / r["expected"] - 1) < 0.15, r
    assert r["speed"] < 0.05, r
