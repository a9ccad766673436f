"""docs/config.md is generated from the schema and must be current; every schema key, output field and diagnostics
column has a unit and a meaning; `validate` prints every key, unset ones as null."""
import re
from pathlib import Path

import yaml

from taichi_mpm.tools import config_reference as ref
from taichi_mpm import fields
from taichi_mpm.io import files as io

DOC = Path(__file__).resolve().parents[1] / "docs" / "config.md"


def test_config_md_is_current():
    assert DOC.read_text() == ref.render(), \
        "docs/config.md is stale: regenerate it with `python -m taichi_mpm.tools.config_reference > docs/config.md`"


def test_every_key_has_a_description():
    keys = ref.keys()
    assert len(keys) == len(set(keys))
    missing = [k for k in keys if k not in ref.DESCRIPTIONS]
    assert not missing, f"schema keys without a description in taichi_mpm/tools/config_reference.py: {missing}"
    stale = [k for k in ref.DESCRIPTIONS if k not in keys]
    assert not stale, f"descriptions of keys the schema no longer has: {stale}"
    for key, (unit, meaning) in ref.DESCRIPTIONS.items():
        assert meaning.strip() and isinstance(unit, str), key


def test_rows_follow_the_schema():
    rows = {r[0]: r for r in ref.walk()}
    assert rows["solver.cfl"][1:4] == ("number", "0.4", "> 0")
    assert rows["solver.basis"][3] == r"linear \| gimp \| quadratic \| cubic \| cpdi \| ddmp \| ck"
    assert rows["solver.dt"][1:3] == ("number or null", "null")
    assert rows["domain.dx"][2] == "required"
    assert rows["domain.boundaries.default"][2] == "slip"
    assert "materials.<name>.E" in rows and "bodies[].shape.radius" in rows
    assert rows["bodies[].shape.radius"][4] == "sphere, cylinder"  # the shape types that have the key
    assert "same keys as `bodies[].shape`" in rows["bodies[].damage_regions[].shape"][4]


def test_output_fields_and_diagnostics_are_documented():
    doc = ref.render()
    for name, f in fields.REGISTRY.items():
        assert f"| `{name}` |" in doc and f.meaning
    for dim in (1, 2, 3):
        for col in io.diagnostics_columns(dim):
            assert re.sub(r"_[yz]$", "_x", col) in ref.DIAGNOSTICS, col


def test_validate_shows_unset_keys_as_null(tmp_path, capsys):
    from taichi_mpm.cli import main

    from conftest import make_cfg

    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(make_cfg(2)))
    assert main(["validate", str(path)]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["solver"]["dt"] is None and printed["crack"] is None
    assert "max_steps" in printed["solver"] and printed["domain"]["boundaries"]["x_min"] is None
