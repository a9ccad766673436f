"""Every file in configs/: each run config validates, builds its scene and runs a few steps; each study file
(configs/studies) validates with every case's config. Compiling a config's kernel set costs 5-30 s on the shared
2-core machine (measured: all 20 configs, 3 steps each, about 400 s), so the default run validates and builds every
config and steps two of them; `pytest -m slow` steps them all."""
from pathlib import Path

import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm.scene import build_scene
from taichi_mpm.tools.study import load_study

from conftest import fast_subset

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted(p.stem for p in (ROOT / "configs").glob("*.yaml"))
STUDIES = sorted(p.stem for p in (ROOT / "configs" / "studies").glob("*.yaml"))
# stepped by the default run: a 1D one and a cheap 2D one (the crack demos step under -m slow: each is ~7 s of
# kernels to compile, and the crack finder has default tests of its own)
FAST = ("vibrating_bar", "snowball")
# particle spacing for the few steps, where the configured one makes a large scene (3D, or fine 2D sand)
COARSE = {"sphere_impact_fracture": 0.05, "sphere_impact": 0.0625, "jelly_drop": 0.05, "granular_collapse_3d": 0.02,
          "twisted_bar": 0.025}


def test_the_lists_are_not_empty():
    assert len(CONFIGS) >= 20 and len(STUDIES) >= 10
    assert set(FAST) <= set(CONFIGS) and set(COARSE) <= set(CONFIGS)


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


@pytest.mark.parametrize("name", fast_subset(CONFIGS, FAST))
def test_config_runs_a_few_steps(name):
    overrides = {"arch": "cpu"}
    if name in COARSE:
        overrides["domain.dx"] = COARSE[name]
    sim = tm.Simulation(tm.load_config(ROOT / "configs" / f"{name}.yaml", overrides=overrides))
    x0 = sim.particles()["x"].copy()
    for _ in range(3):
        dt = sim.step()
        assert dt > 0
    p = sim.particles()
    assert np.isfinite(p["x"]).all() and np.isfinite(p["v"]).all()
    # a few stable steps move no particle further than a cell (the CFL bound keeps it well under)
    assert np.abs(p["x"] - x0).max() < sim.cfg.domain.dx * 2
