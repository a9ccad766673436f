"""Issue 30's config classes ("Trust, round 2"): every size estimated before anything is built, run length
bounded by every rate that limits dt, values outside the precision's range refused, settings that would be
ignored or checked too late refused at validation. Each test failed before its fix (the issue's cases)."""
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm import budget
from taichi_mpm.bases import mapgeom
from taichi_mpm.config import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def round_tank(**map_keys):
    data = yaml.safe_load((ROOT / "configs" / "round_tank.yaml").read_text())
    data["domain"]["map"].update(map_keys)
    data["arch"] = "cpu"
    return data


def ring(cells, angle=360.0):
    return dict(name="ring", dim=2, precision="f32", arch="cpu",
                domain=dict(lower=[-1.1, -1.1], upper=[1.1, 1.1], dx=0.05, boundaries=dict(default="slip"),
                            map=dict(type="annulus", inner_radius=0.5, outer_radius=1.0, angle=angle,
                                     cells=list(cells))),
                solver=dict(end_time=0.01), materials=dict(m=dict(model="neo_hookean", density=1000.0, E=1e4)),
                bodies=[dict(shape=dict(type="sphere", center=[0.0, 0.75], radius=0.1), material="m")])


@pytest.fixture
def nothing_built(monkeypatch):
    """Fail if a mapped grid's net is refined, an annulus built, a MappedGrid made or a scene generated."""
    from taichi_mpm.bases import mapped, nurbs
    from taichi_mpm import scene, solver  # noqa: F401 (imported first: it binds the names it imports)

    def refuse(*a, **k):
        raise AssertionError("built before the size was checked")

    for mod, name in ((mapgeom, "refine"), (nurbs, "annulus"), (mapped, "MappedGrid"), (scene, "build_scene")):
        monkeypatch.setattr(mod, name, refuse)


# ---------------------------------------------------------------- 1: sizes before the expensive work
def test_nurbs_refine_at_the_schema_maximum_validates_fast_and_is_sized_from_the_knots(nothing_built):
    """refine [256, 256] (the schema's old maximum) on the round tank: before, validation refined the net and
    sampled det J on every refined cell (8 GiB asked for); now the checks run on the given net (the same map)
    and the budget counts the refined net from the knots."""
    t0 = time.perf_counter()
    cfg = tm.load_config(round_tank(refine=[256, 256]))
    est = budget.estimate(cfg)
    assert time.perf_counter() - t0 < 10
    assert est.grid_cells == [512, 256]
    assert budget.grid_layout(cfg)["nodes"] == [5 + 2 * 255, 3 + 255]


def test_large_nurbs_net_refined_is_refused_naming_refine(nothing_built):
    """A 41 x 41 net (39 spans a side) refined 256 times: 1e4 x 1e4 control points, refused from its knots."""
    n = 41
    knots = [0.0, 0.0] + list(range(n - 1)) + [n - 2.0] * 2
    net = [[[-0.9 + 1.8 * i / (n - 1), -0.9 + 1.8 * j / (n - 1)] for j in range(n)] for i in range(n)]
    data = round_tank(knots=dict(x=knots, y=knots), control_points=net, weights=None, refine=[256, 256])
    data["domain"].update(lower=[-1.0, -1.0], upper=[1.0, 1.0])
    data["bodies"][0]["shape"] = dict(type="sphere", center=[0.0, 0.0], radius=0.2)
    data["limits"] = dict(memory_gb=8)
    cfg = tm.load_config(data)
    with pytest.raises(ConfigError, match="domain.map.refine") as e:
        budget.check(cfg)
    assert e.value.key == "domain.map.refine"


def test_annulus_cells_at_the_schema_maximum_are_refused_before_building(nothing_built):
    """cells [4096, 4096] (the old maximum): before, the budget built the map (514 GiB asked for by the wall normals); now refused
    from its size (the grid and the solver's first particle location), naming domain.map.cells."""
    t0 = time.perf_counter()
    cfg = tm.load_config(dict(ring([4096, 4096]), limits=dict(memory_gb=16)))
    with pytest.raises(ConfigError, match="memory") as e:
        budget.check(cfg)
    assert e.value.key == "domain.map.cells"
    assert time.perf_counter() - t0 < 5


@pytest.mark.parametrize("grid,size,words", [("nurbs", [4096, 4096], "memory"), ("nurbs", [10**6, 10**6], "2\\^31"),
                                              ("annulus", [10**6, 10**6], "2\\^31"), ("annulus", [2**31 - 4, 1], "2\\^31")])
def test_map_sizes_past_the_old_schema_maxima_are_the_budgets_to_refuse(nothing_built, grid, size, words):
    """The schema bounds cells and refine only by what Taichi can index; the budget refuses from the estimate
    (memory, limits.memory_gb, limits.allow_large; 2^31 elements whatever the limits), fast, naming the key."""
    t0 = time.perf_counter()
    data = round_tank(refine=size) if grid == "nurbs" else ring(size)
    data["limits"] = dict(memory_gb=16)
    cfg = tm.load_config(data)
    with pytest.raises(ConfigError, match=words) as e:
        budget.check(cfg)
    assert e.value.key == ("domain.map.refine" if grid == "nurbs" else "domain.map.cells")
    assert time.perf_counter() - t0 < 5
    if words == "memory":
        data["limits"]["allow_large"] = True
        with pytest.warns(budget.SizeWarning, match="running anyway"):
            budget.check(tm.load_config(data))


@pytest.mark.parametrize("angle,cells", [(360.0, (24, 4)), (180.0, (8, 3)), (100.0, (6, 5)), (45.0, (3, 2))])
def test_map_sizes_from_the_config_equal_the_built_maps(angle, cells):
    from taichi_mpm.bases.mapped import MappedGrid

    cfg = tm.load_config(ring(cells, angle))
    size, grid = budget.map_size(cfg), MappedGrid(cfg)
    assert size.shape == grid.shape and size.cells == [int(c) for c in grid.map.n_cells]
    assert size.field_floats() == grid.field_floats()
    assert size.h_min == pytest.approx(grid.h_min, rel=1e-12)
    data = round_tank(refine=[3, 5])
    cfg = tm.load_config(data)
    size, grid = budget.map_size(cfg), MappedGrid(cfg)
    assert size.shape == grid.shape and size.field_floats() == grid.field_floats()
    assert size.h_min == pytest.approx(grid.h_min, rel=1e-12)


def test_local_surface_matches_the_dense_evaluation():
    """mapgeom.surface reads 3 x 3 control points per point: the same x and J as every B-spline at every point."""
    rng = np.random.default_rng(0)
    t0, t1 = np.array([0, 0, 0, 1, 1, 2.5, 3, 3, 3.0]), np.array([0, 0, 0, 0.5, 2, 2, 2.0])
    P, w = rng.normal(size=(6, 4, 2)), rng.uniform(0.5, 2, (6, 4))
    xi = np.stack([rng.uniform(0, 3, 200), rng.uniform(0, 2, 200)], -1)
    xi[:4] = [[0, 0], [3, 2], [1, 0.5], [2.5, 2]]      # ends and knots (x = 1 a double knot: J jumps there)
    N = [mapgeom.bspline_values(t, 2, xi[:, a]) for a, t in enumerate((t0, t1))]
    R = np.einsum("mi,mj,ij->mij", N[0], N[1], w)
    x_dense = np.einsum("mij,ijc->mc", R / R.sum(axis=(1, 2))[:, None, None], P)
    x, J = mapgeom.surface([t0, t1], [2, 2], P, w, xi)
    assert np.abs(x - x_dense).max() < 1e-13
    h = 1e-6
    for a in range(2):
        e = np.zeros(2)
        e[a] = h
        inner = np.arange(len(xi)) >= 4
        fd = (mapgeom.surface([t0, t1], [2, 2], P, w, xi + e)[0] - mapgeom.surface([t0, t1], [2, 2], P, w, xi - e)[0]) / (2 * h)
        assert np.abs(fd - J[:, :, a])[inner].max() < 1e-6


# ---------------------------------------------------------------- 2: run length
def steps_error(data):
    with pytest.raises(ConfigError, match="steps") as e:
        budget.check(tm.load_config(data))
    return e.value


def test_viscosity_limits_the_estimated_step_and_a_run_of_1e31_steps_is_refused():
    """viscosity 1e30: the solver's step is cfl rho dx^2 / (2 d mu) = 1e-31 s; before, validate estimated 12.7
    steps (the elastic rule only)."""
    data = make_cfg(2, model="fluid", E=1e4, end_time=1.0)
    data["materials"]["m"]["viscosity"] = 1e3
    est = budget.estimate(tm.load_config(data))
    assert est.dt == pytest.approx(0.4 * 1000 * 0.1**2 / (2 * 2 * 1e3))   # below the elastic limit, 0.0126 s
    sim = tm.Simulation(tm.load_config(data))
    assert est.dt == pytest.approx(sim.stable_dt(), rel=1e-12) and sim.dt_limit == "viscosity"
    data["materials"]["m"]["viscosity"] = 1e30
    e = steps_error(data)
    assert e.key == "materials.m.viscosity"


@pytest.mark.parametrize("case", ["E", "hardening", "knots", "velocity", "gravity"])
def test_every_rate_that_limits_dt_bounds_the_run(case):
    data = make_cfg(2, end_time=1.0)
    if case == "E":
        data["materials"]["m"]["E"] = 1e20      # f64: in range, but a wave speed of 3e8 m/s
        key = "materials.m.E"
    elif case == "hardening":
        data["materials"]["m"] = dict(model="snow", density=400.0, E=1.4e5, max_hardening=1e30)
        key = "materials.m.E"
    elif case == "knots":
        data["domain"]["knots"] = dict(x=[0, 0, 0, 0.5, 0.5 + 1e-12, 1, 1, 1])
        key = "domain.knots.x"
    elif case == "velocity":
        data["bodies"][0]["velocity"] = [1e12, 0.0]
        key = "bodies.0.velocity"
    else:
        data["solver"]["gravity"] = [0.0, -1e20]
        data["precision"] = "f64"
        key = "solver.gravity"
    e = steps_error(data)
    assert e.key == key, str(e)
    data.setdefault("limits", {})["allow_large"] = True
    with pytest.warns(budget.SizeWarning, match="steps"):
        budget.check(tm.load_config(data))


def test_limits_steps_sets_the_bound():
    data = make_cfg(2, end_time=1.0)        # ~1e3 steps
    n = budget.estimate(tm.load_config(data)).steps
    data["limits"] = dict(steps=n / 2)
    assert "limits.steps" in str(steps_error(data))
    data["limits"] = dict(steps=n * 2)
    budget.check(tm.load_config(data))
    data["solver"]["max_steps"] = 10        # a run that stops itself is bounded
    data["limits"] = dict(steps=100)
    budget.check(tm.load_config(data))


def test_estimated_dt_is_the_solvers_with_gravity_and_speed():
    data = make_cfg(2, end_time=0.1, velocity=[30.0, 0.0], E=10.0)
    data["solver"]["gravity"] = [0.0, -9.81]
    cfg = tm.load_config(data)
    sim = tm.Simulation(cfg)
    assert budget.estimate(cfg).dt == pytest.approx(sim.stable_dt(), rel=1e-12)
    limits = budget.dt_limits(cfg)
    assert {k: v[0] for k, v in limits.items()} == pytest.approx(sim.dt_limits(), rel=1e-12)


# ---------------------------------------------------------------- 3: values outside the precision's range
def range_error(data, tmp_path=None):
    if tmp_path is not None:
        path = tmp_path / "c.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        data = path
    with pytest.raises(ConfigError, match="outside what precision") as e:
        tm.load_config(data)
    return e.value


def f32(**kw):
    data = make_cfg(2, precision="f32", **kw)
    return data


@pytest.mark.parametrize("case,key", [
    ("E", "materials.m.E"), ("density", "materials.m.density"), ("pressure", "bodies.0.tractions.0.pressure"),
    ("stress", "bodies.0.stress.0"), ("velocity", "bodies.0.velocity.0"), ("gravity", "solver.gravity.1"),
    ("velocity_expression", "bodies.0.velocity.1"), ("grip", "bodies.0.prescribed_velocity.0.velocity.0"),
    ("wall", "domain.boundaries.y_max.velocity.1"), ("ramp", "bodies.0.tractions.0.ramp"),
    ("hardening", "materials.m.max_hardening"), ("tiny_cells", "bodies.0.particles_per_cell"),
    ("yield", "materials.m.yield_stress")])
def test_values_outside_f32_are_config_errors_naming_key_and_precision(tmp_path, case, key):
    """Before: E and density 1e-300 ran a body that never moved (exit 0); pressures of 1e38, stresses of 1e40,
    velocities of 1e30 and gravity 1e39 validated, then stopped with advice to lower solver.cfl."""
    data = f32()
    b, m = data["bodies"][0], data["materials"]["m"]
    if case == "E":
        m["E"] = 1e-300
    elif case == "density":
        m["density"] = 1e-300
    elif case == "pressure":
        b["tractions"] = [dict(pressure=1e38)]
    elif case == "stress":
        b["stress"] = [1e40, 0.0, 0.0]
    elif case == "velocity":
        b["velocity"] = [1e30, 0.0]
    elif case == "gravity":
        data["solver"]["gravity"] = [0.0, -1e39]
    elif case == "velocity_expression":
        b["velocity"] = [0.0, "1e30 * x"]
    elif case == "grip":
        b["prescribed_velocity"] = [dict(velocity=["1e25 * t", None])]
        data["solver"]["end_time"] = 1.0
    elif case == "wall":
        data["domain"]["boundaries"]["y_max"] = dict(type="velocity", velocity=[None, 1e20])
    elif case == "ramp":
        b["tractions"] = [dict(pressure=1e3, ramp="1e20 * t")]
        data["solver"]["end_time"] = 1.0
    elif case == "hardening":
        data["materials"]["m"] = dict(model="snow", density=400.0, E=1.4e5, max_hardening=1e30)
    elif case == "tiny_cells":
        data["domain"].update(dx=1e-16, upper=[1e-15, 1e-15])
        b["shape"] = dict(type="box", lower=[3e-16, 3e-16], upper=[6e-16, 6e-16])
    else:
        data["materials"]["m"] = dict(model="von_mises", density=1000.0, E=1e4, yield_stress=1e19)
    e = range_error(data, tmp_path)
    assert e.key == key, str(e)
    assert "f32" in str(e) and e.line is not None


def test_f64_takes_what_f32_refuses_and_refuses_beyond_its_own_range():
    data = make_cfg(2, precision="f64")
    data["bodies"][0]["stress"] = [1e40, 0.0, 0.0]
    data["materials"]["m"]["E"] = 1e40
    tm.load_config(data)
    data["materials"]["m"]["density"] = 1e-300
    assert range_error(data).key == "materials.m.density"


def test_ordinary_extremes_stay_valid():
    """Steel in Pa, a 1 micron grid in 2D, a 1e3 m/s impact, a centrifuge's 1e5 g: all inside f32's range."""
    data = f32(E=2e11, density=7850.0, velocity=[1e3, 0.0])
    data["solver"]["gravity"] = [0.0, -1e6]
    tm.load_config(data)
    data = f32()
    data["domain"].update(dx=1e-6, upper=[1e-5, 1e-5])
    data["bodies"][0]["shape"] = dict(type="box", lower=[3e-6, 3e-6], upper=[6e-6, 6e-6])
    tm.load_config(data)


# ---------------------------------------------------------------- 4: settings ignored or checked in the wrong place
def config_error(data, tmp_path, key):
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError) as e:
        tm.load_config(path)
    assert e.value.key == key, str(e.value)
    assert e.value.line is not None
    return e.value


def sand(model="drucker_prager", **keys):
    data = make_cfg(2)
    data["materials"] = dict(sand=dict(model=model, density=1600.0, E=1e6, friction_angle=30.0, **keys))
    data["bodies"][0]["material"] = "sand"
    return data


@pytest.mark.parametrize("case,key", [
    ("tensile_strength", "materials.m.tensile_strength"), ("fracture_energy", "materials.m.fracture_energy"),
    ("cpdi", "solver.cpdi"), ("gimp_domain", "solver.gimp_domain"),
    ("volume_correction", "materials.sand.volume_correction"),
    ("volume_correction_mohr_coulomb", "materials.sand.volume_correction"),
    ("dilatancy", "materials.sand.dilatancy")])
def test_settings_nothing_reads_are_config_errors_with_key_and_line(tmp_path, case, key):
    """Before: each validated and the run ignored it (tensile_strength without a crack section, solver.cpdi with
    another basis, volume_correction with dilatancy), or the key named the material only (dilatancy)."""
    data = make_cfg(2)
    m = data["materials"]["m"]
    if case == "tensile_strength":
        m["tensile_strength"] = 1e3
    elif case == "fracture_energy":
        data["crack"] = {}
        m["fracture_energy"] = 10.0
    elif case == "cpdi":
        data["solver"]["cpdi"] = dict(variant="cpdi2")
    elif case == "gimp_domain":
        data["solver"]["gimp_domain"] = "deforming"
    elif case.startswith("volume_correction"):
        data = sand("mohr_coulomb" if case.endswith("coulomb") else "drucker_prager", dilatancy=5.0,
                    volume_correction=True)
    else:
        data = sand(dilatancy=40.0)
    e = config_error(data, tmp_path, key)
    if key.startswith("materials."):
        assert f"'{key.split('.')[1]}'" in str(e) or case == "dilatancy"


@pytest.mark.parametrize("key", ["damage_regions", "interface"])
def test_crack_flags_without_a_crack_section_are_a_documented_warning(key):
    """Legitimately there (a crack section switched off to compare): a ConfigWarning naming the key, not silence."""
    from taichi_mpm.config import ConfigWarning

    data = make_cfg(2)
    data["bodies"][0][key] = True if key == "interface" else [
        dict(shape=dict(type="sphere", center=[0.45, 0.45], radius=0.05))]
    with pytest.warns(ConfigWarning, match=f"bodies.0.{key}"):
        tm.load_config(data)


def test_the_settings_in_their_place_stay_valid():
    data = make_cfg(2, basis="cpdi")
    data["solver"]["cpdi"] = dict(variant="cpdi1")
    tm.load_config(data)
    data["solver"]["basis"] = "quadratic"   # the default written out (Config.to_dict does) is no setting
    tm.load_config(tm.load_config(data).to_dict())
    tm.load_config(sand(dilatancy=0.0, volume_correction=True))
    tm.load_config(sand(dilatancy=5.0))
    data = make_cfg(2)
    data["crack"] = {}
    data["materials"]["m"].update(tensile_strength=1e3, fracture_energy=10.0)
    data["bodies"][0]["damage_regions"] = [dict(shape=dict(type="sphere", center=[0.45, 0.45], radius=0.05))]
    tm.load_config(data)


def validate_cli(tmp_path, data, capsys):
    from taichi_mpm.cli import main

    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    code = main(["validate", str(path)])
    return code, capsys.readouterr().err


def test_damage_region_holding_no_particle_is_refused_at_validate(tmp_path, capsys):
    """As a grip's region: before, a damage region beside the body validated and damaged nothing."""
    data = make_cfg(2)
    data["crack"] = {}
    data["bodies"][0]["damage_regions"] = [dict(shape=dict(type="sphere", center=[0.9, 0.9], radius=0.05))]
    code, err = validate_cli(tmp_path, data, capsys)
    assert code == 2 and "bodies.0.damage_regions.0.shape" in str(err) and "no particle" in err
    assert "c.yaml:" in err   # file and line


@pytest.mark.parametrize("grid", ["nurbs", "annulus"])
def test_body_partly_outside_the_map_is_refused_at_validate(tmp_path, capsys, grid):
    """Before: validate passed and `run` stopped at upload with a message about an annulus (for any map)."""
    if grid == "nurbs":
        data = round_tank(refine=[4, 4])
        data["bodies"][0]["shape"] = dict(type="sphere", center=[-0.8, -0.5], radius=0.2)   # through the wall
        inside = dict(type="sphere", center=[-0.45, -0.4], radius=0.3)
    else:
        data = ring([24, 4])
        data["bodies"][0]["shape"] = dict(type="sphere", center=[0.0, 0.45], radius=0.1)   # over the inner circle
        inside = dict(type="ring", center=[0.0, 0.0], inner_radius=0.5, outer_radius=1.0)  # flush with both
    code, err = validate_cli(tmp_path, data, capsys)
    assert code == 2 and "bodies.0.shape" in err and "outside" in err, err
    assert (grid == "nurbs") == ("nurbs map" in err)
    data["bodies"][0]["shape"] = inside
    code, err = validate_cli(tmp_path, data, capsys)
    assert code == 0, err


@pytest.mark.parametrize("probe,key", [(dict(name="r", type="region", region=dict(type="box", lower=[0.8, 0.8],
                                                                                  upper=[0.9, 0.9])), "region"),
                                       (dict(name="p", type="point", point=[2.0, 0.5]), "point")])
def test_probe_beside_every_body_is_refused_at_validation(tmp_path, probe, key):
    """Before: validated, and the run stopped at its start ('the probe selects no particle')."""
    data = make_cfg(2)
    data["output"] = dict(probes=[probe])
    config_error(data, tmp_path, f"output.probes.0.{key}")
    probe = dict(probe, region=dict(type="box", lower=[0.5, 0.5], upper=[0.9, 0.9])) if key == "region" else \
        dict(probe, point=[0.9, 0.1])
    data["output"] = dict(probes=[probe])
    tm.load_config(data)


def test_expression_velocities_count_in_the_estimated_step():
    """A velocity given as an expression of position counted as 0 before (the estimate's dt was the elastic one)."""
    data = make_cfg(2, end_time=0.1, E=10.0, velocity=["300 * x", 0.0])
    cfg = tm.load_config(data)
    sim = tm.Simulation(cfg)
    est = budget.estimate(cfg)
    # the body's box reaches x = 0.6 (180 m/s), its particles 0.575: the estimate is on the safe side, close
    assert sim.stable_dt() * 0.9 < est.dt <= sim.stable_dt() and sim.dt_limit == "speed"


@pytest.mark.parametrize("case,key", [
    ("mohr_coulomb", "materials.m.dilatancy"), ("drucker_prager", "materials.m.dilatancy"),
    ("box", "bodies.0.shape.upper"), ("box_lengths", "bodies.0.shape.upper"),
    ("ring", "bodies.0.shape.inner_radius"), ("region", "output.probes.0.region.upper")])
def test_cross_field_errors_name_the_field_and_the_file_line(tmp_path, case, key):
    """A check between two keys of one section names the key to change (before: mohr_coulomb's dilatancy above
    its friction angle named 'materials.m', a box with upper <= lower or a ring with inner >= outer radius named
    the whole shape); a material's error names the material in its key."""
    data = make_cfg(2)
    if case in ("mohr_coulomb", "drucker_prager"):
        data["materials"]["m"] = dict(model=case, density=1600.0, E=1e6, friction_angle=30.0, dilatancy=45.0)
    elif case == "box":
        data["bodies"][0]["shape"] = dict(type="box", lower=[0.6, 0.3], upper=[0.3, 0.6])
    elif case == "box_lengths":
        data["bodies"][0]["shape"] = dict(type="box", lower=[0.3, 0.3], upper=[0.6])
    elif case == "ring":
        data["bodies"][0]["shape"] = dict(type="ring", center=[0.5, 0.5], inner_radius=0.3, outer_radius=0.2)
    else:
        data["output"] = dict(probes=[dict(name="r", type="region", region=dict(type="box", lower=[0.5, 0.5],
                                                                                  upper=[0.5, 0.9]))])
    e = config_error(data, tmp_path, key)
    assert str(e).startswith(f"{tmp_path / 'c.yaml'}:{e.line}, key '{key}': "), str(e)
