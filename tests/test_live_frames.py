"""Frames drawn while the solver steps (issue 31, io/live_frames.py): with the colour range and the camera fixed in
advance (output.render.clim, framing) they are the frames the end-of-run path draws from the same data; a stop
while frames are queued finishes them and leaves no partial file; the framing key is validated by name."""
import numpy as np
import pytest

imageio = pytest.importorskip("imageio.v2")
pytest.importorskip("pyvista")

import taichi_mpm as tm  # noqa: E402
from taichi_mpm.errors import ConfigError  # noqa: E402
from taichi_mpm.io import render  # noqa: E402
from taichi_mpm.io.live_frames import LiveFrames  # noqa: E402
from conftest import make_cfg  # noqa: E402

BOX = [[0.2, 0.0, 0.2], [0.8, 0.7, 0.8]]


def falling_block(k, n_side=10):
    """A 3D block of particles at frame k: it falls and spreads, its speeds grow."""
    h = 0.3 / n_side
    axes = [0.35 + (np.arange(n_side) + 0.5) * h] * 3
    x = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    x[:, 1] += 0.3 - 0.05 * k
    x[:, 0] += 0.02 * k * (x[:, 0] - 0.5)
    v = np.zeros_like(x)
    v[:, 1] = -(k + 1) * (1 + x[:, 0])
    n = len(x)
    return dict(x=x, v=v, volume=np.full(n, h ** 3), mass=np.full(n, h ** 3), body=(x[:, 0] > 0.5).astype(int))


def pixels(path):
    return imageio.imread(path)[..., :3].astype(int)


@pytest.mark.parametrize("color_by,extra", [("speed", {"clim": [0.0, 6.0]}), ("body", {})])
def test_live_frames_equal_the_end_of_run_frames(tmp_path, color_by, extra):
    """The same frame data, colour range and 3D box: the frames drawn as they come (own thread, own window) are the
    pictures of the end-of-run path (records rendered at the end), and the live path feeds a readable movie."""
    rc = dict(color_by=color_by, size=[160, 120], camera="iso", framing=BOX, **extra)
    assert render.known_in_advance(rc, 3) and not render.known_in_advance(dict(rc, framing="run"), 3)
    states = [falling_block(k) for k in range(4)]
    for run in ("end", "live"):
        (tmp_path / run).mkdir()
    end = render.FrameRecorder(tmp_path / "end" / "frames", rc, 3, [0, 0, 0], [1, 1, 1], title="t")
    live = LiveFrames(tmp_path / "live" / "frames", rc, 3, [0, 0, 0], [1, 1, 1], title="t",
                      movie=tmp_path / "live" / "movie.mp4")
    for k, s in enumerate(states):
        end.record(s, 0.01 * k, k)
        live.record(s, 0.01 * k, k)
    live.close(complete=True)
    a, b = end.render_all(), live.frames
    assert [f.name for f in a] == [f.name for f in b] == [f"frame_{k:06d}.png" for k in range(4)]
    for fa, fb in zip(a, b):
        d = np.abs(pixels(fa) - pixels(fb))
        assert d.mean() < 0.05 and (d.max(axis=2) > 8).mean() < 1e-3, (fa.name, d.mean())
    assert not np.array_equal(pixels(b[0]), pixels(b[-1]))   # the block moved
    assert live.movie_done and len(imageio.mimread(tmp_path / "live" / "movie.mp4")) == 4
    assert not [p for p in (tmp_path / "live").rglob("*") if ".tmp" in p.name]


def test_png_is_lossless_and_read_back(tmp_path):
    img = (np.random.default_rng(0).random((7, 9, 3)) * 255).astype(np.uint8)
    render.write_png(tmp_path / "a.png", img)
    np.testing.assert_array_equal(imageio.imread(tmp_path / "a.png"), img)


def two_d_run(clim=(0.0, 1.2), writer="thread"):
    cfg = make_cfg(2, velocity=[0.0, -1.0], end_time=0.06)
    cfg["solver"]["gravity"] = [0.0, -9.81]
    cfg["output"] = {"every": 0.02, "formats": ["png", "mp4"], "writer": writer,
                     "render": {"color_by": "speed", "size": [160, 120], "clim": list(clim)}}
    return tm.Simulation(tm.load_config(cfg))


@pytest.mark.parametrize("writer", ["thread", "inline"])
def test_run_draws_its_frames_while_stepping_as_the_end_of_run_path_would(tmp_path, monkeypatch, writer):
    """A 2D run with clim: frames drawn during the run (no frame records written), the movie fed as they come
    (output.writer inline: in the solver's thread); the same run forced onto the end-of-run path gives the same
    frames."""
    from taichi_mpm.io.runner import Run

    monkeypatch.setattr(render.FrameRecorder, "record", lambda *a: pytest.fail("a frame record was written"))
    live = Run(two_d_run(writer=writer), tmp_path / "live").execute()
    assert live._movie_done and live.frames_rendered == 4 and live.frames_while_stepping
    monkeypatch.undo()
    monkeypatch.setattr(render, "known_in_advance", lambda *a: False)
    Run(two_d_run(), tmp_path / "end").execute()
    names = sorted(f.name for f in (tmp_path / "live" / "frames").iterdir())
    assert names == sorted(f.name for f in (tmp_path / "end" / "frames").iterdir()) == \
        [f"frame_{k:06d}.png" for k in range(4)]
    for n in names:
        d = np.abs(pixels(tmp_path / "live" / "frames" / n) - pixels(tmp_path / "end" / "frames" / n))
        assert d.mean() < 0.05, (n, d.mean())
    assert len(imageio.mimread(tmp_path / "live" / "movie.mp4")) == 4


def test_a_stop_finishes_the_queued_frames_and_leaves_no_partial_file(tmp_path, monkeypatch):
    """A stop (as Ctrl-C sets it) while the frame worker is behind (each frame slowed to 0.3 s): every output's
    frame is on disk when Interrupted is raised, no temporary is left, and no movie (the run is not complete)."""
    import time

    from taichi_mpm.io.runner import Interrupted, Run

    slow_png = render.write_png

    def write_png(*a, **k):
        time.sleep(0.3)
        slow_png(*a, **k)

    monkeypatch.setattr(render, "write_png", write_png)
    sim = two_d_run()
    run = Run(sim, tmp_path / "cut")

    queued = []

    def stop_after_three_outputs(s):
        if run.index >= 3 and not run.stop_requested:
            run.stop_requested = True
            queued.append(run.writer.pending + (run._renderer.worker.pending if run._renderer else 0))

    with pytest.raises(Interrupted):
        run.execute(on_step=stop_after_three_outputs)
    assert queued[0] >= 1   # the worker was behind when the stop came
    frames = sorted(p.name for p in (tmp_path / "cut" / "frames").iterdir())
    assert frames == [f"frame_{k:06d}.png" for k in range(run.index)]
    for f in frames:
        assert pixels(tmp_path / "cut" / "frames" / f).shape == (120, 160, 3)
    assert not (tmp_path / "cut" / "movie.mp4").exists()
    assert not [p for p in (tmp_path / "cut").rglob("*") if ".tmp" in p.name]
    monkeypatch.undo()   # resumed: the later frames drawn as they come, the movie joined from every PNG at the end
    resumed = Run(two_d_run(), tmp_path / "cut", resume=True).execute()
    assert not resumed._movie_done
    assert sorted(p.name for p in (tmp_path / "cut" / "frames").iterdir()) == [f"frame_{k:06d}.png" for k in range(4)]
    assert len(imageio.mimread(tmp_path / "cut" / "movie.mp4")) == 4


@pytest.mark.parametrize("framing", ["sky", [[0, 0, 0], [1, 1]], [[0, 1, 0], [1, 0.5, 1]]])
def test_framing_errors_name_the_key(framing):
    cfg = make_cfg(3)
    cfg["output"] = {"render": {"framing": framing}}
    with pytest.raises(ConfigError, match="output.render.framing"):
        tm.load_config(cfg)
    cfg["output"] = {"render": {"framing": "domain", "clim": [0, 1]}}
    assert render.known_in_advance(tm.load_config(cfg).output.render, 3)


def test_a_numerical_failure_leaves_every_frame_before_it_and_no_movie(tmp_path):
    """A run that blows up (dt far above the stable step): the frames of every output before the failure are on
    disk when InstabilityError is raised; no movie and no temporary."""
    from taichi_mpm.errors import InstabilityError
    from taichi_mpm.io.runner import Run

    cfg = make_cfg(2, velocity=[0.5, -1.0], lower=[0.3, 0.1], upper=[0.6, 0.4], end_time=2.0, dt=0.2)
    cfg["output"] = {"every": 0.2, "formats": ["png", "mp4"],
                     "render": {"color_by": "speed", "size": [96, 72], "clim": [0.0, 2.0]}}
    run = Run(tm.Simulation(tm.load_config(cfg)), tmp_path / "boom")
    with pytest.raises(InstabilityError):
        run.execute()
    frames = sorted(p.name for p in (tmp_path / "boom" / "frames").iterdir())
    assert run.index >= 1 and frames == [f"frame_{k:06d}.png" for k in range(run.index)]
    assert not (tmp_path / "boom" / "movie.mp4").exists()
    assert not [p for p in (tmp_path / "boom").rglob("*") if ".tmp" in p.name]
