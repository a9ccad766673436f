"""Quantities of interest for studies and `advise`: what a case measures (`observe:`) and what it is compared
with (`reference:`). docs/study.md describes the keys; in short::

    observe: disk0.vx@end        # PROBE.COLUMN: a probe of output.probes, one CSV column (unit left out)
    observe: kinetic_energy@max  # a project function of the simulation (FUNCTIONS below)
    observe: error_rel           # an analytic problem's own error metric (already an error against its exact solution)
    observe: mypkg.obs:tip       # MODULE:FUNCTION(sim) -> float, only when allowed on the command line
    reference: 0.0123 | exact | finest | richardson

`@end` (default), `@max`, `@min`, `@mean`, `@maxabs` reduce the samples, taken at t = 0 and at the study's
`samples` times. The case process (`Sampler`) records the value as `observed`; the launcher, once every case has
finished, turns it into the error column `error_observed` (`reference_value`, `observed_errors`): relative to the
reference (absolute when the reference is 0).

No physics and no I/O: samples come from the Simulation's public state (particles(), energy(), wall_impulse()).
"""
from __future__ import annotations

import math
import re
import statistics
from typing import Optional

REDUCERS = ("end", "max", "min", "mean", "maxabs")
REFERENCES = ("exact", "finest", "richardson")
SPEC = re.compile(r"^(?P<what>[A-Za-z_][\w.:-]*?)(?:@(?P<at>\w+))?$")


def _energy(part):
    return lambda sim: float(sim.energy()[part])


def _momentum(axis):
    return lambda sim: float(sim.momentum()["linear"][axis])


# functions of the simulation every case can observe (the project's own kinds; no user code)
FUNCTIONS = {
    "kinetic_energy": _energy("kinetic"),
    "strain_energy": _energy("strain"),
    "total_energy": lambda sim: float(sum(sim.energy()[k] for k in ("kinetic", "strain"))),
    "max_speed": lambda sim: float(sim.max_speed()),
    **{f"momentum_{a}": _momentum(i) for i, a in enumerate("xyz")},
}


class ObserveError(ValueError):
    """A bad `observe` / `reference` value; the study turns it into a ConfigError naming the key."""


def parse(text) -> dict:
    """`observe` text -> {kind: probe|function|callable|metric, name, column, at}; the kind `metric` is decided
    later (`classify`), against the problem's metrics."""
    if isinstance(text, dict):
        unknown = set(text) - {"probe", "column", "function", "at"}
        if unknown or ("probe" in text) == ("function" in text) or ("probe" in text) != ("column" in text):
            raise ObserveError("a mapping takes {probe: NAME, column: COLUMN, at: REDUCE} or "
                               "{function: NAME, at: REDUCE}")
        text = (f"{text['probe']}.{text['column']}" if "probe" in text else str(text["function"])) + \
            (f"@{text['at']}" if "at" in text else "")
    if not isinstance(text, str) or not SPEC.match(text):
        raise ObserveError(f"expected PROBE.COLUMN, a function ({', '.join(FUNCTIONS)}), a problem's error metric "
                           f"or MODULE:FUNCTION, optionally with @{'/@'.join(REDUCERS)}, got {text!r}")
    m = SPEC.match(text)
    what, at = m.group("what"), m.group("at") or "end"
    if at not in REDUCERS:
        raise ObserveError(f"unknown reduction @{at} (known: {', '.join('@' + r for r in REDUCERS)})")
    if ":" in what:
        return dict(kind="callable", name=what, column=None, at=at, text=text)
    if "." in what:
        probe, column = what.split(".", 1)
        return dict(kind="probe", name=probe, column=column, at=at, text=text)
    return dict(kind="function", name=what, column=None, at=at, text=text)


def check(spec: dict, cfg, problem_metrics: Optional[list], allow=()) -> dict:
    """Check a parsed spec against one case's config (its probes) and problem; returns the spec with its kind
    settled (a name that is a problem metric becomes kind `metric`). Raises ObserveError."""
    from ..io.probes import probe_columns
    spec = dict(spec)
    if spec["kind"] == "callable":
        if spec["name"] not in allow:
            raise ObserveError(f"{spec['name']!r} is not one of the project's functions: a study runs other code only "
                               f"when you allow it on the command line (--allow-problem {spec['name']})")
    elif spec["kind"] == "probe":
        names = {p.name: p for p in cfg.output.probes}
        if spec["name"] not in names:
            if spec["name"] in FUNCTIONS or (problem_metrics and spec["name"] in problem_metrics):
                raise ObserveError(f"{spec['name']} takes no column")
            raise ObserveError(f"no probe named {spec['name']!r} in output.probes "
                               f"(probes: {', '.join(names) or 'none'}; add one in the config or in `set`)")
        columns = [c.split(" [")[0] for c in probe_columns(names[spec["name"]], cfg.dim)]
        if spec["column"] not in columns:
            raise ObserveError(f"the probe {spec['name']!r} has no column {spec['column']!r} "
                               f"(columns: {', '.join(columns)})")
    elif spec["name"] not in FUNCTIONS:
        if problem_metrics and spec["name"] in problem_metrics and spec["name"].startswith("error_"):
            if spec["at"] != "end":
                raise ObserveError(f"a problem metric ({spec['name']}) is one value per case: no @{spec['at']}")
            spec["kind"] = "metric"
        else:
            known = list(FUNCTIONS) + [m for m in (problem_metrics or []) if m.startswith("error_")]
            raise ObserveError(f"unknown quantity {spec['name']!r} (functions and metrics: {', '.join(known)}; "
                               f"or PROBE.COLUMN for a probe of output.probes)")
    return spec


def check_reference(ref, spec: dict):
    """`reference`: a finite number, `exact` (only for a problem metric, which is an error against the exact
    solution already), `finest` or `richardson`. Returns the value to store."""
    if isinstance(ref, (int, float)) and not isinstance(ref, bool):
        if not math.isfinite(ref):
            raise ObserveError(f"must be a finite number, got {ref!r}")
        if spec["kind"] == "metric":
            raise ObserveError(f"{spec['name']} is already an error against the exact solution: "
                               "use reference: exact (or leave it out)")
        return float(ref)
    if ref not in REFERENCES:
        raise ObserveError(f"must be a number or one of {', '.join(REFERENCES)}, got {ref!r}")
    if (ref == "exact") != (spec["kind"] == "metric"):
        raise ObserveError("reference: exact goes with an analytic problem's error metric (observe: error_rel, ...)"
                           if ref == "exact" else
                           f"{spec['name']} is already an error against the exact solution: use reference: exact")
    return ref


def default_reference(spec: dict):
    return "exact" if spec["kind"] == "metric" else "richardson"


# ---------------------------------------------------------------- in the case process
class Sampler:
    """Samples one observable during a case; `value()` reduces the samples."""

    def __init__(self, spec: dict, sim, problem=None):
        self.spec, self.samples = spec, []
        self._f = None
        if spec["kind"] == "function":
            self._f = FUNCTIONS[spec["name"]]
        elif spec["kind"] == "callable":
            import importlib
            module, attr = spec["name"].split(":", 1)
            self._f = getattr(importlib.import_module(module), attr)
        elif spec["kind"] == "probe":
            from ..io.probes import KINDS, WallProbe
            i, pspec = next((i, p) for i, p in enumerate(sim.cfg.output.probes) if p.name == spec["name"])
            self._probe = KINDS[pspec.type](pspec, sim, f"output.probes.{i}")
            self._col = [c.split(" [")[0] for c in self._probe.columns].index(spec["column"])
            self._wall = isinstance(self._probe, WallProbe)
            self._since = sim.time
            if self._wall:
                sim.wall_impulse(reset=True)

    def sample(self, sim):
        if self.spec["kind"] == "metric":
            return
        if self._f is not None:
            self.samples.append(float(self._f(sim)))
            return
        p = sim.particles() if self._probe.needs_particles else None
        impulse = sim.wall_impulse(reset=True) if self._wall else None
        row = self._probe.row(p, sim, impulse, sim.time - self._since)
        self._since = sim.time
        v = float(row[self._col])
        if math.isfinite(v):   # a wall probe's t = 0 sample has no interval yet
            self.samples.append(v)

    def value(self) -> float:
        s = self.samples
        if not s:
            return math.nan
        at = self.spec["at"]
        return {"end": s[-1], "max": max(s), "min": min(s), "mean": sum(s) / len(s),
                "maxabs": max(s, key=abs)}[at]


# ---------------------------------------------------------------- after the cases: the reference and the errors
def reference_value(records: list[dict], reference, conv_key: str, varied: list[str]) -> tuple[float, str]:
    """(reference value, how it was found) from the finished cases' `observed` values.

    finest: the median observed value over the ok cases at the finest `conv_key` (all other settings);
    richardson: per group of the other varied keys, the three finest levels h1 > h2 > h3 give the observed order
    p = ln((q1 - q2) / (q2 - q3)) / ln(h1 / h2) (levels in a constant ratio) and the extrapolation
    q3 + (q3 - q2) / ((h2 / h3)^p - 1); groups whose differences do not shrink monotonically (0.2 <= p <= 8)
    are skipped; the reference is the median of the groups' extrapolations (the finest median when none fits)."""
    if isinstance(reference, float):
        return reference, "the given value"
    ok = [r for r in records if r.get("outcome") == "ok" and _finite(r.get("observed")) and _finite(r.get(conv_key))]
    if not ok:
        return math.nan, "no finished case observed a value"
    h_min = min(float(r[conv_key]) for r in ok)
    finest = statistics.median(float(r["observed"]) for r in ok if float(r[conv_key]) == h_min)
    if reference == "finest":
        return finest, f"the median of the cases at {conv_key}={h_min:g}"
    others = [k for k in varied if k != conv_key]
    groups: dict[str, dict] = {}
    for r in ok:
        key = repr([r.get(k) for k in others])
        groups.setdefault(key, {}).setdefault(float(r[conv_key]), []).append(float(r["observed"]))
    extrapolated, orders = [], []
    for levels in groups.values():
        hs = sorted(levels, reverse=True)[-3:]
        if len(hs) < 3:
            continue
        q1, q2, q3 = (statistics.mean(levels[h]) for h in hs)
        r12, r23 = hs[0] / hs[1], hs[1] / hs[2]
        if abs(r12 - r23) > 1e-6 * r12 or (q1 - q2) * (q2 - q3) <= 0 or abs(q2 - q3) >= abs(q1 - q2):
            continue
        p = math.log(abs(q1 - q2) / abs(q2 - q3)) / math.log(r12)
        if not 0.2 <= p <= 8:
            continue
        extrapolated.append(q3 + (q3 - q2) / (r23**p - 1))
        orders.append(p)
    if not extrapolated:
        return finest, f"no group converged monotonically over three levels: the median at {conv_key}={h_min:g}"
    return statistics.median(extrapolated), (f"Richardson extrapolation, median of {len(extrapolated)} groups "
                                             f"(observed orders {', '.join(f'{p:.2f}' for p in orders)})")


def observed_errors(records: list[dict], ref: float, spec: dict):
    """Set `error_observed` in each record: |q - ref| / |ref| (|q - ref| when ref = 0); a problem metric is its
    own error."""
    for r in records:
        if spec["kind"] == "metric":
            r["error_observed"] = r.get(spec["name"], math.nan)
        elif r.get("outcome") == "ok" and _finite(r.get("observed")) and math.isfinite(ref):
            d = abs(float(r["observed"]) - ref)
            r["error_observed"] = d / abs(ref) if ref != 0 else d


def _finite(v) -> bool:
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False
