"""A study's output folder: what it writes there, the refusal to replace results unasked, the finished case
records it holds (for --resume and the reports), and the study as it ran (study.yaml)."""
import json
from pathlib import Path

from ...config import ConfigError
from .spec import Study


# what a study writes into its output folder; an existing one of these marks a folder holding results
OUTPUTS = ("study.yaml", "cases", "results.csv", "summary.md", "pareto.png", "convergence.png")


def prepare_out(st: Study, out: Path, named: bool, resume: bool, overwrite: bool) -> Path:
    """Check the output folder (refusing to overwrite results unasked) and return its cases/ folder."""
    def refuse(msg):
        raise ConfigError(msg, key="study" if named else None, line=st.lines.get("study") if named else None,
                          file=st.path if named else None)

    if out.exists() and not out.is_dir():
        refuse(f"the output folder {out} exists and is not a folder")
    links = [n for n in OUTPUTS if (out / n).is_symlink()]
    if links:
        refuse(f"{out / links[0]} is a symbolic link: a study writes only into its own folder")
    held = [n for n in OUTPUTS if (out / n).exists()]
    if held and not (resume or overwrite):
        refuse(f"{out} already holds study results ({', '.join(held)}): add --resume to continue them "
               f"or --overwrite to replace them")
    case_dir = out / "cases"
    if case_dir.exists() and not case_dir.is_dir():
        refuse(f"{case_dir} exists and is not a folder")
    try:
        if overwrite:   # only what a study writes, by name, inside its folder
            for f in case_dir.glob("*.json") if case_dir.is_dir() else ():
                f.unlink()
            for n in OUTPUTS:
                if n != "cases" and (out / n).is_file():
                    (out / n).unlink()
        case_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        refuse(f"cannot write the study outputs in {out}: {e}")
    return case_dir


def finished_records(case_dir: Path) -> dict:
    out = {}
    for f in case_dir.glob("*.json"):
        try:
            rec = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        out[rec.get("digest")] = rec
    return out


def study_dump(st: Study) -> dict:
    d = dict(study=st.name)
    if st.base:
        d["base"] = st.base
    else:
        d["problem"] = st.problem
    for k in ("vary", "cases", "set"):
        if getattr(st, k):
            d[k] = getattr(st, k)
    d.update(repeats=st.repeats, metric=st.metric, time_metric=st.time_metric, convergence_key=st.convergence_key,
             energy_limit=st.energy_limit, timeout=st.timeout, samples=st.samples, timing=st.timing)
    if st.observe is not None:
        d.update(observe=st.observe["text"], reference=st.reference)
    return d
