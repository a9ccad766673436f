"""The interactive window: view maths and the mouse push without a window; a few frames under Xvfb
with a screenshot (skipped when Xvfb is not installed)."""
import json
import os
import select
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm.tools.gui import Session, View, push_particles


def test_view_2d_maps_domain_into_window_and_back():
    view = View(2, [0, 0], [2, 1], (400, 300))
    pos, _ = view.project(np.array([[0.0, 0.0], [2.0, 1.0], [1.0, 0.5]]))
    assert np.all(pos >= 0) and np.all(pos <= 1)
    np.testing.assert_allclose(pos[2], [0.5, 0.5])
    # a window displacement maps back to the world displacement that produced it
    d_world = np.array([0.3, -0.2])
    p2, _ = view.project(np.array([[1.0, 0.5]]) + d_world)
    np.testing.assert_allclose(view.to_world_delta(p2[0] - pos[2]), d_world, atol=1e-12)


def test_view_3d_projection_is_a_rotation():
    view = View(3, [0, 0, 0], [1, 1, 1], (500, 500), yaw=30, pitch=20)
    right, up, toward = view.axes()
    M = np.array([right, up, toward])
    np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-12)
    pos, depth = view.project(np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5] + 0.1 * toward]))
    np.testing.assert_allclose(pos[0], pos[1], atol=1e-12)  # moving along the view axis does not move on screen
    assert depth[1] > depth[0]
    d = np.array([0.02, -0.01])
    w = view.to_world_delta(d)
    p2, _ = view.project(np.array([[0.5, 0.5, 0.5]]) + w)
    np.testing.assert_allclose(p2[0] - pos[0], d, atol=1e-12)


def test_push_pulls_only_nearby_particles_towards_the_drag_velocity():
    sim = tm.Simulation(make_cfg(2, dx=0.1, end_time=0.01))
    x = sim.particles()["x"]
    center = x[0]
    n = push_particles(sim, center, [2.0, 0.0], radius=0.05)
    v = sim.particles()["v"]
    r = np.linalg.norm(x - center, axis=1)
    assert n == int(np.sum(r < 0.1)) and 0 < n < len(x)
    np.testing.assert_allclose(v[0], [2.0, 0.0], atol=1e-12)           # w = 1 at the cursor
    np.testing.assert_allclose(v[r >= 0.1], 0.0)                        # far particles untouched
    inner = (r > 0) & (r < 0.1)
    np.testing.assert_allclose(v[inner, 0], 2.0 * np.exp(-(r[inner] / 0.05) ** 2), rtol=1e-9)


@pytest.mark.slow
def test_session_keys_pause_step_reset_and_colour():
    import taichi as ti

    cfg = make_cfg(2, dx=0.1, velocity=[0.5, 0.0], end_time=1.0)
    cfg["output"] = {"every": 0.01}
    sim = tm.Simulation(cfg)
    s = Session(sim, (300, 300))
    x0 = sim.particles()["x"].copy()
    s.advance()                                   # running: one output interval per frame
    assert sim.time == pytest.approx(0.01)
    assert s.press(ti.GUI.SPACE) and s.paused
    t = sim.time
    s.advance()
    assert sim.time == t                          # paused: nothing moves
    n = sim.n_steps
    s.press("s")
    s.advance()
    assert sim.n_steps == n + 1 and sim.time > t  # a single step
    s.advance()
    assert sim.n_steps == n + 1                   # and only one
    first = s.field
    s.press("c")
    assert s.field != first and s.field in s.fields
    pos, colours, status = s.picture()
    assert pos.shape == (sim.n, 2) and colours.shape == (sim.n,) and s.field in status
    s.press("r")
    assert sim.time == 0.0 and sim.n_steps == 0
    np.testing.assert_array_equal(sim.particles()["x"], x0)
    # a drag to the right pushes the particles under the cursor to +x, capped at a quarter wave speed
    s.press(ti.GUI.SPACE)
    assert not s.paused
    xs, _ = s.view.project(x0)
    touched = s.drag(xs[0], xs[0] + [0.05, 0.0])
    v = sim.particles()["v"]
    assert touched > 0 and v[0, 0] > 0.5 and v[0, 0] <= s.speed_cap + 1e-9
    assert not s.press(ti.GUI.ESCAPE)


@pytest.fixture(scope="module")
def xvfb():
    """A private X server on a display number Xvfb picks itself (-displayfd: no race with other tests)."""
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.skip("Xvfb is not installed")
    r, w = os.pipe()
    proc = subprocess.Popen([exe, "-displayfd", str(w), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, pass_fds=(w,))
    os.close(w)
    number = b""
    deadline = time.time() + 10
    while time.time() < deadline and not number.endswith(b"\n"):
        if not select.select([r], [], [], 0.2)[0]:
            continue
        chunk = os.read(r, 16)
        if not chunk:
            break
        number += chunk
    os.close(r)
    if not number.strip():
        proc.kill()
        pytest.skip("Xvfb did not start")
    yield f":{int(number)}"
    proc.terminate()
    proc.wait(10)


GUI_SCRIPT = """
import json, sys
import taichi_mpm as tm
from taichi_mpm.tools.gui import run_gui
cfg = tm.load_config(json.loads(sys.argv[1]))
script = {int(k): [tuple(a) for a in v] for k, v in json.loads(sys.argv[3]).items()}
sim = run_gui(cfg, max_frames=4, screenshot=sys.argv[2], script=script)
p = sim.particles()
print("STATE", json.dumps(dict(time=sim.time, basis=sim.cfg.solver.basis, cfl=sim.cfg.solver.cfl,
                               gravity=sim.gravity.tolist(), stiffness=sim.stiffness_scale(),
                               flip_blend=sim.flip_blend,
                               v=(p["mass"] @ p["v"] / p["mass"].sum()).tolist())))
"""


@pytest.mark.parametrize("dim", [2, pytest.param(3, marks=pytest.mark.slow)])
def test_gui_runs_under_xvfb_and_saves_a_screenshot(tmp_path, xvfb, dim):
    """A few frames in a real window; in 2D the time-step and stiffness sliders are moved (frame 1) and the basis
    switched (frame 2, the "next basis" button's event), so the window's widgets reach the simulation; in 3D (FLIP)
    the block falls under gravity for two frames, then the gravity slider goes to 0 (frame 2) and it stops
    accelerating."""
    import imageio.v2 as imageio

    cfg = make_cfg(dim, precision="f32", velocity=[0.5] + [0.0] * (dim - 1), end_time=1.0,
                   transfer="apic" if dim == 2 else "flip")
    cfg["solver"]["cfl"] = 0.4
    cfg["output"] = {"every": 0.002, "render": {"size": [320, 240], "color_by": "speed"}}
    if dim == 2:
        script = {1: [["slider", "time-step scale", 0.5], ["slider", "stiffness scale", 2.0]], 2: [["event", "basis"]]}
    else:
        cfg["solver"]["gravity"] = [0.0, -9.81, 0.0]
        script = {2: [["slider", "gravity", 0.0]]}
    shot = tmp_path / "shot.png"
    env = dict(os.environ, DISPLAY=xvfb)
    res = subprocess.run([sys.executable, "-c", GUI_SCRIPT, json.dumps(cfg), str(shot), json.dumps(script)], env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    state = json.loads(res.stdout.split("STATE")[-1])
    if dim == 2:
        # quadratic -> cubic restarted the scene at frame 2: two frames (2 and 3) of one output interval since;
        # the slider's half time step carried over to the new simulation
        assert state["basis"] == "cubic"
        assert state["cfl"] == pytest.approx(0.2)
        assert state["time"] == pytest.approx(2 * 0.002, rel=1e-6)
        assert state["stiffness"] == pytest.approx(2.0)              # the stiffness slider's value carried over too
    else:
        assert state["basis"] == "quadratic" and state["cfl"] == pytest.approx(0.4)
        assert state["time"] == pytest.approx(4 * 0.002, rel=1e-6)  # four frames, one output interval each
        # gravity for frames 0 and 1 only: the fall speed of two frames, not four (f32: 1e-4 is round-off)
        assert state["gravity"] == [0.0, 0.0, 0.0]
        assert state["v"][1] == pytest.approx(-9.81 * 2 * 0.002, rel=1e-4)
        assert state["v"][0] == pytest.approx(0.5, rel=1e-4)
        assert state["flip_blend"] == 0.99   # untouched: the widget's float32 copy of 0.99 is not a move
    img = imageio.imread(shot)
    assert img.shape[:2] == (240, 320)
    assert img[..., :3].astype(float).var() > 100.0
    assert len(np.unique(img[..., :3].reshape(-1, 3), axis=0)) > 10


def test_session_sliders_switch_and_energy_chart():
    """Without a window: the time-step scale reaches the solver's dt, the push strength scales the push, the
    energy chart follows the energies, a transfer switch restarts the scene."""
    cfg = make_cfg(2, dx=0.1, velocity=[0.5, 0.0], end_time=1.0)
    cfg["output"] = {"every": 0.01}
    sim = tm.Simulation(cfg)
    s = Session(sim, (300, 300))
    dt_full = min(sim.dt_limits().values())
    s.set_dt_scale(0.25)
    assert min(sim.dt_limits().values()) == pytest.approx(0.25 * dt_full, rel=1e-12)
    s.advance()
    s.advance()
    assert len(s.chart) == 3
    kin, strain, total = s.chart[-1]
    e = sim.energy()
    assert kin == pytest.approx(e["kinetic"]) and strain == pytest.approx(e["strain"])
    assert total == pytest.approx(s.chart[0][2], rel=1e-3)        # a free elastic block: energy is conserved
    lines = s.chart_lines()
    assert set(lines) == {"kinetic", "strain", "total"} and lines["kinetic"][0].shape == (2, 2)
    x0, y0, x1, y1 = __import__("taichi_mpm.tools.gui", fromlist=["CHART"]).CHART
    for begin, end in lines.values():
        assert np.all(begin[:, 0] >= x0) and np.all(end[:, 0] <= x1) and np.all(begin[:, 1] <= y1 + 1e-12)
    # push strength: half strength moves the particle under the cursor half way to the drag velocity
    x = sim.particles()["x"]
    push_particles(sim, x[0], [2.0, 0.0], radius=0.05, strength=0.5)
    assert sim.particles()["v"][0, 0] == pytest.approx(0.5 + 0.5 * (2.0 - 0.5))
    assert s.switch("transfer")                                   # apic -> mls: a new simulation from t = 0
    assert s.sim is not sim and s.sim.cfg.solver.transfer == "mls" and s.sim.time == 0.0
    assert s.sim.cfg.solver.cfl == pytest.approx(0.25 * s.base_cfl)  # the scale carries over to the new scene
    assert not s.switch("basis", "wavelet") and "not possible" in s.message


@pytest.mark.slow
def test_session_gravity_stiffness_and_flip_sliders_reach_the_solver():
    """Without a window: the gravity, stiffness and FLIP-blend setters change the running simulation (no restart),
    the chart's total stays level across a gravity change (its potential reference moves with the jump), and a
    transfer switch carries the values over to the new simulation."""
    cfg = make_cfg(2, dx=0.1, end_time=1.0, gravity=[0.0, -9.81])
    cfg["output"] = {"every": 0.01}
    sim = tm.Simulation(cfg)
    s = Session(sim, (300, 300))
    assert s.gravity == pytest.approx(9.81) and {x[0] for x in s.sliders()} >= {"gravity", "stiffness scale",
                                                                                 "FLIP blend"}
    s.advance()
    total = s.chart[-1][2]
    s.set_gravity(0.0)
    assert s.sim is sim and np.all(sim.gravity == 0.0)
    s.record_energy()
    assert s.chart[-1][2] == pytest.approx(total, rel=1e-12)        # no step since: the total did not move
    # leapfrog: the velocities lag half a step behind the positions, and that half kick still belongs to the old
    # gravity (at most M g dt / 2); after it, no gravity and no wall reached: no force
    v, mass = sim.momentum()["linear"].copy(), sim.scene.mass.sum()
    s.advance()
    assert 0.0 < v[1] - sim.momentum()["linear"][1] <= mass * 9.81 * 0.5 * sim.dt * (1 + 1e-9)
    v = sim.momentum()["linear"].copy()
    s.advance()
    np.testing.assert_allclose(sim.momentum()["linear"], v, atol=1e-9)
    c0 = sim.wave_speed
    s.set_stiffness(4.0)
    assert sim.stiffness_scale() == 4.0 and sim.wave_speed == pytest.approx(2.0 * c0, rel=1e-12)
    assert not s.set_flip_blend(0.3) and "transfer flip" in s.message   # apic: kept for a switch to flip
    assert s.switch("transfer", "flip")
    assert s.sim.flip_blend == pytest.approx(0.3) and s.sim.stiffness_scale() == 4.0
    assert np.all(s.sim.gravity == 0.0)


def mapped_scene():
    """tests/test_mapped.py's stretch scene (its kernels): an elastic ring in the full annulus, here spinning."""
    from test_mapped import ring_cfg

    cfg = ring_cfg(walls="free", model="neo_hookean")
    cfg["bodies"][0]["angular_velocity"] = 1.0
    cfg["solver"]["end_time"] = 1.0
    cfg["output"] = {"every": 0.02, "render": {"size": [300, 300], "color_by": "speed"}}
    return cfg


@pytest.mark.slow
def test_session_on_a_mapped_grid_draws_its_cells_and_runs():
    """A mapped scene in the windowless session: the cell edges of the annulus (render.grid_lines: 25 spokes and
    5 circles) as window segments, which map back to the circles r = 0.5 .. 1.0 (1e-12: the view is affine);
    frames advance, a drag pushes, the basis switch to cubic restarts it on the map raised to degree 3, and one the
    map refuses (linear) leaves the scene running with a message."""
    import taichi as ti

    sim = tm.Simulation(mapped_scene())
    s = Session(sim, (300, 300))
    begin, end = s.grid_segments
    assert len(begin) == len(end) == 25 * 4 * 12 + 5 * 24 * 12   # 12 segments per cell edge
    assert np.all((begin >= 0) & (begin <= 1)) and np.all((end >= 0) & (end <= 1))
    centre, _ = s.view.project(np.zeros((1, 2)))
    radii = np.linalg.norm([s.view.to_world_delta(p - centre[0]) for p in end], axis=1)
    for r in 0.5 + 0.125 * np.arange(5):            # every radial knot's circle is drawn
        assert np.abs(radii - r).min() < 1e-12
    s.advance()
    assert sim.time == pytest.approx(0.02)
    pos, colours, status = s.picture()
    assert pos.shape == (sim.n, 2) and np.all((pos > 0) & (pos < 1))
    xs, _ = s.view.project(sim.particles()["x"])
    assert s.drag(xs[0], xs[0] + [0.02, 0.0]) > 0
    assert s.press("b") and s.sim is not sim                      # quadratic -> cubic: the map raised to degree 3
    assert s.sim.cfg.solver.basis == "cubic" and "restarted" in s.message
    sim = s.sim
    assert s.press("b") and s.sim is sim                          # cubic -> linear: refused for a map
    assert "not possible" in s.message and "quadratic or cubic" in s.message
    t = sim.time
    assert s.press(ti.GUI.SPACE) and s.paused
    assert s.advance() is False and sim.time == t                 # paused: the same scene, not moving
    assert Session(tm.Simulation(make_cfg(2, dx=0.1)), (300, 300)).grid_segments is None   # no map: no cells


@pytest.mark.slow   # a window of its own (Xvfb); the default run keeps the 2D slider/switch window
def test_gui_draws_a_mapped_grid_under_xvfb(tmp_path, xvfb):
    """The window on a mapped scene: two frames and a screenshot holding the grid's light grey (0xCCCCCC) lines."""
    import imageio.v2 as imageio

    shot = tmp_path / "shot.png"
    env = dict(os.environ, DISPLAY=xvfb)
    res = subprocess.run([sys.executable, "-c", GUI_SCRIPT, json.dumps(mapped_scene()), str(shot), "{}"], env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    state = json.loads(res.stdout.split("STATE")[-1])
    assert state["time"] == pytest.approx(4 * 0.02, rel=1e-6)
    img = imageio.imread(shot)[..., :3]
    grey = (img == [0xCC, 0xCC, 0xCC]).all(axis=-1)
    assert grey.sum() > 300


@pytest.mark.parametrize("environ, says", [({}, "DISPLAY is not set"),
                                           ({"WAYLAND_DISPLAY": "wayland-0"}, "Wayland session without XWayland"),
                                           ({"DISPLAY": ":65000"}, "no X server answers on DISPLAY=:65000")])
def test_gui_without_a_display_says_what_is_missing_and_exits_2(tmp_path, monkeypatch, capsys, environ, says):
    """`taichi-mpm gui` where no window can open: before anything starts (no Taichi traceback, no exit from inside
    GLFW), one line naming what is missing and what to do instead (Xvfb, `render`, `compare`), exit 2."""
    import yaml

    from taichi_mpm.tools import gui
    from taichi_mpm.cli import main

    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    for name, value in environ.items():
        monkeypatch.setenv(name, value)
    monkeypatch.setattr(gui, "Session", lambda *a: pytest.fail("the window's session started without a display"))
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(make_cfg(2)))
    if sys.platform in ("darwin", "win32"):
        pytest.skip("windows open without DISPLAY here")
    assert main(["gui", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("taichi-mpm: error: gui: no ")
    assert says in err and "Traceback" not in err
    assert all(word in err for word in ("xvfb-run", "taichi-mpm render", "taichi-mpm compare"))
    assert gui.display_problem({"DISPLAY": ":65000"}) == "no X server answers on DISPLAY=:65000"
