"""A viscous stress with an affine transfer (APIC) reads the grid's velocity gradient, kept per particle in its own
field (grad_v), not APIC's C_p = B_p D_p^-1: the latter fits the grid velocities in least squares and differs from
their gradient wherever the field is not linear, and a viscous stress read from it does not dissipate the energy
the grid's forces take out (the slow Couette test in test_mapped.py measures the balance)."""
import numpy as np
import pytest
import taichi_mpm as tm
from conftest import make_cfg


def _shear_cfg(transfer):
    """A viscous fluid block in the shear flow v_x = 0.1 sin(2 pi y / 0.3) (not linear: APIC's fit and the grid
    gradient differ), f64, quadratic."""
    cfg = make_cfg(2, model="fluid", transfer=transfer, dx=0.05, boundaries="free")
    cfg["materials"]["m"]["viscosity"] = 1.0
    return cfg


def _start(transfer):
    sim = tm.Simulation(_shear_cfg(transfer))
    x = sim.particles()["x"]
    v = np.zeros_like(x)
    v[:, 0] = 0.1 * np.sin(2 * np.pi * x[:, 1] / 0.3)
    sim.set_particles(v=v)
    sim.step()
    return sim


def test_apic_viscous_stress_reads_the_grid_gradient_not_the_affine_fit():
    """After one step from C = 0, APIC's and PIC's P2G are the same, so the grid velocities are: APIC's grad_v must
    equal PIC's velocity gradient (PIC keeps it in C) to round-off, and differ from APIC's own C_p (its fit), by
    a measured 0.09 of the gradient's size here; a grad_v read from C_p would fail the first assertion by as much."""
    state = _start("apic").get_state()   # (one live Simulation at a time)
    pic = _start("pic").get_state()
    assert "grad_v" in state and "grad_v" not in pic
    gradient = pic["C"]
    size = np.abs(gradient).max()
    assert np.abs(state["grad_v"] - gradient).max() < 1e-12 * size
    fit = state["C"] * 4.0 / 0.05 ** 2   # C holds B_p; quadratic's D_p = dx^2 / 4 I away from walls
    assert np.abs(fit - gradient).max() > 0.05 * size


def test_grad_v_is_part_of_the_state_a_resume_restores():
    sim = _start("apic")
    saved = sim.get_state()
    sim.step()
    assert np.abs(sim.get_state()["grad_v"] - saved["grad_v"]).max() > 0
    sim.set_state(saved)
    assert np.array_equal(sim.get_state()["grad_v"], saved["grad_v"])


@pytest.mark.slow
def test_a_resumed_viscous_apic_run_continues_bit_for_bit(tmp_path):
    """solver.deterministic: 12 steps in one go against 6, a checkpoint file and 6 more in a new Simulation. The
    checkpoint carries grad_v: resumed without it (the field's zeros), the first step's viscous stress differs and
    so do the states (asserted too, so that the comparison can fail)."""
    from taichi_mpm.io import files as io

    cfg = _shear_cfg("apic")
    cfg["solver"]["deterministic"] = True

    def started():
        sim = tm.Simulation(cfg)
        x = sim.particles()["x"]
        v = np.zeros_like(x)
        v[:, 0] = 0.1 * np.sin(2 * np.pi * x[:, 1] / 0.3)
        sim.set_particles(v=v)
        return sim

    whole = started()
    for _ in range(12):
        whole.step()
    end = {k: whole.particles()[k] for k in ("x", "v", "F")}
    part = started()
    for _ in range(6):
        part.step()
    io.save_checkpoint(tmp_path / "checkpoint.npz", part.get_state(), {"config": cfg})
    for keep in (True, False):
        saved = io.load_checkpoint(tmp_path / "checkpoint.npz")[0]
        if not keep:
            saved.pop("grad_v")
        resumed = tm.Simulation(cfg)
        resumed.set_state(saved)
        for _ in range(6):
            resumed.step()
        same = all(np.array_equal(resumed.particles()[k], end[k]) for k in end)
        assert same == keep, keep
