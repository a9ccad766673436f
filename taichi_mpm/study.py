"""Speed/accuracy studies: sweep dotted config keys over a base config or a built-in problem.

The study file, its checks, the allowed problems (`--allow-problem`), the metrics and the output folder are
described in docs/study.md. In short::

    study: bases_vs_resolution        # required; names the output folder studies/NAME (--out overrides)
    problem: {type: mms_axis_aligned, dim: 1, amplitude: 0.05}     # or base: a config file
    vary: {solver.basis: [linear, quadratic], domain.dx: [0.05, 0.025]}
    cases: [{solver.transfer: pic}]   # each combined with every grid point

`load_study` checks everything before anything runs and imports nothing outside the project unless allowed.
Each case runs in its own Python process (`python -m taichi_mpm.study --case CASE.json --result OUT.json`), so
Taichi state is isolated and a crash or hang of one case is recorded as its outcome without stopping the study.
Cases run on a local thread pool (`jobs`) that launches those processes, or on a Dask distributed cluster
(`scheduler`), whose workers launch the same process. Each finished case is written to `OUT/cases/ID.json`;
`results.csv`, the plots and `summary.md` are rebuilt from those files, and `resume=True` reruns only the
cases without a result (and those that ended in `error`).
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
import re
import reprlib
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import yaml

from . import observe as obs
from .config import ConfigError, load_config, read_yaml
from .errors import InstabilityError

STUDY_KEYS = {"study", "description", "base", "problem", "vary", "cases", "set", "repeats", "metric",
              "time_metric", "convergence_key", "energy_limit", "timeout", "samples", "jobs", "observe", "reference",
              "timing"}
# timing: each case's stepping is rerun (same process, compiled kernels kept) until the spread of its step times,
# (max - min) / median, is at most `spread`, or `runs` runs were made; the median is reported (issue 16: one run's
# time on a loaded machine is noise)
TIMING_DEFAULT = {"runs": 3, "spread": 0.1}   # runs: 0 times the first run alone (its compile left out)
TIME_METRICS = ("wall_time", "step_time", "compile_time")
OUTCOMES = ("ok", "unstable", "error")
RECORD_COLUMNS = ["outcome", "cause", "wall_time", "setup_time", "compile_time", "step_time", "time_spread",
                  "timing_runs", "steps", "particles", "particle_steps_per_s", "peak_memory_mb", "sim_time",
                  "energy_ratio_max", "energy_ratio_end", "message"]
# metrics (error columns for the plots) every case has, and those each project problem adds (its errors() keys;
# tests/test_study.py checks that every analytic problem and stability scenario is listed)
COMMON_METRICS = ("energy_drift", "energy_ratio_max", "energy_ratio_end")
PROBLEM_METRICS = {
    "vibrating_bar": ("error_rms", "error_max", "error_com_velocity", "error_rel"),
    "mms_axis_aligned": ("error_rms", "error_max", "error_rel"),
    "generalized_vortex": ("error_rms", "error_max"),
    "colliding_disks": ("error_energy", "energy_ratio_min"),
    "hertz": ("error_contact_time", "contact_time", "contact_time_hertz"),
    **{s: ("j_min", "j_max", "speed_over_c") for s in ("impact", "compression", "rotation", "thin", "edge")},
}
STUDY_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}")   # a plain folder name: no separator, no leading dot
MAX_CASES = 10_000      # a study expanding to more cases is almost surely a typo (and would take ages to list)
MAX_SAMPLES = 10_000
# what a study writes into its output folder; an existing one of these marks a folder holding results
OUTPUTS = ("study.yaml", "cases", "results.csv", "summary.md", "pareto.png", "convergence.png")


def default_jobs() -> int:
    """Cases in parallel by default: one per core minus one, so timings are not skewed by a busy machine."""
    return max(1, (os.cpu_count() or 1) - 1)


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
    jobs: int = field(default_factory=default_jobs)
    observe: Optional[dict] = None          # the quantity of interest (observe.parse), or None
    reference: Any = None                   # a number, exact, finest or richardson (with observe)
    timing: dict = field(default_factory=lambda: dict(TIMING_DEFAULT))
    allow_problems: tuple = ()             # `module:factory` problems the user opted in to
    lines: dict = field(default_factory=dict, repr=False)   # dotted key -> line in the study file

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
                _set_dotted(problem, k[len("problem."):], v)
            else:
                overrides[k] = v
        ident = dict(params=params, repeat=repeat, problem=problem, base=self.base, set=self.set,
                     limit=self.energy_limit, samples=self.samples)
        if self.observe is not None:   # (kept out of older studies' digests, so their --resume still matches)
            ident["observe"] = self.observe["text"]
        ident = json.dumps(ident, sort_keys=True, default=str)
        digest = hashlib.sha1(ident.encode()).hexdigest()[:10]
        return dict(id=f"{index:04d}_{digest}", digest=digest, index=index, repeat=repeat, params=params,
                    problem=problem, base=self.base, base_data=self.base_data, overrides=overrides,
                    energy_limit=self.energy_limit, samples=self.samples,
                    allow_problems=list(self.allow_problems), observe=self.observe, timing=self.timing)


def _set_dotted(data: dict, dotted: str, value):
    node = data
    parts = dotted.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ConfigError(f"problem.{dotted}: cannot set a key inside the value {node!r}")
    node[parts[-1]] = value


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


_repr = reprlib.Repr()  # values in messages, cut short
_repr.maxlevel, _repr.maxlist, _repr.maxdict, _repr.maxstring, _repr.maxother = 3, 6, 6, 60, 60


def _what(v) -> str:
    """How a wrong value is named in a message; a YAML 1.1 pitfall gets a hint."""
    if isinstance(v, str):
        try:
            float(v)
            return f"the text {_repr.repr(v)} (YAML reads 1e3 as text: write 1.0e3)"
        except ValueError:
            return f"the text {_repr.repr(v)}"
    return "null" if v is None else str(v).lower() if isinstance(v, bool) else _repr.repr(v)


def _non_text_key(data, path=""):
    """(dotted path of the mapping, key) of the first key that is not text (a number, a boolean, null), or None."""
    stack = [(path, data)]
    while stack:
        where, v = stack.pop()
        items = v.items() if isinstance(v, dict) else enumerate(v) if isinstance(v, list) else ()
        for k, child in items:
            if isinstance(v, dict) and not isinstance(k, str):
                return where, k
            stack.append((f"{where}.{k}" if where else str(k), child))
    return None


def _dotted_ok(k) -> bool:
    return isinstance(k, str) and bool(k) and all(k.split("."))


def load_study(source, allow_problems=()) -> Study:
    """A study from a YAML path or a dict; ConfigError (naming the key and file line) when invalid.

    Nothing outside the project runs while loading: a `module:factory` problem is imported (and called, to
    validate its cases) only when it is in `allow_problems`; any other problem type is refused before that."""
    if isinstance(source, dict):
        data, lines, path = copy.deepcopy(source), {}, None
    else:
        path = Path(source)
        data, lines = read_yaml(path)
    fail = _Refusal(lines, path)
    st = _study_head(data, fail, path, tuple(allow_problems or ()), lines)
    _read_sweep(st, data, fail)
    _read_settings(st, data, fail)
    # problem types: the project's own, or opted-in `module:factory`; checked before anything is imported
    types = _problem_types(st)
    for key, kind in types:
        why = problem_refused(kind, st.allow_problems)
        if why:
            fail(why, key)
    _read_observe_and_metric(st, data, fail, [t for _, t in types] if types else [None])
    settled = _check_cases(st, fail)   # every case's config, so a typo fails the study before anything runs
    if st.observe is not None:
        st.observe = settled
        try:
            st.reference = obs.check_reference(data.get("reference", obs.default_reference(st.observe)), st.observe)
        except obs.ObserveError as e:
            fail(str(e), "reference")
    return st


class _Refusal:
    """Raises the ConfigError of a bad study file: the message, the key and the line of the key (or of its nearest
    enclosing key), the file."""

    def __init__(self, lines: dict, path: Optional[Path]):
        self.lines, self.path = lines, path

    def __call__(self, msg, key=None):
        line = None
        if key is not None:
            parts = str(key).split(".")
            while parts and line is None:
                line = self.lines.get(".".join(parts))
                parts.pop()
        raise ConfigError(msg, key=key, line=line, file=self.path)


def _study_head(data: dict, fail, path, allow: tuple, lines: dict) -> Study:
    """The study's keys, name, description and its base config or problem."""
    bad_key = _non_text_key(data)
    if bad_key is not None:
        fail(f"keys must be text, got the key {_what(bad_key[1])}", bad_key[0] or None)
    unknown = [k for k in data if k not in STUDY_KEYS]
    if unknown:
        fail(f"unknown key (study keys: {', '.join(sorted(STUDY_KEYS))})", unknown[0])
    name = data.get("study")
    if not isinstance(name, str) or not STUDY_NAME.fullmatch(name):
        fail(f"required: a study name of at most 100 letters, digits, '_', '.' or '-', not starting with '.' "
             f"(it names the output folder studies/NAME), got {_what(name)}", "study")
    if "description" in data and not isinstance(data["description"], str):
        fail("must be text", "description")
    if ("base" in data) == ("problem" in data):
        fail("give exactly one of `base` (a config file) or `problem` (an analytic problem spec)",
             "base" if "base" in data else "study")
    st = Study(name=name, path=path, allow_problems=allow, lines=lines)
    if "base" in data:
        st.base, st.base_data = _base_config(data["base"], path, fail)
    else:
        problem = data["problem"]
        if not isinstance(problem, dict) or "type" not in problem or not all(isinstance(k, str) for k in problem):
            fail("must be a mapping with a `type` (e.g. {type: mms_axis_aligned, dim: 1})", "problem")
        st.problem = problem
    return st


def _base_config(base, path, fail) -> tuple[str, dict]:
    """(absolute path, contents) of the study's base config; relative paths start at the study file's folder."""
    if not isinstance(base, str) or not base or "\0" in base:
        fail(f"must be the path of a config file, got {_what(base)}", "base")
    found = Path(base)
    if not found.is_absolute():
        found = (path.parent if path else Path.cwd()) / found
    if not found.is_file():
        fail(f"base config not found: {found}", "base")
    data, _ = read_yaml(found)
    return str(found.resolve()), data


def _read_sweep(st: Study, data: dict, fail):
    """`vary`, `cases` and `set`: what differs between the cases and what all of them share."""
    vary = data.get("vary") or {}
    if not isinstance(vary, dict):
        fail("must map dotted keys to lists of values", "vary")
    for k, v in vary.items():
        if not _dotted_ok(k):
            fail(f"must map dotted keys (e.g. solver.basis) to lists of values, got the key {_what(k)}", "vary")
        if not isinstance(v, list) or not v:
            fail(f"must be a non-empty list of values, got {_what(v)}", f"vary.{k}")
    st.vary = vary
    cases = data.get("cases") or []
    if not isinstance(cases, list):
        fail("must be a list of mappings of dotted keys to values", "cases")
    for i, c in enumerate(cases):
        if not isinstance(c, dict) or not c or not all(_dotted_ok(k) for k in c):
            fail(f"must be a mapping of dotted keys to values, got {_what(c)}", f"cases.{i}")
    st.cases = cases
    st.set = data.get("set") or {}
    if not isinstance(st.set, dict) or not all(_dotted_ok(k) for k in st.set):
        fail("must map dotted keys to values", "set")
    for k in st.set:
        if k.startswith("problem."):
            fail("`set` holds config overrides; put problem parameters in `problem:`", f"set.{k}")
    if st.problem is None:
        for k in st.varied:
            if k.startswith("problem."):
                fail("a problem.* key needs a `problem:` section (this study has a `base`)",
                     f"vary.{k}" if k in st.vary else "cases")


def _whole(data: dict, fail, key: str, default, limit=None) -> int:
    v = data.get(key, default)
    if not isinstance(v, int) or isinstance(v, bool) or v < 1 or (limit and v > limit):
        fail(f"must be a whole number from 1{f' to {limit}' if limit else ''}, got {_what(v)}", key)
    return v


def _positive_or_null(data: dict, fail, key: str):
    v = data.get(key)
    if v is not None and (not _is_number(v) or v <= 0):
        fail(f"must be a positive number or null, got {_what(v)}", key)
    return v


def _read_settings(st: Study, data: dict, fail):
    """The counts, limits, timing and metric keys, and the number of cases the study expands to."""
    st.repeats = _whole(data, fail, "repeats", 1)
    st.samples = _whole(data, fail, "samples", 20, MAX_SAMPLES)
    st.jobs = _whole(data, fail, "jobs", default_jobs())
    st.timing = _read_timing(data, fail)
    st.energy_limit = _positive_or_null(data, fail, "energy_limit")
    st.timeout = _positive_or_null(data, fail, "timeout")
    st.time_metric = data.get("time_metric", "step_time")
    if st.time_metric not in TIME_METRICS:
        fail(f"must be one of {', '.join(TIME_METRICS)}, got {_what(st.time_metric)}", "time_metric")
    st.convergence_key = data.get("convergence_key", "domain.dx")
    if not _dotted_ok(st.convergence_key):
        fail(f"must be a dotted key (e.g. domain.dx), got {_what(st.convergence_key)}", "convergence_key")
    if not st.vary and not st.cases:
        fail("a study needs `vary` or `cases`", "study")
    n_cases = math.prod(len(v) for v in st.vary.values()) * max(1, len(st.cases)) * st.repeats
    if n_cases > MAX_CASES:
        fail(f"expands to {n_cases} cases (at most {MAX_CASES}: split the study)", "vary" if st.vary else "cases")


def _read_timing(data: dict, fail) -> dict:
    timing = data.get("timing", {})
    if not isinstance(timing, dict) or set(timing) - set(TIMING_DEFAULT):
        fail("must be a mapping {runs: N, spread: S} (runs of each case's stepping, until the time spread "
             "(max - min) / median is at most S)", "timing")
    timing = {**TIMING_DEFAULT, **timing}
    runs, spread = timing["runs"], timing["spread"]
    if not isinstance(runs, int) or isinstance(runs, bool) or not 0 <= runs <= 100:
        fail(f"must be a whole number from 0 to 100, got {_what(runs)}", "timing.runs")
    if not _is_number(spread) or spread <= 0:
        fail(f"must be a positive number, got {_what(spread)}", "timing.spread")
    return timing


def _problem_types(st: Study) -> list[tuple[str, Any]]:
    """(key, problem type) of every problem type the study names: its problem's and those it varies."""
    if st.problem is None:
        return []
    types = [("problem.type", st.problem["type"])]
    types += [(f"vary.problem.type.{j}", t) for j, t in enumerate(st.vary.get("problem.type", []))]
    types += [(f"cases.{i}.problem.type", c["problem.type"]) for i, c in enumerate(st.cases) if "problem.type" in c]
    return types


def _read_observe_and_metric(st: Study, data: dict, fail, types: list):
    """The quantity of interest (`observe`, parsed; checked per case later) and the error metric of the reports."""
    if "observe" in data:
        try:
            st.observe = obs.parse(data["observe"])
        except obs.ObserveError as e:
            fail(str(e), "observe")
    elif "reference" in data:
        fail("a reference needs the quantity it is for: add `observe`", "reference")
    st.metric = data.get("metric")
    if st.metric is None and st.observe is not None:
        st.metric = "error_observed"
    if st.metric is None:
        return
    if not isinstance(st.metric, str):
        fail(f"must be the name of a metric, got {_what(st.metric)}", "metric")
    known = known_metrics(types)
    if known is not None and st.observe is not None:
        known = known + ["observed", "error_observed"]
    if known is not None and st.metric not in known:
        fail(f"unknown metric {st.metric!r} for this study (known: {', '.join(known)})", "metric")


def _check_cases(st: Study, fail) -> Optional[dict]:
    """Validate every case's config and problem (and the quantity of interest in each); returns the quantity as
    the cases settled it (observe.check), or None without one."""
    where = "vary" if st.vary else "cases"
    try:
        cases = st.expand()
    except ConfigError as e:
        fail(str(e), where)
    settled = None
    for case in cases:
        cfg = _case_config_checked(case, st.allow_problems, fail, where)
        if st.observe is not None:   # the quantity exists in every case (its probe, its problem's metric)
            kind = (case["problem"] or {}).get("type") if case["problem"] is not None else None
            try:
                spec = obs.check(st.observe, cfg, known_metrics([kind]), st.allow_problems)
            except obs.ObserveError as e:
                fail(f"{e}" + (f" (case {_repr.repr(case['params'])})" if len(cases) > 1 else ""), "observe")
            if settled is not None and spec["kind"] != settled["kind"]:
                fail(f"{st.observe['text']} is a {settled['kind']} in one case and a {spec['kind']} in another",
                     "observe")
            settled = spec
    return settled


def _case_config_checked(case: dict, allow, fail, where: str):
    """A case's validated Config; a refused problem, a bad config or a problem refusing its parameters fails the
    study naming the case."""
    try:
        why = problem_refused((case["problem"] or {}).get("type"), allow) if case["problem"] is not None else None
        if why:   # e.g. a problem.type.x key that turned the type into a mapping
            raise ConfigError(why)
        _, cfg = case_config(case)
    except ConfigError as e:
        fail(f"case {_repr.repr(case['params'])}: {e}", where)
    except Exception as e:  # noqa: BLE001 - a project (or opted-in) problem refusing its parameters
        fail(f"case {_repr.repr(case['params'])}: invalid problem {_repr.repr(case['problem'])}: "
             f"{type(e).__name__}: {e}", "problem")
    return cfg


def problem_refused(kind, allow=()) -> Optional[str]:
    """Why a problem type may not run from a study file (None when it may): the project's analytic problems and
    stability scenarios always may; a `module:factory` only when the user allowed it (--allow-problem)."""
    from . import analytic, stability
    if not isinstance(kind, str):
        return f"a problem type must be a name (e.g. mms_axis_aligned), got {_what(kind)}"
    if kind in analytic.PROBLEMS or kind in stability.SCENARIOS:
        return None
    if ":" in kind:
        if kind in allow:
            return None
        return (f"problem {kind!r} is not one of the project's problems: a study file cannot run other code unless "
                f"you allow it on the command line (taichi-mpm study STUDY.yaml --allow-problem {kind})")
    return (f"unknown problem {kind!r} (analytic problems: {', '.join(analytic.PROBLEMS)}; "
            f"stability scenarios: {', '.join(stability.SCENARIOS)})")


def known_metrics(types) -> Optional[list[str]]:
    """Metrics every case of these problem types reports (None for a base config: type None), or None when an
    opted-in `module:factory` problem is among them (its metrics are its own)."""
    out = None
    for kind in types:
        if isinstance(kind, str) and ":" in kind:
            return None
        have = list(COMMON_METRICS) + list(PROBLEM_METRICS.get(kind, ()))
        out = have if out is None else [m for m in out if m in have]
    return out


def case_config(case: dict):
    """(problem or None, validated Config) of a case."""
    problem = resolve_problem(case["problem"], case.get("allow_problems", ())) if case.get("problem") else None
    if problem is not None:
        return problem, load_config(problem.config(), case["overrides"])
    if case.get("base") and Path(case["base"]).is_file():
        return None, load_config(case["base"], case["overrides"])
    return None, load_config(case["base_data"], case["overrides"])


# ---------------------------------------------------------------- one case (inside its own process)
def resolve_problem(spec: dict, allow=()):
    """A problem object from a spec: a stability scenario, an analytic problem, or an allowed `module:factory`.
    Raises ConfigError, importing nothing, for any other type."""
    kind = spec.get("type")
    why = problem_refused(kind, allow)
    if why:
        raise ConfigError(why, key="problem.type")
    from . import stability
    if kind in stability.SCENARIOS:
        return stability.make_scenario(spec)
    from . import analytic
    if kind in analytic.PROBLEMS:
        return analytic.make_problem(spec)
    import importlib
    module, attr = kind.split(":", 1)
    return getattr(importlib.import_module(module), attr)(spec)


def run_case_inline(case: dict) -> dict:
    """Run one case in this process and return its record (never raises)."""
    run = _CaseRun(case)
    try:
        run.setup()
        run.step()
        run.finish()
        run.rec["outcome"] = "ok"
    except InstabilityError as e:
        run.rec["energy_ratio_max"] = run.e_max if run.ref > 0 else float("nan")
        run.rec.update(outcome="unstable", cause=e.cause, message=str(e), fail_step=e.step, fail_time=e.time)
    except _Undetected as e:
        run.rec["energy_ratio_max"] = run.e_max
        run.rec.update(outcome="unstable", cause=f"undetected: {e}", message=str(e))
    except Exception as e:  # noqa: BLE001 - every failure becomes the case's outcome
        run.rec.update(outcome="error", message=f"{type(e).__name__}: {e}", traceback=traceback.format_exc()[-2000:])
    return run.record()


class _CaseRun:
    """One case in this process: its setup, the timed stepping (energy and quantity sampled outside the timing),
    the judgement of the end state, and the record. The clock's t0 is the start of the timed span; JIT compile
    time is the first step's."""

    def __init__(self, case: dict):
        self.case = case
        self.rec: dict[str, Any] = dict(case=case["id"], repeat=case["repeat"], outcome="error", cause="", message="")
        self.rec.update(case["params"])
        self.t_start = time.perf_counter()
        self.setup_time = self.compile_time = self.step_time = 0.0
        self.sim, self.e_max, self.ref, self.g0 = None, float("nan"), 0.0, None
        self.clock = {"t0": self.t_start, "compile": 0.0}
        self.problem = self.cfg = self.observe = self.sampler = self.state0 = None

    def setup(self):
        from .solver import Simulation

        case = self.case
        self.problem, self.cfg = case_config(case)
        sim = self.sim = Simulation(self.cfg, body_force=getattr(self.problem, "body_force", None))
        if self.problem is not None and hasattr(self.problem, "setup"):
            self.problem.setup(sim)
        self.rec["particles"] = sim.n
        self.observe = getattr(self.problem, "observe", None)
        if case.get("observe"):   # the study's quantity of interest (observe.py), sampled outside the timing
            self.sampler = obs.Sampler(case["observe"], sim, self.problem)
            self.sampler.sample(sim)
        self.state0 = sim.get_state() if (case.get("timing") or {}).get("runs", 0) > 0 else None
        self.ref, self.g0 = _mech_energy(sim)  # compiles the energy kernel outside the timed stepping
        self.e_max = 1.0
        self.setup_time = time.perf_counter() - self.t_start
        self.clock["t0"] = time.perf_counter()

    def _after_step(self, s):
        clock = self.clock
        if s.n_steps == 1:  # the first step holds the JIT compile
            clock["compile"] = time.perf_counter() - clock["t0"]
            clock["t0"] = time.perf_counter()
        if self.observe is not None:
            t_obs = time.perf_counter()
            self.observe(s)
            if s.n_steps > 1:
                clock["t0"] += time.perf_counter() - t_obs  # observation is not stepping time

    def step(self):
        """Advance to the end time in `samples` pieces; between them, the energy bound and the quantity."""
        sim, samples, end = self.sim, self.case.get("samples", 20), self.cfg.solver.end_time
        for mark in [end * (k + 1) / samples for k in range(samples)]:
            sim.advance_to(mark, on_step=self._after_step)
            if sim.time < mark:  # stopped by solver.max_steps
                break
            t_sample = time.perf_counter()
            e, _ = _mech_energy(sim, self.g0)
            if not math.isfinite(e):
                raise _Undetected("non-finite energy without a solver error")
            if self.ref > 0:
                self.e_max = max(self.e_max, e / self.ref)
            if self.sampler is not None:
                self.sampler.sample(sim)
            self.clock["t0"] += time.perf_counter() - t_sample  # energy and observable sampling are not stepping time
        self.compile_time = self.clock["compile"]
        self.step_time = time.perf_counter() - self.clock["t0"]

    def finish(self):
        """Judge the end state (garbage the solver did not report is `_Undetected`) and record the energies, the
        problem's errors, the quantity and the timing reruns' median."""
        import numpy as np

        sim, rec, case, ref = self.sim, self.rec, self.case, self.ref
        p = sim.particles()
        if not (np.all(np.isfinite(p["x"])) and np.all(np.isfinite(p["v"]))):
            raise _Undetected("non-finite particle state without a solver error")
        e_end, _ = _mech_energy(sim, self.g0)
        limit = case.get("energy_limit")
        if limit and ref > 0 and self.e_max > limit:  # judged at the end: a later solver error takes precedence
            raise _Undetected(f"mechanical energy grew to {self.e_max:.3g} x its initial value without a solver error")
        rec["energy_ratio_max"] = self.e_max if ref > 0 else float("nan")
        rec["energy_ratio_end"] = e_end / ref if ref > 0 else float("nan")
        if self.problem is not None and hasattr(self.problem, "errors"):
            for name, value in self.problem.errors(sim).items():
                rec[name] = _plain(value)
        if self.sampler is not None:
            quantity = case["observe"]
            rec["observed"] = rec.get(quantity["name"]) if quantity["kind"] == "metric" else self.sampler.value()
        end = self.cfg.solver.end_time
        if self.state0 is not None and sim.time >= end * (1 - 1e-12) and sim.n_steps > 1:
            self.step_time = _timing_reruns(sim, self.state0, end, self.step_time, case["timing"], rec)

    def _times_of_a_stop(self):
        """A case that stopped early: its compile and stepping time up to the stop."""
        self.compile_time = self.clock["compile"]
        if self.compile_time == 0.0 and self.sim.n_steps >= 1:
            self.compile_time = time.perf_counter() - self.clock["t0"]
        elif self.step_time == 0.0 and self.sim.n_steps > 1:
            self.step_time = time.perf_counter() - self.clock["t0"]

    def record(self) -> dict:
        rec, sim = self.rec, self.sim
        if rec["outcome"] != "ok" and sim is not None and self.setup_time > 0:
            self._times_of_a_stop()
        rec["setup_time"] = self.setup_time
        rec["compile_time"] = self.compile_time
        rec["step_time"] = self.step_time
        rec["wall_time"] = (time.perf_counter() - self.t_start if "timing_runs" not in rec
                            else self.setup_time + self.compile_time + self.step_time)
        if sim is not None:
            rec["steps"] = sim.n_steps
            rec["sim_time"] = sim.time
            timed_steps = sim.n_steps - 1 if self.step_time > 0 else sim.n_steps
            timed = self.step_time if self.step_time > 0 else self.compile_time
            rec["particle_steps_per_s"] = sim.n * timed_steps / timed if timed > 0 and timed_steps > 0 else float("nan")
        rec["peak_memory_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB
        return rec


def _timing_reruns(sim, state0, end, step_time, timing, rec) -> float:
    """Rerun the stepping from the initial state until the spread (max - min) / median of the reruns' step times
    is at most timing["spread"] (two reruns at least, timing["runs"] at most); record the spread and the number
    of reruns and return their median stepping time for n_steps - 1 steps. The first run is left out: it still
    compiles kernels first used after step 1 (the energy checks); the reruns compile nothing."""
    steps = sim.n_steps
    per_step, spread = [], math.inf
    while len(per_step) < timing["runs"]:
        sim.set_state(state0)
        t0 = time.perf_counter()
        sim.advance_to(end)
        per_step.append((time.perf_counter() - t0) / max(1, sim.n_steps - state0["n_steps"]))
        if len(per_step) >= 2:
            med = statistics.median(per_step)
            spread = (max(per_step) - min(per_step)) / med
            if spread <= timing["spread"]:
                break
    rec["timing_runs"] = len(per_step)
    rec["time_spread"] = spread if len(per_step) > 1 else float("nan")
    return statistics.median(per_step) * (steps - 1)


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
def run_study(study_path, out=None, jobs: Optional[int] = None, scheduler: Optional[str] = None, resume: bool = False,
              progress=None, overwrite: bool = False, allow_problems=(), dry_run: bool = False) -> Optional[Path]:
    """Run every case of a study (skipping finished ones with resume) and write the reports; returns the output dir.

    `allow_problems`: the `module:factory` problem types allowed to run (the project's own always may).
    An output folder that already holds results is refused unless `resume` (continue them) or `overwrite`
    (replace them); nothing outside it is written or deleted. `progress(i, n, case, record)` is called as
    each case finishes (`print_progress` prints one line to stderr). `dry_run` lists the cases on stdout
    and returns None without running or writing anything."""
    if resume and overwrite:
        raise ConfigError("--resume continues a study's results and --overwrite replaces them: give one")
    if jobs is not None and (not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1):
        raise ConfigError(f"must be a whole number from 1, got {_what(jobs)}", key="jobs")
    st = load_study(study_path, allow_problems)
    jobs = jobs or st.jobs
    cases = st.expand()
    out = Path(out) if out is not None else Path("studies") / st.name
    if dry_run:
        for c in cases:
            repeat = f"  repeat {c['repeat']}" if st.repeats > 1 else ""
            print(f"{c['id']}  {json.dumps(c['params'], default=str)}{repeat}")
        print(f"{len(cases)} cases; results would go to {out}")
        return None
    case_dir = prepare_out(st, out, named=out == Path("studies") / st.name, resume=resume, overwrite=overwrite)
    done = finished_records(case_dir) if resume else {}
    todo = [c for c in cases if done.get(c["digest"], {}).get("outcome") not in ("ok", "unstable")]
    (out / "study.yaml").write_text(yaml.safe_dump(study_dump(st), sort_keys=False))
    finished = [0]

    def store(case, rec):
        rec["digest"] = case["digest"]
        (case_dir / f"{case['id']}.json").write_text(json.dumps(rec, indent=1, default=str))
        finished[0] += 1
        if progress:
            progress(finished[0], len(todo), case, rec)

    run_cases(todo, jobs, scheduler, st.timeout, store)
    write_reports(st, out)
    return out


def run_cases(cases: list, jobs: int, scheduler: Optional[str], timeout: Optional[float], store):
    """Run cases (each in its own process) on a local pool of `jobs` or a Dask scheduler; `store(case, record)`
    as each finishes."""
    if scheduler:
        _run_dask(cases, scheduler, timeout, store)
        return
    threads = max(1, (os.cpu_count() or 1) // jobs) if jobs > 1 else None
    with concurrent.futures.ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(execute_case, c, timeout, threads, user_paths()): c for c in cases}
        for fut in concurrent.futures.as_completed(futures):
            store(futures[fut], fut.result())


def prepare_out(st: Study, out: Path, named: bool, resume: bool, overwrite: bool) -> Path:
    """Check the output folder (refusing to overwrite results unasked) and return its cases/ folder."""
    def refuse(msg):
        raise ConfigError(msg, key="study" if named else None, line=st.lines.get("study") if named else None,
                          file=st.path if named else None)

    if out.exists() and not out.is_dir():
        refuse(f"the output folder {out} exists and is not a folder")
    links = [n for n in OUTPUTS if (out / n).is_symlink()]
    if links:
        refuse(f"{out / links[0]} is a symbolic link: a study writes only into its own folder")
    held = [n for n in OUTPUTS if (out / n).exists()]
    if held and not (resume or overwrite):
        refuse(f"{out} already holds study results ({', '.join(held)}): add --resume to continue them "
               f"or --overwrite to replace them")
    case_dir = out / "cases"
    if case_dir.exists() and not case_dir.is_dir():
        refuse(f"{case_dir} exists and is not a folder")
    try:
        if overwrite:   # only what a study writes, by name, inside its folder
            for f in case_dir.glob("*.json") if case_dir.is_dir() else ():
                f.unlink()
            for n in OUTPUTS:
                if n != "cases" and (out / n).is_file():
                    (out / n).unlink()
        case_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        refuse(f"cannot write the study outputs in {out}: {e}")
    return case_dir


def print_progress(i: int, n: int, case: dict, rec: dict):
    """One line per finished case on stderr: case i/N, its parameters, outcome (and cause) and wall time."""
    params = ", ".join(f"{k}={_short(v)}" for k, v in case["params"].items())
    status = rec.get("outcome", "?") + (f" ({rec['cause']})" if rec.get("cause") else "")
    wall = rec.get("wall_time")
    took = f" {float(wall):.1f} s" if _finite(wall) else ""
    rep = f" repeat {case['repeat']}" if case.get("repeat") else ""
    print(f"case {i}/{n} [{params}]{rep}: {status}{took}", file=sys.stderr, flush=True)


def _run_dask(cases, scheduler, timeout, store):
    try:
        from dask.distributed import Client, as_completed
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ConfigError("--scheduler needs dask.distributed: pip install 'taichi-mpm[study]'") from e
    client = Client(scheduler) if isinstance(scheduler, str) else Client(scheduler)
    try:
        futures = {client.submit(execute_case, c, timeout, None, user_paths(), pure=False,
                                 key=f"case-{c['id']}-{c['digest']}"): c for c in cases}
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


def user_paths() -> list[str]:
    """This process's import paths outside the Python installation (project and test dirs), for case processes."""
    import sysconfig
    skip = {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
    return [os.path.abspath(p or ".") for p in sys.path
            if not any(os.path.abspath(p or ".").startswith(s) for s in skip) and "site-packages" not in p
            and not p.endswith(".zip")]


def finished_records(case_dir: Path) -> dict:
    out = {}
    for f in case_dir.glob("*.json"):
        try:
            rec = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        out[rec.get("digest")] = rec
    return out


def study_dump(st: Study) -> dict:
    d = dict(study=st.name)
    if st.base:
        d["base"] = st.base
    else:
        d["problem"] = st.problem
    for k in ("vary", "cases", "set"):
        if getattr(st, k):
            d[k] = getattr(st, k)
    d.update(repeats=st.repeats, metric=st.metric, time_metric=st.time_metric, convergence_key=st.convergence_key,
             energy_limit=st.energy_limit, timeout=st.timeout, samples=st.samples, timing=st.timing)
    if st.observe is not None:
        d.update(observe=st.observe["text"], reference=st.reference)
    return d


# ---------------------------------------------------------------- reports
def collect(st: Study, out: Path) -> list[dict]:
    """The records of this study's cases, in case order."""
    done = finished_records(out / "cases")
    return [done[c["digest"]] for c in st.expand() if c["digest"] in done]


def write_reports(st: Study, out: Path) -> list[dict]:
    """results.csv, pareto.png, convergence.png and summary.md from the case records."""
    import matplotlib
    matplotlib.use("Agg")
    records = collect(st, out)
    varied = st.varied
    reference = None
    if st.observe is not None:   # the reference (a number, or from the finished cases) and each case's error
        if st.observe["kind"] != "metric":
            reference = obs.reference_value(records, st.reference, st.convergence_key, varied)
        obs.observed_errors(records, reference[0] if reference else math.nan, st.observe)
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
    for r in records:   # |1 - E(end)/E(0)| of every finished case: the metric of studies without an exact solution
        if r.get("outcome") == "ok" and _finite(r.get("energy_ratio_end")):
            r["energy_drift"] = abs(float(r["energy_ratio_end"]) - 1.0)
    # the study's metric (checked against the known ones when it was loaded), else error_rms, another error
    # column, or the energy drift
    metric = st.metric or ("error_rms" if "error_rms" in error_cols else
                           error_cols[0] if error_cols else "energy_drift")
    points = _aggregate(records, varied, metric, st.time_metric)
    group_keys = [k for k in varied if k != st.convergence_key]
    front = pareto_front(points)
    fits = convergence_rates(points, group_keys, st.convergence_key)
    plot_pareto(points, front, group_keys, metric, st.time_metric, out / "pareto.png", st.name)
    plot_convergence(points, fits, group_keys, st.convergence_key, metric, out / "convergence.png", st.name)
    (out / "summary.md").write_text(summary_markdown(st, records, varied, metric, front, fits, reference))
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
        fits[label] = dict(rate=slope, intercept=my - slope * mx,
                           points=sorted(pts, key=lambda p: -float(p["params"][conv_key])))
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


def summary_markdown(st, records, varied, metric, front, fits, reference=None) -> str:
    counts = {o: sum(r.get("outcome") == o for r in records) for o in OUTCOMES}
    lines = [f"# Study `{st.name}`", "",
             f"{len(records)} cases: " + ", ".join(f"{n} {o}" for o, n in counts.items()) + ".",
             f"Error metric `{metric}`; time metric `{st.time_metric}` "
             f"(median of up to {st.timing['runs']} timing reruns "
             f"per case, until their spread is at most {st.timing['spread']:g}: column time_spread)."]
    if st.observe is not None:
        lines.append(f"Quantity `{st.observe['text']}`; " + (
            "an error against the exact solution." if reference is None else
            f"reference {reference[0]:.6g} ({reference[1]}); `error_observed` = |observed - reference| / |reference|."))
    lines += ["", "## Cases", ""]
    cols = [*varied, "outcome", *(["observed"] if st.observe is not None else []), metric, "wall_time",
            "compile_time", "step_time", "time_spread", "steps", "particle_steps_per_s", "peak_memory_mb", "cause"]
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
            cells = " | ".join(f"{err[h]:.3g}" if h in err else "-" for h in hs)
            lines.append(f"| {label} | {fit['rate']:.2f} | {cells} |")
    if front:
        lines += ["", "## Pareto front (fastest first)", "",
                  "| " + " | ".join(varied) + f" | {st.time_metric} | {metric} |",
                  "|" + "---|" * (len(varied) + 2)]
        for p in front:
            cells = " | ".join(_md(p["params"].get(k)) for k in varied)
            lines.append(f"| {cells} | {p['time']:.3g} | {p['error']:.3g} |")
    return "\n".join(lines) + "\n"


def _md(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v).replace("|", "/").replace("\n", " ")[:120]


# ---------------------------------------------------------------- entry point of a case process
def main(argv=None):
    """`python -m taichi_mpm.study --case CASE.json --result OUT.json`: run one case in this process (internal: the
    process execute_case launches). A whole study runs with `taichi-mpm study`."""
    ap = argparse.ArgumentParser(prog="python -m taichi_mpm.study", description="run one study case (internal)")
    ap.add_argument("--case", required=True, help="case JSON file")
    ap.add_argument("--result", required=True, help="where to write the case record")
    args = ap.parse_args(argv)
    rec = run_case_inline(json.loads(Path(args.case).read_text()))
    Path(args.result).write_text(json.dumps(rec, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
