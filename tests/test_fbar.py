"""F-bar against volumetric locking (solver.volumetric: fbar, taichi_mpm/extensions/fbar.py).

Locking test: a nearly incompressible block (nu = 0.4999) released under gravity on a slip floor, free sides,
settles; its pressure, averaged over each particle row, must be smooth. The standard method's rows alternate
(the test sees it, so it can fail) and F-bar's do not. Then: the averaging keeps total volume exactly, leaves a
uniform volume change alone, keeps each particle's isochoric part, and keeps momentum; every basis, transfer,
update, precision and grid storage runs it; 1D is the identity; the config key and its crack conflict."""
import copy

import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm.config import ConfigError, load_config
from conftest import make_cfg

RHO, G, W, H = 1000.0, 10.0, 0.5, 0.25


def resting_block(volumetric, basis="quadratic", nu=0.4999, dx=1 / 16, cfl=0.8, steps=500, transfer="pic",
                  **solver):
    """The block [0.25, 0.75] x [0, H] (8 x 4 cells, 2 particles per cell per axis) in [0, 1] x [0, 0.5],
    PIC (its damping lets it settle), released from rest under gravity.
    Returns the particle rows' heights, mean pressure -tr(sigma)/2 and mean -sigma_yy, and the kinetic energy.
    nu = 0.4999: the shear waves that settle the bulge are 71x slower than the pressure waves (which set dt), so
    settling takes thousands of steps (3000 at dx = 1/16; docs/accuracy.md)."""
    cfg = make_cfg(2, basis=basis, transfer=transfer, dx=dx, E=1e6, nu=nu, density=RHO, lower=[0.5 - W / 2, 0.0],
                   upper=[0.5 + W / 2, H], gravity=[0.0, -G], end_time=1.0, cfl=cfl, volumetric=volumetric, **solver)
    cfg["domain"]["upper"] = [1.0, 0.5]
    sim = tm.Simulation(cfg)
    for _ in range(steps):
        sim.step()
    y0 = np.round(sim.scene.x[:, 1], 9)
    heights = np.unique(y0)
    s = sim.particles()["stress"]
    pressure = -(s[:, 0, 0] + s[:, 1, 1]) / 2
    rows = [y0 == h for h in heights]
    return (heights, np.array([pressure[r].mean() for r in rows]), np.array([-s[r, 1, 1].mean() for r in rows]),
            sim.energy()["kinetic"])


def row_oscillation(p):
    """Largest |second difference| of the row means: zero for a linear profile, 2A for rows alternating by +-A."""
    return np.abs(p[1:-1] - 0.5 * (p[:-2] + p[2:])).max()


@pytest.fixture(scope="module")
def blocks():
    # the standard method locks within 500 steps; F-bar needs 3000 to settle (nu = 0.4999, see resting_block)
    return {"standard": resting_block("standard", steps=500), "fbar": resting_block("fbar", steps=3000)}


@pytest.mark.slow
def test_standard_pressure_alternates_row_by_row(blocks):
    """The check below can fail: measured 0.62 rho g H row to row with the standard method after 500 steps
    (2.25 after 4000, still growing; GIMP at nu = 0.499: 2.8)."""
    heights, p, syy, ke = blocks["standard"]
    assert row_oscillation(p) > 0.2 * RHO * G * H


def test_fbar_pressure_smooth_and_hydrostatic(blocks):
    """nu = 0.4999, dx = 1/16 (4 cells over the height), 3000 steps. Measured: row-to-row 0.017 rho g H (bottom and
    top rows included; 0.014 after 4000 steps), sigma_yy within 3.2 % of rho g H of the weight above. Averaged
    with the quadratic basis itself (before the average moved to the linear grid) the rows zig-zagged by 0.087,
    so the 5 % bound (the issue's) fails for that. At rest every row carries the weight above it, whatever the
    lateral distribution: the row mean of -sigma_yy is rho g (H - y) exactly in equilibrium; 5 % leaves room for
    the particle-row quadrature and the top and bottom rows (the standard method is 45 % off)."""
    heights, p, syy, ke = blocks["fbar"]
    rho_g_H = RHO * G * H
    assert ke < 1e-6 * RHO * W * H * G * H            # settled: kinetic energy below 1e-6 of m g H (measured 2e-8)
    assert row_oscillation(p) < 0.05 * rho_g_H
    assert np.abs(syy - RHO * G * (H - heights)).max() < 0.05 * rho_g_H
    assert np.abs(blocks["standard"][2] - RHO * G * (H - heights)).max() > 0.1 * rho_g_H



@pytest.mark.slow
@pytest.mark.parametrize("transfer, dx, steps", [("pic", 1 / 32, 8000), ("apic", 1 / 16, 3000)])
def test_fbar_smooth_at_nu_04999_fine_grid_and_apic(transfer, dx, steps):
    """The full check: 8 cells over the height (PIC, settled), and APIC, which hardly damps (not settled, so
    only the row-to-row bound). Measured: see docs/accuracy.md "Volumetric locking"."""
    heights, p, syy, ke = resting_block("fbar", transfer=transfer, dx=dx, steps=steps)
    rho_g_H = RHO * G * H
    assert row_oscillation(p) < 0.05 * rho_g_H
    if transfer == "pic":
        assert np.abs(syy - RHO * G * (H - heights)).max() < 0.05 * rho_g_H

# ---------------------------------------------------------------- the averaging step itself
def small_block(dim=2, volumetric="fbar", **kw):
    kw.setdefault("dx", 0.1 if dim == 2 else 0.125)
    cfg = make_cfg(dim, E=1e4, nu=0.45, volumetric=volumetric, lower=[0.3] * dim, upper=[0.7] * dim, **kw)
    return tm.Simulation(cfg)


def volume(sim):
    return float(np.sum(sim.scene.volume * np.linalg.det(sim._read("F"))))


@pytest.mark.slow
def test_uniform_volume_change_left_alone_and_volume_kept():
    sim = small_block()
    rng = np.random.default_rng(0)
    n, d = sim.n, sim.dim
    F0 = np.eye(d) + 0.05 * rng.standard_normal((n, d, d))       # J varies from particle to particle
    sim.set_particles(F=F0)                                       # the step starts from these J
    # a uniform volume change 1.02^2 on top of a varying history: F-bar must not touch it (averaging the total
    # J instead of the step's change would flatten the varying J)
    sim.F.from_numpy(sim._to_solver(1.02 * F0))
    sim.extension("fbar").fbar.apply()
    assert np.abs(sim._read("F") - 1.02 * F0).max() < 1e-12
    # a varying volume change: averaged, total volume kept (partition of unity), isochoric parts kept
    F1 = F0 * (1 + 0.03 * rng.standard_normal(n))[:, None, None]
    sim.F.from_numpy(sim._to_solver(F1))
    before = volume(sim)
    sim.extension("fbar").fbar.apply()
    F2 = sim._read("F")
    J1, J2 = np.linalg.det(F1), np.linalg.det(F2)
    assert abs(volume(sim) - before) < 1e-13 * before
    assert np.abs(J2 - J1).max() > 1e-3                          # it did average
    assert np.std(J2 / np.linalg.det(F0)) < 0.5 * np.std(J1 / np.linalg.det(F0))   # the step's change is smoother
    iso = lambda F, J: F / J[:, None, None] ** (1 / d)
    assert np.abs(iso(F2, J2) - iso(F1, J1)).max() < 1e-12


@pytest.mark.slow
def test_momentum_kept():
    """F-bar changes only F (a scalar factor: Kirchhoff stress stays symmetric), so a drifting, spinning,
    breathing block keeps linear and APIC angular momentum to round-off (standard: 1e-15 relative)."""
    sim = small_block(transfer="apic", boundaries="free")
    X = sim.scene.x
    r = X - 0.5
    v = 0.05 + 0.4 * r + 0.1 * np.sin(7.0 * X)
    v[:, 0] += -0.5 * r[:, 1]
    v[:, 1] += 0.5 * r[:, 0]
    sim.set_particles(v=v)
    m0 = sim.momentum()
    for _ in range(15):
        sim.step()
    m1 = sim.momentum()
    scale = np.sum(sim.scene.mass[:, None] * np.abs(v))
    assert np.abs(m1["linear"] - m0["linear"]).max() < 1e-12 * scale
    assert abs(m1["angular"][2] - m0["angular"][2]) < 1e-12 * scale
    assert np.abs(sim._read("F") - np.eye(2)).max() > 1e-3       # it did deform


@pytest.mark.slow
@pytest.mark.parametrize("dim, basis, transfer, update, precision, sparse, model", [
    (2, "linear", "pic", "usl", "f64", True, "neo_hookean"),
    (2, "gimp", "flip", "musl", "f32", False, "fixed_corotated"),
    pytest.param(2, "cubic", "apic", "musl", "f64", True, "fluid", marks=pytest.mark.slow),  # ~40 s cold compile
    (3, "quadratic", "apic", "usl", "f32", True, "neo_hookean"),
])
def test_every_option_runs_and_keeps_volume(dim, basis, transfer, update, precision, sparse, model):
    """The averaging keeps total volume in every combination (f32: to its round-off); fluids stay isotropic."""
    cfg = make_cfg(dim, basis=basis, transfer=transfer, update=update, precision=precision, E=1e4, nu=0.49,
                   model=model, dx=0.1 if dim == 2 else 0.125, lower=[0.3] * dim, upper=[0.7] * dim,
                   volumetric="fbar", gravity=[0.0] * (dim - 1) + [-10.0])
    cfg["domain"]["sparse"] = sparse
    sim = tm.Simulation(cfg)
    X = sim.scene.x
    sim.set_particles(v=0.5 * (X - 0.5) + 0.2 * np.sin(9.0 * X))   # a non-uniform volume change
    tol = 1e-12 if precision == "f64" else 1e-5
    apply, record = sim.extension("fbar").fbar.apply, []

    def recorded():
        before = volume(sim)
        apply()
        record.append(abs(volume(sim) - before) / before)
    sim.extension("fbar").fbar.apply = recorded
    for _ in range(10):
        sim.step()
    assert len(record) == 10 and max(record) < tol
    F = sim._read("F")
    if model == "fluid":
        J = np.linalg.det(F)
        assert np.abs(F - J[:, None, None] ** (1 / dim) * np.eye(dim)).max() < tol
    assert np.abs(F - np.eye(dim)).max() > 1e-4


@pytest.mark.slow
def test_1d_is_the_identity():
    """1D has no locking (all deformation is volumetric): no F-bar object, the same steps as standard."""
    out = {}
    for v in ("standard", "fbar"):
        sim = tm.Simulation(make_cfg(1, E=1e4, nu=0.3, dx=0.05, volumetric=v, velocity=[0.2], gravity=[-10.0]))
        for _ in range(20):
            sim.step()
        out[v] = (sim.extension("fbar"), sim._read("F"))
    assert out["fbar"][0] is None   # no F-bar extension in 1D (step/extensions.py builds none)
    # two runs with Taichi's threads: the order of P2G's atomic adds may differ, so F agrees up to rounding (1e-16 a
    # step, 20 steps), far inside 1e-13; any change of the step itself moves F by about dt |grad v| ~ 1e-4
    assert np.abs(out["fbar"][1] - out["standard"][1]).max() < 1e-13


# ---------------------------------------------------------------- config
def test_config_key():
    base = make_cfg(2)
    assert load_config(base).solver.volumetric == "standard"
    bad = copy.deepcopy(base)
    bad["solver"]["volumetric"] = "bbar"
    with pytest.raises(ConfigError, match="solver.volumetric"):
        load_config(bad)
    both = copy.deepcopy(base)
    both["solver"]["volumetric"] = "fbar"
    both["crack"] = {}
    assert load_config(both).solver.volumetric == "fbar"   # with the crack finder (test_crack_combinations)


@pytest.mark.slow
def test_resume_reads_the_volume_history_from_F():
    """set_state re-reads J^n from the F it sets: resuming from a saved state takes the same steps as going on
    (without the re-read the next step would measure its volume change from a stale J^n)."""
    sim = small_block(velocity=[0.3, -0.2], gravity=[0.0, -10.0])
    X = sim.scene.x
    sim.set_particles(v=0.5 * (X - 0.5))
    for _ in range(5):
        sim.step()
    state = sim.get_state()
    for _ in range(5):
        sim.step()
    F_on = sim._read("F")
    sim.set_particles(F=np.broadcast_to(np.eye(2), F_on.shape).copy())   # scramble the history first
    sim.set_state(state)
    for _ in range(5):
        sim.step()
    assert np.abs(sim._read("F") - F_on).max() < 1e-12
