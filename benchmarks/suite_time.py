"""The default test suite's time as CI sees it: an empty Taichi kernel cache (unless --warm), two workers on two
cores, and where the time goes: per test file and for the slowest tests, the seconds spent in kernels' first
launches (compiles) and in ti.init, and per kernel name, measured in-process by benchmarks/compile_timer_plugin.py
(tests that run the CLI in a subprocess show their wall time only).

    python benchmarks/suite_time.py                 # the README's test command, cold
    python benchmarks/suite_time.py --warm -- tests/test_crack.py
    python benchmarks/suite_time.py --json rows.json     # every test's row, for comparing two runs

Writes nothing outside temporary folders.
"""
import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--warm", action="store_true", help="use the user's kernel cache instead of an empty one")
    p.add_argument("--top", type=int, default=25, help="slowest tests listed")
    p.add_argument("--json", help="also write every test's row (seconds, compile_s, inits) to this file")
    p.add_argument("pytest_args", nargs="*", help="after --: passed to pytest (default: the whole default suite)")
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as out, tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, SUITE_TIME_OUT=out,
                   PYTHONPATH=os.pathsep.join([str(ROOT / "benchmarks"), os.environ.get("PYTHONPATH", "")]))
        if not a.warm:
            env["TI_OFFLINE_CACHE_FILE_PATH"] = cache
        t = time.perf_counter()
        run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "compile_timer_plugin",
                              "-p", "no:cacheprovider", *a.pytest_args], cwd=ROOT, env=env,
                             stdin=subprocess.DEVNULL, capture_output=True, text=True)
        wall = time.perf_counter() - t
        rows = [json.loads(line) for f in Path(out).glob("*.jsonl") for line in f.read_text().splitlines()]
    summary = run.stdout.strip().splitlines()[-1] if run.stdout.strip() else run.stderr[-500:]
    if a.json:
        Path(a.json).write_text(json.dumps(dict(wall=wall, summary=summary, rows=rows), indent=1))
    return report(rows, wall, summary, a.top, run.returncode)


def report(rows, wall, summary, top, returncode):
    total, compile_s = sum(r["seconds"] for r in rows), sum(r["compile_s"] for r in rows)
    print(f"pytest: {summary}")
    print(f"wall {wall:.0f} s; test time {total:.0f} s, of it first launches and ti.init {compile_s:.0f} s; "
          f"Taichi started {sum(r['inits'] for r in rows)} times")
    files, cfiles, counts = collections.Counter(), collections.Counter(), collections.Counter()
    for r in rows:
        f = r["test"].split("::")[0]
        files[f] += r["seconds"]
        cfiles[f] += r["compile_s"]
        counts[f] += 1
    print(f"\n{'seconds':>8} {'compile':>8} {'tests':>5}  file")
    for f, s in files.most_common(top):
        print(f"{s:8.1f} {cfiles[f]:8.1f} {counts[f]:5d}  {f}")
    print(f"\n{'seconds':>8} {'compile':>8} {'inits':>5}  test")
    for r in sorted(rows, key=lambda r: -r["seconds"])[:top]:
        print(f"{r['seconds']:8.1f} {r['compile_s']:8.1f} {r['inits']:5d}  {r['test']}")
    launches = collections.defaultdict(list)
    for r in rows:
        for name, times in r.get("kernels", {}).items():
            launches[name] += times
    print(f"\n{'seconds':>8} {'first':>6} {'median':>7}  kernel (first launches: a compile, or a load from the cache)")
    for name, times in sorted(launches.items(), key=lambda kv: -sum(kv[1]))[:top]:
        print(f"{sum(times):8.1f} {len(times):6d} {sorted(times)[len(times) // 2]:7.3f}  {name}")
    return returncode


if __name__ == "__main__":
    sys.exit(main())
