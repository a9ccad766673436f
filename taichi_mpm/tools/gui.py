"""Interactive window on Taichi's GUI (`taichi-mpm gui CONFIG`).

Keys: space pause/resume, s single step (while paused), r reset, c next colour field, b next basis, t next
transfer, arrow keys turn a 3D view, h hide/show help, Esc quit. Drag with the left mouse button to push
particles: those near the cursor are pulled towards the drag velocity.

Side panel (ti.GUI widgets): sliders for what changes without a recompile: the time-step scale (solver.cfl is read
on the host when each dt is chosen), the push strength, gravity (m/s^2 along the config's gravity direction, or
down the last screen axis), the stiffness scale of every material and FLIP's blend (the solver's runtime
parameters, Simulation.set_gravity / set_stiffness_scale / set_flip_blend); buttons that switch the basis or the
transfer, which restart the scene (those are compile-time choices; the sliders' values carry over). A strip chart
at the bottom right draws the kinetic, strain and total energy of the last frames.

1D bars are drawn along x, 2D scenes as they are (a mapped grid's cells, domain.map, behind the particles). A 3D
scene opens Taichi's GGUI scene (ggui.py: lit spheres, a depth buffer, a perspective camera) where GGUI is built in
and a Vulkan device answers (`view_3d_kind`), else an orthographic projection in ti.GUI, painter-ordered and
depth-shaded; the arrow keys turn either, and the title says which is used and, for the fallback, why. Colour
limits are robust (percentiles of the recent frames, colour_range.LiveLimits). The view logic (`View`), the push
(`push_particles`) and the session (`Session`: keys, sliders, switches, chart) are plain numpy, testable without a
window.
"""
from __future__ import annotations

import os
import sys
import time as _time

import numpy as np

from .. import schemes as transfer_schemes
from ..bases import registry as basis_registry
from ..io.colour_range import LiveLimits
from ..io.render import available_fields, field_values
from .window_layout import CHART, CHART_COLOURS, CHART_LENGTH, HELP, SLIDER_TOLERANCE

TRANSFERS = transfer_schemes.names()   # every registered scheme (schemes/); the switch skips those the basis lacks


def _next_option(options, current, basis=None):
    """The option after `current` (cyclic; the first when `current` is not listed); for transfers, the next one
    the basis works with (schemes/: a scheme's basis_need reads the basis' declaration)."""
    start = options.index(current) + 1 if current in options else 0
    for k in range(len(options)):
        value = options[(start + k) % len(options)]
        if basis is None or transfer_schemes.works_with(value, basis):
            return value
    return options[start % len(options)]


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


def push_particles(sim, center, velocity, radius, positions=None, view=None, strength=1.0):
    """Pull the velocities of particles near `center` towards `velocity`: v += strength w (velocity - v),
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
    w = strength * np.exp(-(r[near] / radius) ** 2)[:, None]
    v = p["v"].reshape(len(r), -1).copy()
    v[near] += w * (np.asarray(velocity, float) - v[near])
    sim.set_particles(v=v)
    return int(near.sum())


def _colour_ints(t, cmap_name):
    """Colour-map positions t in [0, 1] -> (N, 3) 8-bit RGB."""
    import matplotlib

    cmap = matplotlib.colormaps[cmap_name]
    return (cmap(np.clip(t, 0, 1))[:, :3] * 255).astype(np.uint32)


def _pack(rgb):
    rgb = rgb.astype(np.uint32)
    return (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]


class NoDisplay(RuntimeError):
    """No window can open here; the message says what is missing and what to do instead (the CLI exits 2)."""


NO_DISPLAY_ADVICE = ("start it under a virtual X server (xvfb-run -a taichi-mpm gui CONFIG; Debian/Ubuntu: apt-get "
                     "install xvfb), or make pictures without a window: taichi-mpm run CONFIG writes frames and a "
                     "movie, taichi-mpm render RUN_DIR renders a run's snapshots again, taichi-mpm compare CONFIG "
                     "--vary KEY=A,B puts runs side by side")


def display_problem(environ=None) -> str | None:
    """Why no window can open on this machine, or None. Taichi's windows (ti.GUI and GGUI's GLFW) are X11 windows on
    Linux and the BSDs: without DISPLAY, or with one no X server answers, ti.GUI ends in a traceback and GGUI exits
    the process ("cannot initialize GLFW"), so this is asked before anything starts. macOS and Windows: None."""
    environ = os.environ if environ is None else environ
    if sys.platform in ("darwin", "win32", "cygwin"):
        return None
    display = environ.get("DISPLAY", "")
    if not display:
        wayland = " (a Wayland session without XWayland: Taichi opens X11 windows only)" if environ.get(
            "WAYLAND_DISPLAY") else ""
        return f"no display to open a window on: DISPLAY is not set{wayland}"
    if _x11_answers(display) is False:
        return f"no X server answers on DISPLAY={display}"
    return None


def _x11_answers(display: str) -> bool | None:
    """Whether an X server accepts a connection on `display` (XOpenDisplay); None where libX11 cannot be loaded."""
    import ctypes

    try:
        x11 = ctypes.CDLL("libX11.so.6")
    except OSError:
        return None
    x11.XOpenDisplay.restype, x11.XOpenDisplay.argtypes = ctypes.c_void_p, [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = x11.XOpenDisplay(display.encode())
    if not handle:
        return False
    x11.XCloseDisplay(handle)
    return True


def check_display():
    """Raise NoDisplay (what is missing, what to do instead) where no window can open."""
    problem = display_problem()
    if problem:
        raise NoDisplay(f"{problem}; {NO_DISPLAY_ADVICE}")


def ggui_support() -> tuple[bool, bool]:
    """(GGUI built into this Taichi, a Vulkan device answers). Taichi's own probe (with_vulkan) creates a Vulkan
    instance and asks for a device; any failure counts as no device."""
    try:
        from taichi._lib import core

        built = bool(getattr(core, "GGUI_AVAILABLE", False))
        return built, built and bool(core.with_vulkan())
    except Exception:
        return False, False


def view_3d_kind(support: tuple[bool, bool] | None = None) -> str:
    """Which 3D view the window gives: 'ggui' (Taichi's GGUI scene: lit spheres, a depth buffer, a perspective
    camera) where GGUI is built in and a Vulkan device answers, else 'projection' (ti.GUI points in painter's order,
    depth-shaded). `support`: ggui_support()'s answer (probed when None)."""
    built, device = support if support is not None else ggui_support()
    return "ggui" if built and device else "projection"


def window_title(cfg, kind: str | None = None, support: tuple[bool, bool] | None = None) -> str:
    """The title names the 3D view in use and, for the fallback, why GGUI is not used."""
    if cfg.dim < 3:
        return f"taichi-mpm: {cfg.name}"
    support = support if support is not None else ggui_support()
    kind = kind or view_3d_kind(support)
    if kind == "ggui":
        return f"taichi-mpm: {cfg.name} [3D: GGUI scene, lit spheres with depth]"
    why = ("this Taichi has no GGUI" if not support[0] else "no Vulkan device for a GGUI scene" if not support[1]
           else "chosen instead of the GGUI scene")
    return f"taichi-mpm: {cfg.name} [3D: projected, depth-shaded points; {why}]"


GRAVITY_MAX = 20.0                 # m/s^2: the gravity slider's range (at least the config's |g|)
STIFFNESS_RANGE = (0.1, 4.0)       # the stiffness-scale slider's range


def down_direction(cfg) -> np.ndarray:
    """The unit vector the gravity slider acts along: the config's gravity direction, else -y (-x in 1D)."""
    g = np.asarray(cfg.gravity, float)
    n = float(np.linalg.norm(g))
    if n > 0:
        return g / n
    d = np.zeros(cfg.dim)
    d[min(cfg.dim, 2) - 1] = -1.0
    return d


class Session:
    """The window's state machine without the window: keys, sliders, switches, mouse drags, stepping and what to
    draw."""

    def __init__(self, sim, res):
        self.res = res
        self.dt_scale, self.push_strength = 1.0, 1.0
        c = sim.cfg
        self.down = down_direction(c)
        self.gravity = float(np.linalg.norm(c.gravity))    # m/s^2 along `down`
        self.stiffness, self.flip_blend = 1.0, float(c.solver.flip_blend)
        self.paused, self.message, self.show_help = False, "", True
        self._start(sim)

    def sliders(self):
        """(label, minimum, maximum, step, session attribute, setter) of every slider of the side panel."""
        return (("time-step scale", 0.05, 1.0, 0.05, "dt_scale", self.set_dt_scale),
                ("push strength", 0.0, 1.0, 0.05, "push_strength", self.set_push_strength),
                ("gravity", 0.0, max(GRAVITY_MAX, round(self.gravity + 0.5)), 0.5, "gravity", self.set_gravity),
                ("stiffness scale", *STIFFNESS_RANGE, 0.1, "stiffness", self.set_stiffness),
                ("FLIP blend", 0.0, 1.0, 0.05, "flip_blend", self.set_flip_blend))

    def _start(self, sim):
        """Take on a (new) simulation: the basis/transfer switch restarts the scene with its own kernels."""
        self.sim, self.cfg = sim, sim.cfg
        c = self.cfg
        self.base_cfl = c.solver.cfl
        self.set_dt_scale(self.dt_scale)
        self.initial = sim.get_state()
        self.view = View(c.dim, c.domain.lower, c.domain.upper, self.res,
                         *((self.view.yaw, self.view.pitch) if hasattr(self, "view") else ()))
        self.fields = available_fields(sim.particles(), c.dim)
        if getattr(self, "field", None) not in self.fields:
            self.field = c.output.render.color_by if c.output.render.color_by in self.fields else self.fields[0]
        self.cmap = c.output.render.colormap
        self.limits = self._limits()
        self.frame_time = c.output.every
        self.grid_segments = self._grid_segments()
        self.radius_px = max(1.0, 0.6 * float(np.median(sim.scene.spacing)) * self.view.scale)
        self.sphere_radius = 0.5 * float(np.median(sim.scene.spacing))   # world units (the GGUI scene)
        wave = float(getattr(sim, "wave_speed", 0.0) or 0.0)
        self.speed_cap = 0.25 * wave if wave > 0 else 10.0
        self._step_once = False
        self.chart = []            # (kinetic, strain, total) per frame, the last CHART_LENGTH frames
        self._gravity0 = None
        # the runtime parameters the sliders set carry over to a restarted scene
        sim.set_gravity(self.gravity * self.down)
        sim.set_stiffness_scale(self.stiffness)
        if c.solver.transfer == "flip":
            sim.set_flip_blend(self.flip_blend)
        self.record_energy()

    def _grid_segments(self):
        """(begin, end) window-unit segments of a mapped grid's cell edges (render.grid_lines), or None."""
        from ..io.render import grid_lines

        lines = grid_lines(self.cfg)
        if not lines:
            return None
        projected = [self.view.project(line)[0] for line in lines]
        return np.concatenate([p[:-1] for p in projected]), np.concatenate([p[1:] for p in projected])

    def _limits(self):
        r = self.cfg.output.render
        own = self.field == r.color_by  # the config's limits and scale belong to its own field
        return LiveLimits(self.field, r.scale if own else "linear", r.clim if own else None, tuple(r.percentiles))

    # ------------------------------------------------------------ live parameters (no recompile)
    def set_dt_scale(self, scale: float):
        """The time step as a fraction of the config's CFL step: solver.cfl is read on the host for every dt."""
        self.dt_scale = float(np.clip(scale, 0.05, 1.0))
        self.cfg.solver.cfl = self.base_cfl * self.dt_scale

    def set_push_strength(self, strength: float):
        """How far a drag pulls the particles under the cursor towards the drag velocity (0: not at all, 1: fully)."""
        self.push_strength = float(np.clip(strength, 0.0, 1.0))

    def set_gravity(self, magnitude: float):
        """Gravity of `magnitude` m/s^2 along `down` from the next step on (Simulation.set_gravity). The strip chart's
        total moves its potential reference with the jump, so it stays level where energy is conserved."""
        self.gravity = max(0.0, float(magnitude))
        before = self.sim.energy()["gravity"]
        self.sim.set_gravity(self.gravity * self.down)
        if self._gravity0 is not None:
            self._gravity0 += self.sim.energy()["gravity"] - before

    def set_stiffness(self, scale: float):
        """Every material's stiffness times `scale` (Simulation.set_stiffness_scale): stress and stored energy scale,
        waves run sqrt(scale) times faster, the time step shrinks accordingly."""
        self.stiffness = float(np.clip(scale, *STIFFNESS_RANGE))
        self.sim.set_stiffness_scale(self.stiffness)

    def set_flip_blend(self, a: float) -> bool:
        """FLIP's blend (0: PIC velocities, 1: pure FLIP); kept for a later switch to FLIP when the transfer is
        another (False and a message then)."""
        self.flip_blend = float(np.clip(a, 0.0, 1.0))
        if self.cfg.solver.transfer != "flip":
            self.message = f"FLIP blend applies to transfer flip (now {self.cfg.solver.transfer}; t switches)"
            return False
        self.sim.set_flip_blend(self.flip_blend)
        return True

    # ------------------------------------------------------------ switches (restart the scene)
    def switch(self, what: str, value: str | None = None) -> bool:
        """Restart the scene with the next (or the given) basis or transfer; False (and a message) when the scene
        does not allow it. These are compile-time choices: the new kernels compile (or come from Taichi's cache)."""
        from ..config import ConfigError, load_config
        from ..io.runner import Simulation

        # the basis switch cycles through the registry's swept bases (bases/registry.py), cheapest stencil first
        key, options = {"basis": ("solver.basis", basis_registry.swept()),
                        "transfer": ("solver.transfer", TRANSFERS)}[what]
        current = getattr(self.cfg.solver, what)
        if value is None:
            value = _next_option(options, current, self.cfg.solver.basis if what == "transfer" else None)
        data = self.cfg.to_dict()
        data["solver"][what] = value
        data["solver"]["cfl"] = self.base_cfl
        try:
            cfg = load_config(data)
            sim = Simulation(cfg)
        except ConfigError as e:
            self.message = f"{key}={value} not possible here: {e.message}"
            return False
        self._start(sim)
        self.message = f"restarted with {key}={value}"
        return True

    def press(self, key) -> bool:
        """Handle one key (ti.GUI key names) or widget event; False means quit."""
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
            self.chart = []
            self.record_energy()
        elif key == "c":
            self.field = self.fields[(self.fields.index(self.field) + 1) % len(self.fields)]
            self.limits = self._limits()
        elif key in ("b", "basis"):
            self.switch("basis")
        elif key in ("t", "transfer"):
            self.switch("transfer")
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

    def drag(self, prev, cursor, radius=0.06, view=None) -> int:
        """A mouse drag from prev to cursor (window units): push the particles under the cursor (as `view`, the
        window's camera, shows them; the projection view by default)."""
        view = view or self.view
        u = view.to_world_delta(np.asarray(cursor, float) - np.asarray(prev, float)) / self.frame_time
        speed = float(np.linalg.norm(u))
        if speed == 0 or self.push_strength == 0:
            return 0
        if speed > self.speed_cap:
            u *= self.speed_cap / speed
        return push_particles(self.sim, cursor, u, radius=radius, view=view, strength=self.push_strength)

    def advance(self):
        """One frame: a single step when asked, else one output interval unless paused or done."""
        from ..errors import InstabilityError

        t = self.sim.time
        try:
            if self._step_once:
                self.sim.step()
            elif not self.paused and not self.done:
                self.sim.advance(min(self.frame_time, self.cfg.solver.end_time - self.sim.time))
        except InstabilityError as err:
            self.paused, self.message = True, f"unstable: {err}  (r: reset)"
        stepped, self._step_once = self._step_once, False
        if self.sim.time != t:
            self.record_energy()
        return stepped

    # ------------------------------------------------------------ energy strip chart
    def record_energy(self):
        e = self.sim.energy()
        if self._gravity0 is None:
            self._gravity0 = e["gravity"]
        # total: kinetic + strain + the gravity potential released since the start (so that it starts at the
        # initial kinetic + strain energy and stays level where energy is conserved)
        self.chart = (self.chart + [(e["kinetic"], e["strain"], e["kinetic"] + e["strain"] + e["gravity"] -
                                     self._gravity0)])[-CHART_LENGTH:]

    def chart_lines(self):
        """{series: (begin, end)} line segments of the strip chart in window units, inside CHART; one vertical
        scale for the three series (0 to the largest value shown)."""
        x0, y0, x1, y1 = CHART
        data = np.asarray(self.chart, float).reshape(-1, 3)
        if len(data) < 2:
            return {}
        top = float(np.max(np.abs(data))) or 1.0
        xs = x0 + (x1 - x0) * np.arange(len(data)) / (CHART_LENGTH - 1)
        out = {}
        for k, name in enumerate(("kinetic", "strain", "total")):
            ys = y0 + (y1 - y0) * np.clip(data[:, k] / top, -0.05, 1.0)
            pts = np.c_[xs, ys]
            out[name] = (pts[:-1], pts[1:])
        return out

    @property
    def done(self) -> bool:
        end = self.cfg.solver.end_time
        return self.sim.time >= end - 1e-12 * max(1.0, end)

    def colours(self, p):
        """(N, 3) 8-bit RGB of the particles (the colour field under the live limits) and the status line."""
        from ..io.colour_range import normalise

        values = field_values(p, self.field, self.cfg.dim)
        clim = self.limits.update(values)
        cmap = "tab10" if self.field in ("body", "material", "interface") else self.cmap
        scale = self.limits.scale if self.field not in ("body", "material", "interface") else "linear"
        rgb = _colour_ints(normalise(values, clim, scale), cmap)
        state = "paused" if self.paused else ("done" if self.done else "running")
        s = self.cfg.solver
        status = (f"t = {self.sim.time:.4g} s   steps {self.sim.n_steps}   {state}   {s.basis}/{s.transfer}   "
                  f"colour: {self.field} [{clim[0]:.3g}, {clim[1]:.3g}]")
        return rgb, status

    def picture(self):
        """(positions, packed colours) in drawing order, and the status line."""
        p = self.sim.particles()
        rgb, status = self.colours(p)
        pos, depth = self.view.project(p["x"])
        if self.cfg.dim == 3:  # painter's order and depth shading: far particles first and darker
            order = np.argsort(depth)
            span = float(np.ptp(depth)) or 1.0
            shade = 0.55 + 0.45 * (depth - depth.min()) / span
            rgb = (rgb * shade[:, None]).astype(np.uint32)
            pos, rgb = pos[order], rgb[order]
        return pos, _pack(rgb), status


def run_gui(cfg, max_frames=None, screenshot=None, show=True, script=None, view: str | None = None):
    """Open the interactive window for a config (path, dict or Config); returns the simulation shown last (a basis
    or transfer switch replaces it); NoDisplay where no window can open (show=True). A 3D scene opens Taichi's GGUI
    scene where a Vulkan device exists (ggui.py), else the ti.GUI projection; `view` ('ggui' or 'projection')
    overrides the choice, and the title says which. With `max_frames` the window closes by itself after that many
    frames; `screenshot` saves the last frame as a PNG. `script` (for tests and demos): {frame: [action, ...]}
    applied before that frame's events, an action being ("slider", label, value) (moves a slider widget, read back
    like a hand's move) or ("event", name) (a key or a button's event name)."""
    from ..config import load_config
    from ..io.runner import Simulation  # resolves arch auto without Taichi's crashing OpenGL probe

    cfg = cfg if hasattr(cfg, "model_dump") else load_config(cfg)
    if show:
        check_display()   # before Taichi starts: no window, no traceback or exit from inside Taichi (NoDisplay)
    res = tuple(int(s) for s in cfg.output.render.size)
    session = Session(Simulation(cfg), res)
    support = ggui_support() if cfg.dim == 3 else (False, False)
    kind = view or view_3d_kind(support)
    title = window_title(cfg, kind, support)
    if cfg.dim == 3 and kind == "ggui":
        from .ggui import run_ggui

        return run_ggui(session, title, max_frames, screenshot, show, script)
    gui, sliders = _open_window(session, title, res, show)
    prev_cursor = None
    frames = 0
    try:
        while gui.running:
            go, prev_cursor = _handle_input(gui, session, sliders, (script or {}).get(frames, []), prev_cursor)
            if not go:
                break
            stepped = session.advance()
            _draw(gui, session, res)
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


def _open_window(session, title, res, show):
    """The ti.GUI window with the session's sliders (at their current values) and the switch buttons."""
    import taichi as ti

    gui = ti.GUI(title, res=res, background_color=0xFFFFFF, show_gui=show)
    sliders = {}
    for label, lo, hi, step, attr, _ in session.sliders():
        sliders[label] = gui.slider(label, lo, hi, step)
        sliders[label].value = getattr(session, attr)
    gui.button("next basis", "basis")
    gui.button("next transfer", "transfer")
    return gui, sliders


def _handle_input(gui, session, sliders, actions, prev_cursor):
    """One frame's input: scripted actions, key and button events, moved sliders and the mouse drag. Returns
    (whether the window stays open, the cursor while the button is held)."""
    import taichi as ti

    injected = []
    for action in actions:
        if action[0] == "slider":
            sliders[action[1]].value = action[2]
        else:
            injected.append(action[1])
    keys = [e.key for e in gui.get_events(ti.GUI.PRESS)] + injected
    if not all([session.press(k) for k in keys]):
        return False, prev_cursor
    for label, _, _, _, attr, setter in session.sliders():
        if abs(sliders[label].value - getattr(session, attr)) > SLIDER_TOLERANCE:
            setter(sliders[label].value)
    cursor = np.asarray(gui.get_cursor_pos(), float)
    held = gui.is_pressed(ti.GUI.LMB)
    if held and prev_cursor is not None:
        session.drag(prev_cursor, cursor)
    return True, cursor if held else None


def _draw(gui, session, res):
    """The domain box, a mapped grid's cells, the particles, the chart and the text lines."""
    pos, colours, status = session.picture()
    begin, end = session.view.box_edges()
    gui.lines(begin, end, radius=1, color=0x999999)
    if session.grid_segments is not None:
        gui.lines(*session.grid_segments, radius=1, color=0xCCCCCC)
    gui.circles(pos, radius=session.radius_px, color=colours)
    _draw_chart(gui, session)
    gui.text(status, pos=(0.01, 0.99), font_size=16, color=0x000000)
    if session.show_help:
        gui.text(HELP if res[0] >= 900 else "space s r c b t drag arrows esc", pos=(0.01, 0.05),
                 font_size=14, color=0x444444)
    if session.message:
        gui.text(session.message, pos=(0.01, 0.94), font_size=16, color=0xCC0000)


def _draw_chart(gui, session):
    x0, y0, x1, y1 = CHART
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    gui.lines(corners, np.roll(corners, -1, axis=0), radius=1, color=0xBBBBBB)
    for name, (begin, end) in session.chart_lines().items():
        gui.lines(begin, end, radius=1.5, color=CHART_COLOURS[name])
    gui.text("energy: kinetic (red) strain (blue) total (black)", pos=(x0, y1 + 0.03), font_size=12, color=0x444444)
