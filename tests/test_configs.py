"""Every file in configs/: each run config validates, builds its scene and runs a few steps (in the default run:
a config that no longer steps is a broken demo); each study file (configs/studies) validates with every case's
config. The steps are mostly compiles: 1.5-11 s per config cold on the shared 2-core machine, ~120 s of test time
for all 26 (docs/performance.md, "Every config stepped in the default run")."""
from pathlib import Path

import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm.scene import build_scene
from taichi_mpm.tools.study import load_study

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted(p.stem for p in (ROOT / "configs").glob("*.yaml"))
STUDIES = sorted(p.stem for p in (ROOT / "configs" / "studies").glob("*.yaml"))
# particle spacing for the few steps, where the configured one makes a large scene (3D, or fine 2D sand)
COARSE = {"sphere_impact_fracture": 0.05, "sphere_impact": 0.0625, "jelly_drop": 0.05, "granular_collapse_3d": 0.02,
          "twisted_bar": 0.025}


def test_the_lists_are_not_empty():
    assert len(CONFIGS) >= 20 and len(STUDIES) >= 10
    assert set(COARSE) <= set(CONFIGS)


@pytest.mark.parametrize("name", CONFIGS)
def test_config_validates_and_builds(name):
    cfg = tm.load_config(ROOT / "configs" / f"{name}.yaml", overrides={"arch": "cpu"})
    assert cfg.name == name
    scene = build_scene(cfg)
    assert scene.n > 0 and np.isfinite(scene.x).all() and np.all(scene.mass > 0)
    assert set(np.unique(scene.body)) == set(range(len(cfg.bodies)))   # every body has particles


@pytest.mark.parametrize("name", STUDIES)
def test_study_validates(name):
    st = load_study(ROOT / "configs" / "studies" / f"{name}.yaml")
    assert st.name == name


@pytest.mark.parametrize("name", CONFIGS)
def test_config_runs_a_few_steps(name):
    overrides = {"arch": "cpu"}
    if name in COARSE:
        overrides["domain.dx"] = COARSE[name]
    sim = tm.Simulation(tm.load_config(ROOT / "configs" / f"{name}.yaml", overrides=overrides))
    x0 = sim.scene.x
    for _ in range(3):
        dt = sim.step()
        assert dt > 0
    # the checkpoint's state (no stress output: its kernels are the output tests', ~0.3 s each to compile here)
    p = sim.get_state()
    assert p["n_steps"] == 3 and np.isfinite(p["x"]).all() and np.isfinite(p["v"]).all()
    # a few stable steps move no particle further than a cell (the CFL bound keeps it well under)
    assert np.abs(p["x"] - x0).max() < sim.cfg.domain.dx * 2
