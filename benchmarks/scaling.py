"""Throughput against the particle count, ours and Taichi's mpm3d on mpm3d's own scene (issue 31): for each n_grid,
benchmarks/reference.py in a fresh process (mpm3d's kernel, then ours: quadratic APIC fluid, default settings with the
stencil unrolled, as solver.unroll auto does for runs of 1e7 particle-steps or more),
rounds over the sizes repeated, medians reported; a plot of particle-steps per second and of the ratio.

    python benchmarks/scaling.py [--grids 16,32,64,128] [--rounds 3] [--steps 20] [--plot PNG] [--json RUNS]
    python benchmarks/scaling.py --load RUNS [RUNS ...] --plot PNG      # merge runs (say a 256 run) and plot
"""
import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).parent
OURS = "quadratic APIC fluid sparse unrolled"   # what unroll auto picks for a run of 1e7 particle-steps or more


def one(grid: int, steps: int) -> dict:
    """(mpm3d, ours) particle-steps per second and the particle count at one n_grid, in a fresh process."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rows.json"
        subprocess.run([sys.executable, str(HERE / "reference.py"), "--grid", str(grid), "--sparse", "true",
                        "--unroll", "true", "--models", "fluid", "--steps", str(steps), "--repeats", "1",
                        "--json", str(out)], check=True, stdout=subprocess.DEVNULL)
        rows = json.loads(out.read_text())
    ref = next(r for r in rows if r["case"].startswith("mpm3d"))
    ours = next(r for r in rows if r["case"] == OURS)
    return dict(particles=ours["particles"], mpm3d=ref["particle_steps_per_s"], ours=ours["particle_steps_per_s"])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grids", default="16,32,64,128", help="n_grid values (powers of two: mpm3d's block_dim)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--plot", help="PNG of throughput and ratio against the particle count")
    ap.add_argument("--json", help="write the runs here (n_grid -> list of runs)")
    ap.add_argument("--load", nargs="*", default=[], help="runs written by --json to merge instead of running")
    a = ap.parse_args(argv)
    runs = {}
    for path in a.load:
        for g, r in json.loads(Path(path).read_text()).items():
            runs.setdefault(int(g), []).extend(r)
    if not a.load:
        grids = [int(g) for g in a.grids.split(",")]
        runs = {g: [] for g in grids}
        for _ in range(a.rounds):
            for g in grids:
                runs[g].append(one(g, a.steps))
                print(f"n_grid {g}: {runs[g][-1]}", file=sys.stderr, flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(runs, indent=1))
    grids = sorted(runs)
    print("| n_grid | particles | mpm3d Mparticle-steps/s | ours | ratio (median of the rounds' ratios) |")
    print("| --- | --- | --- | --- | --- |")
    table = []
    for g in grids:
        r = runs[g]
        row = dict(grid=g, particles=r[0]["particles"], mpm3d=statistics.median(x["mpm3d"] for x in r),
                   ours=statistics.median(x["ours"] for x in r),
                   ratio=statistics.median(x["ours"] / x["mpm3d"] for x in r))
        table.append(row)
        print(f"| {g} | {row['particles']} | {row['mpm3d'] / 1e6:.2f} | {row['ours'] / 1e6:.2f} | {row['ratio']:.2f} |")
    if a.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, (ax, bx) = plt.subplots(2, 1, figsize=(6, 6), sharex=True, gridspec_kw=dict(height_ratios=[2, 1]))
        n = [r["particles"] for r in table]
        ax.plot(n, [r["ours"] / 1e6 for r in table], "o-", label="taichi-mpm (quadratic APIC fluid)")
        ax.plot(n, [r["mpm3d"] / 1e6 for r in table], "s-", label="Taichi's mpm3d")
        ax.set_ylabel("Mparticle-steps / s")
        ax.legend()
        bx.plot(n, [r["ratio"] for r in table], "o-k")
        bx.axhline(2.0, color="grey", ls="--", lw=0.8)
        bx.set_ylabel("ours / mpm3d")
        bx.set_xscale("log")
        bx.set_xlabel("particles (n_grid^3 / 4)")
        fig.tight_layout()
        fig.savefig(a.plot, dpi=120)


if __name__ == "__main__":
    main()
