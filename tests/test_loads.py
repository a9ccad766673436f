"""Loads and prescribed motion (docs/loads.md), each against something independent: initial fields from expressions
(the vibrating bar's exact solution), tractions (the static extension sigma L / E, momentum balance, the energy
balance, Euler-Bernoulli in a slow test), prescribed velocities on grips and walls (elastic reaction, the 1D impact
stress rho c V, momentum balance against the measured wall impulse)."""
import math
from pathlib import Path

import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm.analytic import VibratingBar
from taichi_mpm.io.probes import read_probe
from taichi_mpm.scene import build_scene

ROOT = Path(__file__).resolve().parents[1]
E, RHO = 100.0, 1.0          # the 1D bars: wave speed c = 10 m/s
C = math.sqrt(E / RHO)


def bar(lower=0.0, upper=1.0, boundaries=None, dx=1 / 32, basis="quadratic", end_time=1.0, **body):
    """A 1D linear elastic bar (nu = 0, so uniaxial strain has modulus E) in the domain [0, 2]."""
    return dict(name="bar", dim=1, precision="f64", arch="cpu",
                domain=dict(lower=[0.0], upper=[2.0], dx=dx, boundaries=boundaries or dict(default="free")),
                solver=dict(basis=basis, transfer="apic", cfl=0.3, end_time=end_time),
                materials=dict(bar=dict(model="linear_elastic", E=E, nu=0.0, density=RHO)),
                bodies=[dict(name="bar", shape=dict(type="box", lower=[lower], upper=[upper]), material="bar",
                             **body)])


# ---------------------------------------------------------------- initial fields
@pytest.mark.slow
def test_vibrating_bar_runs_from_its_config_alone():
    """configs/vibrating_bar.yaml sets v = v0 sin(pi x / L) by an expression; at its own resolution the run follows
    u = v0/omega sin(omega t) sin(pi X / L). Measured: 0.13 % of the amplitude at half a period (0.25 % after a full
    one); 1 % leaves room for round-off and would fail for a bar at rest (100 %) or a wrong mode or amplitude."""
    cfg = tm.load_config(ROOT / "configs" / "vibrating_bar.yaml", overrides={"arch": "cpu", "output.formats": []})
    sim = tm.Simulation(cfg)
    exact = VibratingBar(length=25.0, E=100.0, density=1.0, v0=0.1)
    X = sim.scene.x[:, 0]
    np.testing.assert_allclose(sim.scene.v[:, 0], 0.1 * np.sin(math.pi * X / 25), rtol=0, atol=1e-15)
    sim.advance_to(2.5)  # half a period: T = 2 L / c = 5 s
    u = sim.particles()["x"][:, 0] - X
    amplitude = 0.1 / exact.omega
    assert np.abs(u - exact.exact_displacement(X, 2.5)).max() < 0.01 * amplitude


@pytest.mark.slow
def test_initial_stress_releases_into_the_first_mode():
    """A stored initial stress S0 = E A k cos(k X) (k = pi / L) in a bar at rest between fixed ends: the total stress
    S0 + E u' is that of w = u + A sin(k X), so u = A sin(k X) (cos(omega t) - 1). Measured 0.42 % of A at half a
    period (1.5 % allowed; without the stored stress u = 0, a 200 % error). The stored stress does work S0 : E, kept
    in the strain energy: the balance holds to 1e-4 (measured), 1e-3 allowed."""
    A = 0.05
    stress = f"100 * {A} * pi / 25 * cos(pi * x / 25)"
    cfg = tm.load_config(ROOT / "configs" / "vibrating_bar.yaml",
                         overrides={"arch": "cpu", "output.formats": [], "bodies.0.velocity": None,
                                    "bodies.0.stress": [stress]})
    sim = tm.Simulation(cfg)
    X = sim.scene.x[:, 0]
    k, omega = math.pi / 25, math.pi / 25 * 10.0
    s0 = sim.particles()["stress"][:, 0, 0]
    np.testing.assert_allclose(s0, E * A * k * np.cos(k * X), rtol=1e-12, atol=1e-13)  # output = S0 at t = 0
    sim.advance_to(2.5)
    u = sim.particles()["x"][:, 0] - X
    assert np.abs(u - A * np.sin(k * X) * (math.cos(omega * 2.5) - 1)).max() < 0.015 * A
    assert abs(sim.energy_balance()["ratio"]) < 1e-3


@pytest.mark.slow
def test_geostatic_stress_keeps_a_layer_at_rest():
    """A soil layer under gravity between roller walls, given its lithostatic stress sigma_yy = -rho g (H - y),
    sigma_xx = nu / (1 - nu) sigma_yy (uniaxial strain) as initial stress, is in equilibrium at t = 0: its largest
    speed over 0.1 s is below 1 % of that of the same layer started stress-free (measured 0.29 %), which falls into
    equilibrium at speeds of order g H / c."""
    def largest_speed(stress):
        cfg = dict(name="geostatic", dim=2, precision="f64", arch="cpu",
                   domain=dict(lower=[0.0, 0.0], upper=[0.4, 0.6], dx=0.05, boundaries=dict(default="roller")),
                   solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=0.1, gravity=[0, -9.81]),
                   materials=dict(soil=dict(model="linear_elastic", E=1e6, nu=0.3, density=1000.0)),
                   bodies=[dict(shape=dict(type="box", lower=[0.0, 0.0], upper=[0.4, 0.4]), material="soil",
                                stress=stress)])
        sim = tm.Simulation(tm.load_config(cfg))
        speeds = []
        for k in range(1, 11):
            sim.advance_to(0.01 * k)
            speeds.append(sim.max_speed())
        return max(speeds)

    lithostatic = ["-0.3 / 0.7 * 1000 * 9.81 * (0.4 - y)", "-1000 * 9.81 * (0.4 - y)", 0]
    assert largest_speed(lithostatic) < 0.01 * largest_speed(None)


def test_initial_stress_forms_and_expressions_in_the_scene():
    cfg = tm.load_config(dict(bar(), dim=2, domain=dict(lower=[0, 0], upper=[1, 1], dx=0.25),
                              bodies=[dict(shape=dict(type="box", lower=[0, 0], upper=[0.5, 0.5]), material="bar",
                                           velocity=["x + 2 * y", -1], stress=["-y", 2, "x"])]))
    s = build_scene(cfg)
    x, y = s.x[:, 0], s.x[:, 1]
    np.testing.assert_allclose(s.v, np.stack([x + 2 * y, -np.ones_like(x)], 1))
    np.testing.assert_allclose(s.stress[:, 0, 0], -y)
    np.testing.assert_allclose(s.stress[:, 1, 1], 2.0)
    np.testing.assert_allclose(s.stress[:, 0, 1], x)
    np.testing.assert_allclose(s.stress[:, 1, 0], x)  # Voigt [sxx, syy, sxy]: symmetric
    matrix = tm.load_config(cfg.to_dict(), overrides={"bodies.0.stress": [["-y", "x"], ["x", 2]]})
    np.testing.assert_array_equal(build_scene(matrix).stress, s.stress)
    with pytest.raises(tm.ConfigError, match="symmetric") as e:
        tm.load_config(cfg.to_dict(), overrides={"bodies.0.stress": [[1, 2], [3, 4]]})
    assert e.value.key == "bodies.0.stress.0.1"
    with pytest.raises(tm.ConfigError, match="not a finite number") as e:
        build_scene(tm.load_config(cfg.to_dict(), overrides={"bodies.0.velocity": ["1 / (x - x)", 0]}))
    assert e.value.key == "bodies.0.velocity.0"
    with pytest.raises(tm.ConfigError, match="uses z") as e:
        tm.load_config(cfg.to_dict(), overrides={"bodies.0.velocity": ["z", 0]})


# ---------------------------------------------------------------- tractions
def test_traction_forces_are_traction_times_face_area():
    """2D: every exposed particle face has the area h = dx / ppc (per metre of depth); a traction on the x_max faces
    of a 0.4 x 0.2 block gives t x 0.2 in all, a pressure on the whole surface sums to zero, and a pressure on one
    face pushes inward with p x its length."""
    cfg = tm.load_config(dict(bar(), dim=2, domain=dict(lower=[0, 0], upper=[1, 1], dx=0.1),
                              bodies=[dict(shape=dict(type="box", lower=[0.2, 0.2], upper=[0.6, 0.4]),
                                           material="bar", particles_per_cell=3, tractions=[
                                               dict(region=dict(type="box", lower=[0.55, 0.1], upper=[0.7, 0.5]),
                                                    faces=["x_max"], traction=[300.0, -50.0]),
                                               dict(pressure=7.0),
                                               dict(region=dict(type="sphere", center=[0.4, 0.45], radius=0.1),
                                                    pressure=2.0)])]))
    s = build_scene(cfg)
    f = [load.force.sum(0) for load in s.loads]
    np.testing.assert_allclose(f[0], [300.0 * 0.2, -50.0 * 0.2], rtol=1e-12)
    assert len(s.loads[0].particles) == 6                      # one column of 0.2 / (0.1 / 3) particles
    np.testing.assert_allclose(f[1], [0.0, 0.0], atol=1e-12)   # a closed surface: no net force
    n_top = len(s.loads[2].particles)                          # top particles within 0.1 of x = 0.4 (y_max faces)
    np.testing.assert_allclose(f[2], [0.0, -2.0 * n_top * 0.1 / 3], rtol=1e-12)
    with pytest.raises(tm.ConfigError, match="loads no particle face") as e:   # no x_min face in that region
        build_scene(tm.load_config(cfg.to_dict(), overrides={"bodies.0.tractions.0.faces": ["x_min"]}))
    assert e.value.key == "bodies.0.tractions.0"
    # each name loads its own side: a pressure on x_min alone pushes the left face inward (+x), on y_min up
    for face, want in (("x_min", [7.0 * 0.2, 0.0]), ("y_min", [0.0, 7.0 * 0.4])):
        one = build_scene(tm.load_config(cfg.to_dict(), overrides={"bodies.0.tractions.1.faces": [face]}))
        np.testing.assert_allclose(one.loads[1].force.sum(0), want, rtol=1e-12)


def _time_average(sim, quantity, duration, samples):
    """Mean of quantity(sim) over the next `duration` seconds by the trapezoid rule on `samples` equal intervals."""
    start = sim.time
    values = [quantity(sim)]
    for i in range(1, samples + 1):
        sim.advance_to(start + duration * i / samples)
        values.append(quantity(sim))
    return float(np.trapezoid(values, dx=duration / samples) / duration)


def test_end_traction_oscillates_about_the_static_extension():
    """A bar fixed at x = 0 and suddenly loaded by sigma at its free end oscillates (fixed-free period 4 L / c =
    0.4 s) between 0 and twice the static extension: the time average of its tip displacement is sigma X / E.
    Measured over two periods: GIMP 0.6 %, quadratic 1.3 % (the free end's partly filled cell is under-
    integrated); the issue's 2 % is the tolerance."""
    sigma = 1.0
    cfg = tm.load_config(bar(basis="gimp", boundaries=dict(default="free", x_min="sticky"), tractions=[
        dict(region=dict(type="box", lower=[0.9], upper=[1.1]), faces=["x_max"], traction=[sigma])]))
    sim = tm.Simulation(cfg)
    X = sim.scene.x[:, 0]
    tip = int(np.argmax(X))
    mean = _time_average(sim, lambda s: s.particles()["x"][tip, 0] - X[tip], 0.8, 160)
    assert mean == pytest.approx(sigma * X[tip] / E, rel=0.02)


@pytest.mark.slow
def test_traction_work_and_momentum():
    """A free bar pulled at one end by a ramped traction: the momentum equals the traction's impulse up to the
    velocities' time, sim.velocity_time (P2G conserves momentum and the ramp is taken at the middle of each
    leapfrog kick, exact on the linear parts of the ramp: what is left is the kick across its kink, O(dt^2),
    2e-8 measured, 1e-5 allowed) and the traction's work enters the energy balance: kinetic + strain - work stays within 5 % of
    the work (measured -2 %: APIC's dissipation; without the work it would be +100 %)."""
    ramp = "min(t / 0.2, 1)"
    sim = tm.Simulation(tm.load_config(bar(lower=0.5, upper=1.5, end_time=0.4, tractions=[
        dict(region=dict(type="box", lower=[1.45], upper=[1.5]), faces=["x_max"], traction=[2.0], ramp=ramp)])))
    sim.advance_to(0.4)
    impulse = 2.0 * (sim.velocity_time - 0.1)  # integral of 2 min(t / 0.2, 1) over [0, velocity_time > 0.2]
    assert sim.momentum()["linear"][0] == pytest.approx(impulse, rel=1e-5)
    bal = sim.energy_balance()
    assert bal["work"] > 0 and abs(bal["growth"]) < 0.05 * bal["work"]


@pytest.mark.slow
def test_cantilever_tip_load_matches_euler_bernoulli():
    """A 2D plane-strain cantilever clamped by a sticky wall at x = 0, loaded at its free end by a shear traction
    of resultant P, ramped smoothly over two periods of its first bending mode (T1 = 0.59 s), then averaged over
    one period: the tip deflection against Euler-Bernoulli w(X) = P X^2 (3 L - X) / (6 E' I) at the tip particles,
    E' = E / (1 - nu^2) (plane strain), I = h^3 / 12 per metre of depth. L / h = 10: shear adds 0.8 %
    (Timoshenko). Issue 11's tolerance: 5 %."""
    L, h, nu, Emod, P = 1.0, 0.1, 0.3, 1.0e6, 2.0
    dx, T1 = 0.025, 0.59
    cfg = tm.load_config(dict(
        name="cantilever", dim=2, precision="f64", arch="cpu",
        domain=dict(lower=[0.0, 0.0], upper=[1.2, 0.6], dx=dx, boundaries=dict(default="free", x_min="sticky")),
        solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=3 * T1),
        materials=dict(m=dict(model="linear_elastic", E=Emod, nu=nu, density=100.0)),
        bodies=[dict(shape=dict(type="box", lower=[0.0, 0.3], upper=[L, 0.3 + h]), material="m",
                     tractions=[dict(region=dict(type="box", lower=[L - 0.01, 0.2], upper=[L + 0.1, 0.5]),
                                     faces=["x_max"], traction=[0.0, -P / h],
                                     ramp=f"(1 - cos(pi * min(t / {2 * T1}, 1))) / 2")])]))
    sim = tm.Simulation(cfg)
    X = sim.scene.x
    tip = np.flatnonzero(X[:, 0] > L - dx / 2)
    EI = Emod / (1 - nu**2) * h**3 / 12
    expected = float(np.mean(P * X[tip, 0] ** 2 * (3 * L - X[tip, 0]) / (6 * EI)))
    sim.advance_to(2 * T1)
    mean = _time_average(sim, lambda s: X[tip, 1].mean() - s.particles()["x"][tip, 1].mean(), T1, 60)
    print(f"cantilever tip deflection {mean:.5g} m (Euler-Bernoulli {expected:.5g} m)")
    assert mean == pytest.approx(expected, rel=0.05)


# ---------------------------------------------------------------- prescribed velocities
@pytest.mark.slow
def test_grips_pull_a_bar_quasi_statically(tmp_path):
    """Grips at both ends, the left held, the right pulled at 0.01 m/s (c / 1000) after a smooth start: the bar is
    in quasi-static equilibrium, so both grips carry the same force and that force is E delta / L_free with
    L_free = 0.8 m between the grips. Measured: the reaction 1.0 % and the mid-bar stress 1.2 % above it (the grip
    holds every node its particles touch, shortening the free length by less than a cell, 1/32 m = 4 %): 3 %.
    The forces are read from grip probes (probes/NAME.csv, one mean per 0.2 s)."""
    speed = "0.01 * (1 - cos(pi * min(t / 0.4, 1))) / 2"
    cfg = bar(lower=0.5, upper=1.5, end_time=0.8, prescribed_velocity=[
        dict(region=dict(type="box", lower=[0.5], upper=[0.6]), velocity=[0.0]),
        dict(region=dict(type="box", lower=[1.4], upper=[1.5]), velocity=[speed])])
    cfg["output"] = dict(every=0.8, formats=[], probe_every=0.2,
                         probes=[dict(name="left", type="grip", grip=0), dict(name="right", type="grip", grip=1)])
    sim = tm.Simulation(tm.load_config(cfg))
    sim.run(out_dir=tmp_path)
    left, right = (read_probe(tmp_path / "probes" / f"{n}.csv") for n in ("left", "right"))
    assert right["time [s]"][-1] == pytest.approx(0.8)
    force = right["fx [N/m^2]"][-1]                 # mean force of the right grip over [0.6, 0.8]
    delta_mid = 0.01 * (0.7 - 0.2)                  # right grip's displacement at t = 0.7
    p = sim.particles()
    X = sim.scene.x[:, 0]
    assert p["x"][-1, 0] - X[-1] == pytest.approx(0.01 * (0.8 - 0.2), rel=1e-3)  # the grip moved as told
    assert force == pytest.approx(E * delta_mid / 0.8, rel=0.03)
    assert left["fx [N/m^2]"][-1] == pytest.approx(-force, rel=1e-3)             # equilibrium
    mid = np.abs(X - 1.0) < 0.1
    assert p["stress"][mid, 0, 0].mean() == pytest.approx(E * 0.01 * (0.8 - 0.2) / 0.8, rel=0.03)
    bal = sim.energy_balance()                      # the grips' work F . v is the energy put in
    assert abs(bal["growth"]) < 0.01 * bal["work"]


@pytest.mark.slow
def test_velocity_wall_impact_stress_is_rho_c_v():
    """A velocity wall at x_min driving a bar at rest with V: a wave carries the stress -rho c V behind its front,
    and the wall pushes with rho c V (per unit area) until the wave returns (t < 2 L / c = 0.2 s). Measured: force
    0.1 %, stress 0.03 %; 1 % allowed."""
    V = 0.01
    cfg = bar(boundaries=dict(default="free", x_min=dict(type="velocity", velocity=[V])))
    cfg["output"] = dict(probes=[dict(name="piston", type="wall", face="x_min")])
    sim = tm.Simulation(tm.load_config(cfg))
    sim.advance_to(0.02)
    sim.wall_impulse()
    sim.advance_to(0.07)
    force = sim.wall_impulse()[0, 0] / 0.05
    assert force == pytest.approx(RHO * C * V, rel=0.01)
    behind = sim.scene.x[:, 0] < 0.3  # the front is at c t = 0.7 m
    assert sim.particles()["stress"][behind, 0, 0].mean() == pytest.approx(-RHO * C * V, rel=0.01)


@pytest.mark.slow
def test_block_on_a_moving_floor_takes_its_speed():
    """2D: a block resting on a floor (y_min, type velocity) that speeds up to 0.5 m/s. The floor's impulse
    (wall probe) is exactly the block's momentum change (to round-off), and the block's mean velocity averaged over
    [0.2, 0.4] s is the floor's within 5 % (measured 3 %: the block rocks in shear about the belt speed with a period
    4 H / c_s = 0.13 s, so a 0.2 s window is not a whole number of periods)."""
    cfg = dict(name="conveyor", dim=2, precision="f64", arch="cpu",
               domain=dict(lower=[0.0, 0.0], upper=[2.0, 0.5], dx=0.05,
                           boundaries=dict(default="slip",
                                           y_min=dict(type="velocity", velocity=["0.5 * min(t / 0.1, 1)", 0.0]))),
               solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=0.4),
               materials=dict(m=dict(model="neo_hookean", E=1e4, nu=0.3, density=100.0)),
               bodies=[dict(name="block", shape=dict(type="box", lower=[0.2, 0.0], upper=[0.6, 0.2]), material="m")],
               output=dict(probes=[dict(name="floor", type="wall", face="y_min")]))
    sim = tm.Simulation(tm.load_config(cfg))
    mass = sim.scene.mass.sum()
    sim.advance_to(0.2)
    sim.wall_impulse()
    before = sim.momentum()["linear"].copy()
    mean = _time_average(sim, lambda s: s.momentum()["linear"][0] / mass, 0.2, 20)
    impulse = sim.wall_impulse()[2]
    np.testing.assert_allclose(sim.momentum()["linear"] - before, impulse, rtol=1e-9, atol=1e-12)
    assert mean == pytest.approx(0.5, rel=0.05)
    bal = sim.energy_balance()
    assert bal["work"] > 0 and bal["growth"] < 0.01 * bal["work"]  # the belt's work is counted; it only dissipates


def test_expression_errors_exit_2_with_key_and_line(tmp_path, capsys):
    """A bad expression is a config error at load (key and line); one that turns non-finite during the run stops it
    with exit 2 naming the key (docs/contract.md)."""
    import yaml
    from taichi_mpm.cli import main

    cfg = bar(end_time=0.02, tractions=[dict(traction=[1.0], ramp="log(0.01 - t)")])
    cfg["output"] = dict(formats=[], every=0.02)
    path = tmp_path / "bar.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    assert main(["run", str(path), "--quiet", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "bodies.0.tractions.0.ramp" in err and "not a finite number at t=" in err
    bad = path.read_text().replace("log(0.01 - t)", "log(0.01 - t")
    path.write_text(bad)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    line = next(i + 1 for i, text in enumerate(bad.splitlines()) if "ramp" in text)
    assert f"bar.yaml:{line}" in err and "bodies.0.tractions.0.ramp" in err and "never closed" in err
