"""Off-screen rendering: non-blank PNGs of the requested size in 1D, 2D and 3D, movies, re-rendering a run."""
import numpy as np
import pytest

imageio = pytest.importorskip("imageio.v2")
meshio = pytest.importorskip("meshio")

from taichi_mpm.render import FrameRenderer, field_values, make_movie, render_run, von_mises  # noqa: E402


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
