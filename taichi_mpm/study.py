"""Speed/accuracy studies: sweep dotted config keys over a base config or an analytic problem.

A study file (see DESIGN.md, "Study contract")::

    study: bases_vs_resolution        # required; output goes to studies/NAME/ unless out= is given
    base: ../mms_1d.yaml              # a config file (relative to the study file), or
    problem: {type: mms_axis_aligned, dim: 1, amplitude: 0.05}
    vary:                             # dotted keys -> values; the cases are the full grid
      solver.basis: [linear, quadratic]
      domain.dx: [0.05, 0.025]
    cases:                            # and/or listed cases (each combined with every grid point)
      - {solver.transfer: pic}
    set: {arch: cpu}                  # overrides applied to every case
    repeats: 1
    metric: error_rms                 # the error column for the Pareto and convergence plots
    time_metric: step_time            # wall_time | step_time | compile_time (Pareto x axis)
    convergence_key: domain.dx
    energy_limit: null                # a finished case whose mechanical energy grew past this
                                      # factor is recorded as unstable ("undetected energy growth")
    timeout: null                     # seconds per case
    samples: 20                       # energy samples per case

Keys starting with `problem.` change the problem spec (`problem.amplitude: [0.01, 0.05]`); the
others are config overrides (`solver.basis`, `bodies.0.velocity`, ...).

Each case runs in its own Python process (`python -m taichi_mpm.study --case CASE.json --result
OUT.json`), so Taichi state is isolated and a crash or hang of one case is recorded as its outcome
without stopping the study. Cases run on a local thread pool (`jobs`) that launches those
processes, or on a Dask distributed cluster (`scheduler`), whose workers launch the same process.
Each finished case is written to `OUT/cases/ID.json`; `results.csv`, the plots and `summary.md`
are rebuilt from those files, and `resume=True` reruns only the cases without a result (and those
that ended in `error`).
"""

import argparse
import concurrent.futures
import copy
import csv
import hashlib
import itertools
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import yaml

from .config import ConfigError, load_config, read_yaml

STUDY_KEYS = {"study", "description", "base", "problem", "vary", "cases", "set", "repeats", "metric",
              "time_metric", "convergence_key", "energy_limit", "timeout", "samples"}
TIME_METRICS = ("wall_time", "step_time", "compile_time")
OUTCOMES = ("ok", "unstable", "error")
RECORD_COLUMNS = ["outcome", "cause", "wall_time", "setup_time", "compile_time", "step_time", "steps",
                  "particles", "particle_steps_per_s", "peak_memory_mb", "sim_time", "energy_ratio_max",
                  "energy_ratio_end", "message"]


# ---------------------------------------------------------------- study file
@dataclass
class Study:
    name: str
    path: Optional[Path]
    base: Optional[str] = None              # absolute path of the base config
    base_data: Optional[dict] = None        # its contents (sent with each case)
    problem: Optional[dict] = None
    vary: dict = field(default_factory=dict)
    cases: list = field(default_factory=list)
    set: dict = field(default_factory=dict)
    repeats: int = 1
    metric: Optional[str] = None
    time_metric: str = "step_time"
    convergence_key: str = "domain.dx"
    energy_limit: Optional[float] = None
    timeout: Optional[float] = None
    samples: int = 20

    @property
    def varied(self) -> list[str]:
        """Every key that differs between cases, in the order first met."""
        keys = list(self.vary)
        for c in self.cases:
            for k in c:
                if k not in keys:
                    keys.append(k)
        return keys

    def expand(self) -> list[dict]:
        """The cases: one dict per (grid point x listed case x repeat)."""
        grid_keys = list(self.vary)
        grid = [dict(zip(grid_keys, values)) for values in itertools.product(*(self.vary[k] for k in grid_keys))]
        listed = self.cases or [{}]
        out = []
        for listed_case in listed:
            for point in grid:
                params = {**point, **listed_case}
                for r in range(self.repeats):
                    out.append(self._case(params, r, len(out)))
        return out

    def _case(self, params: dict, repeat: int, index: int) -> dict:
        problem = copy.deepcopy(self.problem) if self.problem is not None else None
        overrides = dict(self.set)
        for k, v in params.items():
            if k.startswith("problem."):
                if problem is None:
                    raise ConfigError("a problem.* key needs a `problem:` section", key=k, file=self.path)
                _set_dotted(problem, k[len("problem."):], v)
            else:
                overrides[k] = v
        ident = json.dumps(dict(params=params, repeat=repeat, problem=problem, base=self.base, set=self.set,
                                limit=self.energy_limit, samples=self.samples), sort_keys=True, default=str)
        digest = hashlib.sha1(ident.encode()).hexdigest()[:10]
        return dict(id=f"{index:04d}_{digest}", digest=digest, index=index, repeat=repeat, params=params,
                    problem=problem, base=self.base, base_data=self.base_data, overrides=overrides,
                    energy_limit=self.energy_limit, samples=self.samples)


def _set_dotted(data: dict, dotted: str, value):
    node = data
    parts = dotted.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value


def load_study(source) -> Study:
    """A study from a YAML path or a dict; ConfigError (naming the key and file line) when invalid."""
    if isinstance(source, dict):
        data, lines, path = copy.deepcopy(source), {}, None
    else:
        path = Path(source)
        data, lines = read_yaml(path)

    def fail(msg, key=None):
        raise ConfigError(msg, key=key, line=lines.get(key) if key else None, file=path)

    unknown = [k for k in data if k not in STUDY_KEYS]
    if unknown:
        fail(f"unknown key (study keys: {', '.join(sorted(STUDY_KEYS))})", unknown[0])
    name = data.get("study")
    if not isinstance(name, str) or not name or "/" in name:
        fail("required: a study name without '/'", "study")
    if ("base" in data) == ("problem" in data):
        fail("give exactly one of `base` (a config file) or `problem` (an analytic problem spec)", "base" if "base" in data else "study")
    st = Study(name=name, path=path)
    if "base" in data:
        base = Path(data["base"])
        if not base.is_absolute():
            base = (path.parent if path else Path.cwd()) / base
        if not base.is_file():
            fail(f"base config not found: {base}", "base")
        st.base = str(base.resolve())
        st.base_data, _ = read_yaml(base)
    else:
        if not isinstance(data["problem"], dict) or "type" not in data["problem"]:
            fail("must be a mapping with a `type` (e.g. {type: mms_axis_aligned, dim: 1})", "problem")
        st.problem = data["problem"]
    vary = data.get("vary") or {}
    if not isinstance(vary, dict):
        fail("must map dotted keys to lists of values", "vary")
    for k, v in vary.items():
        if not isinstance(v, list) or not v:
            fail("must be a non-empty list of values", f"vary.{k}")
    st.vary = vary
    cases = data.get("cases") or []
    if not isinstance(cases, list) or not all(isinstance(c, dict) for c in cases):
        fail("must be a list of mappings of dotted keys to values", "cases")
    st.cases = cases
    st.set = data.get("set") or {}
    if not isinstance(st.set, dict):
        fail("must map dotted keys to values", "set")
    st.repeats = data.get("repeats", 1)
    if not isinstance(st.repeats, int) or st.repeats < 1:
        fail("must be a positive integer", "repeats")
    st.metric = data.get("metric")
    st.time_metric = data.get("time_metric", "step_time")
    if st.time_metric not in TIME_METRICS:
        fail(f"must be one of {', '.join(TIME_METRICS)}", "time_metric")
    st.convergence_key = data.get("convergence_key", "domain.dx")
    st.energy_limit = data.get("energy_limit")
    st.timeout = data.get("timeout")
    st.samples = int(data.get("samples", 20))
    if st.samples < 1:
        fail("must be at least 1", "samples")
    if not st.vary and not st.cases:
        fail("a study needs `vary` or `cases`", "study")
    # validate every case's config here, so a typo fails the study before anything runs
    for case in st.expand():
        try:
            case_config(case)
        except ConfigError as e:
            fail(f"case {case['params']}: {e}", "vary" if st.vary else "cases")
        except (ImportError, AttributeError, KeyError, ValueError, TypeError) as e:
            fail(f"case {case['params']}: invalid problem {case['problem']}: {type(e).__name__}: {e}", "problem")
    return st


def case_config(case: dict):
    """(problem or None, validated Config) of a case."""
    problem = resolve_problem(case["problem"]) if case.get("problem") else None
    if problem is not None:
        return problem, load_config(problem.config(), case["overrides"])
    if case.get("base") and Path(case["base"]).is_file():
        return None, load_config(case["base"], case["overrides"])
    return None, load_config(case["base_data"], case["overrides"])


# ---------------------------------------------------------------- one case (inside its own process)
def resolve_problem(spec: dict):
    """A problem object from a spec: a stability scenario, an analytic problem, or `module:factory`."""
    kind = spec.get("type", "")
    if ":" in kind:
        import importlib
        module, attr = kind.split(":", 1)
        return getattr(importlib.import_module(module), attr)(spec)
    from . import stability
    if kind in stability.SCENARIOS:
        return stability.make_scenario(spec)
    from . import analytic
    return analytic.make_problem(spec)


def run_case_inline(case: dict) -> dict:
    """Run one case in this process and return its record (never raises)."""
    from .errors import InstabilityError

    rec: dict[str, Any] = dict(case=case["id"], repeat=case["repeat"], outcome="error", cause="", message="")
    for k, v in case["params"].items():
        rec[k] = v
    t_start = time.perf_counter()
    setup_time = compile_time = step_time = 0.0
    sim, e_max, ref = None, float("nan"), 0.0
    clock = {"t0": t_start, "compile": 0.0}  # start of the timed span; compile time of the first step
    try:
        problem, cfg = case_config(case)
        from .solver import Simulation
        sim = Simulation(cfg, body_force=getattr(problem, "body_force", None))
        if problem is not None and hasattr(problem, "setup"):
            problem.setup(sim)
        rec["particles"] = sim.n
        observe = getattr(problem, "observe", None)
        e0 = _mech_energy(sim)  # compiles the energy kernel outside the timed stepping
        g0 = e0[1]
        ref = e0[0]
        e_max = 1.0
        end = cfg.solver.end_time
        marks = [end * (k + 1) / case.get("samples", 20) for k in range(case.get("samples", 20))]
        setup_time = time.perf_counter() - t_start
        clock["t0"] = time.perf_counter()

        def after_step(s):
            if s.n_steps == 1:  # the first step holds the JIT compile
                clock["compile"] = time.perf_counter() - clock["t0"]
                clock["t0"] = time.perf_counter()
            if observe is not None:
                t_obs = time.perf_counter()
                observe(s)
                if s.n_steps > 1:
                    clock["t0"] += time.perf_counter() - t_obs  # observation is not stepping time

        for mark in marks:
            sim.advance_to(mark, on_step=after_step)
            if sim.time < mark:  # stopped by solver.max_steps
                break
            t_sample = time.perf_counter()
            e, _ = _mech_energy(sim, g0)
            if not math.isfinite(e):
                raise _Undetected("non-finite energy without a solver error")
            if ref > 0:
                e_max = max(e_max, e / ref)
            clock["t0"] += time.perf_counter() - t_sample  # energy sampling is not stepping time
        compile_time = clock["compile"]
        step_time = time.perf_counter() - clock["t0"]
        p = sim.particles()
        import numpy as np
        if not (np.all(np.isfinite(p["x"])) and np.all(np.isfinite(p["v"]))):
            raise _Undetected("non-finite particle state without a solver error")
        e_end, _ = _mech_energy(sim, g0)
        limit = case.get("energy_limit")
        if limit and ref > 0 and e_max > limit:  # judged at the end: a later solver error takes precedence
            raise _Undetected(f"mechanical energy grew to {e_max:.3g} x its initial value without a solver error")
        rec["energy_ratio_max"] = e_max if ref > 0 else float("nan")
        rec["energy_ratio_end"] = e_end / ref if ref > 0 else float("nan")
        if problem is not None and hasattr(problem, "errors"):
            for name, value in problem.errors(sim).items():
                rec[name] = _plain(value)
        rec["outcome"] = "ok"
    except InstabilityError as e:
        rec["energy_ratio_max"] = e_max if ref > 0 else float("nan")
        rec.update(outcome="unstable", cause=e.cause, message=str(e), fail_step=e.step, fail_time=e.time)
    except _Undetected as e:
        rec["energy_ratio_max"] = e_max
        rec.update(outcome="unstable", cause=f"undetected: {e}", message=str(e))
    except Exception as e:  # noqa: BLE001 - every failure becomes the case's outcome
        rec.update(outcome="error", message=f"{type(e).__name__}: {e}", traceback=traceback.format_exc()[-2000:])
    if rec["outcome"] != "ok" and sim is not None and setup_time > 0:  # stopped early: time up to the stop
        compile_time = clock["compile"]
        if compile_time == 0.0 and sim.n_steps >= 1:
            compile_time = time.perf_counter() - clock["t0"]
        elif step_time == 0.0 and sim.n_steps > 1:
            step_time = time.perf_counter() - clock["t0"]
    rec["setup_time"] = setup_time
    rec["compile_time"] = compile_time
    rec["step_time"] = step_time
    rec["wall_time"] = time.perf_counter() - t_start
    if sim is not None:
        rec["steps"] = sim.n_steps
        rec["sim_time"] = sim.time
        timed_steps = sim.n_steps - 1 if step_time > 0 else sim.n_steps
        timed = step_time if step_time > 0 else compile_time
        rec["particle_steps_per_s"] = sim.n * timed_steps / timed if timed > 0 and timed_steps > 0 else float("nan")
    rec["peak_memory_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB
    return rec


class _Undetected(Exception):
    """The run finished but its state is garbage that the solver did not report."""


def _mech_energy(sim, g0=None):
    """(kinetic + strain + gravity change, gravity) ; the gravity datum is the initial state."""
    e = sim.energy()
    g = e["gravity"]
    return e["kinetic"] + e["strain"] + (g - (g0 if g0 is not None else g)), g


def _plain(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return v if isinstance(v, (str, bool, int)) or v is None else str(v)


# ---------------------------------------------------------------- one case (launcher side)
def execute_case(case: dict, timeout: Optional[float] = None, threads: Optional[int] = None,
                 pythonpath: Optional[list] = None) -> dict:
    """Run a case in a fresh Python process and return its record. Used locally and on Dask workers."""
    with tempfile.TemporaryDirectory(prefix="tmpm_case_") as tmp:
        case_file, result_file, log_file = (Path(tmp) / n for n in ("case.json", "result.json", "log.txt"))
        case_file.write_text(json.dumps(case, default=str))
        env = dict(os.environ)
        if threads:
            env["TI_CPU_MAX_NUM_THREADS"] = str(threads)
        paths = [p for p in (pythonpath or []) if p] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
        if paths:
            env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
        cmd = [sys.executable, "-m", "taichi_mpm.study", "--case", str(case_file), "--result", str(result_file)]
        t0 = time.perf_counter()
        with open(log_file, "wb") as log:
            try:
                proc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, timeout=timeout, env=env)
                rc = proc.returncode
            except subprocess.TimeoutExpired:
                rc = None
        if result_file.is_file():
            return json.loads(result_file.read_text())
        tail = log_file.read_text(errors="replace")[-1500:] if log_file.is_file() else ""
        rec = dict(case=case["id"], repeat=case["repeat"], **case["params"], outcome="error",
                   wall_time=time.perf_counter() - t0)
        rec["message"] = (f"timed out after {timeout:g} s" if rc is None else
                          f"case process exited with code {rc} without a result") + (f"; log: {tail}" if tail else "")
        return rec


# ---------------------------------------------------------------- the study
def run_study(study_path, out=None, jobs: int = 1, scheduler: Optional[str] = None, resume: bool = False,
              progress=None) -> Path:
    """Run every case of a study (skipping finished ones with resume) and write the reports; returns the output dir."""
    st = load_study(study_path)
    out = Path(out) if out is not None else Path("studies") / st.name
    case_dir = out / "cases"
    if case_dir.is_dir() and not resume:
        for f in case_dir.glob("*.json"):
            f.unlink()
    case_dir.mkdir(parents=True, exist_ok=True)
    cases = st.expand()
    done = _finished(case_dir) if resume else {}
    todo = [c for c in cases if done.get(c["digest"], {}).get("outcome") not in ("ok", "unstable")]
    (out / "study.yaml").write_text(yaml.safe_dump(_study_dump(st), sort_keys=False))

    def store(case, rec):
        rec["digest"] = case["digest"]
        (case_dir / f"{case['id']}.json").write_text(json.dumps(rec, indent=1, default=str))
        if progress:
            progress(case, rec)

    if scheduler:
        _run_dask(todo, scheduler, st.timeout, store)
    else:
        jobs = max(1, int(jobs or 1))
        threads = max(1, (os.cpu_count() or 1) // jobs) if jobs > 1 else None
        with concurrent.futures.ThreadPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(execute_case, c, st.timeout, threads, _user_paths()): c for c in todo}
            for fut in concurrent.futures.as_completed(futures):
                store(futures[fut], fut.result())
    write_reports(st, out)
    return out


def _run_dask(cases, scheduler, timeout, store):
    try:
        from dask.distributed import Client, as_completed
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ConfigError("--scheduler needs dask.distributed: pip install 'taichi-mpm[study]'") from e
    client = Client(scheduler) if isinstance(scheduler, str) else Client(scheduler)
    try:
        futures = {client.submit(execute_case, c, timeout, None, _user_paths(), pure=False, key=f"case-{c['id']}-{c['digest']}"): c
                   for c in cases}
        for fut in as_completed(list(futures)):
            case = futures[fut]
            try:
                rec = fut.result()
            except Exception as e:  # noqa: BLE001 - a lost worker is the case's outcome
                rec = dict(case=case["id"], repeat=case["repeat"], **case["params"], outcome="error",
                           message=f"dask: {type(e).__name__}: {e}")
            store(case, rec)
    finally:
        client.close()


def _user_paths() -> list[str]:
    """This process's import paths outside the Python installation (project and test dirs), for case processes."""
    import sysconfig
    skip = {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
    return [os.path.abspath(p or ".") for p in sys.path
            if not any(os.path.abspath(p or ".").startswith(s) for s in skip) and "site-packages" not in p
            and not p.endswith(".zip")]


def _finished(case_dir: Path) -> dict:
    out = {}
    for f in case_dir.glob("*.json"):
        try:
            rec = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        out[rec.get("digest")] = rec
    return out


def _study_dump(st: Study) -> dict:
    d = dict(study=st.name)
    if st.base:
        d["base"] = st.base
    else:
        d["problem"] = st.problem
    for k in ("vary", "cases", "set"):
        if getattr(st, k):
            d[k] = getattr(st, k)
    d.update(repeats=st.repeats, metric=st.metric, time_metric=st.time_metric, convergence_key=st.convergence_key,
             energy_limit=st.energy_limit, timeout=st.timeout, samples=st.samples)
    return d


# ---------------------------------------------------------------- reports
def collect(st: Study, out: Path) -> list[dict]:
    """The records of this study's cases, in case order."""
    done = _finished(out / "cases")
    return [done[c["digest"]] for c in st.expand() if c["digest"] in done]


def write_reports(st: Study, out: Path) -> list[dict]:
    """results.csv, pareto.png, convergence.png and summary.md from the case records."""
    import matplotlib
    matplotlib.use("Agg")
    records = collect(st, out)
    varied = st.varied
    error_cols = sorted({k for r in records for k in r if k.startswith("error_") and k not in varied})
    extra = sorted({k for r in records for k in r} - set(varied) - set(error_cols) - set(RECORD_COLUMNS)
                   - {"case", "repeat", "digest", "traceback", "fail_step", "fail_time"})
    columns = ["case", "repeat", *varied, *RECORD_COLUMNS[:2], *error_cols, *RECORD_COLUMNS[2:], "fail_step",
               "fail_time", *extra]
    with open(out / "results.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, columns, extrasaction="ignore")
        w.writeheader()
        for r in records:
            w.writerow({k: _cell(r.get(k, "")) for k in columns})
    metric = st.metric or (error_cols[0] if "error_rms" not in error_cols and error_cols else "error_rms")
    if metric not in error_cols and not any(metric in r for r in records):
        metric = "energy_drift"
        for r in records:
            if r.get("outcome") == "ok" and _finite(r.get("energy_ratio_end")):
                r["energy_drift"] = abs(float(r["energy_ratio_end"]) - 1.0)
    points = _aggregate(records, varied, metric, st.time_metric)
    group_keys = [k for k in varied if k != st.convergence_key]
    front = pareto_front(points)
    fits = convergence_rates(points, group_keys, st.convergence_key)
    plot_pareto(points, front, group_keys, metric, st.time_metric, out / "pareto.png", st.name)
    plot_convergence(points, fits, group_keys, st.convergence_key, metric, out / "convergence.png", st.name)
    (out / "summary.md").write_text(summary_markdown(st, records, varied, metric, front, fits))
    return records


def _cell(v):
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    if isinstance(v, float):
        return f"{v:.6g}"
    return v


def _finite(v) -> bool:
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def _aggregate(records, varied, metric, time_metric) -> list[dict]:
    """One point per parameter set (repeats merged: median time, mean error) from the ok cases."""
    groups: dict[str, list] = {}
    for r in records:
        if r.get("outcome") != "ok" or not _finite(r.get(metric)) or not _finite(r.get(time_metric)):
            continue
        key = json.dumps({k: r.get(k) for k in varied}, sort_keys=True, default=str)
        groups.setdefault(key, []).append(r)
    points = []
    for key, rs in groups.items():
        times = sorted(float(r[time_metric]) for r in rs)
        points.append(dict(params=json.loads(key), error=sum(float(r[metric]) for r in rs) / len(rs),
                           time=times[len(times) // 2], n=len(rs)))
    return points


def pareto_front(points: list[dict]) -> list[dict]:
    """Points no other point beats in both time and error, sorted by time."""
    front, best = [], math.inf
    for p in sorted(points, key=lambda p: (p["time"], p["error"])):
        if p["error"] < best:
            front.append(p)
            best = p["error"]
    return front


def convergence_rates(points, group_keys, conv_key) -> dict:
    """Least-squares slope of log(error) against log(conv_key) per group (needs two or more values)."""
    fits = {}
    for label, pts in _groups(points, group_keys).items():
        pts = [p for p in pts if _finite(p["params"].get(conv_key)) and p["error"] > 0]
        hs = sorted({float(p["params"][conv_key]) for p in pts})
        if len(hs) < 2:
            continue
        xs = [math.log(float(p["params"][conv_key])) for p in pts]
        ys = [math.log(p["error"]) for p in pts]
        mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
        sxx = sum((x - mx) ** 2 for x in xs)
        slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx
        fits[label] = dict(rate=slope, intercept=my - slope * mx, points=sorted(pts, key=lambda p: -float(p["params"][conv_key])))
    return fits


def _label(params, group_keys) -> str:
    return "/".join(_short(params.get(k)) for k in group_keys) or "all"


def _short(v) -> str:
    return json.dumps(v) if isinstance(v, (list, dict)) else f"{v:g}" if isinstance(v, float) else str(v)


def _groups(points, group_keys) -> dict:
    out: dict[str, list] = {}
    for p in points:
        out.setdefault(_label(p["params"], group_keys), []).append(p)
    return out


def plot_pareto(points, front, group_keys, metric, time_metric, path, title):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=90)
    for label, pts in sorted(_groups(points, group_keys).items()):
        ax.scatter([p["time"] for p in pts], [p["error"] for p in pts], label=label, s=28, alpha=0.8)
    if front:
        ax.step([p["time"] for p in front], [p["error"] for p in front], where="post", color="k", lw=1.2,
                label="Pareto front")
        ax.scatter([p["time"] for p in front], [p["error"] for p in front], s=90, facecolors="none",
                   edgecolors="k", lw=1.2)
    if not points:
        ax.text(0.5, 0.5, "no finished case with an error value", ha="center", transform=ax.transAxes)
    else:
        if all(p["time"] > 0 for p in points):
            ax.set_xscale("log")
        if all(p["error"] > 0 for p in points):
            ax.set_yscale("log")
    xlabel = {"step_time": "stepping wall time [s] (JIT excluded)", "wall_time": "wall time [s]",
              "compile_time": "first step (JIT) time [s]"}[time_metric]
    ax.set_xlabel(xlabel)
    ax.set_ylabel(metric)
    ax.set_title(f"{title}: error vs time")
    ax.grid(True, which="both", alpha=0.3)
    if points and len(_groups(points, group_keys)) <= 16:
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_convergence(points, fits, group_keys, conv_key, metric, path, title):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=90)
    for label, pts in sorted(_groups(points, group_keys).items()):
        pts = [p for p in pts if _finite(p["params"].get(conv_key))]
        if not pts:
            continue
        pts.sort(key=lambda p: float(p["params"][conv_key]))
        hs = [float(p["params"][conv_key]) for p in pts]
        fit = fits.get(label)
        name = f"{label}: slope {fit['rate']:.2f}" if fit else label
        line, = ax.plot(hs, [p["error"] for p in pts], "o", label=name)
        if fit:
            ax.plot(hs, [math.exp(fit["intercept"]) * h ** fit["rate"] for h in hs], "-", color=line.get_color(), lw=1)
    if any(_finite(p["params"].get(conv_key)) for p in points):
        ax.set_xscale("log")
        if all(p["error"] > 0 for p in points):
            ax.set_yscale("log")
        if len(fits) <= 16:
            ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, f"{conv_key} is not varied in this study", ha="center", transform=ax.transAxes)
    ax.set_xlabel(conv_key)
    ax.set_ylabel(metric)
    ax.set_title(f"{title}: convergence")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def summary_markdown(st, records, varied, metric, front, fits) -> str:
    counts = {o: sum(r.get("outcome") == o for r in records) for o in OUTCOMES}
    lines = [f"# Study `{st.name}`", "",
             f"{len(records)} cases: " + ", ".join(f"{n} {o}" for o, n in counts.items()) + ".",
             f"Error metric `{metric}`; time metric `{st.time_metric}`.", "", "## Cases", ""]
    cols = [*varied, "outcome", metric, "wall_time", "compile_time", "step_time", "steps", "particle_steps_per_s",
            "peak_memory_mb", "cause"]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "---|" * len(cols))
    for r in records:
        lines.append("| " + " | ".join(_md(r.get(c, "")) for c in cols) + " |")
    if fits:
        ck = st.convergence_key
        hs = sorted({float(p["params"][ck]) for fit in fits.values() for p in fit["points"]}, reverse=True)
        lines += ["", f"## Convergence (slope of log {metric} against log {ck})", "",
                  "| group | rate | " + " | ".join(f"{ck}={h:g}" for h in hs) + " |", "|---|---|" + "---|" * len(hs)]
        for label, fit in fits.items():
            err = {float(p["params"][ck]): p["error"] for p in fit["points"]}
            lines.append(f"| {label} | {fit['rate']:.2f} | " + " | ".join(f"{err[h]:.3g}" if h in err else "-" for h in hs) + " |")
    if front:
        lines += ["", "## Pareto front (fastest first)", "", "| " + " | ".join(varied) + f" | {st.time_metric} | {metric} |",
                  "|" + "---|" * (len(varied) + 2)]
        for p in front:
            lines.append("| " + " | ".join(_md(p["params"].get(k)) for k in varied) + f" | {p['time']:.3g} | {p['error']:.3g} |")
    return "\n".join(lines) + "\n"


def _md(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v).replace("|", "/").replace("\n", " ")[:120]


# ---------------------------------------------------------------- entry point of a case process
def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m taichi_mpm.study", description="run one study case (internal) or a study")
    ap.add_argument("study", nargs="?", help="a study YAML file (runs the whole study)")
    ap.add_argument("--case", help="case JSON file (internal: run one case in this process)")
    ap.add_argument("--result", help="where to write the case record (with --case)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--scheduler")
    ap.add_argument("--out")
    ap.add_argument("--resume", action="store_true")
    args = ap.parse_args(argv)
    if args.case:
        rec = run_case_inline(json.loads(Path(args.case).read_text()))
        Path(args.result).write_text(json.dumps(rec, default=str))
        return 0
    if not args.study:
        ap.error("give a study file or --case")
    try:
        out = run_study(args.study, out=args.out, jobs=args.jobs, scheduler=args.scheduler, resume=args.resume,
                        progress=lambda c, r: print(f"{c['id']}: {r.get('outcome')} {r.get('cause', '')}", flush=True))
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
