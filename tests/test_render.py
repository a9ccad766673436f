"""Off-screen rendering: non-blank PNGs of the requested size in 1D, 2D and 3D, movies, re-rendering a run."""
import numpy as np
import pytest

imageio = pytest.importorskip("imageio.v2")
meshio = pytest.importorskip("meshio")

from taichi_mpm.io.render import FrameRenderer, field_values, make_movie, render_run, von_mises  # noqa: E402


def particle_dict(dim, n_side=12, seed=0):
    """A block of particles with a velocity gradient, a stretched F and two bodies."""
    rng = np.random.default_rng(seed)
    h = 0.4 / n_side
    axes = [0.3 + (np.arange(n_side) + 0.5) * h] * dim
    x = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, dim)
    n = len(x)
    v = np.zeros((n, dim))
    v[:, 0] = 2.0 * (x[:, 0] - 0.5)
    F = np.broadcast_to(np.eye(dim), (n, dim, dim)).copy()
    F[:, 0, 0] += 0.1 * rng.random(n)
    stress = np.zeros((n, dim, dim))
    stress[:, 0, 0] = 1e3 * (x[:, 0] - 0.3)
    body = (x[:, 0] > 0.5).astype(int)
    stress3 = np.zeros((n, 3, 3))
    stress3[:, :dim, :dim] = stress
    return dict(x=x, v=v, F=F, stress=stress, stress3=stress3, mass=np.full(n, h**dim), volume=np.full(n, h**dim),
                body=body)


def image_stats(path):
    img = imageio.imread(path)
    return img.shape, float(img[..., :3].astype(float).var()), len(np.unique(img[..., :3].reshape(-1, 3), axis=0))


@pytest.mark.parametrize("dim,color_by", [(1, "speed"), (2, "von_mises"), (3, "J"), (2, "body")])
def test_frames_are_non_blank_and_sized(tmp_path, dim, color_by):
    p = particle_dict(dim, n_side=40 if dim == 1 else 12)
    r = FrameRenderer({"color_by": color_by, "size": [320, 240]}, dim, [0.0] * dim, [1.0] * dim)
    out = r.render(p, 0.125, tmp_path / "frame_000000.png")
    r.close()
    shape, var, colours = image_stats(out)
    assert shape[:2] == (240, 320)
    assert var > 100.0          # a white or single-colour image has variance ~0
    assert colours > 20         # particles, colour bar and label: many distinct colours


def test_particles_move_between_frames_with_fixed_limits(tmp_path):
    p = particle_dict(2)
    r = FrameRenderer({"color_by": "speed", "size": [200, 160], "clim": [0.0, 1.0]}, 2, [0, 0], [1, 1])
    a = r.render(p, 0.0, tmp_path / "a.png")
    p2 = dict(p, x=p["x"] + [0.25, 0.0])
    b = r.render(p2, 0.1, tmp_path / "b.png")
    r.close()
    ia, ib = imageio.imread(a)[..., :3].astype(int), imageio.imread(b)[..., :3].astype(int)
    assert np.abs(ia - ib).sum(axis=2).astype(bool).mean() > 0.02  # the block moved visibly


def test_field_values():
    p = particle_dict(3, n_side=3)
    np.testing.assert_allclose(field_values(p, "speed", 3), np.abs(p["v"][:, 0]))
    np.testing.assert_allclose(field_values(p, "J", 3), p["F"][:, 0, 0])
    np.testing.assert_allclose(field_values(p, "sxx", 3), p["stress"][:, 0, 0])
    # uniaxial stress: von Mises equals |sigma_xx|
    np.testing.assert_allclose(von_mises(p["stress"]), np.abs(p["stress"][:, 0, 0]), rtol=1e-12, atol=1e-9)
    # pure shear tau: von Mises = sqrt(3) tau
    s = np.zeros((1, 3, 3))
    s[0, 0, 1] = s[0, 1, 0] = 2.0
    np.testing.assert_allclose(von_mises(s), [2.0 * np.sqrt(3.0)])
    with pytest.raises(ValueError, match="unknown colour field"):
        field_values(p, "temperature", 3)
    with pytest.raises(ValueError, match="damage"):
        field_values(p, "damage", 3)


@pytest.mark.parametrize("suffix", ["mp4", "gif"])
def test_make_movie_is_readable(tmp_path, suffix):
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(5):
        img = np.full((120, 160, 3), 255, np.uint8)
        img[20:60, 10 + 20 * k: 40 + 20 * k] = (200, 30, 30)
        imageio.imwrite(frames / f"frame_{k:06d}.png", img)
    out = make_movie(frames, tmp_path / f"movie.{suffix}", fps=10)
    back = imageio.mimread(out)
    assert len(back) == 5
    assert back[0].shape[:2] == (120, 160)
    # the moving square is where it was drawn (lossy codecs: compare coarsely)
    assert back[4][40, 100, 0] > 150 and back[4][40, 100, 1] < 100


def write_run(run_dir, dim=2, n_out=3):
    """A run directory as io.py writes it: config.yaml, particles_NNNNNN.vtu and particles.pvd."""
    import yaml

    from conftest import make_cfg

    cfg = make_cfg(dim)
    cfg["output"] = {"every": 0.01, "formats": ["vtu", "png"], "render": {"color_by": "speed", "size": [240, 180]}}
    run_dir.mkdir(parents=True)
    (run_dir / "config.yaml").write_text(yaml.safe_dump(cfg))
    entries = []
    for k in range(n_out):
        p = particle_dict(dim, n_side=10)
        x = p["x"] + [0.05 * k] + [0.0] * (dim - 1)
        pts = np.pad(x, ((0, 0), (0, 3 - dim)))
        vel = np.pad(p["v"] * (k + 1), ((0, 0), (0, 3 - dim)))
        st = np.zeros((len(x), 3, 3))
        st[:, :dim, :dim] = p["stress"]
        data = dict(velocity=vel, stress=st.reshape(-1, 9), von_mises=von_mises(p["stress"]),
                    J=np.linalg.det(p["F"]), body=p["body"].astype(float))
        name = f"particles_{k:06d}.vtu"
        meshio.write(run_dir / name, meshio.Mesh(pts, [("vertex", np.arange(len(x))[:, None])], point_data=data))
        entries.append(f'<DataSet timestep="{0.01 * k}" file="{name}"/>')
    (run_dir / "particles.pvd").write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">'
                                           "<Collection>" + "".join(entries) + "</Collection></VTKFile>\n")


def test_render_run_rerenders_saved_output(tmp_path):
    run = tmp_path / "run"
    write_run(run)
    res = render_run(run, color_by="von_mises", size=[200, 150], movie="gif")
    assert [f.name for f in res["frames"]] == [f"frame_{k:06d}.png" for k in range(3)]
    for f in res["frames"]:
        shape, var, _ = image_stats(f)
        assert shape[:2] == (150, 200) and var > 100.0
    assert res["movie"].name == "movie.gif" and len(imageio.mimread(res["movie"])) == 3
    # no movie unless the config's formats ask for one
    assert render_run(run, movie=None)["movie"] is None


def test_render_run_without_config_fails_clearly(tmp_path):
    with pytest.raises(FileNotFoundError, match="config.yaml"):
        render_run(tmp_path)


def test_render_run_rejects_unknown_field_before_rendering(tmp_path):
    from taichi_mpm.errors import ConfigError

    run = tmp_path / "run"
    write_run(run, n_out=1)
    with pytest.raises(ConfigError, match="unknown colour field"):
        render_run(run, color_by="temperature")
    assert not (run / "frames").exists()


# ---------------------------------------------------------------- colour ranges that show the physics
def colormap_positions(img, cmap_name, min_chroma=40):
    """Where on the colour map each coloured pixel of a frame lies, in [0, 1]: the colour map entry that best
    matches the pixel up to a brightness factor (the 3D lighting scales a particle's colour; 2D discs are unlit).
    Grey pixels (background, floor, outline, text) are left out by their low chroma."""
    import matplotlib

    rgb = img[..., :3].reshape(-1, 3).astype(float)
    rgb = rgb[np.ptp(rgb, axis=1) >= min_chroma]
    table = matplotlib.colormaps[cmap_name](np.linspace(0, 1, 256))[:, :3] * 255
    scale = np.clip(rgb @ table.T / np.sum(table**2, axis=1), 0.3, 1.5)          # (pixels, 256) best factors
    residual = np.sum(rgb**2, axis=1)[:, None] - 2 * scale * (rgb @ table.T) + scale**2 * np.sum(table**2, axis=1)
    return np.argmin(residual, axis=1) / 255.0


def map_coverage(positions, bins=10, min_share=0.01):
    """Fraction of the colour map's bins that hold at least min_share of the particle pixels."""
    h, _ = np.histogram(positions, bins=bins, range=(0, 1))
    return float(np.mean(h >= min_share * max(len(positions), 1)))


def impact_states(dim, n_frames=4):
    """A plate hit in its middle: a von Mises stress wave (a ring of ~1 kPa running outwards over a near-zero
    background) plus a few contact particles at 100 kPa, the distribution that leaves a min-max colour range
    one flat colour (issue 13: sphere_impact's plate)."""
    h = 0.02
    axes = [np.arange(0.1, 0.9, h) + h / 2, np.arange(0.0, 0.16, h) + h / 2] + ([np.arange(0.1, 0.9, h) + h / 2]
                                                                              if dim == 3 else [])
    x = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, dim)
    centre = np.array([0.5, 0.16] + ([0.5] if dim == 3 else []))
    r = np.linalg.norm(x - centre, axis=1)
    rng = np.random.default_rng(1)
    states = []
    for k in range(n_frames):
        front = 0.1 + 0.08 * k
        vm = 1e3 * np.exp(-((r - front) / 0.08) ** 2) + 20 * rng.random(len(x))
        vm[np.argsort(r)[:3]] = 1e5                                  # the contact
        stress3 = np.zeros((len(x), 3, 3))
        stress3[:, 0, 0] = vm                                        # uniaxial: von Mises = |sxx|
        states.append(dict(x=x, v=np.zeros_like(x), stress3=stress3, stress=stress3[:, :dim, :dim],
                           volume=np.full(len(x), h**dim), mass=np.full(len(x), h**dim)))
    return states


@pytest.mark.parametrize("dim", [2, 3])
def test_robust_colour_range_spreads_particles_over_the_map(tmp_path, dim):
    """Issue 13's check: the particle pixels of a frame span at least 40 % of the colour map for a heavy-tailed
    field, with the range the renderer chooses for the whole sequence; the min-max range of the old renderer
    puts nearly all of them into the bottom bin (so the check can fail)."""
    from taichi_mpm.io.render import FrameRenderer, sequence_bounds, sequence_limits

    states = impact_states(dim)
    rc = {"color_by": "von_mises", "size": [400, 300], "colormap": "viridis"}
    values = [field_values(s, "von_mises", dim) for s in states]
    lim = sequence_limits(rc, values)
    assert lim[0] == 0.0 and 5e2 < lim[1] < 2e3     # the wave's amplitude sets the top, not the contact's 1e5
    bounds = sequence_bounds([s["x"] for s in states], 0.02, dim) if dim == 3 else None
    coverage = {}
    for name, limits in (("robust", lim), ("min-max", [0.0, max(float(v.max()) for v in values)])):
        r = FrameRenderer(rc, dim, [0.0] * dim, [1.0] * dim, limits=limits, bounds=bounds)
        out = r.render(states[2], 0.1, tmp_path / f"{name}.png")
        r.close()
        img = imageio.imread(out)
        img = img[40: int(0.8 * img.shape[0])]                  # the scene only: not the colour bar below it
        pos = colormap_positions(img, "viridis")
        assert len(pos) > 0.02 * img.shape[0] * img.shape[1]     # particles fill a real part of the frame
        coverage[name] = map_coverage(pos)
    # measured: robust 1.0 (2D and 3D); min-max 0.2 (2D: the bottom bin and the contact's top bin) and 0.1 (3D)
    assert coverage["robust"] >= 0.4, coverage
    assert coverage["min-max"] <= 0.3, coverage


def test_log_scale_limits_and_positions():
    from taichi_mpm.io.colour_range import normalise, robust_limits

    v = np.concatenate([np.logspace(0, 5, 1001), [0.0, -1.0]])       # a log-uniform field with zeros
    lo, hi = robust_limits([v], "von_mises", "log", (0, 100))
    assert hi == pytest.approx(1e5) and lo == pytest.approx(10.0)   # at most 4 decades below the top
    t = normalise(np.array([1e1, 1e3, 1e5, 0.0]), [lo, hi], "log")
    np.testing.assert_allclose(t, [0.0, 0.5, 1.0, 0.0])             # equal ratios, equal steps; zero at the bottom
    # linear: percentiles of all frames together, fixed for the sequence; magnitudes start at 0
    frames = [np.linspace(0, 1, 101) + 5.0, np.linspace(0, 1, 101) + 9.0]
    assert robust_limits(frames, "speed", percentiles=(0, 100)) == [0.0, 10.0]
    assert robust_limits(frames, "pressure", percentiles=(0, 100)) == [5.0, 10.0]
    assert robust_limits([np.array([0, 1, 1, 2])], "body", categorical=True) == [-0.5, 2.5]


@pytest.mark.slow
@pytest.mark.parametrize("demo,overrides,frame", [
    ("colliding_disks", {"domain.dx": 0.05, "solver.end_time": 2.5, "output.every": 0.25}, 8),   # t = 2: impact
    ("sphere_impact", {"domain.dx": 0.0625, "solver.end_time": 0.12, "output.every": 0.02}, 4),  # t = 0.08: contact
])
def test_demo_frames_use_the_colour_map(tmp_path, demo, overrides, frame):
    """The bundled 2D and 3D main demos, coarsened, rendered headless by a run with their default colour field
    (colliding_disks: von Mises; sphere_impact: log von Mises): the particle pixels of a frame during the impact
    span at least 40 % of the colour map (issue 13)."""
    import taichi_mpm as tm
    from taichi_mpm.cli import demos

    cfg = tm.load_config(demos()[demo], {**overrides, "output.formats": ["png"], "arch": "cpu"})
    tm.Simulation(cfg).run(out_dir=tmp_path / demo)
    img = imageio.imread(tmp_path / demo / "frames" / f"frame_{frame:06d}.png")
    scene = img[40: int(0.8 * img.shape[0])]
    pos = colormap_positions(scene, cfg.output.render.colormap)
    assert len(pos) > 0.02 * scene.shape[0] * scene.shape[1]
    assert map_coverage(pos) >= 0.4, map_coverage(pos)
    assert not list((tmp_path / demo / "frames").glob(".record_*"))   # the frame data is gone once rendered


def test_render_options_are_validated_with_their_key():
    import taichi_mpm as tm
    from conftest import make_cfg
    from taichi_mpm.errors import ConfigError

    for render, key in (({"percentiles": [99, 1]}, "percentiles"), ({"percentiles": [1, 101]}, "percentiles"),
                        ({"scale": "sqrt"}, "scale"), ({"scale": "log", "clim": [0, 10]}, "clim")):
        cfg = make_cfg(2)
        cfg["output"] = {"render": render}
        with pytest.raises(ConfigError, match=key):
            tm.load_config(cfg)
    cfg = make_cfg(2)
    cfg["output"] = {"render": {"scale": "log", "percentiles": [5, 95]}}
    assert tm.load_config(cfg).output.render.percentiles == [5, 95]


@pytest.mark.slow
def test_run_renders_its_frames_at_the_end_with_one_colour_range(tmp_path):
    """A run keeps frame data per output and renders the sequence at its end: every frame's colour bar (its
    labels are the range) is the same picture although the speeds change, and no frame data is left behind."""
    import taichi_mpm as tm
    from conftest import make_cfg

    cfg = make_cfg(2, velocity=[0.0, -1.0], end_time=0.06)
    cfg["solver"]["gravity"] = [0.0, -9.81]
    cfg["output"] = {"every": 0.02, "formats": ["png"], "render": {"color_by": "speed", "size": [240, 200]}}
    tm.Simulation(tm.load_config(cfg)).run(out_dir=tmp_path / "run")
    frames = sorted((tmp_path / "run" / "frames").glob("frame_*.png"))
    assert [f.name for f in frames] == [f"frame_{k:06d}.png" for k in range(4)]
    assert not list((tmp_path / "run" / "frames").glob(".record_*"))
    bars = [imageio.imread(f)[-30:, :, :3] for f in frames]
    for b in bars[1:]:
        np.testing.assert_array_equal(b, bars[0])
    assert not np.array_equal(imageio.imread(frames[0])[:150], imageio.imread(frames[-1])[:150])  # it moved


def test_surface_particles_of_a_solid_cube():
    """A 10^3 lattice: the particles within two layers of its faces are drawn, the 6^3 core is not; a cube with a
    hollow middle shows its cavity's walls too (they border an empty voxel)."""
    from taichi_mpm.io.render import surface_particles

    h = 0.1
    ijk = np.stack(np.meshgrid(*[np.arange(10)] * 3, indexing="ij"), -1).reshape(-1, 3)
    x = (ijk + 0.5) * h + 0.01 * h   # slightly off the voxel corners, as particles are
    keep = surface_particles(x, h)
    core = np.all((ijk >= 2) & (ijk <= 7), axis=1)
    np.testing.assert_array_equal(keep, ~core)
    hollow = ~np.all((ijk >= 4) & (ijk <= 5), axis=1)
    keep = surface_particles(x[hollow], h)
    assert keep.sum() > (~core).sum()          # the cavity's walls are visible from inside it
