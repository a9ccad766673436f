"""The run folder and the operating system (issue 30): links planted in a run folder are never followed, written or
deleted through; operating-system errors (disk full, the file-size limit, a file where a folder goes, malformed CSVs,
a frame size VTK cannot allocate) end in one line naming the file with the documented exit code and the last
checkpoint intact; SIGTERM stops a run as Ctrl-C does; a resume never drops a probe's rows; render refuses
snapshots with non-finite coordinates. The CLI runs in-process (main(argv)) except where a real signal or a
resource limit on a second process is the point. Nothing is written outside tmp_path."""
import errno
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import fast_subset, make_cfg
from taichi_mpm.io import files as io
from taichi_mpm.cli import EXIT_IO, main
from taichi_mpm.io.runner import LOCK_NAME, FolderLock, Interrupted, Run, Simulation

REPO = Path(__file__).resolve().parents[1]


def scene(tmp_path, end_time=0.04, formats=("vtu",), probes=True, **output):
    """The tiny 2D f64 scene of test_run_folder (a block moving onto a slip floor), outputs every 0.02 s, with a
    point probe 'tip' and a wall probe 'floor' (sampled every step), written as scene.yaml."""
    cfg = make_cfg(2, velocity=[0.5, -1.0], lower=[0.3, 0.1], upper=[0.6, 0.4], end_time=end_time)
    cfg["output"] = dict(every=0.02, formats=list(formats), **output)
    if probes:
        cfg["output"].update(probe_every="step", probes=[dict(name="tip", type="point", point=[0.45, 0.4]),
                                                         dict(name="floor", type="wall", face="y_min")])
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def run(capsys, *args):
    """main(args) -> (exit code, stderr), with no traceback and at most one error line."""
    code = main([str(a) for a in args])
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("error:") <= 1, err
    return code, err


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """(scene.yaml, a finished run folder to t = 0.02 with probes and a gif): tests copy the folder."""
    tmp = tmp_path_factory.mktemp("finished")
    path = scene(tmp, end_time=0.02, formats=("vtu", "gif"), render=dict(size=[64, 48]))
    assert main(["run", str(path), "--quiet", "--out", str(tmp / "out")]) == 0
    assert (tmp / "out" / "movie.gif").is_file() and (tmp / "out" / "probes" / "tip.csv").is_file()
    return path, tmp / "out"


def copy_of(finished, tmp_path, name="out"):
    shutil.copytree(finished[1], tmp_path / name, symlinks=True)
    return finished[0], tmp_path / name


class Outside:
    """A folder outside the run folder with files a planted link may point at; `untouched()` checks that every
    one is still there, with its content."""

    NAMES = ("victim.txt", "frame_000000.png", "frame_000001.png", ".record_000000.npz", "tip.csv", "energy.png",
             "probe_tip.png", ".x.tmp1", "movie.gif")

    def __init__(self, tmp_path):
        self.dir = tmp_path / "outside"
        self.dir.mkdir()
        for n in self.NAMES:
            (self.dir / n).write_text(f"precious {n}")
        self.file = self.dir / "victim.txt"

    def untouched(self):
        now = sorted(p.name for p in self.dir.iterdir())
        assert now == sorted(self.NAMES), now
        for n in self.NAMES:
            assert (self.dir / n).read_text() == f"precious {n}", n
        return True


def plant(link: Path, target: Path):
    if link.is_dir() and not link.is_symlink():
        shutil.rmtree(link)
    elif os.path.lexists(link):
        link.unlink()
    link.symlink_to(target)


# ---------------------------------------------------------------- links in a run folder are never followed
# each guarded path under -m slow; the default run keeps a file, a folder and the lock (one guard serves them all)
@pytest.mark.parametrize("name,to_dir", fast_subset(
    [(LOCK_NAME, False), ("probes", True), ("probes/tip.csv", False), ("frames", True), ("movie.gif", False),
     ("diagnostics.csv", False), ("plots", True)], [(LOCK_NAME, False), ("probes", True), ("movie.gif", False)]))
def test_links_in_a_fresh_or_overwritten_run_folder_are_refused_and_nothing_outside_changes(tmp_path, capsys, name,
                                                                                          to_dir):
    """Before: the lock file's target was truncated to the pid, probes/ and probes/tip.csv were written through,
    --overwrite deleted frame_*.png inside a linked frames folder and the movie's target was overwritten."""
    outside = Outside(tmp_path)
    path = scene(tmp_path, formats=("vtu", "gif"), render=dict(size=[64, 48]))
    for args in ([], ["--overwrite"]):
        out = tmp_path / f"out{len(args)}"
        (out / "probes").mkdir(parents=True)
        plant(out / name, outside.dir if to_dir else outside.file)
        code, err = run(capsys, "run", path, "--quiet", "--out", out, *args)
        assert code == EXIT_IO and f"{out / name} is a symbolic link" in err, err
        assert outside.untouched()
        assert (out / name).is_symlink()                          # the link is the user's to remove
        assert not (out / "checkpoint.npz").exists()              # nothing run


@pytest.mark.parametrize("name,to_dir", [("probes/tip.csv", False), ("probes", True), ("frames", True),
                                         ("checkpoint.npz", False), ("movie.gif", False)])
def test_links_meet_on_resume_are_refused(finished, tmp_path, capsys, name, to_dir):
    outside = Outside(tmp_path)
    path, out = copy_of(finished, tmp_path)
    plant(out / name, outside.dir if to_dir else outside.file)
    code, err = run(capsys, "run", path, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.04")
    assert code in (2, EXIT_IO) and str(out / name) in err, err   # a linked checkpoint is an unreadable one: 2
    assert outside.untouched()


@pytest.mark.parametrize("name,to_dir", [("plots", True), ("plots/energy.png", False), ("probes", True),
                                         ("probes/tip.csv", False), ("diagnostics.csv", False)])
def test_plot_never_writes_or_reads_through_a_link(finished, tmp_path, capsys, name, to_dir):
    outside = Outside(tmp_path)
    _, out = copy_of(finished, tmp_path)
    (out / "plots").mkdir(exist_ok=True)
    plant(out / name, outside.dir if to_dir else outside.file)
    code, err = run(capsys, "plot", out)
    assert code == EXIT_IO and f"{out / name} is a symbolic link" in err, err
    assert outside.untouched()


@pytest.mark.parametrize("name,to_dir", [("frames", True), ("frames/frame_000000.png", False), ("movie.gif", False),
                                         ("particles_000001.vtu", False)])
def test_render_never_writes_or_reads_through_a_link(finished, tmp_path, capsys, name, to_dir):
    outside = Outside(tmp_path)
    _, out = copy_of(finished, tmp_path)
    (out / "frames").mkdir(exist_ok=True)
    plant(out / name, outside.dir if to_dir else outside.file)
    code, err = run(capsys, "render", out, "--movie", "gif")
    assert code == EXIT_IO and f"{out / name} is a symbolic link" in err, err
    assert outside.untouched()


def test_io_helpers_replace_links_instead_of_following_them(tmp_path):
    """The helpers every write and delete in a run folder goes through, also against a link planted while a run
    is on (after the first check): a link at the final name is replaced, one at the temporary name removed (not
    followed), a linked folder refused, and removing a link removes the link only."""
    outside = Outside(tmp_path)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    target = run_dir / "diagnostics.csv"
    target.symlink_to(outside.file)
    with io.atomic_write(target, "w") as f:
        f.write("mine")
    assert target.read_text() == "mine" and not target.is_symlink()
    (run_dir / io.temporary_name(run_dir / "c.npz").name).symlink_to(outside.file)   # a guessed temporary name
    io.save_checkpoint(run_dir / "c.npz", {"x": np.zeros(3)}, {"config": {}})
    assert io.load_checkpoint(run_dir / "c.npz")[0]["x"].shape == (3,)
    (run_dir / "frames").symlink_to(outside.dir)
    for call in (lambda: io.ensure_folder(run_dir / "frames", root=run_dir),
                 lambda: io.files_in(run_dir / "frames", "frame_*.png", root=run_dir),
                 lambda: io.atomic_write(run_dir / "frames" / "frame_000000.png", root=run_dir).__enter__(),
                 lambda: io.remove_file(run_dir / "frames" / "frame_000000.png", root=run_dir)):
        with pytest.raises(io.FileError, match="is a symbolic link"):
            call()
    io.remove_file(run_dir / "frames", root=run_dir)
    assert not os.path.lexists(run_dir / "frames")
    (run_dir / LOCK_NAME).symlink_to(outside.file)
    with pytest.raises(io.FileError, match="symbolic link"):
        FolderLock(run_dir)
    (run_dir / LOCK_NAME).unlink()
    os.link(outside.file, run_dir / LOCK_NAME)                     # a hard link: the lock would truncate the file
    with pytest.raises(io.FileError, match="other \\(hard\\) links"):
        FolderLock(run_dir)
    (run_dir / LOCK_NAME).unlink()
    fifo = run_dir / "probes.fifo"
    if hasattr(os, "mkfifo"):
        os.mkfifo(fifo)
        with pytest.raises(io.FileError, match="not a regular file"):
            io.read_regular(fifo)                                   # not a read that blocks forever
    assert outside.untouched()
    assert not list(run_dir.glob(".*.tmp*"))


@pytest.mark.parametrize("planted", fast_subset(["probes/tip.csv", "plots/energy.png", "plots/probe_tip.png"],
                                                ["probes/tip.csv", "plots/energy.png"]))
def test_results_guard_covers_probe_files_and_plots(tmp_path, capsys, planted):
    """Before: probe files (and plots) of an earlier run were replaced by a fresh run without a word."""
    path = scene(tmp_path)
    out = tmp_path / "out"
    (out / Path(planted).parent).mkdir(parents=True)
    (out / planted).write_text("an earlier run's")
    code, err = run(capsys, "run", path, "--quiet", "--out", out)
    assert code == 2 and "already holds a run's results" in err and Path(planted).parent.name in err, err
    assert (out / planted).read_text() == "an earlier run's"
    assert run(capsys, "run", path, "--quiet", "--out", out, "--overwrite")[0] == 0
    assert planted == "probes/tip.csv" or not (out / planted).exists()   # replaced (tip.csv) or removed


def test_config_yaml_is_guarded_and_the_config_a_run_reads_is_never_replaced(tmp_path, capsys):
    """Before: config.yaml was written over whatever held the name: another file in the folder without a word, and
    the config being run when it lived there as config.yaml (`run out/config.yaml --out out`), comments lost, even
    without --overwrite."""
    path = scene(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "config.yaml").write_text("# someone's notes\n")
    code, err = run(capsys, "run", path, "--quiet", "--out", out)
    assert code == 2 and "already holds a run's results (config.yaml)" in err, err
    assert (out / "config.yaml").read_text() == "# someone's notes\n"
    mine = out / "config.yaml"
    text = "# my scene, with comments\n" + path.read_text()
    mine.write_text(text)
    for flags in ([], ["--overwrite"]):
        code, err = run(capsys, "run", mine, "--quiet", "--out", out, *flags)
        assert code == 2 and "is the config file this run reads" in err and "output.dir" in err, err
        assert mine.read_text() == text and not (out / "checkpoint.npz").exists()
    other = tmp_path / "done"
    assert run(capsys, "run", path, "--quiet", "--out", other)[0] == 0
    # a run folder's own config.yaml, run again into its folder: written unchanged, no loss
    assert run(capsys, "run", other / "config.yaml", "--quiet", "--out", other, "--overwrite")[0] == 0


# ---------------------------------------------------------------- operating-system errors: one line, exit 4
def _failing(real, fail_at: int, err=errno.ENOSPC):
    """A stand-in for a writer that fails from its `fail_at`-th call on with an OSError (disk full by default)."""
    calls = []

    def writer(*a, **k):
        calls.append(1)
        if len(calls) >= fail_at:
            raise OSError(err, os.strerror(err))
        return real(*a, **k)
    return writer


def test_disk_full_mid_run_keeps_the_last_checkpoint_and_resume_finishes(tmp_path, capsys, monkeypatch):
    """Before: a traceback (exit 1). Now: one line naming the file and the cause, exit 4, the checkpoint of the last
    complete output valid, and --resume goes on from it to the same results as an uninterrupted run."""
    path = scene(tmp_path, end_time=0.06, checkpoint_every=1)   # a checkpoint at every output, as before
    assert run(capsys, "run", path, "--quiet", "--out", tmp_path / "full")[0] == 0
    out = tmp_path / "out"
    monkeypatch.setattr(io, "vtu_bytes", _failing(io.vtu_bytes, 3))   # the third snapshot (t = 0.04)
    code, err = run(capsys, "run", path, "--quiet", "--out", out)
    assert code == EXIT_IO, err
    assert f"cannot write {out / 'particles_000002.vtu'}: No space left on device" in err
    assert f"the last checkpoint (t=0.02) is {out / 'checkpoint.npz'}" in err and "--resume" in err
    state, meta = io.load_checkpoint(out / "checkpoint.npz")
    assert state["time"] == pytest.approx(0.02) and meta["next_output"] == 2
    assert not list(out.glob(".*.tmp*")) and not (out / LOCK_NAME).exists()
    monkeypatch.undo()
    assert run(capsys, "run", path, "--quiet", "--out", out, "--resume")[0] == 0
    full, part = (io.read_diagnostics(d / io.DIAGNOSTICS_NAME) for d in (tmp_path / "full", out))
    np.testing.assert_allclose(part["time"], full["time"])
    np.testing.assert_allclose(part["total"], full["total"], rtol=1e-12)
    a, b = (io.read_csv_columns(d / "probes" / "tip.csv") for d in (tmp_path / "full", out))
    assert list(a["step"]) == list(b["step"])


@pytest.mark.parametrize("where", fast_subset(["checkpoint", "probe row", "diagnostics row"],
                                              ["checkpoint", "probe row"]))
def test_disk_full_in_any_writer_mid_run_is_exit_4_and_the_checkpoint_stays_valid(tmp_path, capsys, monkeypatch,
                                                                                where):
    path = scene(tmp_path, end_time=0.06)
    out = tmp_path / "out"
    if where == "checkpoint":
        monkeypatch.setattr(io.np, "savez", _failing(np.savez, 2))    # the checkpoint at t = 0.02
        name = out / "checkpoint.npz"
    elif where == "probe row":
        import taichi_mpm.io.probes as probes

        real = probes.Probes._write   # (where rows are written: the run's writer thread)
        calls = []

        def write(self, rows):
            real(self, rows)
            calls.append(1)
            if len(calls) == 5:
                self._files["tip"].close()   # a closed file: the next row's write fails as on a full disk
                self._files["tip"] = _Full(self._files["tip"])
        monkeypatch.setattr(probes.Probes, "_write", write)
        name = out / "probes" / "tip.csv"
    else:
        real_append = io.open_append

        def open_append(p):
            raise io.as_file_error(OSError(errno.EFBIG, os.strerror(errno.EFBIG)), "write", p)
        calls = []

        def counted(p):
            calls.append(1)
            return real_append(p) if len(calls) < 2 else open_append(p)
        monkeypatch.setattr(io, "open_append", counted)
        name = out / io.DIAGNOSTICS_NAME
    code, err = run(capsys, "run", path, "--quiet", "--out", out)
    assert code == EXIT_IO, err
    assert f"cannot write {name}: " in err, err
    state, meta = io.load_checkpoint(out / "checkpoint.npz")        # the last complete checkpoint
    assert state["time"] >= 0.0 and f"(t={state['time']:.6g})" in err
    monkeypatch.undo()
    assert run(capsys, "run", path, "--quiet", "--out", out, "--resume")[0] == 0
    assert io.read_diagnostics(out / io.DIAGNOSTICS_NAME)["time"][-1] == pytest.approx(0.06)


class _Full:
    """A probe file whose writes fail as on a full disk."""

    def __init__(self, f):
        self.f = f

    def write(self, text):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def flush(self):
        pass

    def close(self):
        pass


def test_disk_full_on_resume_is_exit_4_and_leaves_the_checkpoint_as_it_was(finished, tmp_path, capsys, monkeypatch):
    path, out = copy_of(finished, tmp_path)
    before = (out / "checkpoint.npz").read_bytes()
    monkeypatch.setattr(io, "_create_exclusive", _failing(io._create_exclusive, 1))
    code, err = run(capsys, "run", path, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.04")
    assert code == EXIT_IO and "No space left on device" in err and str(out) in err, err
    assert (out / "checkpoint.npz").read_bytes() == before
    monkeypatch.undo()
    assert run(capsys, "run", path, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.04")[0] == 0


def _limited_run(args, limit_bytes, timeout=300):
    """`taichi-mpm ARGS` in a second process whose file-size limit (RLIMIT_FSIZE) is limit_bytes."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    # no kernel cache (its files could pass the limit) and no bytecode written into the checkout
    env = dict(os.environ, PYTHONPATH=str(REPO), TI_OFFLINE_CACHE="0", PYTHONDONTWRITEBYTECODE="1")
    return subprocess.run([sys.executable, "-m", "taichi_mpm", *map(str, args)], env=env, preexec_fn=limit,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout)


@pytest.mark.skipif(not hasattr(os, "fork") or sys.platform == "darwin", reason="RLIMIT_FSIZE on Linux")
def test_file_size_limit_mid_run_and_on_resume_is_exit_4(tmp_path):
    """The real limit (ulimit -f) on a second process: a probe file that grows every step passes it mid-run. Before:
    a traceback (exit 1)."""
    path = scene(tmp_path, end_time=0.2)   # about 150 steps at this CFL number: a 30 kB probe file; checkpoint 14 kB
    out = tmp_path / "out"
    slow = ["--set", "solver.cfl=0.1"]
    r = _limited_run(["run", path, "--quiet", "--out", out, *slow], 20_000)
    assert r.returncode == EXIT_IO and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert "File too large" in r.stderr and "probes" in r.stderr and "the last checkpoint" in r.stderr, r.stderr
    state, _ = io.load_checkpoint(out / "checkpoint.npz")
    assert 0.0 < state["time"] < 0.2
    r = _limited_run(["run", path, "--quiet", "--out", out, "--resume", *slow], 20_000)   # still too small
    assert r.returncode == EXIT_IO and "Traceback" not in r.stderr and "File too large" in r.stderr, r.stderr[-2000:]
    assert io.load_checkpoint(out / "checkpoint.npz")[0]["time"] >= state["time"]


def test_a_file_where_a_folder_goes_is_exit_4_before_anything_runs(finished, tmp_path, capsys):
    """Before: FileExistsError / NotADirectoryError tracebacks from `run` (frames, probes, the output folder itself),
    `render` (frames) and `plot` (plots)."""
    path = scene(tmp_path, formats=("vtu", "png"), render=dict(size=[64, 48]))
    for name in ("frames", "probes"):
        out = tmp_path / f"out_{name}"
        out.mkdir()
        (out / name).write_text("mine")
        code, err = run(capsys, "run", path, "--quiet", "--out", out)
        assert code == EXIT_IO and f"{out / name} is a file, not a folder" in err, err
        assert (out / name).read_text() == "mine" and not (out / "checkpoint.npz").exists()
    (tmp_path / "plain").write_text("mine")                            # --out itself: an input error, as before
    code, err = run(capsys, "run", path, "--quiet", "--out", tmp_path / "plain")
    assert code == 2 and "is a file, not a folder" in err and "output.dir" in err
    _, out = copy_of(finished, tmp_path)
    shutil.rmtree(out / "frames")
    (out / "frames").write_text("mine")
    code, err = run(capsys, "render", out)
    assert code == EXIT_IO and f"{out / 'frames'} is a file, not a folder" in err, err
    assert (out / "frames").read_text() == "mine"
    (out / "plots").write_text("mine")                                  # and `plot`
    code, err = run(capsys, "plot", out)
    assert code == EXIT_IO and f"{out / 'plots'} is a file, not a folder" in err, err
    assert (out / "plots").read_text() == "mine"


@pytest.mark.parametrize("content,words", [
    ("", "is empty"), ("\n\n", "is empty"), ("time [s],step,fx [N/m]\n", "holds no rows"),
    ("time [s],step,fx [N/m]\n0.0,0,1.0\n0.1,1\n", "line 3: 2 values, the header has 3"),
    ("time [s],step,fx [N/m]\n0.0,0,abc\n", "line 2, column 'fx [N/m]': 'abc' is not a number"),
    ("a,b\n1,2\n", "no column 'time [s]'"), (b"\xff\xfe\x00garbage", "")])
def test_empty_or_malformed_probe_csv_in_plot_is_exit_2_naming_the_file(finished, tmp_path, capsys, content, words):
    """Before: IndexError / KeyError tracebacks, or a message without the file."""
    _, out = copy_of(finished, tmp_path)
    f = out / "probes" / "tip.csv"
    f.write_bytes(content if isinstance(content, bytes) else content.encode())
    code, err = run(capsys, "plot", out)
    assert code == 2 and str(f) in err and words in err, err
    assert not (out / "plots").exists()                               # checked before any plot is drawn


@pytest.mark.parametrize("content,words", [("", "is empty"), ("step,total\n0,1\n", "no column 'time'"),
                                           ("time,total\n0,1\nx,2\n", "line 3, column 'time'")])
def test_empty_or_malformed_diagnostics_in_plot_is_exit_2_naming_the_file(finished, tmp_path, capsys, content, words):
    _, out = copy_of(finished, tmp_path)
    shutil.rmtree(out / "probes")
    (out / io.DIAGNOSTICS_NAME).write_text(content)
    code, err = run(capsys, "plot", out)
    assert code == 2 and str(out / io.DIAGNOSTICS_NAME) in err and words in err, err


@pytest.mark.parametrize("size", ["100000x100000", "20000x10", "9000x9000"])
def test_a_frame_size_vtk_cannot_allocate_is_refused_before_vtk(finished, tmp_path, capsys, size):
    """Before: VTK aborted the process (exit 134, no message). The check comes before VTK, and for `run` before
    anything is written."""
    _, out = copy_of(finished, tmp_path)
    shutil.rmtree(out / "frames")
    code, err = run(capsys, "render", out, "--size", size)
    assert code == 2 and "too large to render" in err and "output.render.size" in err, err
    assert not (out / "frames").exists()
    w, h = size.split("x")
    path = scene(tmp_path, formats=("vtu", "png"), render=dict(size=[int(w), int(h)]))
    code, err = run(capsys, "run", path, "--quiet", "--out", tmp_path / "big")
    assert code == 2 and "too large to render" in err and "output.render.size" in err, err
    assert not (tmp_path / "big" / "checkpoint.npz").exists()
    from taichi_mpm.io.render import FrameRenderer

    with pytest.raises(ValueError, match="too large"):
        FrameRenderer({"size": [int(w), int(h)]}, 2, [0, 0], [1, 1])


# ---------------------------------------------------------------- SIGTERM stops a run as Ctrl-C does
def _tiny_run(tmp_path, name, end_time=0.06, resume=False):
    c = make_cfg(2, velocity=[0.5, -1.0], lower=[0.3, 0.1], upper=[0.6, 0.4], end_time=end_time)
    c["output"] = dict(every=0.02, formats=[])
    return Run(Simulation(c), tmp_path / name, resume=resume)


def test_sigterm_stops_between_steps_with_a_checkpoint_and_restores_the_handler_before(tmp_path):
    """Before: SIGTERM's handler ran (here a stand-in that records; by default the process died, exit 143, no
    message). The handlers found before the run, whatever they are, are put back."""
    seen = []

    def before_term(signum, frame):
        seen.append(signum)
    old_term = signal.signal(signal.SIGTERM, before_term)
    old_int = signal.getsignal(signal.SIGINT)
    try:
        run_ = _tiny_run(tmp_path, "out")

        def term_at_step_4(s):
            if s.n_steps == 4:
                os.kill(os.getpid(), signal.SIGTERM)
        with pytest.raises(Interrupted) as e:
            run_.execute(on_step=term_at_step_4)
        assert e.value.signum == signal.SIGTERM and e.value.signal_name == "SIGTERM" and not seen
        assert signal.getsignal(signal.SIGTERM) is before_term and signal.getsignal(signal.SIGINT) is old_int
        state, _ = io.load_checkpoint(tmp_path / "out" / "checkpoint.npz")
        assert state["n_steps"] == 4
        assert not (tmp_path / "out" / LOCK_NAME).exists()
        done = _tiny_run(tmp_path, "out", resume=True).execute()
        assert done.done
    finally:
        signal.signal(signal.SIGTERM, old_term)


def test_an_ignored_signal_stays_ignored_during_a_run(tmp_path):
    """A run started in the background (SIGINT ignored) or under a launcher that ignores SIGTERM does not start
    catching them; the handler is SIG_IGN after the run, as before it."""
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        for s in old:
            signal.signal(s, signal.SIG_IGN)

        def both_at_step_2(sim):
            if sim.n_steps == 2:
                os.kill(os.getpid(), signal.SIGTERM)
                os.kill(os.getpid(), signal.SIGINT)
        try:
            assert _tiny_run(tmp_path, "out", end_time=0.02).execute(on_step=both_at_step_2).done
        except Interrupted as e:   # a KeyboardInterrupt: it would end the pytest session
            pytest.fail(f"an ignored signal stopped the run: {e}")
        assert all(signal.getsignal(s) == signal.SIG_IGN for s in old)
    finally:
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


def test_sigterm_in_the_cli_is_one_line_exit_143_and_resume_continues(tmp_path, capsys, monkeypatch):
    from taichi_mpm import cli

    seen = []
    old_term = signal.signal(signal.SIGTERM, lambda s, f: seen.append(s))
    try:
        calls = []

        def clock(self, sim):
            calls.append(1)
            if len(calls) == 3:
                os.kill(os.getpid(), signal.SIGTERM)
        monkeypatch.setattr(cli._StepClock, "__call__", clock)
        path, out = scene(tmp_path, end_time=0.04), tmp_path / "out"
        code, err = run(capsys, "run", path, "--quiet", "--out", out)
        assert code == 143 and not seen, err
        assert "stopped by SIGTERM: stopped at step 3" in err and str(out / "checkpoint.npz") in err and \
            "--resume" in err
        monkeypatch.undo()
        assert run(capsys, "run", path, "--quiet", "--out", out, "--resume")[0] == 0
    finally:
        signal.signal(signal.SIGTERM, old_term)


@pytest.mark.slow
def test_sigterm_to_a_real_run_process(tmp_path):
    """The real thing: `kill PID` on a running `taichi-mpm run` (default SIGTERM handler, stdin closed)."""
    path, out = scene(tmp_path, end_time=100.0, probes=False), tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    # SIGTERM as a shell's `kill` meets it, whatever this test process inherited (a launcher may ignore it)
    p = subprocess.Popen([sys.executable, "-m", "taichi_mpm", "run", str(path), "--quiet", "--out", str(out)],
                         env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, preexec_fn=lambda: signal.signal(signal.SIGTERM, signal.SIG_DFL))
    try:
        deadline = time.time() + 240
        while not (out / "checkpoint.npz").exists():
            assert p.poll() is None and time.time() < deadline
            time.sleep(0.2)
        p.send_signal(signal.SIGTERM)
        err = p.communicate(timeout=120)[1]
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == 143 and "stopped by SIGTERM" in err and "Traceback" not in err, err
    assert io.load_checkpoint(out / "checkpoint.npz")[0]["time"] > 0


# ---------------------------------------------------------------- a resume never drops a probe's rows
@pytest.mark.parametrize("change,key", [({"type": "wall", "face": "y_min", "point": None}, "type"),
                                        ({"point": [0.35, 0.2]}, "point")])
def test_resume_with_a_changed_probe_is_refused_and_its_rows_kept(finished, tmp_path, capsys, change, key):
    """Before: a probe changed from point to wall lost its earlier rows without a word (another header), and a moved
    point probe mixed two particles in one file."""
    path, out = copy_of(finished, tmp_path)
    cfg = yaml.safe_load(path.read_text())
    cfg["output"]["probes"][0].update(change)
    cfg["output"]["probes"][0] = {k: v for k, v in cfg["output"]["probes"][0].items() if v is not None}
    changed = tmp_path / "changed.yaml"
    changed.write_text(yaml.safe_dump(cfg, sort_keys=False))
    before = {f.relative_to(out): f.read_bytes() for f in out.rglob("*") if f.is_file()}
    code, err = run(capsys, "run", changed, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.04")
    assert code == 2 and str(out / "probes" / "tip.csv") in err and f"key 'output.probes.0.{key}'" in err, err
    assert "rows of the probe 'tip'" in err and "new name" in err
    after = {f.relative_to(out): f.read_bytes() for f in out.rglob("*") if f.is_file()}
    assert after == before                                             # nothing written
    cfg["output"]["probes"][0]["name"] = "tip2"                        # the way out the message gives
    changed.write_text(yaml.safe_dump(cfg, sort_keys=False))
    assert run(capsys, "run", changed, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.04")[0] == 0
    assert (out / "probes" / "tip.csv").read_bytes() == before[Path("probes/tip.csv")]
    assert 0.02 < io.read_csv_columns(out / "probes" / "tip2.csv")["time [s]"][0] < 0.04   # from the resumed time on


def test_resume_refuses_a_probe_file_with_another_header(finished, tmp_path, capsys):
    path, out = copy_of(finished, tmp_path)
    f = out / "probes" / "floor.csv"
    text = f.read_text().replace("fy [N/m]", "fz [N/m]", 1)
    f.write_text(text)
    code, err = run(capsys, "run", path, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.04")
    assert code == 2 and str(f) in err and "another header" in err, err
    assert f.read_text() == text


# ---------------------------------------------------------------- render refuses non-finite coordinates
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_render_of_a_snapshot_with_non_finite_coordinates_is_exit_2_naming_it(finished, tmp_path, capsys, bad):
    """Before: rendered without a word (the NaN particles vanished, an infinite one broke the camera)."""
    import meshio

    _, out = copy_of(finished, tmp_path)
    shutil.rmtree(out / "frames")
    f = out / "particles_000001.vtu"
    m = meshio.read(f)
    m.points[[0, 3]] = bad
    meshio.write(f, m, file_format="vtu", binary=True)
    code, err = run(capsys, "render", out, "--movie", "gif")
    assert code == 2 and str(f) in err and "2 of" in err and "non-finite" in err, err
    assert not (out / "frames").exists()
