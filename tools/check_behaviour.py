"""Behaviour check for redesigns: run a fixed set of scenes in `solver.deterministic` mode and compare the states
with those of another commit built on this machine.

    python tools/check_behaviour.py record OUT.npz [--only NAME ...]
    python tools/check_behaviour.py compare A.npz B.npz
    python tools/check_behaviour.py against COMMIT [--only NAME ...]   # records COMMIT (a git worktree in a temp
                                                                        # folder) and this tree, then compares

The scenes cover every basis and transfer, USL/MUSL, 1D/2D/3D, the crack finder, F-bar, a mapped grid, knots,
plasticity, loads and grips: the bundled configs plus a small block per option. Each runs a fixed number of steps
at the stable dt on the CPU backend with outputs off; the state is `Simulation.get_state()` after them. Identical
means bit for bit (deterministic mode promises that on one machine and build). Exit 0 when every state is equal.
"""
from __future__ import annotations

import argparse
import copy
import pathlib
import subprocess
import sys
import tempfile

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
STEPS = 12


def _block(dim=2, basis="quadratic", transfer="apic", **solver):
    """One neo-Hookean box moving and spinning in a cube domain (gravity on, slip walls)."""
    lower, upper = [0.3] * dim, [0.6] * dim
    velocity = [0.5, -0.3, 0.2][:dim]
    body = dict(name="block", shape=dict(type="box", lower=lower, upper=upper), material="m", velocity=velocity)
    return dict(name="block", dim=dim, precision="f64", arch="cpu",
                domain=dict(lower=[0.0] * dim, upper=[1.0] * dim, dx=0.1, boundaries=dict(default="slip")),
                solver=dict(basis=basis, transfer=transfer, end_time=1.0, gravity=[0.0, -9.81, 0.0][:dim], **solver),
                materials=dict(m=dict(model="neo_hookean", E=1.0e4, nu=0.3, density=1000.0)), bodies=[body])


def scenes() -> dict:
    """name -> config (dict or path). Small and fixed: changing it changes what 'identical' was checked on."""
    out = {}
    for basis in ("linear", "gimp", "quadratic", "cubic", "cpdi", "ddmp"):
        out[f"block2d_{basis}"] = _block(2, basis)
    for transfer in ("pic", "flip"):
        out[f"block2d_{transfer}"] = _block(2, "quadratic", transfer)
    out["block2d_musl"] = _block(2, "quadratic", "flip", update="musl")
    out["block1d_linear"] = _block(1, "linear")
    out["block1d_cubic"] = _block(1, "cubic", "flip")
    out["block3d_quadratic"] = _block(3, "quadratic")
    out["block3d_gimp_pic"] = _block(3, "gimp", "pic")
    fb = _block(2, "quadratic", volumetric="fbar")
    fb["materials"]["m"]["nu"] = 0.49
    out["block2d_fbar"] = fb
    kn = _block(2, "quadratic")
    kn["domain"]["knots"] = {"x": [0, 0, 0, 0.2, 0.3, 0.45, 0.5, 0.5, 0.7, 1, 1, 1]}
    out["block2d_knots"] = kn
    two = _block(2, "quadratic")
    two["materials"]["soft"] = dict(model="linear_elastic", E=2.0e3, nu=0.2, density=500.0)
    two["bodies"].append(dict(name="second", shape=dict(type="box", lower=[0.1, 0.1], upper=[0.25, 0.25]),
                              material="soft", velocity=[0.2, 0.1]))
    out["block2d_two_materials"] = two
    # the stencil unrolled (these small blocks' short runs keep it at run time under solver.unroll auto): every
    # transfer and tensor basis on the factorised G2P sums, and auto's split of a long 3D run (3 x 9 nodes)
    for basis in ("linear", "gimp", "quadratic", "cubic"):
        out[f"block2d_{basis}_unrolled"] = _block(2, basis, unroll=True)
    for transfer in ("pic", "flip", "mls", "xpic", "tpic", "asflip"):
        out[f"block2d_{transfer}_unrolled"] = _block(2, "quadratic", transfer, unroll=True)
    out["block2d_musl_unrolled"] = _block(2, "quadratic", "flip", update="musl", unroll=True)
    out["block3d_quadratic_unrolled"] = _block(3, "quadratic", unroll=True)
    out["block3d_gimp_pic_unrolled"] = _block(3, "gimp", "pic", unroll=True)
    long_run = _block(3, "quadratic", "flip", unroll="auto")
    long_run["solver"]["end_time"] = 1.0e3   # auto unrolls runs of 1e7 particle-steps or more (12 steps are run)
    out["block3d_quadratic_long_run"] = long_run
    knots = copy.deepcopy(kn)
    knots["solver"]["unroll"] = True
    out["block2d_knots_unrolled"] = knots
    for dim in (2, 3):   # a sand block thrown at the floor: returns to faces, edges and the apex
        mc = _block(dim, "quadratic")
        mc["materials"]["m"] = dict(model="mohr_coulomb", E=1.0e4, nu=0.3, density=1000.0, friction_angle=30.0)
        mc["bodies"][0].update(velocity=[1.0, -3.0, 0.5][:dim],
                               shape=dict(type="box", lower=[0.1] * dim, upper=[0.4] * dim))
        out[f"block{dim}d_mohr_coulomb"] = mc
    for path in sorted((ROOT / "configs").glob("*.yaml")):
        out[f"config_{path.stem}"] = path
    return out


def _load(spec):
    from taichi_mpm.config import load_config
    if isinstance(spec, pathlib.Path):
        import yaml
        raw = yaml.safe_load(spec.read_text())
    else:
        raw = copy.deepcopy(spec)
    raw["arch"] = "cpu"
    raw.setdefault("solver", {})["deterministic"] = True
    raw.pop("output", None)
    return load_config(raw)


def run_scene(spec) -> dict:
    from taichi_mpm.solver import Simulation
    sim = Simulation(_load(spec))
    for _ in range(STEPS):
        sim.step()
    state = sim.get_state()
    return {k: np.asarray(v) for k, v in state.items()}


def record(out: str, only=None):
    arrays = {}
    for name, spec in scenes().items():
        if only and name not in only:
            continue
        try:
            state = run_scene(spec)
        except Exception as e:   # a scene that fails is recorded as its error: a redesign must fail the same way
            arrays[f"{name}/__error__"] = np.array(f"{type(e).__name__}: {e}")
            print(f"{name}: {type(e).__name__}: {e}", flush=True)
            continue
        for k, v in state.items():
            arrays[f"{name}/{k}"] = v
        print(f"{name}: {len(state)} arrays", flush=True)
    np.savez(out, **arrays)


def compare(a_path: str, b_path: str) -> int:
    a, b = np.load(a_path), np.load(b_path)
    in_a, in_b = {k.split("/")[0] for k in a.files}, {k.split("/")[0] for k in b.files}
    names = sorted(in_a & in_b)
    if in_a ^ in_b:   # a record made with --only: compare what both hold, say what was left out
        print(f"recorded in one only (not compared): {', '.join(sorted(in_a ^ in_b))}")
    bad = 0
    for name in names:
        ka = {k for k in a.files if k.split("/")[0] == name}
        kb = {k for k in b.files if k.split("/")[0] == name}
        diffs = [f"only in one: {sorted(ka ^ kb)}"] if ka != kb else []
        for k in sorted(ka & kb):
            x, y = a[k], b[k]
            if x.shape != y.shape or x.dtype != y.dtype:
                diffs.append(f"{k}: shape/dtype {x.shape} {x.dtype} vs {y.shape} {y.dtype}")
            elif not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
                if x.dtype.kind in "fiu":   # the difference, and against the array's largest entry (round-off?)
                    d = np.max(np.abs(x.astype(float) - y.astype(float)))
                    scale = np.max(np.abs(x.astype(float)))
                    diffs.append(f"{k}: max |diff| {d:.3g} (relative {d / scale if scale > 0 else float('inf'):.2g})")
                else:
                    diffs.append(f"{k}: differs")
        print(f"{name}: {'identical' if not diffs else 'DIFFERENT'}")
        for d in diffs:
            print(f"    {d}")
        bad += bool(diffs)
    print(f"{len(names) - bad} of {len(names)} scenes identical")
    return 1 if bad else 0


def against(commit: str, only=None) -> int:
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="behaviour-"))
    tree = tmp / "tree"
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(tree), commit], check=True)
    try:
        extra = ["--only", *only] if only else []
        for where, out in ((tree, tmp / "before.npz"), (ROOT, tmp / "after.npz")):
            # this script (not the commit's copy) records both, with the package of `where` first on the path
            env_path = f"{where}"
            subprocess.run([sys.executable, str(pathlib.Path(__file__).resolve()), "record", str(out), *extra],
                           check=True, cwd=str(where), env={**__import__("os").environ, "PYTHONPATH": env_path})
        return compare(str(tmp / "before.npz"), str(tmp / "after.npz"))
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("--only", nargs="*")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    g = sub.add_parser("against")
    g.add_argument("commit")
    g.add_argument("--only", nargs="*")
    args = ap.parse_args(argv)
    if args.cmd == "record":
        record(args.out, args.only)
        return 0
    if args.cmd == "compare":
        return compare(args.a, args.b)
    return against(args.commit, args.only)


if __name__ == "__main__":
    sys.exit(main())
