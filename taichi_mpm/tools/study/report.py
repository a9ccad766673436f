"""A study's reports, rebuilt from its case records: results.csv, the Pareto front of error against time, the
convergence rates and their plots, summary.md; and the one-line progress of each finished case."""
import csv
import json
import math
import sys
from pathlib import Path

from .. import observe as obs
from .folder import finished_records
from .spec import Study


OUTCOMES = ("ok", "unstable", "error")


RECORD_COLUMNS = ["outcome", "cause", "wall_time", "setup_time", "compile_time", "step_time", "time_spread",
                  "timing_runs", "steps", "particles", "particle_steps_per_s", "peak_memory_mb", "sim_time",
                  "energy_ratio_max", "energy_ratio_end", "message"]


def print_progress(i: int, n: int, case: dict, rec: dict):
    """One line per finished case on stderr: case i/N, its parameters, outcome (and cause) and wall time."""
    params = ", ".join(f"{k}={_short(v)}" for k, v in case["params"].items())
    status = rec.get("outcome", "?") + (f" ({rec['cause']})" if rec.get("cause") else "")
    wall = rec.get("wall_time")
    took = f" {float(wall):.1f} s" if _finite(wall) else ""
    rep = f" repeat {case['repeat']}" if case.get("repeat") else ""
    print(f"case {i}/{n} [{params}]{rep}: {status}{took}", file=sys.stderr, flush=True)


def collect(st: Study, out: Path) -> list[dict]:
    """The records of this study's cases, in case order."""
    done = finished_records(out / "cases")
    return [done[c["digest"]] for c in st.expand() if c["digest"] in done]


def write_reports(st: Study, out: Path) -> list[dict]:
    """results.csv, pareto.png, convergence.png and summary.md from the case records."""
    import matplotlib
    matplotlib.use("Agg")
    records = collect(st, out)
    varied = st.varied
    reference = None
    if st.observe is not None:   # the reference (a number, or from the finished cases) and each case's error
        if st.observe["kind"] != "metric":
            reference = obs.reference_value(records, st.reference, st.convergence_key, varied)
        obs.observed_errors(records, reference[0] if reference else math.nan, st.observe)
    error_cols = sorted({k for r in records for k in r if k.startswith("error_") and k not in varied})
    extra = sorted({k for r in records for k in r} - set(varied) - set(error_cols) - set(RECORD_COLUMNS)
                   - {"case", "repeat", "digest", "traceback", "fail_step", "fail_time"})
    columns = ["case", "repeat", *varied, *RECORD_COLUMNS[:2], *error_cols, *RECORD_COLUMNS[2:], "fail_step",
               "fail_time", *extra]
    with open(out / "results.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, columns, extrasaction="ignore")
        w.writeheader()
        for r in records:
            w.writerow({k: _cell(r.get(k, "")) for k in columns})
    for r in records:   # |1 - E(end)/E(0)| of every finished case: the metric of studies without an exact solution
        if r.get("outcome") == "ok" and _finite(r.get("energy_ratio_end")):
            r["energy_drift"] = abs(float(r["energy_ratio_end"]) - 1.0)
    # the study's metric (checked against the known ones when it was loaded), else error_rms, another error
    # column, or the energy drift
    metric = st.metric or ("error_rms" if "error_rms" in error_cols else
                           error_cols[0] if error_cols else "energy_drift")
    points = _aggregate(records, varied, metric, st.time_metric)
    group_keys = [k for k in varied if k != st.convergence_key]
    front = pareto_front(points)
    fits = convergence_rates(points, group_keys, st.convergence_key)
    plot_pareto(points, front, group_keys, metric, st.time_metric, out / "pareto.png", st.name)
    plot_convergence(points, fits, group_keys, st.convergence_key, metric, out / "convergence.png", st.name)
    (out / "summary.md").write_text(summary_markdown(st, records, varied, metric, front, fits, reference))
    return records


def _cell(v):
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    if isinstance(v, float):
        return f"{v:.6g}"
    return v


def _finite(v) -> bool:
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def _aggregate(records, varied, metric, time_metric) -> list[dict]:
    """One point per parameter set (repeats merged: median time, mean error) from the ok cases."""
    groups: dict[str, list] = {}
    for r in records:
        if r.get("outcome") != "ok" or not _finite(r.get(metric)) or not _finite(r.get(time_metric)):
            continue
        key = json.dumps({k: r.get(k) for k in varied}, sort_keys=True, default=str)
        groups.setdefault(key, []).append(r)
    points = []
    for key, rs in groups.items():
        times = sorted(float(r[time_metric]) for r in rs)
        points.append(dict(params=json.loads(key), error=sum(float(r[metric]) for r in rs) / len(rs),
                           time=times[len(times) // 2], n=len(rs)))
    return points


def pareto_front(points: list[dict]) -> list[dict]:
    """Points no other point beats in both time and error, sorted by time."""
    front, best = [], math.inf
    for p in sorted(points, key=lambda p: (p["time"], p["error"])):
        if p["error"] < best:
            front.append(p)
            best = p["error"]
    return front


def convergence_rates(points, group_keys, conv_key) -> dict:
    """Least-squares slope of log(error) against log(conv_key) per group (needs two or more values)."""
    fits = {}
    for label, pts in _groups(points, group_keys).items():
        pts = [p for p in pts if _finite(p["params"].get(conv_key)) and p["error"] > 0]
        hs = sorted({float(p["params"][conv_key]) for p in pts})
        if len(hs) < 2:
            continue
        xs = [math.log(float(p["params"][conv_key])) for p in pts]
        ys = [math.log(p["error"]) for p in pts]
        mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
        sxx = sum((x - mx) ** 2 for x in xs)
        slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx
        fits[label] = dict(rate=slope, intercept=my - slope * mx,
                           points=sorted(pts, key=lambda p: -float(p["params"][conv_key])))
    return fits


def _label(params, group_keys) -> str:
    return "/".join(_short(params.get(k)) for k in group_keys) or "all"


def _short(v) -> str:
    return json.dumps(v) if isinstance(v, (list, dict)) else f"{v:g}" if isinstance(v, float) else str(v)


def _groups(points, group_keys) -> dict:
    out: dict[str, list] = {}
    for p in points:
        out.setdefault(_label(p["params"], group_keys), []).append(p)
    return out


def _plain_log_ticks(ax):
    """Log axes labelled at 1, 2 and 5 times the powers of ten (over three decades: at the powers) in plain numbers
    (matplotlib labels the minor ticks of an axis spanning a decade or two in scientific notation, and the labels
    run into each other)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter
    for axis, scale, (lo, hi) in ((ax.xaxis, ax.get_xscale(), ax.get_xlim()),
                                  (ax.yaxis, ax.get_yscale(), ax.get_ylim())):
        if scale == "log":
            wide = hi > 1e3 * lo    # beyond three decades the powers of ten alone
            axis.set_major_locator(LogLocator(base=10, subs=(1.0,) if wide else (1.0, 2.0, 5.0)))
            axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            axis.set_minor_formatter(NullFormatter())


def plot_pareto(points, front, group_keys, metric, time_metric, path, title):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=90)
    for label, pts in sorted(_groups(points, group_keys).items()):
        ax.scatter([p["time"] for p in pts], [p["error"] for p in pts], label=label, s=28, alpha=0.8)
    if front:
        ax.step([p["time"] for p in front], [p["error"] for p in front], where="post", color="k", lw=1.2,
                label="Pareto front")
        ax.scatter([p["time"] for p in front], [p["error"] for p in front], s=90, facecolors="none",
                   edgecolors="k", lw=1.2)
    if not points:
        ax.text(0.5, 0.5, "no finished case with an error value", ha="center", transform=ax.transAxes)
    else:
        if all(p["time"] > 0 for p in points):
            ax.set_xscale("log")
        if all(p["error"] > 0 for p in points):
            ax.set_yscale("log")
        _plain_log_ticks(ax)
    xlabel = {"step_time": "stepping wall time [s] (JIT excluded)", "wall_time": "wall time [s]",
              "compile_time": "first step (JIT) time [s]"}[time_metric]
    ax.set_xlabel(xlabel)
    ax.set_ylabel(metric)
    ax.set_title(f"{title}: error vs time")
    ax.grid(True, which="both", alpha=0.3)
    if points and len(_groups(points, group_keys)) <= 16:
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_convergence(points, fits, group_keys, conv_key, metric, path, title):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=90)
    for label, pts in sorted(_groups(points, group_keys).items()):
        pts = [p for p in pts if _finite(p["params"].get(conv_key))]
        if not pts:
            continue
        pts.sort(key=lambda p: float(p["params"][conv_key]))
        hs = [float(p["params"][conv_key]) for p in pts]
        fit = fits.get(label)
        name = f"{label}: slope {fit['rate']:.2f}" if fit else label
        line, = ax.plot(hs, [p["error"] for p in pts], "o", label=name)
        if fit:
            ax.plot(hs, [math.exp(fit["intercept"]) * h ** fit["rate"] for h in hs], "-", color=line.get_color(), lw=1)
    if any(_finite(p["params"].get(conv_key)) for p in points):
        ax.set_xscale("log")
        if all(p["error"] > 0 for p in points):
            ax.set_yscale("log")
        _plain_log_ticks(ax)
        if len(fits) <= 16:
            ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, f"{conv_key} is not varied in this study", ha="center", transform=ax.transAxes)
    ax.set_xlabel(conv_key)
    ax.set_ylabel(metric)
    ax.set_title(f"{title}: convergence")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def summary_markdown(st, records, varied, metric, front, fits, reference=None) -> str:
    counts = {o: sum(r.get("outcome") == o for r in records) for o in OUTCOMES}
    lines = [f"# Study `{st.name}`", "",
             f"{len(records)} cases: " + ", ".join(f"{n} {o}" for o, n in counts.items()) + ".",
             f"Error metric `{metric}`; time metric `{st.time_metric}` "
             f"(median of up to {st.timing['runs']} timing reruns "
             f"per case, until their spread is at most {st.timing['spread']:g}: column time_spread)."]
    if st.observe is not None:
        lines.append(f"Quantity `{st.observe['text']}`; " + (
            "an error against the exact solution." if reference is None else
            f"reference {reference[0]:.6g} ({reference[1]}); `error_observed` = |observed - reference| / |reference|."))
    lines += ["", "## Cases", ""]
    cols = [*varied, "outcome", *(["observed"] if st.observe is not None else []), metric, "wall_time",
            "compile_time", "step_time", "time_spread", "steps", "particle_steps_per_s", "peak_memory_mb", "cause"]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "---|" * len(cols))
    for r in records:
        lines.append("| " + " | ".join(_md(r.get(c, "")) for c in cols) + " |")
    if fits:
        ck = st.convergence_key
        hs = sorted({float(p["params"][ck]) for fit in fits.values() for p in fit["points"]}, reverse=True)
        lines += ["", f"## Convergence (slope of log {metric} against log {ck})", "",
                  "| group | rate | " + " | ".join(f"{ck}={h:g}" for h in hs) + " |", "|---|---|" + "---|" * len(hs)]
        for label, fit in fits.items():
            err = {float(p["params"][ck]): p["error"] for p in fit["points"]}
            cells = " | ".join(f"{err[h]:.3g}" if h in err else "-" for h in hs)
            lines.append(f"| {label} | {fit['rate']:.2f} | {cells} |")
    if front:
        lines += ["", "## Pareto front (fastest first)", "",
                  "| " + " | ".join(varied) + f" | {st.time_metric} | {metric} |",
                  "|" + "---|" * (len(varied) + 2)]
        for p in front:
            cells = " | ".join(_md(p["params"].get(k)) for k in varied)
            lines.append(f"| {cells} | {p['time']:.3g} | {p['error']:.3g} |")
    return "\n".join(lines) + "\n"


def _md(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v).replace("|", "/").replace("\n", " ")[:120]
