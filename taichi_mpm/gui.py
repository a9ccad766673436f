"""Interactive window on Taichi's GUI (`taichi-mpm gui CONFIG`).

Keys: space pause/resume, s single step (while paused), r reset, c next colour field,
arrow keys turn a 3D view, h hide/show help, Esc quit. Drag with the left mouse button to push
particles: those near the cursor are pulled towards the drag velocity.

1D bars are drawn along x, 2D scenes as they are, 3D scenes as an orthographic projection that
the arrow keys rotate (ti.GUI draws 2D only; painter's order and depth shading give the 3D cue).
The view logic (`View`) and the push (`push_particles`) are plain numpy, testable without a window.
"""
from __future__ import annotations

import time as _time

import numpy as np

from .render import available_fields, field_values

HELP = "space: pause  s: step  r: reset  c: colour  drag: push  arrows: turn (3D)  esc: quit"


class View:
    """Maps world positions to window coordinates in [0, 1]^2 (ti.GUI's convention, y up) and back."""

    def __init__(self, dim, lower, upper, res, yaw=35.0, pitch=25.0):
        self.dim = dim
        self.lower = np.asarray(lower, float)
        self.upper = np.asarray(upper, float)
        self.res = np.asarray(res, float)
        self.yaw, self.pitch = yaw, pitch
        self.center = 0.5 * (self.lower + self.upper)
        ext = self.upper - self.lower
        w, h = self.res
        band = 0.86 * h  # room for the help line and the colour legend
        if dim == 1:
            self.scale = 0.92 * w / ext[0]
        elif dim == 2:
            self.scale = min(0.92 * w / ext[0], band / ext[1])
        else:
            self.scale = 0.95 * min(w, band) / float(np.linalg.norm(ext))
        self.screen_center = np.array([0.5 * w, 0.5 * h])

    def axes(self):
        """World directions of the screen's right and up axes and of the viewing depth (3D only)."""
        a, b = np.radians(self.yaw), np.radians(self.pitch)
        Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
        R = Rx @ Ry  # world -> camera
        return R[0], R[1], R[2]

    def project(self, x):
        """(N, dim) world positions -> (N, 2) window positions in [0, 1] and (N,) depth (larger = nearer)."""
        x = np.asarray(x, float).reshape(len(x), -1)
        n = len(x)
        if self.dim == 1:
            px = np.c_[(x[:, 0] - self.center[0]) * self.scale, np.zeros(n)]
            depth = np.zeros(n)
        elif self.dim == 2:
            px = (x - self.center) * self.scale
            depth = np.zeros(n)
        else:
            right, up, toward = self.axes()
            r = x - self.center
            px = np.c_[r @ right, r @ up] * self.scale
            depth = r @ toward
        return (px + self.screen_center) / self.res, depth

    def to_world_delta(self, d_screen):
        """A displacement in window units ([0, 1]^2) -> world displacement (in the view plane for 3D)."""
        d_px = np.asarray(d_screen, float) * self.res / self.scale
        if self.dim == 1:
            return np.array([d_px[0]])
        if self.dim == 2:
            return d_px
        right, up, _ = self.axes()
        return d_px[0] * right + d_px[1] * up

    def box_edges(self):
        """Domain outline as (begin, end) window coordinates."""
        lo, hi = self.lower, self.upper
        if self.dim == 1:
            h = 0.02
            pts = np.array([[lo[0]], [hi[0]]])
            p, _ = self.project(pts)
            a, b = p[0], p[1]
            return (np.array([a + [0, -h], a + [0, h], a + [0, -h], b + [0, -h]]),
                    np.array([b + [0, -h], b + [0, h], a + [0, h], b + [0, h]]))
        corners = np.array(np.meshgrid(*[[l, u] for l, u in zip(lo, hi)], indexing="ij")).reshape(self.dim, -1).T
        idx = np.arange(len(corners))
        pairs = [(i, j) for i in idx for j in idx if i < j and np.sum(corners[i] != corners[j]) == 1]
        p, _ = self.project(corners)
        return np.array([p[i] for i, _ in pairs]), np.array([p[j] for _, j in pairs])


def push_particles(sim, center, velocity, radius, positions=None, view=None):
    """Pull the velocities of particles near `center` towards `velocity`: v += w (velocity - v),
    w = exp(-(r / radius)^2) for r < 2 radius. `center` and `radius` are in world units, or, with a
    `view`, in window units measured on the projected positions (a 3D push acts through the depth).
    Returns the number of particles touched."""
    p = sim.particles()
    x = p["x"] if positions is None else positions
    if view is not None:
        xs, _ = view.project(x)
        r = np.linalg.norm((xs - np.asarray(center, float)) * view.res / view.res.max(), axis=1)
    else:
        r = np.linalg.norm(np.asarray(x, float).reshape(len(x), -1) - np.asarray(center, float), axis=1)
    near = r < 2 * radius
    if not near.any():
        return 0
    w = np.exp(-(r[near] / radius) ** 2)[:, None]
    v = p["v"].reshape(len(r), -1).copy()
    v[near] += w * (np.asarray(velocity, float) - v[near])
    sim.set_particles(v=v)
    return int(near.sum())


def _colour_ints(values, clim, cmap_name):
    import matplotlib

    cmap = matplotlib.colormaps[cmap_name]
    lo, hi = clim
    t = np.clip((values - lo) / (hi - lo if hi > lo else 1.0), 0, 1)
    rgb = (cmap(t)[:, :3] * 255).astype(np.uint32)
    return rgb


def _pack(rgb):
    rgb = rgb.astype(np.uint32)
    return (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]


class _Limits:
    """Colour limits that only widen while one field is shown (reset when the field changes)."""

    def __init__(self, fixed=None):
        self.lim = None
        self.fixed = list(fixed) if fixed else None

    def update(self, values, name):
        if self.fixed:
            return self.fixed
        if name == "body":
            return [-0.5, max(float(values.max()) + 0.5, 1.5)]
        finite = values[np.isfinite(values)]
        lo, hi = (float(finite.min()), float(finite.max())) if len(finite) else (0.0, 1.0)
        if self.lim is not None:
            lo, hi = min(lo, self.lim[0]), max(hi, self.lim[1])
        self.lim = [lo, hi]
        if hi - lo < 1e-6 * max(1.0, abs(hi)):
            return [lo - 1.0, hi + 1.0] if hi == 0 else [lo - 0.5 * abs(hi), hi + 0.5 * abs(hi)]
        return self.lim


class Session:
    """The window's state machine without the window: keys, mouse drags, stepping and what to draw."""

    def __init__(self, sim, res):
        self.sim, self.cfg = sim, sim.cfg
        c = self.cfg
        self.initial = sim.get_state()
        self.view = View(c.dim, c.domain.lower, c.domain.upper, res)
        self.fields = available_fields(sim.particles(), c.dim)
        self.field = c.output.render.color_by if c.output.render.color_by in self.fields else self.fields[0]
        self.cmap = c.output.render.colormap
        self.limits = self._limits()
        self.frame_time = c.output.every
        self.radius_px = max(1.0, 0.6 * float(np.median(sim.scene.spacing)) * self.view.scale)
        wave = float(getattr(sim, "wave_speed", 0.0) or 0.0)
        self.speed_cap = 0.25 * wave if wave > 0 else 10.0
        self.paused, self.message, self.show_help = False, "", True
        self._step_once = False

    def _limits(self):
        r = self.cfg.output.render
        return _Limits(r.clim if self.field == r.color_by else None)  # the config's limits belong to its field

    def press(self, key) -> bool:
        """Handle one key (ti.GUI key names); False means quit."""
        import taichi as ti

        if key in (ti.GUI.ESCAPE, ti.GUI.EXIT):
            return False
        if key == ti.GUI.SPACE:
            self.paused = not self.paused
        elif key == "s":
            self.paused, self._step_once = True, True
        elif key == "r":
            self.sim.set_state(self.initial)
            self.limits, self.message = self._limits(), ""
        elif key == "c":
            self.field = self.fields[(self.fields.index(self.field) + 1) % len(self.fields)]
            self.limits = self._limits()
        elif key == "h":
            self.show_help = not self.show_help
        elif key == ti.GUI.LEFT:
            self.view.yaw -= 10
        elif key == ti.GUI.RIGHT:
            self.view.yaw += 10
        elif key == ti.GUI.UP:
            self.view.pitch = min(89.0, self.view.pitch + 10)
        elif key == ti.GUI.DOWN:
            self.view.pitch = max(-89.0, self.view.pitch - 10)
        return True

    def drag(self, prev, cursor, radius=0.06) -> int:
        """A mouse drag from prev to cursor (window units): push the particles under the cursor."""
        u = self.view.to_world_delta(np.asarray(cursor, float) - np.asarray(prev, float)) / self.frame_time
        speed = float(np.linalg.norm(u))
        if speed == 0:
            return 0
        if speed > self.speed_cap:
            u *= self.speed_cap / speed
        return push_particles(self.sim, cursor, u, radius=radius, view=self.view)

    def advance(self):
        """One frame: a single step when asked, else one output interval unless paused or done."""
        from .errors import InstabilityError

        try:
            if self._step_once:
                self.sim.step()
            elif not self.paused and not self.done:
                self.sim.advance(min(self.frame_time, self.cfg.solver.end_time - self.sim.time))
        except InstabilityError as err:
            self.paused, self.message = True, f"unstable: {err}  (r: reset)"
        stepped, self._step_once = self._step_once, False
        return stepped

    @property
    def done(self) -> bool:
        end = self.cfg.solver.end_time
        return self.sim.time >= end - 1e-12 * max(1.0, end)

    def picture(self):
        """(positions, packed colours) in drawing order, and the status line."""
        p = self.sim.particles()
        values = field_values(p, self.field, self.cfg.dim)
        clim = self.limits.update(values, self.field)
        pos, depth = self.view.project(p["x"])
        rgb = _colour_ints(values, clim, "tab10" if self.field == "body" else self.cmap)
        if self.cfg.dim == 3:  # painter's order and depth shading: far particles first and darker
            order = np.argsort(depth)
            span = float(np.ptp(depth)) or 1.0
            shade = 0.55 + 0.45 * (depth - depth.min()) / span
            rgb = (rgb * shade[:, None]).astype(np.uint32)
            pos, rgb = pos[order], rgb[order]
        state = "paused" if self.paused else ("done" if self.done else "running")
        status = (f"t = {self.sim.time:.4g} s   steps {self.sim.n_steps}   {state}   colour: {self.field} "
                  f"[{clim[0]:.3g}, {clim[1]:.3g}]")
        return pos, _pack(rgb), status


def run_gui(cfg, max_frames=None, screenshot=None, show=True):
    """Open the interactive window for a config (path, dict or Config). With `max_frames` the window
    closes by itself after that many frames; `screenshot` saves the last frame as a PNG."""
    import taichi as ti

    from .config import load_config
    from .runner import Simulation  # resolves arch auto without Taichi's crashing OpenGL probe

    cfg = cfg if hasattr(cfg, "model_dump") else load_config(cfg)
    res = tuple(int(s) for s in cfg.output.render.size)
    session = Session(Simulation(cfg), res)
    gui = ti.GUI(f"taichi-mpm: {cfg.name}", res=res, background_color=0xFFFFFF, show_gui=show)
    prev_cursor = None
    frames = 0
    try:
        while gui.running:
            if not all([session.press(e.key) for e in gui.get_events(ti.GUI.PRESS)]):
                break
            cursor = np.asarray(gui.get_cursor_pos(), float)
            held = gui.is_pressed(ti.GUI.LMB)
            if held and prev_cursor is not None:
                session.drag(prev_cursor, cursor)
            prev_cursor = cursor if held else None
            stepped = session.advance()
            pos, colours, status = session.picture()
            begin, end = session.view.box_edges()
            gui.lines(begin, end, radius=1, color=0x999999)
            gui.circles(pos, radius=session.radius_px, color=colours)
            gui.text(status, pos=(0.01, 0.99), font_size=16, color=0x000000)
            if session.show_help:
                gui.text(HELP if res[0] >= 700 else "space s r c drag arrows esc", pos=(0.01, 0.05), font_size=14,
                         color=0x444444)
            if session.message:
                gui.text(session.message, pos=(0.01, 0.94), font_size=16, color=0xCC0000)
            frames += 1
            last = max_frames is not None and frames >= max_frames
            gui.show(str(screenshot) if (last and screenshot) else None)
            if last:
                break
            if (session.paused or session.done) and not stepped:
                _time.sleep(0.01)
    finally:
        gui.close()
    return session.sim
