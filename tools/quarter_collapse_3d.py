"""The 3D column collapse of configs/granular_collapse_3d.yaml (Lube et al. 2004; a = 1 as there, or another
aspect ratio) on a quarter of the cylinder: the planes x = 0 and z = 0 through its axis are slip walls (the
symmetry planes of the heap), so a grid four times finer per cell count costs a quarter of the full cylinder's
particles. The body is a mesh of the quarter cylinder written into the output folder; the material mu(I) with the
2D columns' parameters (E 0.3 MPa).

    python tools/quarter_collapse_3d.py CELLS_PER_R0 [--aspect A] [--out DIR] [--set KEY=VALUE]   # e.g. 12, 18, 24

Prints the run-out (R_inf - R0) / R0 (the 99.5th percentile of the distance from the axis) against Lube et al.'s
1.24 a (a < 1.7) or 1.6 a^(1/2) (a > 1.7; the two meet at a = 1.7), the height at the axis and the fastest
particle's speed at the end (the heap must be at rest). A column of height a R0 runs for 0.6 s sqrt(a) (free fall
and spreading scale with sqrt(H / g)) in a box that leaves twice the expected run-out. docs/materials.md has the
figures (R0/12 reproduces the full cylinder's).
"""
import argparse
import sys
import time
from pathlib import Path

import meshio
import numpy as np

import taichi_mpm as tm
from taichi_mpm.config import parse_overrides

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "demos"))
from granular_collapse_3d import lube_2004  # noqa: E402 (the full cylinder's demo holds Lube et al. 2004's fits)

R0 = 0.06
MU_I = {"model": "mu_i", "E": 3.0e5, "nu": 0.3, "density": 1500, "mu_s": 0.577, "mu_2": 0.84,
        "grain_diameter": 0.001, "max_pressure": 2000}


def quarter_cylinder(path: Path, H: float, segments: int = 256):
    """A closed triangulated quarter cylinder (axis y, from the origin, radius R0, height H)."""
    th = np.linspace(0, np.pi / 2, segments + 1)
    ring = [(R0 * np.cos(t), 0.0, R0 * np.sin(t)) for t in th]
    pts = [(0.0, 0.0, 0.0), (0.0, H, 0.0)] + ring + [(x, H, z) for x, _, z in ring]
    b, t = 2, 3 + segments   # first bottom and top arc points
    tri = []
    for k in range(segments):
        tri += [(0, b + k + 1, b + k), (1, t + k, t + k + 1), (b + k, b + k + 1, t + k + 1), (b + k, t + k + 1, t + k)]
    tri += [(0, b, t), (0, t, 1), (0, 1, t + segments), (0, t + segments, b + segments)]
    meshio.write(path, meshio.Mesh(np.array(pts), [("triangle", np.array(tri))]))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cells", type=int, help="cells per radius R0")
    ap.add_argument("--aspect", type=float, default=1.0, help="aspect ratio a = H / R0 of the column")
    ap.add_argument("--out", type=Path, default=Path("runs/quarter_collapse_3d"))
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="config overrides after the tool's own, e.g. materials.sand={model: mohr_coulomb, ...}")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    mesh = a.out / "quarter_cylinder.stl"
    H, expected = a.aspect * R0, lube_2004(a.aspect)
    quarter_cylinder(mesh, H)
    dx = R0 / a.cells
    # a = 1: the full run's box (0.17 and 0.08 m), in cells; taller columns: twice the expected run-out
    extents = (0.17, 0.08) if a.aspect <= 1 else (R0 * (1 + 2 * expected), H + 0.02)
    side, top = (float(dx * np.ceil(extent / dx - 1e-9)) for extent in extents)
    cfg = tm.load_config(ROOT / "configs" / "granular_collapse_3d.yaml", overrides={
        "arch": "cpu", "output.formats": [], "domain.lower": [0.0, 0.0, 0.0], "domain.upper": [side, top, side],
        "domain.dx": dx, "bodies.0.shape": {"type": "mesh", "file": str(mesh.resolve())},
        "materials.sand": MU_I, "solver.end_time": 0.6 * float(np.sqrt(max(a.aspect, 1.0))),
        **parse_overrides(a.overrides)})
    t0 = time.time()
    sim = tm.Simulation(cfg)
    sim.advance_to(cfg.solver.end_time)
    state = sim.particles()
    x = state["x"]
    r = np.hypot(x[:, 0], x[:, 2])
    runout = (np.percentile(r, 99.5) - R0) / R0
    height = np.percentile(x[r < 0.5 * R0, 1], 99.5) / R0
    speed = float(np.linalg.norm(state["v"], axis=1).max())
    print(f"a = {a.aspect:g}, R0/{a.cells}: {sim.n} particles, {sim.n_steps} steps, {time.time() - t0:.0f} s: run-out "
          f"{runout:.3f} (Lube et al. 2004: {expected:.3f}, {runout / expected - 1:+.1%}), height {height:.3f} R0, "
          f"fastest particle {speed:.2g} m/s at t = {sim.time:.2f} s")
    return dict(runout=float(runout), expected=float(expected), height=float(height), speed=speed, particles=sim.n)


if __name__ == "__main__":
    main()
