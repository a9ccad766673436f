"""Memory and time follow the particles: a fixed body in ever larger domains (sparse grid).

The same elastic block (same particles, same cells) sits in domains of growing size; step time and the process
memory growth per domain are reported as ratios to the smallest domain, measured in the same run (each domain in
its own process, so memory is not shared between cases).

    python benchmarks/sparse_domain.py              # 3D: 128^3 ... 1024^3 cells
"""
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, parser, peak_rss_mb, report, time_steps  # noqa: E402


def one_case(dim, cells, body_cells, steps, repeats, arch):
    import taichi_mpm as tm

    dx = 1.0 / 128
    extent = cells * dx
    cfg = block_config(dim, cells, extent=extent, body=(8 * dx, (8 + body_cells) * dx), arch=arch)
    rss0 = peak_rss_mb()
    sim = tm.Simulation(cfg)
    sim.step()
    t = time_steps(sim.step, steps, repeats)
    return dict(dim=dim, domain_cells=f"{cells}^{dim}", particles=sim.n, ms_per_step=t * 1e3,
                rss_growth_mb=peak_rss_mb() - rss0)


def main(argv=None):
    p = parser(__doc__)
    p.add_argument("--dim", type=int, default=3)
    p.add_argument("--case", help="internal: run one case and print JSON")
    a = p.parse_args(argv)
    if a.case:
        print("RESULT " + json.dumps(one_case(*json.loads(a.case))))
        return None
    sizes = [32, 64, 128] if a.tiny else ([128, 256, 512, 1024] if a.dim == 3 else [256, 1024, 4096, 16384])
    body_cells = 8 if a.tiny else 24
    steps = a.steps or (2 if a.tiny else 20)
    rows = []
    for cells in sizes:
        arg = json.dumps([a.dim, cells, body_cells, steps, 1 if a.tiny else a.repeats, a.arch])
        out = subprocess.run([sys.executable, __file__, "--case", arg], capture_output=True, text=True, check=True)
        rows.append(json.loads(next(l for l in out.stdout.splitlines() if l.startswith("RESULT "))[7:]))
    for r in rows:
        r["time_ratio"] = r["ms_per_step"] / rows[0]["ms_per_step"]
    report(rows, a.json)
    return rows


if __name__ == "__main__":
    main()
