"""Each benchmark script runs in its tiny configuration, so the scripts cannot rot. No timing is asserted here
(benchmarks are not tests); only that they run and report sane, complete rows."""
import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).parents[1] / "benchmarks"


def load(name):
    sys.path.insert(0, str(BENCH))
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow  # cold compile time: the default suite keeps a cheaper test of the same feature
def test_reference_benchmark_runs_both_kernels():
    rows = load("reference").main(["--tiny", "--sparse", "true"])
    assert rows[0]["case"].startswith("mpm3d") and len(rows) == 3
    assert all(r["particles"] == rows[0]["particles"] and r["particle_steps_per_s"] > 0 for r in rows)


@pytest.mark.slow
def test_roofline_reports_ceilings_and_kernels():
    out = load("roofline").main(["--tiny"])
    assert all(out["ceilings"][k] > 0 for k in ("bandwidth", "flops", "atomics"))
    rows = {r["kernel"]: r for r in out["rows"]}
    assert {"p2g", "g2p", "grid_update", "step (all)"} <= set(rows)
    assert rows["p2g"]["bound_ms"] > 0 and rows["g2p"]["x_of_bound"] > 0


@pytest.mark.slow
def test_throughput_benchmark_reports_each_case():
    # one case (a cold kernel set costs ~20 s of compile); the case loop is the product of the option lists
    rows = load("throughput").main(["--tiny", "--dims", "2", "--bases", "quadratic",
                                    "--transfers", "apic", "--precisions", "f32", "--layouts", "sparse"])
    assert [(r["basis"], r["transfer"]) for r in rows] == [("quadratic", "apic")]
    assert rows[0]["cost_vs_quadratic_apic"] == 1.0 and rows[0]["particle_steps_per_s"] > 0


@pytest.mark.slow
def test_memory_benchmark_minimal_scene_is_small():
    rows = load("memory").main(["--tiny"])
    minimal = rows[0]
    assert minimal["bytes_per_particle"] <= 80  # issue 6 target, exact from the allocated fields
    assert rows[1]["bytes_per_particle"] > minimal["bytes_per_particle"]  # APIC adds C


@pytest.mark.slow
@pytest.mark.parametrize("script", [pytest.param("sparse_domain", marks=pytest.mark.slow), "compile_time",
                                    pytest.param("threads", marks=pytest.mark.slow)])
def test_subprocess_benchmarks_run(script):
    rows = load(script).main(["--tiny"])
    assert len(rows) >= 2


@pytest.mark.slow  # cold compile time: the default suite keeps a cheaper test of the same feature
def test_materials_benchmark_reports_every_model():
    from taichi_mpm.materials import MODELS

    rows = load("materials").main(["--tiny", "--dims", "2"])
    assert [r["model"] for r in rows][0] == "fixed_corotated" and {r["model"] for r in rows} == set(MODELS)
    assert rows[0]["cost_vs_fixed_corotated"] == 1.0 and all(r["ns_per_particle_step"] > 0 for r in rows)


def test_device_capacity_per_feature_set():
    # no run: counts from the solver's own size estimate; more state per particle must mean fewer particles
    rows = load("device").main(["--arch", "cpu", "--quick", "--sections", "capacity", "--capacity", "140"])
    count = {r["case"]: r["particles"] for r in rows}
    assert count["PIC elastic f32"] > count["APIC elastic f32"] > count["APIC elastic f64"] > 0
    assert count["APIC elastic f32 + crack"] < count["APIC elastic f32"]
    assert all(r["particles"] < 2**31 for r in rows)  # Taichi's i32 index


def test_device_ratios_skip_cases_that_failed():
    """A peer that could not run (its engine absent) leaves an error row: no ratio to it, the others still get
    theirs."""
    rows = load("device").add_ratios([
        dict(section="mpm3d", case="mpm3d reference (dense)", particle_steps_per_s=2.0),
        dict(section="mpm3d", case="quadratic APIC fluid", particle_steps_per_s=3.0),
        dict(section="elements", case="taichi_elements (peer)", error="exit 1: no engine"),
        dict(section="elements", case="ours, elastic", particle_steps_per_s=5.0)])
    assert rows[1]["vs_mpm3d"] == 1.5 and "vs_taichi_elements" not in rows[3]


def test_device_refuses_an_absent_arch():
    from taichi_mpm.solver import available_archs

    if "cuda" in available_archs():
        pytest.skip("this machine has CUDA")
    with pytest.raises(SystemExit, match="not available"):
        load("device").main(["--arch", "cuda", "--sections", "capacity", "--capacity", "1"])


@pytest.mark.slow  # compiles every basis and the crack finder in 3D: the script a GPU session runs, on CPU
def test_device_script_runs_every_section_on_cpu(tmp_path):
    rows = load("device").main(["--arch", "cpu", "--quick", "--bases", "quadratic", "linear", "--fill-memory", "0.05",
                                "--budget-s", "3000", "--json", str(tmp_path / "d.json")])
    assert not [r for r in rows if "error" in r and r["case"] != "taichi_elements (peer)"], rows
    sections = {r["section"] for r in rows}
    assert {"mpm3d", "elements", "bases", "crack", "long", "fill"} <= sections
    assert all(r["particle_steps_per_s"] > 0 for r in rows if "particle_steps_per_s" in r)
    assert next(r for r in rows if r["case"].startswith("quadratic APIC fluid"))["vs_mpm3d"] > 0


@pytest.mark.slow  # two 3D kernel sets (with and without the crack finder) compile cold in worker processes
def test_crack_cost_benchmark_reports_ratio_and_kernels():
    rows = load("crack_cost").main(["--tiny", "--scenes", "blocks"])
    assert len(rows) == 1 and rows[0]["ratio"] > 0 and rows[0]["near_fraction"] > 0
    assert rows[0]["particle_normals_cpu_ms"] > 0


@pytest.mark.slow  # five CLI runs of the main demo cut to 0.01 s
def test_outputs_benchmark_reports_every_mode():
    rows = load("outputs").main(["--tiny"])
    assert [r["mode"] for r in rows] == ["live", "end", "off", "vtu"]   # the default --modes
    assert all(r["total_over_solver"] >= 1.0 and r["particle_steps_per_s"] > 0 and r["folder_mb"] > 0 for r in rows)
    assert rows[0]["folder_mb"] > rows[2]["folder_mb"]     # snapshots and frames cost room; off writes none
    assert rows[3]["folder_mb"] < rows[0]["folder_mb"]     # vtu: the same snapshots without the frames


@pytest.mark.slow
def test_targets_table_reports_each_target_met_or_not():
    rows = load("targets").main(["--only", "elements", "crack", "--tiny", "--rounds", "1"])
    elements, crack = rows
    assert elements["met"] == "not measured" and "--taichi-elements" in elements["note"]
    assert crack["goal"] == "<= 1.3" and crack["measured"] > 0 and crack["met"] in ("yes", "no")


def test_basis_cost_variants_name_solver_keys():
    """basis_cost.py's `basis:key=value` variants: the basis and the nested solver keys they set (values read as
    YAML), which the block's config takes as it is."""
    bc = load("basis_cost")
    assert bc.solver_options("quadratic") == ("quadratic", {})
    assert bc.solver_options("ddmp:ddmp.sub_points=true:ddmp.fold_below=0.1") == (
        "ddmp", {"ddmp": {"sub_points": True, "fold_below": 0.1}})
    cfg = bc.block(2, "ddmp:ddmp.sub_points=true", 0.1)
    assert cfg["solver"]["basis"] == "ddmp" and cfg["solver"]["ddmp"] == {"sub_points": True}
    import taichi_mpm as tm
    assert tm.load_config(cfg).solver.ddmp.sub_points is True
