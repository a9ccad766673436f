"""Speed/accuracy studies: sweep dotted config keys over a base config or a built-in problem.

The study file, its checks, the allowed problems (`--allow-problem`), the metrics and the output folder are
described in docs/study.md. In short::

    study: bases_vs_resolution        # required; names the output folder studies/NAME (--out overrides)
    problem: {type: mms_axis_aligned, dim: 1, amplitude: 0.05}     # or base: a config file
    vary: {solver.basis: [linear, quadratic], domain.dx: [0.05, 0.025]}
    cases: [{solver.transfer: pic}]   # each combined with every grid point

`load_study` checks everything before anything runs and imports nothing outside the project unless allowed.
Each case runs in its own Python process (`python -m taichi_mpm.tools.study --case CASE.json --result OUT.json`), so
Taichi state is isolated and a crash or hang of one case is recorded as its outcome without stopping the study.
Cases run on a local thread pool (`jobs`) that launches those processes, or on a Dask distributed cluster
(`scheduler`), whose workers launch the same process. Each finished case is written to `OUT/cases/ID.json`;
`results.csv`, the plots and `summary.md` are rebuilt from those files, and `resume=True` reruns only the
cases without a result (and those that ended in `error`).
"""

import concurrent.futures
import json
import os
from pathlib import Path
from typing import Optional

import yaml

from ...config import ConfigError
from .case import execute_case, run_case_inline, user_paths
from .folder import OUTPUTS, finished_records, prepare_out, study_dump
from .report import (OUTCOMES, RECORD_COLUMNS, collect, convergence_rates, pareto_front, plot_convergence, plot_pareto,
                     print_progress, summary_markdown, write_reports)
from .spec import (COMMON_METRICS, MAX_CASES, MAX_SAMPLES, PROBLEM_METRICS, STUDY_KEYS, TIME_METRICS, TIMING_DEFAULT,
                   Study, case_config, default_jobs, describe, known_metrics, load_study, problem_refused,
                   resolve_problem)

__all__ = ["COMMON_METRICS", "MAX_CASES", "MAX_SAMPLES", "OUTCOMES", "OUTPUTS", "PROBLEM_METRICS", "RECORD_COLUMNS",
           "STUDY_KEYS", "TIME_METRICS", "TIMING_DEFAULT", "Study", "case_config", "collect", "convergence_rates",
           "default_jobs", "execute_case", "finished_records", "known_metrics", "load_study", "pareto_front",
           "plot_convergence", "plot_pareto", "prepare_out", "print_progress", "problem_refused", "resolve_problem",
           "run_case_inline", "run_cases", "run_study", "study_dump", "summary_markdown", "user_paths", "write_reports"]


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
        raise ConfigError(f"must be a whole number from 1, got {describe(jobs)}", key="jobs")
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
