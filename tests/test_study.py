"""Studies end to end: cases in their own processes, CSV + plots + summary, unstable cases, resume, Dask."""
import csv
import json
import math
import sys
from pathlib import Path

import pytest
import yaml

from taichi_mpm.cli import main
from taichi_mpm.config import ConfigError
from taichi_mpm.tools.study import convergence_rates, load_study, pareto_front, run_study

HERE = Path(__file__).parent
MMS_1D = {"type": "mms_axis_aligned", "dim": 1, "amplitude": 0.001}   # taichi_mpm.analytic
PROBLEM = {"type": "study_problems:mms1d", "amplitude": 0.01}        # a cheaper stand-in, tests/study_problems.py
ALLOW = ["study_problems:mms1d", "study_problems:broken"]            # outside the project: opted in (--allow-problem)


def _write(tmp_path, study) -> Path:
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump(study, sort_keys=False))
    return path


def _rows(out):
    with open(out / "results.csv") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def small_study(tmp_path_factory):
    """Two bases x two resolutions on the 1D manufactured solution, two jobs in parallel."""
    tmp = tmp_path_factory.mktemp("study")
    path = _write(tmp, dict(study="mms1d_small", problem=MMS_1D,
                            vary={"solver.basis": ["linear", "quadratic"], "domain.dx": [0.0625, 0.03125]},
                            samples=4))
    out = run_study(path, out=tmp / "out", jobs=2)
    return path, out


@pytest.mark.slow
def test_small_study_writes_csv_plots_and_rates(small_study):
    _, out = small_study
    rows = _rows(out)
    assert len(rows) == 4
    for col in ("solver.basis", "domain.dx", "outcome", "cause", "error_rms", "error_max", "wall_time",
                "compile_time", "step_time", "steps", "particle_steps_per_s", "peak_memory_mb"):
        assert col in rows[0], col
    assert [r["outcome"] for r in rows] == ["ok"] * 4, [r["message"] for r in rows]
    for r in rows:
        assert float(r["wall_time"]) >= float(r["compile_time"]) + float(r["step_time"]) > 0
        assert int(r["steps"]) > 10
        assert float(r["particle_steps_per_s"]) > 1e3
        assert 20 < float(r["peak_memory_mb"]) < 4000
    err = {(r["solver.basis"], float(r["domain.dx"])): float(r["error_rms"]) for r in rows}
    rate_q = math.log(err["quadratic", 0.0625] / err["quadratic", 0.03125]) / math.log(2)
    assert rate_q >= 1.7, err
    rate_l = math.log(err["linear", 0.0625] / err["linear", 0.03125]) / math.log(2)
    assert rate_l >= 1.7 and err["quadratic", 0.03125] < 2e-5, err   # small amplitude: no cell crossing
    for name in ("pareto.png", "convergence.png"):
        png = out / name
        assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000
    summary = (out / "summary.md").read_text()
    assert "| quadratic |" in summary and "Pareto front" in summary
    # the fitted slope in the summary matches the two-point rate
    line = next(l for l in summary.splitlines() if l.startswith("| quadratic | ") and "Convergence" not in l
                and l.count("|") == 5)
    assert float(line.split("|")[2]) == pytest.approx(rate_q, abs=0.01)


@pytest.mark.slow
def test_resume_skips_finished_cases(small_study, tmp_path):
    path, out = small_study
    before = {f.name: f.read_text() for f in (out / "cases").glob("*.json")}
    victim = sorted(before)[0]
    (out / "cases" / victim).unlink()
    run_study(path, out=out, jobs=1, resume=True)
    after = {f.name: f.read_text() for f in (out / "cases").glob("*.json")}
    assert set(after) == set(before)
    assert all(after[n] == before[n] for n in before if n != victim)   # untouched: not rerun
    assert json.loads(after[victim])["outcome"] == "ok"
    assert len(_rows(out)) == 4


@pytest.mark.slow
def test_unstable_case_is_recorded_and_others_finish(tmp_path):
    path = _write(tmp_path, dict(study="blowup", problem=PROBLEM, set={"domain.dx": 0.0625}, samples=2,
                                 cases=[{"solver.dt": 1.0e-4}, {"solver.dt": 0.05}, {"solver.basis": "no_such_basis"}]))
    with pytest.raises(ConfigError, match="no_such_basis"):  # an invalid case config fails the study before it runs
        load_study(path, allow_problems=ALLOW)
    # dt = 1e-3 is CFL 1.6 here: J <= 0 within a few steps; dt = 5e-3 (CFL 8) reaches the end time in two
    # steps with the energy grown ~460 x and no solver error: the energy limit must catch that garbage
    path = _write(tmp_path, dict(study="blowup", problem=PROBLEM, set={"domain.dx": 0.0625}, samples=2,
                                 energy_limit=10.0,
                                 cases=[{"solver.dt": 1.0e-4}, {"solver.dt": 1.0e-3},
                                        {"problem.type": "study_problems:broken"}, {"solver.dt": 5.0e-3}]))
    out = run_study(path, out=tmp_path / "out", jobs=1, allow_problems=ALLOW)
    rows = _rows(out)
    assert [r["outcome"] for r in rows] == ["ok", "unstable", "error", "unstable"]
    # the solver's energy balance now stops this garbage itself (after the last step); the study's own
    # energy limit stays as the backstop for runs with the check off
    assert rows[3]["cause"] == "energy growth beyond the work done on the system"
    assert 0.5 < float(rows[0]["energy_ratio_max"]) < 10
    from taichi_mpm.solver import CAUSES
    assert rows[1]["cause"] in CAUSES  # now the energy balance (before J <= 0)
    assert int(rows[1]["fail_step"]) >= 1 and "numerical instability" in rows[1]["message"]
    assert "broken setup on purpose" in rows[2]["message"]
    assert float(rows[0]["error_rms"]) < 1e-4
    assert (out / "pareto.png").is_file() and (out / "summary.md").is_file()


def test_study_file_errors_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match="vary.solver.basis"):
        load_study(_write(tmp_path, dict(study="x", problem=PROBLEM, vary={"solver.basis": "quadratic"})), ALLOW)
    with pytest.raises(ConfigError, match="bogus"):
        load_study(_write(tmp_path, dict(study="x", problem=PROBLEM, vary={"domain.dx": [0.1]}, bogus=1)), ALLOW)
    with pytest.raises(ConfigError, match="exactly one"):
        load_study(_write(tmp_path, dict(study="x", vary={"domain.dx": [0.1]})))


def test_grid_and_cases_expand(tmp_path):
    st = load_study(_write(tmp_path, dict(study="x", problem=PROBLEM, repeats=2,
                                          vary={"solver.basis": ["linear", "cubic"], "domain.dx": [0.1, 0.05, 0.025]},
                                          cases=[{"solver.transfer": "pic"}, {"solver.transfer": "flip"}])), ALLOW)
    cases = st.expand()
    assert len(cases) == 2 * 3 * 2 * 2
    assert len({c["digest"] for c in cases}) == len(cases)
    assert st.varied == ["solver.basis", "domain.dx", "solver.transfer"]
    assert cases[0]["overrides"] == {"solver.basis": "linear", "domain.dx": 0.1, "solver.transfer": "pic"}


def test_pareto_front_and_rates():
    pts = [dict(params={"b": "a", "h": h}, time=t, error=e)
           for h, t, e in [(0.1, 1.0, 1e-2), (0.05, 2.0, 2.5e-3), (0.025, 4.0, 6.25e-4)]]
    pts.append(dict(params={"b": "z", "h": 0.1}, time=3.0, error=5e-3))   # dominated by (2.0, 2.5e-3)
    front = pareto_front(pts)
    assert [p["time"] for p in front] == [1.0, 2.0, 4.0]
    fits = convergence_rates(pts, ["b"], "h")
    assert fits["a"]["rate"] == pytest.approx(2.0, abs=1e-9)
    assert "z" not in fits


@pytest.mark.slow
def test_two_cases_on_a_local_dask_cluster(tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    path = _write(tmp_path, dict(study="dask2", problem=PROBLEM, set={"domain.dx": 0.0625}, samples=2,
                                 vary={"solver.basis": ["quadratic", "gimp"]}))
    with distributed.LocalCluster(processes=True, n_workers=1, threads_per_worker=2, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        out = run_study(path, out=tmp_path / "out", scheduler=cluster.scheduler_address, allow_problems=ALLOW)
    rows = _rows(out)
    assert [r["solver.basis"] for r in rows] == ["quadratic", "gimp"]
    assert [r["outcome"] for r in rows] == ["ok", "ok"], [r["message"] for r in rows]
    # a sanity bound (a case run wrong has an error of the amplitude, 1e-2): measured 1.6e-4 / 1.4e-4 at dx 1/16
    # since positions follow the trapezoid under the MMS body force (below 1e-4 with symplectic Euler)
    assert all(float(r["error_rms"]) < 3e-4 for r in rows), [r["error_rms"] for r in rows]


@pytest.mark.slow
def test_study_over_a_base_config_file(tmp_path):
    """`base:` a config file (relative to the study file); no exact solution: energy drift is the metric."""
    from conftest import make_cfg
    cfg = make_cfg(2, velocity=[0.3, 0.0], dx=0.1, end_time=0.02, E=1.0e4)
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "block.yaml").write_text(yaml.safe_dump(cfg))
    (tmp_path / "studies").mkdir()
    path = tmp_path / "studies" / "s.yaml"
    path.write_text(yaml.safe_dump(dict(study="base_cfg", base="../configs/block.yaml", samples=3,
                                        vary={"solver.transfer": ["pic", "apic"]})))
    out = run_study(path, out=tmp_path / "out")
    rows = _rows(out)
    assert [r["solver.transfer"] for r in rows] == ["pic", "apic"]
    assert [r["outcome"] for r in rows] == ["ok", "ok"]
    assert not any(k.startswith("error_") for k in rows[0])
    for r in rows:   # a free block in uniform motion keeps its kinetic energy exactly
        assert float(r["energy_ratio_end"]) == pytest.approx(1.0, abs=1e-9)
        assert int(r["particles"]) == 36
    assert "energy_drift" in (out / "summary.md").read_text()
    with pytest.raises(ConfigError, match="base config not found"):
        load_study(_write(tmp_path, dict(study="x", base="nope.yaml", vary={"domain.dx": [0.1]})))


# ---------------------------------------------------------------- study files run no code of their own
EVIL = '''import pathlib
pathlib.Path(__file__).with_name("imported.txt").write_text("imported")
def make(spec):
    pathlib.Path(__file__).with_name("called.txt").write_text("called")
    raise RuntimeError("a study file called me")
'''


@pytest.mark.parametrize("where", ["problem", "cases", "vary"])
@pytest.mark.parametrize("kind", ["os:system", "subprocess:run", "evil_problem:make"])
def test_study_file_cannot_import_or_call_other_code(tmp_path, monkeypatch, capsys, where, kind):
    (tmp_path / "evil_problem.py").write_text(EVIL)
    monkeypatch.syspath_prepend(str(tmp_path))
    called = []
    monkeypatch.setattr("os.system", lambda *a: called.append(a))
    monkeypatch.setattr("subprocess.run", lambda *a, **k: called.append(a))
    study = dict(study="evil", problem=dict(MMS_1D), vary={"domain.dx": [0.0625]})
    key = {"problem": "problem.type", "cases": "cases.0.problem.type", "vary": "vary.problem.type.1"}[where]
    if where == "problem":
        study["problem"]["type"] = kind
    elif where == "cases":
        study["cases"] = [{"problem.type": kind}]
    else:
        study["vary"]["problem.type"] = ["mms_axis_aligned", kind]
    path = _write(tmp_path, study)
    line = next(i + 1 for i, l in enumerate(path.read_text().splitlines()) if kind in l)
    with pytest.raises(ConfigError, match="--allow-problem") as err:
        load_study(path)
    assert err.value.key == key and err.value.line == line
    monkeypatch.chdir(tmp_path)
    assert main(["study", str(path)]) == 2
    msg = capsys.readouterr().err
    assert f"study.yaml:{line}" in msg and key in msg and "Traceback" not in msg
    assert not called and "evil_problem" not in sys.modules
    assert not (tmp_path / "imported.txt").exists() and not (tmp_path / "called.txt").exists()
    assert not (tmp_path / "studies").exists()


def test_allow_problem_opts_in(tmp_path, monkeypatch, capsys):
    """With --allow-problem the factory is imported and called (to validate its cases); others stay refused."""
    (tmp_path / "evil_problem.py").write_text(EVIL)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    path = _write(tmp_path, dict(study="evil", problem={"type": "evil_problem:make"}, vary={"domain.dx": [0.1]}))
    assert main(["study", str(path), "--allow-problem", "study_problems:mms1d", "--dry-run"]) == 2
    assert not (tmp_path / "imported.txt").exists()
    capsys.readouterr()
    assert main(["study", str(path), "--allow-problem", "evil_problem:make", "--dry-run"]) == 2
    assert (tmp_path / "called.txt").exists()      # called, and its failure is reported as invalid input
    assert "a study file called me" in capsys.readouterr().err
    path = _write(tmp_path, dict(study="ok", problem=PROBLEM, vary={"domain.dx": [0.0625, 0.03125]}))
    assert main(["study", str(path), "--dry-run", *(f"--allow-problem={a}" for a in ALLOW)]) == 0
    out = capsys.readouterr().out
    assert "2 cases" in out and '"domain.dx": 0.03125' in out
    assert not (tmp_path / "studies").exists()     # a dry run writes nothing


def test_metrics_table_covers_every_project_problem():
    from taichi_mpm import analytic
    from taichi_mpm.tools import stability
    from taichi_mpm.tools.study import PROBLEM_METRICS
    assert set(PROBLEM_METRICS) == set(analytic.PROBLEMS) | set(stability.SCENARIOS)


# ---------------------------------------------------------------- names, options: refused up front, key and line
@pytest.mark.parametrize("name", ["..", ".", "a/b", "a\\b", "a\x00b", ".hidden", "", "x" * 101, 12, None, ["a"]])
def test_study_names_that_are_not_plain_folder_names_are_refused(tmp_path, monkeypatch, capsys, name):
    path = _write(tmp_path, dict(study=name, problem=MMS_1D, vary={"domain.dx": [0.0625]}))
    with pytest.raises(ConfigError, match="study name") as err:
        load_study(path)
    assert err.value.key == "study" and err.value.line == 1
    monkeypatch.chdir(tmp_path)
    assert main(["study", str(path)]) == 2
    assert "key 'study'" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["study.yaml"]


BAD_OPTIONS = [
    ("samples", 0), ("samples", 2.5), ("samples", "ten"), ("samples", True), ("samples", 10**6),
    ("repeats", 0), ("repeats", True), ("repeats", -1), ("jobs", 0), ("jobs", "2"),
    ("timeout", 0), ("timeout", -5), ("timeout", "1e3"), ("timeout", float("inf")), ("timeout", True),
    ("energy_limit", 0), ("energy_limit", float("nan")), ("energy_limit", [2]),
    ("metric", "error_typo"), ("metric", "error_energy"), ("metric", 3), ("time_metric", "cpu_time"),
    ("convergence_key", 1), ("convergence_key", "a..b"), ("description", {"a": 1}),
    ("vary.domain.dx", []), ("vary.domain.dx", 0.1), ("vary.domain.dx", {"a": 1}), ("set", [1]),
    ("cases", {"a": 1}), ("cases", [{}]), ("cases", ["solver.basis=cubic"]), ("bogus", 1), ("problem", "mms"),
]


@pytest.mark.parametrize("key,value", BAD_OPTIONS, ids=[f"{k}={v!r}" for k, v in BAD_OPTIONS])
def test_bad_study_options_name_key_and_line(tmp_path, key, value):
    study = dict(study="opts", problem=MMS_1D, vary={"domain.dx": [0.0625]}, samples=3)
    if key.startswith("vary."):
        study["vary"] = {key[5:]: value}
    else:
        study[key] = value
    path = _write(tmp_path, study)
    with pytest.raises(ConfigError) as err:
        load_study(path)
    assert err.value.key is not None and err.value.key.split(".")[0] == key.split(".")[0], str(err.value)
    assert err.value.line is not None, str(err.value)


def test_metric_known_for_the_problem(tmp_path):
    assert load_study(_write(tmp_path, dict(study="m", problem=MMS_1D, vary={"domain.dx": [0.0625]},
                                            metric="error_max"))).metric == "error_max"
    with pytest.raises(ConfigError, match="known: energy_drift, energy_ratio_max, energy_ratio_end, error_rms"):
        load_study(_write(tmp_path, dict(study="m", problem=MMS_1D, vary={"domain.dx": [0.0625]},
                                         metric="error_energy")))


def test_too_many_cases_is_refused_before_expanding(tmp_path):
    vary = {f"k{i}": list(range(10)) for i in range(12)}   # 10^12 cases: must not be listed
    with pytest.raises(ConfigError, match="cases"):
        load_study(_write(tmp_path, dict(study="big", problem=MMS_1D, vary=vary)))


# ---------------------------------------------------------------- the output folder
def _fake_case(case, timeout=None, threads=None, paths=None):
    return dict(case=case["id"], repeat=case["repeat"], **case["params"], outcome="ok", cause="", wall_time=0.25,
                step_time=0.1, energy_ratio_end=1.0, error_rms=float(case["params"]["domain.dx"]) ** 2)


def test_output_folder_is_not_overwritten_unasked(tmp_path, monkeypatch, capsys):
    """Cases are stubbed (no simulation): this checks the folder rules and the progress lines only."""
    import taichi_mpm.tools.study as study_mod
    monkeypatch.setattr(study_mod, "execute_case", _fake_case)
    monkeypatch.chdir(tmp_path)
    path = _write(tmp_path, dict(study="folder", problem=MMS_1D, vary={"domain.dx": [0.0625, 0.03125]}))
    assert main(["study", str(path)]) == 0
    err = capsys.readouterr().err
    assert "case 1/2 [domain.dx=0.0625]: ok 0.2 s" in err and "case 2/2 [domain.dx=0.03125]: ok 0.2 s" in err
    out = tmp_path / "studies" / "folder"
    assert len(_rows(out)) == 2
    (out / "notes.txt").write_text("mine")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert main(["study", str(path)]) == 2                      # results there: refused, nothing touched
    err = capsys.readouterr().err
    assert "--resume" in err and "--overwrite" in err and "key 'study'" in err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert main(["study", str(path), "--resume", "--overwrite"]) == 2
    assert main(["study", str(path), "--resume"]) == 0          # nothing left to run
    assert "case " not in capsys.readouterr().err
    (out / "cases" / "stale.json").write_text("{}")
    assert main(["study", str(path), "--overwrite"]) == 0
    assert not (out / "cases" / "stale.json").exists() and (out / "notes.txt").read_text() == "mine"
    assert len(list((out / "cases").glob("*.json"))) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["studies", "study.yaml"]
    with pytest.raises(ConfigError, match="jobs"):
        run_study(path, out=tmp_path / "o2", jobs=0)


# ---------------------------------------------------------------- material parameters (issue 11)
GRANULAR = Path(__file__).resolve().parents[1] / "configs" / "granular_collapse.yaml"


def _granular_study(tmp_path, angles):
    return _write(tmp_path, dict(
        study="friction", base=str(GRANULAR), samples=3, observe="column.ux@end", reference="finest",
        vary={"materials.sand.friction_angle": angles},
        set={"arch": "cpu", "domain.dx": 0.025, "solver.end_time": 0.25, "output.formats": [],
             "output.probes": [{"name": "column", "type": "body", "body": 0}]}))


def test_study_varies_material_parameters_and_names_a_bad_one(tmp_path):
    """A study can sweep a model's own keys (materials.sand.friction_angle of drucker_prager): the cases expand and
    validate; an inadmissible angle fails the study before it runs, naming the key."""
    st = load_study(_granular_study(tmp_path, [20, 40]))
    assert [c["params"]["materials.sand.friction_angle"] for c in st.expand()] == [20, 40]
    with pytest.raises(ConfigError, match="friction_angle"):
        load_study(_granular_study(tmp_path, [20, 95]))


@pytest.mark.slow
def test_study_over_friction_angle_spreads_weaker_sand_farther(tmp_path):
    """The friction-angle sweep run: the column's centre of mass moves farther along the floor for phi = 20 than
    for phi = 40 deg (weaker sand spreads more; a sweep that did not reach the model would give equal values)."""
    out = run_study(_granular_study(tmp_path, [20, 40]), out=tmp_path / "out")
    rows = _rows(out)
    assert [r["outcome"] for r in rows] == ["ok", "ok"], [r["message"] for r in rows]
    ux = {float(r["materials.sand.friction_angle"]): float(r["observed"]) for r in rows}
    assert ux[20] > 1.2 * ux[40] > 0, ux
