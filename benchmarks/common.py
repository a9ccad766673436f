"""Shared helpers for the benchmark scripts (not tests): timing, memory, the reference mpm3d kernel."""
import argparse
import json
import re
import resource
import statistics
import time
from pathlib import Path

import numpy as np
import taichi as ti


def parser(description):
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--tiny", action="store_true", help="a seconds-long configuration (used by the test suite)")
    p.add_argument("--repeats", type=int, default=3, help="timed repetitions; the median is reported")
    p.add_argument("--steps", type=int, default=None, help="steps per timed repetition")
    p.add_argument("--arch", default="cpu")
    p.add_argument("--json", type=Path, default=None, help="also write the results as JSON here")
    return p


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def time_steps(step, steps: int, repeats: int, sync=ti.sync, cpu: bool = False):
    """Median seconds per step over `repeats` runs of `steps` steps (after one warm-up step).

    With cpu=True, also the median process CPU time per step (all threads): on a shared machine it moves far less
    than wall time, so ratios of CPU times are the steadier comparison."""
    step()
    sync()
    wall, proc = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        for _ in range(steps):
            step()
        sync()
        wall.append((time.perf_counter() - t) / steps)
        proc.append((time.process_time() - c) / steps)
    return (statistics.median(wall), statistics.median(proc)) if cpu else statistics.median(wall)


def kernel_timer(spent: dict, clock=time.perf_counter):
    """timed(name, fn): fn wrapped to add its duration, between two ti.sync(), to spent[name] (per-kernel times);
    it returns what fn returns."""
    def timed(name, fn):
        def call(*args, **kwargs):
            ti.sync()
            t = clock()
            out = fn(*args, **kwargs)
            ti.sync()
            spent[name] = spent.get(name, 0.0) + clock() - t
            return out
        return call
    return timed


def report(rows: list[dict], path: Path | None):
    if not rows:
        return
    keys = list(rows[0])
    widths = [max(len(k), *(len(_fmt(r.get(k))) for r in rows)) for k in keys]
    print("  ".join(k.ljust(w) for k, w in zip(keys, widths)))
    for r in rows:
        print("  ".join(_fmt(r.get(k)).ljust(w) for k, w in zip(keys, widths)))
    if path:
        path.write_text(json.dumps(rows, indent=1))


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def mpm3d_reference(n_grid: int, arch):
    """Taichi's own examples/simulation/mpm3d.py, run headless with n_grid cells per axis.

    The example's source is read from the installed taichi package and only its size line and ti.init call are
    changed; nothing of its kernel is. Returns (substep, particle positions, n_particles, dt)."""
    src_path = Path(ti.__file__).parent / "examples" / "simulation" / "mpm3d.py"
    src = src_path.read_text()
    dt = {32: 4e-4, 64: 2e-4, 128: 8e-5}.get(n_grid, 2e-4 * 64 / n_grid)
    src, n = re.subn(r"^dim, n_grid, steps, dt = .*$", f"dim, n_grid, steps, dt = 3, {n_grid}, 25, {dt}", src,
                     flags=re.M)
    assert n == 1, "mpm3d.py changed: size line not found"
    src = src.replace("ti.init(arch=ti.gpu)", f"ti.init(arch=ti.{arch}, random_seed=0)")
    ns = {"__name__": "mpm3d_reference"}
    exec(compile(src, str(src_path), "exec"), ns)
    ns["init"]()
    return ns["substep"], ns["F_x"].to_numpy(), ns["n_particles"], dt


def block_config(dim, n_grid, *, basis="quadratic", transfer="apic", model="fixed_corotated", precision="f32",
                 sparse=True, arch="cpu", extent=1.0, body=(0.15, 0.55), ppc=2, E=400.0):
    """A falling elastic (or fluid) block in a box, the benchmark scene."""
    mat = {"model": model, "density": 1.0}
    mat.update({"K": E} if model == "fluid" else {"E": E, "nu": 0.2})
    lo, hi = body
    return {
        "name": "bench", "dim": dim, "precision": precision, "arch": arch,
        "domain": {"lower": [0.0] * dim, "upper": [extent] * dim, "dx": extent / n_grid, "sparse": sparse},
        "solver": {"basis": basis, "transfer": transfer, "end_time": 1.0, "dt": 1e-4,
                   "gravity": [0.0, -9.8] + [0.0] * (dim - 2) if dim > 1 else [-9.8]},
        "materials": {"m": mat},
        "bodies": [{"shape": {"type": "box", "lower": [lo] * dim, "upper": [hi] * dim}, "material": "m",
                    "particles_per_cell": ppc}],
    }


def positions_scene(cfg, x: np.ndarray):
    """A Scene with the given particle positions (one body, one material), e.g. the reference kernel's."""
    from taichi_mpm.config import load_config
    from taichi_mpm.scene import Scene

    c = load_config(cfg)
    n, d = x.shape
    dx = c.domain.dx
    vol = np.full(n, (0.5 * dx) ** d)  # mpm3d's p_vol
    rho = next(iter(c.materials.values())).density
    z = np.zeros(n)
    return c, Scene(x=x.astype(np.float64), v=np.zeros((n, d)), volume=vol, mass=vol * rho,
                    body=z.astype(np.int32), material=z.astype(np.int32), damage=z, interface=z.astype(np.int32),
                    spacing=np.full(n, 0.5 * dx), materials=[next(iter(c.materials))])


def te_scene_config(res: int, arch: str = "cpu"):
    """taichi_elements' benchmark scene: an elastic (fixed-corotated) cube 0.4^3 falling in a unit box, res^3 cells,
    8 particles per cell, E = 1e6, nu = 0.2, rho = 1000, dt = 2e-2 dx (taichi_elements' default_dt), f32."""
    dx = 1.0 / res
    return {"name": "te_scene", "dim": 3, "precision": "f32", "arch": arch,
            "domain": {"lower": [0.0] * 3, "upper": [1.0] * 3, "dx": dx, "sparse": True},
            "solver": {"basis": "quadratic", "transfer": "apic", "dt": 2e-2 * dx, "end_time": 10.0,
                       "gravity": [0.0, -9.8, 0.0]},
            "materials": {"e": {"model": "fixed_corotated", "E": 1e6, "nu": 0.2, "density": 1000.0}},
            "bodies": [{"name": "cube", "shape": {"type": "box", "lower": [0.3] * 3, "upper": [0.7] * 3},
                        "material": "e", "particles_per_cell": 2}]}
