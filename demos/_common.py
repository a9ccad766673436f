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
    ap.add_argument("--out", default=None, help="output directory (default: output.dir of the config + '_python', "
                                                "e.g. runs/NAME_python, so `taichi-mpm demo NAME` keeps runs/NAME)")
    args = ap.parse_args(argv)
    cfg = tm.load_config(CONFIGS / f"{name}.yaml", overrides=parse_overrides(args.overrides))
    return cfg, args


def default_out(cfg) -> Path:
    """The script's own output folder, beside the CLI demo's: output.dir + '_python' (runs/NAME_python)."""
    d = Path(cfg.output.dir.format(name=cfg.name))
    return d.with_name(d.name + "_python")


def run(sim, out=None, on_step=None):
    """Run to the end time writing the config's outputs; report particles, steps and wall time."""
    out = Path(out) if out is not None else default_out(sim.cfg)
    t0 = time.perf_counter()
    sim.run(out_dir=out, on_step=on_step, overwrite=True)  # a demo script regenerates its outputs
    wall = time.perf_counter() - t0
    print(f"{sim.cfg.name}: {sim.n} particles, {sim.n_steps} steps to t={sim.time:.4g} s in {wall:.1f} s -> {out}",
          file=sys.stderr)
    return sim
