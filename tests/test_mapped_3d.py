"""3D mapped grids (`domain.map` of type cylinder or shell, issue 32): the NURBS volumes are exact cylinders and
spheres, their faces' normals radial, their cell sizes the chords of their corners; the rational basis keeps the
isoparametric identities through the kernel functions; in the solver a spinning tube conserves linear and angular
momentum, a fluid ring spinning against slip spheres keeps its angular momentum, and a pressurised thick cylinder
matches Lame's radial stress. f64 throughout."""
import math

import numpy as np
import pytest
import taichi as ti

import taichi_mpm as tm
from taichi_mpm.bases import mapgeom
from taichi_mpm.bases.mapped import build_map
from taichi_mpm.budget import map_size
from taichi_mpm.bases.nurbs import shell
from taichi_mpm.config import load_config
from taichi_mpm.errors import ConfigError
from taichi_mpm.scene import build_scene
from conftest import spin_free

A, B = 0.5, 1.0     # inner and outer radius of every map here


def corners(knots, P, w):
    """x at every combination of distinct knots (the cell corners), host evaluation."""
    u = [np.unique(t) for t in knots]
    xi = np.stack(np.meshgrid(*u, indexing="ij"), -1)
    return mapgeom.surface(knots, [2, 2, 2], P, w, xi.reshape(-1, 3))[0].reshape(xi.shape)


def test_cylinder_and_shell_nets_are_exact_and_their_walls_radial():
    """Every parameter surface xi1 = const of the cylinder is the circular cylinder r = A + (B - A) xi1 / n and z
    is linear along xi2; the shell's is the sphere of that radius (1e-14 at 2000 random points: the weights make
    the circles exact). J against central differences (h = 1e-6: 1e-8). The wall normals at the inner and outer
    control points are -/+ the radial direction through the control point itself (1e-14: so a slip wall exerts
    no torque about the axis or the centre). The cell-size rule (products of 1D chords) equals the brute-force
    smallest and largest corner-to-corner edge (1e-12)."""
    rng = np.random.default_rng(3)
    cells = [12, 4, 6]
    for kind in ("cylinder", "shell"):
        if kind == "cylinder":
            knots, P, w = mapgeom.cylinder_net(A, B, 1.5 * math.pi, 0.3, cells, [0.1, -0.2, 0.05])
            centre = np.array([0.1, -0.2, 0.05])
        else:
            knots, P, w = mapgeom.shell_net(A, B, 1.5 * math.pi, np.radians([-50.0, 70.0]), cells, [0.0, 0.0, 0.0])
            centre = np.zeros(3)
        xi = rng.random((2000, 3)) * cells
        x, J = mapgeom.surface(knots, [2, 2, 2], P, w, xi)
        rel = x - centre
        r = np.linalg.norm(rel[:, :2] if kind == "cylinder" else rel, axis=1)
        assert np.abs(r - (A + (B - A) * xi[:, 1] / cells[1])).max() < 1e-14
        if kind == "cylinder":
            assert np.abs(rel[:, 2] - 0.3 * xi[:, 2] / cells[2]).max() < 1e-14
        for a in range(3):
            e = np.zeros(3)
            e[a] = 1e-6
            up, down = (mapgeom.surface(knots, [2, 2, 2], P, w, q)[0] for q in (xi + e, xi - e))
            assert np.abs((up - down) / 2e-6 - J[:, :, a]).max() < 1e-8
        n = mapgeom.face_normals(knots, [2, 2, 2], P, w)
        for j, k, sign in ((0, 2, -1.0), (-1, 3, 1.0)):
            q = P[:, j] - centre
            if kind == "cylinder":
                q[..., 2] = 0.0
            assert np.abs(n[:, j, :, k] - sign * q / np.linalg.norm(q, axis=-1, keepdims=True)).max() < 1e-14
        c = corners(knots, P, w)
        edges = np.concatenate([np.linalg.norm(np.diff(c, axis=a), axis=-1).ravel() for a in range(3)])
        lat = None if kind == "cylinder" else np.radians([-50.0, 70.0])
        lo, hi = mapgeom.solid_cell_sizes(kind, A, B, 1.5 * math.pi, cells, length=0.3, latitudes=lat)
        assert abs(lo - edges.min()) < 1e-12 and abs(hi - edges.max()) < 1e-12
        ctrl, _ = mapgeom.solid_shape(kind, 270.0, cells, 120.0)
        assert list(w.shape) == ctrl


def test_rational_basis_keeps_the_isoparametric_identities_in_3d():
    """Through the kernel functions the solver uses (nurbs.Map.rational / jacobian / invert), on a shell sector:
    sum R_k = 1, sum R_k P_k = x(xi) of the host evaluation, sum P_k (x) grad_x R_k = I (so APIC's affine fields
    and grad v = L are exact on the curved grid), and Newton finds xi again from the nearest sample (1e-12)."""
    ti.init(arch=ti.cpu, default_fp=ti.f64, log_level=ti.ERROR, offline_cache=True)
    mp = shell(A, B, 0.5 * math.pi, np.radians([-30.0, 40.0]), [4, 2, 4], (0.2, 0.0, -0.1))
    mp.materialize()
    rng = np.random.default_rng(7)
    xi = rng.random((300, 3)) * [4, 2, 4]
    K = len(mp.terms)
    out = np.zeros((300, 4))      # sum R - 1, |sum R P - x|, |sum P (x) grad R - I|, |xi found - xi|
    x_host = mp.evaluate(xi)
    start = xi + rng.uniform(-0.3, 0.3, xi.shape)

    @ti.kernel
    def run(xi: ti.types.ndarray(), x: ti.types.ndarray(), start: ti.types.ndarray(), out: ti.types.ndarray()):
        for m in range(xi.shape[0]):
            q = ti.Vector([xi[m, 0], xi[m, 1], xi[m, 2]])
            b, R, G = mp.rational(q)
            JiT = mp.jacobian(b, G).inverse().transpose()
            s = 0.0
            y = ti.Vector.zero(float, 3)
            I = ti.Matrix.zero(float, 3, 3)
            for k in range(K):
                Pk = mp.ctrl[b + mp.term(k)]
                s += R[k]
                y += R[k] * Pk
                I += Pk.outer_product(JiT @ ti.Vector([G[k, 0], G[k, 1], G[k, 2]]))
            out[m, 0] = ti.abs(s - 1.0)
            out[m, 1] = (y - ti.Vector([x[m, 0], x[m, 1], x[m, 2]])).norm()
            out[m, 2] = ti.abs(I - ti.Matrix.identity(float, 3)).max()
            found, ok = mp.invert(y, ti.Vector([start[m, 0], start[m, 1], start[m, 2]]), 1e-13)
            out[m, 3] = (found - q).norm() if ok else 1.0

    run(xi, x_host, np.clip(start, 0.0, [4, 2, 4]), out)
    assert out[:, 0].max() < 1e-14
    assert out[:, 1].max() < 1e-14
    assert out[:, 2].max() < 1e-12
    assert out[:, 3].max() < 1e-12


def tube_cfg(basis="quadratic"):
    """A tube (r in [0.67, 0.83], out of every wall node's reach) in the full thick-cylinder map."""
    return dict(
        name="tube", dim=3, precision="f64", arch="cpu",
        domain=dict(lower=[-1.125, -1.125, -0.125], upper=[1.125, 1.125, 0.25], dx=0.0625,
                    boundaries=dict(default="free"),
                    map=dict(type="cylinder", inner_radius=A, outer_radius=B, length=0.125, angle=360,
                             cells=[32, 4, 2])),
        solver=dict(basis=basis, transfer="apic", end_time=0.1),
        materials=dict(m=dict(model="neo_hookean", density=1000.0, E=1e4, nu=0.3)),
        bodies=[dict(name="tube", shape=dict(type="cylinder", axis="z", center=[0, 0, 0.0625], radius=0.83,
                                             inner_radius=0.67, height=0.125), material="m")])


def half_cylinder(second: bool, length=0.125):
    """The coarse net of half the thick cylinder (two rational quarter pieces x one cell x one cell): angles 0..180
    degrees, or (second) 180..360, as (knots, P, w)."""
    t, P, w = mapgeom.cylinder_net(A, B, math.pi, length, [2, 1, 1], [0.0, 0.0, 0.0])
    if second:
        P = P * [-1.0, -1.0, 1.0]          # turned by 180 degrees about z
    return t, P, w


def as_patch(t, P, w):
    return dict(knots=dict(zip("xyz", (list(map(float, k)) for k in t))), control_points=P.tolist(),
                weights=w.tolist())


def test_nurbs_volume_and_two_joined_patches_are_the_built_in_cylinder():
    """The full thick cylinder written as data two ways, each refined to the built-in's 32 x 4 x 2 cells: one
    `nurbs` volume (its 4 rational quarter pieces x 1 x 1 cells), and two half-cylinder `patches` joined at their
    shared faces (each one's last layer of control points the other's first; periodic). Both build the built-in
    map: knots (in cells), control points, weights and wall normals to 1e-14, the same size estimate (nodes and
    smallest cell) and the same particles. So the Lame run below holds for the joined patches as for the
    built-in map. The same join in 2D (two half annuli) gives the annulus."""
    from taichi_mpm.bases.mapped import build_map

    built = load_config(tube_cfg())
    t, P, w = mapgeom.cylinder_net(A, B, 2 * math.pi, 0.125, [4, 1, 1], [0.0, 0.0, 0.0])
    single = tube_cfg()
    single["domain"]["map"] = dict(type="nurbs", periodic=True, refine=[8, 4, 2], **as_patch(t, P, w))
    joined = tube_cfg()
    joined["domain"]["map"] = dict(type="nurbs", periodic=True, refine=[8, 4, 2],
                                   patches=[as_patch(*half_cylinder(False)), as_patch(*half_cylinder(True))])
    ref, _ = build_map(built.domain.map)
    n_ref = mapgeom.face_normals(ref.knots, ref.degrees, ref.P, ref.w, True)
    for cfg in (load_config(single), load_config(joined)):
        mp, periodic = build_map(cfg.domain.map)
        assert periodic and all(np.abs(a - b).max() < 1e-13 for a, b in zip(mp.knots, ref.knots))
        assert np.abs(mp.P - ref.P).max() < 1e-14 and np.abs(mp.w - ref.w).max() < 1e-14
        assert np.abs(mapgeom.face_normals(mp.knots, mp.degrees, mp.P, mp.w, True) - n_ref).max() < 1e-14
        size, size_ref = map_size(cfg), map_size(built)
        assert size.shape == size_ref.shape and abs(size.h_min - size_ref.h_min) < 1e-14
        assert len(build_scene(cfg).x) == len(build_scene(built).x)
    from taichi_mpm.bases.nurbs import annulus
    halves = []
    for second in (False, True):
        a = annulus(A, B, math.pi, 2, 1)
        halves.append((a.knots, -a.P if second else a.P, a.w))
    knots, P, w = mapgeom.join_patches(halves)
    whole = annulus(A, B, 2 * math.pi, 4, 1)
    assert np.abs(knots[0] - whole.knots[0]).max() < 1e-14 and np.abs(P - whole.P).max() < 1e-15


def test_3d_map_config_errors():
    """Each is a ConfigError naming the key: a 3D map in a 2D scene (and a 2D one in 3D), cells along an arc
    that its rational pieces do not divide, latitudes the wrong way round, a box that does not hold the map, a
    tube's inner radius beyond its outer one; and a body reaching outside the map's image is refused by the
    scene naming the body."""
    def refused(mutate, key):
        cfg = tube_cfg()
        mutate(cfg)
        with pytest.raises(ConfigError) as err:
            build_scene(load_config(cfg))
        assert err.value.key == key, err.value

    def two_d(c):
        c.update(dim=2)
        c["domain"].update(lower=[-1.125, -1.125], upper=[1.125, 1.125])
        c["bodies"][0]["shape"] = dict(type="ring", center=[0, 0], inner_radius=0.6, outer_radius=0.9)
    refused(two_d, "domain.map.type")

    def annulus_in_3d(c):
        c["domain"]["map"] = dict(type="annulus", inner_radius=A, outer_radius=B, cells=[8, 2])
    refused(annulus_in_3d, "domain.map.type")

    refused(lambda c: c["domain"]["map"].update(angle=270, cells=[10, 4, 2]), "domain.map.cells")

    def shell(c, **kw):
        c["domain"].update(lower=[-1.125] * 3, upper=[1.125] * 3)
        c["domain"]["map"] = dict(type="shell", inner_radius=A, outer_radius=B, cells=[16, 4, 8], **kw)
    refused(lambda c: shell(c, latitudes=[30, -30]), "domain.map.latitudes")
    refused(lambda c: c["domain"].update(upper=[1.125, 1.125, 0.0625]), "domain.upper")
    refused(lambda c: c["bodies"][0]["shape"].update(inner_radius=0.9), "bodies.0.shape.inner_radius")
    refused(lambda c: c["bodies"][0]["shape"].update(height=0.25), "bodies.0.shape")     # pokes out of the ends
    shell_cfg = tube_cfg()
    shell(shell_cfg, latitudes=[-45, 45])
    assert len(build_scene(load_config(shell_cfg)).x) > 0     # the tube lies inside the shell

    def patches(c, first=None, second=None, **kw):
        one, two = as_patch(*half_cylinder(False)), as_patch(*half_cylinder(True))
        for patch, change in ((one, first), (two, second)):
            if change:
                change(patch)
        c["domain"]["map"] = dict(type="nurbs", periodic=True, refine=[8, 4, 2], patches=[one, two], **kw)

    def stretch_y(p):
        p["knots"]["y"] = [0, 0, 0, 1, 2, 2, 2]               # two spans across the wall: does not conform
        p["control_points"] = [[row[0], row[0], row[1], row[1]] for row in p["control_points"]]
        p["weights"] = [[row[0], row[0], row[1], row[1]] for row in p["weights"]]
    refused(lambda c: patches(c, second=stretch_y), "domain.map.patches.1.knots.y")

    def shift(p):
        p["control_points"] = (np.asarray(p["control_points"]) + [0.0, 0.01, 0.0]).tolist()
    refused(lambda c: patches(c, second=shift), "domain.map.patches.1.control_points")
    refused(lambda c: patches(c, knots=dict(x=[0, 0, 0, 1, 1, 1], y=[0, 0, 0, 1, 1, 1])), "domain.map")

    def no_z(p):
        p["knots"].pop("z")
    refused(lambda c: patches(c, first=no_z), "domain.map.patches.0.knots.z")

    def fold(p):
        P = p["control_points"]
        P[1][0][0], P[1][1][0] = P[1][1][0], P[1][0][0]     # inner and outer control point swapped
    refused(lambda c: patches(c, first=fold), "domain.map.control_points")

    def outside(c):
        patches(c)
        c["bodies"][0]["shape"].update(radius=1.05)          # the tube reaches beyond the outer cylinder
    refused(outside, "bodies.0.shape")


@pytest.mark.slow
@pytest.mark.parametrize("basis", ["quadratic", "cubic"])
def test_spinning_tube_conserves_momentum_on_the_cylinder_map(basis):
    """A free neo-Hookean tube spinning at 1 rad/s, drifting and deformed by a sine field, 10 steps APIC: linear
    and angular momentum to 1e-12 of their scales (measured 6.3e-16 and 1.3e-16: P2G, the grid update and G2P
    conserve both on the rational basis since sum R_k P_k = x_p), F moved 0.07 from I. The seam of the full
    turn (periodic in xi0) is crossed by the stencils of the particles near angle 0. cubic: the map raised to
    degree 3, 64 control points per particle (measured 3.7e-16 and 1.6e-15)."""
    sim = tm.Simulation(tube_cfg(basis=basis))
    size = map_size(sim.cfg)          # the budget's estimate from the config alone equals what was built
    assert size.shape == sim.mapped.shape and size.h_min == sim.mapped.h_min
    assert size.field_floats() == sim.mapped.field_floats()
    linear, angular, strain = spin_free(sim)
    assert linear < 1e-12 and angular < 1e-12 and strain > 0.05


@pytest.mark.slow
def test_fluid_ring_spinning_against_slip_spheres_keeps_its_angular_momentum():
    """A weakly compressible fluid ring (a tube r in [0.6, 0.9], |z| < 0.125) spinning at 1 rad/s inside the
    spherical shell r in [0.5, 1], latitudes -45..45 degrees, every face a slip wall: centrifugal pressure pushes it
    onto the outer sphere, whose wall impulses point through the centre. Its angular momentum changes by at most
    1e-12 of itself per step over 40 steps (the issue's bar 1e-10; measured 4.3e-15), and the outer sphere's
    loaded control points end with no outward normal velocity (1e-12 m/s)."""
    cfg = tube_cfg()
    cfg["domain"].update(lower=[-1.125] * 3, upper=[1.125] * 3, boundaries=dict(default="slip"))
    cfg["domain"]["map"] = dict(type="shell", inner_radius=A, outer_radius=B, angle=360, latitudes=[-45, 45],
                                cells=[32, 4, 8])
    cfg["materials"]["m"] = dict(model="fluid", density=1000.0, K=1e4)
    cfg["bodies"][0].update(shape=dict(type="cylinder", axis="z", center=[0, 0, 0], radius=0.9, inner_radius=0.6,
                                       height=0.25), angular_velocity=[0, 0, 1.0])
    sim = tm.Simulation(cfg)
    L = [sim.momentum()["angular"][2]]
    for _ in range(40):
        sim.step()
        L.append(sim.momentum()["angular"][2])
    assert np.abs(np.diff(L)).max() < 1e-12 * abs(L[0])
    n0, n1, n2 = sim.mapped.shape
    normal = sim.mapped.normals[:, -1, :, 3]
    m = sim.grid.m.to_numpy()[:n0, n1 - 1, :n2]
    v = sim.grid.vec["v"].to_numpy()[:n0, n1 - 1, :n2]
    assert (m > 0).sum() > 50                                   # the ring loads the outer sphere's nodes
    assert (v * normal).sum(-1)[m > 0].max() < 1e-12


def lame_cfg(h, ramp, hold):
    """A thick cylinder r in [A, B] pressurised inside by P_IN, plane strain (slip walls at both ends), two cells
    long, on the full cylinder map with cells of the particle spacing h across the wall. The pressure is ramped as
    (1 - cos(pi t / ramp)) / 2 and then held."""
    n_r = round((B - A) / h)
    n_t = 4 * round(2 * math.pi * 0.75 / h / 4)
    length = 2 * h
    region = dict(type="sphere", center=[0, 0, length / 2], radius=A + h)   # the inner surface only
    return dict(
        name="lame", dim=3, precision="f64", arch="cpu",
        domain=dict(lower=[-1.125, -1.125, -h], upper=[1.125, 1.125, length + h], dx=h,
                    boundaries=dict(default="free", z_min="slip", z_max="slip"),
                    map=dict(type="cylinder", inner_radius=A, outer_radius=B, length=length, angle=360,
                             cells=[n_t, n_r, 2])),
        solver=dict(basis="quadratic", transfer="apic", end_time=ramp + hold),
        materials=dict(m=dict(model="neo_hookean", density=1000.0, E=1e6, nu=0.3)),
        bodies=[dict(name="tube", shape=dict(type="cylinder", axis="z", center=[0, 0, length / 2], radius=B,
                                             inner_radius=A, height=length), material="m",
                     tractions=[dict(pressure=P_IN, faces=["x_min", "x_max", "y_min", "y_max"], region=region,
                                     ramp=f"0.5 - 0.5 * cos(pi * min(t / {ramp}, 1))")])])


P_IN = 100.0     # Pa: p / E = 1e-4, small strain (Lame's linear solution applies)


def lame_errors(sim, ramp, hold, r_from, h):
    """Step the pressurised cylinder through ramp and hold; sigma_r of every particle averaged over the hold, the
    particles' final radii, and per radial bin of width h from r_from the mean error against Lame's over p."""
    total, samples = 0.0, 0
    while sim.time < ramp + hold - 1e-12:
        sim.step()
        if sim.time >= ramp:
            P = sim.particles()
            n = P["x"] * [1.0, 1.0, 0.0]
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            total = total + np.einsum("pi,pij,pj->p", n, P["stress"], n)
            samples += 1
    srr = total / samples
    r = np.hypot(*sim.particles()["x"][:, :2].T)
    exact = P_IN * A**2 / (B**2 - A**2) * (1 - B**2 / r**2)
    edges = np.arange(r_from, B + 1e-9, h)
    bins = [(r >= lo) & (r < hi) for lo, hi in zip(edges[:-1], edges[1:])]
    return srr, r, [(srr[m].mean() - exact[m].mean()) / P_IN for m in bins]


@pytest.mark.slow
@pytest.mark.parametrize("grid", ["cylinder", "two patches"])
def test_pressurised_thick_cylinder_matches_lame(grid):
    """Lame's thick cylinder on the NURBS-volume map (the issue's check): r in [0.5, 1], internal pressure p, plane
    strain, dx = wall thickness / 8 (8 cells across the wall, 2 particles per cell and axis, 9664 particles).
    The exact radial stress is sigma_r = p A^2 / (B^2 - A^2) (1 - B^2 / r^2). The pressure is ramped over 0.4 s
    (about 4 periods of the breathing mode) and sigma_r averaged over the next 0.22 s; a ramp and hold twice as
    long changed no bin by more than 1e-5 p, so what is left is the discretisation's. Per radial bin of 1/16 m
    beyond two particle spacings of the loaded surface (where the staircase of particle faces carries the
    pressure), the mean sigma_r is within 0.02 p of Lame's (measured: -0.2 %, -1.35 %, -0.68 %, -0.49 %, -0.49 %,
    +0.06 % of p from r = 0.625 to 1). `two patches`: the same cylinder given as two half-cylinder NURBS patches
    joined at their shared faces (domain.map.patches), refined to the same 76 x 8 x 2 cells: the same figures."""
    h, ramp, hold = 0.0625, 0.4, 0.22
    cfg = lame_cfg(h, ramp, hold)
    if grid == "two patches":
        cfg["domain"]["map"] = dict(type="nurbs", periodic=True, refine=[19, 8, 2],
                                    patches=[as_patch(*half_cylinder(k, length=2 * h)) for k in (False, True)])
    srr, r, errors = lame_errors(tm.Simulation(cfg), ramp, hold, A + 2 * h, h)
    assert np.abs(errors).max() < 0.02, errors
    assert srr[r < A + h].mean() < -0.5 * P_IN        # the inner surface does carry the pressure


def map_placed_lame_cfg(h=0.0625, ramp=0.4, hold=0.22):
    """lame_cfg with the particles placed in the map's parameter cells (bodies[].placement: map) and the pressure
    on the map's inner face (parameter face y_min), whose particle faces then lie on r = A."""
    cfg = lame_cfg(h, ramp, hold)
    body = cfg["bodies"][0]
    body["placement"] = "map"
    body["tractions"][0].update(faces=["y_min"], region=None)
    return cfg


def test_map_placement_fills_the_map_and_loads_its_face():
    """placement: map puts 2 particles per axis in every parameter cell of the cylinder map: their volumes
    |det J| dxi^3 add up to the tube's pi (B^2 - A^2) L (midpoint rule on det J: measured 3e-5 relative), the
    inner face's particles carry p times their face's area along the outward radius (the pressure pushes into the
    wall): in all p 2 pi A L (the map's circle is exact; the areas by the same midpoint rule), net zero. The
    lattice placement's staircase of faces gave the same total only on average over the x and y faces."""
    cfg = load_config(map_placed_lame_cfg())
    s = build_scene(cfg)
    L = cfg.domain.map.length
    assert s.n == 76 * 8 * 2 * 8
    assert s.volume.sum() == pytest.approx(math.pi * (B**2 - A**2) * L, rel=1e-4)
    load = s.loads[0]
    x, f = s.x[load.particles], load.force
    r = np.hypot(x[:, 0], x[:, 1])
    assert np.all(r < A + 0.0625 / 2)                                   # the first layer only
    radial = np.stack([x[:, 0] / r, x[:, 1] / r], axis=1)
    assert np.all(np.einsum("na,na->n", f[:, :2], radial) > 0.9999 * np.linalg.norm(f, axis=1))
    # the face areas by the midpoint rule on the rational arc's speed, as the volumes: measured 3e-5 relative
    assert np.linalg.norm(f, axis=1).sum() == pytest.approx(P_IN * 2 * math.pi * A * L, rel=1e-4)
    assert np.abs(f.sum(0)).max() < 1e-9 * P_IN


@pytest.mark.parametrize("basis, degree", [("quadratic", 2), ("cubic", 3)])
def test_node_loads_are_the_faces_consistent_load(basis, degree):
    """apply_to: nodes puts the inner face's pressure on the grid as int R_i (-p n) dA: only the control points of
    the inner face (parameter index y = 0) of the solver's net (cubic: degree 3) take it, no particle does; the
    forces add to zero (a closed ring), and since sum R_i P_i = x on the face, sum f_i (x) P_i = p int e_r (x) x dA
    = p pi A^2 L in x and y, zero elsewhere (2 Gauss points per face axis on the rational arc: measured 5.8e-10
    relative with the quadratic net)."""
    cfg = map_placed_lame_cfg()
    cfg["bodies"][0]["tractions"][0]["apply_to"] = "nodes"
    cfg["solver"]["basis"] = basis
    c = load_config(cfg)
    s = build_scene(c)
    assert s.loads == [] and len(s.node_loads) == 1
    load = s.node_loads[0]
    assert set(load.nodes[:, 1]) == {0}
    L = c.domain.map.length
    net, _ = build_map(c.domain.map, degree)
    assert load.nodes[:, 0].max() == net.w.shape[0] - 2     # every control point around the ring but the seam's
    assert np.abs(load.force.sum(0)).max() < 1e-12 * P_IN * A * L
    M = np.einsum("ka,kb->ab", load.force, net.P[tuple(load.nodes.T)])
    expected = np.diag([1.0, 1.0, 0.0]) * P_IN * math.pi * A**2 * L
    assert np.abs(M - expected).max() < 1e-8 * P_IN * math.pi * A**2 * L, M


def test_node_loads_need_map_faces_and_one_velocity_field():
    """apply_to: nodes needs the loaded faces to be the grid's (placement: map) and the single velocity field that
    a crack or contact section splits: config errors naming the key."""
    cfg = lame_cfg(0.0625, 0.4, 0.22)
    cfg["bodies"][0]["tractions"][0]["apply_to"] = "nodes"
    with pytest.raises(ConfigError, match="placement: map") as e:
        load_config(cfg)
    assert e.value.key == "bodies.0.tractions.0.apply_to"
    cfg = map_placed_lame_cfg()
    cfg["bodies"][0]["tractions"][0]["apply_to"] = "nodes"
    cfg["crack"] = {}
    with pytest.raises(ConfigError, match="single velocity field") as e:
        load_config(cfg)
    assert e.value.key == "bodies.0.tractions.0.apply_to"


def test_map_placement_needs_a_map():
    """Without domain.map there are no parameter cells to fill: a config error naming the key."""
    cfg = lame_cfg(0.0625, 0.4, 0.22)
    cfg["bodies"][0]["placement"] = "map"
    del cfg["domain"]["map"]
    with pytest.raises(ConfigError, match="no map") as e:
        load_config(cfg)
    assert e.value.key == "bodies.0.placement"


@pytest.mark.slow
@pytest.mark.parametrize("apply_to, grid", [("particles", "cylinder"), ("nodes", "cylinder"), ("nodes", "two patches")])
def test_map_placed_thick_cylinder_against_lame(apply_to, grid):
    """Lame's cylinder (as above) with the particles in the map's parameter cells and the pressure on the map's
    inner face: the particles' faces lie on r = A and take p along the exact normal. Per bin of 1/16 m from r = A,
    error / p measured:
    - particles: +0.296, -0.060, +0.0217, -0.0019, +0.0026, +0.0011, -0.0001, +0.0019 (the lattice placement:
      +0.235, -0.079, -0.002, -0.013, -0.007, -0.005, -0.005, +0.001). Beyond three particle spacings 5x smaller than
      the lattice's; the two bins at the loaded face stay off by a third and a twentieth of p (the particle forces
      reach the nodes through the first particles' weights, spread over three layers of nodes). Asserted: beyond
      two spacings within 0.025 p, beyond three within 0.005 p.
    - nodes (apply_to: nodes, the face's consistent nodal load on the inner control points): -0.0131, +0.0058,
      -0.0024, +0.0003, -0.0004, 0.0000, -0.0007, +0.0017, the same on two joined patches: every bin within the
      issue's 2 % of p, the loaded face's included (asserted)."""
    ramp, hold = 0.4, 0.22
    cfg = map_placed_lame_cfg(ramp=ramp, hold=hold)
    cfg["bodies"][0]["tractions"][0]["apply_to"] = apply_to
    if grid == "two patches":
        cfg["domain"]["map"] = dict(type="nurbs", periodic=True, refine=[19, 8, 2],
                                    patches=[as_patch(*half_cylinder(k, length=0.125)) for k in (False, True)])
    sim = tm.Simulation(cfg)
    _, _, errors = lame_errors(sim, ramp, hold, A, 0.0625)
    errors = np.array(errors)
    print(apply_to, grid, "error / p per bin", np.round(errors, 4))
    if apply_to == "nodes":
        assert np.abs(errors).max() < 0.02, errors
    else:
        assert np.abs(errors[2:]).max() < 0.025 and np.abs(errors[3:]).max() < 0.005, errors
    assert abs(sim.energy_balance()["ratio"]) < 0.01     # the loads' work counted (measured 1.1e-3 with nodes)
