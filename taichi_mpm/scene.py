"""Bodies -> particle arrays (numpy). No Taichi here: the solver uploads what the scene needs.

Each shape is a point-membership test plus a bounding box; particles sit on a lattice of
spacing dx/ppc aligned with the grid, so bodies placed on cell boundaries fill cells evenly.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import Body, Box, Config, ConfigError, Cylinder, Mesh, Ring, Sphere


@dataclass
class Scene:
    x: np.ndarray            # (N, d) positions
    v: np.ndarray            # (N, d) velocities
    volume: np.ndarray       # (N,) initial volumes
    mass: np.ndarray         # (N,)
    body: np.ndarray         # (N,) body index
    material: np.ndarray     # (N,) index into `materials`
    damage: np.ndarray       # (N,) initial damage in [0, 1]
    interface: np.ndarray    # (N,) 1 for surface particles of interface bodies
    spacing: np.ndarray      # (N,) initial particle spacing (dx / ppc)
    materials: list = field(default_factory=list)   # material names, in index order

    @property
    def n(self) -> int:
        return len(self.x)


def _rotation(rot, d):
    """Rotation matrix from degrees: scalar (2D) or [rx, ry, rz] Euler angles (3D, applied x then y then z)."""
    if rot is None or d == 1:
        return np.eye(d)
    if d == 2:
        a = np.radians(rot if np.isscalar(rot) else rot[0])
        return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    rx, ry, rz = np.radians(rot if not np.isscalar(rot) else [0, 0, rot])
    Rx = np.array([[1, 0, 0], [0, np.cos(rx), -np.sin(rx)], [0, np.sin(rx), np.cos(rx)]])
    Ry = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    Rz = np.array([[np.cos(rz), -np.sin(rz), 0], [np.sin(rz), np.cos(rz), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def shape_center(shape, d) -> np.ndarray:
    if isinstance(shape, Box):
        return 0.5 * (np.asarray(shape.lower) + np.asarray(shape.upper))
    if isinstance(shape, Mesh):
        lo, hi = shape_bounds(shape, d, None)
        return 0.5 * (lo + hi)
    return np.asarray(shape.center, dtype=float)


def shape_bounds(shape, d, base_dir) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box of a shape (rotations included)."""
    if isinstance(shape, Box):
        lo, hi = np.asarray(shape.lower, float), np.asarray(shape.upper, float)
        if shape.rotation is None:
            return lo, hi
        c, R = 0.5 * (lo + hi), _rotation(shape.rotation, d)
        corners = np.array(np.meshgrid(*[[l, h] for l, h in zip(lo, hi)], indexing="ij")).reshape(d, -1).T
        pts = (corners - c) @ R.T + c
        return pts.min(0), pts.max(0)
    if isinstance(shape, (Sphere, Ring)):
        r = shape.radius if isinstance(shape, Sphere) else shape.outer_radius
        c = np.asarray(shape.center, float)
        return c - r, c + r
    if isinstance(shape, Cylinder):
        c = np.asarray(shape.center, float)
        ext = np.sqrt(shape.radius**2 + (shape.height / 2) ** 2)
        return c - ext, c + ext
    if isinstance(shape, Mesh):
        pts = _mesh_surface(shape, base_dir).points[:, :d]
        return pts.min(0), pts.max(0)
    raise TypeError(shape)


def _mesh_surface(shape: Mesh, base_dir):
    import meshio
    import pyvista as pv

    path = Path(shape.file)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    if not path.is_file():
        raise ConfigError(f"mesh file not found: {path}", key="shape.file")
    try:
        m = meshio.read(path)
    except Exception as e:  # meshio raises many types for unreadable files
        raise ConfigError(f"meshio cannot read {path}: {e}", key="shape.file")
    grid = pv.from_meshio(m)
    surf = grid.extract_surface(algorithm=None).triangulate()
    scale = np.broadcast_to(np.asarray(shape.scale, float), (3,))
    surf.points = surf.points * scale + np.pad(np.asarray(shape.translate or [0, 0, 0], float), (0, 3))[:3]
    return surf


def inside(shape, pts: np.ndarray, base_dir=None) -> np.ndarray:
    """Boolean mask of the points (N, d) that lie inside the shape."""
    d = pts.shape[1]
    if isinstance(shape, Box):
        lo, hi = np.asarray(shape.lower, float), np.asarray(shape.upper, float)
        c = 0.5 * (lo + hi)
        local = (pts - c) @ _rotation(shape.rotation, d)  # inverse rotation (R orthogonal)
        return np.all(np.abs(local) <= 0.5 * (hi - lo) + 1e-12, axis=1)
    if isinstance(shape, Sphere):
        return np.sum((pts - shape.center) ** 2, axis=1) <= shape.radius**2
    if isinstance(shape, Ring):
        r2 = np.sum((pts - shape.center) ** 2, axis=1)
        return (r2 <= shape.outer_radius**2) & (r2 >= shape.inner_radius**2)
    if isinstance(shape, Cylinder):
        R = _rotation(shape.rotation, 3)
        local = (pts - shape.center) @ R
        a = "xyz".index(shape.axis)
        radial = np.delete(local, a, axis=1)
        return (np.sum(radial**2, axis=1) <= shape.radius**2) & (np.abs(local[:, a]) <= shape.height / 2)
    if isinstance(shape, Mesh):
        import pyvista as pv

        surf = _mesh_surface(shape, base_dir)
        p3 = np.pad(pts, ((0, 0), (0, 3 - d)))
        sel = pv.PolyData(p3).select_interior_points(surf, check_surface=False) if hasattr(pv.PolyData, "select_interior_points") \
            else pv.PolyData(p3).select_enclosed_points(surf, check_surface=False)
        key = "selected_points" if "selected_points" in sel.point_data else "SelectedPoints"
        return np.asarray(sel.point_data[key], bool)
    raise TypeError(shape)


def _lattice(lo, hi, origin, h, jitter, rng):
    """Points at cell centres of a lattice of spacing h aligned with `origin`, covering [lo, hi]."""
    axes = []
    for l, u, o in zip(lo, hi, origin):
        k0 = int(np.floor((l - o) / h))
        k1 = int(np.ceil((u - o) / h))
        axes.append(o + (np.arange(k0, k1) + 0.5) * h)
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(lo))
    if jitter:
        pts = pts + rng.uniform(-0.5 * jitter * h, 0.5 * jitter * h, pts.shape)
    return pts


def _surface_flags(pts, h):
    """1 for particles with a missing lattice neighbour along any axis (the body's surface layer)."""
    base = np.round(pts / h - 0.5).astype(np.int64)
    occupied = set(map(tuple, base))
    flags = np.zeros(len(pts), np.int32)
    for a in range(pts.shape[1]):
        for s in (-1, 1):
            nb = base.copy()
            nb[:, a] += s
            flags |= np.fromiter((tuple(k) not in occupied for k in nb), bool, len(nb))
    return flags


def _body_particles(cfg, bi, body, mat_names, base_dir, rng) -> dict:
    """Particle arrays of one body."""
    d, dx = cfg.dim, cfg.domain.dx
    origin = np.asarray(cfg.domain.lower, float)
    dlo, dhi = origin, np.asarray(cfg.domain.upper, float)
    key = f"bodies.{bi}"
    h = dx / body.particles_per_cell
    lo, hi = shape_bounds(body.shape, d, base_dir)
    if np.any(lo < dlo - 1e-9) or np.any(hi > dhi + 1e-9):
        raise ConfigError(f"body lies outside the domain (body bounds {lo.tolist()}..{hi.tolist()}, "
                          f"domain {dlo.tolist()}..{dhi.tolist()})", key=f"{key}.shape")
    pts = _lattice(lo, hi, origin, h, 0.0, rng)
    pts = pts[inside(body.shape, pts, base_dir)]
    if len(pts) == 0:
        raise ConfigError("shape holds no particle at this resolution (make it larger or refine domain.dx / particles_per_cell)",
                          key=f"{key}.shape")
    iface = _surface_flags(pts, h) if body.interface else np.zeros(len(pts), np.int32)
    if body.placement == "jittered":
        pts = pts + rng.uniform(-0.25 * h, 0.25 * h, pts.shape)
        pts = np.clip(pts, dlo + 1e-9, dhi - 1e-9)
    mat = cfg.materials[body.material]
    vol = np.full(len(pts), h**d)
    v = np.zeros_like(pts)
    if body.velocity is not None:
        v += np.asarray(body.velocity, float)
    if body.angular_velocity is not None:
        r = pts - shape_center(body.shape, d)
        w = body.angular_velocity
        v += np.stack([-w * r[:, 1], w * r[:, 0]], axis=1) if d == 2 else np.cross(np.asarray(w, float), r)
    dmg = np.zeros(len(pts))
    for region in body.damage_regions:
        m = inside(region.shape, pts, base_dir)
        dmg[m] = np.maximum(dmg[m], region.value)
    return dict(x=pts, v=v, volume=vol, mass=vol * mat.density, body=np.full(len(pts), bi, np.int32),
                material=np.full(len(pts), mat_names.index(body.material), np.int32),
                damage=dmg, interface=iface, spacing=np.full(len(pts), h))


def build_scene(cfg: Config, seed: int = 0) -> Scene:
    base_dir = Path(cfg._source).parent if getattr(cfg, "_source", None) else None
    rng = np.random.default_rng(seed)
    mat_names = list(dict.fromkeys(b.material for b in cfg.bodies))
    parts = []
    for bi, body in enumerate(cfg.bodies):
        try:
            parts.append(_body_particles(cfg, bi, body, mat_names, base_dir, rng))
        except ConfigError as e:
            if e.key is None or not e.key.startswith("shape"):
                raise
            raise ConfigError(e.message, key=f"bodies.{bi}.{e.key}") from None  # mesh errors: name the body
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return Scene(materials=mat_names, **cat)
