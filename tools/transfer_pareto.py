"""The Pareto plot of error against stepping time over every basis x transfer (issue 28), from a study's
results.csv (configs/studies/pareto_2d_transfers.yaml):

    taichi-mpm study configs/studies/pareto_2d_transfers.yaml --jobs 2 --out studies/pareto_2d_transfers
    python tools/transfer_pareto.py studies/pareto_2d_transfers/results.csv docs/images/pareto_transfers.png

Colour: the transfer; marker: the basis; a thin line joins one combination's resolutions; the black steps are the
Pareto front (no other case is both faster and more accurate). Prints the front and every case as markdown.
The study's own pareto.png groups by every varied key and drops its legend past 16 groups; this one is legible
with 40 combinations.
"""
import argparse
import csv
import math
import sys


def read_points(path, metric="error_rms", time_metric="step_time"):
    """The finished cases of results.csv with a finite error: dicts basis, transfer, dx, time, error."""
    points = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            try:
                error, time = float(row[metric]), float(row[time_metric])
            except (KeyError, ValueError):
                continue
            if row.get("outcome") == "ok" and math.isfinite(error) and math.isfinite(time) and time > 0:
                points.append(dict(basis=row["solver.basis"], transfer=row["solver.transfer"],
                                   dx=float(row["domain.dx"]), time=time, error=error))
    return points


def pareto_front(points):
    """The cases no other case beats in both time and error, by increasing time."""
    front, best = [], math.inf
    for p in sorted(points, key=lambda p: (p["time"], p["error"])):
        if p["error"] < best:
            front.append(p)
            best = p["error"]
    return front


def plot(points, front, path, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    transfers = list(dict.fromkeys(p["transfer"] for p in points))
    bases = list(dict.fromkeys(p["basis"] for p in points))
    colours = {t: plt.get_cmap("tab10")(i % 10) for i, t in enumerate(transfers)}
    markers = {b: m for b, m in zip(bases, "osD^vPX*")}
    fig, ax = plt.subplots(figsize=(8.0, 5.2), dpi=90)
    for b in bases:
        for t in transfers:
            pts = sorted((p for p in points if p["basis"] == b and p["transfer"] == t), key=lambda p: p["time"])
            if pts:
                ax.plot([p["time"] for p in pts], [p["error"] for p in pts], "-", color=colours[t], lw=0.6,
                        alpha=0.5)
                ax.scatter([p["time"] for p in pts], [p["error"] for p in pts], color=colours[t],
                           marker=markers[b], s=30, alpha=0.85)
    ax.step([p["time"] for p in front], [p["error"] for p in front], where="post", color="k", lw=1.2)
    ax.scatter([p["time"] for p in front], [p["error"] for p in front], s=110, facecolors="none",
               edgecolors="k", lw=1.2)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("stepping wall time [s] (JIT excluded)")
    ax.set_ylabel("rms displacement error [m]")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    handles = [Line2D([], [], color=colours[t], marker="o", ls="", label=t) for t in transfers]
    handles += [Line2D([], [], color="0.3", marker=markers[b], ls="", label=b) for b in bases]
    handles.append(Line2D([], [], color="k", label="Pareto front"))
    ax.legend(handles=handles, fontsize=7, ncol=2, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def markdown(points, front):
    lines = ["Pareto front:", "", "| basis | transfer | dx | step time (s) | error |", "|---|---|---|---|---|"]
    lines += [f"| {p['basis']} | {p['transfer']} | {p['dx']:g} | {p['time']:.3g} | {p['error']:.3g} |" for p in front]
    lines += ["", "Every case:", "", "| basis | transfer | dx | step time (s) | error |", "|---|---|---|---|---|"]
    lines += [f"| {p['basis']} | {p['transfer']} | {p['dx']:g} | {p['time']:.3g} | {p['error']:.3g} |"
              for p in sorted(points, key=lambda p: (p["dx"], p["error"]))]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results_csv")
    ap.add_argument("png")
    ap.add_argument("--title", default="2D manufactured solution: every basis x transfer")
    args = ap.parse_args(argv)
    points = read_points(args.results_csv)
    if not points:
        print(f"{args.results_csv}: no finished case with an error value", file=sys.stderr)
        return 1
    front = pareto_front(points)
    plot(points, front, args.png, args.title)
    print(markdown(points, front))
    return 0


if __name__ == "__main__":
    sys.exit(main())
