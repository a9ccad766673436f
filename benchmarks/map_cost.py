"""The cost of a mapped grid against the box grid, on the same particles: the thick cylinder of
configs/thick_cylinder.yaml (9664 particles, quadratic or cubic, f32 or f64) stepped on its NURBS-volume grid
(domain.map: cylinder, 76 x 8 x 2 cells) and on the box grid of the same dx (the same tube of particles, no map),
each in its own process, alternating, medians of `--rounds`; ms per step over `--steps` steps after the first 5
(compile excluded).

    python benchmarks/map_cost.py [--rounds 3] [--steps 50] [--basis quadratic] [--precision f32]

The ratio, not the milliseconds, is the figure (the machine is shared): docs/performance.md, "Mapped grids".
"""
from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]


def one(grid: str, basis: str, precision: str, steps: int) -> float:
    import taichi_mpm as tm

    overrides = {"arch": "cpu", "solver.basis": basis, "precision": precision, "output.formats": []}
    cfg = tm.load_config(ROOT / "configs" / "thick_cylinder.yaml", overrides=overrides)
    if grid == "box":
        data = cfg.to_dict()
        data["domain"]["map"] = None
        cfg = tm.load_config(data)
    sim = tm.Simulation(cfg)
    for _ in range(5):
        sim.step()
    t = time.perf_counter()
    for _ in range(steps):
        sim.step()
    return (time.perf_counter() - t) / steps * 1e3


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--basis", default="quadratic")
    ap.add_argument("--precision", default="f32")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(one(a.one, a.basis, a.precision, a.steps)))
        return 0
    times = {"map": [], "box": []}
    for _ in range(a.rounds):
        for grid in times:
            out = subprocess.run([sys.executable, __file__, "--one", grid, "--basis", a.basis, "--precision",
                                  a.precision, "--steps", str(a.steps)], capture_output=True, text=True, check=True)
            times[grid].append(json.loads(out.stdout.strip().splitlines()[-1]))
    ratios = [m / b for m, b in zip(times["map"], times["box"])]
    print(f"{a.basis} {a.precision}: map ms/step {[round(t, 2) for t in times['map']]}, box "
          f"{[round(t, 2) for t in times['box']]}, map / box per round {[round(r, 2) for r in ratios]}, "
          f"median {statistics.median(ratios):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
