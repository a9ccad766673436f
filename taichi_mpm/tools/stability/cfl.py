"""The largest stable CFL number of a stability scenario, per basis and transfer: bisection over the CFL number,
each trial a study case run in its own process (study.execute_case)."""
import concurrent.futures
import json
import math
from typing import Optional

from ... import schemes as transfer_schemes
from ...bases import registry as basis_registry
from ..study import execute_case, user_paths

def is_stable(rec: dict, energy_limit: float) -> bool:
    """Stable: finished, and the mechanical energy never exceeded energy_limit x its initial value."""
    return rec.get("outcome") == "ok" and float(rec.get("energy_ratio_max", math.inf)) <= energy_limit


def cfl_case(basis: str, transfer: str, cfl: float, spec: dict, samples: int = 20, energy_limit: float = 1.1,
             extra: Optional[dict] = None) -> dict:
    """A study case (study/case.py) of `spec` at one CFL number."""
    params = {"solver.basis": basis, "solver.transfer": transfer, "solver.cfl": cfl, **(extra or {})}
    return dict(id=f"cfl_{basis}_{transfer}_{cfl:.4f}", digest="", index=0, repeat=0, params=params,
                problem=dict(spec), base=None, base_data=None, overrides=params, energy_limit=energy_limit,
                samples=samples)


def largest_stable_cfl(basis: str, transfer: str, spec: dict, lo: float = 0.1, hi: float = 1.5, tol: float = 0.05,
                       energy_limit: float = 1.1, timeout: Optional[float] = 600, extra: Optional[dict] = None,
                       log=None) -> dict:
    """Bisection for the largest CFL number in [lo, hi] at which `spec` is stable (assumes stability is
    monotone in CFL). Returns {cfl, trials: [(cfl, outcome, cause, energy_ratio_max)]}; cfl = None when
    even `lo` is unstable, `hi` when `hi` is stable."""
    trials = []

    def trial(c):
        rec = execute_case(cfl_case(basis, transfer, c, spec, energy_limit=energy_limit, extra=extra), timeout,
                           None, user_paths())
        ok = is_stable(rec, energy_limit)
        trials.append((round(c, 4), rec.get("outcome"), rec.get("cause", ""), rec.get("energy_ratio_max")))
        if log:
            log(f"{basis}/{transfer} cfl={c:.3f}: {'stable' if ok else 'UNSTABLE'} {rec.get('outcome')} "
                f"{rec.get('cause', '')} E/E0={rec.get('energy_ratio_max')}")
        return ok

    if trial(hi):
        return dict(basis=basis, transfer=transfer, cfl=hi, trials=trials)
    if not trial(lo):
        return dict(basis=basis, transfer=transfer, cfl=None, trials=trials)
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if trial(mid):
            lo = mid
        else:
            hi = mid
    return dict(basis=basis, transfer=transfer, cfl=lo, trials=trials)


CFL_SPEC = {"type": "impact", "dim": 2, "cells": 16, "mach": 0.1, "transits": 24.0}  # 6 transits was too short


def cfl_table(bases=None, transfers=None, spec=None, jobs: int = 1, **kw) -> list[dict]:
    """largest_stable_cfl for every basis x transfer (combinations in parallel with `jobs`); bases: default the
    registry's swept bases (bases/registry.py); transfers: every registered scheme by default, each only with the
    bases it works with (schemes/)."""
    spec = spec or CFL_SPEC
    bases = basis_registry.swept() if bases is None else bases
    transfers = transfers or transfer_schemes.names()
    combos = [(b, t) for b in bases for t in transfers if transfer_schemes.works_with(t, b)]
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        return list(pool.map(lambda bt: largest_stable_cfl(bt[0], bt[1], spec, **kw), combos))


def cfl_markdown(rows: list[dict], spec: dict) -> str:
    transfers = list(dict.fromkeys(r["transfer"] for r in rows))
    bases = list(dict.fromkeys(r["basis"] for r in rows))
    lines = [f"Largest stable CFL number (bisection, tolerance in the trials) on `{json.dumps(spec)}`", "",
             "| basis | " + " | ".join(transfers) + " |", "|---|" + "---|" * len(transfers)]
    for b in bases:
        cells = []
        for t in transfers:
            r = next((r for r in rows if r["basis"] == b and r["transfer"] == t), None)
            cells.append("n/a" if r is None else "< lo" if r["cfl"] is None else f"{r['cfl']:.2f}")
        lines.append(f"| {b} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
