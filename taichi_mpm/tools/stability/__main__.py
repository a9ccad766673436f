"""`python -m taichi_mpm.tools.stability cfl|map`: the largest stable CFL table (stability/cfl.py) and the stability map
picture (stability/picture.py)."""
import argparse
import json
import sys
from pathlib import Path

import yaml

from ... import schemes as transfer_schemes
from .cfl import CFL_SPEC, cfl_markdown, cfl_table
from .picture import plot_map


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m taichi_mpm.tools.stability")
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("cfl", help="largest stable CFL number per basis and transfer")
    c.add_argument("--bases", help="comma-separated (default: the registry's swept bases, bases/registry.py)")
    c.add_argument("--transfers", default=",".join(transfer_schemes.names()))
    c.add_argument("--spec", default=json.dumps(CFL_SPEC), help="scenario spec (JSON)")
    c.add_argument("--lo", type=float, default=0.1)
    c.add_argument("--hi", type=float, default=1.5)
    c.add_argument("--tol", type=float, default=0.05)
    c.add_argument("--energy-limit", type=float, default=1.1)
    c.add_argument("--update", choices=("usl", "musl", "usf"), help="solver.update of every trial (default: usl)")
    c.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a config key of every trial, e.g. solver.cpdi.variant=cpdi2 (repeatable)")
    c.add_argument("--jobs", type=int, default=1)
    c.add_argument("--out", help="write the table (markdown) and trials (JSON) with this path stem")
    m = sub.add_parser("map", help="picture of a stability study's results.csv")
    m.add_argument("results_csv")
    m.add_argument("png")
    m.add_argument("--column", default="solver.transfer")
    m.add_argument("--title", default="stability map")
    args = ap.parse_args(argv)
    if args.cmd == "map":
        plot_map(args.results_csv, args.png, args.column, args.title)
        return 0
    spec = json.loads(args.spec)
    bases = args.bases.split(",") if args.bases else None
    extra = {k: yaml.safe_load(v) for k, v in (item.split("=", 1) for item in args.set)}   # values as YAML reads them
    if args.update:
        extra["solver.update"] = args.update
    rows = cfl_table(bases, args.transfers.split(","), spec, jobs=args.jobs, lo=args.lo, hi=args.hi,
                     tol=args.tol, energy_limit=args.energy_limit, log=lambda m: print(m, flush=True),
                     extra=extra or None)
    md = cfl_markdown(rows, spec)
    print(md)
    if args.out:
        Path(args.out).with_suffix(".md").write_text(md)
        Path(args.out).with_suffix(".json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
