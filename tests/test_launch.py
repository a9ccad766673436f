"""Tests that do not depend on how pytest was launched (issue 30): the checkout under test is what every test and
every process a test starts imports, whatever an editable install of the environment points at and whichever
folder the process starts in. (Signal state: test_run_folder_trust compares with the state found, never with an
assumed default; the suite is run once under nohup with stdin closed and once from a read-only copy.)"""
import os
import subprocess
import sys
from pathlib import Path

import taichi_mpm

REPO = Path(__file__).resolve().parents[1]


def test_this_process_imports_the_checkout_under_test():
    assert Path(taichi_mpm.__file__).resolve().parent == REPO / "taichi_mpm"


def test_a_process_a_test_starts_elsewhere_imports_the_checkout_under_test(tmp_path):
    """Before: the GGUI and GUI window tests and the thread-count scatter test started `python -c ...` with the
    environment as found, from another folder: it imported the package the environment's editable install points
    at (another checkout: 'cannot import name gui' there), not the code under test."""
    r = subprocess.run([sys.executable, "-c", "import taichi_mpm; print(taichi_mpm.__file__)"], cwd=tmp_path,
                       env=dict(os.environ), capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stderr
    assert Path(r.stdout.strip()).resolve().parent == REPO / "taichi_mpm", r.stdout
