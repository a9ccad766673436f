"""USF, update stress first (solver.update: usf, issue 28; Bardenhagen 2002), beside USL and MUSL: F and the
stress from the node velocities before forces, then the forces of the new stress, then velocities and positions.

Bardenhagen's vibrating bar (fixed-fixed, quadratic, FLIP, 2 particles per cell, t = 2.5), measured:
  E/E0 at 32 cells, dt 0.1 dx/c:  usl 0.99971  musl 0.99984  usf 1.00009 (USL dissipates, USF gains a little)
  rms error, dt 0.05 dx/c, 8/16/32 cells:  usl 6.39e-3 1.73e-3 4.36e-4 (rate 1.94)
                                           usf 4.28e-3 6.38e-4 1.17e-4 (rate 2.60)
  at dt 0.1 dx/c USF's error stops falling (1.2e-3 at 16 cells, 8.5e-4 at 32; docs/transfers.md).
"""
import numpy as np
import pytest

import taichi_mpm as tm
import taichi_mpm.analytic as an


def bar(update, cells, dt_factor):
    pr = an.make_problem({"type": "vibrating_bar"})
    dx = pr.L / cells
    sim, e = an.run_problem(pr, {"domain.dx": dx, "solver.basis": "quadratic", "solver.transfer": "flip",
                                 "solver.flip_blend": 1.0, "solver.dt": dt_factor * dx / pr.c,
                                 "solver.update": update})
    en = sim.energy()
    e0 = 0.5 * pr.rho * pr.v0 ** 2 * pr.L / 2      # the first mode's energy, all kinetic at t = 0
    return (en["kinetic"] + en["strain"]) / e0, e["error_rms"]


@pytest.mark.slow
def test_usf_keeps_the_bar_energy_better_than_usl():
    ratio_usf, err_usf = bar("usf", 32, 0.1)
    ratio_usl, err_usl = bar("usl", 32, 0.1)
    assert ratio_usl == pytest.approx(0.99971, abs=5e-5)
    assert ratio_usf == pytest.approx(1.00009, abs=5e-5)
    assert abs(ratio_usf - 1) < 0.5 * abs(ratio_usl - 1)
    assert err_usf < 1e-3                            # amplitude v0 / omega = 0.08


@pytest.mark.slow
def test_usf_converges_on_the_vibrating_bar():
    cells = [8, 16, 32]
    errs = [bar("usf", n, 0.05)[1] for n in cells]
    assert all(a > b for a, b in zip(errs, errs[1:]))
    rate = -np.polyfit(np.log(cells), np.log(errs), 1)[0]
    assert rate > 2.2                                # measured 2.60
    assert errs[-1] < 0.5 * bar("usl", 32, 0.05)[1]  # measured 1.17e-4 against 4.36e-4


def test_usf_conserves_linear_momentum():
    from test_conservation import moving_block

    m0, m1, scale = moving_block(2, "quadratic", "apic", update="usf")
    assert np.abs(m1["linear"] - m0["linear"]).max() < 1e-10 * scale
    assert np.abs(m0["linear"]).max() > 0.02 * scale


def test_usf_is_refused_with_fbar(cfg_factory):
    cfg = cfg_factory(update="usf", volumetric="fbar")
    with pytest.raises(tm.ConfigError, match="solver.update") as e:
        tm.load_config(cfg)
    assert "fbar" in str(e.value)
    assert tm.load_config(cfg_factory(update="usf")).solver.update == "usf"
