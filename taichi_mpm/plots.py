"""`taichi-mpm plot RUN_DIR`: PNG plots of a run's probe CSVs and of the energies in diagnostics.csv.

One figure per probe (one panel per quantity group: position, displacement, velocity, stress, kinetic energy,
force) in RUN_DIR/plots/probe_NAME.png, and RUN_DIR/plots/energy.png. Headless (matplotlib's Agg backend).
"""
from __future__ import annotations

import re
from pathlib import Path

from . import io
from .probes import PROBES_DIR, read_probe

GROUPS = (("position", r"^[xyz] "), ("displacement", r"^u[xyz] "), ("velocity", r"^v[xyz] "),
          ("stress", r"^s[xyz]{2} "), ("kinetic energy", r"^kinetic "), ("force", r"^f[xyz] "))


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_probe(csv_path, png_path) -> Path:
    plt = pyplot()
    data = read_probe(csv_path)
    t = data.pop("time [s]")
    data.pop("step", None)
    groups = [(title, [c for c in data if re.match(pat, c)]) for title, pat in GROUPS]
    groups = [(title, cols) for title, cols in groups if cols]
    fig, axes = plt.subplots(len(groups), 1, figsize=(7, 2.4 * len(groups)), sharex=True, squeeze=False)
    for ax, (title, cols) in zip(axes[:, 0], groups):
        for c in cols:
            ax.plot(t, data[c], label=c)
        ax.set_ylabel(title)
        ax.legend(fontsize="small", loc="best")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"probe {Path(csv_path).stem}")
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return Path(png_path)


def plot_energy(csv_path, png_path) -> Path:
    plt = pyplot()
    d = io.read_diagnostics(csv_path)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for c in ("kinetic", "strain", "gravity", "total"):
        if c in d:
            ax.plot(d["time"], d[c], label=c)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("energy [J] (2D: J/m)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return Path(png_path)


def plot_run(run_dir, probe: str | None = None, out=None) -> list[Path]:
    """Plots of the run's probes (or the one named) and, without a probe name, its energies. `out`: the file for a
    single plot (only with `probe`, or in a run with just one plot); default RUN_DIR/plots/. FileNotFoundError
    when there is nothing to plot."""
    run_dir = Path(run_dir)
    csvs = sorted((run_dir / PROBES_DIR).glob("*.csv"))
    if probe is not None:
        csvs = [c for c in csvs if c.stem == probe]
        if not csvs:
            known = ", ".join(c.stem for c in sorted((run_dir / PROBES_DIR).glob("*.csv"))) or "none"
            raise FileNotFoundError(f"no probe '{probe}' in {run_dir} (probes: {known})")
    jobs = [(plot_probe, c, f"probe_{c.stem}.png") for c in csvs]
    diag = run_dir / io.DIAGNOSTICS_NAME
    if probe is None and diag.is_file():
        jobs.append((plot_energy, diag, "energy.png"))
    if not jobs:
        raise FileNotFoundError(f"nothing to plot in {run_dir}: no {PROBES_DIR}/*.csv and no {io.DIAGNOSTICS_NAME}")
    if out is not None and len(jobs) > 1:
        raise ValueError(f"--out names one file, but there are {len(jobs)} plots: add --probe NAME")
    plots = run_dir / "plots"
    if out is None:
        plots.mkdir(exist_ok=True)
    return [fn(src, Path(out) if out is not None else plots / name) for fn, src, name in jobs]
