"""`taichi-mpm advise`: the cheapest setting (basis x transfer x resolution, optionally x particles per cell)
whose estimated error in one quantity is below a tolerance, found by a small adaptive sweep.

    taichi-mpm advise CONFIG --observe disk0.vx --tolerance 1%
    taichi-mpm advise --problem "{type: vibrating_bar, end_time: 2.0}" --observe error_rel --tolerance 1%

The sweep is a study (study/: same case processes, records, reports, output-folder rules) run in rounds:

1. Reference. With `reference: richardson` (the default for a probe or a function) or `finest`, the most
   accurate candidate (the highest-order basis, APIC before FLIP before PIC, most particles per cell) runs at every
   resolution level first; the observe module extrapolates (or takes the finest value). A number, or an analytic
   problem's error metric (`reference: exact`), needs no such runs.
2. Level by level, coarse to fine, every candidate still open runs at that resolution (in parallel). A candidate
   whose estimated error is within the tolerance is `feasible` and is not refined further (a finer run costs more);
   one whose cost at this level, doubled (the least a refinement adds: dt halves), already exceeds the cheapest
   feasible cost is `pruned`. With `finest`, the finest level has no error estimate of its own.
3. The answer is the feasible run of least cost (`cost`: step_time, the stepping wall time without the JIT
   compile, median of the timing reruns; or wall_time).

Outputs in OUT (default advice/NAME): the study's files (study.yaml, cases/, results.csv, summary.md,
pareto.png: error against cost, convergence.png) and advice.md (the answer, the reference, and one row per
run with its status). docs/study.md describes it.
"""
from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path
from typing import Optional

import yaml

from .. import schemes as transfer_schemes
from . import observe as obs
from ..bases import registry as basis_registry
from ..config import ConfigError
from .study import (case_config, default_jobs, finished_records, load_study, prepare_out, print_progress, run_cases,
                    study_dump, write_reports)

TRANSFERS = transfer_schemes.names()   # every registered scheme (schemes/)
# a tie-break among equally cheap candidates: a basis's rank is its declaration's `accuracy`, a transfer's too
TRANSFER_ACCURACY = {name: transfer_schemes.get(name).accuracy for name in TRANSFERS}
COSTS = ("step_time", "wall_time", "work")
ADVICE = "advice.md"


def parse_tolerance(text) -> float:
    """`1%` -> 0.01, `0.01` -> 0.01; a positive finite number."""
    t = str(text).strip()
    try:
        value = float(t[:-1]) / 100 if t.endswith("%") else float(t)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"--tolerance: expected a positive number or percentage (0.01 or 1%), got {text!r}")
    return value


def parse_problem(text) -> dict:
    """`vibrating_bar` or a YAML mapping `{type: vibrating_bar, end_time: 2.0}`."""
    try:
        spec = yaml.safe_load(str(text))
    except yaml.YAMLError as e:
        raise ConfigError(f"--problem: not a problem name or a YAML mapping: {e}") from None
    if isinstance(spec, str):
        spec = {"type": spec}
    if not isinstance(spec, dict) or "type" not in spec:
        raise ConfigError(f"--problem: expected a name or a mapping with a type, got {text!r}")
    return spec


def advise(config=None, *, problem: Optional[dict] = None, observe, tolerance: float, reference=None,
           bases=None, transfers=("flip", "apic"), levels: int = 3, ppc=None, overrides=None, out=None,
           jobs: Optional[int] = None, cost: str = "step_time", timing=None, samples: int = 20,
           timeout: Optional[float] = None, allow_problems=(), resume: bool = False, overwrite: bool = False,
           progress=print_progress, scheduler: Optional[str] = None) -> dict:
    """Run the adaptive sweep; returns {"choice": row or None, "rows": [...], "reference": (value, how),
    "out": Path}. A row: params, error (estimated), cost, status, record. `bases`: default the registry's swept
    bases (bases/registry.py), cheapest stencil first."""
    bases = basis_registry.swept() if bases is None else bases
    _check_arguments(config, problem, cost, levels, bases, transfers, ppc)
    base_study = _base_study(config, problem, observe, samples, overrides, bases, timing, reference, timeout)
    first = load_study(base_study, allow_problems)          # checks observe/reference against the base config
    _, cfg = case_config(first.expand()[0])
    sweep = _Sweep(base_study, cfg, bases, transfers, ppc, levels, allow_problems, jobs, out)
    sweep.open_folder(resume, overwrite)
    sweep.progress, sweep.scheduler = progress, scheduler
    ref = sweep.find_reference()                             # 1. the reference
    status = sweep.refine(ref, tolerance, cost)              # 2. level by level
    rows = sweep.rows(ref, status, tolerance, cost)
    feasible = [r for r in rows if r["status"].startswith("feasible") and math.isfinite(r["cost"])]
    choice = min(feasible, key=lambda r: r["cost"]) if feasible else None   # 3. the cheapest feasible run
    write_reports(sweep.st, sweep.out)
    (sweep.out / ADVICE).write_text(_advice_markdown(sweep.st, rows, choice, ref, tolerance, cost, sweep.dxs,
                                                     sweep.unestimated))
    return dict(choice=choice, rows=rows, reference=ref, out=sweep.out, tolerance=tolerance, cost=cost,
                unestimated=sweep.unestimated)


def _check_arguments(config, problem, cost, levels, bases, transfers, ppc):
    if (config is None) == (problem is None):
        raise ConfigError("advise needs one of: a config file, or an analytic problem (--problem)")
    if cost not in COSTS:
        raise ConfigError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
    if not isinstance(levels, int) or isinstance(levels, bool) or not 1 <= levels <= 8:
        raise ConfigError(f"--levels: a whole number from 1 to 8, got {levels!r}")
    for name, values, known in (("--bases", bases, basis_registry.swept()), ("--transfers", transfers, TRANSFERS)):
        bad = [v for v in values if v not in known]
        if bad or not values:
            raise ConfigError(f"{name}: expected some of {', '.join(known)}, "
                              f"got {', '.join(map(str, values)) or 'none'}")
    if ppc is not None and (not ppc or not all(_whole_in(n, 1, 8) for n in ppc)):
        raise ConfigError(f"--ppc: whole numbers from 1 to 8, got {ppc!r}")


def _whole_in(n, lo: int, hi: int) -> bool:
    return isinstance(n, int) and not isinstance(n, bool) and lo <= n <= hi


def _base_study(config, problem, observe, samples, overrides, bases, timing, reference, timeout) -> dict:
    """The study every candidate shares (its observe, samples, overrides, timing, reference, timeout), on the
    config file or the analytic problem."""
    study = dict(study="advise", observe=observe, samples=samples, set=dict(overrides or {}),
                 convergence_key="domain.dx", cases=[{"solver.basis": bases[0]}])
    optional = dict(timing=timing, reference=reference, timeout=timeout)
    study.update({k: v for k, v in optional.items() if v is not None})
    if problem is not None:
        study["problem"] = problem
    else:
        study["base"] = str(Path(config).resolve())
        if not Path(config).is_file():
            raise ConfigError(f"config file not found: {config}")
    return study


class _Sweep:
    """The candidates (basis x transfer x particles per cell) at every resolution level, as one study whose cases
    run in batches; `records` holds what ran, keyed by the case's parameters."""

    def __init__(self, base_study, cfg, bases, transfers, ppc, levels, allow_problems, jobs, out):
        self.name = re.sub(r"[^A-Za-z0-9_.-]", "_", cfg.name)[:80] or "run"
        self.dim, self.nbodies = cfg.dim, len(cfg.bodies)
        self.dxs = [cfg.domain.dx / 2**k for k in range(levels)]
        self.combos = [(b, t, n) for b in bases for t in transfers for n in (list(ppc) if ppc else [None])
                       if transfer_schemes.works_with(t, b)]   # mls needs a D_p that is never singular
        study = dict(base_study, study=f"advise_{self.name}",
                     cases=[self.params(b, t, dx, n) for (b, t, n) in self.combos for dx in self.dxs])
        self.st = load_study(study, allow_problems)              # every candidate's config validated up front
        self.st.jobs = jobs or default_jobs()
        self.cases = {_key(c["params"]): c for c in self.st.expand()}
        self.out = Path(out) if out is not None else Path("advice") / self.name
        self.records: dict[str, dict] = {}
        self.done: dict[str, dict] = {}
        self.unestimated = None     # the level whose runs define the reference (no error estimate of their own)
        self.progress = self.scheduler = None

    def params(self, basis, transfer, dx, n=None) -> dict:
        p = {"solver.basis": basis, "solver.transfer": transfer, "domain.dx": dx}
        if n is not None:
            p.update({f"bodies.{i}.particles_per_cell": n for i in range(self.nbodies)})
        return p

    def open_folder(self, resume: bool, overwrite: bool):
        """The output folder (the study's rules; advice.md counts as a result) and, with resume, its records."""
        self.case_dir = prepare_out(self.st, self.out, named=False, resume=resume, overwrite=overwrite)
        if (self.out / ADVICE).exists() and not (resume or overwrite):
            raise ConfigError(f"{self.out} already holds advice ({ADVICE}): add --resume or --overwrite")
        (self.out / "study.yaml").write_text(yaml.safe_dump(study_dump(self.st), sort_keys=False))
        if resume:
            self.done = {d: r for d, r in finished_records(self.case_dir).items()
                         if r.get("outcome") in ("ok", "unstable")}

    def run(self, batch: list[dict]):
        """Run the settings of `batch` not run yet (or reuse a --resume record), in parallel."""
        todo = []
        for p in batch:
            c = self.cases[_key(p)]
            if c["digest"] in self.done:
                self.records[_key(p)] = self.done[c["digest"]]
            elif _key(p) not in self.records:
                todo.append(c)
        finished = [0]

        def store(case, rec):
            rec["digest"] = case["digest"]
            (self.case_dir / f"{case['id']}.json").write_text(json.dumps(rec, indent=1, default=str))
            self.records[_key(case["params"])] = rec
            finished[0] += 1
            if self.progress:
                self.progress(finished[0], len(todo), case, rec)

        run_cases(todo, self.st.jobs, self.scheduler, self.st.timeout, store)

    def find_reference(self) -> tuple:
        """(value or None, how): given, the exact solution (a problem's error metric: None), or from the most
        accurate candidate run at every level (the finest value, or Richardson's extrapolation). When the value
        is the finest run's own (`finest`, or Richardson without three converging levels), the finest level has no
        error estimate: its runs would measure themselves."""
        st = self.st
        if isinstance(st.reference, float):
            return st.reference, "the given value"
        if st.reference not in ("finest", "richardson"):
            return None, "an analytic problem's error against its exact solution"
        best = max(self.combos, key=lambda c: (basis_registry.get(c[0]).accuracy, TRANSFER_ACCURACY[c[1]],
                                               c[2] or 0))
        batch = [self.params(best[0], best[1], dx, best[2]) for dx in self.dxs]
        self.run(batch)
        recs = [self.records[_key(p)] for p in batch]
        ref = obs.reference_value(recs, st.reference, "domain.dx", ["domain.dx"])
        if not math.isfinite(ref[0]):
            raise ConfigError(f"advise: no reference value: {ref[1]} (see {self.out / 'results.csv'})")
        if ref[0] == obs.reference_value(recs, "finest", "domain.dx", ["domain.dx"])[0]:
            self.unestimated = self.dxs[-1]
        return ref

    def error(self, rec, ref) -> float:
        if rec.get("outcome") != "ok":
            return math.nan
        if self.st.observe["kind"] == "metric":
            return float(rec.get(self.st.observe["name"], math.nan))
        q = float(rec.get("observed", math.nan))
        return abs(q - ref[0]) / abs(ref[0]) if ref[0] != 0 else abs(q - ref[0])

    def refine(self, ref, tolerance: float, cost: str) -> dict:
        """Level by level, coarse to fine, run every candidate still open; a feasible one is not refined, one whose
        doubled cost already exceeds the cheapest feasible cost is pruned. Returns {case key: status}."""
        status: dict[str, str] = {}
        open_combos, best_cost = list(self.combos), math.inf
        for dx in self.dxs:
            if not open_combos:
                break
            batch = [self.params(b, t, dx, n) for (b, t, n) in open_combos]
            self.run(batch)
            still = []
            for combo, p in zip(open_combos, batch):
                rec = self.records[_key(p)]
                c = _cost(rec, cost, p, self.dim)
                status[_key(p)] = self._judge(rec, dx, self.error(rec, ref), c, tolerance)
                if status[_key(p)] == "feasible":
                    best_cost = min(best_cost, c)
                else:
                    still.append((combo, p, c))
            open_combos = []
            for combo, p, c in still:
                if math.isfinite(c) and 2 * c > best_cost:   # any finer run of it costs more than the best found
                    status[_key(p)] += "; pruned"
                else:
                    open_combos.append(combo)
        return status

    def _judge(self, rec, dx, err, c, tolerance) -> str:
        if dx == self.unestimated:
            return "no estimate (finest level)"
        if rec.get("outcome") != "ok":
            return rec.get("outcome", "error")
        return "feasible" if err <= tolerance and math.isfinite(c) else "above tolerance"

    def rows(self, ref, status, tolerance, cost) -> list[dict]:
        """One row per run; a reference run not reached by the levels counts as a candidate too, unless its value
        is the reference itself."""
        rows = []
        for key, rec in self.records.items():
            p = self.cases[key]["params"]
            own = p["domain.dx"] == self.unestimated
            row = dict(params=p, error=math.nan if own else self.error(rec, ref), cost=_cost(rec, cost, p, self.dim),
                       status=status.get(key, "reference run"), record=rec)
            if row["status"] == "reference run" and not own and rec.get("outcome") == "ok" \
                    and row["error"] <= tolerance:
                row["status"] = "feasible (reference run)"
            rows.append(row)
        return rows


def _key(p: dict) -> str:
    return repr(sorted(p.items()))


def _cost(rec: dict, cost: str, params: dict, dim: int) -> float:
    """The measured time, or `work`: particle-steps x stencil nodes per particle (a count independent of the
    machine and its load, for comparisons that must repeat)."""
    if rec.get("outcome") != "ok":
        return math.nan
    try:
        if cost == "work":
            nodes = basis_registry.get(params["solver.basis"]).nodes_per_particle(dim)
            return float(rec["particles"]) * float(rec["steps"]) * nodes
        return float(rec.get(cost, math.nan))
    except (KeyError, TypeError, ValueError):
        return math.nan


def _setting(p: dict) -> str:
    ppc = [v for k, v in p.items() if k.endswith("particles_per_cell")]
    return (f"solver.basis={p['solver.basis']} solver.transfer={p['solver.transfer']} domain.dx={p['domain.dx']:g}"
            + (f" particles_per_cell={ppc[0]}" if ppc else ""))


def answer_line(result: dict) -> str:
    c = result["choice"]
    if c is None:
        note = _unestimated_note(result.get("unestimated"))
        return f"no setting reached the tolerance {result['tolerance']:.3g}{note}; see {result['out'] / ADVICE}"
    r = c["record"]
    return (f"cheapest setting with estimated error {c['error']:.3g} <= {result['tolerance']:.3g}: "
            f"{_setting(c['params'])} "
            f"({_cost_text(result['cost'], c['cost'])}; stepping {float(r.get('step_time', math.nan)):.3g} s, "
            f"{int(r.get('particles', 0))} particles, {int(r.get('steps', 0))} steps); evidence in {result['out']}")


def _cost_text(cost: str, value: float) -> str:
    return f"work {value:.3g} particle-steps x stencil nodes" if cost == "work" else f"{cost} {value:.3g} s"


def _unestimated_note(dx) -> str:
    """Why the finest level has no error estimate, when it has none."""
    if dx is None:
        return ""
    return (f" (the finest level, domain.dx={dx:g}, gives the reference itself, so its runs have no error estimate "
            f"of their own)")


def _advice_markdown(st, rows, choice, ref, tolerance, cost, dxs, unestimated=None) -> str:
    lines = [f"# Advice for `{st.observe['text']}` within {tolerance:.3g}", ""]
    if choice is None:
        lines.append(f"No setting reached the tolerance{_unestimated_note(unestimated)}: refine further (--levels) "
                     f"or widen it.")
    else:
        rec = choice["record"]
        lines.append(f"**Cheapest setting:** `{_setting(choice['params'])}`: estimated error {choice['error']:.3g}, "
                     f"{_cost_text(cost, choice['cost'])} "
                     f"(measured: stepping {float(rec.get('step_time', math.nan)):.3g} s, "
                     f"wall time {float(rec.get('wall_time', math.nan)):.3g} s with set-up and JIT compile).")
    lines += ["", ("Reference: the exact solution (the problem's own error metric)." if ref[0] is None else
                   f"Reference value {ref[0]:.6g}: {ref[1]}; error = |observed - reference| / |reference|."),
              f"Resolution levels: domain.dx = {', '.join(f'{d:g}' for d in dxs)}. Costs are measured on this machine "
              "(median of the timing reruns; `time_spread` in results.csv); on a loaded machine they are noisy.",
              "", f"| setting | outcome | observed | estimated error | {cost} | step_time [s] | time spread | status |",
              "|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["cost"] if math.isfinite(r["cost"]) else math.inf)):
        rec = r["record"]
        lines.append(f"| {_setting(r['params'])} | {rec.get('outcome')} | {_num(rec.get('observed'))} | "
                     f"{_num(r['error'])} | {_num(r['cost'])} | {_num(rec.get('step_time'))} | "
                     f"{_num(rec.get('time_spread'))} | "
                     f"{r['status']} |")
    lines += ["", "Plots: `pareto.png` (error against time), `convergence.png`; all runs: `results.csv`, `summary.md`."]
    return "\n".join(lines) + "\n"


def _num(v) -> str:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return "-"
    return f"{v:.4g}" if math.isfinite(v) else "-"


def main_cli(args) -> int:
    """`taichi-mpm advise` (called by cli.py with its parsed arguments)."""
    problem = parse_problem(args.problem) if args.problem else None
    result = advise(args.config, problem=problem, observe=args.observe, tolerance=parse_tolerance(args.tolerance),
                    reference=_reference_arg(args.reference), bases=_list(args.bases, basis_registry.swept()),
                    transfers=_list(args.transfers, ("flip", "apic")), levels=args.levels,
                    ppc=[_int(v, "--ppc") for v in args.ppc.split(",")] if args.ppc else None,
                    overrides=_overrides(args.overrides), out=args.out, jobs=args.jobs, cost=args.cost,
                    allow_problems=args.allow_problems, resume=args.resume, overwrite=args.overwrite)
    print(answer_line(result), file=sys.stderr)
    print(_setting(result["choice"]["params"]) if result["choice"] else "none")
    return 0


def _reference_arg(text):
    if text is None:
        return None
    try:
        return float(text)
    except ValueError:
        return text


def _list(text, default):
    return tuple(v.strip() for v in text.split(",") if v.strip()) if text else tuple(default)


def _int(text, key):
    try:
        return int(text)
    except ValueError:
        raise ConfigError(f"{key}: expected whole numbers separated by commas, got {text!r}") from None


def _overrides(items):
    from ..config import parse_overrides
    return parse_overrides(items or [])
