"""The run folder (issue 9): where a run may write, one writer at a time, nothing of an earlier run replaced unasked,
no temporary files left behind, and every corrupt input read back (checkpoint on --resume, .pvd / .vtu in render)
an exit 2 naming the file. The CLI runs in-process (main(argv)) except where a second process is the point."""
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

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm.io import files as io
from taichi_mpm.cli import main
from taichi_mpm.config import ConfigError
from taichi_mpm.io.runner import LOCK_NAME, FolderLock

REPO = Path(__file__).resolve().parents[1]


def scene(tmp_path, end_time=0.04, **top):
    """The tiny 2D f64 scene of test_cli (a block moving onto a slip floor), 3 outputs, written as scene.yaml."""
    cfg = make_cfg(2, velocity=[0.5, -1.0], lower=[0.3, 0.1], upper=[0.6, 0.4], end_time=end_time)
    cfg["output"] = dict(every=0.02, formats=["vtu"])
    cfg.update(top)
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """(scene.yaml, a run folder holding that scene's finished run to t = 0.02): tests copy the folder."""
    tmp = tmp_path_factory.mktemp("finished")
    path = scene(tmp, end_time=0.02)
    assert main(["run", str(path), "--quiet", "--out", str(tmp / "out")]) == 0
    return path, tmp / "out"


def copy_of(finished, tmp_path, name="out"):
    shutil.copytree(finished[1], tmp_path / name)
    return finished[0], tmp_path / name


def run(capsys, *args):
    """main(args) -> (exit code, stderr)."""
    code = main([str(a) for a in args])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


# ---------------------------------------------------------------- where a run writes
@pytest.mark.parametrize("name", ["..", ".", "a/b", "../x", "a\\b", "a\x00b", "tab\there", ".hidden", "", " x", "x ",
                                  "x" * 101])
def test_run_names_that_are_not_plain_folder_names_are_refused(name):
    """name becomes runs/NAME: before, `..` wrote (and deleted old snapshots) in the working directory."""
    with pytest.raises(ConfigError) as e:
        tm.load_config(make_cfg() | {"name": name})
    assert e.value.key == "name" and "plain folder name" in str(e.value)


@pytest.mark.parametrize("name", ["test", "a-b_c.d", "é", "x" * 100, "Run 2"])
def test_plain_names_stay_valid(name):
    assert tm.load_config(make_cfg() | {"name": name}).name == name


def test_run_named_dotdot_writes_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    path = scene(tmp_path, name="..")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    code, err = run(capsys, "run", path, "--quiet")
    assert code == 2 and "key 'name'" in err and err.count("error:") == 1
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_nul_in_the_output_folder_is_a_config_error(tmp_path, capsys):
    code, err = run(capsys, "run", scene(tmp_path), "--quiet", "--out", str(tmp_path / "a\x00b"))
    assert code == 2 and "output folder" in err


# ---------------------------------------------------------------- one writer, nothing replaced unasked
def test_second_writer_is_refused_while_the_first_holds_the_folder(tmp_path, capsys):
    """flock locks conflict between two open files even in one process, so a held FolderLock stands for a run
    in another process (test_killed_run_... below uses a real second process)."""
    out = tmp_path / "out"
    out.mkdir()
    held = FolderLock(out)
    assert (out / LOCK_NAME).read_text() == str(os.getpid())
    code, err = run(capsys, "run", scene(tmp_path), "--quiet", "--out", out)
    assert code == 2 and f"another run (pid {os.getpid()}) is writing into {out}" in err
    assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME]   # nothing written by the refused run
    held.release()
    assert not (out / LOCK_NAME).exists()
    assert run(capsys, "run", scene(tmp_path), "--quiet", "--out", out)[0] == 0
    assert not (out / LOCK_NAME).exists()                          # released at the end of the run


@pytest.mark.slow
def test_rerun_into_a_folder_with_results_needs_overwrite_or_resume(finished, tmp_path, capsys):
    path, out = copy_of(finished, tmp_path)
    mtime = (out / "checkpoint.npz").stat().st_mtime_ns
    (out / "notes.txt").write_text("mine")
    code, err = run(capsys, "run", path, "--quiet", "--out", out)
    assert code == 2 and "already holds a run's results" in err and "--overwrite" in err and "--resume" in err
    assert (out / "checkpoint.npz").stat().st_mtime_ns == mtime
    code, err = run(capsys, "run", path, "--quiet", "--out", out, "--resume", "--overwrite")
    assert code == 2 and "not allowed with argument" in err
    assert run(capsys, "run", path, "--quiet", "--out", out, "--overwrite")[0] == 0
    assert (out / "notes.txt").read_text() == "mine"                # only the run's own files are replaced
    sim = tm.Simulation(tm.load_config(path))
    with pytest.raises(ConfigError, match="already holds"):
        sim.run(out_dir=out)                                         # the API says the same
    sim.run(out_dir=out, overwrite=True)                             # and the refusal left the folder free
    assert not (out / LOCK_NAME).exists()


@pytest.mark.slow
def test_leftover_temporary_files_are_removed_and_others_kept(finished, tmp_path, capsys):
    """A killed run can leave `.NAME.tmpPID` files of io's atomic writes; the next run holding the lock removes
    them (and only them)."""
    path, out = copy_of(finished, tmp_path)
    (out / "probes").mkdir()
    planted = [out / ".checkpoint.npz.tmp4242", out / ".particles_000003.vtu.tmp7", out / "probes" / ".tip.csv.tmp1"]
    kept = [out / ".keep", out / "notes.tmp1", out / ".x.tmp"]
    for f in planted + kept:
        f.write_text("x")
    assert run(capsys, "run", path, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.04")[0] == 0
    assert not any(f.exists() for f in planted) and all(f.exists() for f in kept)
    assert not list(out.rglob(".*.tmp[0-9]*"))


# ---------------------------------------------------------------- corrupt inputs read back
def _corrupt(kind, ck: Path):
    good = ck.read_bytes()
    z = dict(np.load(ck))
    if kind == "garbage":
        ck.write_bytes(b"not a checkpoint" * 10)
    elif kind == "truncated":
        ck.write_bytes(good[: len(good) // 2])
    elif kind == "empty":
        ck.write_bytes(b"")
    elif kind == "no metadata":
        del z["__meta__"]
        np.savez(ck, **z)
    elif kind == "bad metadata":
        z["__meta__"] = np.array("{not json")
        np.savez(ck, **z)
    elif kind == "pickled":
        z["x"] = np.array([object()], dtype=object)
        np.savez(ck, **z)
    elif kind == "wrong shape":
        z["F"] = z["F"][:, :1]
        np.savez(ck, **z)
    elif kind == "fewer particles":
        for k in ("x", "v", "F"):
            z[k] = z[k][:-1]
        np.savez(ck, **z)
    elif kind == "no positions":
        del z["x"]
        np.savez(ck, **z)
    elif kind == "nan":
        z["x"] = z["x"] * np.nan
        np.savez(ck, **z)
    elif kind == "directory":
        ck.unlink()
        ck.mkdir()


CORRUPT = ["garbage", "truncated", "empty", "no metadata", "bad metadata", "pickled", "wrong shape",
           "fewer particles", "nan", "directory"]


def test_corrupt_truncated_or_mismatched_checkpoint_exits_2_naming_the_file(finished, tmp_path, capsys):
    for kind in CORRUPT + ["no positions"]:
        path, out = copy_of(finished, tmp_path, kind.replace(" ", "_"))
        _corrupt(kind, out / "checkpoint.npz")
        code, err = run(capsys, "run", path, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.04")
        assert code == 2 and str(out / "checkpoint.npz") in err and err.count("error:") == 1, (kind, err)
        assert not (out / "particles_000002.vtu").exists(), kind    # nothing run, nothing written


@pytest.mark.slow
def test_changed_output_every_is_followed_on_resume(finished, tmp_path, capsys):
    """Before, the checkpoint's interval silently won; output.* may change on --resume (docs/contract.md)."""
    path, out = copy_of(finished, tmp_path)
    code, err = run(capsys, "run", path, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.04",
                    "--set", "output.every=0.005")
    assert code == 0 and "output.every changed from 0.02 to 0.005" in err
    times = io.read_diagnostics(out / io.DIAGNOSTICS_NAME)["time"]
    np.testing.assert_allclose(times, [0, 0.02, 0.025, 0.03, 0.035, 0.04], atol=1e-12)


def test_corrupt_series_or_snapshot_in_render_exits_2_naming_the_file(finished, tmp_path, capsys):
    """Found before any frame is drawn, so no display is needed."""
    out = copy_of(finished, tmp_path)[1]
    pvd, vtu = out / io.PVD_NAME, out / "particles_000001.vtu"
    good_pvd = pvd.read_text()
    cases = [(vtu, b"<VTKFile garbage"), (vtu, b""), (pvd, b"<VTKFile><Coll"),
             (pvd, good_pvd.replace('file="particles_000001.vtu"', 'file="../../etc/passwd"').encode()),
             (pvd, good_pvd.replace('timestep="0.0"', 'timestep="soon"').encode())]
    for f, content in cases:
        saved = f.read_bytes()
        f.write_bytes(content)
        code, err = run(capsys, "render", out, "--movie", "gif")
        assert code == 2 and str(f) in err and err.count("error:") == 1, (f.name, content[:20], err)
        assert not (out / "frames").exists() and not (out / "movie.gif").exists()
        f.write_bytes(saved)


@pytest.mark.parametrize("key,value", [("camera", "bogus"), ("color_by", "bogus"), ("color_by", "sxw"),
                                       ("colormap", "no_such_map")])
def test_bogus_render_options_fail_validation(key, value):
    """Before, they passed validation (a 2D run ignored a bogus camera; a bogus colour field failed at the first
    frame, after the simulation had started)."""
    cfg = make_cfg()
    cfg["output"] = dict(render={key: value})
    with pytest.raises(ConfigError) as e:
        tm.load_config(cfg)
    assert e.value.key == f"output.render.{key}" and value in str(e.value)


# ---------------------------------------------------------------- a real second process, killed
@pytest.mark.slow
def test_killed_run_releases_the_folder_and_resume_cleans_up(tmp_path, capsys):
    """A run in another process holds the folder (a second writer exits 2); killed with SIGKILL it leaves its lock
    file behind, but the OS has released the lock: --resume continues and removes the leftovers."""
    out, path = tmp_path / "out", scene(tmp_path, end_time=100.0)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    first = subprocess.Popen([sys.executable, "-m", "taichi_mpm", "run", str(path), "--quiet", "--out", str(out)],
                             env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 240
        while not (out / "checkpoint.npz").exists():
            assert first.poll() is None and time.time() < deadline
            time.sleep(0.2)
        code, err = run(capsys, "run", path, "--quiet", "--out", out, "--overwrite")
        assert code == 2 and f"another run (pid {first.pid})" in err
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait()
    assert (out / LOCK_NAME).exists()
    (out / ".diagnostics.csv.tmp99999").write_text("half")
    code, err = run(capsys, "run", path, "--quiet", "--out", out, "--resume", "--set", "solver.end_time=0.1")
    assert code == 0 and not list(out.glob(".*.tmp*")) and not (out / LOCK_NAME).exists()


# ---------------------------------------------------------------- hostile YAML, an arch this machine lacks
ALIAS_BOMB = "l0: &l0 [x]\n" + "".join(f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]\n" for i in range(1, 9))


@pytest.mark.parametrize("text,words", [
    (ALIAS_BOMB + "name: x\n", "expands to more than"),            # 9^8 = 43 million values if walked
    ("name: " + "[" * 3000 + "]" * 3000 + "\n", "nested too deeply"),
    ("".join("  " * i + f"k{i}:\n" for i in range(1500)), "nested too deeply"),
])
def test_alias_bomb_and_deep_nesting_exit_2(tmp_path, capsys, text, words):
    """Before: MemoryError / RecursionError tracebacks."""
    (tmp_path / "hostile.yaml").write_text(text)
    code, err = run(capsys, "validate", tmp_path / "hostile.yaml")
    assert code == 2 and words in err and "hostile.yaml" in err and err.count("error:") == 1


def test_validate_refuses_an_arch_this_machine_lacks(tmp_path, capsys):
    """`run` refuses it (tests/test_reproducibility.py); `validate` used to say the config was fine."""
    from taichi_mpm.solver import GPU_ARCHS, available_archs

    missing = [a for a in GPU_ARCHS if a not in available_archs()]
    if not missing:
        pytest.skip("every GPU arch is available here")
    code, err = run(capsys, "validate", scene(tmp_path), "--arch", missing[0])
    assert code == 2 and f"arch {missing[0]} is not available" in err and "key 'arch'" in err
