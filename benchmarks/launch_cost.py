"""Fixed costs of a step on the CPU: kernel launches and the thread pool, ours against Taichi's mpm3d (issue 31).

Part 1, launches alone (one process): microseconds per launch of an empty kernel, of a kernel whose one top-level
loop has one iteration (Taichi runs a top-level loop as a parallel task, waking the thread pool), of the same loop
serialised (`ti.loop_config(serialize=True)`: a serial task on the calling thread), of a parallel loop over
8 192 items, and of two such loops in one kernel against two launches of it. Part 2, one step (each case in a fresh
process with Taichi's kernel profiler): Python launches and offloaded tasks per step, the sum of each task's minimum
time and of its mean, and wall time per step, for mpm3d's substep and ours (quadratic APIC fluid, the scaling
benchmark's case) on mpm3d's particles at --grid.

    python benchmarks/launch_cost.py [--grid 32] [--steps 200]

The sum of minima is what the kernels cost when nothing disturbs them; mean minus minimum is what this machine's
other work and the pool's wake-ups add; wall minus mean is the Python side (docs/performance.md, "Fixed costs of a
step").
"""
import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).parent


def launches_alone(repeats=5, calls=2000):
    import taichi as ti
    ti.init(arch=ti.cpu, log_level=ti.ERROR)
    a = ti.field(ti.i32, shape=8192)

    @ti.kernel
    def empty():
        pass

    @ti.kernel
    def one_iteration():
        for _ in range(1):
            a[0] = 0

    @ti.kernel
    def one_iteration_serial():
        ti.loop_config(serialize=True)
        for _ in range(1):
            a[0] = 0

    @ti.kernel
    def parallel_8192():
        for i in a:
            a[i] += 1

    @ti.kernel
    def two_loops():
        for i in a:
            a[i] += 1
        for i in a:
            a[i] -= 1

    def two_kernels():
        parallel_8192()
        parallel_8192()

    out = {}
    for name, k in (("empty kernel", empty), ("one-iteration loop (parallel task)", one_iteration),
                    ("one-iteration loop, serialised", one_iteration_serial),
                    ("parallel loop, 8 192 items", parallel_8192),
                    ("two such loops in one kernel", two_loops), ("two such kernels", two_kernels)):
        k()
        times = []
        for _ in range(repeats):
            ti.sync()
            t0 = time.perf_counter()
            for _ in range(calls):
                k()
            ti.sync()
            times.append((time.perf_counter() - t0) / calls * 1e6)
        out[name] = statistics.median(times)
    return out


def one_step(which: str, grid: int, steps: int) -> dict:
    """Run in a child process: launches and tasks per step, sums of task minima and means, wall ms per step."""
    sys.path.insert(0, str(HERE))
    import taichi as ti
    from taichi.lang import kernel_impl
    from common import block_config, mpm3d_reference, positions_scene

    substep, x, n, dt = mpm3d_reference(grid, "cpu")
    if which == "ours":
        import taichi_mpm as tm
        cfg = block_config(3, grid, model="fluid", sparse=True, arch="cpu")
        cfg["solver"].update(dt=dt, unroll=True)
        cfg, scene = positions_scene(cfg, x)
        sim = tm.Simulation(cfg, scene=scene)
        step = sim.step
    else:
        step = substep
    for _ in range(20):
        step()
    launches = [0]
    original = kernel_impl.Kernel.launch_kernel

    def counted(self, *args, **kwargs):
        launches[0] += 1
        return original(self, *args, **kwargs)

    kernel_impl.Kernel.launch_kernel = counted
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    ti.sync()
    wall = (time.perf_counter() - t0) / steps * 1e3
    kernel_impl.Kernel.launch_kernel = original
    import contextlib
    import io
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        ti.profiler.print_kernel_profiler_info("count")
    rows = re.findall(r"\[\s*[\d.]+%\s+[\d.]+ s\s+(\d+)x \|\s+([\d.]+)\s+([\d.]+)\s+[\d.]+ ms\] (\S+)", text.getvalue())
    tasks = sum(int(c) for c, *_ in rows) / steps
    parallel = sum(int(c) for c, _, _, name in rows if "serial" not in name) / steps
    min_ms = sum(int(c) * float(lo) for c, lo, _, _ in rows) / steps
    mean_ms = sum(int(c) * float(avg) for c, _, avg, _ in rows) / steps
    return dict(case=which, particles=int(n), launches=launches[0] / steps, tasks=tasks, parallel_tasks=parallel,
                kernel_min_ms=min_ms, kernel_mean_ms=mean_ms, wall_ms=wall)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--grid", type=int, default=32)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--child", choices=["ours", "mpm3d"], help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.child:
        print(json.dumps(one_step(a.child, a.grid, a.steps)))
        return
    for name, us in launches_alone().items():
        print(f"{name:40s} {us:8.1f} us a launch")
    env = dict(os.environ, TI_KERNEL_PROFILER="1")
    print(f"\none step at n_grid {a.grid}, {a.steps} steps (kernel profiler on)")
    print(f"{'case':6s} {'particles':>9s} {'launches':>9s} {'tasks':>6s} {'parallel':>8s} {'sum of minima ms':>17s} "
          f"{'sum of means ms':>16s} {'wall ms':>8s}")
    for which in ("mpm3d", "ours"):
        out = subprocess.run([sys.executable, __file__, "--child", which, "--grid", str(a.grid), "--steps",
                              str(a.steps)], env=env, capture_output=True, text=True, check=True).stdout
        r = json.loads(out.strip().splitlines()[-1])
        print(f"{r['case']:6s} {r['particles']:9d} {r['launches']:9.1f} {r['tasks']:6.1f} {r['parallel_tasks']:8.1f} "
              f"{r['kernel_min_ms']:17.2f} {r['kernel_mean_ms']:16.2f} {r['wall_ms']:8.2f}")


if __name__ == "__main__":
    main()
