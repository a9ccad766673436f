"""Running a simulation to its end time while writing outputs (the CLI's `run` and `sim.run()`).

`Run(sim, out_dir)` owns an output directory (layout in docs/contract.md). Called with a Simulation it writes
one output (snapshot, diagnostics row, frame, checkpoint), so it works as `sim.run(on_output=run)`;
`run.execute()` drives the steps itself, which adds progress callbacks, a clean stop on Ctrl-C and
bit-for-bit resumption from checkpoint.npz.

Outputs are written at the start and then at the times k * output.every (and at end_time): the next
output time is the first such time after the current time. The checkpoint is rewritten at every
output (and on a stop), so after a numerical failure the last good state is on disk. A resumed run
takes the same steps as the uninterrupted one: the step loop below depends only on the state the
checkpoint holds (positions, velocities, F, C, time, step count and the CFL speed estimate).
"""
from __future__ import annotations

import math
import os
import re
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Optional

from . import io, probes
from .config import Config, ConfigError
from .errors import InstabilityError
from .solver import Simulation as _Simulation

# keys that may differ between a checkpoint and the config it resumes with
RESUMABLE_CHANGES = ("name", "arch", "solver.end_time", "solver.max_steps", "output", "limits")


LOCK_NAME = "run.lock"
# temporary files of io's atomic writes (".NAME.tmpPID"): complete files are renamed over the real ones, so any
# such file in a run folder held by this run's lock is left over from a killed run
_TEMPORARY = re.compile(r"\..+\.tmp\d+")


class FolderLock:
    """One writer per run folder: an exclusive advisory lock (flock) on RUN_DIR/run.lock, which holds the owner's
    pid. The operating system releases it when the process ends, however it ends, so a file left by a killed run
    is no obstacle (the next run takes it over and removes it). Where flock does not exist (Windows), no lock."""

    def __init__(self, folder: Path):
        self.path = Path(folder) / LOCK_NAME
        self.fd = None
        try:
            import fcntl
        except ImportError:
            return
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
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
                same = os.path.samestat(os.fstat(fd), os.stat(self.path))
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self.fd = fd

    def release(self):
        if self.fd is not None:
            try:
                os.unlink(self.path)
            except OSError:
                pass
            os.close(self.fd)  # closing releases the flock
            self.fd = None

    __del__ = release


class Interrupted(KeyboardInterrupt):
    """Ctrl-C stopped a run between two steps; the checkpoint holds the state at that moment."""

    def __init__(self, run: "Run"):
        self.run = run
        super().__init__(f"stopped at step {run.sim.n_steps}, t={run.sim.time:.6g}; the checkpoint is "
                         f"{run.out_dir / io.CHECKPOINT_NAME} (continue with --resume)")


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

    STALE = ("particles_*.vtu", "particles_*.npz", io.PVD_NAME, io.DIAGNOSTICS_NAME, io.CHECKPOINT_NAME,
             "frames/frame_*.png", "frames/.record_*.npz", "movie.mp4", "movie.gif")

    def __init__(self, sim, out_dir=None, formats=None, every: Optional[float] = None, resume: bool = False,
                 log: Optional[Callable[[str], None]] = None, overwrite: bool = False):
        self.sim, self.cfg = sim, sim.cfg
        self.out_dir = output_dir(self.cfg, out_dir)
        self.formats = list(self.cfg.output.formats if formats is None else formats)
        self.every = float(every or self.cfg.output.every)
        self.fields = list(self.cfg.output.fields)
        self.log = log or (lambda msg: print(msg, file=sys.stderr))
        self.index = 0           # number of the next output
        self.last_time = None    # time of the last output written
        self._rows = 0           # rows in diagnostics.csv
        self.entries = []        # (time, file) of the VTU series
        self.stop_requested = False
        self.output_seconds = 0.0  # wall time spent writing outputs (the CLI's summary keeps it apart from stepping)
        self._renderer = None    # render.FrameRecorder: frames are rendered at the end of the run
        self.render_seconds = 0.0  # wall time of rendering frames and movies (part of output_seconds)
        self.frames_rendered = 0
        self._frames = any(f in self.formats for f in ("png", "mp4", "gif"))
        if resume and overwrite:
            raise ConfigError("--resume continues a run's results and --overwrite replaces them: give one")
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        except ValueError as e:  # a NUL character in --out or output.dir
            raise ConfigError(f"cannot use {str(self.out_dir)!r} as the output folder: {e}", key="output.dir") from None
        self.lock = FolderLock(self.out_dir)
        try:
            self._remove_temporaries()
            if resume:
                self._restore()
            else:
                self._fresh(overwrite)
            io.write_config(self.out_dir / io.CONFIG_NAME, self.cfg)
            self.probes = probes.Probes(sim, self.out_dir, resume=resume)  # probes/NAME.csv (output.probes)
        except BaseException:  # a refused resume or overwrite leaves the folder free at once
            self.lock.release()
            raise

    # ------------------------------------------------------------ set-up
    def _remove_temporaries(self):
        """Temporary files a killed run left (with the lock held, no other writer can own one)."""
        for folder in (self.out_dir, self.out_dir / "probes", self.out_dir / "frames"):
            if folder.is_dir():
                for f in folder.iterdir():
                    if _TEMPORARY.fullmatch(f.name) and f.is_file():
                        f.unlink()

    def held(self) -> list[str]:
        """The results of an earlier run in the output folder (what a fresh run would replace)."""
        return [p for p in self.STALE if next(self.out_dir.glob(p), None) is not None]

    def _fresh(self, overwrite: bool = False):
        held = self.held()
        if held and not overwrite:
            raise ConfigError(f"{self.out_dir} already holds a run's results ({', '.join(held[:4])}): add --resume to "
                              f"continue that run or --overwrite to replace its results")
        for pattern in self.STALE:
            for f in self.out_dir.glob(pattern):
                f.unlink()
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
        try:
            self.sim.set_state(state)  # checks every array before applying any
        except (ValueError, TypeError, KeyError) as e:
            raise ConfigError(f"--resume: {path} does not fit this scene ({e})") from None
        self.index = int(meta.get("next_output", 0))
        old_every = meta.get("every")
        if isinstance(old_every, (int, float)) and not math.isclose(old_every, self.every, rel_tol=1e-12):
            self.log(f"note: output.every changed from {old_every:g} to {self.every:g} s on --resume: the outputs "
                     f"after t={self.sim.time:g} follow the new interval")
        self.entries = [e for e in io.read_pvd(self.out_dir / io.PVD_NAME)][: int(meta.get("n_vtu", 0))]
        self.diagnostics = io.Diagnostics(self.out_dir / io.DIAGNOSTICS_NAME, self.sim.dim,
                                          keep=int(meta.get("n_rows", 0)))
        self._rows = int(meta.get("n_rows", 0))
        self.last_time = meta.get("last_time")

    # ------------------------------------------------------------ one output
    def __call__(self, sim=None):
        """Write one output of the current state (observer for Simulation.run(on_output=...))."""
        sim = self.sim if sim is None else sim
        t0 = time.perf_counter()
        name = io.SNAPSHOT.format(self.index)
        if "vtu" in self.formats or "npz" in self.formats or self._frames:
            p = io.derived_fields(sim.particles(), sim.scene)
            if "vtu" in self.formats:
                io.write_vtu(self.out_dir / f"{name}.vtu", p, self.fields)
                self.entries.append((sim.time, f"{name}.vtu"))
                io.write_pvd(self.out_dir / io.PVD_NAME, self.entries)
            if "npz" in self.formats:
                io.write_npz(self.out_dir / f"{name}.npz", p, self.fields)
            if self._frames:
                self._render(p, sim.time)
        self.diagnostics.append(io.diagnostics_row(sim))
        self.probes.on_output(sim)
        self._rows = self._rows + 1
        self.index += 1
        self.last_time = sim.time
        self.checkpoint()
        self.output_seconds += time.perf_counter() - t0

    def checkpoint(self):
        meta = dict(next_output=self.index, last_time=self.last_time, every=self.every, n_vtu=len(self.entries), n_rows=self._rows,
                    config=io.config_dict(self.cfg))
        io.save_checkpoint(self.out_dir / io.CHECKPOINT_NAME, self.sim.get_state(), meta)

    def _render(self, p: dict, time: float):
        """Keep this output's frame data; the frames are rendered at the end of the run (render_frames), with one
        colour range and one camera for the whole sequence."""
        if self._renderer is None:
            try:
                from .render import FrameRecorder, grid_lines
            except ImportError as e:
                self.log(f"warning: no frames or movie: the renderer is not available ({e})")
                self._frames = False
                return
            c = self.cfg
            try:
                self._renderer = FrameRecorder(self.out_dir / "frames", c.output.render, c.dim, list(c.domain.lower),
                                               list(c.domain.upper), title=c.name, lines=grid_lines(c))
            except ValueError as e:  # an unknown camera
                raise ConfigError(str(e), key="output.render.camera") from None
        try:
            self._renderer.record(p, time, self.index)
        except ValueError as e:  # an unknown or absent colour field
            raise ConfigError(str(e), key="output.render.color_by") from None

    def render_frames(self):
        """Render the recorded frames (frames/frame_NNNNNN.png); render_seconds and frames_rendered say what it cost."""
        if self._renderer is None:
            return
        t0 = time.perf_counter()
        self.frames_rendered += len(self._renderer.render_all())
        self.render_seconds += time.perf_counter() - t0
        self.output_seconds += time.perf_counter() - t0

    def finish(self):
        """After the last output: the frames and movies, when asked."""
        self.probes.close()
        self.render_frames()
        self._renderer = None
        movies = [f for f in ("mp4", "gif") if f in self.formats]
        if not movies or not self._frames:
            return
        from .render import make_movie

        t0 = time.perf_counter()
        for fmt in movies:
            make_movie(self.out_dir / "frames", self.out_dir / f"movie.{fmt}", fps=20)
        self.render_seconds += time.perf_counter() - t0
        self.output_seconds += time.perf_counter() - t0

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

        Ctrl-C (when called from the main thread) finishes the current step, writes the checkpoint and
        raises Interrupted. InstabilityError propagates with the last good checkpoint left on disk."""
        try:
            try:
                self._loop(on_step, handle_sigint)
            except InstabilityError:
                try:
                    self.render_frames()  # the frames up to the last good state show what went wrong
                except Exception as e:  # the instability is the news; a failed picture must not hide it
                    self.log(f"warning: the frames could not be rendered ({type(e).__name__}: {e})")
                raise
            self.finish()
        finally:
            self.lock.release()  # also on Ctrl-C and instability: the folder is free for --resume
        return self

    def _loop(self, on_step, handle_sigint):
        sim, end = self.sim, self.cfg.solver.end_time
        restore = None
        if handle_sigint and threading.current_thread() is threading.main_thread():
            def _stop(signum, frame):
                self.stop_requested = True
                signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C stops at once
            restore = signal.signal(signal.SIGINT, _stop)
        try:
            if self.index == 0:
                self(sim)

            def after_step(s):
                self.probes.on_step(s)
                if on_step is not None:
                    on_step(s)
                if self.stop_requested:
                    self.checkpoint()
                    raise Interrupted(self)

            while not self.done:
                if self.stop_requested:
                    self.checkpoint()
                    raise Interrupted(self)
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
            if restore is not None:
                signal.signal(signal.SIGINT, restore)


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
