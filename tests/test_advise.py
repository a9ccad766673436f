"""Studies on the user's own quantity (`observe`, `reference`) and `taichi-mpm advise`.

Default tests: the checks of the new keys (no case runs), the reference arithmetic on made-up records, and one
small advise on the 1D manufactured solution, compared with the exhaustive sweep of the same candidates.
Slow tests (`-m slow`): advise against exhaustive sweeps on the manufactured solution and the vibrating bar
(where the true error is known), and advise on colliding_disks' rebound velocity."""
import csv
import re
from pathlib import Path

import pytest

from taichi_mpm.tools import observe as obs
from taichi_mpm.tools.advise import advise, parse_problem, parse_tolerance
from taichi_mpm.analytic import VibratingBar
from taichi_mpm.cli import main
from taichi_mpm.config import ConfigError
from taichi_mpm.tools.study import load_study, run_study

REPO = Path(__file__).resolve().parents[1]
BAR_PROBE = {"output.probes": [{"name": "bar", "type": "body", "body": "bar"}]}


def bar_study(**kw):
    return dict(dict(study="s", problem={"type": "vibrating_bar", "cells": 8}, vary={"domain.dx": [3.125, 1.5625]},
                     set=BAR_PROBE), **kw)


# ---------------------------------------------------------------- checks, before anything runs
@pytest.mark.parametrize("study, key, words", [
    (bar_study(observe="nope.vx"), "observe", "no probe named 'nope'"),
    (bar_study(observe="bar.q"), "observe", "has no column 'q' (columns: ux, vx, sxx"),
    (bar_study(observe="bar.vx@median"), "observe", "unknown reduction @median"),
    (bar_study(observe="potential_energy"), "observe", "unknown quantity 'potential_energy'"),
    (bar_study(observe="os:system"), "observe", "--allow-problem os:system"),
    (bar_study(observe="bar.vx", reference="best"), "reference", "a number or one of exact, finest, richardson"),
    (bar_study(observe="bar.vx", reference="exact"), "reference", "goes with an analytic problem's error metric"),
    (bar_study(observe="error_rel", reference=0.5), "reference", "already an error against the exact solution"),
    (bar_study(reference="finest"), "reference", "add `observe`"),
    (bar_study(observe="bar.vx", metric="error_speed"), "metric", "unknown metric 'error_speed'"),
    (bar_study(observe="bar.vx", timing={"runs": -1}), "timing.runs", "from 0 to 100"),
])
def test_bad_observe_reference_metric_timing_are_config_errors(study, key, words):
    with pytest.raises(ConfigError) as e:
        load_study(study)
    assert e.value.key == key and words in str(e.value)


def test_observe_kinds_settle_against_the_problem():
    st = load_study(bar_study(observe="bar.vx@max"))
    assert st.observe["kind"] == "probe" and st.reference == "richardson" and st.metric == "error_observed"
    st = load_study(bar_study(observe="error_rel"))
    assert st.observe["kind"] == "metric" and st.reference == "exact"
    st = load_study(bar_study(observe="kinetic_energy@mean", reference=0.01))
    assert st.observe["kind"] == "function" and st.reference == 0.01
    assert all(c["observe"]["text"] == "kinetic_energy@mean" for c in st.expand())


def test_tolerance_and_problem_arguments():
    assert parse_tolerance("1%") == pytest.approx(0.01) and parse_tolerance("0.02") == 0.02
    for bad in ("0", "-1%", "abc", "nan"):
        with pytest.raises(ConfigError, match="--tolerance"):
            parse_tolerance(bad)
    assert parse_problem("vibrating_bar") == {"type": "vibrating_bar"}
    assert parse_problem("{type: hertz, cells: 8}") == {"type": "hertz", "cells": 8}
    assert main(["advise", "--problem", "vibrating_bar", "--observe", "bar.vx", "--tolerance", "1%"]) == 2  # no probe
    assert main(["advise", "--problem", "nope", "--observe", "error_rel", "--tolerance", "1%"]) == 2
    assert main(["advise", "missing.yaml", "--observe", "error_rel", "--tolerance", "1%"]) == 2


# ---------------------------------------------------------------- the reference from made-up records
def test_richardson_recovers_a_known_limit():
    # q(h) = 2 + 0.5 h^2 exactly: three levels give order 2 and the limit 2 (to round-off)
    recs = [dict(outcome="ok", observed=2 + 0.5 * h**2, **{"domain.dx": h, "solver.basis": b})
            for h in (0.4, 0.2, 0.1) for b in ("linear", "cubic")]
    value, how = obs.reference_value(recs, "richardson", "domain.dx", ["solver.basis", "domain.dx"])
    assert value == pytest.approx(2.0, abs=1e-12) and "orders 2.00, 2.00" in how
    value, how = obs.reference_value(recs, "finest", "domain.dx", ["solver.basis", "domain.dx"])
    assert value == pytest.approx(2 + 0.5 * 0.01) and "domain.dx=0.1" in how
    # oscillating values: no extrapolation, the finest median instead (and it says so)
    bad = [dict(outcome="ok", observed=v, **{"domain.dx": h}) for h, v in ((0.4, 1.0), (0.2, 3.0), (0.1, 2.0))]
    value, how = obs.reference_value(bad, "richardson", "domain.dx", ["domain.dx"])
    assert value == 2.0 and "no group converged" in how
    obs.observed_errors(recs, 2.0, {"kind": "probe"})
    assert recs[0]["error_observed"] == pytest.approx(0.5 * 0.16 / 2)


@pytest.mark.slow
def test_observed_values_of_a_function_and_an_allowed_callable(tmp_path):
    # a 1D block gliding at 0.5 m/s (no gravity, away from the walls): its mean x moves by exactly 0.5 t and its
    # kinetic energy stays m v^2 / 2; one run, both observables (the callable in the study, the function in a
    # second study of the same case, reusing the compiled kernels). Tolerances: round-off of f64 sums (1e-9)
    import yaml
    from conftest import make_cfg
    cfg = make_cfg(1, velocity=[0.5], lower=[0.3], upper=[0.6], end_time=0.04)
    (tmp_path / "block.yaml").write_text(yaml.safe_dump(cfg))
    x0 = 0.45   # the block's centre
    study = dict(study="glide", base="block.yaml", vary={"solver.transfer": ["apic"]}, timing={"runs": 0},
                 observe="study_problems:mean_x@end", reference=x0 + 0.5 * 0.04)
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(study))
    with pytest.raises(ConfigError, match="--allow-problem study_problems:mean_x"):
        load_study(tmp_path / "s.yaml")
    out = run_study(tmp_path / "s.yaml", out=tmp_path / "a", jobs=1, allow_problems=["study_problems:mean_x"])
    (row,) = csv.DictReader(open(out / "results.csv"))
    assert float(row["observed"]) == pytest.approx(x0 + 0.02, abs=1e-9)
    assert float(row["error_observed"]) < 1e-8
    assert "reference 0.47 (the given value)" in (out / "summary.md").read_text()

    mass = 1000.0 * 0.3   # density x length (1D: per m^2 of cross-section)
    study.update(observe="kinetic_energy@max", reference=0.5 * mass * 0.5**2)
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(study))
    out = run_study(tmp_path / "s.yaml", out=tmp_path / "b", jobs=1)
    (row,) = csv.DictReader(open(out / "results.csv"))
    assert float(row["error_observed"]) < 1e-9


# ---------------------------------------------------------------- one small advise, against its exhaustive sweep
MMS = {"type": "mms_axis_aligned", "cells": 8, "amplitude": 0.01}


def exhaustive(tmp_path, problem, observe, bases, transfers, dxs, overrides=None, name="all"):
    """Every candidate run (a plain study of the same cases): {(basis, transfer, dx): record}."""
    import yaml
    study = dict(study=name, problem=problem, observe=observe, set=dict(overrides or {}), timing={"runs": 0},
                 vary={"solver.basis": list(bases), "solver.transfer": list(transfers), "domain.dx": list(dxs)})
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(study))
    out = run_study(path, out=tmp_path / name, jobs=1)
    with open(out / "results.csv") as f:
        return {(r["solver.basis"], r["solver.transfer"], float(r["domain.dx"])): r for r in csv.DictReader(f)}


def work(row, dim=1):
    stencil = {"linear": 2, "gimp": 3, "quadratic": 3, "cubic": 4}
    return float(row["particles"]) * float(row["steps"]) * stencil[row["solver.basis"]] ** dim


def check_against_exhaustive(result, table, true_error, tol, dim=1):
    """The pick's true error is within the tolerance and its cost within 1.5x of the cheapest setting whose
    true error is (costs: `work`, the same count in both, so the comparison does not depend on the machine's load)."""
    c = result["choice"]
    assert c is not None, result["out"]
    p = c["params"]
    row = table[(p["solver.basis"], p["solver.transfer"], p["domain.dx"])]
    assert true_error(row) <= tol
    feasible = [work(r, dim) for r in table.values() if r["outcome"] == "ok" and true_error(r) <= tol]
    assert work(row, dim) <= 1.5 * min(feasible)


@pytest.mark.slow
def test_advise_mms_small_matches_the_exhaustive_sweep(tmp_path, capsys):
    # 2 bases x 2 levels of the 1D manufactured solution; error_rel is the true error (against the exact
    # solution) relative to the amplitude. Measured at this size: linear 0.110 / 0.028, quadratic 0.155 / 0.042:
    # a 5 % tolerance is met only at dx = 1/16, where linear is the cheaper
    tol, dxs = 0.05, (0.125, 0.0625)
    table = exhaustive(tmp_path, MMS, "error_rel", ("linear", "quadratic"), ("flip",), dxs)
    # advise reuses those records (same cases, same digests: --resume), so this checks its choice and pruning
    result = advise(problem=MMS, observe="error_rel", tolerance=tol, bases=("linear", "quadratic"),
                    transfers=("flip",), levels=2, cost="work", timing={"runs": 0}, out=tmp_path / "all",
                    resume=True, jobs=1)
    check_against_exhaustive(result, table, lambda r: float(r["error_rel"]), tol)
    assert result["choice"]["params"] == {"solver.basis": "linear", "solver.transfer": "flip", "domain.dx": 0.0625}
    advice = (tmp_path / "all" / "advice.md").read_text()
    assert "Cheapest setting" in advice and "feasible" in advice and (tmp_path / "all" / "pareto.png").is_file()


# ---------------------------------------------------------------- slow: the acceptance runs
@pytest.mark.slow
def test_advise_mms_against_exhaustive_sweep(tmp_path):
    bases, transfers, levels, tol = ("linear", "gimp", "quadratic", "cubic"), ("flip", "apic"), 3, 0.02
    dxs = [0.125 / 2**k for k in range(levels)]
    result = advise(problem=MMS, observe="error_rel", tolerance=tol, bases=bases, transfers=transfers,
                    levels=levels, cost="work", timing={"runs": 0}, out=tmp_path / "advice", jobs=1)
    table = exhaustive(tmp_path, MMS, "error_rel", bases, transfers, dxs)
    check_against_exhaustive(result, table, lambda r: float(r["error_rel"]), tol)
    ran = sum(1 for r in result["rows"])
    assert ran < len(table)   # adaptive: fewer runs than the exhaustive sweep


@pytest.mark.slow
def test_advise_vibrating_bar_with_an_estimated_reference(tmp_path):
    # the bar's centre-of-mass velocity at t = 2 s from a body probe; advise does not know the exact value
    # (Richardson extrapolation of the most accurate candidate); its pick is checked against the exact solution
    problem, tol = {"type": "vibrating_bar", "cells": 8, "end_time": 2.0}, 0.02
    bases, transfers, levels = ("linear", "quadratic", "cubic"), ("flip", "apic"), 4
    result = advise(problem=problem, observe="bar.vx", tolerance=tol, bases=bases, transfers=transfers,
                    levels=levels, cost="work", timing={"runs": 0}, overrides=BAR_PROBE, out=tmp_path / "advice",
                    jobs=1)
    exact = VibratingBar(cells=8, end_time=2.0).exact_com_velocity(2.0)
    assert result["reference"][0] == pytest.approx(exact, rel=0.005)   # the extrapolation itself: 0.5 %
    dxs = [25 / 8 / 2**k for k in range(levels)]
    table = exhaustive(tmp_path, problem, "bar.vx", bases, transfers, dxs, overrides=BAR_PROBE)
    check_against_exhaustive(result, table, lambda r: abs(float(r["observed"]) - exact) / abs(exact), tol)


@pytest.mark.slow
def test_advise_colliding_disks_rebound_velocity(tmp_path, capsys):
    # the demo's config with its lower_disk probe; rebound velocity = the disk's mean vx at the end (t = 4 s)
    code = main(["advise", str(REPO / "configs" / "colliding_disks.yaml"), "--observe", "lower_disk.vx",
                 "--tolerance", "5%", "--bases", "linear,quadratic", "--transfers", "apic", "--levels", "3",
                 "--set", "domain.dx=0.1", "--set", "arch=cpu", "--set", "output.formats=[]",
                 "--cost", "work", "--out", str(tmp_path / "disks")])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "cheapest setting" in captured.err and captured.out.startswith("solver.basis=")
    advice = (tmp_path / "disks" / "advice.md").read_text()
    m = re.search(r"Reference value (-?[\d.e+-]+)", advice)
    assert m, advice
    reference = float(m.group(1))
    # the disks rebound: the lower disk moves back (vx < 0), and no faster than it came in (0.1 m/s: equal
    # elastic disks exchange at most their impact speed); the chosen setting's own value says the same
    assert -0.1 < reference < 0
    rows = {r["case"]: r for r in csv.DictReader(open(tmp_path / "disks" / "results.csv"))}
    chosen = [r for r in rows.values() if r["outcome"] == "ok" and "solver.basis=" + r["solver.basis"] in captured.out
              and f"domain.dx={float(r['domain.dx']):g}" in captured.out and r["solver.transfer"] == "apic"]
    assert chosen and all(-0.1 < float(r["observed"]) < 0 for r in chosen)


# ---------------------------------------------------------------- an impossible tolerance (issue 30)
def _fake_records(observed):
    """A stand-in for run_cases that 'runs' each case instantly: outcome ok, observed = observed(dx)."""
    def run_cases(cases, jobs, scheduler, timeout, store):
        for c in cases:
            dx = float(c["params"]["domain.dx"])
            store(c, dict(case=c["id"], repeat=c["repeat"], **c["params"], outcome="ok", cause="",
                          observed=observed(dx), step_time=1.0 / dx, wall_time=2.0 / dx, particles=int(100 / dx),
                          steps=int(10 / dx)))
    return run_cases


@pytest.mark.parametrize("levels", [1, 2, 3])
def test_an_impossible_tolerance_has_no_feasible_candidate(tmp_path, monkeypatch, capsys, levels):
    """1e-30 is below any run's error. With fewer than three levels Richardson cannot extrapolate and the
    reference is the finest run's own value: that run (error 0 by construction) must not count as meeting it."""
    import taichi_mpm.tools.advise as advise_mod
    monkeypatch.setattr(advise_mod, "run_cases", _fake_records(lambda dx: 1.0 + 0.01 * dx**2))
    result = advise(problem={"type": "vibrating_bar", "cells": 8}, observe="bar.vx", tolerance=1e-30,
                    bases=("linear", "quadratic"), transfers=("apic",), levels=levels, overrides=BAR_PROBE,
                    timing={"runs": 0}, out=tmp_path / "advice", jobs=1, progress=None)
    assert result["choice"] is None
    assert not [r for r in result["rows"] if r["status"].startswith("feasible")], result["rows"]
    assert "no setting reached the tolerance" in advise_mod.answer_line(result)
    finest = 3.125 / 2 ** (levels - 1)
    assert (f"domain.dx={finest:g}, gives the reference itself" in advise_mod.answer_line(result)) == (levels < 3)
    assert "No setting reached the tolerance" in (tmp_path / "advice" / "advice.md").read_text()


def test_a_reachable_tolerance_is_still_met(tmp_path, monkeypatch):
    """The same fake runs at 1 %: the coarse linear run's error against the Richardson limit 1.0 is 0.01 * 3.125^2
    / 1 > 1 %, the next level's 0.024 > 1 %, the finest 0.006: the cheapest candidate at the finest level wins."""
    import taichi_mpm.tools.advise as advise_mod
    monkeypatch.setattr(advise_mod, "run_cases", _fake_records(lambda dx: 1.0 + 0.001 * dx**2))
    result = advise(problem={"type": "vibrating_bar", "cells": 8}, observe="bar.vx", tolerance=0.01,
                    bases=("linear", "quadratic"), transfers=("apic",), levels=3, overrides=BAR_PROBE,
                    timing={"runs": 0}, out=tmp_path / "advice", jobs=1, progress=None)
    assert result["reference"][0] == pytest.approx(1.0)
    assert result["choice"] is not None and result["choice"]["error"] <= 0.01
