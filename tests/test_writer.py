"""Outputs written off the stepping path (issue 31): the writer thread writes the same files as the solver's own
thread; a real run process killed (SIGINT, SIGTERM) while the writer is busy loses no finished snapshot, leaves no
partial file, and --resume continues bit for bit; output.fields / only_fields / checkpoint_every / writer are
checked with errors naming the key; snapshots of an f32 run hold f32 points."""
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm.cli import main
from taichi_mpm.config import ConfigError, validate
from taichi_mpm.io import files as io
from taichi_mpm.io.writer import Writer

REPO = Path(__file__).resolve().parents[1]


def scene(tmp_path, end_time=0.06, name="scene.yaml", **output):
    """A tiny 2D scene (a block moving onto a slip floor, deterministic), outputs every 0.01 s, a point probe
    sampled every step."""
    cfg = make_cfg(2, velocity=[0.5, -1.0], lower=[0.3, 0.1], upper=[0.6, 0.4], end_time=end_time,
                   deterministic=True)
    cfg["output"] = dict(every=0.01, formats=["vtu"], probe_every="step",
                         probes=[dict(name="tip", type="point", point=[0.45, 0.4])], **output)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def folder(out: Path) -> dict:
    """Every file of a run folder but the config (which names the writer) -> its bytes; the checkpoint as its
    arrays and metadata (np.savez stamps no time, but compare what it holds)."""
    files = {}
    for f in sorted(out.rglob("*")):
        if f.is_file() and f.name not in (io.CONFIG_NAME, io.CHECKPOINT_NAME):
            files[str(f.relative_to(out))] = f.read_bytes()
    return files


def same_checkpoint(a: Path, b: Path, ignore=("config",)):
    (sa, ma), (sb, mb) = io.load_checkpoint(a), io.load_checkpoint(b)
    assert sorted(sa) == sorted(sb)
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)
    assert {k: v for k, v in ma.items() if k not in ignore} == {k: v for k, v in mb.items() if k not in ignore}


# ---------------------------------------------------------------- the writer
def test_writer_runs_jobs_in_order_waits_when_full_and_raises_a_failure_once():
    w = Writer(depth=1)
    done, gate = [], threading.Event()
    w.submit("a", lambda: (gate.wait(5), done.append(1)))
    w.submit("a", done.append, 2)               # fills the queue of one
    t = threading.Timer(0.2, gate.set)
    t.start()
    w.submit("b", done.append, 3)               # waits until the first job has finished
    assert w.wait_seconds >= 0.1                # (the gate opened after 0.2 s: the solver waited on the writer)
    w.drain()
    assert done == [1, 2, 3] and w.counts == {"a": 2, "b": 1}

    def fail():
        raise OSError(28, "No space left on device")
    w.submit("c", fail)
    time.sleep(0.1)
    with pytest.raises(OSError, match="No space"):
        w.submit("c", done.append, 5)           # the failure comes out at the next hand-over
    w.submit("c", done.append, 6)               # nothing is written after a failed write
    w.close()                                   # reported once: close is quiet
    assert done == [1, 2, 3]


def test_thread_and_inline_writers_write_identical_files(tmp_path, capsys):
    """Same VTU bytes, series, diagnostics, probe rows and checkpoint state, threaded or inline."""
    outs = {}
    for writer in ("thread", "inline"):
        path = scene(tmp_path, name=f"{writer}.yaml", writer=writer, checkpoint_every=2)
        outs[writer] = tmp_path / writer
        assert main(["run", str(path), "--quiet", "--out", str(outs[writer])]) == 0
    a, b = folder(outs["thread"]), folder(outs["inline"])
    assert sorted(a) == sorted(b) and len([k for k in a if k.endswith(".vtu")]) == 7
    for k in a:
        assert a[k] == b[k], k
    same_checkpoint(outs["thread"] / io.CHECKPOINT_NAME, outs["inline"] / io.CHECKPOINT_NAME)


def test_checkpoint_every_writes_the_last_output_state_and_resume_is_exact(tmp_path, capsys):
    """checkpoint_every = 4 of 7 outputs: the checkpoint of the end is written (the last output), and a run resumed
    from an early stop reaches the same files as an uninterrupted one."""
    path = scene(tmp_path, checkpoint_every=4)
    assert main(["run", str(path), "--quiet", "--out", str(tmp_path / "full")]) == 0
    state, meta = io.load_checkpoint(tmp_path / "full" / io.CHECKPOINT_NAME)
    assert state["time"] == pytest.approx(0.06) and meta["next_output"] == 7
    assert main(["run", str(path), "--quiet", "--out", str(tmp_path / "part"), "--set", "solver.end_time=0.03"]) == 0
    assert main(["run", str(path), "--quiet", "--out", str(tmp_path / "part"), "--resume"]) == 0
    a, b = folder(tmp_path / "full"), folder(tmp_path / "part")
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k] == b[k], k


def test_f32_snapshots_hold_f32_points_and_only_fields_selects(tmp_path, capsys):
    cfg = make_cfg(2, precision="f32", end_time=0.001)
    cfg["output"] = dict(every=0.01, formats=["vtu"], fields=["velocity", "von_mises"], only_fields=True)
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--quiet", "--out", str(tmp_path / "o")]) == 0
    back = io.read_vtu(tmp_path / "o" / "particles_000000.vtu", 2)
    assert sorted(back) == ["velocity", "von_mises", "x"] and back["x"].dtype == np.float32
    cfg["output"]["only_fields"] = False
    path.write_text(yaml.safe_dump(cfg))
    capsys.readouterr()
    assert main(["run", str(path), "--quiet", "--out", str(tmp_path / "o"), "--overwrite", "--profile"]) == 0
    err = capsys.readouterr().err     # --profile: where the time went, one row per kind
    for row in ("total", "first step (compile)", "stepping", "snapshot", "of which vtu",
                "checkpoint", "diagnostics", "the solver waited on the writer"):
        assert re.search(rf"^ +{re.escape(row)}(\s+\([a-z ]+\))? +\d+\.\d\d$", err, flags=re.M), (row, err)
    back = io.read_vtu(tmp_path / "o" / "particles_000000.vtu", 2)
    assert {"stress", "J", "body", "von_mises", "velocity"} <= set(back)   # the standard set, as before


@pytest.mark.parametrize("key,value,words", [
    ("checkpoint_every", 0, "greater than or equal to 1"), ("checkpoint_every", 1.5, "integer"),
    ("checkpoint_every", True, ""), ("writer", "process", "thread"), ("fields", ["spead"], "unknown output field"),
    ("only_fields", "sometimes", "bool")])
def test_output_keys_are_checked_naming_the_key(key, value, words):
    cfg = make_cfg(2)
    cfg["output"] = {key: value}
    with pytest.raises(ConfigError) as e:
        validate(cfg)
    assert f"output.{key}" in str(e.value) and words in str(e.value), str(e.value)


# ---------------------------------------------------------------- a real process killed while the writer is busy
SLOW_WRITER = """
import sys, time
from taichi_mpm.io import files as io
real = io.write_vtu
def slow(*a, **k):
    time.sleep(0.15)          # a slow disk: the queue fills, the writer is busy when the signal comes
    return real(*a, **k)
io.write_vtu = slow
from taichi_mpm.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, pytest.param(signal.SIGTERM, marks=pytest.mark.slow)])
def test_a_run_killed_while_the_writer_is_busy_loses_nothing_and_resumes_bit_for_bit(tmp_path, sig):
    path = scene(tmp_path, end_time=0.3)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-c", SLOW_WRITER, "run", str(path), "--quiet", "--out", str(out)],
                         env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, preexec_fn=lambda: [signal.signal(s, signal.SIG_DFL) for s in (signal.SIGINT,
                                                                                                  signal.SIGTERM)])
    try:
        deadline = time.time() + 120
        while len(list(out.glob("particles_*.vtu"))) < 3:
            assert p.poll() is None and time.time() < deadline, p.stderr.read() if p.poll() is not None else ""
            time.sleep(0.05)
        p.send_signal(sig)
        err = p.communicate(timeout=120)[1]
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    # 128 + sig; 0 when the signal came during the last step (the run then completes; test below)
    assert p.returncode in (128 + sig, 0) and "Traceback" not in err, err
    assert not list(out.rglob(".*.tmp*"))                         # no partial file
    state, meta = io.load_checkpoint(out / io.CHECKPOINT_NAME)    # the stop's state, after every output before it
    series = io.series(out)
    assert len(series) == meta["n_vtu"] == meta["next_output"] >= 3
    for _, f in series:                                           # every snapshot handed over is complete
        assert io.read_vtu(f, 2)["x"].shape == (state["x"].shape[0], 2)
    assert main(["run", str(path), "--quiet", "--out", str(out), "--resume"]) == 0
    assert main(["run", str(path), "--quiet", "--out", str(tmp_path / "full")]) == 0
    a, b = folder(tmp_path / "full"), folder(out)
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k] == b[k], k                                    # bit for bit (deterministic mode)
    same_checkpoint(tmp_path / "full" / io.CHECKPOINT_NAME, out / io.CHECKPOINT_NAME)


@pytest.mark.parametrize("stop_at", [0.02, pytest.param(0.06, marks=pytest.mark.slow)])
def test_a_stop_on_a_step_that_lands_on_an_output_time_keeps_that_output(tmp_path, stop_at):
    """A stop asked during the step that reaches an output time (0.02: mid-run) writes that output before the
    checkpoint; the resumed run then writes every later one, bit for bit as an uninterrupted run. (Before: the
    stop came first, the resumed run aimed at the output after the state's time and skipped this one; seen when
    a SIGTERM landed on such a step.) Asked during the last step (0.06), the run completes: nothing is left to
    do, and a --resume says so and leaves the folder as the uninterrupted run's (no run.lock)."""
    from taichi_mpm.io.runner import Interrupted, Run

    path = scene(tmp_path)
    assert main(["run", str(path), "--quiet", "--out", str(tmp_path / "full")]) == 0
    run = Run(tm.Simulation(tm.load_config(path)), tmp_path / "cut")

    def stop_on_the_step_reaching(s):
        if abs(s.time - stop_at) < 1e-12:
            run.stop_requested = True

    if stop_at < 0.06:
        with pytest.raises(Interrupted):
            run.execute(on_step=stop_on_the_step_reaching)
    else:
        run.execute(on_step=stop_on_the_step_reaching)
    assert run.index == round(stop_at / 0.01) + 1        # the output at stop_at is written
    assert main(["run", str(path), "--quiet", "--out", str(tmp_path / "cut"), "--resume"]) == 0
    a, b = folder(tmp_path / "full"), folder(tmp_path / "cut")
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k] == b[k], k
