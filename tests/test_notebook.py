"""docs/sandbox.ipynb: its cells run (they are docs/build_sandbox_notebook.py's CELLS) and the committed notebook
holds exactly those cells with their pictures."""
import json
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs"))

from build_sandbox_notebook import CELLS, run_cells  # noqa: E402


def test_committed_notebook_matches_its_cells_and_is_small():
    nb = json.loads((ROOT / "docs" / "sandbox.ipynb").read_text())
    assert ["".join(c["source"]) for c in nb["cells"]] == [source for _, source in CELLS]
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    assert all(c["outputs"] for c in code)                       # committed with its outputs
    assert sum("image/png" in o.get("data", {}) for c in code for o in c["outputs"]) >= 2   # frames and a study
    assert (ROOT / "docs" / "sandbox.ipynb").stat().st_size < 600_000   # readable on GitHub


@pytest.mark.slow
def test_notebook_cells_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)                                   # its comparison goes to runs/ here
    (tmp_path / "configs").symlink_to(ROOT / "configs")
    outputs = run_cells()
    pictures = [o for out in outputs if out for o in out if "image/png" in o.get("data", {})]
    assert len(pictures) == 2
    assert (tmp_path / "runs" / "notebook_compare" / "summary.csv").is_file()
