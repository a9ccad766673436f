"""Bodies -> particle arrays (numpy). No Taichi here: the solver uploads what the scene needs.

Each shape is a point-membership test plus a bounding box; particles sit on a lattice of
spacing dx/ppc aligned with the grid, so bodies placed on cell boundaries fill cells evenly.
"""
from __future__ import annotations

import contextlib
import io
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import NamedTuple, Optional

import numpy as np

from .config import SPACE, TIME, Body, Box, Config, ConfigError, Cylinder, Mesh, Ring, Sphere
from . import geometry
from .expressions import evaluate


@dataclass
class Load:
    """One traction entry: the particles it loads and the force each gets at ramp 1 (traction x face area)."""
    particles: np.ndarray    # (M,) particle indices
    force: np.ndarray        # (M, d) N (per metre of depth in 2D, per m^2 in 1D)
    ramp: object             # number or expression text of t
    key: str                 # bodies.I.tractions.J, for error messages


@dataclass
class NodeLoad:
    """One traction entry applied as nodal forces (tractions[].apply_to: nodes): the consistent load
    int R_i t dA over the loaded faces of a map-placed body, on the mapped grid's control points."""
    nodes: np.ndarray        # (K, d) grid indices of the loaded nodes (a periodic map's seam folded)
    force: np.ndarray        # (K, d) N at ramp 1
    ramp: object             # number or expression text of t
    key: str                 # bodies.I.tractions.J


@dataclass
class Grip:
    """One prescribed-velocity entry: the particles whose velocity is prescribed, and the velocity spec."""
    particles: np.ndarray    # (M,) particle indices
    velocity: list           # per axis: number, expression text of t, or None (free)
    key: str                 # bodies.I.prescribed_velocity.J


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
    stress: Optional[np.ndarray] = None   # (N, d, d) initial Cauchy stress (bodies[].stress); None: no body has one
    loads: list = field(default_factory=list)   # Load per bodies[].tractions entry on particles, in body order
    node_loads: list = field(default_factory=list)   # NodeLoad per entry with apply_to: nodes
    grips: list = field(default_factory=list)   # Grip per bodies[].prescribed_velocity entry, in body order
    # (particles, F, material state) per bodies[].geostatic: cam_clay's K0 start (materials.cam_clay.geostatic_state)
    geostatic: list = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.x)


def shape_center(shape, d, base_dir=None, key="shape") -> np.ndarray:
    if isinstance(shape, Box):
        return 0.5 * (np.asarray(shape.lower) + np.asarray(shape.upper))
    if isinstance(shape, Mesh):
        lo, hi = shape_bounds(shape, d, base_dir, key)
        return 0.5 * (lo + hi)
    return np.asarray(shape.center, dtype=float)


def shape_bounds(shape, d, base_dir=None, key="shape") -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box of a shape (rotations included; a mesh's from its file)."""
    if isinstance(shape, Mesh):
        m = load_mesh(shape, d, base_dir, key)
        return m.lower, m.upper
    return geometry.bounds(shape, d)


def shape_volume(shape, d, base_dir=None, key="shape") -> float:
    """Length, area or volume of a shape in `d` dimensions (what its particles fill)."""
    ball = {1: 2.0, 2: np.pi, 3: 4.0 / 3.0 * np.pi}[d]  # volume of the unit ball
    if isinstance(shape, Box):
        return float(np.prod(np.asarray(shape.upper, float) - np.asarray(shape.lower, float)))
    if isinstance(shape, Sphere):
        return ball * shape.radius**d
    if isinstance(shape, Ring):
        return ball * (shape.outer_radius**d - shape.inner_radius**d)
    if isinstance(shape, Cylinder):
        return np.pi * (shape.radius**2 - shape.inner_radius**2) * shape.height
    if isinstance(shape, Mesh):
        return load_mesh(shape, d, base_dir, key).volume
    raise TypeError(shape)


def inside(shape, pts: np.ndarray, base_dir=None, key="shape") -> np.ndarray:
    """Boolean mask of the points (N, d) that lie inside the shape."""
    d = pts.shape[1]
    if isinstance(shape, Box):
        lo, hi = np.asarray(shape.lower, float), np.asarray(shape.upper, float)
        c = 0.5 * (lo + hi)
        local = (pts - c) @ geometry.rotation(shape.rotation, d)  # inverse rotation (R orthogonal)
        return np.all(np.abs(local) <= 0.5 * (hi - lo) + 1e-12, axis=1)
    if isinstance(shape, Sphere):
        return np.sum((pts - shape.center) ** 2, axis=1) <= shape.radius**2
    if isinstance(shape, Ring):
        r2 = np.sum((pts - shape.center) ** 2, axis=1)
        return (r2 <= shape.outer_radius**2) & (r2 >= shape.inner_radius**2)
    if isinstance(shape, Cylinder):
        R = geometry.rotation(shape.rotation, 3)
        local = (pts - shape.center) @ R
        a = "xyz".index(shape.axis)
        radial = np.delete(local, a, axis=1)
        r2 = np.sum(radial**2, axis=1)
        return (r2 <= shape.radius**2) & (r2 >= shape.inner_radius**2) & (np.abs(local[:, a]) <= shape.height / 2)
    if isinstance(shape, Mesh):
        return load_mesh(shape, d, base_dir, key).inside(pts)
    raise TypeError(shape)


# ---------------------------------------------------------------- meshes
@dataclass
class Outline:
    """A 2D mesh as the boundary of the area it covers: edges (E, 2, 2) of its cells' boundary, or its
    closed line loops. Membership by the even-odd rule, so holes and several pieces need no orientation."""
    edges: np.ndarray

    @property
    def lower(self):
        return self.edges.reshape(-1, 2).min(0)

    @property
    def upper(self):
        return self.edges.reshape(-1, 2).max(0)

    def _crossings(self, y: float) -> np.ndarray:
        """Sorted x where the boundary crosses the line at height y (half-open in y: a vertex counts once)."""
        a, b = self.edges[:, 0], self.edges[:, 1]
        hit = (a[:, 1] <= y) != (b[:, 1] <= y)
        a, b = a[hit], b[hit]
        return np.sort(a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1]))

    def inside(self, pts: np.ndarray) -> np.ndarray:
        """Odd number of crossings to the right of the point: inside. One pass per distinct y (a lattice has few)."""
        ys, row = np.unique(pts[:, 1], return_inverse=True)
        out = np.zeros(len(pts), bool)
        order = np.argsort(row, kind="stable")
        starts = np.searchsorted(row[order], np.arange(len(ys) + 1))
        for i, y in enumerate(ys):
            idx = order[starts[i]:starts[i + 1]]
            xc = self._crossings(y)
            out[idx] = (len(xc) - np.searchsorted(xc, pts[idx, 0], side="right")) % 2 == 1
        return out

    @cached_property
    def volume(self) -> float:
        """Area by the even-odd rule: between two consecutive vertex heights the inside length is linear in y
        (edges do not cross), so the midpoint rule is exact."""
        ys = np.unique(self.edges[:, :, 1])
        area = 0.0
        for y0, y1 in zip(ys[:-1], ys[1:]):
            xc = self._crossings(0.5 * (y0 + y1))
            area += (y1 - y0) * float(np.sum(xc[1::2] - xc[0::2]))
        return area


@dataclass
class Surface:
    """A 3D mesh as a closed, outward-oriented triangle surface (pyvista.PolyData)."""
    surf: object
    volume: float

    @property
    def lower(self):
        return np.asarray(self.surf.bounds, float).reshape(3, 2)[:, 0]

    @property
    def upper(self):
        return np.asarray(self.surf.bounds, float).reshape(3, 2)[:, 1]

    def inside(self, pts: np.ndarray) -> np.ndarray:
        import pyvista as pv

        # vtkSelectEnclosedPoints: correct only for a closed surface with outward normals (checked in load_mesh);
        # an inverted one selects the complement
        cloud = pv.PolyData(np.asarray(pts, float))
        select = getattr(cloud, "select_interior_points", None) or cloud.select_enclosed_points
        sel = select(self.surf, check_surface=False)
        key = "selected_points" if "selected_points" in sel.point_data else "SelectedPoints"
        return np.asarray(sel.point_data[key], bool)


_MESHES: dict = {}  # (file, mtime, size, dim, scale, translate) -> Outline | Surface


def load_mesh(shape: Mesh, d: int, base_dir=None, key="shape"):
    """The mesh of a `mesh` shape, scaled and translated: an Outline in 2D, a closed Surface in 3D.
    Read once per file and placement; any problem is a ConfigError naming `key.file` and the file."""
    path = Path(shape.file)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    if not path.is_file():
        raise ConfigError(f"mesh file not found: {path}", key=f"{key}.file")
    scale = np.asarray(shape.scale, float)
    scale = np.full(3, scale) if scale.ndim == 0 else np.pad(scale, (0, 3 - len(scale)), constant_values=1.0)
    shift = np.pad(np.asarray(shape.translate or [], float), (0, 3 - len(shape.translate or [])))
    st = path.stat()
    cache_key = (str(path.resolve()), st.st_mtime_ns, st.st_size, d, tuple(scale), tuple(shift))
    if cache_key not in _MESHES:
        mesh = _read_mesh(path, key)
        points = np.pad(np.asarray(mesh.points, float), ((0, 0), (0, max(0, 3 - mesh.points.shape[1]))))[:, :3]
        points = points * scale + shift
        if len(_MESHES) > 16:
            _MESHES.clear()
        _MESHES[cache_key] = (_outline if d == 2 else _surface)(mesh, points, path, f"{key}.file")
    return _MESHES[cache_key]


def _read_mesh(path: Path, key: str):
    import meshio

    said = io.StringIO()
    try:  # some readers print their complaint and call sys.exit; numpy may warn on binary garbage
        with warnings.catch_warnings(), contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            warnings.simplefilter("ignore")
            mesh = meshio.read(path)
    except (Exception, SystemExit) as e:
        detail = " ".join(said.getvalue().split()) if isinstance(e, SystemExit) else str(e)
        raise ConfigError(f"meshio cannot read {path}: {detail or type(e).__name__}", key=f"{key}.file") from None
    if len(mesh.points) == 0 or not mesh.cells:
        raise ConfigError(f"the mesh {path} has no points or no cells", key=f"{key}.file")
    return mesh


def _outline(mesh, points, path, key) -> Outline:
    """Boundary edges of the area cells (edges used by one cell), else the line cells, which must close."""
    span = np.ptp(points, axis=0)
    if span[2] > 1e-9 * max(span[0], span[1], 1e-300):
        raise ConfigError(f"a 2D scene needs a mesh in a plane z = const; {path} spans {span[2]:g} in z", key=key)
    faces, lines = [], []
    for block in mesh.cells:
        t, cells = block.type, np.asarray(block.data)
        if t.startswith("triangle"):
            faces.append(cells[:, :3])
        elif t.startswith("quad"):
            faces.append(cells[:, :4])
        elif t.startswith("polygon"):
            faces.append(cells)
        elif t.startswith("line"):
            lines.append(cells[:, :2])
    if faces:
        edges = np.concatenate([np.stack([f, np.roll(f, -1, axis=1)], axis=-1).reshape(-1, 2) for f in faces])
        pairs, counts = np.unique(np.sort(edges, axis=1), axis=0, return_counts=True)
        edges = pairs[counts == 1]  # shared edges are interior
    elif lines:
        edges = np.concatenate(lines)
        ends = np.bincount(edges.ravel(), minlength=len(points))
        if np.any(ends % 2):
            raise ConfigError(f"the line cells in {path} do not form closed polygons: {int(np.sum(ends % 2))} open "
                              "ends (a 2D mesh body needs triangles, quads, polygons or closed line loops)", key=key)
    else:
        kinds = ", ".join(sorted({b.type for b in mesh.cells}))
        raise ConfigError(f"{path} holds no 2D cells (found: {kinds}); a 2D mesh body needs triangles, quads, "
                          "polygons or closed line loops", key=key)
    outline = Outline(points[edges][:, :, :2])
    if len(outline.edges) == 0 or outline.volume <= 0:
        raise ConfigError(f"the mesh {path} encloses no area", key=key)
    return outline


def _surface(mesh, points, path, key) -> Surface:
    """The closed triangle surface of a surface or volume mesh, oriented outward (see Surface.inside)."""
    import meshio
    import pyvista as pv

    try:
        grid = pv.from_meshio(meshio.Mesh(points, mesh.cells))
        surf = grid.extract_surface(algorithm=None).triangulate().clean()
    except Exception as e:
        raise ConfigError(f"cannot extract a surface from {path}: {e}", key=key) from None
    tri = _triangles(surf)
    if len(tri) == 0:
        raise ConfigError(f"{path} holds no surface (a 3D mesh body needs a closed surface or a volume mesh)", key=key)
    boundary, non_manifold = _open_edges(tri)
    if boundary or non_manifold:
        extra = f" and {non_manifold} edges shared by more than two faces" if non_manifold else ""
        raise ConfigError(f"the surface in {path} is not closed: {boundary} boundary edges (edges of only one "
                          f"face){extra}; a mesh body needs a closed surface (every edge shared by exactly two faces)",
                          key=key)
    p = np.asarray(surf.points, float)
    oriented, volume, fixes = _orient(p, tri, path, key)
    if fixes:
        warnings.warn(f"key '{key}': the surface in {path} was {' and '.join(fixes)}; particles fill the corrected, "
                      "outward-facing surface", MeshWarning, stacklevel=2)
        surf = _polydata(p, oriented)
    return Surface(surf, volume)


def _polydata(p, tri):
    import pyvista as pv

    return pv.PolyData(p, np.hstack([np.full((len(tri), 1), 3), tri]).ravel())


def _open_edges(tri: np.ndarray) -> tuple[int, int]:
    """(edges of one face, edges of more than two faces): a closed surface has every edge in exactly two."""
    _, counts = np.unique(np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1),
                          axis=0, return_counts=True)
    return int(np.sum(counts == 1)), int(np.sum(counts > 2))


def _orient(p, tri, path, key):
    """Orient a closed surface for vtkSelectEnclosedPoints, which selects the complement of an inverted one:
    within each closed piece every edge runs once each way (faces flipped to agree with their neighbours), and
    each piece faces outward, or inward for a cavity (a piece inside an odd number of others).
    Returns (triangles, enclosed volume, descriptions of what was changed)."""
    F = len(tri)
    directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])  # row r belongs to face r % F
    _, edge = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True)
    order = np.argsort(edge.ravel(), kind="stable")
    a, b = order[0::2], order[1::2]  # the two faces of each edge (closed: exactly two)
    same = directed[a, 0] == directed[b, 0]  # both run the edge the same way: one of them must flip
    side, other, rel = np.concatenate([a % F, b % F]), np.concatenate([b % F, a % F]), np.concatenate([same, same])
    by_face = np.argsort(side, kind="stable")  # three neighbours per triangle
    nbs, rels = other[by_face].reshape(F, 3).tolist(), rel[by_face].reshape(F, 3).tolist()
    flip, piece = [0] * F, [-1] * F
    n_pieces = 0
    for seed in range(F):  # breadth-first over shared edges: flip parity relative to each piece's first face
        if piece[seed] >= 0:
            continue
        piece[seed], todo = n_pieces, [seed]
        while todo:
            f = todo.pop()
            for g, r in zip(nbs[f], rels[f]):
                want = flip[f] ^ r
                if piece[g] < 0:
                    piece[g], flip[g] = n_pieces, want
                    todo.append(g)
                elif flip[g] != want:
                    raise ConfigError(f"the faces of the surface in {path} cannot be oriented consistently "
                                      "(a non-orientable or self-intersecting surface)", key=key)
        n_pieces += 1
    flip, piece = np.array(flip, bool), np.array(piece)
    tri = np.where(flip[:, None], tri[:, ::-1], tri)
    signed = np.einsum("ij,ij->i", p[tri[:, 0]], np.cross(p[tri[:, 1]], p[tri[:, 2]])) / 6.0
    volumes = np.bincount(piece, weights=signed, minlength=n_pieces)
    depth = np.zeros(n_pieces, int)
    if n_pieces > 1:  # nesting: is a vertex of piece i inside piece j (oriented outward for the test)?
        probes = p[tri[np.unique(piece, return_index=True)[1], 0]]  # a vertex of each piece
        for j in range(n_pieces):
            tj = tri[piece == j] if volumes[j] > 0 else tri[piece == j][:, ::-1]
            others = np.arange(n_pieces) != j
            depth[others] += Surface(_polydata(p, tj), 0.0).inside(probes[others])
    wrong = (volumes > 0) != (depth % 2 == 0)
    flip ^= wrong[piece]
    tri = np.where(wrong[piece][:, None], tri[:, ::-1], tri)
    fixes = []
    changed = np.bincount(piece, weights=flip, minlength=n_pieces)
    sizes = np.bincount(piece, minlength=n_pieces)
    if np.any((changed > 0) & (changed < sizes)):
        fixes.append(f"inconsistently oriented ({int(changed[changed < sizes].sum())} of {F} faces disagreed with "
                     "their neighbours)")
    if np.any(changed == sizes):
        fixes.append("inverted (its faces pointed inward)" if n_pieces == 1 else
                     f"inverted in {int(np.sum(changed == sizes))} of its {n_pieces} closed pieces")
    return tri, float(np.abs(volumes).dot(np.where(depth % 2 == 0, 1.0, -1.0))), fixes


class MeshWarning(UserWarning):
    """A mesh that was corrected on loading (its orientation)."""


def _triangles(surf) -> np.ndarray:
    faces = np.asarray(surf.faces)
    if len(faces) == 0:
        return np.zeros((0, 3), np.int64)
    return faces.reshape(-1, 4)[:, 1:].astype(np.int64)


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


def _surface_flags(pts, h, first_axis=0, box=None):
    """1 for particles with a missing lattice neighbour along any axis from first_axis on (the body's surface
    layer; a full-turn map's angle, axis 0 of its parameters, has no surface). box: the domain's (lower, upper), for
    a lattice in space: a neighbour whose place lies beyond the domain's faces is not missing (no other body can
    touch a face on the domain's boundary, and counting it tilted the interface normals of two bodies flush with
    a common face of the domain: docs/crack_finder.md, "Friction")."""
    base = np.round(pts / h - 0.5).astype(np.int64)
    occupied = set(map(tuple, base))
    flags = np.zeros(len(pts), np.int32)
    for a in range(first_axis, pts.shape[1]):
        for s in (-1, 1):
            nb = base.copy()
            nb[:, a] += s
            missing = np.fromiter((tuple(k) not in occupied for k in nb), bool, len(nb))
            if box is not None:
                place = pts[:, a] + s * h   # the neighbour's place
                missing &= (place > box[0][a]) & (place < box[1][a])
            flags |= missing
    return flags


def _exposed_faces(pts, origin, h) -> np.ndarray:
    """(N, d, 2) bool: the particle's lattice neighbour along -axis (0) or +axis (1) is missing from the body, so
    that face of the particle's cell is on the body's surface (outward normal -e_a or +e_a)."""
    base = np.round((pts - origin) / h - 0.5).astype(np.int64)
    lo = base.min(0) - 1
    ext = base.max(0) - lo + 2
    def code(k):
        return np.ravel_multi_index(tuple((k - lo).T), tuple(ext))
    occupied = np.sort(code(base))
    out = np.zeros((len(pts), pts.shape[1], 2), bool)
    for a in range(pts.shape[1]):
        for side, s in enumerate((-1, 1)):
            nb = base.copy()
            nb[:, a] += s
            c = code(nb)
            i = np.minimum(np.searchsorted(occupied, c), len(occupied) - 1)
            out[:, a, side] = occupied[i] != c
    return out


def _loaded_faces(t, exposed, pts, key, base_dir) -> np.ndarray:
    """(N, d, 2) the exposed particle faces one traction entry loads: those of the particles inside its region (or
    all), restricted to its `faces`."""
    d = pts.shape[1]
    chosen = np.ones(len(pts), bool) if t.region is None else inside(t.region, pts, base_dir, f"{key}.region")
    mask = exposed & chosen[:, None, None]
    if t.faces is not None:
        keep = np.zeros((d, 2), bool)
        for face in t.faces:
            keep["xyz".index(face[0]), int(face.endswith("max"))] = True   # int: a bool index is a mask
        mask &= keep[None]
    if not mask.any():
        raise ConfigError("loads no particle face: no surface particle of the body lies in the region"
                          + (" with the faces named" if t.faces else ""), key=key)
    return mask


def _traction_forces(t, mask, h, areas=None):
    """Particles and forces (at ramp 1) of one traction entry: every loaded face (`mask`, _loaded_faces) gets
    traction x h^(d-1) or -pressure n h^(d-1). With `areas` (placement map: (N, d, 2, d) outward area vectors of
    the particles' faces in the map's parameter lattice, whose faces the names then mean), traction x |area| or
    -pressure x area."""
    d = mask.shape[1]
    n_faces = mask.sum(axis=(1, 2))
    sel = np.flatnonzero(n_faces)
    if areas is not None:
        vec = (areas * mask[..., None])[sel].sum(axis=(1, 2))            # the loaded faces' outward area vectors
        size = (np.linalg.norm(areas, axis=-1) * mask)[sel].sum(axis=(1, 2))
        force = np.outer(size, np.asarray(t.traction, float)) if t.traction is not None else -t.pressure * vec
        return sel, force
    area = h ** (d - 1)
    if t.traction is not None:
        force = np.outer(n_faces[sel], np.asarray(t.traction, float)) * area
    else:  # outward normal of face (a, side) is (2 side - 1) e_a; pressure pushes along -n
        normals = mask[sel, :, 1].astype(float) - mask[sel, :, 0].astype(float)
        force = -t.pressure * normals * area
    return sel, force


def _node_traction(t, mask, placed, key) -> NodeLoad:
    """apply_to nodes: the consistent nodal forces sum_q R_i(xi_q) (traction |A_q| or -pressure A_q) of the loaded
    faces, each face sampled at 2 Gauss points per tangential parameter axis (A_q: their area vectors)."""
    from .bases import mapgeom

    net = placed.net
    _, _, xi, vec = _map_face_points(net, placed.xi, mask, round(1 / placed.h), FACE_GAUSS)
    f = np.outer(np.linalg.norm(vec, axis=1), t.traction) if t.traction is not None else -t.pressure * vec
    nodal = mapgeom.node_sums(net.knots, net.degrees, net.w, xi, f)
    if placed.wraps:   # a full turn: the last layer of control points is the first (the grid stores it once)
        nodal[0] += nodal[-1]
        nodal = nodal[:-1]
    nodes = np.argwhere(np.abs(nodal).sum(-1) > 0)
    return NodeLoad(nodes.astype(np.int32), nodal[tuple(nodes.T)], t.ramp, key)


def _map_lattice(net, per_cell: int):
    """placement map: `per_cell` particles per axis in every cell of the mapped grid's parameter space (net: its
    nurbs.Map), at the centres of equal parameter sub-cells: (xi (N, d), x (N, d), volume (N,) = |det J| dxi^d,
    J (N, d, d))."""
    from .bases import mapgeom

    axes = [(np.arange(round(t[-1] * per_cell)) + 0.5) / per_cell for t in net.knots]   # knots in cell units
    xi = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    x, J = mapgeom.surface(net.knots, net.degrees, net.P, net.w, xi)
    return xi, x, np.abs(np.linalg.det(J)) / per_cell ** len(axes)


# a face's sample points along each tangential parameter axis (in units of the face) and their weights: the
# midpoint, or Gauss-Legendre's 2 points (exact for cubics along the face)
FACE_MIDPOINT = ((0.5,), (1.0,))
FACE_GAUSS = ((0.5 - 0.5 / 3 ** 0.5, 0.5 + 0.5 / 3 ** 0.5), (0.5, 0.5))


def _map_face_points(net, xi, mask, per_cell: int, rule=FACE_MIDPOINT):
    """The masked faces (N, d, 2) of the particles' parameter sub-cells, sampled by `rule` per tangential axis:
    (particle (Q,), its face (Q, 2): axis and side, parameter points (Q, d), outward area vectors (Q, d)); a face's
    vectors add up to its area vector -+|det J| J^-T e_a dxi^(d-1) (J at each point)."""
    from itertools import product

    from .bases import mapgeom

    d = xi.shape[1]
    offsets, weights = rule
    who, faces, where, vectors = [], [], [], []
    for a in range(d):
        tangential = [b for b in range(d) if b != a]
        for side in (0, 1):
            sel = np.flatnonzero(mask[:, a, side])
            if not len(sel):
                continue
            for at in product(range(len(offsets)), repeat=d - 1):
                face = xi[sel].copy()
                face[:, a] += (side - 0.5) / per_cell
                weight = 1.0
                for b, k in zip(tangential, at):
                    face[:, b] += (offsets[k] - 0.5) / per_cell
                    weight *= weights[k]
                _, Jf = mapgeom.surface(net.knots, net.degrees, net.P, net.w, face)
                # |det J| J^-T e_a: the face's area vector along increasing xi_a (whatever the map's handedness)
                cof = np.abs(np.linalg.det(Jf))[:, None, None] * np.linalg.inv(Jf).transpose(0, 2, 1)
                who.append(sel)
                faces.append(np.tile((a, side), (len(sel), 1)))
                where.append(face)
                vectors.append((2 * side - 1) * weight * cof[:, :, a] / per_cell ** (d - 1))
    if not who:
        return np.zeros(0, int), np.zeros((0, 2), int), np.zeros((0, d)), np.zeros((0, d))
    return np.concatenate(who), np.concatenate(faces), np.concatenate(where), np.concatenate(vectors)


def _map_face_areas(net, xi, exposed, per_cell: int):
    """(N, d, 2, d): the outward area vector of each exposed face of the particles' parameter sub-cells (zero for
    the others), -+|det J| J^-T e_a dxi^(d-1) with J taken at the face's centre."""
    n, d = xi.shape
    out = np.zeros((n, d, 2, d))
    who, faces, _, vec = _map_face_points(net, xi, exposed, per_cell)
    out[who, faces[:, 0], faces[:, 1]] = vec
    return out


def _label(bi, body) -> str:
    return f"bodies.{bi}" + (f" ({body.name!r})" if body.name else "")


def _overlap_free(cfg, bi, body, pts, base_dir) -> np.ndarray:
    """Mask of the particles to keep: a particle inside an earlier body's shape would double the mass there.
    Touching bodies keep all: their particles sit inside their own shapes, not on the shared face."""
    keep = np.ones(len(pts), bool)
    if body.overlap == "allow":
        return keep
    for bj, other in enumerate(cfg.bodies[:bi]):
        okey = f"bodies.{bj}.shape"
        lo, hi = shape_bounds(other.shape, cfg.dim, base_dir, okey)
        near = keep & np.all((pts >= lo - 1e-9) & (pts <= hi + 1e-9), axis=1)
        if not near.any():
            continue
        hit = np.zeros(len(pts), bool)
        hit[near] = inside(other.shape, pts[near], base_dir, okey)
        if not hit.any():
            continue
        if body.overlap == "error":
            raise ConfigError(f"{_label(bi, body)} overlaps {_label(bj, other)}: {int(hit.sum())} of its {len(pts)} "
                              f"particles lie inside bodies.{bj}'s shape, which would double the mass there; set "
                              f"bodies.{bi}.overlap: skip to leave them out, or allow to keep both (e.g. a mixture)",
                              key=f"bodies.{bi}.shape")
        keep &= ~hit
    return keep


class _Placed(NamedTuple):
    x: np.ndarray          # (N, d) positions
    volume: np.ndarray     # (N,)
    lattice: np.ndarray    # (N, d) the lattice the neighbours are found on: x, or the map's parameters (placement map)
    h: float               # its spacing
    origin: np.ndarray     # and origin
    xi: Optional[np.ndarray] = None   # placement map: the parameters (= lattice), the map (a nurbs.Map) and
    net: object = None                #   whether its angle wraps (a full turn: no surface along axis 0)
    wraps: bool = False


def _placed_particles(cfg, bi, body, key, base_dir, rng, lo, hi, h) -> _Placed:
    """A body's particles inside its shape and outside earlier bodies: on the lattice of spacing h from the domain's
    corner, or (placement map) in the mapped grid's parameter cells, volumes and faces following the map."""
    d, origin = cfg.dim, np.asarray(cfg.domain.lower, float)
    net = wraps = None
    if body.placement == "map":
        from .bases import registry
        from .bases.mapped import build_map
        # the solver's net (cubic: degree 3): the same geometry, and the control points nodal loads go to
        net, wraps = build_map(cfg.domain.map, registry.get(cfg.solver.basis).degree)
        xi, pts, vol = _map_lattice(net, body.particles_per_cell)
    else:
        pts = _lattice(lo, hi, origin, h, 0.0, rng)
        xi, vol = None, np.full(len(pts), h**d)

    def take(sel):
        return tuple(None if a is None else a[sel] for a in (pts, vol, xi))

    pts, vol, xi = take(inside(body.shape, pts, base_dir, f"{key}.shape"))
    if len(pts) == 0:
        raise ConfigError("shape holds no particle at this resolution (make it larger or refine domain.dx / "
                          "particles_per_cell)", key=f"{key}.shape")
    pts, vol, xi = take(_overlap_free(cfg, bi, body, pts, base_dir))
    if len(pts) == 0:
        raise ConfigError("every particle of this body lies inside earlier bodies (overlap: skip left none)",
                          key=f"{key}.overlap")
    if xi is None:
        return _Placed(pts, vol, pts, h, origin)
    return _Placed(pts, vol, xi, 1.0 / body.particles_per_cell, np.zeros(d), xi, net, bool(wraps))


def _placed_faces(placed: _Placed) -> np.ndarray:
    """(N, d, 2) the particles' exposed faces on their lattice (a full-turn map, whose angle's first and last
    particles are neighbours, has no faces along it)."""
    exposed = _exposed_faces(placed.lattice, placed.origin, placed.h)
    if placed.wraps:
        exposed[:, 0, :] = False
    return exposed


def _body_particles(cfg, bi, body, mat_names, base_dir, rng) -> dict:
    """Particle arrays of one body."""
    d, dx = cfg.dim, cfg.domain.dx
    origin = np.asarray(cfg.domain.lower, float)
    dlo, dhi = origin, np.asarray(cfg.domain.upper, float)
    key = f"bodies.{bi}"
    h = dx / body.particles_per_cell
    lo, hi = shape_bounds(body.shape, d, base_dir, f"{key}.shape")
    if np.any(lo < dlo - 1e-9) or np.any(hi > dhi + 1e-9):
        raise ConfigError(f"body lies outside the domain (body bounds {lo.tolist()}..{hi.tolist()}, "
                          f"domain {dlo.tolist()}..{dhi.tolist()})", key=f"{key}.shape")
    placed = _placed_particles(cfg, bi, body, key, base_dir, rng, lo, hi, h)
    pts, vol, xi = placed.x, placed.volume, placed.xi
    in_space = xi is None   # (a placement map's lattice holds its parameters)
    iface = (_surface_flags(placed.lattice, placed.h, int(placed.wraps), (dlo, dhi) if in_space else None)
             if body.interface else np.zeros(len(pts), np.int32))
    exposed = _placed_faces(placed) if body.tractions else None   # on the lattice, before jitter
    areas = None   # placement map: every face's area vector, once for all of the body's tractions on particles
    if xi is not None and any(t.apply_to == "particles" for t in body.tractions):
        areas = _map_face_areas(placed.net, xi, exposed, body.particles_per_cell)
    if body.placement == "jittered":
        pts = pts + rng.uniform(-0.25 * h, 0.25 * h, pts.shape)
        pts = np.clip(pts, dlo + 1e-9, dhi - 1e-9)
    mat = cfg.materials[body.material]
    coords = {SPACE[a]: pts[:, a] for a in range(d)}
    v = np.zeros_like(pts)
    if body.velocity is not None:
        for a, comp in enumerate(body.velocity):
            v[:, a] += evaluate(comp, f"{key}.velocity.{a}", SPACE, **coords)
    if body.angular_velocity is not None:
        r = pts - shape_center(body.shape, d, base_dir, f"{key}.shape")
        w = body.angular_velocity
        v += np.stack([-w * r[:, 1], w * r[:, 0]], axis=1) if d == 2 else np.cross(np.asarray(w, float), r)
    dmg = np.zeros(len(pts))
    for j, region in enumerate(body.damage_regions):
        m = inside(region.shape, pts, base_dir, f"{key}.damage_regions.{j}.shape")
        if not m.any():   # as a grip's region: a region that damages nothing is a mistake, not a no-op
            raise ConfigError("the damage region holds no particle of the body", key=f"{key}.damage_regions.{j}.shape")
        dmg[m] = np.maximum(dmg[m], region.value)
    grips = []
    for j, g in enumerate(body.prescribed_velocity):
        gkey = f"{key}.prescribed_velocity.{j}"
        sel = np.arange(len(pts)) if g.region is None else np.flatnonzero(inside(g.region, pts, base_dir,
                                                                                  f"{gkey}.region"))
        if len(sel) == 0:
            raise ConfigError("the region holds no particle of the body", key=f"{gkey}.region")
        for a, comp in enumerate(g.velocity):  # the grip starts at its prescribed velocity
            if comp is not None:
                v[sel, a] = evaluate(comp, f"{gkey}.velocity.{a}", TIME, t=0.0)
        grips.append(Grip(sel, list(g.velocity), gkey))
    loads, node_loads = [], []
    for j, t in enumerate(body.tractions):
        tkey = f"{key}.tractions.{j}"
        mask = _loaded_faces(t, exposed, pts, tkey, base_dir)
        if t.apply_to == "nodes":   # (config: only with placement map)
            node_loads.append(_node_traction(t, mask, placed, tkey))
        else:
            loads.append(Load(*_traction_forces(t, mask, h, areas), t.ramp, tkey))
    return dict(x=pts, v=v, volume=vol, mass=vol * mat.density, body=np.full(len(pts), bi, np.int32),
                material=np.full(len(pts), mat_names.index(body.material), np.int32),
                damage=dmg, interface=iface, spacing=np.full(len(pts), h) if xi is None else vol ** (1.0 / d),
                stress=_initial_stress(body.stress, d, coords, f"{key}.stress"), loads=loads, grips=grips,
                node_loads=node_loads,
                geostatic=_geostatic(cfg, body, pts, key, base_dir))


def _geostatic(cfg, body, pts, key, base_dir):
    """bodies[].geostatic: (F, material state) of the body's particles consolidated under its own weight (K0):
    vertical effective stress rho |g| (surface - height), height along the last axis; None without the key."""
    spec = body.geostatic
    if spec is None:
        return None
    from .materials.cam_clay import geostatic_state

    mat = cfg.materials[body.material]
    surface = spec.surface if spec.surface is not None else float(shape_bounds(body.shape, cfg.dim, base_dir,
                                                                               f"{key}.shape")[1][-1])
    sigma_v = mat.density * abs(cfg.gravity[-1]) * (surface - pts[:, -1])
    if not (sigma_v > 0).all():
        raise ConfigError(f"particles of the body lie at or above the ground ({surface:g} m; the highest at "
                          f"{pts[:, -1].max():g} m): raise the surface", key=f"{key}.geostatic.surface")
    return geostatic_state(mat, cfg.dim, sigma_v, spec.k0, spec.ocr)


def _inside_map(cfg, bi, pts):
    """A mapped grid covers only its map's image, not the domain box: particles outside it cannot be located in
    parameter space (the solver would stop at upload). ConfigError naming the body."""
    m = cfg.domain.map
    if m is None or not len(pts):
        return
    if m.type != "nurbs":
        tol = 1e-9 * m.outer_radius
        rel = pts - np.asarray(m.center, float)
        r = np.linalg.norm(rel if m.type == "shell" else rel[:, :2], axis=1)
        angle = np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360.0
        out = (r < m.inner_radius - tol) | (r > m.outer_radius + tol)
        if m.angle < 360.0:
            out |= (angle > m.angle + 1e-9) & (angle < 360.0 - 1e-9)
        if m.type == "cylinder":
            out |= (rel[:, 2] < -tol) | (rel[:, 2] > m.length + tol)
        if m.type == "shell":
            lat = np.degrees(np.arcsin(np.clip(rel[:, 2] / np.maximum(r, 1e-300), -1.0, 1.0)))
            out |= (lat < m.latitudes[0] - 1e-9) | (lat > m.latitudes[1] + 1e-9)
    if m.type in ("cylinder", "shell"):
        what = (f"the {m.type} of domain.map (radii {m.inner_radius:g} to {m.outer_radius:g} about {m.center}"
                + (f", 0 to {m.angle:g} degrees" if m.angle < 360.0 else "")
                + (f", z from 0 to {m.length:g} above it)" if m.type == "cylinder" else
                   f", latitudes {m.latitudes[0]:g} to {m.latitudes[1]:g} degrees)"))
    elif m.type == "annulus":
        what = (f"the annulus of domain.map (radii {m.inner_radius:g} to {m.outer_radius:g} about "
                f"{m.center}" + (f", 0 to {m.angle:g} degrees)" if m.angle < 360.0 else ")"))
    else:
        from .bases import mapgeom

        given, P, w = mapgeom.config_net(m)
        _, cells = mapgeom.refined_shape(given, m.refine)
        knots = [mapgeom.scaled_knots(t, n) for t, n in zip(given, cells)]
        if len(knots) == 2:
            poly = mapgeom.boundary(knots, [2, 2], P, w)
            out = mapgeom.outside(poly, pts, 1e-6 * float(np.ptp(poly, axis=0).max()))
        else:     # within 1e-6 of the net's size of the map counts as inside, as for the 2D outline
            size = float(np.ptp(P.reshape(-1, 3), axis=0).max())
            out = ~mapgeom.locate_host(knots, [2, 2, 2], P, w, pts, 1e-6 * size, m.periodic)[1]
        what = "the nurbs map of domain.map (its image, not the domain box)"
    if out.any():
        first = pts[np.flatnonzero(out)[0]]
        raise ConfigError(f"{int(out.sum())} of the body's {len(pts)} particles lie outside the mapped grid: "
                          f"outside {what}, e.g. at {np.round(first, 6).tolist()}; a mapped grid covers its map "
                          "only: move the body inside", key=f"bodies.{bi}.shape")


def _initial_stress(spec, d, coords, key) -> Optional[np.ndarray]:
    """(N, d, d) Cauchy stress of bodies[].stress (Voigt list or matrix), or None."""
    if spec is None:
        return None
    n = len(next(iter(coords.values())))
    out = np.zeros((n, d, d))
    if isinstance(spec[0], list):
        pairs = [((i, j), spec[i][j], f"{key}.{i}.{j}") for i in range(d) for j in range(d)]
    else:
        index = {1: [(0, 0)], 2: [(0, 0), (1, 1), (0, 1)],
                 3: [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]}[d]
        pairs = [(ij, spec[k], f"{key}.{k}") for k, ij in enumerate(index)]
    for (i, j), comp, k in pairs:
        out[:, i, j] = out[:, j, i] = evaluate(comp, k, SPACE, **coords)
    return out


def base_dir_of(cfg: Config):
    """The folder relative mesh paths start from: the config file's."""
    return Path(cfg._source).parent if getattr(cfg, "_source", None) else None


def build_scene(cfg: Config, seed: int = 0) -> Scene:
    """Particles of all bodies, in body order. Callers check the size first (budget.check: the solver and
    `validate` do), so an absurd resolution is refused before any particle is generated; budget reads this
    module's shapes, so the check cannot live here."""
    base_dir = base_dir_of(cfg)
    rng = np.random.default_rng(seed)
    mat_names = list(dict.fromkeys(b.material for b in cfg.bodies))
    parts = [_body_particles(cfg, bi, body, mat_names, base_dir, rng) for bi, body in enumerate(cfg.bodies)]
    for bi, p in enumerate(parts):
        _inside_map(cfg, bi, p["x"])
    special = ("stress", "loads", "grips", "geostatic", "node_loads")
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k not in special}
    offsets = np.cumsum([0] + [len(p["x"]) for p in parts])
    stress = None
    if any(p["stress"] is not None for p in parts):
        d = cfg.dim
        stress = np.concatenate([p["stress"] if p["stress"] is not None else np.zeros((len(p["x"]), d, d))
                                 for p in parts])
    loads = [Load(l.particles + off, l.force, l.ramp, l.key) for p, off in zip(parts, offsets) for l in p["loads"]]
    grips = [Grip(g.particles + off, g.velocity, g.key) for p, off in zip(parts, offsets) for g in p["grips"]]
    geostatic = [(np.arange(len(p["x"])) + off, *p["geostatic"]) for p, off in zip(parts, offsets)
                 if p["geostatic"] is not None]
    node_loads = [n for p in parts for n in p["node_loads"]]
    return Scene(materials=mat_names, stress=stress, loads=loads, grips=grips, geostatic=geostatic,
                 node_loads=node_loads, **cat)
