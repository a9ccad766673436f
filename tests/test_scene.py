"""Scene building (issue 9): 2D meshes fill their area, 3D surfaces must be closed and are oriented, unreadable
mesh files are ConfigErrors, overlapping bodies are refused unless `overlap` says otherwise. No Taichi here."""
import warnings

import meshio
import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm.cli import demos
from taichi_mpm.scene import MeshWarning, build_scene, shape_volume

H = 0.025  # particle spacing: dx = 0.05, two particles per cell


def cfg_with(shapes, dim=2, body_keys=None):
    """Bodies b0, b1, ... of the given shapes; body_keys: {index: extra keys of that body}."""
    body_keys = body_keys or {}
    bodies = [dict(name=f"b{i}", shape=s, material="m", particles_per_cell=2, **body_keys.get(i, {}))
              for i, s in enumerate(shapes)]
    return tm.load_config(dict(name="t", dim=dim, arch="cpu", domain=dict(lower=[0] * dim, upper=[1] * dim, dx=0.05),
                               solver=dict(end_time=0.1), materials=dict(m=dict(model="neo_hookean", density=2.0, E=1e3)),
                               bodies=bodies))


def mesh_cfg(path, dim=2, **shape_keys):
    return cfg_with([dict(type="mesh", file=str(path), **shape_keys)], dim)


def flat(points):
    return np.c_[points, np.zeros(len(points))]


# ---------------------------------------------------------------- 2D meshes
# an L: the square [0.2, 0.8]^2 without its upper right quarter [0.5, 0.8]^2 (area 0.27)
L_POINTS = np.array([[0.2, 0.2], [0.5, 0.2], [0.8, 0.2], [0.2, 0.5], [0.5, 0.5], [0.8, 0.5], [0.2, 0.8], [0.5, 0.8]])
L_QUADS = np.array([(0, 1, 4, 3), (1, 2, 5, 4), (3, 4, 7, 6)])
L_LOOP = [0, 1, 2, 5, 4, 7, 6, 3]


def in_L(x):
    return np.all((x > 0.2) & (x < 0.8), axis=1) & ~np.all(x > 0.5, axis=1)


@pytest.fixture(scope="module")
def L_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("L")
    tris = np.array([t for a, b, c, e in L_QUADS for t in ((a, b, c), (a, c, e))])
    lines = np.array([(L_LOOP[i], L_LOOP[(i + 1) % 8]) for i in range(8)])
    files = {"triangles": d / "L.vtu", "quads": d / "Lq.vtk", "lines": d / "Lline.vtk"}
    meshio.write(files["triangles"], meshio.Mesh(flat(L_POINTS), [("triangle", tris)]))
    meshio.write(files["quads"], meshio.Mesh(flat(L_POINTS), [("quad", L_QUADS)]))
    meshio.write(files["lines"], meshio.Mesh(flat(L_POINTS), [("line", lines)]))
    return files


@pytest.mark.parametrize("kind", ["triangles", "quads", "lines"])
def test_2d_mesh_fills_its_area_not_its_bounding_box(L_files, kind):
    """The L's particles: none outside the L (the old bounding-box fill put 144 of its 576 in the missing quarter),
    and their volumes add up to its area. Its edges lie on lattice cell faces, so the fill is exact."""
    s = build_scene(mesh_cfg(L_files[kind]))
    assert in_L(s.x).all()
    assert s.volume.sum() == pytest.approx(0.27, rel=1e-9)
    assert shape_volume(mesh_cfg(L_files[kind]).bodies[0].shape, 2) == pytest.approx(0.27, rel=1e-12)


def test_2d_triangle_mesh_area_within_a_few_percent(tmp_path):
    """A triangle whose edges cut the lattice: particle volume within 3 % of its area (the boundary layer of
    half-filled cells holds ~ perimeter * h / 2 = 4 % of the area at this resolution, on average half of that
    in error), and every particle inside it (barycentric test)."""
    tri = np.array([[0.13, 0.11], [0.87, 0.23], [0.41, 0.83]])
    path = tmp_path / "tri.vtu"
    meshio.write(path, meshio.Mesh(flat(tri), [("triangle", np.array([[0, 1, 2]]))]))
    (ax, ay), (bx, by) = tri[1] - tri[0], tri[2] - tri[0]
    area = 0.5 * abs(ax * by - ay * bx)
    s = build_scene(mesh_cfg(path))
    assert s.volume.sum() == pytest.approx(area, rel=0.03)
    T = np.column_stack([tri[1] - tri[0], tri[2] - tri[0]])
    uv = np.linalg.solve(T, (s.x - tri[0]).T).T
    assert np.all(uv >= 0) and np.all(uv.sum(1) <= 1)
    assert shape_volume(mesh_cfg(path).bodies[0].shape, 2) == pytest.approx(area, rel=1e-12)


def test_2d_mesh_with_a_hole(tmp_path):
    """A square frame of quads (outer [0.2, 0.8]^2, hole [0.4, 0.6]^2): the even-odd rule leaves the hole empty."""
    g = np.array([0.2, 0.4, 0.6, 0.8])
    pts = np.array([[x, y] for y in g for x in g])
    quads = np.array([(j * 4 + i, j * 4 + i + 1, (j + 1) * 4 + i + 1, (j + 1) * 4 + i)
                      for j in range(3) for i in range(3) if (i, j) != (1, 1)])
    path = tmp_path / "frame.vtk"
    meshio.write(path, meshio.Mesh(flat(pts), [("quad", quads)]))
    s = build_scene(mesh_cfg(path))
    assert not np.any(np.all((s.x > 0.4) & (s.x < 0.6), axis=1))
    assert s.volume.sum() == pytest.approx(0.36 - 0.04, rel=1e-9)


def test_2d_mesh_scale_and_translate(L_files):
    s = build_scene(mesh_cfg(L_files["quads"], scale=[0.5, 1.0], translate=[0.1, 0.0]))
    assert s.volume.sum() == pytest.approx(0.135, rel=1e-9)
    assert s.x[:, 0].min() > 0.2 and s.x[:, 0].max() < 0.5


def test_open_2d_line_loop_is_an_error(tmp_path):
    lines = np.array([(L_LOOP[i], L_LOOP[i + 1]) for i in range(7)])  # the closing segment is missing
    path = tmp_path / "open.vtk"
    meshio.write(path, meshio.Mesh(flat(L_POINTS), [("line", lines)]))
    with pytest.raises(tm.ConfigError, match="2 open ends") as e:
        build_scene(mesh_cfg(path))
    assert e.value.key == "bodies.0.shape.file"


# ---------------------------------------------------------------- 3D surfaces
R, C = 0.3, (0.5, 0.5, 0.5)


@pytest.fixture(scope="module")
def spheres(tmp_path_factory):
    import pyvista as pv

    d = tmp_path_factory.mktemp("spheres")
    s = pv.Sphere(radius=R, center=C, theta_resolution=24, phi_resolution=24).triangulate()
    tri = s.faces.reshape(-1, 4)[:, 1:]
    mixed = tri.copy()
    mixed[::3] = mixed[::3, ::-1]
    inner = pv.Sphere(radius=0.15, center=C, theta_resolution=16, phi_resolution=16).triangulate()
    both = np.vstack([s.points, inner.points])
    inner_tri = inner.faces.reshape(-1, 4)[:, 1:] + len(s.points)
    files = dict(closed=(tri, s.points), inverted=(tri[:, ::-1], s.points), mixed=(mixed, s.points),
                 open=(tri[5:], s.points), hollow=(np.vstack([tri, inner_tri[:, ::-1]]), both),
                 hollow_outward=(np.vstack([tri, inner_tri]), both))
    out = {}
    for name, (t, p) in files.items():
        out[name] = d / f"{name}.vtk"
        meshio.write(out[name], meshio.Mesh(p, [("triangle", t)]))
    out["stl"] = d / "closed.stl"
    meshio.write(out["stl"], meshio.Mesh(s.points, [("triangle", tri)]))
    return out


def test_closed_surface_fills_its_volume(spheres):
    s = build_scene(mesh_cfg(spheres["stl"], dim=3))
    r = np.linalg.norm(s.x - C, axis=1)
    assert r.max() < R
    # the faceted sphere (24 x 24) holds 1.3 % less than the sphere; the lattice adds ~1 % noise at this size
    assert s.volume.sum() == pytest.approx(4 / 3 * np.pi * R**3, rel=0.03)


@pytest.mark.parametrize("name, what", [("inverted", "inverted"), ("mixed", "inconsistently oriented"),
                                        ("hollow_outward", "inverted in 1 of its 2")])
def test_badly_oriented_surface_is_corrected_with_a_warning(spheres, name, what):
    """vtkSelectEnclosedPoints selects the complement of an inverted surface; the loader flips faces so that
    the same particles result as from the well-oriented file (a cavity's shell must face inward)."""
    good = build_scene(mesh_cfg(spheres["hollow" if name.startswith("hollow") else "closed"], dim=3))
    with pytest.warns(MeshWarning, match=what):
        s = build_scene(mesh_cfg(spheres[name], dim=3))
    np.testing.assert_array_equal(s.x, good.x)


def test_well_oriented_surfaces_load_without_warning(spheres):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = build_scene(mesh_cfg(spheres["hollow"], dim=3))
    r = np.linalg.norm(s.x - C, axis=1)
    assert r.min() > 0.14 and r.max() < R  # the cavity stays empty (its faceted shell reaches in to ~0.147)


def test_open_surface_is_an_error_naming_key_and_boundary_edges(spheres):
    with pytest.raises(tm.ConfigError, match=r"not closed: \d+ boundary edges") as e:
        build_scene(mesh_cfg(spheres["open"], dim=3))
    assert e.value.key == "bodies.0.shape.file"


# ---------------------------------------------------------------- unreadable files
@pytest.mark.parametrize("name, content", [("bad.stl", b"solid x\n facet garbage\n"),
                                           ("bad.vtk", b"\x00\x01garbage" * 10),  # meshio calls sys.exit here
                                           ("bad.msh", b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\nfoo\n"),
                                           ("bad.xyz", b"1 2 3\n")])
def test_corrupt_mesh_file_is_a_config_error_naming_the_file(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(tm.ConfigError) as e:
        build_scene(mesh_cfg(path, dim=3))
    assert e.value.key == "bodies.0.shape.file" and str(path) in str(e.value)


def test_reader_that_exits_is_caught(tmp_path, monkeypatch):
    path = tmp_path / "x.vtk"
    path.write_text("anything")

    def exits(*a, **k):
        print("reader says no")
        raise SystemExit(1)

    monkeypatch.setattr(meshio, "read", exits)
    with pytest.raises(tm.ConfigError, match="reader says no"):
        build_scene(mesh_cfg(path, dim=3))


def test_mesh_error_in_a_damage_region_names_its_key(tmp_path):
    cfg = cfg_with([dict(type="box", lower=[0.2, 0.2], upper=[0.6, 0.6])])
    data = cfg.to_dict()
    data["bodies"][0]["damage_regions"] = [dict(shape=dict(type="mesh", file=str(tmp_path / "none.vtk")))]
    with pytest.raises(tm.ConfigError) as e:
        build_scene(tm.load_config(data))
    assert e.value.key == "bodies.0.damage_regions.0.shape.file"


# ---------------------------------------------------------------- overlapping bodies
BOX0 = dict(type="box", lower=[0.2, 0.2], upper=[0.5, 0.5])
BOX1 = dict(type="box", lower=[0.4, 0.3], upper=[0.7, 0.6])   # overlaps BOX0 in [0.4, 0.5] x [0.3, 0.5]


def test_overlapping_bodies_are_an_error_naming_both():
    with pytest.raises(tm.ConfigError) as e:
        build_scene(cfg_with([BOX0, BOX1]))
    assert e.value.key == "bodies.1.shape"
    assert "bodies.1 ('b1') overlaps bodies.0 ('b0')" in str(e.value) and "overlap: skip" in str(e.value)
    assert "32 of its 144 particles" in str(e.value)  # the 0.1 x 0.2 overlap holds 4 x 8 particles


def test_overlap_skip_leaves_out_the_shared_particles_and_allow_keeps_them():
    base = build_scene(cfg_with([BOX0]))
    skip = build_scene(cfg_with([BOX0, BOX1], body_keys={1: dict(overlap="skip")}))
    b1 = skip.x[skip.body == 1]
    assert not np.any(np.all((b1 > 0.2) & (b1 < 0.5), axis=1))
    assert skip.volume.sum() == pytest.approx(0.09 + 0.09 - 0.02, rel=1e-9)   # the union, counted once
    allow = build_scene(cfg_with([BOX0, BOX1], body_keys={1: dict(overlap="allow")}))
    assert allow.mass.sum() == pytest.approx(2.0 * 0.18, rel=1e-9)             # both kept: the mixture's mass
    assert base.n + 144 == allow.n


def test_overlap_with_a_later_body_is_checked_against_every_earlier_one():
    disk = dict(type="sphere", center=[0.6, 0.45], radius=0.06)  # inside BOX1 only
    with pytest.raises(tm.ConfigError, match="bodies.2 .'b2'. overlaps bodies.1"):
        build_scene(cfg_with([BOX0, BOX1, disk], body_keys={1: dict(overlap="skip")}))


def test_touching_bodies_do_not_overlap():
    """Sharing a face (x = 0.5) or touching at a point: no particle lies inside the other body's shape."""
    s = build_scene(cfg_with([BOX0, dict(type="box", lower=[0.5, 0.2], upper=[0.8, 0.5]),
                              dict(type="sphere", center=[0.35, 0.65], radius=0.15)]))
    assert s.volume.sum() == pytest.approx(0.18 + np.pi * 0.15**2, rel=0.02)


@pytest.mark.parametrize("name", sorted(demos()))
def test_bundled_configs_build(name):
    """Every bundled scene passes the overlap rule (touching bodies, damage regions) and the size check."""
    cfg = tm.load_config(demos()[name])
    s = build_scene(cfg)
    assert s.n > 0 and set(np.unique(s.body)) == set(range(len(cfg.bodies)))


def test_cylinder_bounds_are_exact_so_a_column_can_stand_on_the_floor():
    """A cylinder's bounding box is its own (the cap circles), not the sphere around it: a column standing on the
    floor (y from 0) fits a domain that starts at 0, and a tilted one reaches |u_i| h / 2 + r sqrt(1 - u_i^2)."""
    from taichi_mpm.config import validate
    from taichi_mpm.scene import build_scene, shape_bounds

    cfg = validate(dict(name="c", dim=3, domain=dict(lower=[0, 0, 0], upper=[0.4, 0.2, 0.4], dx=0.02),
                        solver=dict(end_time=0.1), materials=dict(m=dict(model="neo_hookean", E=1e4, density=1000)),
                        bodies=[dict(shape=dict(type="cylinder", center=[0.2, 0.05, 0.2], radius=0.1, height=0.1),
                                     material="m")]))
    lo, hi = shape_bounds(cfg.bodies[0].shape, 3)
    np.testing.assert_allclose(lo, [0.1, 0.0, 0.1], atol=1e-12)
    np.testing.assert_allclose(hi, [0.3, 0.1, 0.3], atol=1e-12)
    x = build_scene(cfg).x
    assert x[:, 1].min() > 0 and x[:, 1].max() < 0.1
    tilted = cfg.bodies[0].shape.model_copy(update=dict(rotation=[0, 0, 90]))   # axis y turned onto -x
    lo, hi = shape_bounds(tilted, 3)
    np.testing.assert_allclose(hi - lo, [0.1, 0.2, 0.2], atol=1e-12)
