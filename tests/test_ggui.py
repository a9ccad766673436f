"""The 3D window's choice between Taichi's GGUI scene and the ti.GUI projection, and the GGUI camera's maths without
a Vulkan device; and the GGUI window itself under Xvfb where a Vulkan device answers (Mesa's llvmpipe on a machine
without a GPU: apt-get install xvfb mesa-vulkan-drivers, as .ci/run does), skipped elsewhere."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm.tools import gui
from taichi_mpm.tools.ggui import CHART_VERTICES, PerspectiveView, box_vertices, chart_vertices, particle_data
from test_gui import xvfb  # noqa: F401 (the private X server fixture)


@pytest.mark.parametrize("support, kind, says", [((True, True), "ggui", "GGUI scene, lit spheres"),
                                                 ((True, False), "projection", "no Vulkan device"),
                                                 ((False, False), "projection", "no GGUI")])
def test_view_choice_and_title(support, kind, says):
    cfg = tm.load_config(make_cfg(3))
    assert gui.view_3d_kind(support) == kind
    title = gui.window_title(cfg, support=support)
    assert says in title and title.startswith("taichi-mpm: test [3D:")
    assert gui.window_title(tm.load_config(make_cfg(2)), support=support) == "taichi-mpm: test"  # 2D: no choice
    # the probe on this machine answers with two booleans and the choice follows them
    probed = gui.ggui_support()
    assert all(isinstance(b, bool) for b in probed)
    assert gui.view_3d_kind() == gui.view_3d_kind(probed)


def test_run_gui_opens_the_ggui_window_where_vulkan_answers(monkeypatch):
    """The dispatch: with GGUI and a device (faked here) a 3D scene goes to ggui.run_ggui with a title naming the GGUI
    scene; without a device, or in 2D, it stays in ti.GUI (the window itself runs under Xvfb in test_gui.py)."""
    import taichi_mpm.tools.ggui as ggui

    calls = []
    monkeypatch.setattr(gui, "ggui_support", lambda: (True, True))
    monkeypatch.setattr(ggui, "run_ggui", lambda session, title, *a: calls.append((session, title)) or session.sim)
    cfg = make_cfg(3, dx=0.1, end_time=0.01)
    sim = gui.run_gui(cfg, max_frames=1, show=False)
    assert len(calls) == 1 and "GGUI scene" in calls[0][1] and calls[0][0].sim is sim


def test_perspective_view_matches_ggui_camera_matrices():
    """PerspectiveView projects as GGUI's own camera does (ti.ui.Camera's view and projection matrices, which need no
    Vulkan device): window positions agree to float32 round-off (1e-5); the box fits the window; nearer = larger
    depth; a window drag maps back to the world displacement in the plane through the centre."""
    import taichi as ti

    try:
        camera = ti.ui.Camera()
    except Exception as e:  # a Taichi built without GGUI
        pytest.skip(f"no GGUI camera: {e}")
    view = gui.View(3, [0, 0, 0], [2.0, 1.0, 1.0], (640, 480), yaw=35, pitch=25)
    pv = PerspectiveView(view)
    camera.position(*pv.eye)
    camera.lookat(*pv.center)
    camera.up(*pv.up)
    camera.fov(pv.fov)
    M = np.array(camera.get_projection_matrix(pv.aspect)).T @ np.array(camera.get_view_matrix()).T  # glm: columns
    corners = box_vertices(view.lower, view.upper)
    pts = np.r_[corners, [pv.center], np.random.default_rng(0).uniform([0, 0, 0], [2, 1, 1], (20, 3))]
    clip = np.c_[pts, np.ones(len(pts))] @ M.T
    ggui_window = 0.5 + 0.5 * clip[:, :2] / clip[:, 3:4]
    mine, depth = pv.project(pts)
    np.testing.assert_allclose(mine, ggui_window, atol=1e-5)
    assert np.all((mine[:24] > 0) & (mine[:24] < 1))                  # the camera frames the domain box
    np.testing.assert_allclose(mine[24], [0.5, 0.5], atol=1e-12)
    near, _ = pv.project(np.array([pv.center + 0.1 * pv.toward]))
    assert pv.project(np.array([pv.center + 0.1 * pv.toward]))[1][0] > depth[24]
    np.testing.assert_allclose(near[0], [0.5, 0.5], atol=1e-12)       # along the view axis: the same spot
    d = np.array([0.03, -0.02])
    moved, _ = pv.project(np.array([pv.center + pv.to_world_delta(d)]))
    np.testing.assert_allclose(moved[0] - 0.5, d, atol=1e-12)
    # box edges: 12 edges, each along one axis, each of the domain's length along that axis
    edges = corners.reshape(12, 2, 3)
    lengths = np.abs(edges[:, 1] - edges[:, 0])
    assert np.all((lengths > 0).sum(axis=1) == 1) and sorted(lengths.sum(axis=1)) == [1.0] * 8 + [2.0] * 4


def test_session_drag_through_the_perspective_camera():
    """The GGUI window pushes through its camera: a drag at the projected position of a particle reaches it."""
    sim = tm.Simulation(make_cfg(3, dx=0.1, end_time=1.0))
    s = gui.Session(sim, (320, 240))
    pv = PerspectiveView(s.view)
    x = sim.particles()["x"]
    win, depth = pv.project(x)
    k = int(np.argmax(depth))                        # the particle nearest the camera
    touched = s.drag(win[k], win[k] + [0.02, 0.0], view=pv)
    v = sim.particles()["v"]
    assert touched > 0 and v[k] @ pv.right > 0 and abs(v[k] @ pv.toward) < 1e-12


def test_ggui_frame_data_colours_and_chart():
    """What the GGUI window hands to its fields: float32 centres, colours in [0, 1] that follow the colour field (a
    spinning block: speed grows with the radius, so colours differ), the strip chart padded to its fixed size with
    segments outside the window."""
    sim = tm.Simulation(make_cfg(3, dx=0.1, end_time=1.0))
    x = sim.scene.x - sim.scene.x.mean(axis=0)
    sim.set_particles(v=np.c_[-x[:, 1], x[:, 0], np.zeros(len(x))])
    s = gui.Session(sim, (320, 240))
    s.field = "speed"
    s.limits = s._limits()
    s.advance()
    centres, colours, status = particle_data(s, sim.particles())
    assert centres.dtype == colours.dtype == np.float32 and centres.shape == colours.shape == (sim.n, 3)
    assert colours.min() >= 0.0 and colours.max() <= 1.0 and len(np.unique(colours, axis=0)) > 3
    assert "speed" in status
    verts, cols = chart_vertices(s)
    assert verts.shape == (CHART_VERTICES, 2) and cols.shape == (CHART_VERTICES, 3)
    drawn = verts[:, 0] >= 0
    assert np.all((verts[drawn] >= 0) & (verts[drawn] <= 1)) and np.all(verts[~drawn] == -1.0)
    assert drawn.sum() == 8 + 3 * 2 * (len(s.chart) - 1)   # the frame and three series of len - 1 segments


def test_cli_gui_view_option(tmp_path, monkeypatch):
    """`taichi-mpm gui CONFIG --view ggui|projection` forces the 3D view (auto: the choice above); an unknown view
    exits 2 (argparse's usage error) before anything runs."""
    import yaml

    from taichi_mpm.cli import main

    seen = []
    monkeypatch.setattr(gui, "run_gui", lambda cfg, **kw: seen.append(kw["view"]))
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(make_cfg(3)))
    assert main(["gui", str(path), "--view", "projection"]) == 0
    assert main(["gui", str(path)]) == 0
    assert seen == ["projection", None]
    assert main(["gui", str(path), "--view", "vulkan"]) == 2 and len(seen) == 2


GGUI_SCRIPT = """
import json, sys
import taichi_mpm as tm
from taichi_mpm.tools import gui
cfg = tm.load_config(json.loads(sys.argv[1]))
script = {int(k): [tuple(a) for a in v] for k, v in json.loads(sys.argv[3]).items()}
kind = gui.view_3d_kind()
sim = gui.run_gui(cfg, max_frames=4, screenshot=sys.argv[2], script=script)
p = sim.particles()
print("STATE", json.dumps(dict(kind=kind, time=sim.time, arch=sim.backend.arch, field=None,
                               gravity=sim.gravity.tolist(), v=(p["mass"] @ p["v"] / p["mass"].sum()).tolist())))
"""


def test_ggui_window_runs_under_xvfb_and_saves_an_image(tmp_path, xvfb):  # noqa: F811 (the fixture)
    """The real GGUI loop (ti.ui.Window: lit spheres, the ImGui panel, the strip chart), the solver on the CPU
    backend: four frames of a falling block, the gravity slider set to 0 at frame 2 (the ImGui slider's setter) and
    the colour key at frame 1; the saved image is the window's size, shows the particles (saturated pixels on
    the white background) and the block fell for two frames only."""
    import imageio.v2 as imageio

    built, device = gui.ggui_support()
    if not built:
        pytest.skip("this Taichi has no GGUI")
    if not device:
        pytest.skip("no Vulkan device answers (apt-get install mesa-vulkan-drivers gives llvmpipe)")
    cfg = make_cfg(3, dx=0.1, precision="f32", velocity=[0.5, 0.0, 0.0], end_time=1.0)
    cfg["solver"]["gravity"] = [0.0, -9.81, 0.0]
    cfg["output"] = {"every": 0.002, "render": {"size": [320, 240], "color_by": "speed"}}
    script = {1: [["event", "c"]], 2: [["slider", "gravity", 0.0]]}
    shot = tmp_path / "ggui.png"
    env = dict(os.environ, DISPLAY=xvfb)
    res = subprocess.run([sys.executable, "-c", GGUI_SCRIPT, json.dumps(cfg), str(shot), json.dumps(script)],
                         env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600)   # ImGui writes imgui.ini to its cwd
    assert res.returncode == 0, res.stderr[-3000:]
    state = json.loads(res.stdout.split("STATE")[-1])
    assert state["kind"] == "ggui" and state["arch"] == "cpu"
    assert state["time"] == pytest.approx(4 * 0.002, rel=1e-6)
    assert state["gravity"] == [0.0, 0.0, 0.0]
    assert state["v"][1] == pytest.approx(-9.81 * 2 * 0.002, rel=1e-4)
    img = imageio.imread(shot)
    assert img.shape[:2] == (240, 320)
    rgb = img[..., :3].astype(int)
    assert rgb.var() > 100.0 and len(np.unique(rgb.reshape(-1, 3), axis=0)) > 50
    coloured = (rgb.max(axis=2) - rgb.min(axis=2)) > 80    # the colour-mapped spheres, not the grey box
    h, w = img.shape[:2]
    coloured[:int(0.44 * h), :int(0.32 * w)] = False         # the ImGui panel (its slider bars are blue)
    coloured[:int(0.07 * h), :] = False                      # the status line
    coloured[int(0.70 * h):, int(0.60 * w):] = False         # the energy strip chart (red and blue lines)
    assert coloured.sum() > 200
