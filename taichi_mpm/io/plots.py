"""`taichi-mpm plot RUN_DIR`: PNG plots of a run's probe CSVs and of the energies in diagnostics.csv.

One figure per probe (one panel per quantity group: position, displacement, velocity, stress, kinetic energy,
force) in RUN_DIR/plots/probe_NAME.png, and RUN_DIR/plots/energy.png. Headless (matplotlib's Agg backend).

An empty or malformed CSV is a ValueError naming the file and the line (the CLI's exit 2), found before any plot
is drawn; plots are written to a temporary file and renamed (io.atomic_path), and a run folder with a link where
`plot` reads or writes is refused (io.refuse_links, io.FileError: exit 4).
"""
from __future__ import annotations

import re
from pathlib import Path

from . import files as io
from .probes import PROBES_DIR, read_probe

GROUPS = (("position", r"^[xyz] "), ("displacement", r"^u[xyz] "), ("velocity", r"^v[xyz] "),
          ("stress", r"^s[xyz]{2} "), ("kinetic energy", r"^kinetic "), ("force", r"^f[xyz] "))


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, png_path, root=None):
    with io.atomic_path(png_path, root=root) as tmp:
        fig.savefig(tmp, dpi=100, format="png")


def plot_probe(csv_path, png_path, data=None, root=None) -> Path:
    plt = pyplot()
    data = dict(read_probe(csv_path) if data is None else data)
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
    try:
        _save(fig, png_path, root)
    finally:
        plt.close(fig)
    return Path(png_path)


def plot_energy(csv_path, png_path, data=None, root=None) -> Path:
    plt = pyplot()
    d = io.read_diagnostics(csv_path) if data is None else data
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for c in ("kinetic", "strain", "gravity", "total"):
        if c in d:
            ax.plot(d["time"], d[c], label=c)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("energy [J] (2D: J/m)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    try:
        _save(fig, png_path, root)
    finally:
        plt.close(fig)
    return Path(png_path)


def plot_run(run_dir, probe: str | None = None, out=None) -> list[Path]:
    """Plots of the run's probes (or the one named) and, without a probe name, its energies. `out`: the file for a
    single plot (only with `probe`, or in a run with just one plot); default RUN_DIR/plots/. FileNotFoundError
    when there is nothing to plot."""
    run_dir = Path(run_dir)
    io.refuse_links(run_dir)
    every = [c for c in io.files_in(run_dir / PROBES_DIR, "*.csv", root=run_dir) if not c.is_dir()]
    csvs = every
    if probe is not None:
        csvs = [c for c in csvs if c.stem == probe]
        if not csvs:
            known = ", ".join(c.stem for c in every) or "none"
            raise FileNotFoundError(f"no probe '{probe}' in {run_dir} (probes: {known})")
    jobs = [(plot_probe, c, f"probe_{c.stem}.png", read_probe) for c in csvs]
    diag = run_dir / io.DIAGNOSTICS_NAME
    if probe is None and diag.is_file():
        jobs.append((plot_energy, diag, "energy.png", io.read_diagnostics))
    if not jobs:
        raise FileNotFoundError(f"nothing to plot in {run_dir}: no {PROBES_DIR}/*.csv and no {io.DIAGNOSTICS_NAME}")
    if out is not None and len(jobs) > 1:
        raise ValueError(f"--out names one file, but there are {len(jobs)} plots: add --probe NAME")
    data = [read(src) for _, src, _, read in jobs]   # every file checked before any plot is drawn
    for (_, src, _, _), d in zip(jobs, data):
        if not any(len(v) for v in d.values()):
            raise ValueError(f"{src} holds no rows (only its header): nothing to plot")
    if out is not None:
        return [jobs[0][0](jobs[0][1], Path(out), data[0])]
    plots = io.ensure_folder(run_dir / "plots", root=run_dir)
    return [fn(src, plots / name, d, root=run_dir) for (fn, src, name, _), d in zip(jobs, data)]
