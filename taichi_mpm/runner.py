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
             "frames/frame_*.png", "movie.mp4", "movie.gif")

    def __init__(self, sim, out_dir=None, formats=None, every: Optional[float] = None, resume: bool = False,
                 log: Optional[Callable[[str], None]] = None):
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
        self._renderer = None
        self._frames = any(f in self.formats for f in ("png", "mp4", "gif"))
        self.out_dir.mkdir(parents=True, exist_ok=True)
        if resume:
            self._restore()
        else:
            self._fresh()
        io.write_config(self.out_dir / io.CONFIG_NAME, self.cfg)
        self.probes = probes.Probes(sim, self.out_dir, resume=resume)  # probes/NAME.csv (output.probes)

    # ------------------------------------------------------------ set-up
    def _fresh(self):
        for pattern in self.STALE:
            for f in self.out_dir.glob(pattern):
                f.unlink()
        self.diagnostics = io.Diagnostics(self.out_dir / io.DIAGNOSTICS_NAME, self.sim.dim)

    def _restore(self):
        path = self.out_dir / io.CHECKPOINT_NAME
        if not path.is_file():
            raise ConfigError(f"--resume: no checkpoint to resume from ({path} does not exist)")
        state, meta = io.load_checkpoint(path)
        changed = config_changes(meta.get("config", {}), io.config_dict(self.cfg))
        if changed:
            old, new = _flat(meta.get("config", {})), _flat(io.config_dict(self.cfg))
            k = changed[0]
            raise ConfigError(f"--resume: the checkpoint in {self.out_dir} was written with {k}={old.get(k)!r}, "
                              f"the config now has {new.get(k)!r}; only solver.end_time, solver.max_steps and "
                              f"output.* may change when resuming", key=k)
        end = self.cfg.solver.end_time
        if "time" in state and float(state["time"]) > end * (1 + 1e-12):
            raise ConfigError(f"--resume: the checkpoint in {self.out_dir} is at t={float(state['time']):.6g}, after "
                              f"solver.end_time={end:g}; a resumed run continues forward: set solver.end_time "
                              f"above {float(state['time']):.6g} (or start a fresh run without --resume)",
                              key="solver.end_time")
        if int(state["x"].shape[0]) != self.sim.n:
            raise ConfigError(f"--resume: the checkpoint holds {state['x'].shape[0]} particles, the scene {self.sim.n}")
        self.sim.set_state(state)
        self.index = int(meta.get("next_output", 0))
        self.every = float(meta.get("every", self.every))
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
        if self._renderer is None:
            try:
                from .render import FrameRenderer
            except ImportError as e:
                self.log(f"warning: no frames or movie: the renderer is not available ({e})")
                self._frames = False
                return
            c = self.cfg
            try:
                self._renderer = FrameRenderer(c.output.render, c.dim, list(c.domain.lower), list(c.domain.upper))
            except ValueError as e:  # an unknown camera
                raise ConfigError(str(e), key="output.render.camera") from None
            (self.out_dir / "frames").mkdir(exist_ok=True)
        try:
            self._renderer.render(p, time, self.out_dir / "frames" / f"frame_{self.index:06d}.png")
        except ValueError as e:  # an unknown or absent colour field
            raise ConfigError(str(e), key="output.render.color_by") from None

    def finish(self):
        """After the last output: movies from the frames, when asked."""
        self.probes.close()
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        movies = [f for f in ("mp4", "gif") if f in self.formats]
        if not movies or not self._frames:
            return
        from .render import make_movie

        t0 = time.perf_counter()
        for fmt in movies:
            make_movie(self.out_dir / "frames", self.out_dir / f"movie.{fmt}", fps=20)
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
        self.finish()
        return self


class Simulation(_Simulation):
    """taichi_mpm.Simulation: the solver, whose run() writes outputs when given no observer."""

    def run(self, on_output: Optional[Callable] = None, every: Optional[float] = None, *, out_dir=None,
            formats=None, resume: bool = False, on_step: Optional[Callable] = None):
        """Run to solver.end_time. With on_output: call it at t=0 and every `every` seconds and write
        nothing; without: write the outputs of the config (or `formats`) into output.dir (or `out_dir`)."""
        if on_output is not None:
            return super().run(on_output, every)
        Run(self, out_dir, formats=formats, every=every, resume=resume).execute(on_step=on_step)
        return self
