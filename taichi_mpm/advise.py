"""`taichi-mpm advise`: the cheapest setting (basis x transfer x resolution, optionally x particles per cell)
whose estimated error in one quantity is below a tolerance, found by a small adaptive sweep.

    taichi-mpm advise CONFIG --observe disk0.vx --tolerance 1%
    taichi-mpm advise --problem "{type: vibrating_bar, end_time: 2.0}" --observe error_rel --tolerance 1%

The sweep is a study (study.py: same case processes, records, reports, output-folder rules) run in rounds:

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

from . import observe as obs
from .config import ConfigError
from .study import (finished_records, prepare_out, study_dump, case_config, default_jobs, load_study, print_progress,
                    run_cases, write_reports)

BASES = ("linear", "gimp", "quadratic", "cubic")          # cheapest stencil first
TRANSFERS = ("pic", "flip", "apic")
ACCURACY = {"cubic": 4, "quadratic": 3, "gimp": 2, "linear": 1, "apic": 3, "flip": 2, "pic": 1}
COSTS = ("step_time", "wall_time", "work")
STENCIL = {"linear": 2, "gimp": 3, "quadratic": 3, "cubic": 4}   # nodes per particle and axis
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
           bases=BASES, transfers=("flip", "apic"), levels: int = 3, ppc=None, overrides=None, out=None,
           jobs: Optional[int] = None, cost: str = "step_time", timing=None, samples: int = 20,
           timeout: Optional[float] = None, allow_problems=(), resume: bool = False, overwrite: bool = False,
           progress=print_progress, scheduler: Optional[str] = None) -> dict:
    """Run the adaptive sweep; returns {"choice": row or None, "rows": [...], "reference": (value, how),
    "out": Path}. A row: params, error (estimated), cost, status, record."""
    if (config is None) == (problem is None):
        raise ConfigError("advise needs one of: a config file, or an analytic problem (--problem)")
    if cost not in COSTS:
        raise ConfigError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
    if not isinstance(levels, int) or isinstance(levels, bool) or not 1 <= levels <= 8:
        raise ConfigError(f"--levels: a whole number from 1 to 8, got {levels!r}")
    for name, values, known in (("--bases", bases, BASES), ("--transfers", transfers, TRANSFERS)):
        bad = [v for v in values if v not in known]
        if bad or not values:
            raise ConfigError(f"{name}: expected some of {', '.join(known)}, got {', '.join(map(str, values)) or 'none'}")
    if ppc is not None and (not ppc or any(not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= 8
                                           for n in ppc)):
        raise ConfigError(f"--ppc: whole numbers from 1 to 8, got {ppc!r}")

    base_study = dict(study="advise", observe=observe, samples=samples, set=dict(overrides or {}),
                      convergence_key="domain.dx", cases=[{"solver.basis": bases[0]}])
    if timing is not None:
        base_study["timing"] = timing
    if reference is not None:
        base_study["reference"] = reference
    if timeout is not None:
        base_study["timeout"] = timeout
    if problem is not None:
        base_study["problem"] = problem
    else:
        base_study["base"] = str(Path(config).resolve())
        if not Path(config).is_file():
            raise ConfigError(f"config file not found: {config}")
    first = load_study(base_study, allow_problems)          # checks observe/reference against the base config
    _, cfg = case_config(first.expand()[0])
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", cfg.name)[:80] or "run"
    dx0 = cfg.domain.dx
    dxs = [dx0 / 2**k for k in range(levels)]
    nbodies = len(cfg.bodies)

    def params(basis, transfer, dx, n=None):
        p = {"solver.basis": basis, "solver.transfer": transfer, "domain.dx": dx}
        if n is not None:
            p.update({f"bodies.{i}.particles_per_cell": n for i in range(nbodies)})
        return p

    ppcs = list(ppc) if ppc else [None]
    combos = [(b, t, n) for b in bases for t in transfers for n in ppcs]
    study_dict = dict(base_study, study=f"advise_{name}",
                      cases=[params(b, t, dx, n) for (b, t, n) in combos for dx in dxs])
    st = load_study(study_dict, allow_problems)              # every candidate's config validated up front
    st.jobs = jobs or default_jobs()
    cases = {_key(c["params"]): c for c in st.expand()}
    out = Path(out) if out is not None else Path("advice") / name
    case_dir = prepare_out(st, out, named=False, resume=resume, overwrite=overwrite)
    if (out / ADVICE).exists() and not (resume or overwrite):
        raise ConfigError(f"{out} already holds advice ({ADVICE}): add --resume or --overwrite")
    (out / "study.yaml").write_text(yaml.safe_dump(study_dump(st), sort_keys=False))
    done = {d: r for d, r in finished_records(case_dir).items() if r.get("outcome") in ("ok", "unstable")} if resume else {}
    records: dict[str, dict] = {}

    def run(batch: list[dict]):
        """Run the settings of `batch` not run yet (or reuse a --resume record), in parallel."""
        todo = []
        for p in batch:
            c = cases[_key(p)]
            if c["digest"] in done:
                records[_key(p)] = done[c["digest"]]
            elif _key(p) not in records:
                todo.append(c)
        finished = [0]

        def store(case, rec):
            rec["digest"] = case["digest"]
            (case_dir / f"{case['id']}.json").write_text(json.dumps(rec, indent=1, default=str))
            records[_key(case["params"])] = rec
            finished[0] += 1
            if progress:
                progress(finished[0], len(todo), case, rec)

        run_cases(todo, st.jobs, scheduler, st.timeout, store)

    # 1. the reference
    ref = (None, "an analytic problem's error against its exact solution")
    if isinstance(st.reference, float):
        ref = (st.reference, "the given value")
    elif st.reference in ("finest", "richardson"):
        best = max(combos, key=lambda c: (ACCURACY[c[0]], ACCURACY[c[1]], c[2] or 0))
        run([params(*best[:2], dx, best[2]) for dx in dxs])
        recs = [records[_key(params(*best[:2], dx, best[2]))] for dx in dxs]
        ref = obs.reference_value(recs, st.reference, "domain.dx", ["domain.dx"])
    if ref[0] is not None and not math.isfinite(ref[0]):
        raise ConfigError(f"advise: no reference value: {ref[1]} (see {out / 'results.csv'})")

    def error(rec) -> float:
        if rec.get("outcome") != "ok":
            return math.nan
        if st.observe["kind"] == "metric":
            return float(rec.get(st.observe["name"], math.nan))
        q = float(rec.get("observed", math.nan))
        return abs(q - ref[0]) / abs(ref[0]) if ref[0] != 0 else abs(q - ref[0])

    # 2. level by level
    status: dict[str, str] = {}
    open_combos = list(combos)
    best_cost = math.inf
    for k, dx in enumerate(dxs):
        if not open_combos:
            break
        batch = [params(b, t, dx, n) for (b, t, n) in open_combos]
        run(batch)
        still = []
        for combo, p in zip(open_combos, batch):
            rec = records[_key(p)]
            err, c = error(rec), _cost(rec, cost, p, cfg.dim)
            no_estimate = st.reference == "finest" and k == len(dxs) - 1
            if rec.get("outcome") == "ok" and not no_estimate and err <= tolerance and math.isfinite(c):
                status[_key(p)] = "feasible"
                best_cost = min(best_cost, c)
            else:
                status[_key(p)] = "no estimate (finest level)" if no_estimate else \
                    "above tolerance" if rec.get("outcome") == "ok" else rec.get("outcome", "error")
                still.append((combo, c))
        open_combos = []
        for combo, c in still:
            if math.isfinite(c) and 2 * c > best_cost:   # any finer run of it costs more than the best found
                status[_key(params(combo[0], combo[1], dxs[k], combo[2]))] += "; pruned"
            else:
                open_combos.append(combo)

    rows = []
    for key, rec in records.items():
        p = next(c["params"] for c in cases.values() if _key(c["params"]) == key)
        finest_level = st.reference == "finest" and p["domain.dx"] == dxs[-1]   # the reference itself: no estimate
        rows.append(dict(params=p, error=math.nan if finest_level else error(rec), cost=_cost(rec, cost, p, cfg.dim),
                         status=status.get(key, "reference run"), record=rec))
    for row in rows:   # the reference runs count as candidates too
        if row["status"] == "reference run" and row["record"].get("outcome") == "ok" and row["error"] <= tolerance \
                and not (st.reference == "finest" and row["params"]["domain.dx"] == dxs[-1]):
            row["status"] = "feasible (reference run)"
    feasible = [r for r in rows if r["status"].startswith("feasible") and math.isfinite(r["cost"])]
    choice = min(feasible, key=lambda r: r["cost"]) if feasible else None
    write_reports(st, out)
    (out / ADVICE).write_text(_advice_markdown(st, rows, choice, ref, tolerance, cost, dxs))
    return dict(choice=choice, rows=rows, reference=ref, out=out, tolerance=tolerance, cost=cost)


def _key(p: dict) -> str:
    return repr(sorted(p.items()))


def _cost(rec: dict, cost: str, params: dict, dim: int) -> float:
    """The measured time, or `work`: particle-steps x stencil nodes per particle (a count independent of the
    machine and its load, for comparisons that must repeat)."""
    if rec.get("outcome") != "ok":
        return math.nan
    try:
        if cost == "work":
            return float(rec["particles"]) * float(rec["steps"]) * STENCIL[params["solver.basis"]] ** dim
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
        return (f"no setting reached the tolerance {result['tolerance']:.3g}; "
                f"see {result['out'] / ADVICE}")
    r = c["record"]
    return (f"cheapest setting with estimated error {c['error']:.3g} <= {result['tolerance']:.3g}: {_setting(c['params'])} "
            f"({_cost_text(result['cost'], c['cost'])}; stepping {float(r.get('step_time', math.nan)):.3g} s, "
            f"{int(r.get('particles', 0))} particles, {int(r.get('steps', 0))} steps); evidence in {result['out']}")


def _cost_text(cost: str, value: float) -> str:
    return f"work {value:.3g} particle-steps x stencil nodes" if cost == "work" else f"{cost} {value:.3g} s"


def _advice_markdown(st, rows, choice, ref, tolerance, cost, dxs) -> str:
    lines = [f"# Advice for `{st.observe['text']}` within {tolerance:.3g}", ""]
    if choice is None:
        lines.append("No setting reached the tolerance: refine further (--levels) or widen it.")
    else:
        rec = choice["record"]
        lines.append(f"**Cheapest setting:** `{_setting(choice['params'])}`: estimated error {choice['error']:.3g}, "
                     f"{_cost_text(cost, choice['cost'])} (measured: stepping {float(rec.get('step_time', math.nan)):.3g} s, "
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
                     f"{_num(r['error'])} | {_num(r['cost'])} | {_num(rec.get('step_time'))} | {_num(rec.get('time_spread'))} | "
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
                    reference=_reference_arg(args.reference), bases=_list(args.bases, BASES),
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
    from .config import parse_overrides
    return parse_overrides(items or [])
