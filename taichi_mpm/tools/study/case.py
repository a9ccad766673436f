"""One study case. Inside its own process (`python -m taichi_mpm.tools.study --case CASE.json --result OUT.json`, which
`execute_case` launches): set up, step with the energy and the quantity sampled outside the timed span, judge the end
state (garbage the solver did not report is "undetected") and write the record; timing reruns give the median step
time. The launcher side runs that process with a timeout and turns a crash or a hang into the case's record."""
import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any, Optional

from .. import observe as obs
from ...errors import InstabilityError
from .spec import case_config


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
        from ...solver import Simulation

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
        cmd = [sys.executable, "-m", "taichi_mpm.tools.study", "--case", str(case_file), "--result", str(result_file)]
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


def user_paths() -> list[str]:
    """This process's import paths outside the Python installation (project and test dirs), for case processes."""
    import sysconfig
    skip = {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
    return [os.path.abspath(p or ".") for p in sys.path
            if not any(os.path.abspath(p or ".").startswith(s) for s in skip) and "site-packages" not in p
            and not p.endswith(".zip")]


def main(argv=None):
    """`python -m taichi_mpm.tools.study --case CASE.json --result OUT.json`: run one case in this process
    (internal: the process execute_case launches). A whole study runs with `taichi-mpm study`."""
    ap = argparse.ArgumentParser(prog="python -m taichi_mpm.tools.study", description="run one study case (internal)")
    ap.add_argument("--case", required=True, help="case JSON file")
    ap.add_argument("--result", required=True, help="where to write the case record")
    args = ap.parse_args(argv)
    rec = run_case_inline(json.loads(Path(args.case).read_text()))
    Path(args.result).write_text(json.dumps(rec, default=str))
    return 0
