"""Adding an output field is one registration (fields.register; docs/architecture.md "Adding an output field"):
a kinetic energy density registered from the test folder is accepted by config validation (output.fields and
output.render.color_by), written to the VTU snapshots of a short run, read back with the values it must have, offered
as a colour field by the renderer and the window, and refused again once unregistered."""
import numpy as np
import pytest
import yaml

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm import fields
from taichi_mpm.cli import main
from taichi_mpm.io import files as io
from taichi_mpm.io.render import field_values
from taichi_mpm.io.render_options import color_fields, window_fields

NAME = "kinetic_energy_density"
V0 = [0.5, 0.2]
RHO = 1000.0


def kinetic_energy_density(p: dict) -> np.ndarray:
    """0.5 rho |v|^2, rho = m / V (current volume)."""
    v = np.asarray(p["v"], float)
    return 0.5 * np.asarray(p["mass"], float) / np.asarray(p["volume"], float) * np.einsum("ni,ni->n", v, v)


@pytest.fixture
def registered():
    field = fields.register(NAME, "J/m^3", "kinetic energy per unit current volume, 0.5 rho |v|^2",
                            kinetic_energy_density, needs=["v", "mass", "volume"])
    try:
        yield field
    finally:
        fields.unregister(NAME)


def scene(**output) -> dict:
    data = make_cfg(2, velocity=V0, density=RHO, end_time=0.01, boundaries="free")
    data["output"] = dict(formats=["vtu"], every=0.005, **output)
    return data


def test_a_registered_field_is_accepted_written_and_read_back(registered, tmp_path):
    data = scene(fields=[NAME, "mass", "volume"], render=dict(color_by=NAME))
    cfg = tm.load_config(data)
    assert cfg.output.fields[0] == NAME and cfg.output.render.color_by == NAME
    assert NAME in tm.config.output_fields() and NAME in color_fields()
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    files = sorted(out.glob("particles_*.vtu"))
    assert len(files) == 3
    first = io.read_vtu(files[0], dim=2)
    # at t = 0 every particle moves at V0 in an undeformed body: 0.5 x 1000 x (0.25 + 0.04) = 145 J/m^3
    np.testing.assert_allclose(first[NAME], 0.5 * RHO * np.dot(V0, V0), rtol=1e-12)
    for f in files:
        back = io.read_vtu(f, dim=2)
        expected = kinetic_energy_density({"v": back["velocity"], "mass": back["mass"], "volume": back["volume"]})
        np.testing.assert_allclose(back[NAME], expected, rtol=1e-12)
        assert back[NAME].shape == (len(back["x"]),)
    # a colour field of frames and of the window, computed from the live particle dict
    sim = tm.Simulation(cfg)
    p = sim.particles()
    np.testing.assert_allclose(field_values(p, NAME, 2), kinetic_energy_density(p), rtol=1e-12)
    assert NAME in window_fields(p, 2) and window_fields(p, 2)[0] == "speed"


def test_registration_rules_and_unregistering(registered):
    with pytest.raises(ValueError, match="already registered"):
        fields.register(NAME, "J/m^3", "again", kinetic_energy_density)
    with pytest.raises(ValueError, match="built-in"):
        fields.unregister("speed")
    with pytest.raises(ValueError, match="kind"):
        fields.register("odd", "1", "a field of an unknown kind", kinetic_energy_density, kind="cloud")
    fields.unregister(NAME)
    try:
        assert NAME not in color_fields()
        with pytest.raises(tm.ConfigError, match=f"unknown output field '{NAME}'") as e:
            tm.load_config(scene(fields=[NAME]))
        assert e.value.key == "output.fields.0"
        with pytest.raises(tm.ConfigError) as e:
            tm.load_config(scene(render=dict(color_by=NAME)))
        assert e.value.key == "output.render.color_by"
    finally:   # the fixture unregisters it again
        fields.register(NAME, "J/m^3", "kinetic energy density", kinetic_energy_density, needs=["v", "mass", "volume"])
