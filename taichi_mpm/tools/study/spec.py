"""The study file (docs/study.md): its keys and their checks, the cases it expands to, and the problems a study may
run. `load_study` checks everything before anything runs and imports nothing outside the project unless allowed:
a `module:factory` problem is imported (and called, to validate its cases) only when it is in `allow_problems`."""
import copy
import hashlib
import itertools
import json
import math
import os
import re
import reprlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from .. import observe as obs
from ...config import ConfigError, load_config, read_yaml


STUDY_KEYS = {"study", "description", "base", "problem", "vary", "cases", "set", "repeats", "metric",
              "time_metric", "convergence_key", "energy_limit", "timeout", "samples", "jobs", "observe", "reference",
              "timing"}


# timing: each case's stepping is rerun (same process, compiled kernels kept) until the spread of its step times,
# (max - min) / median, is at most `spread`, or `runs` runs were made; the median is reported (issue 16: one run's
# time on a loaded machine is noise)
TIMING_DEFAULT = {"runs": 3, "spread": 0.1}   # runs: 0 times the first run alone (its compile left out)


TIME_METRICS = ("wall_time", "step_time", "compile_time")


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


def default_jobs() -> int:
    """Cases in parallel by default: one per core minus one, so timings are not skewed by a busy machine."""
    return max(1, (os.cpu_count() or 1) - 1)


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


def describe(v) -> str:
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
        fail(f"keys must be text, got the key {describe(bad_key[1])}", bad_key[0] or None)
    unknown = [k for k in data if k not in STUDY_KEYS]
    if unknown:
        fail(f"unknown key (study keys: {', '.join(sorted(STUDY_KEYS))})", unknown[0])
    name = data.get("study")
    if not isinstance(name, str) or not STUDY_NAME.fullmatch(name):
        fail(f"required: a study name of at most 100 letters, digits, '_', '.' or '-', not starting with '.' "
             f"(it names the output folder studies/NAME), got {describe(name)}", "study")
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
        fail(f"must be the path of a config file, got {describe(base)}", "base")
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
            fail(f"must map dotted keys (e.g. solver.basis) to lists of values, got the key {describe(k)}", "vary")
        if not isinstance(v, list) or not v:
            fail(f"must be a non-empty list of values, got {describe(v)}", f"vary.{k}")
    st.vary = vary
    cases = data.get("cases") or []
    if not isinstance(cases, list):
        fail("must be a list of mappings of dotted keys to values", "cases")
    for i, c in enumerate(cases):
        if not isinstance(c, dict) or not c or not all(_dotted_ok(k) for k in c):
            fail(f"must be a mapping of dotted keys to values, got {describe(c)}", f"cases.{i}")
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
        fail(f"must be a whole number from 1{f' to {limit}' if limit else ''}, got {describe(v)}", key)
    return v


def _positive_or_null(data: dict, fail, key: str):
    v = data.get(key)
    if v is not None and (not _is_number(v) or v <= 0):
        fail(f"must be a positive number or null, got {describe(v)}", key)
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
        fail(f"must be one of {', '.join(TIME_METRICS)}, got {describe(st.time_metric)}", "time_metric")
    st.convergence_key = data.get("convergence_key", "domain.dx")
    if not _dotted_ok(st.convergence_key):
        fail(f"must be a dotted key (e.g. domain.dx), got {describe(st.convergence_key)}", "convergence_key")
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
        fail(f"must be a whole number from 0 to 100, got {describe(runs)}", "timing.runs")
    if not _is_number(spread) or spread <= 0:
        fail(f"must be a positive number, got {describe(spread)}", "timing.spread")
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
        fail(f"must be the name of a metric, got {describe(st.metric)}", "metric")
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
    from ... import analytic
    from .. import stability
    if not isinstance(kind, str):
        return f"a problem type must be a name (e.g. mms_axis_aligned), got {describe(kind)}"
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


def resolve_problem(spec: dict, allow=()):
    """A problem object from a spec: a stability scenario, an analytic problem, or an allowed `module:factory`.
    Raises ConfigError, importing nothing, for any other type."""
    kind = spec.get("type")
    why = problem_refused(kind, allow)
    if why:
        raise ConfigError(why, key="problem.type")
    from .. import stability
    if kind in stability.SCENARIOS:
        return stability.make_scenario(spec)
    from ... import analytic
    if kind in analytic.PROBLEMS:
        return analytic.make_problem(spec)
    import importlib
    module, attr = kind.split(":", 1)
    return getattr(importlib.import_module(module), attr)(spec)
