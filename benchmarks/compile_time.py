"""Time to the first step of a typical 3D scene: cold (empty Taichi offline cache) and warm (cache filled).
Per basis two runs: a long one (solver.unroll auto unrolls its stencil) and a short one (end_time 0.01 s: 100
steps, below stencils.UNROLL_WORK, so auto keeps the stencil loop at run time).

Each measurement runs in a fresh process, pointing Taichi's offline cache at a fresh directory for the cold run
and at the same directory again for the warm run.

    python benchmarks/compile_time.py

The processes inherit the environment: with PYTHONDONTWRITEBYTECODE set, each one also compiles the package's
modules from source (0.1-0.3 s more than an installed package, which has its bytecode cached).
"""
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, parser, report  # noqa: E402


def first_step(basis, transfer, end_time=None):
    t0 = time.perf_counter()
    import taichi_mpm as tm

    t_import = time.perf_counter() - t0
    cfg = block_config(3, 32, basis=basis, transfer=transfer)
    if end_time is not None:
        cfg["solver"]["end_time"] = end_time
    sim = tm.Simulation(cfg)
    sim.step()
    return dict(import_s=t_import, first_step_s=time.perf_counter() - t0, unroll=str(sim.unroll))


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--case", help="internal")
    p.add_argument("--bases", nargs="+", default=["quadratic", "cubic"])
    a = p.parse_args(argv)
    if a.case:
        print("RESULT " + json.dumps(first_step(*json.loads(a.case))))
        return None
    rows = []
    bases = a.bases[:1] if a.tiny else a.bases
    for basis in bases:
        for run, end_time in (("long run", None), ("short run", 0.01)):
            with tempfile.TemporaryDirectory() as cache:
                env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache)
                for label in ("cold", "warm"):
                    out = subprocess.run([sys.executable, __file__, "--case", json.dumps([basis, "apic", end_time])],
                                         capture_output=True, text=True, check=True, env=env)
                    r = json.loads(next(l for l in out.stdout.splitlines() if l.startswith("RESULT "))[7:])
                    rows.append(dict(scene=f"3D {basis} APIC elastic, {run}", cache=label, **r))
    report(rows, a.json)
    return rows


if __name__ == "__main__":
    main()
