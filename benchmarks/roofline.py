"""Roofline-style estimate: the best step time this machine allows, and how far each kernel is from it.

Ceilings measured here with Taichi kernels on all threads (f32): memory bandwidth (a streaming triad), arithmetic
throughput (independent fused multiply-add chains in registers) and scattered atomic adds (27 per particle into a
grid, the pattern of P2G). The solver's step is then timed kernel by kernel on mpm3d's scene (benchmarks/
reference.py: 3D quadratic APIC, weakly compressible fluid, sparse grid, same particles and dt), and each kernel is
compared with max(flops / peak flops, bytes / bandwidth) from the per-particle counts below.

Counts per particle-step (3D, quadratic, APIC storing B, fluid, f32; counted by hand from solver.py and
stencils.py, multiply and add counted separately, divisions and pow as one):
  P2G  flops: weights and derivatives 3 x 13, stress and affine matrix ~35, per node 59 (w 2, grad w 6, r 3,
       affine momentum 18, mass 2, momentum 7, stress . grad w 15, impulse 6) x 27            ~= 1 670
       bytes: reads x, v, F, C, vol0 (25 floats)                                                  = 100
  G2P  flops: weights 3 x 13, per node 56 (w 2, grad w 6, r 3, v 6, B 21, grad v 18) x 27, F update 54,
       det 17, fluid J 20, checks 15                                                              ~= 1 660
       bytes: reads x, F (12 floats), writes x, v, C, F (24 floats)                               = 144
The grid's own traffic (clear, P2G scatter, update, G2P gather: ~92 B per active node and step) is small here:
mpm3d's scene has ~0.2 active nodes per particle. Atomic adds are not flops: the P2G scatter's 27 x 4 atomic adds
per particle get their own ceiling.

    python benchmarks/roofline.py              # 64^3, 65 536 particles
    python benchmarks/roofline.py --tiny       # seconds, for the test suite
"""
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import taichi as ti

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, kernel_timer, mpm3d_reference, parser, positions_scene, report  # noqa: E402

COUNTS = {  # per particle-step, see the module docstring
    "p2g": dict(flops=1670, bytes=100),
    "g2p": dict(flops=1660, bytes=144),
}
ATOMICS_PER_PARTICLE = 27 * 4  # P2G: mass and three momentum components at 27 nodes


def _best(fn, repeats):
    fn()
    ti.sync()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ti.sync()
        best = min(best, time.perf_counter() - t)
    return best


def ceilings(n: int, repeats: int) -> dict:
    """Bandwidth (bytes/s), f32 flop rate (flops/s) and scattered atomic-add rate (adds/s) on all threads."""
    a, b, c = (ti.field(ti.f32, n) for _ in range(3))

    @ti.kernel
    def triad(s: ti.f32):
        for i in a:
            a[i] = b[i] + s * c[i]

    chains, iters = 128, 64  # enough independent chains to hide the FMA latency in wide vectors

    @ti.kernel
    def fma(scale: ti.f32, shift: ti.f32) -> ti.f32:  # run-time constants: nothing for the compiler to fold
        total = 0.0
        for i in range(n // 64):
            acc = ti.Vector([ti.cast(i + k, ti.f32) * 1e-9 for k in range(chains)])
            for _ in range(iters):
                acc = acc * scale + shift
            total += acc.sum()
        return total

    grid = ti.field(ti.f32, (64, 64, 64))

    @ti.kernel
    def scatter(m: ti.i32):
        for p in range(m):  # particles in sorted order, 3^3 neighbours each, like P2G on a sorted particle list
            base = ti.Vector([(p // 4096) % 60, (p // 64) % 60, p % 60])
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                for q in ti.static(range(4)):
                    grid[base + ti.Vector([i, j, k])] += 1e-3 * q

    b.fill(1.0)
    c.fill(2.0)
    t_triad = _best(lambda: triad(3.0), repeats)
    with warnings.catch_warnings():  # Taichi warns about acc.sum() unrolling 128 terms: meant
        warnings.simplefilter("ignore", SyntaxWarning)
        t_fma = _best(lambda: fma(0.999999, 1e-7), repeats)
    m = n // 8
    t_atomic = _best(lambda: scatter(m), repeats)
    return dict(bandwidth=3 * 4 * n / t_triad, flops=(n // 64) * chains * iters * 2 / t_fma,
                atomics=m * ATOMICS_PER_PARTICLE / t_atomic)


def kernel_times(sim, steps: int) -> dict:
    """Seconds per step of each solver kernel (each call synchronised: the sum exceeds the plain step a little)."""
    spent = {}
    timed = kernel_timer(spent)
    sim._k = {name: timed(name, fn) for name, fn in sim._k.items()}
    grid_clear = sim.grid.clear
    sim.grid.clear = timed("grid clear", grid_clear)
    if sim.bins is not None:   # the coloured scatter's binning (scatter.py)
        sim.bins.bin = timed("bin", sim.bins.bin)
    sim.step()
    spent.clear()
    t = time.perf_counter()
    for _ in range(steps):
        sim.step()
    ti.sync()
    total = (time.perf_counter() - t) / steps
    return {name: s / steps for name, s in spent.items()} | {"step (all)": total}


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--grid", type=int, default=64)
    a = p.parse_args(argv)
    n_grid = 16 if a.tiny else a.grid
    steps = a.steps or (2 if a.tiny else 20)
    repeats = 1 if a.tiny else a.repeats

    ti.init(arch=getattr(ti, a.arch), default_fp=ti.f32, log_level=ti.ERROR)
    ceil = ceilings(1 << (18 if a.tiny else 25), repeats)
    print(f"ceilings: bandwidth {ceil['bandwidth'] / 1e9:.1f} GB/s, f32 {ceil['flops'] / 1e9:.1f} GFLOP/s, "
          f"scattered atomic adds {ceil['atomics'] / 1e9:.2f} G/s (ridge {ceil['flops'] / ceil['bandwidth']:.1f} "
          f"flop/byte)")

    _, x, _, dt = mpm3d_reference(n_grid, a.arch)
    import taichi_mpm as tm

    cfg = block_config(3, n_grid, model="fluid", sparse=True, arch=a.arch)
    cfg["solver"].update(dt=dt)
    cfg, scene = positions_scene(cfg, x)
    sim = tm.Simulation(cfg, scene=scene)
    n = sim.n
    times = kernel_times(sim, steps)
    rows = []
    for name, t in times.items():
        row = dict(kernel=name, ms_per_step=t * 1e3, share=t / times["step (all)"], gflops=None, gb_per_s=None,
                   bound_ms=None, x_of_bound=None, limit=None)
        count = COUNTS.get(name)
        if count:
            t_flops, t_bytes = n * count["flops"] / ceil["flops"], n * count["bytes"] / ceil["bandwidth"]
            bound = max(t_flops, t_bytes)
            atomic = name == "p2g" and sim.bins is None   # coloured scatter (the CPU default): plain adds
            if atomic:  # the scatter's atomic adds are a ceiling of their own
                bound = max(bound, n * ATOMICS_PER_PARTICLE / ceil["atomics"])
            row.update(gflops=n * count["flops"] / t / 1e9, gb_per_s=n * count["bytes"] / t / 1e9,
                       bound_ms=bound * 1e3, x_of_bound=t / bound,
                       limit="atomics" if atomic and bound > max(t_flops, t_bytes) else
                       ("flops" if t_flops >= t_bytes else "bytes"))
        rows.append(row)
    best = sum(r["bound_ms"] or 0.0 for r in rows) / 1e3
    print(f"grid {n_grid}^3, {n} particles, {steps} steps, arch {a.arch}: best possible P2G + G2P "
          f"{best * 1e3:.2f} ms/step against {times['step (all)'] * 1e3:.2f} ms measured for the whole step "
          f"({times['step (all)'] / best:.1f}x)")
    report(rows, a.json)
    return dict(ceilings=ceil, rows=rows)


if __name__ == "__main__":
    main()
