"""Stability at the extremes: scenarios for the stability map, and the largest stable CFL number.

Each scenario is a problem in the sense of `taichi_mpm.analytic` (config(), setup(sim),
observe(sim), errors(sim), body_force) so a study runs it like any other problem
(`problem: {type: impact, E: 2.0e11, mach: 0.5}`). Times scale with the elastic wave speed c, so a
case takes about the same number of steps whatever E, nu and density are.

Scenarios (2D by default, `dim` 1-3 where it makes sense; unit square domain, `cells` per side):
- impact:       a block hits the slip wall y = 0 at `mach` x c (up to 0.5), then `transits` wave transits.
- compression:  a block starts isotropically compressed to volume ratio J (down to 0.05) and springs
                back in free space (free walls far away).
- rotation:     a disk spins with rim speed `mach` x c for `turns` revolutions, free walls.
- thin:         a plate one particle thick (particles_per_cell 1, thickness dx) with a bending velocity
                profile of peak `mach` x c, free walls.
- edge:         a block moves at `mach` x c toward the x_max wall (`boundary`: free | slip | sticky) and
                reaches it; with a free wall the particles leave the domain.

A case is *stable* when it reaches its end time with finite state and mechanical energy at most
`energy_limit` x its initial value; otherwise it must have stopped with `InstabilityError` (cause in
the record). A finished case that breaks the energy bound is "undetected" garbage (see study.py).

`python -m taichi_mpm.stability cfl` measures the largest stable CFL number per basis and transfer by
bisection, each trial in its own process.
"""

import argparse
import concurrent.futures
import json
import math
import sys
from pathlib import Path
from typing import Optional

import numpy as np


def _lame(E, nu):
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


class Scenario:
    """Common parts: one material, unit-cube domain of `cells` cells per side, times in units of dx-free c."""

    name = "scenario"
    body_force = None
    boundaries = "free"

    def __init__(self, dim=2, E=1.0e6, nu=0.3, density=1000.0, model="neo_hookean", cells=32, ppc=2,
                 mach=0.1, transits=4.0, precision="f64", **solver):
        if not 1 <= int(dim) <= 3:
            raise ValueError(f"dim must be 1, 2 or 3, got {dim}")
        self.dim, self.E, self.nu, self.rho, self.model = int(dim), float(E), float(nu), float(density), model
        self.cells, self.ppc, self.mach, self.transits = int(cells), int(ppc), float(mach), float(transits)
        self.precision, self.solver = precision, solver
        mu, lam = _lame(self.E, self.nu)
        self.c = math.sqrt((lam + 2 * mu) / self.rho)  # the solver's CFL speed
        self.speed = self.mach * self.c
        self.min_J = 1.0

    @property
    def dx(self) -> float:
        return 1.0 / self.cells

    def bodies(self) -> list:
        raise NotImplementedError

    @property
    def end_time(self) -> float:
        raise NotImplementedError

    def config(self) -> dict:
        d = self.dim
        solver = dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=self.end_time)
        solver.update(self.solver)
        return dict(name=self.name, dim=d, precision=self.precision, arch="cpu",
                    domain=dict(lower=[0.0] * d, upper=[1.0] * d, dx=self.dx,
                                boundaries=self.boundary_config()),
                    solver=solver,
                    materials=dict(m=dict(model=self.model, E=self.E, nu=self.nu, density=self.rho)),
                    bodies=self.bodies(), output=dict(formats=[]))

    def boundary_config(self) -> dict:
        return {"default": self.boundaries}

    def box(self, lo, hi, **kw) -> dict:
        return dict(name=self.name, shape=dict(type="box", lower=list(lo), upper=list(hi)), material="m",
                    particles_per_cell=self.ppc, **kw)

    def setup(self, sim):
        self.n_observed = 0

    def observe(self, sim):
        self.n_observed += 1

    def errors(self, sim) -> dict:
        p = sim.particles()
        J = np.linalg.det(p["F"])
        speed = np.sqrt(np.sum(p["v"] ** 2, axis=1))
        return {"j_min": float(J.min()), "j_max": float(J.max()), "speed_over_c": float(speed.max() / self.c)}


class Impact(Scenario):
    """A block of side 0.25 a gap of 2 cells above the slip floor, moving down at mach x c."""

    name = "impact"
    boundaries = "slip"

    def bodies(self):
        d, dx = self.dim, self.dx
        lo = [0.375] * d
        hi = [0.625] * d
        axis = 1 if d > 1 else 0
        lo[axis], hi[axis] = 2 * dx, 2 * dx + 0.25
        v = [0.0] * d
        v[axis] = -self.speed
        return [self.box(lo, hi, velocity=v)]

    @property
    def end_time(self):
        return 2 * self.dx / self.speed + self.transits * 0.25 / self.c


class Compression(Scenario):
    """A block of side 0.0625 (4 cells of 64) at the centre with F = J^(1/d) I at t = 0 (free walls far away)."""

    name = "compression"

    def __init__(self, J=0.2, **kw):
        kw.setdefault("cells", 64)
        kw.setdefault("transits", 2.0)  # released from J = 0.05 it expands at ~2c: end before it reaches the walls
        super().__init__(**kw)
        if not 0 < J <= 1:
            raise ValueError(f"J must be in (0, 1], got {J}")
        self.J0 = float(J)

    def bodies(self):
        return [self.box([0.46875] * self.dim, [0.53125] * self.dim)]

    @property
    def end_time(self):
        return self.transits * 0.0625 / self.c

    def setup(self, sim):
        super().setup(sim)
        F = np.broadcast_to(np.eye(self.dim) * self.J0 ** (1.0 / self.dim), (sim.n, self.dim, self.dim)).copy()
        sim.set_particles(F=F)


class Rotation(Scenario):
    """A disk of radius 0.2 at the centre spinning with rim speed mach x c for `turns` turns (2D/3D about z)."""

    name = "rotation"

    def __init__(self, turns=0.5, **kw):
        kw.setdefault("dim", 2)
        super().__init__(**kw)
        if self.dim == 1:
            raise ValueError("rotation needs dim 2 or 3")
        self.turns, self.radius = float(turns), 0.2

    def bodies(self):
        w = self.speed / self.radius
        b = dict(name="disk", shape=dict(type="sphere", center=[0.5] * self.dim, radius=self.radius),
                 material="m", particles_per_cell=self.ppc,
                 angular_velocity=w if self.dim == 2 else [0.0, 0.0, w])
        return [b]

    @property
    def end_time(self):
        return self.turns * 2 * math.pi * self.radius / self.speed


class Thin(Scenario):
    """A plate one particle thick (thickness dx, one particle per cell) of length 0.5 with the bending
    velocity profile v_y = mach c sin(pi s), s along the plate in [0, 1]."""

    name = "thin"

    def __init__(self, **kw):
        kw.setdefault("dim", 2)
        kw["ppc"] = 1
        super().__init__(**kw)
        if self.dim == 1:
            raise ValueError("thin needs dim 2 or 3")

    def bodies(self):
        d, dx = self.dim, self.dx
        lo, hi = [0.25] * d, [0.75] * d
        lo[1], hi[1] = 0.5, 0.5 + dx
        return [self.box(lo, hi)]

    @property
    def end_time(self):
        return self.transits * 0.5 / self.c

    def setup(self, sim):
        super().setup(sim)
        X = sim.scene.x
        v = np.zeros_like(X)
        v[:, 1] = self.speed * np.sin(np.pi * (X[:, 0] - 0.25) / 0.5)
        sim.set_particles(v=v)


class Edge(Scenario):
    """A block of side 0.25 moving at mach x c toward x_max, starting 2 cells from it; runs until it
    would have travelled 4 cells further."""

    name = "edge"

    def __init__(self, boundary="free", **kw):
        super().__init__(**kw)
        if boundary not in ("free", "slip", "sticky"):
            raise ValueError(f"boundary must be free, slip or sticky, got {boundary!r}")
        self.wall = boundary

    def boundary_config(self):
        return {"default": "slip", "x_max": self.wall}

    def bodies(self):
        d, dx = self.dim, self.dx
        lo, hi = [0.375] * d, [0.625] * d
        hi[0] = 1.0 - 2 * dx
        lo[0] = hi[0] - 0.25
        v = [0.0] * d
        v[0] = self.speed
        return [self.box(lo, hi, velocity=v)]

    @property
    def end_time(self):
        return 6 * self.dx / self.speed


SCENARIOS = {"impact": Impact, "compression": Compression, "rotation": Rotation, "thin": Thin, "edge": Edge}


def make_scenario(spec: dict) -> Scenario:
    spec = dict(spec)
    kind = spec.pop("type")
    if kind not in SCENARIOS:
        raise ValueError(f"unknown stability scenario {kind!r} (known: {', '.join(SCENARIOS)})")
    return SCENARIOS[kind](**spec)


# ---------------------------------------------------------------- largest stable CFL
def is_stable(rec: dict, energy_limit: float) -> bool:
    """Stable: finished, and the mechanical energy never exceeded energy_limit x its initial value."""
    return rec.get("outcome") == "ok" and float(rec.get("energy_ratio_max", math.inf)) <= energy_limit


def cfl_case(basis: str, transfer: str, cfl: float, spec: dict, samples: int = 20, energy_limit: float = 1.1,
             extra: Optional[dict] = None) -> dict:
    """A study case (see study.py) of `spec` at one CFL number."""
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
    from .study import execute_case
    from .study import _user_paths

    trials = []

    def trial(c):
        rec = execute_case(cfl_case(basis, transfer, c, spec, energy_limit=energy_limit, extra=extra), timeout,
                           None, _user_paths())
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


def cfl_table(bases=("linear", "gimp", "quadratic", "cubic"), transfers=("pic", "flip", "apic"), spec=None,
              jobs: int = 1, **kw) -> list[dict]:
    """largest_stable_cfl for every basis x transfer (combinations in parallel with `jobs`)."""
    spec = spec or CFL_SPEC
    combos = [(b, t) for b in bases for t in transfers]
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
            r = next(r for r in rows if r["basis"] == b and r["transfer"] == t)
            cells.append("< lo" if r["cfl"] is None else f"{r['cfl']:.2f}")
        lines.append(f"| {b} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- the map picture
def case_label(row: dict, keys: list, column: str) -> str:
    """'impact E=1e+03 cfl=0.8' style label from a results.csv row: the swept keys except `column`."""
    kind = row.get("problem.type") or "impact"
    parts = []
    for k in keys:
        v = row.get(k, "")
        if v in ("", None) or k in ("problem.type", column):
            continue
        try:
            v = f"{float(v):g}"
        except ValueError:
            pass
        parts.append(f"{k.split('.')[-1]}={v}")
    return f"{kind} " + " ".join(parts)


def plot_map(results_csv, path, column: str = "solver.transfer", title: str = "stability map"):
    """One row per scenario case, one column per value of `column`: green stable, orange stopped with
    InstabilityError (cause abbreviated), red finished as garbage ("undetected"), grey error."""
    import csv

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(results_csv) as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
        names = reader.fieldnames
    keys = names[names.index("repeat") + 1: names.index("outcome")]  # the swept keys
    cols = list(dict.fromkeys(r.get(column, "") for r in rows))
    labels = list(dict.fromkeys(case_label(r, keys, column) for r in rows))
    short = {"inverted or collapsed particle (J <= 0)": "J<=0", "particle left the domain": "left domain",
             "non-finite value (NaN or infinity) in velocity or deformation": "NaN",
             "energy growth beyond the work done on the system": "energy", "fluid volume collapse": "fluid J",
             "numerical fracture (a body tore apart on the grid)": "fracture"}
    fig, ax = plt.subplots(figsize=(2.2 + 1.3 * len(cols), 0.6 + 0.24 * len(labels)), dpi=80)
    for r in rows:
        i, j = labels.index(case_label(r, keys, column)), cols.index(r.get(column, ""))
        out, cause = r["outcome"], r.get("cause", "")
        if out == "ok":
            color, text = "#4caf50", "stable"
        elif out == "unstable" and cause.startswith("undetected"):
            color, text = "#e53935", "garbage"
        elif out == "unstable":
            color, text = "#ffb74d", short.get(cause, cause[:12])
        else:
            color, text = "#9e9e9e", "error"
        ax.add_patch(plt.Rectangle((j, i), 1, 1, color=color, ec="white"))
        ax.text(j + 0.5, i + 0.5, text, ha="center", va="center", fontsize=7)
    ax.set_xlim(0, len(cols))
    ax.set_ylim(len(labels), 0)
    ax.set_xticks([j + 0.5 for j in range(len(cols))], cols, fontsize=8)
    ax.set_yticks([i + 0.5 for i in range(len(labels))], labels, fontsize=7)
    ax.xaxis.tick_top()
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m taichi_mpm.stability")
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("cfl", help="largest stable CFL number per basis and transfer")
    c.add_argument("--bases", default="linear,gimp,quadratic,cubic")
    c.add_argument("--transfers", default="pic,flip,apic")
    c.add_argument("--spec", default=json.dumps(CFL_SPEC), help="scenario spec (JSON)")
    c.add_argument("--lo", type=float, default=0.1)
    c.add_argument("--hi", type=float, default=1.5)
    c.add_argument("--tol", type=float, default=0.05)
    c.add_argument("--energy-limit", type=float, default=1.1)
    c.add_argument("--jobs", type=int, default=1)
    c.add_argument("--out", help="write the table (markdown) and trials (JSON) with this path stem")
    m = sub.add_parser("map", help="picture of a stability study's results.csv")
    m.add_argument("results_csv")
    m.add_argument("png")
    m.add_argument("--column", default="solver.transfer")
    m.add_argument("--title", default="stability map")
    args = ap.parse_args(argv)
    if args.cmd == "map":
        plot_map(args.results_csv, args.png, args.column, args.title)
        return 0
    spec = json.loads(args.spec)
    rows = cfl_table(args.bases.split(","), args.transfers.split(","), spec, jobs=args.jobs, lo=args.lo, hi=args.hi,
                     tol=args.tol, energy_limit=args.energy_limit, log=lambda m: print(m, flush=True))
    md = cfl_markdown(rows, spec)
    print(md)
    if args.out:
        Path(args.out).with_suffix(".md").write_text(md)
        Path(args.out).with_suffix(".json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
