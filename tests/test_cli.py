"""The taichi-mpm command line: exit codes and messages, validate/demo, the files `run` writes,
resume (after a finished run and after Ctrl-C) reproducing the uninterrupted run, instability.

The CLI runs in-process (main(argv)) except where the exit code / no-traceback contract is checked."""
import os
import signal
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest
import yaml

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm.io import files as io
from taichi_mpm.cli import configs_dir, main
from taichi_mpm.scene import build_scene

REPO = Path(__file__).resolve().parents[1]


def scene_cfg(tmp_path, name="scene.yaml", **kw):
    """A tiny 2D f64 scene: a block moving down onto a slip floor; 3 outputs by default."""
    cfg = make_cfg(2, velocity=[0.5, -1.0], lower=[0.3, 0.1], upper=[0.6, 0.4], end_time=0.04)
    cfg["output"] = dict(every=0.02, formats=["vtu"], dir=str(tmp_path / "runs" / "{name}"))
    for k, v in kw.items():
        cfg = io_set(cfg, k, v)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def sim_wave_speed(cfg):
    """(lambda + 2 mu) / rho of the single material: the squared P-wave speed."""
    m = cfg.materials["m"]
    return (m.lam + 2 * m.mu) / m.density


def io_set(cfg, key, value):
    from taichi_mpm.config import apply_overrides

    return apply_overrides(cfg, {key: value})


def cli(*args, cwd):
    """Run `python -m taichi_mpm ARGS` in a subprocess: (exit code, stdout, stderr)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    r = subprocess.run([sys.executable, "-m", "taichi_mpm", *map(str, args)], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=300)
    return r.returncode, r.stdout, r.stderr


# ---------------------------------------------------------------- invalid input: exit 2, one message
def test_invalid_inputs_exit_2_without_traceback(tmp_path):
    good = scene_cfg(tmp_path)
    text = good.read_text()
    (tmp_path / "unknown.yaml").write_text(text.replace("  dx: 0.1\n", "  dx: 0.1\n  dxx: 2\n"))
    line_dxx = text.splitlines().index("  dx: 0.1") + 2
    (tmp_path / "outside.yaml").write_text(text.replace("- 0.4\n", "- 1.4\n", 1))
    (tmp_path / "empty.yaml").write_text("")
    (tmp_path / "broken.yaml").write_text("name: x\n  dim: [2\n")
    cases = [
        (["run", "unknown.yaml"], ["unknown.yaml:%d" % line_dxx, "domain.dxx", "unknown key"]),
        (["run", "outside.yaml", "--quiet"], ["outside.yaml:", "bodies.0.shape", "outside the domain"]),
        (["validate", "empty.yaml"], ["empty.yaml", "empty"]),
        (["run", "broken.yaml"], ["broken.yaml:2", "not valid YAML"]),
        (["run", "missing.yaml"], ["missing.yaml", "not found"]),
        (["run", "scene.yaml", "--set", "bodies.0.material=steel"], ["bodies.0.material", "steel", "--set"]),
        (["run", "scene.yaml", "--set", "solver.basis"], ["KEY=VALUE"]),
        (["render", "nowhere"], ["nowhere"]),
        (["frobnicate"], ["invalid choice"]),
    ]
    for args, words in cases:
        code, out, err = cli(*args, cwd=tmp_path)
        assert code == 2, (args, err)
        assert "Traceback" not in err + out, args
        for w in words:
            assert w in err, (args, w, err)
        assert err.count("error:") == 1, err


def test_python_m_help_and_module_entry(tmp_path):
    code, out, err = cli("--help", cwd=tmp_path)
    assert code == 0 and "run" in out and "validate" in out and "demo" in out


# ---------------------------------------------------------------- validate, demo
def test_validate_prints_resolved_config_with_overrides(tmp_path, capsys):
    path = scene_cfg(tmp_path)
    assert main(["validate", str(path), "--set", "solver.basis=cubic", "--set", "bodies.0.velocity=[0,-2]",
                 "--arch", "cpu"]) == 0
    out, err = capsys.readouterr()
    resolved = yaml.safe_load(out)
    assert resolved["solver"]["basis"] == "cubic"
    assert resolved["bodies"][0]["velocity"] == [0.0, -2.0]
    assert resolved["solver"]["transfer"] == "apic" and resolved["solver"]["cfl"] == 0.4  # defaults filled in
    assert tm.load_config(resolved).solver.basis == "cubic"  # the printed config is itself valid
    assert "36 particles" in err


def test_demo_list_lists_the_configs_present(capsys):
    names = sorted(p.stem for p in configs_dir().glob("*.yaml"))
    assert names, "no demo configs in configs/"
    assert main(["demo", "--list"]) == 0
    listed = [line.split()[0] for line in capsys.readouterr().out.splitlines() if line.strip()]
    assert listed == names
    assert main(["demo", "no_such_demo"]) == 2
    assert "no_such_demo" in capsys.readouterr().err


# ---------------------------------------------------------------- run: files
def test_run_writes_vtu_series_diagnostics_checkpoint_config(tmp_path, capsys):
    path = scene_cfg(tmp_path)
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    cfg = tm.load_config(path)
    n = build_scene(cfg).n
    assert n == 36
    files = sorted(out.glob("particles_*.vtu"))
    assert [f.name for f in files] == [f"particles_{k:06d}.vtu" for k in range(3)]
    for f in files:
        m = meshio.read(f)
        assert m.points.shape == (n, 3)
        assert {"velocity", "stress", "von_mises", "J", "body"} <= set(m.point_data)
        assert m.point_data["velocity"].shape == (n, 3) and m.point_data["stress"].shape == (n, 9)
        assert np.all(m.point_data["J"] > 0)
    assert io.read_pvd(out / "particles.pvd") == [(0.0, files[0].name), (0.02, files[1].name), (0.04, files[2].name)]
    first = io.read_vtu(files[0], 2)
    np.testing.assert_allclose(first["velocity"], np.tile([0.5, -1.0], (n, 1)), atol=1e-14)
    np.testing.assert_allclose(first["x"], build_scene(cfg).x, atol=1e-15)
    diag = io.read_diagnostics(out / "diagnostics.csv")
    np.testing.assert_allclose(diag["time"], [0.0, 0.02, 0.04], atol=1e-15)
    mass = 1000.0 * 0.3 * 0.3
    np.testing.assert_allclose(diag["kinetic"][0], 0.5 * mass * 1.25, rtol=1e-12)
    np.testing.assert_allclose(diag["momentum_x"], 0.5 * mass, rtol=1e-10)  # no wall acts along x
    np.testing.assert_allclose(diag["cfl"], 0.4, rtol=1e-6)  # adaptive dt: the CFL number of the config
    c = np.sqrt(sim_wave_speed(cfg))
    np.testing.assert_allclose(diag["dt"], 0.4 * 0.1 / (c + diag["max_speed"]), rtol=1e-9)
    assert tm.load_config(out / "config.yaml").to_dict() == cfg.to_dict()
    state, meta = io.load_checkpoint(out / "checkpoint.npz")
    assert state["time"] == pytest.approx(0.04) and meta["next_output"] == 3
    np.testing.assert_array_equal(state["x"], io.read_vtu(files[-1], 2)["x"])


@pytest.mark.slow
def test_python_api_run_writes_outputs(tmp_path):
    cfg = tm.load_config(scene_cfg(tmp_path))
    sim = tm.Simulation(cfg).run()
    assert sim.time == pytest.approx(0.04)
    run_dir = tmp_path / "runs" / "test"
    assert len(list(run_dir.glob("particles_*.vtu"))) == 3 and (run_dir / "checkpoint.npz").is_file()
    seen = []
    tm.Simulation(cfg).run(on_output=lambda s: seen.append(s.time))  # an observer instead of files
    assert seen == pytest.approx([0.0, 0.02, 0.04])
    sim = tm.Simulation(cfg)
    sim.advance(0.025)  # a run that starts late writes its start, then the output times after it
    sim.run(out_dir=tmp_path / "late")
    assert [t for t, _ in io.read_pvd(tmp_path / "late" / "particles.pvd")] == pytest.approx([0.025, 0.04])
    assert sim.time == pytest.approx(0.04)


# ---------------------------------------------------------------- resume
def positions(run_dir):
    return [io.read_vtu(f, 2)["x"] for _, f in io.series(run_dir)]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """The uninterrupted reference: the scene run to t=0.08 (5 outputs)."""
    tmp = tmp_path_factory.mktemp("full")
    path = scene_cfg(tmp)
    assert main(["run", str(path), "--out", str(tmp / "full"), "--quiet", "--set", "solver.end_time=0.08"]) == 0
    return tmp / "full"


@pytest.mark.slow
def test_resume_reproduces_uninterrupted_run(tmp_path, full_run):
    path = scene_cfg(tmp_path)
    full, part = full_run, tmp_path / "part"
    assert main(["run", str(path), "--out", str(part), "--quiet", "--set", "solver.end_time=0.04"]) == 0
    assert len(positions(part)) == 3
    assert main(["run", str(path), "--out", str(part), "--quiet", "--resume", "--set", "solver.end_time=0.08"]) == 0
    a, b = positions(full), positions(part)
    assert len(a) == len(b) == 5
    assert np.max(np.abs(a[-1] - a[0])) > 0.05  # the block moved
    # Default mode (Taichi's threads, f64): P2G's atomic adds run in a varying order, so the two runs may differ by
    # rounding (1e-16 relative per step; docs/reliability.md measured 1e-15 after 218 steps). 1e-12 m is far above
    # that over these ~20 steps and far below what a resume error (a lost C or F, a different dt) moves a particle
    # (>= dt |v| ~ 1e-3 m). Bit-for-bit resumption under solver.deterministic: tests/test_reproducibility.py.
    for xa, xb in zip(a, b):
        np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-12)
    da, db = io.read_diagnostics(full / "diagnostics.csv"), io.read_diagnostics(part / "diagnostics.csv")
    np.testing.assert_allclose(db["strain"], da["strain"], rtol=1e-12)
    assert da["strain"][-1] > 0  # the floor compressed it
    assert io.read_pvd(part / "particles.pvd") == io.read_pvd(full / "particles.pvd")


def test_resume_refuses_a_different_config(tmp_path, capsys):
    path = scene_cfg(tmp_path)
    out = tmp_path / "o"
    assert main(["run", str(path), "--out", str(out), "--quiet", "--resume"]) == 2
    assert "no checkpoint" in capsys.readouterr().err
    assert main(["run", str(path), "--out", str(out), "--quiet", "--set", "solver.end_time=0.02"]) == 0
    assert main(["run", str(path), "--out", str(out), "--quiet", "--resume", "--set", "solver.transfer=pic"]) == 2
    assert "solver.transfer" in capsys.readouterr().err


def test_ctrl_c_keeps_checkpoint_and_resume_matches(tmp_path, full_run):
    from taichi_mpm.io.runner import Interrupted, Run

    path = scene_cfg(tmp_path, **{"solver.end_time": "0.08"})
    cfg = tm.load_config(path)
    full = full_run

    sim = tm.Simulation(cfg)
    run = Run(sim, tmp_path / "cut")

    def ctrl_c_at_step_5(s):
        if s.n_steps == 5:
            os.kill(os.getpid(), signal.SIGINT)  # the real signal: the handler lets the step finish

    # Ctrl-C in a terminal: Python's handler. Set here, not assumed: a background job (a script's `cmd &`, whose
    # pytest workers inherit it) or some CI runners start with SIGINT ignored, where a run rightly keeps it ignored
    # and nothing stops it (test_run_restores_an_ignored_sigint); the handler found is put back after
    found = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        before = signal.getsignal(signal.SIGINT)
        with pytest.raises(Interrupted):
            run.execute(on_step=ctrl_c_at_step_5)
        assert signal.getsignal(signal.SIGINT) is before  # the handler it found is restored
    finally:
        signal.signal(signal.SIGINT, found if found is not None else signal.SIG_DFL)
    state, meta = io.load_checkpoint(tmp_path / "cut" / "checkpoint.npz")
    assert state["n_steps"] == 5 and 0.02 < state["time"] < 0.08  # between two output times
    assert main(["run", str(path), "--out", str(tmp_path / "cut"), "--quiet", "--resume"]) == 0
    a, b = positions(full), positions(tmp_path / "cut")
    assert len(a) == len(b) == 5
    for xa, xb in zip(a, b):  # within rounding of the threads' order: see test_resume_reproduces_uninterrupted_run
        np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-12)


def test_run_restores_an_ignored_sigint(tmp_path):
    """Started where SIGINT is ignored (a background job of a script: Python then keeps SIG_IGN), a run keeps it
    ignored, as a background job should be (docs/contract.md: a signal ignored when the run starts stays ignored):
    a SIGINT at step 2 does not stop it, and SIG_IGN is what it leaves behind, not Python's default handler."""
    from taichi_mpm.io.runner import Run

    sim = tm.Simulation(tm.load_config(scene_cfg(tmp_path, **{"solver.end_time": "0.08"})))

    def ctrl_c_at_step_2(s):
        if s.n_steps == 2:
            os.kill(os.getpid(), signal.SIGINT)

    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        Run(sim, tmp_path / "cut").execute(on_step=ctrl_c_at_step_2)
        assert sim.time == pytest.approx(0.08)   # ran to its end
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)


# ---------------------------------------------------------------- instability
def test_instability_exits_3_and_keeps_last_good_checkpoint(tmp_path):
    scene_cfg(tmp_path)
    out = tmp_path / "boom"
    # --arch auto also checks that choosing a device never probes OpenGL (a segmentation fault on headless machines)
    code, stdout, err = cli("run", "scene.yaml", "--out", out, "--quiet", "--arch", "auto", "--set", "solver.dt=0.2",
                            "--set", "output.every=0.2", "--set", "solver.end_time=2", cwd=tmp_path)
    assert code == 3, err
    assert "Traceback" not in err + stdout
    assert "numerical instability at step" in err and "particle" in err and "t=" in err
    assert any(c in err for c in ("J <= 0", "non-finite", "left the domain"))
    state, meta = io.load_checkpoint(out / "checkpoint.npz")
    entries = io.read_pvd(out / "particles.pvd")
    assert state["time"] == entries[-1][0]  # the checkpoint is the last output written
    assert np.all(np.isfinite(state["x"])) and np.all(np.linalg.det(state["F"]) > 0)
    assert "checkpoint.npz" in err


# ---------------------------------------------------------------- progress bar, render
def test_run_progress_bar_then_render_run_dir(tmp_path, capsys):
    imageio = pytest.importorskip("imageio.v2")
    path = scene_cfg(tmp_path)
    out = tmp_path / "r"
    assert main(["run", str(path), "--out", str(out)]) == 0  # not quiet: progress bar and summary on stderr
    captured = capsys.readouterr()
    assert "particle-steps/s" in captured.err and "done:" in captured.err and "3 outputs" in captured.err
    assert captured.out == ""  # stdout stays clean (Taichi's start-up line goes to stderr)
    assert main(["render", str(out), "--color-by", "von_mises", "--size", "160x120", "--movie", "gif"]) == 0
    frames = sorted((out / "frames").glob("frame_*.png"))
    assert [f.name for f in frames] == [f"frame_{k:06d}.png" for k in range(3)]
    img = imageio.imread(frames[-1])
    assert img.shape[:2] == (120, 160) and img[..., :3].astype(float).var() > 10
    assert (out / "movie.gif").is_file()
    assert main(["render", str(out), "--size", "12"]) == 2
    assert "WIDTHxHEIGHT" in capsys.readouterr().err
    assert main(["study", str(tmp_path / "none.yaml")]) == 2


@pytest.mark.slow
def test_resume_of_a_plastic_run_keeps_plastic_strain_and_jp(tmp_path):
    """`taichi-mpm run --resume` of a drucker_prager block moving into the floor at 1 m/s:
    it starts on the floor, so it yields from the first steps; the resumed run ends with the plastic_strain and J_p
    of the uninterrupted one (to the rounding of unordered
    atomics, as test_resume_reproduces_uninterrupted_run). A resume that restarted the history from zero would
    end with less plastic strain (by the strain accumulated before the cut, > 1e-3 here)."""
    path = scene_cfg(tmp_path, **{"materials.m": {"model": "drucker_prager", "E": 1.0e4, "nu": 0.3, "density": 1000.0,
                                                  "friction_angle": 30, "dilatancy": 10},
                                  "bodies.0.shape.lower": [0.3, 0.0], "bodies.0.shape.upper": [0.6, 0.3],
                                  "output.formats": ["npz"], "output.fields": ["plastic_strain", "Jp"]})
    full, part = tmp_path / "full", tmp_path / "part"
    assert main(["run", str(path), "--out", str(full), "--quiet", "--set", "solver.end_time=0.08"]) == 0
    assert main(["run", str(path), "--out", str(part), "--quiet", "--set", "solver.end_time=0.04"]) == 0
    cut = np.load(sorted(part.glob("particles_*.npz"))[-1])
    assert cut["plastic_strain"].max() > 1e-3 and np.abs(cut["Jp"] - 1).max() > 1e-4   # it yielded before the cut
    assert main(["run", str(path), "--out", str(part), "--quiet", "--resume", "--set", "solver.end_time=0.08"]) == 0
    a, b = (np.load(sorted(d.glob("particles_*.npz"))[-1]) for d in (full, part))
    assert a["plastic_strain"].max() > cut["plastic_strain"].max()
    for key in ("x", "plastic_strain", "Jp"):
        np.testing.assert_allclose(b[key], a[key], rtol=0, atol=1e-12, err_msg=key)
