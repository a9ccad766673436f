"""The small CLI defects of issue 16, one test each: `demo --list | head` (no BrokenPipe traceback), `--quiet`
(nothing on stdout or stderr, Taichi's banner included), the summary's stepping rate apart from compile and
outputs, `--resume` with an end time before the checkpoint, the Python demo's own output folder, and the
documented Python way to continue a checkpoint with a changed parameter."""
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm.io import files as io
from taichi_mpm.cli import main

REPO = Path(__file__).resolve().parents[1]


def bar_cfg(tmp_path, **output):
    """A 1D bar moving at constant speed (one tiny scene for every test here: one compiled kernel set)."""
    cfg = make_cfg(1, velocity=[0.5], lower=[0.3], upper=[0.6], end_time=0.04)
    cfg["output"] = dict(every=0.02, formats=[], dir=str(tmp_path / "runs" / "{name}"), **output)
    path = tmp_path / "bar.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def python_m(*args, cwd, stdout=subprocess.PIPE):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.Popen([sys.executable, "-m", "taichi_mpm", *map(str, args)], cwd=cwd, env=env,
                            stdout=stdout, stderr=subprocess.PIPE)


def test_demo_list_into_a_closed_pipe_has_no_traceback(tmp_path):
    # `taichi-mpm demo --list | head -0`: the reader is gone before the list is written
    p = python_m("demo", "--list", cwd=tmp_path)
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 0
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_quiet_run_prints_nothing_taichi_banner_included(tmp_path):
    path = bar_cfg(tmp_path)
    p = python_m("run", path, "--quiet", "--out", tmp_path / "q", cwd=tmp_path)
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0
    assert out == b"" and err == b""  # no "[Taichi] version ..." or "Starting on arch" line either
    assert (tmp_path / "q" / "checkpoint.npz").is_file()


def test_summary_separates_compile_stepping_and_outputs(tmp_path, capsys):
    path = bar_cfg(tmp_path)
    assert main(["run", str(path), "--out", str(tmp_path / "s"), "--set", "output.formats=[vtu]",
                 "--set", "output.every=0.002"]) == 0
    err = capsys.readouterr().err
    m = re.search(r"done: (\d+) steps .* in ([\d.]+) s \((\d+) particles\): first step \(JIT compile\) ([\d.]+) s, "
                  r"stepping ([\d.]+) s at ([\d.e+-]+) particle-steps/s, outputs ([\d.]+) s", err)
    assert m, err
    steps, wall, n, first, stepping, rate, outputs = (float(g) for g in m.groups())
    # the three parts make up the wall time (each printed to 0.1 s: 0.25 s of rounding at most)
    assert first + stepping + outputs == pytest.approx(wall, abs=0.25)
    assert outputs > 0  # 21 VTU files were written, and their time is not in the stepping rate
    if stepping >= 0.1:  # the printed rate is the stepping rate: the true stepping time lies within 0.05 s of the
        # printed one (one decimal), the rate has 3 significant digits (0.5 %)
        work = n * (steps - 1)
        assert work / (stepping + 0.05) * 0.995 <= rate <= work / (stepping - 0.05) * 1.005
    assert "particle-steps/s" in err  # the progress bar's column, which also leaves outputs and compile out


def test_resume_with_end_time_before_the_checkpoint(tmp_path, capsys):
    path = bar_cfg(tmp_path)
    out = str(tmp_path / "r")
    assert main(["run", str(path), "--out", out, "--quiet"]) == 0          # checkpoint at t = 0.04
    assert main(["run", str(path), "--out", out, "--quiet", "--resume", "--set", "solver.end_time=0.02"]) == 2
    err = capsys.readouterr().err
    assert "solver.end_time" in err and "t=0.04, after solver.end_time=0.02" in err and "Traceback" not in err
    assert main(["run", str(path), "--out", out, "--resume"]) == 0         # at end_time exactly: nothing to do
    assert "already at t=0.04" in capsys.readouterr().err


def test_python_workaround_continues_a_checkpoint_with_a_changed_parameter(tmp_path):
    # docs/contract.md, "Continuing with a changed parameter": load the state, build a Simulation from the
    # changed config, set_state, run into a new folder
    path = bar_cfg(tmp_path)
    assert main(["run", str(path), "--out", str(tmp_path / "a"), "--quiet"]) == 0
    state, meta = io.load_checkpoint(tmp_path / "a" / "checkpoint.npz")
    cfg = tm.load_config(path, overrides={"solver.cfl": 0.2, "solver.end_time": 0.08})
    sim = tm.Simulation(cfg)
    sim.set_state(state)
    sim.run(out_dir=tmp_path / "b")
    assert sim.time == pytest.approx(0.08) and meta["last_time"] == pytest.approx(0.04)
    # the bar keeps moving at 0.5 m/s: from the checkpoint's positions, 0.5 * 0.04 m further
    assert np.allclose(sim.particles()["x"][:, 0], state["x"][:, 0] + 0.5 * 0.04, atol=1e-9)
    rows = (tmp_path / "b" / "diagnostics.csv").read_text().splitlines()
    assert float(rows[1].split(",")[0]) == pytest.approx(0.04)   # the new folder starts at the checkpoint's time


def test_python_demo_writes_beside_the_cli_demo(tmp_path, monkeypatch, capsys):
    sys.path.insert(0, str(REPO / "demos"))
    try:
        import _common
    finally:
        sys.path.remove(str(REPO / "demos"))
    cfg = tm.load_config(REPO / "configs" / "vibrating_bar.yaml")
    assert _common.default_out(cfg) == Path("runs/vibrating_bar_python")
    # and it is used: a run without --out goes there (relative to the current folder)
    monkeypatch.chdir(tmp_path)
    sim = tm.Simulation(tm.load_config(bar_cfg(tmp_path), overrides={"output.dir": "runs/{name}"}))
    _common.run(sim)
    assert (tmp_path / "runs" / f"{sim.cfg.name}_python" / "checkpoint.npz").is_file()
    assert not (tmp_path / "runs" / sim.cfg.name).exists()   # the CLI's folder stays untouched
