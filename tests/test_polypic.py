"""PolyPIC (solver.transfer: polypic; Fu et al. 2017): G2P fits each particle's stencil velocities with polynomial
modes orthogonal under its weights, P2G maps that polynomial. Checked against what holds independently of the code:
a grid field in the span of the modes survives a transfer round trip exactly (APIC keeps only its affine part), the
full mode set interpolates (a field the total-degree set lacks survives only with `full`), linear momentum to
round-off (uniform B-splines of degree p have constant moments up to p), angular momentum nearly, a checkpoint
continues the run, and the combinations it cannot make are refused."""
import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm.step import polynomial
from conftest import fast_subset, make_cfg
from test_conservation import moving_block


def wave_kept(transfer: str, modes: str = "total", across: bool = False, steps: int = 100) -> float:
    """A shear wave v_x = sin(k y) (times sin(k x) with `across`) of wavelength 4 cells in a block at rest in a free
    domain, carried through `steps` transfer round trips with nothing else acting (dt = 1e-12 s, E = 1e-6 Pa, no
    gravity): its amplitude after them over after the first, on particles at least four cells inside the block."""
    solver = {"polypic_modes": modes} if transfer == "polypic" else {}
    cfg = make_cfg(basis="quadratic", transfer=transfer, E=1e-6, dx=0.05, lower=[0.2, 0.2], upper=[0.8, 0.8],
                   boundaries="free", gravity=[0.0, 0.0], **solver)
    sim = tm.Simulation(cfg)
    x = sim.scene.x
    k = 2 * np.pi / 0.2
    v = np.zeros_like(x)
    v[:, 0] = np.sin(k * x[:, 1]) * (np.sin(k * x[:, 0]) if across else 1.0)
    sim.set_particles(v=v)
    inside = np.all((x > 0.2 + 4 * 0.05) & (x < 0.8 - 4 * 0.05), axis=1)
    sim.step(1e-12)
    first = np.abs(sim.particles()["v"][inside, 0]).max()
    for _ in range(steps):
        sim.step(1e-12)
    return float(np.abs(sim.particles()["v"][inside, 0]).max() / first)


def test_polypic_carries_a_wave_its_stencil_resolves_without_loss(monkeypatch):
    """Along y the wave's node values lie in the span of 1, y, y^2 on each particle's three nodes, so the fit
    interpolates them and every round trip gives the grid back: without the top modes' ridge, amplitude kept to
    round-off over 100 round trips (measured 1 + 1e-14). With it (the default, step/polynomial.py) the y^2 mode is
    fitted slightly short each trip: measured 1 - 1.03e-4 in 100 round trips (the loss is proportional to the ridge:
    1.03e-3 at 1e-6, 1.03e-5 at 1e-8); the bounds fail if the ridge is gone (round-off) or ten times larger (APIC
    keeps 0.114 of the wave, PIC 0.036)."""
    kept = wave_kept("polypic")
    assert 1e-5 < 1.0 - kept < 1e-3
    assert wave_kept("apic") < 0.2
    monkeypatch.setattr(polynomial, "TOP_MODE_RIDGE", 1e-30)   # none, but 0 / 0 where a norm vanishes
    assert wave_kept("polypic") == pytest.approx(1.0, abs=1e-12)


@pytest.mark.slow
def test_full_modes_interpolate_the_stencil(monkeypatch):
    """sin(k x) sin(k y) needs the modes x^2 y, x y^2, x^2 y^2 too: without the ridge the full set keeps it (measured
    1 + 2e-10 after 100 round trips), the total-degree set loses most of it (0.082; APIC 0.047). With the ridge the
    full set keeps 0.9976 (measured): its top modes include x^2 y^2, whose norm is the smallest."""
    assert 0.99 < wave_kept("polypic", "full", across=True) < 1.0 - 1e-4
    assert wave_kept("polypic", "total", across=True) < 0.2
    monkeypatch.setattr(polynomial, "TOP_MODE_RIDGE", 1e-30)   # none, but 0 / 0 where a norm vanishes
    assert wave_kept("polypic", "full", across=True) == pytest.approx(1.0, abs=1e-8)


@pytest.mark.parametrize("modes", fast_subset(["total", "full"], ["total"]))
def test_polypic_momenta(modes):
    """test_conservation's drifting, spinning, breathing block (quadratic, usl, 20 steps): linear momentum to
    round-off; angular momentum, counted as P2G maps it (m sum w x_i x v(x_i): step/diagnostics.py), drifts by
    1.5e-5 (total) and 1.3e-5 (full) of itself (measured): the cubic moments sum w r x v(r) of a quadratic field vary
    with the particle's position, so the move changes them (APIC 1e-15, TPIC 1.1e-4, PIC loses 79 %)."""
    m0, m1, scale = moving_block(2, "quadratic", "polypic", "usl", polypic_modes=modes)
    assert np.abs(m1["linear"] - m0["linear"]).max() < 1e-10 * scale
    assert np.abs(m0["linear"]).max() > 0.02 * scale
    assert abs(m1["angular"] - m0["angular"]).max() < 1e-4 * np.abs(m0["angular"]).max()


def test_checkpoint_continues_the_run():
    """get_state holds the modes; set back to it, the run steps to the same particles (same process: round-off)."""
    cfg = make_cfg(basis="quadratic", transfer="polypic", dx=0.05, lower=[0.35, 0.35], upper=[0.65, 0.65],
                   boundaries="free")
    sim = tm.Simulation(cfg)
    sim.set_particles(v=0.3 * np.sin(5 * sim.scene.x))
    for _ in range(5):
        sim.step()
    state = sim.get_state()
    assert state["polypic_c"].shape == (sim.n, 6, 2) and state["polypic_g"].shape == (sim.n, 2, 3)
    for _ in range(5):
        sim.step()
    after = sim.particles()
    sim.set_state(state)
    for _ in range(5):
        sim.step()
    for key in ("x", "v", "F"):
        assert np.abs(sim.particles()[key] - after[key]).max() < 1e-12, key
    with pytest.raises(ValueError, match="polypic_c"):
        sim.set_state(dict(state, polypic_c=state["polypic_c"][:, :3]))


@pytest.mark.parametrize("change, key", [
    (lambda c: c.update(crack={}), "solver.transfer"),
    (lambda c: c["solver"].update(basis="gimp"), "solver.transfer"),
    (lambda c: c.update(dim=3) or c["solver"].update(basis="cubic", polypic_modes="full"), "solver.polypic_modes"),
    (lambda c: c["solver"].update(transfer="apic", polypic_modes="full"), "solver.polypic_modes"),
])
def test_polypic_refusals(cfg_factory, change, key):
    """The crack finder's transfers are PIC, FLIP and APIC's; gimp's weights do not reproduce the modes; 3D cubic's
    64 full modes are not built; polypic_modes with another transfer is read by nothing."""
    cfg = cfg_factory(transfer="polypic")
    assert tm.load_config(cfg).solver.transfer == "polypic"
    change(cfg)
    if cfg["dim"] == 3:
        cfg["domain"].update(lower=[0.0] * 3, upper=[1.0] * 3)
        cfg["bodies"][0]["shape"].update(lower=[0.3] * 3, upper=[0.6] * 3)
    with pytest.raises(tm.ConfigError, match=key):
        tm.load_config(cfg)
