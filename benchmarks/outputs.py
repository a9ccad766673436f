"""What outputs cost a user (issue 31): the main demo (configs/sphere_impact.yaml) run by the CLI with its outputs
(VTU, frames, movie): frames drawn while the solver steps on their own worker thread (`live`: the demo's clim and
framing fix the colour range and the camera in advance), the same frames drawn at the end of the run (`end`:
output.render.framing=run, the path of runs whose range or camera is known only at the end), everything written
inline (the solver's thread), outputs off, and VTU snapshots only (no frames), threaded and inline.

Reports per mode: total wall time, first step (compile), stepping, total / (first step + stepping) (target <= 1.4
with outputs on), the stepping rate (particle-steps/s: lower when frames are drawn beside the solver on a loaded
machine), the run folder's size, the per-kind breakdown of `--profile` and the load average (a shared machine:
read the figures with it). `--rounds N` runs the modes N rounds, interleaved, so that a change of load shows.

    PYTHONPATH=. python benchmarks/outputs.py                  # the whole demo: live, end, off, vtu
    PYTHONPATH=. python benchmarks/outputs.py --end-time 0.1   # a shorter run with the same outputs per step
"""
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from common import parser, report

REPO = Path(__file__).resolve().parents[1]
MODES = {  # --set overrides of each mode
    "live": [],                                                   # frames while stepping (the demo's config)
    "end": ["output.render.framing=run"],                         # frames at the end of the run
    "inline": ["output.writer=inline"],
    "off": ["output.formats=[]", "output.checkpoint_every=1000000"],
    "vtu": ["output.formats=[vtu]"],                              # snapshots and checkpoints, no frames
    "vtu_inline": ["output.formats=[vtu]", "output.writer=inline"],
}


def folder_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 1e6


def run_mode(config: Path, mode: str, out: Path, extra: list[str]) -> dict:
    sets = [a for s in MODES[mode] + extra for a in ("--set", s)]
    cmd = [sys.executable, "-m", "taichi_mpm", "run", str(config), "--out", str(out), "--overwrite", "--quiet",
           "--profile", *sets]
    load = os.getloadavg()[0]
    p = subprocess.run(cmd, env=dict(os.environ, PYTHONPATH=str(REPO)), capture_output=True, text=True, timeout=1800)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({p.returncode}): {p.stderr[-2000:]}")
    table = dict((m.group(1).strip(), float(m.group(2)))
                 for m in re.finditer(r"^\s{2,}(.+?)\s+(-?\d+\.\d+)$", p.stderr, flags=re.M))
    first, stepping, total = table["first step (compile)"], table["stepping"], table["total"]
    rate = float(re.search(r"stepping ([\d.e+-]+) particle-steps/s", p.stderr).group(1))
    row = dict(mode=mode, total_s=total, first_step_s=first, stepping_s=stepping, particle_steps_per_s=rate,
               total_over_solver=total / (first + stepping), load_avg=round(load, 2),
               folder_mb=round(folder_mb(out), 1))
    row.update({k.strip(): v for k, v in table.items() if k not in ("total", "first step (compile)", "stepping")})
    return row


def main(argv=None):
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--config", type=Path, default=REPO / "configs" / "sphere_impact.yaml")
    p.add_argument("--end-time", type=float, default=None, help="solver.end_time (default: the config's)")
    p.add_argument("--modes", default="live,end,off,vtu", help="comma-separated, of: " + ", ".join(MODES))
    p.add_argument("--rounds", type=int, default=1, help="rounds of all the modes, interleaved")
    a = p.parse_args(argv)
    extra = [f"solver.end_time={a.end_time}"] if a.end_time else []
    if a.tiny:
        extra = ["solver.end_time=0.01", "output.every=0.005", "output.render.size=[96,72]"]
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="outputs_bench_"))
    try:
        for _ in range(max(1, a.rounds)):
            for mode in a.modes.split(","):
                rows.append(run_mode(a.config, mode, tmp / mode, extra))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    core = ["mode", "total_s", "first_step_s", "stepping_s", "particle_steps_per_s", "total_over_solver", "folder_mb",
            "load_avg"]
    report([{k: r.get(k) for k in core} for r in rows], a.json)
    print()
    for r in rows:
        print(f"{r['mode']}: " + ", ".join(f"{k} {v:.2f}" for k, v in r.items() if k not in core))
    return rows


if __name__ == "__main__":
    main()
