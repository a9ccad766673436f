"""The `taichi-mpm` command (also `python -m taichi_mpm`).

    taichi-mpm run CONFIG [--set KEY=VALUE]... [--out DIR] [--arch ARCH] [--quiet] [--resume | --overwrite]
    taichi-mpm validate CONFIG [--set KEY=VALUE]...
    taichi-mpm demo [NAME] [--list] [run options]
    taichi-mpm render RUN_DIR [--color-by FIELD] [--size WxH] [--camera CAMERA] [--movie FILE|mp4|gif]
    taichi-mpm compare CONFIG --vary KEY=A,B[,C] [--set KEY=VALUE]... [--out DIR] [--overwrite] [--color-by FIELD]
                    [--size WxH] [--camera CAMERA] [--no-movie] [--arch ARCH] [--allow-large] [--quiet]
    taichi-mpm gui CONFIG [--set KEY=VALUE]... [--arch ARCH] [--max-frames N] [--screenshot PNG] [--view VIEW]
    taichi-mpm study STUDY.yaml [--jobs N] [--scheduler ADDRESS] [--out DIR] [--resume | --overwrite]
                    [--allow-problem MODULE:FACTORY]... [--dry-run]
    taichi-mpm plot RUN_DIR [--probe NAME] [--out PNG]
    taichi-mpm advise CONFIG | --problem SPEC  --observe Q --tolerance TOL [--reference REF] [--bases B,B]
                    [--transfers T,T] [--ppc N,N] [--levels N] [--cost step_time|wall_time|work] [--set KEY=VALUE]...
                    [--jobs N] [--out DIR] [--resume | --overwrite] [--allow-problem MODULE:FACTORY]...

Exit codes: 0 success; 2 invalid input (one message on stderr, no traceback); 3 numerical
instability (the last good state is kept as checkpoint.npz); 4 a file could not be read or written (disk full,
file-size limit, permission, a link or a file in the way; one line naming it; the last checkpoint stays valid);
130 stopped by Ctrl-C, 143 by SIGTERM (checkpoint kept).
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from io import StringIO
from pathlib import Path

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")  # keep stdout for results (e.g. `validate`)

from .config import ConfigError, load_config, locate, parse_overrides  # noqa: E402
from .errors import InstabilityError  # noqa: E402
from .bases import registry as basis_registry  # noqa: E402

EXIT_OK, EXIT_FAILURE, EXIT_INPUT, EXIT_UNSTABLE, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
EXIT_IO = 4  # an operating-system error reading or writing a file (docs/contract.md, exit codes)


def configs_dir() -> Path:
    """The bundled scenes: the repository's configs/ directory next to the package."""
    import taichi_mpm

    return Path(taichi_mpm.__file__).resolve().parents[1] / "configs"


def demos() -> dict[str, Path]:
    d = configs_dir()
    return {p.stem: p for p in sorted(d.glob("*.yaml"))} if d.is_dir() else {}


def _describe_demo(path: Path) -> str:
    """The first comment line of a demo config, as its one-line description."""
    try:
        for line in path.read_text().splitlines():
            s = line.strip()
            if s.startswith("#"):
                return s.lstrip("#").strip()
            if s:
                break
    except OSError:
        pass
    return ""


# ---------------------------------------------------------------- argument parsing
class _Parser(argparse.ArgumentParser):
    def error(self, message):  # usage errors are invalid input: exit 2 with one message
        self.print_usage(sys.stderr)
        raise _InputError(message)


class _InputError(Exception):
    pass


def _size(text: str):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w <= 0 or h <= 0:
            raise ValueError
        return [w, h]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, e.g. 960x720, got {text!r}") from None


def _positive_int(text: str):
    try:
        v = int(text)
        if v <= 0:
            raise ValueError
        return v
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None


def _add_config_options(p, run=True):
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value before validation (dotted key; list items by index), repeatable")
    if run:
        p.add_argument("--out", metavar="DIR", help="output directory (default: output.dir of the config)")
        p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
        p.add_argument("--profile", action="store_true",
                       help="print where the time went: compile, stepping, each kind of output, waiting on the writer")
        again = p.add_mutually_exclusive_group()
        again.add_argument("--resume", action="store_true", help="continue from checkpoint.npz in the output directory")
        again.add_argument("--overwrite", action="store_true",
                           help="replace the results of an earlier run in the output directory")
    p.add_argument("--arch", choices=["auto", "cpu", "cuda", "vulkan", "metal"], help="override the config's arch")
    p.add_argument("--allow-large", dest="overrides", action="append_const", const="limits.allow_large=true",
                   help="run even when the size estimate exceeds limits.memory_gb / limits.particles")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="taichi-mpm", description="Material Point Method sandbox on Taichi.")
    parser.add_argument("--version", action="version", version="taichi-mpm 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    p = sub.add_parser("run", help="run a scene to its end time, writing outputs")
    p.add_argument("config", metavar="CONFIG")
    _add_config_options(p)

    p = sub.add_parser("validate", help="check a config and print it resolved")
    p.add_argument("config", metavar="CONFIG")
    _add_config_options(p, run=False)

    p = sub.add_parser("demo", help="run a bundled scene from configs/")
    p.add_argument("name", nargs="?", metavar="NAME")
    p.add_argument("--list", action="store_true", help="list the bundled scenes")
    _add_config_options(p)

    p = sub.add_parser("render", help="render frames / a movie from a run directory")
    p.add_argument("run_dir", metavar="RUN_DIR")
    p.add_argument("--color-by", metavar="FIELD", help="field to colour by (e.g. speed, von_mises, J, body, damage)")
    p.add_argument("--size", type=_size, metavar="WxH", help="image size in pixels, e.g. 960x720")
    p.add_argument("--camera", metavar="CAMERA", help="camera (e.g. iso, xy, xz, yz)")
    p.add_argument("--movie", metavar="FILE|mp4|gif", help="also write a movie (file name or format)")

    p = sub.add_parser("compare", help="run a scene with one setting varied; side-by-side frames, movie, curves")
    p.add_argument("config", metavar="CONFIG")
    p.add_argument("--vary", required=True, metavar="KEY=A,B[,C]",
                   help="the dotted key and its values, e.g. solver.basis=linear,cubic (commas inside [...] stay)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value for every variant, repeatable")
    p.add_argument("--out", metavar="DIR", help="output directory (default: output.dir of the config + _compare_KEY)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier comparison in the output directory")
    p.add_argument("--color-by", metavar="FIELD", help="field to colour by (default: the config's output.render)")
    p.add_argument("--size", type=_size, metavar="WxH", help="size of a whole side-by-side frame in pixels")
    p.add_argument("--camera", metavar="CAMERA", help="3D camera (e.g. iso, xy, xz, yz)")
    p.add_argument("--no-movie", action="store_true", help="frames and curves only")
    p.add_argument("--arch", choices=["auto", "cpu", "cuda", "vulkan", "metal"], help="override the config's arch")
    p.add_argument("--allow-large", dest="overrides", action="append_const", const="limits.allow_large=true",
                   help="run even when the estimated work or size exceeds the limits")
    p.add_argument("--quiet", action="store_true", help="no progress lines")

    p = sub.add_parser("gui", help="interactive window")
    p.add_argument("config", metavar="CONFIG")
    _add_config_options(p, run=False)
    p.add_argument("--max-frames", type=_positive_int, metavar="N", help="close after N frames")
    p.add_argument("--screenshot", metavar="PNG", help="save the last frame to this file")
    p.add_argument("--view", choices=["auto", "ggui", "projection"], default="auto",
                   help="3D view: GGUI scene where a Vulkan device exists (auto), or force one")

    p = sub.add_parser("study", help="speed/accuracy sweep (docs/study.md)")
    p.add_argument("study", metavar="STUDY.yaml")
    p.add_argument("--jobs", type=_positive_int, metavar="N",
                   help="cases run in parallel (default: the study's jobs, 1)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="dask scheduler address")
    p.add_argument("--out", metavar="DIR", help="output directory (default: studies/NAME)")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="keep the finished cases in the output directory, run the rest")
    again.add_argument("--overwrite", action="store_true", help="replace the results already in the output directory")
    p.add_argument("--allow-problem", dest="allow_problems", action="append", default=[], metavar="MODULE:FACTORY",
                   help="let the study run this problem factory (Python code outside the project), repeatable")
    p.add_argument("--dry-run", action="store_true", help="check the study and list its cases; run and write nothing")

    p = sub.add_parser("advise",
                       help="cheapest basis/transfer/resolution for a tolerance on one quantity (docs/study.md)")
    p.add_argument("config", nargs="?", metavar="CONFIG", help="a config file (or give --problem)")
    p.add_argument("--problem", metavar="SPEC", help="an analytic problem instead: NAME or '{type: NAME, key: value}'")
    p.add_argument("--observe", required=True, metavar="Q",
                   help="PROBE.COLUMN[@end|max|min|mean|maxabs], a function (kinetic_energy, ...) "
                        "or a problem's error metric")
    p.add_argument("--tolerance", required=True, metavar="TOL", help="the error allowed: 1%% or 0.01")
    p.add_argument("--reference", metavar="REF", help="a number, exact, finest or richardson (default: richardson, "
                   "or exact for a problem's error metric)")
    p.add_argument("--bases", metavar="B,B", help=f"bases to try (default: {','.join(basis_registry.swept())})")
    p.add_argument("--transfers", metavar="T,T", help="transfers to try (default: flip,apic)")
    p.add_argument("--ppc", metavar="N,N", help="particles per cell to try (default: the config's)")
    p.add_argument("--levels", type=_positive_int, default=3, metavar="N",
                   help="resolution levels: domain.dx, dx/2, ... (default 3)")
    p.add_argument("--cost", choices=["step_time", "wall_time", "work"], default="step_time",
                   help="what 'cheapest' means: stepping time without the JIT compile (default), wall time, or "
                   "work = particle-steps x stencil nodes (the same on every machine)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value for every run, repeatable")
    p.add_argument("--jobs", type=_positive_int, metavar="N", help="runs in parallel (default: cores - 1)")
    p.add_argument("--out", metavar="DIR", help="output directory (default: advice/NAME)")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="reuse the finished runs in the output directory")
    again.add_argument("--overwrite", action="store_true", help="replace the results already in the output directory")
    p.add_argument("--allow-problem", dest="allow_problems", action="append", default=[], metavar="MODULE:FACTORY",
                   help="let it run this problem factory or observable function (code outside the project)")

    p = sub.add_parser("plot", help="plot a run's probes (probes/*.csv) and energies into RUN_DIR/plots/")
    p.add_argument("run_dir", metavar="RUN_DIR")
    p.add_argument("--probe", metavar="NAME", help="plot only this probe")
    p.add_argument("--out", metavar="PNG", help="write the plot to this file (one plot: with --probe)")
    return parser


# ---------------------------------------------------------------- helpers
def _load(path, args):
    overrides = parse_overrides(args.overrides)
    if getattr(args, "arch", None):
        overrides["arch"] = args.arch
    return load_config(path, overrides)


def _err(msg: str):
    print(f"taichi-mpm: error: {msg}", file=sys.stderr)


class _ProgressBar:
    """rich progress on stderr: simulation time, dt, particle-steps per second, time left."""

    def __init__(self, sim, run):
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

        self.sim, self.end = sim, sim.cfg.solver.end_time
        self.progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(),
            TextColumn("t={task.completed:.4g}/{task.total:.4g} s"),
            TextColumn("dt={task.fields[dt]:.3g}"),
            TextColumn("{task.fields[rate]:.3g} particle-steps/s"),
            TextColumn("left"), TimeRemainingColumn(),
            console=Console(stderr=True), transient=False)
        self.task = self.progress.add_task(sim.cfg.name, total=self.end, completed=sim.time, dt=0.0, rate=0.0)
        self.run = run
        self._first = sim.n_steps  # the step count before the first (compiling) step
        self._t, self._steps, self._last, self._out = time.perf_counter(), sim.n_steps, 0.0, run.output_seconds

    def __enter__(self):
        self.progress.__enter__()
        return self

    def __exit__(self, *exc):
        self.update(force=True)
        return self.progress.__exit__(*exc)

    def update(self, sim=None, force=False):
        now = time.perf_counter()
        if not force and now - self._last < 0.1:
            return
        sim = self.sim
        rate = self.progress.tasks[0].fields["rate"]
        # stepping rate only: the time spent writing outputs (VTU, frames) in the interval is left out, as in
        # the summary, and the first step (which holds the JIT compile) starts the clock
        stepping = now - self._t - (self.run.output_seconds - self._out)
        if sim.n_steps > self._steps and stepping > 0 and self._steps > self._first:
            rate = sim.n * (sim.n_steps - self._steps) / stepping
        if sim.n_steps > self._steps:
            self._t, self._steps, self._out = now, sim.n_steps, self.run.output_seconds
        self.progress.update(self.task, completed=min(sim.time, self.end), dt=sim.dt, rate=rate)
        self._last = now


class _StepClock:
    """Splits a run's wall time into the first step (which holds the JIT compile), stepping and writing
    outputs, so that the summary's particle-steps/s is the stepping rate the progress bar shows."""

    def __init__(self, sim, run):
        self.sim, self.run = sim, run
        self.t0, self.steps0, self.out0 = time.perf_counter(), sim.n_steps, run.output_seconds
        self.first = None   # (time, output seconds) after the first step

    def __call__(self, sim):
        if self.first is None:
            self.first = (time.perf_counter(), self.run.output_seconds)

    def summary(self) -> str:
        now, sim, run = time.perf_counter(), self.sim, self.run
        steps = sim.n_steps - self.steps0
        text = f"{steps} steps to t={sim.time:g} in {now - self.t0:.1f} s ({sim.n} particles"
        if self.first is None:
            return text + ")"
        first = self.first[0] - self.t0 - (self.first[1] - self.out0)
        stepping = now - self.first[0] - (run.output_seconds - self.first[1])
        rate = f"{sim.n * (steps - 1) / stepping:.3g} particle-steps/s" if steps > 1 and stepping > 0 else "-"
        text += (f"): first step (JIT compile) {first:.1f} s, stepping {stepping:.1f} s at {rate}, "
                 f"outputs {run.output_seconds - self.out0:.1f} s")
        if run.frames_rendered and run.frames_while_stepping:   # on the frame worker: beside the solver
            text += (f" ({run.frames_rendered} frames and the movie drawn while stepping in "
                     f"{run.render_seconds:.1f} s, {run.render_seconds / run.frames_rendered:.2f} s per frame)")
        elif run.frames_rendered:
            text += (f" (of which rendering {run.frames_rendered} frames and the movie "
                     f"{run.render_seconds:.1f} s, {run.render_seconds / run.frames_rendered:.2f} s per frame)")
        b = run.breakdown()
        where = "in the background" if run.writer.threaded else "inline"
        text += f"; files written {where}: " + ", ".join(f"{k} {v:.1f} s" for k, v in b.items()
                                                          if k != "waited" and not k.startswith("snapshot: "))
        return text + f"; the solver waited {b['waited']:.1f} s on the writer"

    def profile(self) -> str:
        """--profile: the breakdown as a table (seconds; the background kinds overlap with stepping)."""
        now, run = time.perf_counter(), self.run
        first = (self.first[0] - self.t0 - (self.first[1] - self.out0)) if self.first else 0.0
        stepping = (now - self.first[0] - (run.output_seconds - self.first[1])) if self.first else 0.0
        rows = [("total", now - self.t0), ("first step (compile)", first), ("stepping", stepping),
                ("outputs in the solver's thread", run.output_seconds - self.out0)]
        where = "writer" if run.writer.threaded else "inline"
        for k, v in run.breakdown().items():
            if k.startswith("snapshot: "):
                rows.append((f"      of which {k[10:]}", v))
            elif k == "waited":
                rows.append(("  the solver waited on the writer", v))
            else:
                suffix = (" (at the end)" if k in ("frames", "movie") else "" if k.endswith("stepping)")
                          else f" ({where})")
                rows.append((f"  {k}{suffix}", v))
        steps = self.sim.n_steps - self.steps0
        rate = self.sim.n * (steps - 1) / stepping if steps > 1 and stepping > 0 else 0.0
        head = f"profile (seconds; {steps} steps, {self.sim.n} particles, stepping {rate:.3g} particle-steps/s):"
        return "\n".join([head] + [f"  {name:<34} {v:8.2f}" for name, v in rows])


def _run_config(cfg, args) -> int:
    try:
        return _run(cfg, args)
    except ConfigError as e:  # found after validation (a body outside the domain, a bad colour field, ...)
        raise locate(e, cfg) from None


def _run(cfg, args) -> int:
    from .io import files as io
    from .io.runner import Interrupted, Run, Simulation, output_dir

    if args.resume:  # an unreadable checkpoint is refused before anything is allocated
        checkpoint = output_dir(cfg, args.out) / io.CHECKPOINT_NAME
        if checkpoint.exists():
            io.load_checkpoint(checkpoint)
    # ti.init prints "[Taichi] Starting on arch=..." to stdout: keep stdout clean
    with contextlib.redirect_stdout(StringIO() if args.quiet else sys.stderr):
        sim = Simulation(cfg)
    run = Run(sim, args.out, resume=args.resume, overwrite=args.overwrite)  # an OSError: main's exit 4
    if args.resume and run.done:
        run.lock.release()   # the folder is free again (no run.lock left behind)
        if not args.quiet:
            print(f"nothing to do: {run.out_dir} is already at t={sim.time:g} = solver.end_time", file=sys.stderr)
        return EXIT_OK
    clock = _StepClock(sim, run)
    try:
        if args.quiet:
            run.execute(on_step=clock)
        else:
            with _ProgressBar(sim, run) as bar:
                run.execute(on_step=lambda s: (clock(s), bar.update(s)))
    except Interrupted as e:
        _err(f"interrupted: {e}" if e.signal_name == "SIGINT" else f"stopped by {e.signal_name}: {e}")
        return 128 + e.signum   # 130 for Ctrl-C, 143 for SIGTERM
    except OSError as e:  # disk full, file-size limit, ...: the checkpoint is only ever replaced by a complete one
        from .io.files import describe

        t = run.checkpoint_time
        kept = (f"the last checkpoint (t={t:.6g}) is {run.out_dir / io.CHECKPOINT_NAME}: fix the cause and continue "
                f"with --resume" if t is not None else "no checkpoint was written")
        _err(f"{describe(e)}; {kept}")
        return EXIT_IO
    except InstabilityError as e:
        where = run.out_dir / "checkpoint.npz"
        kept = (f"the last good state (t={run.checkpoint_time:.6g}) is in {where}" if run.checkpoint_time is not None
                else "")
        _err(f"{e}\n  {kept}; outputs written so far are kept in {run.out_dir}")
        return EXIT_UNSTABLE
    if not args.quiet:
        print(f"done: {clock.summary()}; {run.index} outputs in {run.out_dir}", file=sys.stderr)
    if getattr(args, "profile", False):
        print(clock.profile(), file=sys.stderr)
    return EXIT_OK


# ---------------------------------------------------------------- commands
def cmd_run(args) -> int:
    return _run_config(_load(args.config, args), args)


def cmd_validate(args) -> int:
    import yaml

    from . import budget
    from .io import files as io
    from .scene import build_scene

    cfg = _load(args.config, args)
    try:
        if cfg.arch not in ("auto", "cpu"):  # an arch named explicitly must exist here, as for `run`
            from .backend import resolve_arch

            resolve_arch(cfg.arch, cfg, lambda c: budget.check(c, warn=False))   # and can run this scene
        estimate = budget.check(cfg)  # before the scene: an absurd size is refused, not generated
        scene = build_scene(cfg)
    except ConfigError as e:
        raise locate(e, cfg) from None
    print(yaml.safe_dump(io.config_dict(cfg), sort_keys=False, default_flow_style=None), end="")
    counts = estimate.grid_cells   # the box / domain.dx, or a mapped grid's cells (budget.grid_layout)
    print(f"valid: {scene.n} particles in {len(cfg.bodies)} bod{'y' if len(cfg.bodies) == 1 else 'ies'}, "
          f"grid {'x'.join(map(str, counts))} cells", file=sys.stderr)
    print(estimate.summary(), file=sys.stderr)
    return EXIT_OK


def cmd_demo(args) -> int:
    available = demos()
    if args.list or not args.name:
        if not available:
            _err(f"no demos found in {configs_dir()}")
            return EXIT_INPUT
        width = max(len(n) for n in available)
        for name, path in available.items():
            desc = _describe_demo(path)
            print(f"{name:<{width}}  {desc}".rstrip())
        if not args.list:
            print("\nrun one with: taichi-mpm demo NAME", file=sys.stderr)
        return EXIT_OK
    if args.name not in available:
        raise _InputError(f"unknown demo {args.name!r} (available: {', '.join(available) or 'none'})")
    return _run_config(_load(available[args.name], args), args)


def cmd_render(args) -> int:
    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise _InputError(f"run directory not found: {run_dir}")
    from .io.render import render_run

    try:
        result = render_run(run_dir, color_by=args.color_by, size=args.size, camera=args.camera, movie=args.movie)
    except FileNotFoundError as e:  # not a run directory, or no saved states in it
        raise _InputError(str(e)) from None
    frames = result.get("frames", []) if isinstance(result, dict) else []
    movie = result.get("movie") if isinstance(result, dict) else None
    print(f"rendered {len(frames)} frames into {run_dir / 'frames'}" + (f"; movie {movie}" if movie else ""),
          file=sys.stderr)
    return EXIT_OK


def cmd_compare(args) -> int:
    if not Path(args.config).is_file():
        raise _InputError(f"config file not found: {args.config}")
    from .tools.compare import compare

    overrides = parse_overrides(args.overrides)
    if args.arch:
        overrides["arch"] = args.arch
    log = None if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    with contextlib.redirect_stdout(StringIO() if args.quiet else sys.stderr):  # ti.init's start-up lines
        res = compare(args.config, args.vary, overrides, out=args.out, overwrite=args.overwrite,
                      color_by=args.color_by, size=args.size, camera=args.camera, movie=not args.no_movie, log=log)
    if not args.quiet:
        print(f"comparison in {res['out']}: {len(res['frames'])} frames, "
              + (f"movie {res['movie'].name}, " if res["movie"] else "") + "curves.png, summary.csv", file=sys.stderr)
    return EXIT_OK


def cmd_gui(args) -> int:
    cfg = _load(args.config, args)
    from .tools.gui import NoDisplay, run_gui

    try:
        run_gui(cfg, max_frames=args.max_frames, screenshot=args.screenshot,
                view=None if args.view == "auto" else args.view)
    except ConfigError as e:
        raise locate(e, cfg) from None
    except NoDisplay as e:   # no window can open here: what is missing, what to do instead
        _err(f"gui: {e}")
        return EXIT_INPUT
    return EXIT_OK


def cmd_study(args) -> int:
    path = Path(args.study)
    if not path.is_file():
        raise _InputError(f"study file not found: {path}")
    from .tools.study import print_progress, run_study

    out = run_study(path, out=args.out, jobs=args.jobs, scheduler=args.scheduler, resume=args.resume,
                    overwrite=args.overwrite, allow_problems=args.allow_problems, dry_run=args.dry_run,
                    progress=print_progress)
    if out is not None:
        print(f"study done: results.csv, summary.md and plots in {out}", file=sys.stderr)
    return EXIT_OK


def cmd_advise(args) -> int:
    if args.config is not None and not Path(args.config).is_file():
        raise _InputError(f"config file not found: {args.config}")
    from .tools.advise import main_cli

    return main_cli(args)


def cmd_plot(args) -> int:
    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise _InputError(f"run directory not found: {run_dir}")
    from .io.plots import plot_run

    try:
        written = plot_run(run_dir, probe=args.probe, out=args.out)
    except (FileNotFoundError, ValueError) as e:
        raise _InputError(str(e)) from None
    print(f"wrote {len(written)} plot{'s' if len(written) != 1 else ''}: {', '.join(map(str, written))}",
          file=sys.stderr)
    return EXIT_OK


COMMANDS = {"run": cmd_run, "validate": cmd_validate, "demo": cmd_demo, "render": cmd_render, "compare": cmd_compare,
            "gui": cmd_gui,
            "study": cmd_study, "plot": cmd_plot, "advise": cmd_advise}


def main(argv=None) -> int:
    """Entry point; returns the exit code (the console script passes it to sys.exit)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        return COMMANDS[args.command](args)
    except SystemExit as e:  # --help, --version
        return e.code if isinstance(e.code, int) else EXIT_OK
    except (_InputError, ConfigError) as e:
        _err(str(e))
        return EXIT_INPUT
    except InstabilityError as e:  # outside a run's step loop (e.g. gui, study)
        _err(str(e))
        return EXIT_UNSTABLE
    except ModuleNotFoundError as e:
        if e.name and e.name.startswith("taichi_mpm."):
            _err(f"this command is not available in this installation ({e.name} is missing)")
            return EXIT_FAILURE
        raise
    except KeyboardInterrupt:
        _err("interrupted")
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # `taichi-mpm demo --list | head`: the reader has what it wanted
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so that the interpreter's final flush does not fail again
        return EXIT_OK
    except OSError as e:  # disk full, file-size limit, permission, a link or a file in the way: one line, exit 4
        from .io.files import FileError

        if isinstance(e, FileError):
            _err(e.message)
        elif e.filename is not None:
            _err(f"cannot access {e.filename}: {e.strerror or e}")
        else:
            _err(f"operating-system error: {e.strerror or e}")
        return EXIT_IO


if __name__ == "__main__":
    sys.exit(main())
