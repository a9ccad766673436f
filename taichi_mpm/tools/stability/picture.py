"""The stability map: a picture of a stability study's results.csv, one row per scenario case and one column per
value of a key (`python -m taichi_mpm.tools.stability map`)."""


def case_label(row: dict, keys: list, column: str) -> str:
    """'impact E=1e+03 cfl=0.8' style label from a results.csv row: the swept keys except `column`."""
    kind = row.get("problem.type") or "impact"
    parts = []
    for k in keys:
        v = row.get(k, "")
        if v in ("", None) or k in ("problem.type", column):
            continue
        try:
            v = f"{float(v):g}"
        except ValueError:
            pass
        parts.append(f"{k.split('.')[-1]}={v}")
    return f"{kind} " + " ".join(parts)


def plot_map(results_csv, path, column: str = "solver.transfer", title: str = "stability map"):
    """One row per scenario case, one column per value of `column`: green stable, orange stopped with
    InstabilityError (cause abbreviated), red finished as garbage ("undetected"), grey error."""
    import csv

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(results_csv) as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
        names = reader.fieldnames
    keys = names[names.index("repeat") + 1: names.index("outcome")]  # the swept keys
    cols = list(dict.fromkeys(r.get(column, "") for r in rows))
    labels = list(dict.fromkeys(case_label(r, keys, column) for r in rows))
    short = {"inverted or collapsed particle (J <= 0)": "J<=0", "particle left the domain": "left domain",
             "non-finite value (NaN or infinity) in velocity or deformation": "NaN",
             "energy growth beyond the work done on the system": "energy", "fluid volume collapse": "fluid J",
             "numerical fracture (a body tore apart on the grid)": "fracture"}
    fig, ax = plt.subplots(figsize=(2.2 + 1.3 * len(cols), 0.6 + 0.24 * len(labels)), dpi=80)
    for r in rows:
        i, j = labels.index(case_label(r, keys, column)), cols.index(r.get(column, ""))
        out, cause = r["outcome"], r.get("cause", "")
        if out == "ok":
            color, text = "#4caf50", "stable"
        elif out == "unstable" and cause.startswith("undetected"):
            color, text = "#e53935", "garbage"
        elif out == "unstable":
            color, text = "#ffb74d", short.get(cause, cause[:12])
        else:
            color, text = "#9e9e9e", "error"
        ax.add_patch(plt.Rectangle((j, i), 1, 1, color=color, ec="white"))
        ax.text(j + 0.5, i + 0.5, text, ha="center", va="center", fontsize=7)
    ax.set_xlim(0, len(cols))
    ax.set_ylim(len(labels), 0)
    ax.set_xticks([j + 0.5 for j in range(len(cols))], cols, fontsize=8)
    ax.set_yticks([i + 0.5 for i in range(len(labels))], labels, fontsize=7)
    ax.xaxis.tick_top()
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
