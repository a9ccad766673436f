"""Running a simulation to its end time while writing outputs (the CLI's `run` and `sim.run()`).

`Run(sim, out_dir)` owns an output directory (layout in docs/contract.md). Called with a Simulation it writes
one output (snapshot, diagnostics row, frame, checkpoint), so it works as `sim.run(on_output=run)`;
`run.execute()` drives the steps itself, which adds progress callbacks, a clean stop on Ctrl-C and
bit-for-bit resumption from checkpoint.npz.

Outputs are written at the start and then at the times k * output.every (and at end_time): the next
output time is the first such time after the current time. The checkpoint is rewritten every
output.checkpoint_every outputs, at the first and the last, on a stop (Ctrl-C, SIGTERM) and after a numerical
failure (the state of the last output, held in memory until then), so the last good state is on disk. A resumed run
takes the same steps as the uninterrupted one: the step loop below depends only on the state the
checkpoint holds (positions, velocities, F, C, time, step count and the CFL speed estimate).

The files are written by io.writer.Writer (output.writer: a thread while the solver steps, or inline): each output
hands it numpy copies of what the files need, in order, and the writer is drained before a stop is reported and
before the run returns. Called as an observer (outside execute) each output is drained at once.
"""
from __future__ import annotations

import errno
import math
import os
import re
import signal
import stat
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from . import files as io, probes
from .writer import Writer
from ..config import Config, ConfigError
from ..errors import InstabilityError
from ..solver import Simulation as _Simulation

# keys that may differ between a checkpoint and the config it resumes with
RESUMABLE_CHANGES = ("name", "arch", "solver.end_time", "solver.max_steps", "output", "limits")


LOCK_NAME = "run.lock"
# temporary files of io's atomic writes (".NAME.tmpPID", a movie's ".NAME.tmpPID.mp4"): complete files are renamed
# over the real ones, so any such file in a run folder held by this run's lock is left over from a killed run
_TEMPORARY = re.compile(r"\..+\.tmp\d+(\.[A-Za-z0-9]+)?")
# the signals a run stops on cleanly (checkpoint written, Interrupted raised); exit code 128 + the signal's number
STOP_SIGNALS = (signal.SIGINT,) + ((signal.SIGTERM,) if hasattr(signal, "SIGTERM") else ())


class FolderLock:
    """One writer per run folder: an exclusive advisory lock (flock) on RUN_DIR/run.lock, which holds the owner's
    pid. The operating system releases it when the process ends, however it ends, so a file left by a killed run
    is no obstacle (the next run takes it over and removes it). Where flock does not exist (Windows), no lock.
    The file is created exclusively or opened as it is, never through a link (O_NOFOLLOW) and never a FIFO or
    device (O_NONBLOCK, then checked): a link or special file there is an io.FileError."""

    def __init__(self, folder: Path):
        self.path = Path(folder) / LOCK_NAME
        self.fd = None
        try:
            import fcntl
        except ImportError:
            return
        flags = os.O_RDWR | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
        while True:
            try:
                try:
                    fd = os.open(self.path, flags | os.O_CREAT | os.O_EXCL, 0o644)
                except FileExistsError:
                    fd = os.open(self.path, flags)   # a lock file of a run before (or of the run holding it)
            except FileNotFoundError:   # removed between the two opens by the run that held it: once more
                continue
            except OSError as e:
                if os.path.islink(self.path) or e.errno == errno.ELOOP:
                    raise io.FileError(f"{self.path} is a symbolic link (to {io._link_target(self.path)}): the lock file "
                                       f"is never opened through a link; remove it", self.path) from None
                raise io.as_file_error(e, "create the lock file", self.path) from None
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode) or st.st_nlink > 1:   # a hard link's other names are not the run's
                os.close(fd)
                what = "not a regular file" if not stat.S_ISREG(st.st_mode) else "a file with other (hard) links"
                raise io.FileError(f"{self.path} is {what}: remove it (it is the run's lock file, which is "
                                   f"truncated and written)", self.path)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                try:
                    owner = os.read(fd, 32).decode(errors="replace").strip() or "?"
                finally:
                    os.close(fd)
                raise ConfigError(f"another run (pid {owner}) is writing into {self.path.parent}: wait for it to end, "
                                  f"or give this run another output folder (--out DIR or output.dir)") from None
            try:  # the holder before us may have removed the file between our open and flock: lock the file there
                same = os.path.samestat(os.fstat(fd), os.lstat(self.path))
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        try:
            os.ftruncate(fd, 0)
            os.write(fd, str(os.getpid()).encode())
        except OSError as e:
            os.close(fd)
            raise io.as_file_error(e, "write", self.path) from None
        self.fd = fd

    def release(self):
        if self.fd is not None:
            try:  # only the file this lock holds (not one put in its place)
                if os.path.samestat(os.fstat(self.fd), os.lstat(self.path)):
                    os.unlink(self.path)
            except OSError:
                pass
            os.close(self.fd)  # closing releases the flock
            self.fd = None

    __del__ = release


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (SIGINT) or SIGTERM stopped a run between two steps; the checkpoint holds the state at that moment.
    `signum` is the signal (the CLI exits with 128 + signum: 130, 143)."""

    def __init__(self, run: "Run", signum: int = signal.SIGINT):
        self.run, self.signum = run, int(signum)
        super().__init__(f"stopped at step {run.sim.n_steps}, t={run.sim.time:.6g}; the checkpoint is "
                         f"{run.out_dir / io.CHECKPOINT_NAME} (continue with --resume)")

    @property
    def signal_name(self) -> str:
        try:
            return signal.Signals(self.signum).name
        except ValueError:
            return f"signal {self.signum}"


def output_dir(cfg: Config, out=None) -> Path:
    if out is not None:
        return Path(out)
    try:
        return Path(cfg.output.dir.format(name=cfg.name))
    except (KeyError, IndexError, ValueError) as e:
        raise ConfigError(f"cannot expand {cfg.output.dir!r} ({e!r}); the only placeholder is {{name}}",
                          key="output.dir") from None


def _flat(d, prefix=""):
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flat(v, key + "."))
        else:
            out[key] = v
    return out


def config_changes(old: dict, new: dict) -> list[str]:
    """Dotted keys whose values differ, other than those a resumed run may change."""
    a, b = _flat(old), _flat(new)
    keys = sorted(set(a) | set(b))
    return [k for k in keys if a.get(k) != b.get(k)
            and not any(k == p or k.startswith(p + ".") for p in RESUMABLE_CHANGES)]


class Run:
    """Writes a simulation's outputs into `out_dir` (default: output.dir of the config)."""

    # every kind of result: what a fresh run refuses to replace without --overwrite, and what --overwrite removes
    STALE = ("particles_*.vtu", "particles_*.npz", io.PVD_NAME, io.DOMAINS_PVD, io.DIAGNOSTICS_NAME,
             io.CHECKPOINT_NAME, "frames/frame_*.png", "frames/.record_*.npz", "movie.mp4", "movie.gif", f"{probes.PROBES_DIR}/*.csv",
             "plots/probe_*.png", "plots/energy.png", io.CONFIG_NAME)

    def __init__(self, sim, out_dir=None, formats=None, every: Optional[float] = None, resume: bool = False,
                 log: Optional[Callable[[str], None]] = None, overwrite: bool = False):
        self.sim, self.cfg = sim, sim.cfg
        self.out_dir = output_dir(self.cfg, out_dir)
        self.formats = list(self.cfg.output.formats if formats is None else formats)
        self.every = float(every or self.cfg.output.every)
        self.fields = list(self.cfg.output.fields)
        self.only_fields = bool(self.cfg.output.only_fields)
        self.dtype = np.float32 if self.cfg.precision == "f32" else np.float64   # snapshot floats: the run's own
        self.checkpoint_every = int(self.cfg.output.checkpoint_every)
        self.log = log or (lambda msg: print(msg, file=sys.stderr))
        self.index = 0           # number of the next output
        self.last_time = None    # time of the last output written
        self._rows = 0           # rows in diagnostics.csv
        self.entries = []        # (time, file) of the VTU series (handed to the writer)
        self.entries_written = []  # (the writer's) those whose VTU is on disk: what particles.pvd lists
        self.stop_requested = False
        self.stop_signal = None  # the signal that asked for the stop
        self.checkpoint_time = None  # time of the state checkpoint.npz holds (None: none written by this run yet)
        self._held = None        # (state, meta) of the last output while its checkpoint is not written
        self._executing = False  # in execute(): outputs are drained at its end, not one by one
        self.output_seconds = 0.0  # wall time spent writing outputs (the CLI's summary keeps it apart from stepping)
        self._renderer = None    # render.FrameRecorder: frames are rendered at the end of the run
        self.render_seconds = 0.0  # wall time of rendering frames and movies (part of output_seconds)
        self.frames_rendered = 0
        self._movie_done = False  # movie.mp4 was fed by the frame worker during the run
        self.frames_while_stepping = False  # the frames were drawn by the frame worker (io/live_frames.py)
        self._frames = any(f in self.formats for f in ("png", "mp4", "gif"))
        if resume and overwrite:
            raise ConfigError("--resume continues a run's results and --overwrite replaces them: give one")
        if self._frames:  # before anything is written: VTK aborts the process on a size it cannot allocate
            from .render import check_size

            try:
                check_size(self.cfg.output.render.size)
            except ValueError as e:
                raise ConfigError(str(e), key="output.render.size") from None
            try:   # here: a mapped grid's geometry may use Taichi, which the writer thread never calls
                from .render import grid_lines
            except ImportError:
                self._lines = None   # (the first output says the renderer is not available)
            else:
                self._lines = grid_lines(self.cfg)
        try:
            if os.path.lexists(self.out_dir) and not self.out_dir.is_dir():  # what the user gave: an input error
                raise ConfigError(f"{self.out_dir} is a file, not a folder: give the run another output folder "
                                  f"(--out DIR or output.dir)", key="output.dir")
            self.out_dir.mkdir(parents=True, exist_ok=True)
        except ValueError as e:  # a NUL character in --out or output.dir
            raise ConfigError(f"cannot use {str(self.out_dir)!r} as the output folder: {e}", key="output.dir") from None
        except OSError as e:
            raise io.as_file_error(e, "create the output folder", self.out_dir) from None
        self.lock = FolderLock(self.out_dir)
        self.writer = Writer(threaded=self.cfg.output.writer == "thread")
        try:
            io.refuse_links(self.out_dir)  # nothing is written, read or deleted through a link (docs/reliability.md)
            self._remove_temporaries()
            if resume:
                self._restore()
            else:
                self._fresh(overwrite)
            for folder, used in ((probes.PROBES_DIR, bool(self.cfg.output.probes)), ("frames", self._frames)):
                if used:  # a file where the folder goes: said now, not at the first output
                    io.ensure_folder(self.out_dir / folder, root=self.out_dir)
            io.write_config(self.out_dir / io.CONFIG_NAME, self.cfg)
            self.probes = probes.Probes(sim, self.out_dir, resume=resume,  # probes/NAME.csv (output.probes)
                                        submit=lambda fn, *a: self.writer.submit("probes", fn, *a))
        except BaseException:  # a refused resume or overwrite leaves the folder free at once
            self.writer.close()
            self.lock.release()
            raise

    # ------------------------------------------------------------ set-up
    def _remove_temporaries(self):
        """Temporary files a killed run left (with the lock held, no other writer can own one)."""
        for folder in (self.out_dir, self.out_dir / probes.PROBES_DIR, self.out_dir / "frames", self.out_dir / "plots"):
            for f in io.files_in(folder, ".*.tmp*", root=self.out_dir):
                if _TEMPORARY.fullmatch(f.name) and not f.is_dir():
                    io.remove_file(f, root=self.out_dir)

    def _matching(self, pattern: str) -> list[Path]:
        """The run folder's entries matching a STALE pattern ("NAME*" or "FOLDER/NAME*"), links not followed."""
        folder, _, name = pattern.rpartition("/")
        return io.files_in(self.out_dir / folder if folder else self.out_dir, name, root=self.out_dir)

    def held(self) -> list[str]:
        """The results of an earlier run in the output folder (what a fresh run would replace)."""
        return [p for p in self.STALE if self._matching(p)]

    def _refuse_replacing_the_input(self):
        """A fresh run writes config.yaml into its folder: never over the config file it reads (a config kept as
        config.yaml in the output folder would lose its comments and layout; --overwrite included). A file the
        run would write unchanged (re-running a run folder's own config.yaml) is no loss."""
        target, source = self.out_dir / io.CONFIG_NAME, self.cfg._source
        try:
            same = bool(source) and target.is_file() and not target.is_symlink() and os.path.samefile(source, target)
            if not same or target.read_text() == io.config_text(self.cfg):
                return
        except (OSError, UnicodeDecodeError):
            return   # unreadable: the write reports it
        raise ConfigError(f"{target} is the config file this run reads, and the run writes its resolved config to "
                          f"that name (replacing your file, its comments included): keep the config outside the "
                          f"output folder or give it another name", key="output.dir")

    def _fresh(self, overwrite: bool = False):
        self._refuse_replacing_the_input()
        held = self.held()
        if held and not overwrite:
            raise ConfigError(f"{self.out_dir} already holds a run's results ({', '.join(held[:4])}"
                              f"{', ...' if len(held) > 4 else ''}): add --resume to continue that run or "
                              f"--overwrite to replace its results")
        for pattern in self.STALE:
            for f in self._matching(pattern):
                io.remove_file(f, root=self.out_dir)
        self.diagnostics = io.Diagnostics(self.out_dir / io.DIAGNOSTICS_NAME, self.sim.dim)

    def _restore(self):
        path = self.out_dir / io.CHECKPOINT_NAME
        if not path.is_file():
            raise ConfigError(f"--resume: no checkpoint to resume from ({path} does not exist)")
        state, meta = io.load_checkpoint(path)  # a corrupt file: ConfigError naming it
        changed = config_changes(meta.get("config", {}), io.config_dict(self.cfg))
        if changed:
            old, new = _flat(meta.get("config", {})), _flat(io.config_dict(self.cfg))
            k = changed[0]
            raise ConfigError(f"--resume: the checkpoint in {self.out_dir} was written with {k}={old.get(k)!r}, "
                              f"the config now has {new.get(k)!r}; only solver.end_time, solver.max_steps and "
                              f"output.* may change when resuming", key=k)
        held = getattr(state.get("x"), "shape", (None,))[:1] or (None,)
        if held[0] != self.sim.n:
            raise ConfigError(f"--resume: {path} holds {held[0]} particle positions, the scene {self.sim.n} particles")
        end, t_state = self.cfg.solver.end_time, _scalar(state.get("time"))
        if t_state is not None and t_state > end * (1 + 1e-12):
            raise ConfigError(f"--resume: the checkpoint in {self.out_dir} is at t={t_state:.6g}, after "
                              f"solver.end_time={end:g}; a resumed run continues forward: set solver.end_time "
                              f"above {t_state:.6g} (or start a fresh run without --resume)",
                              key="solver.end_time")
        # a probe whose file holds rows must still be the probe that wrote them (checked before anything is written)
        probes.check_resume(self.cfg, self.out_dir, meta.get("config", {}), self.sim.dim)
        try:
            self.sim.set_state(state)  # checks every array before applying any
        except (ValueError, TypeError, KeyError) as e:
            raise ConfigError(f"--resume: {path} does not fit this scene ({e})") from None
        self.checkpoint_time = self.sim.time
        self.index = int(meta.get("next_output", 0))
        old_every = meta.get("every")
        if isinstance(old_every, (int, float)) and not math.isclose(old_every, self.every, rel_tol=1e-12):
            self.log(f"note: output.every changed from {old_every:g} to {self.every:g} s on --resume: the outputs "
                     f"after t={self.sim.time:g} follow the new interval")
        self.entries = [e for e in io.read_pvd(self.out_dir / io.PVD_NAME)][: int(meta.get("n_vtu", 0))]
        self.entries_written = list(self.entries)
        self.diagnostics = io.Diagnostics(self.out_dir / io.DIAGNOSTICS_NAME, self.sim.dim,
                                          keep=int(meta.get("n_rows", 0)))
        self._rows = int(meta.get("n_rows", 0))
        self.last_time = meta.get("last_time")

    # ------------------------------------------------------------ one output
    def __call__(self, sim=None):
        """Write one output of the current state (observer for Simulation.run(on_output=...)). What the files need
        is read from the solver here (numpy copies: later steps cannot change them); the files are written by
        the writer (a thread while the solver steps, output.writer)."""
        sim = self.sim if sim is None else sim
        t0 = time.perf_counter()
        name = io.SNAPSHOT.format(self.index)
        if "vtu" in self.formats or "npz" in self.formats or self._frames:
            self.writer.submit("snapshot", self._write_snapshot, sim.particles(), name, sim.time, self.index)
            if "vtu" in self.formats:
                self.entries.append((sim.time, f"{name}.vtu"))
        self.writer.submit("diagnostics", self.diagnostics.append, io.diagnostics_row(sim))
        self.probes.on_output(sim)
        self._rows = self._rows + 1
        self.index += 1
        self.last_time = sim.time
        # the state of every output is held (a numerical failure writes the last one); the file is written every
        # output.checkpoint_every outputs, at the first and the last
        self._held = self._checkpoint_data()
        if self.index == 1 or self.index % self.checkpoint_every == 0 or self.done or sim.at_step_limit:
            self._save(*self._held)
        if not self._executing:   # an observer of sim.run(on_output=...): the files are there when it returns
            self.writer.drain()
            if self._live:
                self._renderer.drain()
        self.output_seconds += time.perf_counter() - t0

    def _write_snapshot(self, particles: dict, name: str, t: float, index: int):
        """(the writer) One output's files: VTU and its series entry, NPZ, the frame's record."""
        p = io.derived_fields(particles, self.sim.scene)
        if "vtu" in self.formats:
            t0 = time.perf_counter()
            io.write_vtu(self.out_dir / f"{name}.vtu", p, self.fields, dtype=self.dtype, only=self.only_fields)
            self.entries_written.append((t, f"{name}.vtu"))
            io.write_pvd(self.out_dir / io.PVD_NAME, self.entries_written)
            if "domain_corners" in p:   # cpdi2: the domains as cells, a series of their own
                io.write_domains_vtu(self.out_dir / io.domains_name(f"{name}.vtu"), p, self.fields,
                                     dtype=self.dtype, only=self.only_fields)
                io.write_pvd(self.out_dir / io.DOMAINS_PVD, [(t, io.domains_name(f)) for t, f in self.entries_written])
            self.writer.seconds["snapshot: vtu"] += time.perf_counter() - t0
        if "npz" in self.formats:
            io.write_npz(self.out_dir / f"{name}.npz", p, self.fields)
        if self._frames:
            t0 = time.perf_counter()
            self._render(p, t, index)
            self.writer.seconds["snapshot: frame records"] += time.perf_counter() - t0

    def _checkpoint_data(self) -> tuple[dict, dict]:
        """The state now (numpy copies) and the output counters that go with it."""
        meta = dict(next_output=self.index, last_time=self.last_time, every=self.every, n_vtu=len(self.entries),
                    n_rows=self._rows, config=io.config_dict(self.cfg))
        return self.sim.get_state(), meta

    def _save(self, state: dict, meta: dict):
        """Hand the writer a checkpoint: it is written after every output handed over before it, so the files it
        counts are on disk when it is."""
        self.writer.submit("checkpoint", self._write_checkpoint, state, meta)
        self._held = None

    def _write_checkpoint(self, state: dict, meta: dict):
        """(the writer) checkpoint.npz, replaced atomically; checkpoint_time says the state the file holds."""
        io.save_checkpoint(self.out_dir / io.CHECKPOINT_NAME, state, meta)
        self.checkpoint_time = float(state["time"])

    def checkpoint(self):
        """A checkpoint of the state now (a stop between two steps)."""
        t0 = time.perf_counter()
        self._save(*self._checkpoint_data())
        self.output_seconds += time.perf_counter() - t0

    def save_last_output(self):
        """The checkpoint of the last output, when it is not written yet (after a numerical failure: the last good
        state on disk, as with a checkpoint at every output)."""
        if self._held is not None:
            self._save(*self._held)

    def _render(self, p: dict, time: float, index: int):
        """This output's frame: drawn now on the frame worker when its colour range and camera are fixed in advance
        (io/live_frames.py), else its data kept and the frames rendered at the end of the run (render_frames),
        with one colour range and one camera for the whole sequence."""
        if self._renderer is None:
            try:
                from .render import FrameRecorder, known_in_advance
                from .live_frames import LiveFrames
            except ImportError as e:
                self.log(f"warning: no frames or movie: the renderer is not available ({e})")
                self._frames = False
                return
            c = self.cfg
            args = (self.out_dir / "frames", c.output.render, c.dim, list(c.domain.lower), list(c.domain.upper))
            try:
                if "png" in self.formats and known_in_advance(c.output.render, c.dim):
                    # the movie is fed frame by frame only from the first output (a resumed run joins the PNGs)
                    movie = self.out_dir / "movie.mp4" if "mp4" in self.formats and index == 0 else None
                    self._renderer = LiveFrames(*args, title=c.name, lines=self._lines, movie=movie,
                                                threaded=self.writer.threaded)
                else:
                    self._renderer = FrameRecorder(*args, title=c.name, lines=self._lines)
            except ValueError as e:  # an unknown camera
                raise ConfigError(str(e), key="output.render.camera") from None
        try:
            self._renderer.record(p, time, index)
        except ValueError as e:  # an unknown or absent colour field
            raise ConfigError(str(e), key="output.render.color_by") from None

    def render_frames(self):
        """Render the recorded frames (frames/frame_NNNNNN.png); render_seconds and frames_rendered say what it cost.
        (In this thread, after the writer has drained: VTK draws only in the thread that made its window.)"""
        self.writer.drain()
        if self._renderer is None:
            return
        t0 = time.perf_counter()
        if self._live:   # drawn while the solver stepped: only the queued frames are left
            self._renderer.drain()
            self.output_seconds += time.perf_counter() - t0
            return
        self.frames_rendered += len(self._renderer.render_all())
        self.render_seconds += time.perf_counter() - t0
        self.writer.seconds["frames"] += time.perf_counter() - t0
        self.output_seconds += time.perf_counter() - t0

    @property
    def _live(self) -> bool:
        from .live_frames import LiveFrames

        return isinstance(self._renderer, LiveFrames)

    def _close_frames(self, complete: bool):
        """End the frame worker (its queued frames written first); complete: the movie it fed is kept."""
        if self._renderer is None or not self._live:
            return
        live, self._renderer = self._renderer, None
        self.frames_while_stepping = True
        t0 = time.perf_counter()
        try:
            live.close(complete)
        finally:
            self.output_seconds += time.perf_counter() - t0
            self.frames_rendered += len(live.frames)
            self.render_seconds += sum(live.seconds.values())
            for k, v in live.seconds.items():
                self.writer.seconds[f"{k} (while stepping)"] += v
            self._movie_done = live.movie_done

    def finish(self):
        """After the last output: the frames and movies, when asked."""
        t0 = time.perf_counter()
        self.probes.close()
        self.writer.drain()
        self.output_seconds += time.perf_counter() - t0
        self.render_frames()
        self._close_frames(complete=True)
        self._renderer = None
        movies = [f for f in ("mp4", "gif") if f in self.formats and not (f == "mp4" and self._movie_done)]
        if not movies or not self._frames:
            return
        from .render import make_movie

        t0 = time.perf_counter()
        for fmt in movies:
            make_movie(self.out_dir / "frames", self.out_dir / f"movie.{fmt}", fps=20, root=self.out_dir)
        self.render_seconds += time.perf_counter() - t0
        self.writer.seconds["movie"] += time.perf_counter() - t0
        self.output_seconds += time.perf_counter() - t0

    def breakdown(self) -> dict:
        """Seconds per output kind as the writer measured them (snapshot: derived fields and files, of which
        "snapshot: vtu" and "snapshot: frame records"; checkpoint, diagnostics, probes; frames and movie, rendered
        at the end, or "frames (while stepping)" and "movie (while stepping)" on the frame worker) and `waited`: the time the solver waited on the writer."""
        out = {k: v for k, v in self.writer.seconds.items() if v > 0}
        out["waited"] = self.writer.wait_seconds
        return out

    # ------------------------------------------------------------ the loop
    def next_time(self) -> float:
        """The first output time k * every after the current time (a function of the time alone, so a
        resumed run aims at the same times as the uninterrupted one), capped at end_time."""
        k = math.floor(self.sim.time / self.every + 1e-9) + 1
        return min(k * self.every, self.cfg.solver.end_time)

    @property
    def done(self) -> bool:
        end = self.cfg.solver.end_time
        return self.last_time is not None and self.last_time >= end - 1e-12 * max(1.0, end)

    def execute(self, on_step: Optional[Callable] = None, handle_sigint: bool = True) -> "Run":
        """Step to solver.end_time writing an output at each output time; on_step(sim) after every step.

        Ctrl-C or SIGTERM (when called from the main thread) finishes the current step, writes the checkpoint and
        raises Interrupted. InstabilityError propagates with the last good checkpoint left on disk; so does an
        io.FileError (disk full, file-size limit: the checkpoint is replaced only by a complete one)."""
        self._executing = True
        try:
            try:
                self._loop(on_step, handle_sigint)
            except InstabilityError:
                try:  # the outputs up to the failure first, then the report
                    self.save_last_output()
                    self.render_frames()  # the frames up to the last good state show what went wrong
                except Exception as e:  # the instability is the news; a failed picture must not hide it
                    self.log(f"warning: the frames could not be rendered ({type(e).__name__}: {e})")
                raise
            self.finish()
        finally:
            self._executing = False
            self._close_writer()
            self.lock.release()  # also on Ctrl-C and instability: the folder is free for --resume
        return self

    def _close_writer(self):
        """Every job handed over is written before the run returns or reports a stop; a write that fails here is
        raised unless another error is already on its way (then it is logged: that error is the news)."""
        t0 = time.perf_counter()
        in_flight = sys.exc_info()[1] is not None
        try:
            try:
                self.writer.close()
            finally:
                self._close_frames(complete=False)   # (after a complete run: closed already, by finish)
        except Exception as e:
            if not in_flight:
                raise
            self.log(f"warning: an output could not be written ({type(e).__name__}: {e})")
        finally:
            self.output_seconds += time.perf_counter() - t0

    def _handle_signals(self) -> dict:
        """Catch SIGINT and SIGTERM: the run stops after the current step. Returns {signal: handler before} for
        _restore_signals. A signal that is ignored (SIG_IGN: a run started in the background, under nohup) stays
        ignored, and one whose handler was set outside Python (getsignal is None) is left alone: it could not be
        put back."""
        before = {}

        def _stop(signum, frame):
            self.stop_requested, self.stop_signal = True, signum
            # a second one stops at once: Ctrl-C as KeyboardInterrupt, SIGTERM as the handler before (default: exit)
            signal.signal(signum, signal.default_int_handler if signum == signal.SIGINT else before[signum])

        for sig in STOP_SIGNALS:
            prev = signal.getsignal(sig)
            if prev is None or prev == signal.SIG_IGN:
                continue
            before[sig] = prev
            signal.signal(sig, _stop)
        return before

    def _stop(self):
        self.checkpoint()
        t0 = time.perf_counter()
        self.writer.drain()   # every output handed over is on disk before the stop is reported
        if self._live:
            self._renderer.drain()   # and so is every frame queued
        self.output_seconds += time.perf_counter() - t0
        raise Interrupted(self, self.stop_signal or signal.SIGINT)

    def _loop(self, on_step, handle_sigint):
        sim, end = self.sim, self.cfg.solver.end_time
        restore = {}
        if handle_sigint and threading.current_thread() is threading.main_thread():
            restore = self._handle_signals()
        try:
            if self.index == 0:
                self(sim)

            def after_step(s):
                self.probes.on_step(s)
                if on_step is not None:
                    on_step(s)
                # a step that lands on an output time writes that output before the stop (the loop's check below
                # stops then; after the last step the run completes): a resumed run aims at the output after its
                # state's time and would skip this one
                if self.stop_requested and s.time < target - 1e-12 * max(1.0, abs(target)):
                    self._stop()

            while not self.done:
                if self.stop_requested:
                    self._stop()
                target = self.next_time()
                sim.advance_to(target, on_step=after_step)
                self(sim)
                if sim.at_step_limit and sim.time < target:
                    self.log(f"stopped at solver.max_steps={self.cfg.solver.max_steps} (t={sim.time:.6g} of {end:g})")
                    break
        except InstabilityError as e:
            e.run_dir = self.out_dir
            raise
        finally:
            for sig, prev in restore.items():  # what was there before, whatever it was
                signal.signal(sig, prev)


class Simulation(_Simulation):
    """taichi_mpm.Simulation: the solver, whose run() writes outputs when given no observer."""

    def run(self, on_output: Optional[Callable] = None, every: Optional[float] = None, *, out_dir=None,
            formats=None, resume: bool = False, on_step: Optional[Callable] = None, overwrite: bool = False):
        """Run to solver.end_time. With on_output: call it at t=0 and every `every` seconds and write
        nothing; without: write the outputs of the config (or `formats`) into output.dir (or `out_dir`)."""
        if on_output is not None:
            return super().run(on_output, every)
        Run(self, out_dir, formats=formats, every=every, resume=resume, overwrite=overwrite).execute(on_step=on_step)
        return self


def _scalar(value) -> float | None:
    """A checkpoint's number as a float, or None when it is missing or not one number (set_state reports that)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return None
