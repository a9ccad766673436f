"""Multi-core scaling on the CPU backend: the same 3D scene with 1, 2, 4, ... threads, each in its own process.

Taichi reads `cpu_max_num_threads` from the environment (TI_CPU_MAX_NUM_THREADS), so each thread count gets a fresh
process and nothing else changes. Reports particle-steps/s and the speed-up over one thread; the efficiency column
(speed-up / threads) shows where scaling stops (memory bandwidth, atomics in P2G, serial kernel launches).

    python benchmarks/threads.py                    # 3D quadratic APIC elastic, 64^3 grid, 1..all cores
    python benchmarks/threads.py --threads 1 2 --grid 32
"""
import json
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, parser, report, time_steps  # noqa: E402


def one(grid, steps, repeats):
    import taichi_mpm as tm

    sim = tm.Simulation(block_config(3, grid, body=(0.1, 0.7)))
    sim.step()
    t = time_steps(sim.step, steps, repeats)
    return dict(particles=sim.n, ms_per_step=t * 1e3, particle_steps_per_s=sim.n / t)


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--grid", type=int, default=64)
    p.add_argument("--threads", type=int, nargs="+", default=None, help="default: 1, 2, 4, ... up to the core count")
    p.add_argument("--worker", action="store_true", help="internal")
    a = p.parse_args(argv)
    grid = 16 if a.tiny else a.grid
    steps = a.steps or (2 if a.tiny else 20)
    repeats = 1 if a.tiny else a.repeats
    if a.worker:
        print("RESULT " + json.dumps(one(grid, steps, repeats)))
        return None
    cores = os.cpu_count() or 1
    counts = a.threads or sorted({1, *[2**k for k in range(1, 8) if 2**k <= cores], cores})
    rows = []
    for k in counts:
        env = dict(os.environ, TI_CPU_MAX_NUM_THREADS=str(k))
        cmd = [sys.executable, __file__, "--worker", "--grid", str(grid), "--steps", str(steps),
               "--repeats", str(repeats)]
        out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
        r = json.loads(next(line for line in out.stdout.splitlines() if line.startswith("RESULT "))[7:])
        rows.append(dict(threads=k, **r))
    for r in rows:
        r["speedup"] = r["particle_steps_per_s"] / rows[0]["particle_steps_per_s"]
        r["efficiency"] = r["speedup"] * rows[0]["threads"] / r["threads"]
    print(f"grid {grid}^3, {steps} steps x {repeats} repeats (median), {cores} cores on this machine")
    report(rows, a.json)
    return rows


if __name__ == "__main__":
    main()
