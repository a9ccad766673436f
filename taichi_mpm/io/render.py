"""Off-screen rendering of particle states with pyvista: PNG frames and movies.

`FrameRenderer` keeps one off-screen plotter for a whole sequence and only updates the point
coordinates and colours per frame, so a 960x720 frame of ~20k particles renders in a fraction
of a second. 1D bars are drawn as a strip of cells along x, 2D scenes as points in the xy plane
seen through an orthographic camera, 3D scenes as shaded spheres (camera `iso` by default).

Rendering reads solver state only through the particle dict of `Simulation.particles()` or the
saved VTU files (`render_run`); it never touches Taichi.

Frames, records and movies are written through io's helpers: a temporary file renamed over the real name, never
through a link in the run folder, a frames folder that is a file or a link refused before any frame
(io.FileError). A frame size is checked (check_size) before VTK sees it: VTK aborts the whole process (exit 134)
when it cannot allocate a window. A saved state with non-finite (NaN or infinite) coordinates is refused naming
its file (ConfigError), never drawn silently.
"""
from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from . import colour_range
from .. import fields as registry
from . import files as io
from ..fields import von_mises  # noqa: F401 (the one implementation, in fields.py)

from .render_options import ALIASES as _ALIASES
from .render_options import CAMERAS, CATEGORICAL, color_fields, known_in_advance, options, scalar_fields  # noqa: F401 (re-exported)
from .render_options import window_fields as available_fields  # noqa: F401 (the window's list, re-exported)


# frame sizes VTK is given: each side at most MAX_SIDE pixels and at most MAX_PIXELS in all (8192 x 8192: about
# 1.3 GB of frame buffers and copies). Beyond, VTK's allocation fails and it aborts the process without a message.
MAX_SIDE, MAX_PIXELS = 16384, 8192 * 8192


def check_size(size) -> tuple[int, int]:
    """(width, height) of a frame, checked: two whole numbers >= 1, each side <= MAX_SIDE, width x height <=
    MAX_PIXELS; ValueError otherwise (callers turn it into an input error: exit 2)."""
    try:
        w, h = (int(v) for v in size)
        if any(float(v) != int(v) for v in size):
            raise ValueError
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"a frame size is [width, height] in whole pixels, got {size!r}") from None
    if w < 1 or h < 1:
        raise ValueError(f"a frame size needs width and height >= 1 pixel, got {w}x{h}")
    if w > MAX_SIDE or h > MAX_SIDE or w * h > MAX_PIXELS:
        raise ValueError(f"a frame of {w}x{h} pixels is too large to render (at most {MAX_SIDE} pixels a side and "
                         f"{MAX_PIXELS:,} pixels in all, e.g. 8192x8192; the renderer would fail to allocate it)")
    return w, h



_BACKEND: dict = {}


def _pyvista():
    """pyvista, set up once for off-screen work: without a display VTK renders through EGL when the
    library is there (no X attempt, no warning); failing that, through a virtual X server (Xvfb)."""
    import pyvista as pv

    pv.OFF_SCREEN = True
    if not _BACKEND:
        _BACKEND["display"] = os.environ.get("DISPLAY") or None
        if not _BACKEND["display"]:
            import ctypes.util
            import shutil

            if ctypes.util.find_library("EGL"):
                os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
            elif shutil.which("Xvfb"):
                pv.start_xvfb()
    return pv


# ---------------------------------------------------------------- fields
def field_values(particles: dict, name: str, dim: int) -> np.ndarray:
    """Per-particle scalar values of a named field: a scalar field of the output-field registry (speed, von_mises,
    J, body, damage, pressure, ...), vx/vy/vz, or a component sxx, syy, szz, sxy, ... of the full 3x3 stress.
    Raises ValueError for an unknown or absent field."""
    name = _ALIASES.get(name, name)
    n = len(np.asarray(particles["x"]))
    if name in ("vx", "vy", "vz"):
        a = "xyz".index(name[1])
        if a >= dim:
            raise ValueError(f"field '{name}' needs dim > {a}")
        return np.asarray(particles["v"], float).reshape(n, -1)[:, a]
    m = re.fullmatch(r"s([xyz])([xyz])", name)
    if m:
        i, j = "xyz".index(m.group(1)), "xyz".index(m.group(2))
        return registry.stress3(particles)[:, i, j]
    if name not in scalar_fields():
        raise ValueError(f"unknown colour field '{name}' (choose from {', '.join(scalar_fields())}, or sxx, sxy, ..., "
                         "szz)")
    if name == "body" and "body" not in particles:
        return np.zeros(n)
    if not registry.available(particles, name):
        if name == "damage":
            raise ValueError("this state has no damage field (the scene has no crack section)")
        raise ValueError(f"this state has no '{name}' field (it needs {', '.join(registry.REGISTRY[name].needs)})")
    return np.asarray(registry.values(particles, name), float).reshape(n)


def _label(name):
    name = _ALIASES.get(name, name)
    if name in registry.REGISTRY:
        return registry.label(name)
    if name in ("vx", "vy", "vz"):
        return f"velocity {name[1]} [m/s]"
    return f"stress {name[1:]} [Pa]"


# ---------------------------------------------------------------- renderer
def surface_particles(x, spacing: float) -> np.ndarray:
    """Mask of the 3D particles that can be seen from outside: those with an empty voxel within two voxels in one
    of the six axis directions, on voxels of the particle spacing. Conservative: a stretched or jumbled body
    leaves more voxels empty, and then more particles are drawn, never fewer of the visible ones (an occupied
    voxel holds a particle that covers the one behind it)."""
    x = np.asarray(x, float).reshape(len(x), -1)
    if len(x) < 64 or not spacing > 0:
        return np.ones(len(x), bool)
    # + 0.5: a lattice's particles sit at voxel centres, not on voxel faces where round-off picks the side
    ijk = np.floor((x - x.min(axis=0)) / spacing + 0.5).astype(np.int64) + 2
    dims = ijk.max(axis=0) + 3
    occupied = np.zeros(tuple(dims), bool)
    occupied[tuple(ijk.T)] = True
    hidden = np.ones(len(x), bool)
    for a in range(3):
        for s in (-2, -1, 1, 2):  # two layers: a deformed lattice's voxels leave gaps one layer would show through
            n = ijk.copy()
            n[:, a] += s
            hidden &= occupied[tuple(n.T)]
    return ~hidden


def _polydata(points):
    return _pyvista().PolyData(points)


_VIEWS = {"iso": (1.0, 0.75, 1.5), "front": (0, 0, 1), "xy": (0, 0, 1), "xz": (0, 1, 0), "top": (0, 1, 0),
          "yz": (1, 0, 0), "side": (1, 0, 0)}


class FrameRenderer:
    """Renders particle states of one scene to PNG files with one camera and one colour scale.

    render_cfg: the config's `output.render` (color_by, size, camera, point_size, colormap, clim, scale,
    percentiles) or a dict with those keys. limits: the colour range of the whole sequence (`colour_range.
    robust_limits` over every frame; the config's `clim` wins); without one, robust limits of the frames seen so
    far (widened only). bounds: (lower, upper) corners the 3D camera frames (the bodies over the whole run;
    default the domain). title: text in the top right corner (scene name, a comparison's variant).

    3D: particles as lit spheres over a floor (the domain's y_min wall) and a faint domain outline, perspective
    camera. 2D: discs seen along z, orthographic, inside the domain outline. 1D: a strip of cells along x.
    One off-screen plotter serves the whole sequence; a frame only updates points, colours and the time label.
    """

    def __init__(self, render_cfg, dim: int, lower, upper, limits=None, bounds=None, title: str | None = None,
                 lines=None):
        o = options(render_cfg)
        check_size(o["size"])   # before VTK: it aborts the process on a window it cannot allocate
        self.lines = lines      # 2D: polylines (M, 2) drawn under the particles (a mapped grid's cells)
        self.color_by, self.size, self.camera = o["color_by"], o["size"], o["camera"]
        self.point_size, self.cmap = o["point_size"], o["cmap"]
        self.scale, self.percentiles = o["scale"], o["percentiles"]
        self.dim = int(dim)
        self.lower = np.asarray(lower, float)
        self.upper = np.asarray(upper, float)
        if self.dim == 3 and self.camera not in CAMERAS:
            raise ValueError(f"unknown camera '{self.camera}' (choose from {', '.join(CAMERAS)})")
        self.categorical = self.color_by in CATEGORICAL
        if self.categorical:
            self.scale = "linear"
        fixed = o["clim"] or (list(limits) if limits is not None else None)
        self.live = colour_range.LiveLimits(self.color_by, self.scale, fixed, self.percentiles)
        self.bounds = (np.asarray(bounds[0], float), np.asarray(bounds[1], float)) if bounds is not None else None
        self.title = title
        self._plotter = None
        self._n = None
        self.seconds = 0.0   # wall time spent rendering and writing frames
        self.frames = 0

    # ------------------------------------------------------------ public
    def render(self, particles: dict, time: float, path) -> Path:
        """Write one PNG of the configured size showing `particles` at `time`."""
        import time as _time

        t0 = _time.perf_counter()
        values = field_values(particles, self.color_by, self.dim)
        path = Path(path)
        if not path.parent.is_dir():   # (a folder the caller gave, even through a link, is the caller's choice)
            io.ensure_folder(path.parent, parents=True)
        img = self.image(particles["x"], values, time, spacing=self._spacing(particles), volume=particles.get("volume"))
        write_png(path, img)
        self.seconds += _time.perf_counter() - t0
        self.frames += 1
        return path

    def image(self, x, values, time: float, spacing: float | None = None, volume=None) -> np.ndarray:
        """The (H, W, 3) uint8 picture of positions x coloured by values at `time` (no file written)."""
        values = np.asarray(values, float)
        bad = int(np.count_nonzero(~np.isfinite(np.asarray(x, float).reshape(len(x), -1)).all(axis=1))) if len(x) else 0
        if bad:
            raise ValueError(f"{bad} of {len(x)} particles have non-finite (NaN or infinite) coordinates: not drawn")
        clim = self.live.update(values)
        if spacing is None:
            spacing = self._spacing({"x": x})
        if self.dim == 3:  # hidden particles cost fill time and show nothing
            keep = surface_particles(x, spacing)
            x, values = np.asarray(x)[keep], values[keep]
        p = self._setup(x, spacing, volume, clim)
        self._update(x, values, clim, volume, spacing)
        self._time_actor.SetInput(f"t = {time:.4g} s")
        p.render()  # (pyvista's screenshot renders only the first time)
        return p.screenshot(return_img=True)[..., :3]

    def close(self):
        if self._plotter is not None:
            self._plotter.close()
            self._plotter = None

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    # ------------------------------------------------------------ internals
    def _spacing(self, particles):
        vol = np.asarray(particles.get("volume", []), float)
        if len(vol):
            return float(np.median(np.abs(vol))) ** (1.0 / self.dim)
        ext = float(np.max(self.upper - self.lower))
        return ext / max(1.0, len(particles["x"]) ** (1.0 / self.dim))

    def _points3(self, x):
        x = np.asarray(x, float).reshape(len(x), -1)[:, : self.dim]
        return np.pad(x, ((0, 0), (0, 3 - self.dim)))

    def _bar_points(self, x, volume, spacing):
        """1D: each particle becomes a quad [x - h/2, x + h/2] x [0, H]."""
        x = np.asarray(x, float).reshape(-1)
        h = (np.abs(np.asarray(volume, float).reshape(-1)) if volume is not None else np.full(len(x), spacing)) / 2
        H = 0.04 * float(self.upper[0] - self.lower[0])
        z = np.zeros_like(x)
        return np.stack([np.c_[x - h, z, z], np.c_[x + h, z, z], np.c_[x + h, z + H, z], np.c_[x - h, z + H, z]],
                        axis=1).reshape(-1, 3)

    def _band(self):
        """Window fractions the scene may use: below the time label, above the colour bar."""
        h = self.size[1]
        return max(0.2, 75 / h), min(0.92, 1 - 40 / h)

    def _setup(self, x, spacing, volume, clim):
        pv = _pyvista()
        n = len(x)
        if self._plotter is not None and (n == self._n or self.dim == 3):
            return self._plotter
        self.close()
        p = pv.Plotter(off_screen=True, window_size=list(self.size))
        self._n = n
        lo3 = np.pad(self.lower, (0, 3 - self.dim))
        hi3 = np.pad(self.upper, (0, 3 - self.dim))
        if self.dim == 3:
            p.set_background("white", top="#d8e0ea")  # a soft sky: depth reads better than on flat white
        else:
            p.set_background("white")
        if self.dim == 1:
            pts = self._bar_points(x, volume, spacing)
            self._mesh = pv.PolyData(pts, faces=np.c_[np.full(n, 4), 4 * np.arange(n)[:, None] + np.arange(4)].ravel())
            H = 0.04 * (hi3[0] - lo3[0])
            hi3 = hi3 + np.array([0, H, 0])
        else:
            self._mesh = pv.PolyData(self._points3(x))
        self._mesh["value"] = np.zeros(n)
        bar = dict(title="", color="black", fmt="%.3g", n_labels=5 if self.size[0] >= 560 else 3, vertical=False,
                   position_x=0.2, position_y=0.0,
                   width=0.6, height=0.085, label_font_size=14)
        if self.categorical:  # one tab10 colour per body, each labelled on the bar
            import matplotlib.colors

            k = max(2, int(round(clim[1] - clim[0])))
            cmap = matplotlib.colors.ListedColormap([matplotlib.colormaps["tab10"](i % 10) for i in range(k)])
            bar.update(n_labels=0)
            common = dict(annotations={float(i): str(i) for i in range(k)}, n_colors=k)
        else:
            cmap, common = self.cmap, dict(n_colors=256)
        common.update(scalars="value", cmap=cmap, scalar_bar_args=bar, clim=clim, log_scale=self.scale == "log")
        if self.dim == 1:
            self._actor = p.add_mesh(self._mesh, preference="cell", lighting=False, **common)
        else:
            self._place_camera(p, lo3, hi3)
            # discs cover the square lattice's gaps (sqrt 2) so that a body reads as a continuum (2D); spheres
            # touch (3D)
            ps = self.point_size or max(2.0, (1.1 if self.dim == 3 else 1.45) * spacing * self._pixels_per_unit(p))
            # spheres (impostors: one shaded disc per particle, cheap) lit in 3D; flat discs in 2D, whose colour
            # must read exactly against the colour bar
            self._actor = p.add_mesh(self._mesh, style="points", point_size=ps, render_points_as_spheres=True,
                                     lighting=self.dim == 3, ambient=0.3 if self.dim == 3 else 0.0,
                                     diffuse=0.75 if self.dim == 3 else 1.0, specular=0.25 if self.dim == 3 else 0.0,
                                     specular_power=20, **common)
        if self.dim == 3:
            floor = pv.Plane(center=(0.5 * (lo3[0] + hi3[0]), lo3[1] - 1e-4 * (hi3[1] - lo3[1]),
                                     0.5 * (lo3[2] + hi3[2])),
                             direction=(0, 1, 0), i_size=hi3[2] - lo3[2], j_size=hi3[0] - lo3[0])
            p.add_mesh(floor, color="#c9c9c4", ambient=0.5, diffuse=0.5, specular=0.0)
            p.add_mesh(pv.Box(bounds=(lo3[0], hi3[0], lo3[1], hi3[1], lo3[2], hi3[2])).outline(), color="#9aa3ad",
                       line_width=1, opacity=0.6)
        else:
            top = hi3[1] if self.dim == 2 else hi3[1]
            p.add_mesh(pv.Box(bounds=(lo3[0], hi3[0], lo3[1], top, 0, 0)).outline(), color="#8c8c8c", line_width=1)
            for line in self.lines or []:    # behind the particles (z below them): the grid reads as background
                p.add_mesh(pv.lines_from_points(np.c_[line, np.full(len(line), -1e-3 * (hi3[0] - lo3[0]))]),
                           color="#b4b4b4", line_width=1)
        if self.dim == 1:
            self._place_camera(p, lo3, hi3)
        w, h = self.size
        if p.scalar_bars:  # labels under the bar, the field and its unit above it: they never overlap
            for sb in p.scalar_bars.values():
                sb.SetTextPositionToPrecedeScalarBar()
            title = _label(self.color_by) + (" (log scale)" if self.scale == "log" else "")
            t = p.add_text(title, position=(w // 2, int(0.085 * h) + 4), font_size=11, color="black")
            t.GetTextProperty().SetJustificationToCentered()
        self._time_actor = p.add_text("t =", position=(12, h - 34), font_size=12, color="black")
        if self.title:
            p.add_text(self.title, position="upper_right", font_size=11, color="#333333")
        self._plotter = p
        return p

    def _pixels_per_unit(self, p):
        """Screen pixels per unit length at the camera's focal point."""
        h = self.size[1]
        if self.dim < 3:
            return h / (2 * p.camera.parallel_scale)
        dist = float(np.linalg.norm(np.subtract(p.camera.position, p.camera.focal_point)))
        return h / (2 * dist * np.tan(np.radians(p.camera.view_angle / 2)))

    def _place_camera(self, p, lo3, hi3):
        """2D and 1D: the domain, orthographic. 3D: the bodies' bounds (or the domain) fitted into the band between
        colour bar and time label, corner by corner, for the chosen view direction."""
        w, h = self.size
        bottom, top = self._band()
        mid = 0.5 * (top + bottom)
        if self.dim < 3:
            ext = hi3 - lo3
            c = 0.5 * (lo3 + hi3)
            p.enable_parallel_projection()
            fit_height = ext[1] / (top - bottom) if self.dim == 2 else 0.0  # a 1D strip only fits the width
            scale = max(fit_height, ext[0] * h / w / 0.92, 1e-9) / 2  # half the visible height
            focal = c - np.array([0.0, (mid - 0.5) * 2 * scale, 0.0])
            p.camera.focal_point = tuple(focal)
            p.camera.position = tuple(focal + np.array([0, 0, 10 * max(ext.max(), 1e-9)]))
            p.camera.up = (0, 1, 0)
            p.camera.parallel_scale = scale
            return
        blo, bhi = self.bounds if self.bounds is not None else (lo3, hi3)
        direction = np.asarray(_VIEWS[self.camera], float)
        direction /= np.linalg.norm(direction)
        up = np.array((0, 0, -1.0) if self.camera in ("xz", "top") else (0, 1.0, 0))
        right = np.cross(up, direction)
        right /= np.linalg.norm(right)
        up = np.cross(direction, right)
        c = 0.5 * (blo + bhi)
        corners = np.array(np.meshgrid(*zip(blo, bhi), indexing="ij")).reshape(3, -1).T - c
        angle = 30.0
        t = np.tan(np.radians(angle / 2))
        fy, fx = 0.95 * (top - bottom), 0.92          # window fractions the bodies may fill
        xr, yu, zd = corners @ right, corners @ up, corners @ direction
        dist = float(np.max(np.maximum(zd + np.abs(yu) / (t * fy), zd + np.abs(xr) / (t * w / h * fx))))
        # aim so that the band's middle, not the window's, holds the bodies' centre
        shift = (mid - 0.5) * 2 * dist * t
        focal = c - shift * up
        p.camera.focal_point = tuple(focal)
        p.camera.position = tuple(focal + dist * direction)
        p.camera.up = tuple(up)
        p.camera.view_angle = angle
        p.reset_camera_clipping_range()

    def _update(self, x, values, clim, volume, spacing):
        if self.dim == 1:
            self._mesh.points = self._bar_points(x, volume, spacing)
            self._mesh.cell_data["value"] = np.asarray(values, float)
        else:
            if self._mesh.n_points != len(x):  # 3D: the visible particles change in number
                self._mesh.copy_from(_polydata(self._points3(x)))
            else:
                self._mesh.points = self._points3(x)
            shown = np.asarray(values, float)
            if self.scale == "log":  # non-positive values take the bottom colour instead of the NaN colour
                shown = np.clip(shown, clim[0], None)
            self._mesh["value"] = shown
        self._actor.mapper.scalar_range = (float(clim[0]), float(clim[1]))
        if self.dim == 3:
            self._plotter.reset_camera_clipping_range()

# ---------------------------------------------------------------- movies
def make_movie(frames_dir, out_path, fps: int = 20, root=None) -> Path:
    """Join frames_dir/frame_*.png (in name order) into an mp4 (imageio-ffmpeg, H.264) or a gif, by suffix.
    frames_dir may also be a list of PNG paths. The movie is written to a temporary file and renamed over out_path
    (a link there is replaced, never followed); `root`: the run folder it belongs to (links inside refused)."""
    import imageio.v2 as imageio

    if isinstance(frames_dir, (list, tuple)):
        frames = [Path(f) for f in frames_dir]
    else:
        frames = io.files_in(frames_dir, "frame_*.png", root=root)
    if not frames:
        raise FileNotFoundError(f"no frame_*.png in {frames_dir}")
    out = Path(out_path)
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4", ".mov", ".mkv", ".avi"):
        raise ValueError(f"unknown movie format '{suffix}' (use .mp4 or .gif)")
    if not out.parent.is_dir():
        io.ensure_folder(out.parent, parents=True)
    with io.atomic_path(out, suffix=suffix, root=root) as tmp:   # the writers pick the format by the suffix
        if suffix == ".gif":
            images = [imageio.imread(f)[..., :3] for f in frames]
            imageio.mimsave(tmp, images, duration=1000.0 / fps, loop=0)
            return out
        writer = imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7, macro_block_size=1,
                                    pixelformat="yuv420p", ffmpeg_log_level="error")
        try:
            for f in frames:
                img = imageio.imread(f)[..., :3]
                h, w = img.shape[:2]
                if h % 2 or w % 2:  # yuv420p needs even sides
                    img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
                writer.append_data(img)
        finally:
            writer.close()
    return out


# ---------------------------------------------------------------- saved runs
def read_series(run_dir) -> list[tuple[float, Path]]:
    """(time, vtu path) of a run's saved particle states, from particles.pvd or, failing that, the file names."""
    run_dir = Path(run_dir)
    pvd = run_dir / "particles.pvd"
    if pvd.is_file():
        try:
            root = ET.parse(pvd).getroot()
            items = []
            for ds in root.iter("DataSet"):
                name = ds.get("file") or ""
                if Path(name).name != name or not name.endswith(".vtu"):  # only the run's own files, by name
                    raise ValueError(f"a DataSet names {name!r}, not a .vtu file in the run folder")
                items.append((float(ds.get("timestep", 0.0)), run_dir / name))
        except (ET.ParseError, ValueError, TypeError) as e:
            from ..errors import ConfigError

            raise ConfigError(f"cannot read {pvd}: {e} (a corrupt series file: remove it to render the "
                              f"particles_*.vtu files in name order)") from None
        if items:
            return items
    files = sorted(run_dir.glob("particles_*.vtu"))
    return [(float("nan"), f) for f in files]


def read_particles(vtu_path, dim: int) -> dict:
    """A particle dict (x, v, stress, stress3, F, von_mises, J, body, damage, ...) from one saved VTU file."""
    import contextlib
    import io as _io
    import warnings

    from ..errors import ConfigError
    from .files import read_vtu

    said = _io.StringIO()
    try:  # meshio's VTU reader prints its complaint and calls sys.exit on some corrupt files
        with warnings.catch_warnings(), contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            warnings.simplefilter("ignore")
            p = read_vtu(vtu_path, dim)
    except (Exception, SystemExit) as e:
        detail = " ".join(said.getvalue().split()) if isinstance(e, SystemExit) else f"{type(e).__name__}: {e}"
        raise ConfigError(f"cannot read {vtu_path}: {detail[:300] or type(e).__name__} (a corrupt or truncated "
                          f"snapshot)") from None
    if "velocity" in p:
        p["v"] = p.pop("velocity")
    x = np.asarray(p["x"], float).reshape(len(p["x"]), -1)
    bad = ~np.isfinite(x).all(axis=1)
    if bad.any():
        raise ConfigError(f"{vtu_path}: {int(bad.sum())} of {len(x)} particles have non-finite (NaN or infinite) "
                          f"coordinates (the first: particle {int(np.argmax(bad))}); such a state cannot be drawn: "
                          f"remove the file, or render a run whose snapshots are intact")
    return p


def sequence_bounds(positions, spacing: float, dim: int):
    """(lower, upper) 3D corners of the union of every frame's particle positions, padded by one spacing: what a
    3D camera frames so that the bodies fill the picture and the camera does not move during the sequence."""
    lo = np.min([np.min(np.asarray(x, float).reshape(len(x), -1), axis=0) for x in positions], axis=0)
    hi = np.max([np.max(np.asarray(x, float).reshape(len(x), -1), axis=0) for x in positions], axis=0)
    lo, hi = np.pad(lo[:dim], (0, 3 - dim)), np.pad(hi[:dim], (0, 3 - dim))
    return lo - spacing, hi + spacing


def framing_bounds(render_cfg, dim: int, lower, upper):
    """The (lower, upper) 3D corners `output.render.framing` fixes before the run (domain, or its box); None for
    `run` (the bodies over the whole run: sequence_bounds, known at its end) and in 2D and 1D (the domain)."""
    framing = options(render_cfg)["framing"]
    if int(dim) < 3 or framing == "run":
        return None
    lo, hi = (lower, upper) if framing == "domain" else framing
    return np.asarray(lo, float), np.asarray(hi, float)


def sequence_limits(render_cfg, values) -> list[float] | None:
    """The colour range of a sequence: the config's clim, else robust percentiles of every frame's values."""
    o = options(render_cfg)
    if o["clim"]:
        return o["clim"]
    categorical = o["color_by"] in CATEGORICAL
    return colour_range.robust_limits(list(values), o["color_by"], "linear" if categorical else o["scale"],
                                      o["percentiles"], categorical=categorical)


def frame_data(particles: dict, color_by: str, dim: int) -> dict:
    """What one frame needs, copied: positions and the colour field as float32, the particle spacing (median
    volume ** 1/dim; NaN without volumes), 1D volumes (the bar's cells). ValueError for an unknown or absent field.
    The frames drawn during the run and those drawn at its end both start from this."""
    values = field_values(particles, color_by, dim)
    n = len(particles["x"])
    vol = np.asarray(particles.get("volume", np.zeros(0)), float).reshape(-1)
    spacing = float(np.median(np.abs(vol))) ** (1.0 / dim) if len(vol) else float("nan")
    return dict(x=np.asarray(particles["x"], np.float32).reshape(n, -1), values=values.astype(np.float32),
                spacing=spacing, volume=vol.astype(np.float32) if dim == 1 else np.zeros(0, np.float32))


class FrameRecorder:
    """A run's frames, rendered at its end with one colour range and one camera for the whole sequence.

    `record` keeps what a frame needs (positions and the colour field as float32, the particle spacing; about
    16 bytes per particle and output) in RUN_DIR/frames/.record_NNNNNN.npz; `render_all` computes the robust
    limits and the camera bounds over every record, writes frames/frame_NNNNNN.png and removes the records. A run
    stopped by Ctrl-C keeps its records, so that the resumed run renders the whole sequence.
    """

    PATTERN = ".record_*.npz"

    def __init__(self, frames_dir, render_cfg, dim: int, lower, upper, title: str | None = None, lines=None):
        self.dir = Path(frames_dir)
        self.lines = lines
        self.render_cfg, self.dim, self.lower, self.upper, self.title = render_cfg, dim, lower, upper, title
        self.color_by = options(render_cfg)["color_by"]
        if dim == 3 and options(render_cfg)["camera"] not in CAMERAS:
            raise ValueError(f"unknown camera '{options(render_cfg)['camera']}' (choose from {', '.join(CAMERAS)})")
        check_size(options(render_cfg)["size"])
        self.root = self.dir.parent   # the run folder: no link inside it is followed
        self.seconds = 0.0

    def record(self, particles: dict, time: float, index: int):
        """Keep one output's frame data (ValueError for an unknown or absent colour field)."""
        d = frame_data(particles, self.color_by, self.dim)
        io.ensure_folder(self.dir, root=self.root)
        path = self.dir / f".record_{index:06d}.npz"
        with io.atomic_write(path, root=self.root) as f:
            np.savez(f, time=float(time), **d)

    def records(self) -> list[Path]:
        return [r for r in io.files_in(self.dir, self.PATTERN, root=self.root) if not r.is_dir()]

    def render_all(self) -> list[Path]:
        """Render every recorded frame into frames/frame_NNNNNN.png; returns the frames in order."""
        import time as _time

        records = self.records()
        if not records:
            return []
        t0 = _time.perf_counter()
        data = []
        for r in records:
            with np.load(r) as z:
                data.append({k: z[k] for k in z.files})
        spacing = float(np.nanmedian([float(d["spacing"]) for d in data]))
        limits = sequence_limits(self.render_cfg, [d["values"] for d in data])
        bounds = framing_bounds(self.render_cfg, self.dim, self.lower, self.upper)
        if bounds is None and self.dim == 3:
            bounds = sequence_bounds([d["x"] for d in data], spacing, self.dim)
        renderer = FrameRenderer(self.render_cfg, self.dim, self.lower, self.upper, limits=limits, bounds=bounds,
                                 title=self.title, lines=self.lines)
        frames = []
        try:
            for r, d in zip(records, data):
                out = self.dir / r.name.replace(".record_", "frame_").replace(".npz", ".png")
                img = renderer.image(d["x"], d["values"], float(d["time"]), spacing=spacing,
                                     volume=d["volume"] if len(d["volume"]) else None)
                write_png(out, img, root=self.root)
                frames.append(out)
        finally:
            renderer.close()
        for r in records:
            io.remove_file(r, root=self.root)
        self.seconds += _time.perf_counter() - t0
        return frames


def grid_lines(cfg, per_cell: int = 12):
    """The cell edges of a mapped grid (domain.map) as polylines in physical space: the parameter lines through
    every distinct knot, `per_cell` segments per cell (curved cells look curved). None without a map, and for a
    3D map (3D frames draw the particles only)."""
    if cfg.domain.map is None or cfg.dim != 2:
        return None
    from ..bases.mapped import build_map

    mp = build_map(cfg.domain.map)[0]
    knots = [np.unique(t) for t in mp.knots]
    fine = [np.unique(np.concatenate([np.linspace(a, b, per_cell + 1) for a, b in zip(k[:-1], k[1:])]))
            for k in knots]
    lines = []
    for axis in range(2):
        for k in knots[axis]:
            xi = np.empty((len(fine[1 - axis]), 2))
            xi[:, axis], xi[:, 1 - axis] = k, fine[1 - axis]
            lines.append(mp.evaluate(xi))
    return lines


def write_png(path, img, root=None):
    """One frame, written atomically (a temporary renamed over `path`); unfiltered rows at zlib level 1 (png.py:
    half Pillow's time, a smaller file)."""
    from .png import png_bytes

    data = png_bytes(img)
    with io.atomic_write(path, root=root) as f:
        f.write(data)


def render_run(run_dir, color_by=None, size=None, camera=None, movie=None, fps: int = 20) -> dict:
    """Re-render the saved output of a run directory into frames/frame_NNNNNN.png (and a movie).

    color_by, size, camera override the run's `output.render`; the colour limits are fixed over the whole
    sequence (config `clim`, or robust percentiles over all saved states), and so is the 3D camera (the bodies'
    bounds over the run). movie: None follows the run's output.formats (mp4 / gif), False makes none, True or
    "mp4" / "gif" or a path makes one. Returns {"frames": [paths], "movie": path or None, "seconds": render time}.
    """
    import time as _time

    from ..config import load_config
    from ..errors import ConfigError

    run_dir = Path(run_dir)
    io.refuse_links(run_dir)   # nothing read, written or deleted through a link in the run folder
    cfg_path = run_dir / "config.yaml"
    if not cfg_path.is_file():
        raise FileNotFoundError(f"{run_dir} holds no config.yaml (not a run directory?)")
    cfg = load_config(cfg_path)
    rc = cfg.output.render.model_dump()
    if color_by and color_by != rc["color_by"]:
        rc["color_by"], rc["clim"] = color_by, None  # the config's limits belong to its own field
    if size:
        rc["size"] = list(size)
    if camera:
        rc["camera"] = camera
    try:
        check_size(rc["size"])   # before anything is read: VTK aborts the process on a size it cannot allocate
    except ValueError as e:
        raise ConfigError(str(e), key="output.render.size") from None
    series = read_series(run_dir)
    if not series:
        raise FileNotFoundError(f"{run_dir} holds no particles_*.vtu files")
    dim = cfg.dim
    states = [read_particles(f, dim) for _, f in series]
    try:  # bad options are input errors (exit code 2 on the command line), found before any frame
        vals = [field_values(s, rc["color_by"], dim) for s in states]
        FrameRenderer(rc, dim, cfg.domain.lower, cfg.domain.upper)
    except ValueError as e:
        raise ConfigError(str(e), key="output.render") from None
    t0 = _time.perf_counter()
    spacing = FrameRenderer(rc, dim, cfg.domain.lower, cfg.domain.upper)._spacing(states[0])
    bounds = framing_bounds(rc, dim, cfg.domain.lower, cfg.domain.upper)
    if bounds is None and dim == 3:
        bounds = sequence_bounds([s["x"] for s in states], spacing, dim)
    frames_dir = io.ensure_folder(run_dir / "frames", root=run_dir)   # a file in its place: said before any frame
    renderer = FrameRenderer(rc, dim, cfg.domain.lower, cfg.domain.upper, limits=sequence_limits(rc, vals),
                             bounds=bounds, title=cfg.name)
    frames = []
    try:
        for k, ((t, f), state) in enumerate(zip(series, states)):
            m = re.search(r"(\d+)", f.stem)
            idx = int(m.group(1)) if m else k
            if not np.isfinite(t):
                t = idx * cfg.output.every
            frames.append(renderer.render(state, t, frames_dir / f"frame_{idx:06d}.png"))
    finally:
        renderer.close()
    seconds = _time.perf_counter() - t0
    if movie is None:
        movie = next((fmt for fmt in cfg.output.formats if fmt in ("mp4", "gif")), False)
    movie_path = None
    if movie:
        if movie is True:
            movie_path = run_dir / "movie.mp4"
        elif str(movie).lower() in ("mp4", "gif"):
            movie_path = run_dir / f"movie.{str(movie).lower()}"
        else:
            movie_path = Path(movie)
        # this sequence only, not stale frames of an older run
        make_movie(frames, movie_path, fps=fps, root=run_dir if movie_path.parent == run_dir else None)
    return {"frames": frames, "movie": movie_path, "seconds": seconds}
