"""Shared by the demo scripts: load configs/<name>.yaml with `--set KEY=VALUE` overrides and run it."""
import argparse
import sys
import time
from pathlib import Path

import taichi_mpm as tm
from taichi_mpm.config import parse_overrides

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def parse(name, argv=None, doc=None):
    ap = argparse.ArgumentParser(prog=f"demos/{name}.py", description=doc)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="override a config key, e.g. --set domain.dx=0.05 --set output.formats=[vtu]")
    ap.add_argument("--out", default=None, help="output directory (default: output.dir of the config)")
    args = ap.parse_args(argv)
    cfg = tm.load_config(CONFIGS / f"{name}.yaml", overrides=parse_overrides(args.overrides))
    return cfg, args


def run(sim, out=None, setup=None):
    """Run to the end time writing the config's outputs; report particles, steps and wall time."""
    t0 = time.perf_counter()
    sim.run(out_dir=out, overwrite=True)  # a demo script regenerates its outputs
    wall = time.perf_counter() - t0
    print(f"{sim.cfg.name}: {sim.n} particles, {sim.n_steps} steps to t={sim.time:.4g} s in {wall:.1f} s "
          f"-> {out or sim.cfg.output.dir.format(name=sim.cfg.name)}", file=sys.stderr)
    return sim
