"""`taichi-mpm compare`: variants of one scene side by side (frames, movie, curves, summary), one colour range."""
import csv
from pathlib import Path

import numpy as np
import pytest

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm.tools.compare import _out_dir, compare, parse_vary, split_values
from taichi_mpm.errors import ConfigError

imageio = pytest.importorskip("imageio.v2")


def spinning_block():
    """A block spinning at 2 rad/s about its centre, no gravity: PIC's velocity averaging takes its rotation
    away, APIC keeps it (Jiang et al. 2015)."""
    cfg = make_cfg(2, dx=0.1, end_time=0.5)
    cfg["bodies"][0]["angular_velocity"] = 2.0
    cfg["output"] = {"every": 0.1, "render": {"color_by": "speed", "size": [400, 200]}}
    return cfg


def test_pic_loses_the_rotation_apic_keeps_side_by_side(tmp_path):
    res = compare(spinning_block(), "solver.transfer=pic,apic", out=tmp_path / "cmp")
    pic, apic = res["variants"]
    ke = {v.value: [r["kinetic"] for r in v.rows] for v in res["variants"]}
    # the first transfer costs both a part of the rotation (the particles start with C = 0, so APIC's affine part
    # starts empty: measured 2.625 -> 1.434 J/m); from then on APIC keeps it (measured within 1.4 %, the rest
    # swaps with strain energy) while PIC's averaging damps it to nothing (measured 0.0089 -> 1e-5 J/m)
    assert ke["apic"][-1] == pytest.approx(ke["apic"][1], rel=0.03)
    assert ke["pic"][-1] < 0.01 * ke["pic"][1] and ke["pic"][-1] < 1e-3 * ke["apic"][-1]
    for v in res["variants"]:                       # the block's centre stays put: zero linear momentum
        assert max(r["momentum"] for r in v.rows) < 1e-9 * max(1.0, ke[v.value][0])
    assert [f.name for f in res["frames"]] == [f"frame_{k:06d}.png" for k in range(6)]
    img = imageio.imread(res["frames"][-1])[..., :3]
    assert img.shape[:2] == (200, 2 * 200 + 2)     # two panels of 200 px and a separator
    left, right = img[:, :200], img[:, 202:]
    # one colour range for both panels: the two colour bars (bottom 8 % of each panel) are the same picture
    np.testing.assert_array_equal(left[-16:, 30:170], right[-16:, 30:170])
    assert left[20:150].astype(float).var() > 100 and right[20:150].astype(float).var() > 100
    assert len(imageio.mimread(res["movie"])) == 6
    rows = list(csv.DictReader(open(res["summary"])))
    assert [r["value"] for r in rows] == ["pic", "apic"] and all(r["status"] == "ok" for r in rows)
    assert res["curves"].stat().st_size > 10_000
    # a second comparison into the same folder needs --overwrite
    with pytest.raises(ConfigError, match="overwrite"):
        compare(spinning_block(), "solver.transfer=pic,apic", out=tmp_path / "cmp")


def test_vary_parsing_and_bad_input(tmp_path):
    assert split_values("linear,cubic") == ["linear", "cubic"]
    assert split_values("[0,-9.81],[0,0]") == ["[0,-9.81]", "[0,0]"]
    assert parse_vary("solver.basis=linear,cubic,gimp") == ("solver.basis", ["linear", "cubic", "gimp"])
    for bad in ("solver.basis", "solver.basis=linear", "=a,b", "solver..basis=a,b", "solver.basis=a,a"):
        with pytest.raises(ConfigError):
            parse_vary(bad)
    with pytest.raises(ConfigError, match="solver.basis=wavelet"):   # every variant is validated before any run
        compare(spinning_block(), "solver.basis=linear,wavelet", out=tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_cli_compare_exit_codes(tmp_path):
    from taichi_mpm.cli import main

    assert main(["compare", str(tmp_path / "missing.yaml"), "--vary", "solver.basis=linear,cubic"]) == 2
    cfg = tmp_path / "c.yaml"
    import yaml

    cfg.write_text(yaml.safe_dump(spinning_block()))
    assert main(["compare", str(cfg), "--vary", "solver.basis"]) == 2
    assert main(["compare", str(cfg), "--vary", "solver.basis=linear,cubic", "--color-by", "temperature"]) == 2


def test_default_folder_takes_only_a_plain_key_name():
    # the folder beside the run's is named after the varied key; a key whose last part is a user's name with
    # path characters (a material called "a/../../x") must not become a path outside it
    cfg = tm.load_config(make_cfg(2))
    base = Path(cfg.output.dir.replace("{name}", cfg.name))
    assert _out_dir(cfg, "solver.basis", None) == base.parent / f"{base.name}_compare_basis"
    assert _out_dir(cfg, "materials.a/../../x", None) == base.parent / f"{base.name}_compare_vary"


@pytest.mark.slow
def test_compare_on_a_mapped_grid(tmp_path, monkeypatch):
    """`compare` on a mapped scene (the annulus of tests/test_mapped.py, its stretch-test kernels): two spin
    rates side by side. The kinetic energy at t = 0 goes as omega^2 (exactly 4x, 1e-12: the same particles),
    both runs finish, and each panel's renderer gets the curved grid's cell edges (25 spokes and 5 circles;
    that the renderer draws them is tests/test_mapped.py::test_the_curved_grid_is_drawn; counting grey pixels
    here separated them poorly: 281 against 177 without the lines, the colour bar being grey too)."""
    import taichi_mpm.io.render as render
    from test_mapped import ring_cfg

    given = []

    class Spy(render.FrameRenderer):
        def __init__(self, *a, lines=None, **k):
            given.append(lines)
            super().__init__(*a, lines=lines, **k)

    monkeypatch.setattr(render, "FrameRenderer", Spy)

    cfg = ring_cfg(walls="free", model="neo_hookean")
    cfg["solver"]["end_time"] = 0.04
    cfg["output"] = {"every": 0.02, "render": {"color_by": "speed", "size": [400, 200]}}
    res = compare(cfg, "bodies.0.angular_velocity=0.5,1.0", out=tmp_path / "cmp")
    ke = [[r["kinetic"] for r in v.rows] for v in res["variants"]]
    assert ke[1][0] == pytest.approx(4 * ke[0][0], rel=1e-12) and ke[0][0] > 0
    rows = list(csv.DictReader(open(res["summary"])))
    assert all(r["status"] == "ok" for r in rows)
    img = imageio.imread(res["frames"][-1])[..., :3]
    assert img.shape[:2] == (200, 2 * 200 + 2) and img.astype(float).var() > 100
    expected = render.grid_lines(tm.load_config(cfg))
    panels = given[-2:]          # the first renderer only checks the render options
    assert len(given) == 3 and all(len(lines) == 25 + 5 for lines in panels)
    for lines in panels:
        for a, b in zip(lines, expected):
            np.testing.assert_array_equal(a, b)


@pytest.mark.slow   # 65 s cold (f32 fluid kernels, rendering) on the shared machine
def test_cli_compare_on_the_round_tank(tmp_path):
    """`taichi-mpm compare configs/round_tank.yaml` (a generic NURBS grid, coarsened as in tests/test_demos.py's
    quick run, so its kernels): two bulk moduli side by side to 0.1 s; both finish (status ok) and the frames
    have two panels. The drop has not landed yet (it lands at 0.2 s), so the bulk modulus barely matters: the
    final momenta agree within 5 % (measured 236.2 and 231.9 N s/m, 1.8 %; K = 1e6 and 2e6 Pa)."""
    from taichi_mpm.cli import main

    cfg = Path(__file__).resolve().parents[1] / "configs" / "round_tank.yaml"
    sets = ["arch=cpu", "domain.dx=0.08", "domain.map.refine=[6,6]", "solver.end_time=0.1", "output.every=0.05"]
    args = ["compare", str(cfg), "--vary", "materials.water.K=1e6,2e6", "--size", "640x240", "--out",
            str(tmp_path / "cmp")] + [a for s in sets for a in ("--set", s)]
    assert main(args) == 0
    rows = list(csv.DictReader(open(tmp_path / "cmp" / "summary.csv")))
    assert [r["status"] for r in rows] == ["ok", "ok"]
    frames = sorted((tmp_path / "cmp").rglob("frame_*.png"))
    h, w = imageio.imread(frames[-1]).shape[:2]
    assert len(frames) == 3 and h == 240 and 640 <= w <= 644      # two panels (widths rounded) and a separator
    p = [float(r["momentum_end"]) for r in rows]
    assert p[0] > 0 and abs(p[1] - p[0]) < 0.05 * p[0]


def test_vary_takes_a_bounded_number_of_values(tmp_path, monkeypatch, capsys):
    """1000 values are refused up front (exit 2, naming --vary and the cap), before any config is loaded or run."""
    from taichi_mpm.tools import compare as compare_mod
    from taichi_mpm.cli import main

    many = "solver.cfl=" + ",".join(f"{0.1 + 1e-4 * i:.4f}" for i in range(1000))
    with pytest.raises(ConfigError, match=f"--vary.*1000 values.*at most {compare_mod.MAX_VARIANTS}"):
        parse_vary(many)
    assert len(parse_vary("solver.cfl=" + ",".join(str(0.1 * (i + 1)) for i in range(compare_mod.MAX_VARIANTS)))[1]) \
        == compare_mod.MAX_VARIANTS
    ran = []
    monkeypatch.setattr(compare_mod, "run_variant", lambda *a, **k: ran.append(a))
    monkeypatch.setattr(compare_mod, "load_config", lambda *a, **k: ran.append(a))
    cfg = tmp_path / "c.yaml"
    import yaml

    cfg.write_text(yaml.safe_dump(spinning_block()))
    assert main(["compare", str(cfg), "--vary", many, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "--vary" in err and "1000 values" in err and err.count("taichi-mpm: error:") == 1
    assert ran == [] and not (tmp_path / "o").exists()


def test_the_work_is_estimated_before_any_variant_runs(tmp_path, monkeypatch):
    """The log's first line says how much will run (variants, particles x steps, frames), from the size estimate,
    before the first variant starts; a comparison estimated beyond the work limit is refused naming --vary."""
    from taichi_mpm import budget
    from taichi_mpm.tools import compare as compare_mod

    lines = []
    monkeypatch.setattr(compare_mod, "run_variant", lambda v, field, log=None: lines.append(f"ran {v.label}"))
    res = compare(spinning_block(), "solver.transfer=pic,apic", out=tmp_path / "cmp", log=lines.append)
    est = budget.estimate(tm.load_config(spinning_block()))
    first = lines[0]
    assert first.startswith("compare: 2 variants") and f"{2 * est.particles * est.steps:.3g} particle-steps" in first
    assert lines[1] == "ran transfer = pic"
    assert res["work"]["particle_steps"] == pytest.approx(2 * est.particles * est.steps)
    monkeypatch.setattr(compare_mod, "MAX_WORK", est.particles * est.steps)   # one variant's work: two exceed it
    with pytest.raises(ConfigError, match="--vary") as e:
        compare(spinning_block(), "solver.transfer=pic,apic", out=tmp_path / "cmp2", log=lines.append)
    assert "particle-steps" in str(e.value) and "--allow-large" in str(e.value)
    res = compare(spinning_block(), "solver.transfer=pic,apic", {"limits.allow_large": True}, out=tmp_path / "cmp3")
    assert res["work"]["particle_steps"] > compare_mod.MAX_WORK   # opted in: it runs
