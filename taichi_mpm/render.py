"""Off-screen rendering of particle states with pyvista: PNG frames and movies.

`FrameRenderer` keeps one off-screen plotter for a whole sequence and only updates the point
coordinates and colours per frame, so a 960x720 frame of ~20k particles renders in a fraction
of a second. 1D bars are drawn as a strip of cells along x, 2D scenes as points in the xy plane
seen through an orthographic camera, 3D scenes as shaded spheres (camera `iso` by default).

Rendering reads solver state only through the particle dict of `Simulation.particles()` or the
saved VTU files (`render_run`); it never touches Taichi.
"""
from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from . import fields as registry
from .fields import von_mises  # noqa: F401 (the one implementation, in fields.py)

# Scalar fields a frame can be coloured by: the registry's scalar and label fields, velocity components vx, vy, vz
# and the components sxx, sxy, ..., szz of the full 3x3 stress.
FIELDS = tuple(n for n, f in registry.REGISTRY.items() if f.kind in ("scalar", "label")) + ("vx", "vy", "vz")
_ALIASES = {"velocity": "speed", "velocity_x": "vx", "velocity_y": "vy", "velocity_z": "vz", "mises": "von_mises",
            "stress": "von_mises"}
_CAMERAS_3D = ("iso", "xy", "xz", "yz", "front", "side", "top")
CAMERAS = _CAMERAS_3D  # the names output.render.camera and --camera accept (2D and 1D frames ignore the camera)


def color_fields() -> list[str]:
    """Every name output.render.color_by and --color-by accept: the scalar fields, aliases, vx/vy/vz, sxx ... szz."""
    return list(FIELDS) + list(_ALIASES) + [f"s{a}{b}" for a in "xyz" for b in "xyz"]


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
    if name not in FIELDS:
        raise ValueError(f"unknown colour field '{name}' (choose from {', '.join(FIELDS)}, or sxx, sxy, ..., szz)")
    if name == "body" and "body" not in particles:
        return np.zeros(n)
    if not registry.available(particles, name):
        if name == "damage":
            raise ValueError("this state has no damage field (the scene has no crack section)")
        raise ValueError(f"this state has no '{name}' field (it needs {', '.join(registry.REGISTRY[name].needs)})")
    return np.asarray(registry.values(particles, name), float).reshape(n)


def available_fields(particles: dict, dim: int) -> list[str]:
    names = ["speed", "von_mises", "J", "body", "pressure"] + ["vx", "vy", "vz"][:dim]
    if "damage" in particles:
        names.insert(4, "damage")
    return names


def _label(name):
    name = _ALIASES.get(name, name)
    if name in registry.REGISTRY:
        return registry.label(name)
    if name in ("vx", "vy", "vz"):
        return f"velocity {name[1]} [m/s]"
    return f"stress {name[1:]} [Pa]"


# ---------------------------------------------------------------- renderer
class FrameRenderer:
    """Renders particle states of one scene to PNG files with a fixed camera and colour scale.

    render_cfg: the config's `output.render` (color_by, size, camera, point_size, colormap, clim),
    or a dict with those keys. Colour limits: `clim` when given; otherwise they start from the
    first frame and only ever widen, so a colour keeps its meaning through a sequence.
    """

    def __init__(self, render_cfg, dim: int, lower, upper):
        rc = render_cfg.model_dump() if hasattr(render_cfg, "model_dump") else dict(render_cfg or {})
        self.color_by = _ALIASES.get(rc.get("color_by") or "speed", rc.get("color_by") or "speed")
        self.size = tuple(int(s) for s in (rc.get("size") or (960, 720)))
        self.camera = rc.get("camera") or "iso"
        self.point_size = rc.get("point_size")
        self.cmap = rc.get("colormap") or "viridis"
        self.fixed_clim = list(rc["clim"]) if rc.get("clim") else None
        self.dim = int(dim)
        self.lower = np.asarray(lower, float)
        self.upper = np.asarray(upper, float)
        if self.dim == 3 and self.camera not in _CAMERAS_3D:
            raise ValueError(f"unknown camera '{self.camera}' (choose from {', '.join(_CAMERAS_3D)})")
        self._clim = None
        self._plotter = None
        self._mesh = None
        self._n = None

    # ------------------------------------------------------------ public
    def render(self, particles: dict, time: float, path) -> Path:
        """Write one PNG of the configured size showing `particles` at `time`."""
        values = field_values(particles, self.color_by, self.dim)
        clim = self._update_clim(values)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        p = self._setup(particles)
        self._update(particles, values, clim)
        p.add_text(f"t = {time:.4g} s", position=(12, self.size[1] - 34), font_size=12, color="black", name="time")
        p.render()
        p.screenshot(str(path))
        return path

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
    def _update_clim(self, values):
        if self.fixed_clim:
            return self.fixed_clim
        if self.color_by == "body":  # categorical: one colour per body, fixed by the first frame
            if self._clim is None:
                nb = int(np.max(values)) + 1 if len(values) else 1
                self._clim = [-0.5, max(nb, 2) - 0.5]
            return self._clim
        finite = values[np.isfinite(values)]
        lo, hi = (float(finite.min()), float(finite.max())) if len(finite) else (0.0, 1.0)
        if self._clim is not None:
            lo, hi = min(lo, self._clim[0]), max(hi, self._clim[1])
        self._clim = [lo, hi]
        if hi - lo < 1e-6 * max(1.0, abs(hi)):  # a flat field (e.g. a uniform speed at t = 0)
            pad = 0.5 * abs(hi) if hi != 0 else 1.0
            nonneg = self.color_by in ("speed", "von_mises", "damage", "plastic_strain") and lo >= 0
            return [0.0 if nonneg else lo - pad, hi + pad]
        return self._clim

    def _spacing(self, particles):
        vol = np.asarray(particles.get("volume", []), float)
        if len(vol):
            return float(np.median(np.abs(vol))) ** (1.0 / self.dim)
        ext = float(np.max(self.upper - self.lower))
        return ext / max(1.0, len(particles["x"]) ** (1.0 / self.dim))

    def _points3(self, x):
        x = np.asarray(x, float).reshape(len(x), -1)[:, : self.dim]
        return np.pad(x, ((0, 0), (0, 3 - self.dim)))

    def _bar_mesh(self, particles):
        """1D: each particle becomes a quad [x - h/2, x + h/2] x [0, H]; colours are cell data."""
        pv = _pyvista()
        x = np.asarray(particles["x"], float).reshape(-1)
        vol = np.asarray(particles.get("volume", np.full(len(x), self._spacing(particles))), float).reshape(-1)
        h = np.abs(vol) / 2
        H = 0.04 * float(self.upper[0] - self.lower[0])
        pts = np.stack([np.c_[x - h, np.zeros_like(x), np.zeros_like(x)], np.c_[x + h, np.zeros_like(x), np.zeros_like(x)],
                        np.c_[x + h, np.full_like(x, H), np.zeros_like(x)], np.c_[x - h, np.full_like(x, H), np.zeros_like(x)]],
                       axis=1).reshape(-1, 3)
        n = len(x)
        faces = np.c_[np.full(n, 4), 4 * np.arange(n)[:, None] + np.arange(4)].ravel()
        return pv.PolyData(pts, faces=faces)

    def _pixels_per_unit(self):
        ext = self.upper - self.lower
        w, h = self.size
        if self.dim == 1:
            return 0.9 * w / ext[0]
        if self.dim == 2:
            return 0.9 * min(w / ext[0], h / ext[1])
        return 0.75 * min(w, h) / float(np.linalg.norm(ext))

    def _setup(self, particles):
        pv = _pyvista()
        n = len(particles["x"])
        if self._plotter is not None and n == self._n:
            return self._plotter
        self.close()
        p = pv.Plotter(off_screen=True, window_size=list(self.size))
        p.set_background("white")
        self._n = n
        lo3 = np.pad(self.lower, (0, 3 - self.dim))
        hi3 = np.pad(self.upper, (0, 3 - self.dim))
        if self.dim == 1:
            self._mesh = self._bar_mesh(particles)
            H = 0.04 * (hi3[0] - lo3[0])
            hi3 = hi3 + np.array([0, H, 0])
        else:
            self._mesh = pv.PolyData(self._points3(particles["x"]))
        self._mesh[self.color_by] = np.zeros(self._mesh.n_cells if self.dim == 1 else n)
        cmap = "tab10" if self.color_by == "body" else self.cmap
        bar = dict(title=_label(self.color_by), color="black", fmt="%.3g", n_labels=5, vertical=False,
                   position_x=0.2, position_y=0.03, width=0.6, height=0.07, title_font_size=16, label_font_size=14)
        if self.dim == 1:
            self._actor = p.add_mesh(self._mesh, scalars=self.color_by, cmap=cmap, scalar_bar_args=bar, show_edges=False,
                       preference="cell", lighting=False)
        else:
            ps = self.point_size or max(2.0, 1.05 * self._spacing(particles) * self._pixels_per_unit())
            self._actor = p.add_mesh(self._mesh, scalars=self.color_by, cmap=cmap, scalar_bar_args=bar, style="points",
                       point_size=ps, render_points_as_spheres=self.dim == 3, lighting=self.dim == 3)
        box = pv.Box(bounds=(lo3[0], hi3[0], lo3[1], hi3[1], lo3[2], hi3[2]))
        p.add_mesh(box.outline() if self.dim == 3 else pv.Box(bounds=(lo3[0], hi3[0], lo3[1], hi3[1], 0, 0)).outline(),
                   color="gray", line_width=1)
        self._place_camera(p, lo3, hi3)
        self._plotter = p
        return p

    def _place_camera(self, p, lo3, hi3):
        """Fit the domain into the window above the colour bar (bottom ~20 %) and below the time label."""
        c = 0.5 * (lo3 + hi3)
        ext = hi3 - lo3
        w, h = self.size
        top = min(0.92, 1 - 40 / h)       # window fractions the domain may use: below the time label
        bottom = max(0.2, 75 / h)         # and above the colour bar
        mid = 0.5 * (top + bottom)
        if self.dim < 3:
            p.enable_parallel_projection()
            fit_height = ext[1] / (top - bottom) if self.dim == 2 else 0.0  # a 1D strip only fits the width
            scale = max(fit_height, ext[0] * h / w / 0.92, 1e-9) / 2  # half the visible height
            focal = c - np.array([0.0, (mid - 0.5) * 2 * scale, 0.0])
            p.camera.focal_point = tuple(focal)
            p.camera.position = tuple(focal + np.array([0, 0, 10 * max(ext.max(), 1e-9)]))
            p.camera.up = (0, 1, 0)
            p.camera.parallel_scale = scale
            return
        views = {"iso": (1.0, 0.75, 1.5), "front": (0, 0, 1), "xy": (0, 0, 1), "xz": (0, 1, 0), "top": (0, 1, 0),
                 "yz": (1, 0, 0), "side": (1, 0, 0)}
        direction = np.asarray(views[self.camera], float)
        direction /= np.linalg.norm(direction)
        up = (0, 0, -1) if self.camera in ("xz", "top") else (0, 1, 0)
        angle = 30.0
        radius = 0.5 * float(np.linalg.norm(ext))      # the domain's bounding sphere
        half = np.radians(angle / 2)
        dist = radius / np.sin(half) / (top - bottom) * 0.95
        dist = max(dist, radius / np.sin(half) * h / w / 0.95)
        # aim above the centre so the domain sits in the band between bar and label
        up_vec = np.asarray(up, float)
        shift = (mid - 0.5) * 2 * dist * np.tan(half)
        focal = c - shift * up_vec
        p.camera.focal_point = tuple(focal)
        p.camera.position = tuple(focal + dist * direction)
        p.camera.up = up
        p.camera.view_angle = angle
        p.reset_camera_clipping_range()

    def _update(self, particles, values, clim):
        if self.dim == 1:
            new = self._bar_mesh(particles)
            self._mesh.points = new.points
        else:
            self._mesh.points = self._points3(particles["x"])
        self._mesh[self.color_by] = np.asarray(values, float)
        self._actor.mapper.scalar_range = (float(clim[0]), float(clim[1]))
        if self.dim == 3:
            self._plotter.reset_camera_clipping_range()


# ---------------------------------------------------------------- movies
def make_movie(frames_dir, out_path, fps: int = 20) -> Path:
    """Join frames_dir/frame_*.png (in name order) into an mp4 (imageio-ffmpeg, H.264) or a gif, by suffix.
    frames_dir may also be a list of PNG paths."""
    import imageio.v2 as imageio

    if isinstance(frames_dir, (list, tuple)):
        frames = [Path(f) for f in frames_dir]
    else:
        frames = sorted(Path(frames_dir).glob("frame_*.png"))
    if not frames:
        raise FileNotFoundError(f"no frame_*.png in {frames_dir}")
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    suffix = out.suffix.lower()
    if suffix == ".gif":
        images = [imageio.imread(f)[..., :3] for f in frames]
        imageio.mimsave(out, images, duration=1000.0 / fps, loop=0)
        return out
    if suffix not in (".mp4", ".mov", ".mkv", ".avi"):
        raise ValueError(f"unknown movie format '{suffix}' (use .mp4 or .gif)")
    writer = imageio.get_writer(out, fps=fps, codec="libx264", quality=7, macro_block_size=1,
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
            from .errors import ConfigError

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

    from .errors import ConfigError
    from .io import read_vtu

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
    return p


def render_run(run_dir, color_by=None, size=None, camera=None, movie=None, fps: int = 20) -> dict:
    """Re-render the saved output of a run directory into frames/frame_NNNNNN.png (and a movie).

    color_by, size, camera override the run's `output.render`; the colour limits are fixed over
    the whole sequence (config `clim`, or the range over all saved states). movie: None follows the
    run's output.formats (mp4 / gif), False makes none, True or "mp4" / "gif" or a path makes one.
    Returns {"frames": [paths], "movie": path or None}.
    """
    from .config import load_config
    from .errors import ConfigError

    run_dir = Path(run_dir)
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
    series = read_series(run_dir)
    if not series:
        raise FileNotFoundError(f"{run_dir} holds no particles_*.vtu files")
    dim = cfg.dim
    states = [read_particles(f, dim) for _, f in series]
    try:  # bad options are input errors (exit code 2 on the command line), found before any frame
        field_values(states[0], rc["color_by"], dim)
        FrameRenderer(rc, dim, cfg.domain.lower, cfg.domain.upper)
    except ValueError as e:
        raise ConfigError(str(e), key="output.render") from None
    if not rc.get("clim"):
        vals = [field_values(s, rc["color_by"], dim) for s in states]
        lo = min(float(np.nanmin(v)) for v in vals)
        hi = max(float(np.nanmax(v)) for v in vals)
        if hi > lo:
            rc["clim"] = [lo, hi]
    renderer = FrameRenderer(rc, dim, cfg.domain.lower, cfg.domain.upper)
    frames_dir = run_dir / "frames"
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
        make_movie(frames, movie_path, fps=fps)  # this sequence only, not stale frames of an older run
    return {"frames": frames, "movie": movie_path}
