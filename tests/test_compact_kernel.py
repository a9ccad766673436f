"""CK-MPM's compact kernel (solver.basis: ck, taichi_mpm/bases/compact_kernel.py), f64: the stencil identities on
the two staggered grids (walls included), conservation, and (slow) the manufactured solutions and the trade against
quadratic B-splines (docs/bases.md, "CK-MPM")."""
import numpy as np
import pytest

import taichi_mpm as tm
from conftest import fast_subset, make_cfg
import test_conservation as tcons   # module objects: their tests are not collected again here
import test_cpdi as tcp
import test_crack as tcr
import test_fbar as tfb


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_stencil_identities_on_both_grids(dim):
    """Partition of unity, linear reproduction, zero gradient sum, sum x_i (x) grad w = I (each grid alone misses
    the last two by up to 1/pi: only their average is exact) and D_p's closed form against the node sum, to 1e-12 at
    random positions and on and next to the walls, where B's ghost node lies half a cell beyond."""
    sim = tm.Simulation(make_cfg(dim, basis="ck", dx=0.25, extent=1.0, lower=[0.0] * dim, upper=[1.0] * dim,
                                 boundaries="free"))
    rng = np.random.default_rng(dim)
    x = rng.uniform(0.0, 1.0, (sim.n, dim))
    x[:5] = [[0.0] * dim, [1.0] * dim, [1e-9] * dim, [0.999] * dim, [0.125] * dim]
    sim.set_particles(x=x)
    assert tcp.stencil_sums(sim).max() < 1e-12


def test_nodes_are_a_cell_apart_on_each_grid():
    """A particle weights 2 nodes per axis on each grid, a cell apart, A's on the cell corners and B's on the
    centres (storage index k at (k - 1) / 2 cells): 2 x 2^d contributions, the grid 2 n + 3 nodes per axis."""
    sim = tm.Simulation(make_cfg(2, basis="ck", dx=0.25, extent=1.0, boundaries="free"))
    assert sim.basis.nodes(4) == 11 and sim.basis.contributions(2) == 8 and sim.ctx.stencil.count == 8
    assert [sim.basis.coord_py(k, 4) for k in (0, 1, 2, 9, 10)] == [-0.5, 0.0, 0.5, 4.0, 4.5]


@pytest.mark.parametrize("transfer", fast_subset(["flip", "apic", "mls"], ["apic"]))
def test_moving_block_keeps_momentum(transfer):
    """tests/test_conservation.py's drifting, spinning, breathing block: linear momentum to round-off, and with
    APIC's B_p D_p^-1 (D_p a full matrix here, never singular: MLS takes ck) the angular momentum too."""
    m0, m1, scale = tcp.moving_block(basis="ck", transfer=transfer)
    assert np.abs(m1["linear"] - m0["linear"]).max() < 1e-10 * scale
    if transfer != "flip":
        assert abs(m1["angular"][2] - m0["angular"][2]) < 1e-10 * abs(m0["angular"][2])


@pytest.mark.slow
def test_apic_spinning_disk_keeps_its_angular_momentum():
    """The spinning disk of tests/test_conservation.py, 200 steps."""
    L0, L1 = tcons.spinning_disk("ck", "usl", steps=200)
    assert L0 > 1.0 and abs(L1 - L0) < 1e-10 * abs(L0)


@pytest.mark.slow
def test_crack_finder_separates_interface_blocks():
    """tests/test_crack.py's two interface blocks pulled apart at +-0.2 m/s (2D, 30 steps, threshold 0): each
    keeps its velocity (measured -0.2000 / +0.2000, as quadratic) and the gap opens."""
    sim, p, b, gaps, t, smax = tcr._pull(tcr.blocks_cfg(2, basis="ck", crack=True, threshold=0.0), steps=30)
    va, vb = p["v"][b == 0, 0].mean(), p["v"][b == 1, 0].mean()
    assert abs(va + 0.2) < 0.01 * 0.2 and abs(vb - 0.2) < 0.01 * 0.2, (va, vb)
    assert gaps[-1] > 0.08


@pytest.mark.slow
def test_crack_finder_precracked_bar():
    """tests/test_crack.py's pre-cracked bar: pulled open, 2.9 % of the uncracked stress crosses the crack
    (quadratic 1.8 %; with the support radius of a 2-cell stencil, as ck's window of 4 half-cell nodes was first
    read, 8.1 %); pushed closed, the crack carries 0.93 of the uncracked compression."""
    tcr.test_precracked_bar_in_tension("ck")
    tcr.test_closed_crack_in_compression("ck")


@pytest.mark.slow
def test_fbar_on_the_linear_grid_keeps_volume():
    """F-bar averages the volume change on the linear grid (registry fbar_linear_grid), as for quadratic:
    test_fbar.py's check that the averaging keeps the total volume, 2D APIC f64."""
    tfb.test_every_option_runs_and_keeps_volume(2, "ck", "apic", "usl", "f64", True, "neo_hookean")


@pytest.mark.slow
def test_fbar_block_at_rest_at_nu_04999_is_smooth_and_hydrostatic():
    """test_fbar.py's block settling under gravity at nu = 0.4999 (PIC, 3000 steps, CFL 0.5: ck's largest stable
    CFL is below quadratic's): measured row-to-row pressure 0.012 rho g H (quadratic 0.017), sigma_yy within 2.8 %
    of the weight above. Averaged on ck's own nodes instead, the rows zig-zagged by 0.059."""
    heights, p, syy, ke = tfb.resting_block("fbar", basis="ck", steps=3000, cfl=0.5)
    rho_g_h = tfb.RHO * tfb.G * tfb.H
    assert ke < 1e-6 * tfb.RHO * tfb.W * tfb.H * tfb.G * tfb.H
    assert tfb.row_oscillation(p) < 0.05 * rho_g_h
    assert np.abs(syy - tfb.RHO * tfb.G * (tfb.H - heights)).max() < 0.05 * rho_g_h


def mms_errors(cells, amplitude, **problem):
    """test_cpdi.py's 1D manufactured-solution errors with ck (the problem's own transfer, FLIP, unless given)."""
    return np.array(tcp.mms_errors(1, amplitude, cells, basis="ck", **problem))


@pytest.mark.slow
def test_sticky_walls_keep_second_order():
    """The 1D manufactured solution at G = 0.001 between sticky walls, 2 particles per cell. B has no node on a
    wall; its ghost beyond it is the image of the node inside (compact_kernel.make_ghost_images). Measured 16/32
    cells: 2.27e-5, 5.59e-6 (64, 128: 1.37e-6, 3.35e-7, rate 2.03; quadratic 6.87e-7 at 128). With the ghost under
    the node-wise wall condition instead: 2.60e-4, 1.61e-4 (rate 0.72, first order: the wall's velocity
    interpolated to a quarter of B's first node's); with the ghost's velocity mirrored but not its sums folded:
    1.23e-4, 6.0e-5 (rate 1.0)."""
    e = mms_errors([16, 32], 0.001)
    assert e[1] < 7e-6 and e[0] / e[1] > 3.5, e


@pytest.mark.slow
def test_large_amplitude_stalls_like_the_point_integrated_bases():
    """G = 0.05 (particles cross cells), 2 particles per cell: measured 1.23e-3 6.65e-4 3.95e-4 5.27e-4 at 16-128
    cells, below quadratic's error at 16 and 32 (2.11e-3, 5.80e-4) and above it from 64 on (1.73e-4, 1.01e-4): the
    kernel's gradient, 1 - cos(2 pi t) across a cell, makes the particles' quadrature of the force coarser than a
    B-spline's once they are unevenly spaced (docs/bases.md, "CK-MPM")."""
    e = mms_errors([16, 32, 64, 128], 0.05)
    assert e[0] < 1.5e-3 and e[1] < 8e-4 and e.max() < 2e-3, e


def spinning_disk_energy(basis, transfer="apic"):
    """A free elastic disk (r 0.2 m, E 1e4 Pa, dx 1/32) spinning at 2 rad/s, one revolution: the fraction of its
    energy kept and of its angular momentum."""
    cfg = make_cfg(2, basis=basis, transfer=transfer, dx=1 / 32, E=1e4, boundaries="free", energy_growth_limit=None)
    cfg["bodies"][0]["shape"] = dict(type="sphere", center=[0.5, 0.5], radius=0.2)
    cfg["bodies"][0]["angular_velocity"] = 2.0
    cfg["solver"]["gravity"] = [0.0, 0.0]
    sim = tm.Simulation(cfg)
    e0, L0 = sim.energy_balance()["total"], sim.momentum()["angular"][2]
    while sim.time < np.pi:
        sim.step()
    return sim.energy_balance()["total"] / e0, sim.momentum()["angular"][2] / L0


@pytest.mark.slow
def test_apic_dissipates_less_than_the_wider_b_splines():
    """The kernel's claim (less numerical diffusion than quadratic B-splines): energy kept after one revolution,
    measured ck 0.9768, quadratic 0.9527, cubic 0.9380 (angular momentum kept to 1e-6 by all three; PIC keeps
    1e-4 of the energy with any of them)."""
    ck, L = spinning_disk_energy("ck")
    quadratic, _ = spinning_disk_energy("quadratic")
    assert abs(L - 1.0) < 1e-6
    assert 1.0 - ck < 0.6 * (1.0 - quadratic), (ck, quadratic)


@pytest.mark.slow
def test_wall_probe_counts_both_grids():
    """A block settling on a sticky floor under gravity (2D, E 1e5 Pa, APIC), the floor's wall probe averaged over
    0.5-1 s: its force is the block's weight, A's wall nodes giving one share through the node-wise condition and
    the folding of B's ghosts the other (measured 1.020 of the weight; quadratic 1.027; before the fold was
    measured, 0.507)."""
    cfg = make_cfg(2, basis="ck", boundaries="sticky", E=1e5, lower=[0.3, 0.0], upper=[0.6, 0.3], dx=0.05)
    cfg["output"] = dict(probes=[dict(name="floor", type="wall", face="y_min")])
    cfg["solver"]["gravity"] = [0.0, -9.81]
    sim = tm.Simulation(cfg)
    while sim.time < 0.5:
        sim.step()
    sim.wall_impulse(reset=True)
    t0 = sim.time
    while sim.time < 1.0:
        sim.step()
    force = sim.wall_impulse(reset=True)[2, 1] / (sim.time - t0)
    assert abs(force / (sim.scene.mass.sum() * 9.81) - 1.0) < 0.05


@pytest.mark.slow
def test_large_amplitude_converges_with_4_particles_per_cell_and_mls():
    """The stall above is the particles' quadrature: with 4 particles per cell and MLS, measured 3.89e-4 9.82e-5
    2.56e-5 8.43e-6 (rate 1.85; FLIP 1.52)."""
    cells = [16, 32, 64, 128]
    e = mms_errors(cells, 0.05, transfer="mls", particles_per_cell=4)
    rate = -np.polyfit(np.log(cells), np.log(e), 1)[0]
    assert rate >= 1.75 and e[-1] < 1.2e-5, (e, rate)
