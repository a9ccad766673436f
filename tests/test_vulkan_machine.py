"""A user's machine with Mesa's Vulkan drivers and no GPU (the default on Ubuntu desktops; `apt-get install
mesa-vulkan-drivers` gives the CPU renderer llvmpipe): the README's first command and every bundled demo run
with the configs' `arch: auto`, which there must not pick the emulated GPU (issue 30). Slow (pytest -m slow): the
README's demo in full, every other demo for a few steps. Installs nothing: skipped where no Vulkan device answers."""
import os
import shutil
import subprocess
import sys

import pytest

from taichi_mpm import backend
from taichi_mpm.cli import demos

pytestmark = pytest.mark.slow


def vulkan_or_skip():
    device = backend.vulkan_device()
    if device is None or "vulkan" not in backend.available_archs():
        pytest.skip("no Vulkan device answers here (apt-get install mesa-vulkan-drivers gives llvmpipe)")
    return device


def taichi_mpm(*args, cwd, timeout=1800):
    """The installed command, as the README runs it (the console script, else python -m taichi_mpm)."""
    exe = shutil.which("taichi-mpm")
    cmd = [exe] if exe else [sys.executable, "-m", "taichi_mpm"]
    return subprocess.run([*cmd, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env=dict(os.environ, PYTHONWARNINGS="default"))


def expected_note(device) -> str | None:
    """What auto says here: it passes over an emulated GPU (unless CUDA is found first)."""
    if "cuda" in backend.available_archs() or not device.emulated:
        return None
    return f"arch auto: cpu; vulkan skipped ({device.name} is a CPU-emulated GPU"


def test_readme_demo_runs_where_mesa_vulkan_is_installed(tmp_path):
    """`taichi-mpm demo sphere_impact`, the README's first command, to its end: frames and the movie."""
    device = vulkan_or_skip()
    r = taichi_mpm("demo", "sphere_impact", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Traceback" not in r.stderr and "Pointer SNode" not in r.stderr
    note = expected_note(device)
    if note:
        assert note in r.stderr
    run = tmp_path / "runs" / "sphere_impact"
    assert (run / "movie.mp4").stat().st_size > 0 and len(list((run / "frames").glob("*.png"))) > 10


@pytest.mark.parametrize("name", sorted(demos()))
def test_every_demo_runs_where_mesa_vulkan_is_installed(tmp_path, name):
    """Each bundled demo, a few steps with its outputs, on the backend `arch: auto` picks here."""
    device = vulkan_or_skip()
    r = taichi_mpm("demo", name, "--set", "solver.max_steps=3", "--set", "output.formats=[vtu]", "--quiet",
                   "--out", tmp_path / "run", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Traceback" not in r.stderr
    note = expected_note(device)
    if note:
        assert note in r.stderr
    assert list((tmp_path / "run").rglob("*.vtu"))
