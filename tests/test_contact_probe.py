"""The contact probe (output.probes type `contact`): the force the other bodies exert on a body. Two blocks
stacked on a slip floor under gravity: once settled, the lower block carries the upper one's weight, and in every
interval the two contact forces are equal and opposite (Newton's third law: the grid exchange conserves
momentum) once the floor's force on the lower block is taken out."""
import numpy as np
import pytest

from conftest import make_cfg
from taichi_mpm.io.probes import read_probe
from taichi_mpm.io.runner import Run, Simulation

G = 10.0


@pytest.mark.slow
def test_stacked_blocks_contact_force_is_the_upper_weight(tmp_path):
    c = make_cfg(2, transfer="pic", dx=0.1, lower=[0.3, 0.0], upper=[0.7, 0.3], end_time=1.0, gravity=[0, -G])
    c["bodies"][0]["name"] = "lower"
    c["bodies"].append(dict(name="upper", shape=dict(type="box", lower=[0.3, 0.3], upper=[0.7, 0.5]), material="m"))
    c["domain"]["upper"] = [1.0, 0.8]
    c["output"] = dict(formats=[], every=0.25, probe_every=0.05, probes=[
        dict(name="on_upper", type="contact", body="upper"),
        dict(name="on_lower", type="contact", body="lower"),
        dict(name="floor", type="wall", face="y_min")])
    sim = Simulation(c)
    Run(sim, tmp_path).execute()
    upper_mass = float(sim.scene.mass[sim.scene.body == 1].sum())   # 1000 kg/m^3 x 0.4 x 0.2 = 80 kg/m
    assert upper_mass == pytest.approx(80.0)
    up, low, floor = (read_probe(tmp_path / f"probes/{n}.csv") for n in ("on_upper", "on_lower", "floor"))
    t = up["time [s]"]
    assert np.isnan(up["fy [N/m]"][0]) and len(t) >= 20   # t = 0: no interval yet
    # Newton's third law per interval, to round-off (1e-9 of the weight): the lower block's probe also holds the
    # floor's push (it touches the wall), which the floor probe measures
    on_lower_from_upper = low["fy [N/m]"][1:] - floor["fy [N/m]"][1:]
    assert on_lower_from_upper == pytest.approx(-up["fy [N/m]"][1:], abs=1e-9 * upper_mass * G)
    # settled (PIC damps the drop's ringing): over the last half second the lower block pushes the upper one up
    # with its weight, 800 N/m, within 1 % (measured 803.1: the rest is the upper block's remaining momentum change)
    dt = np.diff(t)
    late = t[1:] > 0.5 + 1e-9
    mean = np.sum(up["fy [N/m]"][1:][late] * dt[late]) / np.sum(dt[late])
    assert mean == pytest.approx(upper_mass * G, rel=0.01)
    assert np.abs(up["fx [N/m]"][1:]).max() < 1e-6 * upper_mass * G   # symmetric stack: no sideways push
