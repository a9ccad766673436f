"""The 3D interactive window on Taichi's GGUI (ti.ui.Window): particles as lit spheres with a depth buffer, seen
through a perspective camera that the arrow keys turn; chosen by gui.run_gui where a Vulkan device exists
(gui.view_3d_kind), else the ti.GUI projection is used. The same Session drives both windows (keys, sliders,
switches, push, energy chart); here the sliders and buttons are an ImGui panel.

`PerspectiveView` is the camera's maths in numpy (testable without Vulkan): it places the camera and projects
particles the way GGUI's camera does (glm::lookAt and glm::perspective with a vertical field of view), so that a
mouse drag pushes the particles under the cursor.
"""
from __future__ import annotations

import math

import numpy as np

from .window_layout import CHART, CHART_COLOURS, CHART_LENGTH, HELP, SLIDER_TOLERANCE

FOV = 40.0            # vertical field of view, degrees
PANEL = (0.01, 0.01, 0.30, 0.42)   # the ImGui panel: x, y (from the top-left), width, height in window units
SWITCH_KEYS = ("b", "basis", "t", "transfer")   # keys and button events that restart Taichi (a new Simulation)


def _chart_capacity() -> int:
    return 8 + 3 * 2 * (CHART_LENGTH - 1)   # the frame's 4 segments, 3 series of CHART_LENGTH - 1 segments


CHART_VERTICES = _chart_capacity()


class PerspectiveView:
    """A perspective camera looking at the domain's centre from the direction of a gui.View's yaw and pitch, far
    enough that the domain's bounding sphere fits the window. Same interface as gui.View (project, to_world_delta,
    res, scale) so that gui.push_particles works with it."""

    def __init__(self, view, fov=FOV):
        self.dim, self.res = 3, np.asarray(view.res, float)
        self.center = np.asarray(view.center, float)
        self.right, self.up, self.toward = view.axes()
        self.aspect = self.res[0] / self.res[1]
        self.tan = math.tan(math.radians(fov) / 2)
        radius = 0.5 * float(np.linalg.norm(view.upper - view.lower))
        fit = self.tan * min(1.0, self.aspect)          # the narrower of the two half-angles' tangents
        self.distance = 1.05 * radius * math.sqrt(1 + fit * fit) / fit
        self.eye = self.center + self.distance * self.toward
        self.scale = self.res[1] / (2 * self.distance * self.tan)   # pixels per metre at the centre's depth
        self.fov = fov

    def project(self, x):
        """(N, 3) world positions -> (N, 2) window positions ([0, 1]^2, y up) and (N,) depth (larger = nearer)."""
        r = np.asarray(x, float).reshape(-1, 3) - self.eye
        ahead = np.maximum(-(r @ self.toward), 1e-12)   # distance in front of the camera
        ndc = np.c_[(r @ self.right) / (ahead * self.tan * self.aspect), (r @ self.up) / (ahead * self.tan)]
        return 0.5 + 0.5 * ndc, -ahead

    def to_world_delta(self, d_screen):
        """A displacement in window units -> world displacement in the plane through the centre, facing the camera."""
        d = np.asarray(d_screen, float) * self.res / self.scale
        return d[0] * self.right + d[1] * self.up

    def light(self):
        """A point light above and to the right of the camera (shading that shows the spheres' shape)."""
        return self.eye + 0.6 * self.distance * (self.up + 0.5 * self.right)


def box_vertices(lower, upper) -> np.ndarray:
    """The 12 edges of the domain box as 24 vertex rows (line pairs, GGUI's `lines` order)."""
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    corners = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)])
    pairs = [(i, i | (1 << a)) for i in range(8) for a in range(3) if not (i >> a) & 1]
    return np.array([corners[k] for pair in pairs for k in pair])


def chart_vertices(session):
    """The strip chart's segments as (vertices (M, 2), colours (M, 3)) in GGUI canvas units (y up), padded to
    CHART_VERTICES with segments outside the window (so the fields keep one size)."""
    x0, y0, x1, y1 = CHART
    frame = np.array([[x0, y0], [x1, y0], [x1, y0], [x1, y1], [x1, y1], [x0, y1], [x0, y1], [x0, y0]])
    verts, cols = [frame], [np.full((8, 3), 0.73)]
    for name, (begin, end) in session.chart_lines().items():
        c = CHART_COLOURS[name]
        rgb = np.array([(c >> 16) & 255, (c >> 8) & 255, c & 255]) / 255.0
        verts.append(np.stack([begin, end], axis=1).reshape(-1, 2))
        cols.append(np.tile(rgb, (2 * len(begin), 1)))
    verts, cols = np.concatenate(verts), np.concatenate(cols)
    pad = CHART_VERTICES - len(verts)
    return np.r_[verts, np.full((pad, 2), -1.0)], np.r_[cols, np.ones((pad, 3))]


def particle_data(session, p):
    """(centres (N, 3), colours (N, 3) in [0, 1], both float32, and the status line): what GGUI's particles draw."""
    rgb, status = session.colours(p)
    return p["x"].astype(np.float32), (rgb / 255.0).astype(np.float32), status


class _Buffers:
    """The Taichi fields GGUI draws from; made again after a basis/transfer switch (which restarts Taichi)."""

    def __init__(self, ti, n, box):
        self.centers = ti.Vector.field(3, ti.f32, n)
        self.colours = ti.Vector.field(3, ti.f32, n)
        self.box = ti.Vector.field(3, ti.f32, len(box))
        self.box.from_numpy(box.astype(np.float32))
        self.chart = ti.Vector.field(2, ti.f32, CHART_VERTICES)
        self.chart_colours = ti.Vector.field(3, ti.f32, CHART_VERTICES)

    def set_chart(self, verts, cols):
        self.chart.from_numpy(verts.astype(np.float32))
        self.chart_colours.from_numpy(cols.astype(np.float32))


def run_ggui(session, title, max_frames=None, screenshot=None, show=True, script=None):
    """The GGUI window's loop over a gui.Session (see gui.run_gui for the arguments); returns the last simulation."""
    import taichi as ti

    res = tuple(int(r) for r in session.res)
    window = buffers = shown = None
    frames, prev_cursor = 0, None
    try:
        while True:
            if session.sim is not shown:   # first frame, or a switch restarted Taichi: a new window and fields
                if window is not None:
                    window.destroy()
                window = ti.ui.Window(title, res, vsync=False, show_window=show)
                shown = session.sim
                box = box_vertices(session.cfg.domain.lower, session.cfg.domain.upper)
                buffers = _Buffers(ti, shown.n, box)
                camera = ti.ui.Camera()
            if not window.running:
                break
            keys = _frame_keys(ti, window, session, (script or {}).get(frames, []))
            gui = window.get_gui()
            _control_panel(gui, session, keys)
            if any(k in SWITCH_KEYS for k in keys):   # close the window before the switch restarts Taichi
                window.destroy()
                window = shown = None
            if not all([session.press(k) for k in keys]):
                break
            if session.sim is not shown:
                continue                   # switched (or tried to): a new window for the simulation first
            view = PerspectiveView(session.view)
            cursor = np.asarray(window.get_cursor_pos(), float)
            held = window.is_pressed(ti.ui.LMB) and not _over_panel(cursor)
            if held and prev_cursor is not None:
                session.drag(prev_cursor, cursor, view=view)
            prev_cursor = cursor if held else None
            session.advance()
            _draw(window, gui, session, buffers, camera, view)
            frames += 1
            last = max_frames is not None and frames >= max_frames
            if last and screenshot:
                window.save_image(str(screenshot))
            window.show()
            if last:
                break
    finally:
        if window is not None:
            window.destroy()
    return session.sim


def _frame_keys(ti, window, session, actions) -> list:
    """This frame's key events and scripted actions (a scripted slider move acts as dragging that slider does)."""
    keys = [e.key for e in window.get_events(ti.ui.PRESS)]
    for action in actions:
        if action[0] == "slider":
            next(s for s in session.sliders() if s[0] == action[1])[5](action[2])
        else:
            keys.append(action[1])
    return keys


def _control_panel(gui, session, keys: list):
    """The ImGui panel: sliders (applied when moved), the switch buttons (their events appended to keys), help and
    the session's message."""
    with gui.sub_window("controls", *PANEL) as w:
        for label, lo, hi, _, attr, setter in session.sliders():
            value = w.slider_float(label, float(getattr(session, attr)), float(lo), float(hi))
            if abs(value - getattr(session, attr)) > SLIDER_TOLERANCE:
                setter(value)
        if w.button("next basis"):
            keys.append("basis")
        if w.button("next transfer"):
            keys.append("transfer")
        if session.show_help:
            w.text(HELP)
        if session.message:
            w.text(session.message, color=(0.8, 0.0, 0.0))


def _draw(window, gui, session, buffers, camera, view):
    """The status line, the lit particles and the domain box through the camera, and the energy chart."""
    centres, colours, status = particle_data(session, session.sim.particles())
    buffers.centers.from_numpy(centres)
    buffers.colours.from_numpy(colours)
    with gui.sub_window("status", 0.32, 0.01, 0.67, 0.05) as w:
        w.text(status)
    camera.position(*map(float, view.eye))
    camera.lookat(*map(float, view.center))
    camera.up(*map(float, view.up))
    camera.fov(float(view.fov))
    scene = window.get_scene()
    scene.set_camera(camera)
    scene.ambient_light((0.35, 0.35, 0.35))
    scene.point_light(pos=tuple(map(float, view.light())), color=(0.9, 0.9, 0.9))
    scene.particles(buffers.centers, radius=session.sphere_radius, per_vertex_color=buffers.colours)
    scene.lines(buffers.box, width=1.0, color=(0.6, 0.6, 0.6))
    canvas = window.get_canvas()
    canvas.set_background_color((1.0, 1.0, 1.0))
    canvas.scene(scene)
    verts, cols = chart_vertices(session)
    buffers.set_chart(verts, cols)
    canvas.lines(buffers.chart, width=0.002, per_vertex_color=buffers.chart_colours)


def _over_panel(cursor) -> bool:
    """The cursor is over the ImGui panel (window units, y up; the panel is placed from the top-left)."""
    x, y, w, h = PANEL
    return x <= cursor[0] <= x + w and 1 - y - h <= cursor[1] <= 1 - y
