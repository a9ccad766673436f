"""The backend choice (backend.py): `arch: auto` never picks a CPU-emulated GPU, a GPU backend without pointer SNodes
gets a dense grid or is skipped with one line saying why, an explicit arch that cannot run the scene is a config
error naming the key. The choice is tested with the machine's probes faked (every kind of machine), and for real on
Mesa's llvmpipe Vulkan where it is installed (`mesa-vulkan-drivers`; .ci/run installs it)."""
import warnings

import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm import budget
from conftest import make_cfg
from taichi_mpm import backend
from taichi_mpm.backend import Backend, BackendNote, VulkanDevice

LLVMPIPE = VulkanDevice("llvmpipe (LLVM 15.0.6, 256 bits)", "cpu", True, True, True)
RADEON = VulkanDevice("AMD Radeon RX 7600 (RADV NAVI33)", "discrete", True, True, True)
NO_F64 = VulkanDevice("Intel(R) Arc(tm) A750 Graphics (DG2)", "discrete", False, True, True)
NO_I8 = VulkanDevice("Some GPU", "integrated", True, True, False)


def machine(monkeypatch, found, device=None):
    """Fake what Taichi and the Vulkan loader find."""
    monkeypatch.setattr(backend, "available_archs", lambda: list(found))
    monkeypatch.setattr(backend, "vulkan_device", lambda: device)


def cfg(arch="auto", **kw):
    c = make_cfg(2, **kw)
    c["arch"] = arch
    return tm.load_config(c)


def test_auto_never_picks_a_cpu_emulated_gpu(monkeypatch):
    machine(monkeypatch, ["vulkan", "cpu"], LLVMPIPE)
    b = backend.choose(cfg())
    assert b == Backend("cpu", True, b.note)
    assert b.note == ("arch auto: cpu; vulkan skipped (llvmpipe (LLVM 15.0.6, 256 bits) is a CPU-emulated GPU, "
                      "slower than Taichi's cpu backend)")
    assert backend.resolve_arch("auto") == "cpu"
    for name in ("SwiftShader Device (Subzero)", "lavapipe"):
        assert VulkanDevice(name, "other", True, True, True).emulated
    assert not RADEON.emulated


def test_auto_on_a_real_gpu_without_sparse_gets_a_dense_grid(monkeypatch):
    machine(monkeypatch, ["vulkan", "cpu"], RADEON)
    b = backend.choose(cfg())
    assert (b.arch, b.sparse) == ("vulkan", False)
    assert b.note == ("arch auto: vulkan with a dense grid (Taichi's vulkan backend has no sparse grids; the run uses "
                      "more memory than with domain.sparse on cpu or cuda)")
    c = cfg()
    c.domain.sparse = False
    assert backend.choose(c) == Backend("vulkan", False, None)   # dense asked for: nothing to say
    assert backend.resolve_arch("auto") == "vulkan"


@pytest.mark.parametrize("device, lacks", [(NO_F64, "no f64 shaders"), (None, "no Vulkan device answers")])
def test_auto_skips_a_gpu_that_cannot_run_the_scene(monkeypatch, device, lacks):
    machine(monkeypatch, ["vulkan", "cpu"], device)
    b = backend.choose(cfg())
    assert b.arch == "cpu" and b.sparse and "vulkan skipped (" in b.note and lacks in b.note


def test_auto_skips_vulkan_when_the_scene_needs_what_the_device_lacks(monkeypatch):
    machine(monkeypatch, ["vulkan", "cpu"], NO_I8)
    two = make_cfg(2)
    two["materials"]["n"] = dict(two["materials"]["m"])
    two["bodies"].append(dict(name="b2", shape=dict(type="box", lower=[0.1, 0.1], upper=[0.2, 0.2]), material="n"))
    two["arch"] = "auto"
    b = backend.choose(tm.load_config(two))
    assert b.arch == "cpu" and "no u8 (several materials) shaders" in b.note
    assert backend.choose(cfg()).arch == "vulkan"   # one material: no u8 field


def test_auto_skips_vulkan_when_the_dense_grid_does_not_fit(monkeypatch):
    machine(monkeypatch, ["vulkan", "cpu"], RADEON)
    c = cfg(dx=0.0005)   # 2000^2 cells: sparse blocks around a small body fit, a dense grid is over the limit
    c.limits.memory_gb = 0.05
    b = backend.choose(c, size_check=lambda c: budget.check(c, warn=False))
    assert b.arch == "cpu" and b.sparse and "the dense grid it would need does not fit" in b.note


def test_auto_says_which_gpu_it_skipped_before_the_one_it_took(monkeypatch):
    machine(monkeypatch, ["vulkan", "metal", "cpu"], NO_F64)
    c = cfg()
    c.domain.sparse = False
    b = backend.choose(c)   # metal is always skipped (no f64): cpu, both skips said
    assert b.arch == "cpu" and "vulkan skipped (the Vulkan device" in b.note and "metal skipped (" in b.note
    machine(monkeypatch, ["vulkan", "cpu"], RADEON)
    assert backend.choose(c) == Backend("vulkan", False, None)


def test_auto_prefers_cuda_and_keeps_its_sparse_grid(monkeypatch):
    machine(monkeypatch, ["cuda", "vulkan", "cpu"], LLVMPIPE)
    assert backend.choose(cfg()) == Backend("cuda", True, None)
    assert backend.choose(cfg("cpu")) == Backend("cpu", True, None)


def test_metal_is_skipped_and_refused(monkeypatch):
    machine(monkeypatch, ["metal", "cpu"])
    b = backend.choose(cfg())
    assert b.arch == "cpu" and "metal skipped (Taichi's metal backend has no f64" in b.note
    with pytest.raises(tm.ConfigError) as e:
        backend.choose(cfg("metal"))
    assert e.value.key == "arch" and "arch metal cannot run this scene" in str(e.value)


def test_explicit_gpu_arch_that_cannot_run_the_scene_is_a_config_error(monkeypatch):
    machine(monkeypatch, ["vulkan", "cpu"], NO_F64)
    with pytest.raises(tm.ConfigError) as e:
        backend.choose(cfg("vulkan"))
    assert e.value.key == "arch"
    assert str(e.value) == ("key 'arch': arch vulkan cannot run this scene: the Vulkan device Intel(R) Arc(tm) A750 "
                            "Graphics (DG2) has no f64 shaders; use arch: auto or cpu")
    machine(monkeypatch, ["vulkan", "cpu"], RADEON)
    c = make_cfg(2)
    c.update(arch="vulkan", crack=dict())   # normal_refresh 0.01 by default
    with pytest.raises(tm.ConfigError) as e:
        backend.choose(tm.load_config(c))
    assert e.value.key == "arch" and "node-normal cache (crack.normal_refresh > 0) needs a sparse grid" in str(e.value)
    b = backend.choose(cfg("vulkan"))   # it can: a dense grid, said in one line
    assert (b.arch, b.sparse) == ("vulkan", False) and b.note.startswith("arch vulkan: a dense grid (Taichi's vulkan")
    c = cfg("vulkan")
    c.domain.sparse = False
    assert backend.choose(c) == Backend("vulkan", False, None)
    machine(monkeypatch, ["vulkan", "cpu"], LLVMPIPE)
    assert "llvmpipe (LLVM 15.0.6, 256 bits) is a CPU-emulated GPU, much slower than arch: cpu" in \
        backend.choose(cfg("vulkan")).note


def test_validate_refuses_an_explicit_arch_that_cannot_run_the_scene(monkeypatch, tmp_path, capsys):
    import yaml

    from taichi_mpm.cli import main

    machine(monkeypatch, ["metal", "cpu"])
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(make_cfg(2)))
    assert main(["validate", str(path), "--arch", "metal"]) == 2
    err = capsys.readouterr().err
    assert "key 'arch'" in err and "arch metal cannot run this scene" in err and "Traceback" not in err


# ---------------------------------------------------------------- on this machine's Vulkan (llvmpipe), if any
def real_vulkan():
    if "vulkan" not in backend.available_archs() or backend.vulkan_device() is None:
        pytest.skip("no Vulkan device here (apt-get install mesa-vulkan-drivers gives llvmpipe)")
    return backend.vulkan_device()


def test_the_probe_answers_on_this_machine():
    """Without Vulkan the probe finds nothing and auto is cpu or cuda; with it, it names the device and its kind."""
    device = backend.vulkan_device()
    if device is None:
        assert backend.resolve_arch("auto") in ("cpu", "cuda")
        return
    assert device.name and device.kind in ("discrete", "integrated", "virtual", "cpu", "other")
    if device.emulated and "cuda" not in backend.available_archs():
        assert backend.resolve_arch("auto") == "cpu"


def test_auto_runs_a_3d_sparse_scene_where_vulkan_is_emulated():
    """The README's class of failure: with llvmpipe and no CUDA, `arch: auto` started Taichi's vulkan backend and the
    sparse grid failed (Pointer SNode is not supported on this backend). Now: cpu, a sparse grid, one note."""
    device = real_vulkan()
    if not device.emulated or "cuda" in backend.available_archs():
        pytest.skip("this machine's Vulkan is a real GPU (or CUDA is here): auto does not pick cpu")
    c = make_cfg(3, dx=0.1, precision="f32")
    c["arch"] = "auto"
    with pytest.warns(BackendNote, match="vulkan skipped .*CPU-emulated GPU"):
        sim = tm.Simulation(c)
    assert sim.backend.arch == "cpu" and sim.grid.sparse
    sim.advance(0.005)
    assert np.isfinite(sim.particles()["x"]).all()


def test_explicit_vulkan_runs_with_a_dense_grid_and_matches_cpu():
    """arch: vulkan on a backend without pointer SNodes: a dense grid, and the same steps as on cpu (f32)."""
    real_vulkan()
    c = make_cfg(2, dx=0.1, precision="f32", velocity=[0.5, -0.3], end_time=0.02)
    c["arch"] = "vulkan"
    with pytest.warns(BackendNote, match="arch vulkan: a dense grid"):
        gpu = tm.Simulation(c)
    assert gpu.backend.arch == "vulkan" and not gpu.grid.sparse
    for _ in range(5):
        gpu.step(1e-3)
    x_gpu = gpu.particles()["x"]
    c["arch"] = "cpu"
    with warnings.catch_warnings():
        warnings.simplefilter("error", BackendNote)   # cpu: nothing to say
        cpu = tm.Simulation(c)
    for _ in range(5):
        cpu.step(1e-3)
    np.testing.assert_allclose(x_gpu, cpu.particles()["x"], atol=1e-5)
