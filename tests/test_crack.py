"""Crack finder (issue 4): modified shape functions, separation, cracked bars, contact, damage law.

Fast tests run 2D scenes on coarse grids (dx = 0.05, two particles per cell per axis); the 3D and
other-basis variants of the scene tests are marked slow.
"""
import time
from pathlib import Path

import numpy as np
import pytest
import taichi as ti

import taichi_mpm as tm
from conftest import fast_subset, make_cfg

DATA = Path(__file__).parent / "data"
BASES = ["linear", "gimp", "quadratic", "cubic", "ck"]


# ---------------------------------------------------------------- scenes
def blocks_cfg(dim=2, basis="quadratic", v=0.2, crack=True, dx=0.05, height=0.3, **crack_keys):
    """Two interface blocks touching at x = 0.5, moving apart at +-v (towards each other for v < 0)."""
    lo, hi = [0.1] * (dim - 1), [0.1 + height] * (dim - 1)
    cfg = make_cfg(dim, basis=basis, dx=dx, end_time=1.0)
    cfg["bodies"] = [
        dict(name="a", shape=dict(type="box", lower=[0.2] + lo, upper=[0.5] + hi), material="m",
             velocity=[-v] + [0.0] * (dim - 1), interface=True),
        dict(name="b", shape=dict(type="box", lower=[0.5] + lo, upper=[0.8] + hi), material="m",
             velocity=[v] + [0.0] * (dim - 1), interface=True)]
    if crack:
        cfg["crack"] = dict(crack_keys)
    return cfg


def bar_cfg(crack, basis="quadratic"):
    """A bar [0.1, 0.9] x [0.4, 0.6] with a through crack: one fully damaged particle column at x = 0.4875."""
    cfg = make_cfg(2, dx=0.05, end_time=1.0, E=1.0e4, nu=0.0, basis=basis, boundaries="free")
    cfg["bodies"] = [dict(name="bar", shape=dict(type="box", lower=[0.1, 0.4], upper=[0.9, 0.6]), material="m",
                          damage_regions=[dict(shape=dict(type="box", lower=[0.475, 0.3], upper=[0.5, 0.7]))])]
    if crack:
        cfg["crack"] = {}
    return cfg


def disks_cfg(crack=True, transfer="apic"):
    """Sulsky's colliding elastic disks (coarse), unequal speeds so the total momentum is not zero."""
    cfg = make_cfg(2, dx=0.05, end_time=1.5, E=1000.0, transfer=transfer)
    cfg["bodies"] = [
        dict(name="a", shape=dict(type="sphere", center=[0.35, 0.35], radius=0.15), material="m",
             velocity=[0.13, 0.11], interface=True),
        dict(name="b", shape=dict(type="sphere", center=[0.65, 0.65], radius=0.15), material="m",
             velocity=[-0.08, -0.1], interface=True)]
    if crack:
        cfg["crack"] = {}
    return cfg


# ---------------------------------------------------------------- modified shape functions
def _check_partition(cfg):
    sim = tm.Simulation(cfg)
    out = sim.extension("crack").partition_check()
    masked = out[:, 0] > 0
    assert masked.sum() >= 10
    inv_dx = 1.0 / cfg["domain"]["dx"]
    assert np.abs(out[masked, 1] - 1).max() < 1e-12      # sum of tangential functions
    assert np.abs(out[masked, 2] - 1).max() < 1e-12      # sum of normal functions
    assert out[masked, 3].max() < 1e-12 * inv_dx          # sum of their gradients
    assert out[masked, 4].max() < 1e-12 * inv_dx
    assert out[masked, 5].max() < 1e-12                   # sum_i W_ip = I (tensor weights)
    assert out[masked, 6].all()                           # every masked particle has a node across
    return out


@pytest.mark.parametrize("dim, basis", fast_subset([(d, b) for d in (2, 3) for b in BASES],
                                                   {(2, "linear")}))
def test_modified_functions_partition_of_unity(dim, basis):
    """Masked particles (cut in tension, and cut with normal contact when approaching): both rescaled
    families sum to 1 and their gradients to 0, to 1e-12 in f64."""
    apart = _check_partition(blocks_cfg(dim, basis, v=0.2))
    assert (apart[:, 0] == 1).sum() > 0
    closing = _check_partition(blocks_cfg(dim, basis, v=-0.2))
    assert (closing[:, 0] == 2).sum() > 0                 # contact state: normal part kept across


@pytest.mark.slow
def test_modified_functions_partition_3d_quadratic():
    _check_partition(blocks_cfg(3, "quadratic", v=0.2, dx=0.1))


@pytest.mark.slow
def test_cell_list_search_matches_all_pairs():
    """The SPH normals from the cell list's pruned row search equal a sum over all particle pairs (of one body:
    these are interface bodies): no neighbour within r is cut (the search walks rows of cells and drops cells out of reach). Interface blocks, 2D, f64,
    positions jittered by up to 0.4 particle spacings (on the lattice, distances to cell faces are multiples of a
    quarter cell and a search cut too short would go unseen)."""
    sim = tm.Simulation(blocks_cfg(2, v=0.2))
    x = sim.x.to_numpy()
    x += np.random.default_rng(1).uniform(-0.4, 0.4, x.shape) * 0.025
    sim.x.from_numpy(x)
    c = sim.extension("crack")
    c.update()
    vol, D = sim.vol0.to_numpy(), c.D.to_numpy()
    state, normal = c.state.to_numpy(), c.normal.to_numpy()
    rv = x[:, None, :] - x[None, :, :]
    s = np.linalg.norm(rv, axis=2) / c.radius
    side = c.fields.side.to_numpy()   # an interface body's normal sums over its own particles alone
    inside = (s < 1) & ((side[:, None] < 0) | (side[:, None] == side[None, :]))
    wk = np.where(s < 0.5, 1 - 6 * s**2 + 6 * s**3, 2 * (1 - s) ** 3) * inside
    dk = np.where(s < 0.5, -12 * s + 18 * s**2, -6 * (1 - s) ** 2) * inside
    gw = (dk / np.maximum(s, 1e-300) / c.radius**2)[:, :, None] * rv
    Sw, SD = wk @ vol, wk @ (vol * D)
    gS, gSD = np.einsum("pq,q,pqa->pa", inside * 1.0, vol, gw), np.einsum("pq,q,pqa->pa", inside * 1.0, vol * D, gw)
    grad = gSD / Sw[:, None] - (SD / Sw**2)[:, None] * gS
    near = state > 0
    assert near.sum() >= 20
    want = grad[near] / np.linalg.norm(grad[near], axis=1)[:, None]
    # f64 sums of ~50 terms in another order: 1e-12 leaves room for rounding; searches cut 0.3 cells short moved n by 1e-2
    assert np.abs(normal[near] - want).max() < 1e-12


# ---------------------------------------------------------------- no crack section: unchanged
def _reference_run(dim, crack):
    """The scene stored in data/no_crack_reference.npz (made by this function before the crack finder
    existed, without the `crack` key). Regenerate only after a deliberate change of the core numerics."""
    cfg = make_cfg(dim, velocity=[0.3] + [0.0] * (dim - 1), dx=0.1, gravity=[0.0, -9.81] + [0.0] * (dim - 2))
    cfg["bodies"][0]["angular_velocity"] = 2.0 if dim == 2 else [0.0, 0.0, 2.0]
    if crack:
        cfg["crack"] = {}
    sim = tm.Simulation(cfg)
    for _ in range(20):
        sim.step(1e-3)
    return sim


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, pytest.param(3, marks=pytest.mark.slow)])  # 3D: ~60 s of cold compile
def test_scene_without_crack_is_unchanged(dim):
    ref = np.load(DATA / "no_crack_reference.npz")
    sim = _reference_run(dim, crack=False)
    assert sim.extension("crack") is None and "A0" not in sim.grid.vec          # nothing allocated
    p = sim.particles()
    assert "damage" not in p
    # The reference was stored on another CPU: LLVM's instruction selection (FMA contraction, vector width) and the
    # order of P2G's atomic adds across threads change the last bits (seen: 5.6e-17). Equal up to rounding means
    # within 1e-12 of the field's scale: f64 rounding (1e-16) grown over 20 steps stays far below that, while any
    # change of the numerics (a weight, a force term, a transfer) moves positions by >= dt^2 |a| ~ 1e-5.
    # Regenerated when the time integration became leapfrog (a half kick on the first step). Against the
    # symplectic-Euler arrays it replaced, it differs by exactly what that predicts: symplectic Euler's extra half
    # kick put the mean height N dt (dt/2) |g| = 9.81e-5 lower and the velocity (dt/2) |g| = 4.905e-3 lower
    # (checked to 1e-16 in 2D and 3D when stored).
    for name in ("x", "v"):
        want = ref[f"{name}{dim}"]
        assert np.abs(p[name] - want).max() <= 1e-12 * np.abs(want).max(), name
    plain_bytes = sim.bytes_per_particle
    # with a crack section but nothing damaged, every particle keeps its standard functions: the stored result up
    # to rounding (the crack branch changes how LLVM contracts multiply-adds; seen: 6e-17 in 3D)
    sim = _reference_run(dim, crack=True)
    assert sim.bytes_per_particle > plain_bytes
    assert np.abs(sim.particles()["x"] - ref[f"x{dim}"]).max() <= 1e-12 * np.abs(ref[f"x{dim}"]).max()


# ---------------------------------------------------------------- two blocks pulled apart
def _pull(cfg, steps=30):
    sim = tm.Simulation(cfg)
    b = sim.particles()["body"]
    gaps, times, smax = [], [], 0.0
    for _ in range(steps):
        sim.step()
        p = sim.particles()
        gaps.append(p["x"][b == 1, 0].min() - p["x"][b == 0, 0].max())
        times.append(sim.time)
        smax = max(smax, p["stress"][:, 0, 0].max())
    return sim, p, b, np.array(gaps), np.array(times), smax


@pytest.mark.slow
def test_two_blocks_stay_joined_without_crack_finder():
    sim, p, b, gaps, t, smax = _pull(blocks_cfg(crack=False))
    assert gaps.max() < 0.05                                   # below one cell
    assert smax > 50.0                                         # tension builds up (E = 1e4, v = 0.2)


@pytest.mark.slow
def test_two_blocks_separate_with_crack_finder():
    """Each block keeps its imposed velocity within 5 %; the gap between their facing surfaces opens at
    their relative speed (averaged over 40 steps: the freed faces vibrate)."""
    sim, p, b, gaps, t, smax = _pull(blocks_cfg(crack=True), steps=40)
    va, vb = p["v"][b == 0, 0].mean(), p["v"][b == 1, 0].mean()
    assert abs(va + 0.2) < 0.05 * 0.2 and abs(vb - 0.2) < 0.05 * 0.2
    rate = (gaps[-1] - gaps[0]) / (t[-1] - t[0])
    assert rate == pytest.approx(vb - va, rel=0.10)
    assert gaps[-1] > 0.1


@pytest.mark.parametrize("dim", fast_subset([2, 3], []))
def test_threshold_0_keeps_the_blocks_apart_at_the_contact_face_edges(dim):
    """The nodes at the edges of the contact face lie outside both blocks, with normals out of the free surface,
    which both blocks' edge particles kept at threshold 0 (they leaked momentum: 0.193 m/s of 0.2 kept in 2D,
    0.167 in 3D). Each such node now belongs to one interface body (its owner, classify), and the other's particles
    count it across: measured 0.2000 m/s in 2D and 3D. Asserted within 2 % (the leak was 3.5 % and 17 %)."""
    sim, p, b, gaps, t, smax = _pull(blocks_cfg(dim, crack=True, threshold=0.0), steps=30)
    va, vb = p["v"][b == 0, 0].mean(), p["v"][b == 1, 0].mean()
    assert abs(va + 0.2) < 0.02 * 0.2 and abs(vb - 0.2) < 0.02 * 0.2, (va, vb)


@pytest.mark.slow
def test_two_blocks_separate_3d_with_interface_threshold():
    """In 3D the edges of the contact face leak momentum with threshold 0 (blocks lose 17 %); with
    threshold -0.6 (nodes whose normal turns more than 53 degrees away count as across) they keep it."""
    sim, p, b, gaps, t, smax = _pull(blocks_cfg(3, crack=True, threshold=-0.6), steps=30)
    va, vb = p["v"][b == 0, 0].mean(), p["v"][b == 1, 0].mean()
    assert abs(va + 0.2) < 0.01 * 0.2 and abs(vb - 0.2) < 0.01 * 0.2
    assert gaps[-1] > 0.08


# ---------------------------------------------------------------- cracked bar
def _bar(crack, v0, basis="quadratic"):
    return push_bar(tm.Simulation(bar_cfg(crack, basis)), v0)


def push_bar(sim, v0, start=None):
    """A bar cracked at x = 0.4875 (bar_cfg's; from the state `start` when given): left of the crack moves at v0
    (< 0 pulls the crack open, > 0 closes it); mean sigma_xx over the right side near the crack once the wave of
    the uncracked bar has run 0.2 into it; the gap between the two sides' particles (the damaged column
    excluded)."""
    if start is not None:
        sim.set_state(start)
    x0 = sim.particles()["x"]
    v = np.zeros_like(x0)
    left, right = x0[:, 0] < 0.475, x0[:, 0] > 0.5
    v[left, 0] = v0
    sim.set_particles(v=v)
    sim.advance(0.2 / np.sqrt(1.0e4 / 1000.0))
    p = sim.particles()
    near = right & (x0[:, 0] < 0.65)
    return p["stress"][near, 0, 0].mean(), p["x"][right, 0].min() - p["x"][left, 0].max()


@pytest.mark.slow
@pytest.mark.parametrize("basis", ["quadratic", pytest.param("linear", marks=pytest.mark.slow),
                                   pytest.param("gimp", marks=pytest.mark.slow),
                                   pytest.param("cubic", marks=pytest.mark.slow)])
def test_precracked_bar_in_tension(basis):
    plain, _ = _bar(False, -0.05, basis)
    cracked, _ = _bar(True, -0.05, basis)
    assert plain > 50.0                                        # without the finder, stress crosses the crack
    assert abs(cracked) < 0.05 * plain


@pytest.mark.slow
@pytest.mark.parametrize("basis", ["quadratic", pytest.param("linear", marks=pytest.mark.slow),
                                   pytest.param("gimp", marks=pytest.mark.slow),
                                   pytest.param("cubic", marks=pytest.mark.slow)])
def test_closed_crack_in_compression(basis):
    plain, _ = _bar(False, 0.05, basis)
    cracked, gap = _bar(True, 0.05, basis)
    assert plain < -50.0
    assert cracked == pytest.approx(plain, rel=0.10)
    assert gap > 0.0                                           # the two sides do not interpenetrate


# ---------------------------------------------------------------- colliding disks
@pytest.mark.slow
@pytest.mark.parametrize("transfer,update", [("apic", "usl"), pytest.param("flip", "musl", marks=pytest.mark.slow),
                                             pytest.param("pic", "musl", marks=pytest.mark.slow)])
def test_colliding_disks_with_interfaces(transfer, update):
    cfg = disks_cfg(transfer=transfer)
    cfg["solver"]["update"] = update
    sim = tm.Simulation(cfg)
    p = sim.particles()
    b, m = p["body"], p["mass"]
    axis = np.array([1.0, 1.0]) / np.sqrt(2.0)
    P0 = (m[:, None] * p["v"]).sum(0)
    scale = (m[:, None] * np.abs(p["v"])).sum()
    overlap = []
    while sim.time < 1.5:
        sim.step()
        p = sim.particles()
        overlap.append((p["x"][b == 0] @ axis).max() - (p["x"][b == 1] @ axis).min())
        assert np.abs((m[:, None] * p["v"]).sum(0) - P0).max() < 1e-8 * scale
    overlap = np.array(overlap)
    assert overlap.max() < 0.0                                 # no particle of a disk passes the other's front
    assert overlap.max() > -0.05                               # ... and they did meet
    va, vb = p["v"][b == 0].mean(0) @ axis, p["v"][b == 1].mean(0) @ axis
    assert va < 0.0 < vb + 0.1 and vb - va > 0.05              # moving apart after the impact
    assert overlap[-1] < overlap.max() - 0.02


# ---------------------------------------------------------------- damage law
def test_rankine_law_softens_linearly():
    """Uniaxial stress path: (1 - d) E kappa falls linearly from f_t at eps0 to 0 at eps_f = 2 G_f / (f_t dx)."""
    from taichi_mpm.config import Material
    from taichi_mpm.materials import degrade_tension, rankine_damage, rankine_params

    ti.init(arch=ti.cpu, default_fp=ti.f64)
    mat = Material(model="linear_elastic", density=1000.0, E=1.0e6, tensile_strength=1.0e3, fracture_energy=2.0)
    E, eps0, epsf = rankine_params(mat, dx=0.01)
    assert eps0 == pytest.approx(1e-3) and epsf == pytest.approx(0.4)

    @ti.kernel
    def stress_at(eps: ti.types.ndarray(), out: ti.types.ndarray()):
        for i in range(eps.shape[0]):
            sig = ti.Matrix([[E * eps[i], 0.0], [0.0, -0.5 * E * eps[i]]])
            d, k = rankine_damage(sig, 0.0, E, eps0, epsf)
            deg = degrade_tension(sig, d)
            out[i, 0] = d
            out[i, 1] = deg[0, 0]
            out[i, 2] = deg[1, 1]

    eps = np.array([0.5e-3, 1e-3, 0.1, 0.2, 0.3, 0.5])
    out = np.zeros((len(eps), 3))
    stress_at(eps, out)
    expected = np.where(eps <= eps0, E * eps, np.maximum(0.0, 1e3 * (epsf - eps) / (epsf - eps0)))
    assert np.allclose(out[:, 1], expected, rtol=1e-10, atol=1e-9)
    assert np.allclose(out[:, 2], -0.5 * E * eps, rtol=1e-12)   # compression is not degraded
    assert out[-1, 0] == 1.0


@pytest.mark.slow
def test_load_to_failure_crack_grows():
    """A notched bar whose ends are jerked outwards: the two tension waves meet at the notch, damage
    nucleates at its tip and runs through the section; the crack finder then lets the halves drift apart
    and the section carries no more tension."""
    sim = tm.Simulation(load_to_failure_cfg())
    x0 = sim.particles()["x"]
    v = np.zeros_like(x0)
    v[:, 0] = 0.04 * (np.where(x0[:, 0] > 0.7, 1.0, 0.0) - np.where(x0[:, 0] < 0.3, 1.0, 0.0))
    sim.set_particles(v=v)
    right, left = x0[:, 0] > 0.6, x0[:, 0] < 0.4
    seps = []
    for _ in range(3):
        sim.advance(0.1)
        p = sim.particles()
        seps.append(p["x"][right, 0].mean() - p["x"][left, 0].mean())
    broken = p["damage"] >= 0.99
    rows = np.unique(np.round(x0[broken, 1], 6))
    assert len(rows) == 16                                      # every particle row of the bar is cut
    assert np.abs(x0[broken, 0] - 0.5).max() < 0.02             # along the notch section
    assert seps[0] < seps[1] < seps[2]                          # the halves drift apart
    section = np.abs(x0[:, 0] - 0.5) < 0.05
    assert np.abs(p["stress"][section, 0, 0]).mean() < 0.1 * 500.0


@pytest.mark.slow  # cold compile time: the default suite keeps a cheaper test of the same feature
def test_state_round_trip_keeps_damage():
    """get_state/set_state (checkpoints) carry the grown damage and the damage law's history. Deterministic (one
    thread): with several, P2G's atomic adds in a varying order could differ by rounding, and a damage threshold
    can turn a rounding difference into a different crack; under solver.deterministic the continued run must be
    bit-identical."""
    cfg = load_to_failure_cfg()
    cfg["solver"]["deterministic"] = True
    sim = tm.Simulation(cfg)
    x0 = sim.particles()["x"]
    v = np.zeros_like(x0)
    v[:, 0] = 0.04 * (np.where(x0[:, 0] > 0.7, 1.0, 0.0) - np.where(x0[:, 0] < 0.3, 1.0, 0.0))
    sim.set_particles(v=v)
    sim.advance(0.05)
    state = sim.get_state()
    assert (state["damage"] > 0.99).sum() > 8 and state["damage_kappa"].max() > 0
    sim.advance(0.02)
    ahead = sim.particles()
    sim2 = tm.Simulation(cfg)
    sim2.set_state(state)
    sim2.advance(0.02)
    again = sim2.particles()
    np.testing.assert_array_equal(again["x"], ahead["x"])
    np.testing.assert_array_equal(again["damage"], ahead["damage"])


def _slow_pull(refresh, steps, state=None, state_at=None):
    """2D interface blocks drawn apart at 0.02 m/s (particles move ~1e-4 cells a step), one thread, no fast math:
    (what the run ends with, the state at step `state_at`); `state`: start from it."""
    cfg = blocks_cfg(2, crack=True, v=0.02, normal_refresh=refresh)
    cfg["solver"]["deterministic"] = True
    sim = tm.Simulation(cfg)
    if state is not None:
        sim.set_state(state)
    saved = None
    for k in range(steps):
        if k == state_at:
            saved = sim.get_state()
        sim.step()
    crack = sim.extension("crack")
    end = dict(x=sim.particles()["x"], normal=crack.normal.to_numpy(), state=crack.state.to_numpy(),
               refreshes=crack.refreshes if crack.cached else None)
    return sim, end, saved


@pytest.mark.slow
def test_normals_kept_between_steps_stay_close_to_every_step_ones():
    """crack.normal_refresh (default 0.01): the SPH normals are recomputed once a particle has moved 0.5 % of the
    support radius. Over 60 steps of a slow pull that is 9 times (measured); the normals then differ from the
    every-step ones by what that motion turns them (measured 5.9e-3, bound 1e-2 = the relative motion allowed, 1 %
    of r, over r), and positions differ by 0 (bound 1e-3 of a cell: the normals only tilt the split of a near
    particle's momentum by that much). Since the nodes have owners the two blocks are apart from the first step and
    move unstressed, so the contact test of the particles near their free surfaces compares a trial traction of
    rounding size with 0: 19 of 288 states differ between the runs (none before owners, when the edges leaked and
    stressed the blocks) without moving anything; bound 10 %."""
    _, exact, _ = _slow_pull(0.0, 60)
    sim, kept, _ = _slow_pull(0.01, 60)
    assert exact["refreshes"] is None and 2 <= kept["refreshes"] <= 20
    # refreshes recompute the normals near the interface only: the blocks' other particles moved as a whole
    assert sim.n < sim.extension("crack").recomputed[None] < sim.n * (1 + kept["refreshes"]) / 2
    assert np.abs(kept["normal"] - exact["normal"]).max() < 1e-2
    assert (kept["state"] != exact["state"]).mean() < 0.1
    assert np.abs(kept["x"] - exact["x"]).max() < 1e-3 * 0.05


def _gliding_pair(refresh):
    """The interface blocks gliding together at (0.5, 0.2) m/s, no gravity: a motion as a whole."""
    cfg = blocks_cfg(2, crack=True, v=0.0, normal_refresh=refresh)
    cfg["solver"]["gravity"] = [0.0, 0.0]
    for body in cfg["bodies"]:
        body["velocity"] = [0.5, 0.2]
    sim = tm.Simulation(cfg)
    for _ in range(30):
        sim.step()
    return sim


@pytest.mark.slow   # 16 s of kernels; the kept normals' refresh is checked by default in the two tests around it
def test_a_body_moving_as_a_whole_keeps_its_normals():
    """A refresh recomputes a normal only where the neighbours moved against each other by the skin: the blocks
    gliding together refresh at every step (particles move more than 0.5 % of r in each) and never recompute one after
    the first step; their kept normals match those recomputed every step (the normal of a neighbourhood moved as a
    whole is the same, up to rounding: bound 1e-6), and the same particles are modified."""
    sim = _gliding_pair(0.01)
    crack = sim.extension("crack")
    assert crack.refreshes >= 4
    assert crack.recomputed[None] == sim.n        # the first step's, none since
    normals, states = crack.normal.to_numpy(), crack.state.to_numpy()
    exact = _gliding_pair(0.0).extension("crack")
    assert np.abs(normals - exact.normal.to_numpy()).max() < 1e-6
    # the same particles are near the interface; contact itself is decided on zero traction and zero closing
    # speed here (the blocks touch at rest relative to each other), so rounding picks it: not compared
    np.testing.assert_array_equal(states != 0, exact.state.to_numpy() != 0)


@pytest.mark.slow
def test_kept_normals_travel_with_the_state():
    """get_state carries the kept normals, the positions they belong to and whether they are due, so a run
    continued from a checkpoint is bit-identical to the one that went on (which reused normals across the
    checkpoint); set_particles(x=...) makes them due."""
    _, ahead, state = _slow_pull(0.01, 40, state_at=20)
    assert state["crack_normals"].shape == (len(ahead["x"]), 2) and ahead["refreshes"] < 40
    sim, again, _ = _slow_pull(0.01, 20, state=state)
    np.testing.assert_array_equal(again["x"], ahead["x"])
    np.testing.assert_array_equal(again["normal"], ahead["normal"])
    before = sim.extension("crack").refreshes
    sim.set_particles(x=sim.particles()["x"])
    sim.step()
    assert sim.extension("crack").refreshes == before + 1


@pytest.mark.slow
def test_contact_list_holds_every_facing_neighbour():
    """With normals kept between steps, the contact test sums over a list per particle built when they were: the
    particles that can come within reach and face it before they are recomputed. Checked by brute force each step
    of a slow 2D push into contact: every neighbour within r whose normal faces p's (n_p . n_q < -threshold) is in
    p's list (or p searches each step); the lists hold far fewer entries than the neighbours within r a search
    would visit (a particle of a free surface has an empty one); and contact is found (the push closes the gap)."""
    cfg = blocks_cfg(2, crack=True, v=-0.02)
    sim = tm.Simulation(cfg)
    r, listed, pairs, contact = sim.extension("crack").radius, 0, 0, 0
    for _ in range(30):
        sim.step()
        x = sim.particles()["x"]
        n = sim._to_creation(sim.extension("crack").normal.to_numpy())  # solver slots -> creation order, as x
        lists = sim.extension("crack").contact_lists()
        close = np.linalg.norm(x[:, None] - x[None], axis=-1) < r
        # a pair within 1e-12 of the threshold is a rounding tie (the corners' normals of two interface blocks are
        # exact diagonals, n_p . n_q = 0 = -threshold): the kernel's sum may round it either way
        facing = close & ((n @ n.T) < -sim.cfg.crack.threshold - 1e-12) & (np.abs(n).sum(axis=1) > 0)[:, None]
        for p in np.nonzero(facing.any(axis=1))[0]:
            assert lists[p] is None or set(np.nonzero(facing[p])[0]) <= set(lists[p]), p
        listed += sum(len(a) for a in lists if a is not None)
        pairs += int(close.sum())
        contact += int((sim._to_creation(sim.extension("crack").state.to_numpy()) == 2).sum())
    print(f"listed {listed}, pairs within r {pairs}, contact {contact}")
    assert 0 < listed < 0.2 * pairs and contact > 0


def test_contact_gap_without_interface_bodies_is_refused():
    cfg = bar_cfg(True)
    cfg["crack"]["contact_gap"] = 0.3
    with pytest.raises(tm.ConfigError, match="interface bodies only") as e:
        tm.load_config(cfg)
    assert e.value.key == "crack.contact_gap"


@pytest.mark.parametrize("fp", ["f32", "f64"])
def test_node_owner_key_keeps_the_largest_weight_and_on_ties_the_larger_side(fp):
    """nodes.owner_key_funcs: the max over the keys of (weight, side) claims is the claim of the largest weight, and
    among equal weights the larger side, whatever order the claims come in (what the two passes over the interface
    particles gave before). Weights in [0, 1] with deliberate ties, 40 nodes of 12 claims each, shuffled."""
    from taichi_mpm.extensions.crack.nodes import MAX_SIDES, owner_key_funcs

    ti.init(arch=ti.cpu, default_fp=getattr(ti, fp))
    key, side_of = owner_key_funcs(fp)
    rng = np.random.default_rng(7)
    nodes, claims = 40, 12
    w = rng.choice([0.0, 0.125, 0.5, 1.0, *rng.random(6)], size=(nodes, claims)).astype(np.float64 if fp == "f64"
                                                                                    else np.float32)
    side = rng.integers(0, MAX_SIDES, size=(nodes, claims)).astype(np.int32)
    owner = ti.field(ti.i64, nodes)

    @ti.kernel
    def claim(w: ti.types.ndarray(), side: ti.types.ndarray(), out: ti.types.ndarray()):
        for i, j in ti.ndrange(nodes, claims):
            ti.atomic_max(owner[i], key(w[i, j], side[i, j]))
        for i in range(nodes):
            out[i] = side_of(owner[i])

    out = np.zeros(nodes, np.int32)
    claim(w, side, out)
    for i in range(nodes):
        best = max(zip(w[i], side[i]))   # the largest weight, ties to the larger side
        assert out[i] == best[1] + 1, (i, w[i], side[i])


def test_too_many_interface_bodies_are_refused():
    """The node owners hold an interface body's side in 8 bits: a 256th interface body is refused by name, before
    any field is allocated; 255 load."""
    from taichi_mpm.config import MAX_INTERFACE_BODIES
    from taichi_mpm.extensions.crack.nodes import MAX_SIDES
    assert MAX_INTERFACE_BODIES == MAX_SIDES
    cfg = blocks_cfg()
    small = dict(cfg["bodies"][0], shape=dict(type="box", lower=[0.2, 0.1], upper=[0.22, 0.12]))
    cfg["bodies"] = [dict(small, name=f"b{i}") for i in range(MAX_SIDES)]
    tm.load_config(cfg)
    cfg["bodies"].append(dict(small, name="one_more"))
    with pytest.raises(tm.ConfigError, match="at most 255 interface bodies") as e:
        tm.load_config(cfg)
    assert e.value.key == f"bodies.{MAX_SIDES}.interface"


@pytest.mark.slow
def test_contact_gap_keeps_contact_to_surfaces_that_touch():
    """crack.contact_gap 0.3: two interface blocks a cell (two spacings) apart close at 1 m/s. A particle counts as
    in contact only while the nearest particle facing it lies within 1.3 particle spacings, checked by brute force
    each step (facing: n_p . n_q < 1e-12, the contact test's n_p . n_q < -threshold with its rounding ties, a
    superset). Measured, contacts per step: none for 9 steps, then 20-24 once the blocks meet; without the check
    44 particles, 3 spacings from the other block and within the SPH reach (4), are in contact at the first step
    and 56-102 after. Asserted: none at the first step, some later."""
    cfg = blocks_cfg(2, crack=True, v=-0.5, contact_gap=0.3)
    cfg["bodies"][1]["shape"]["lower"][0] = 0.55
    sim = tm.Simulation(cfg)
    finder = sim.extension("crack")
    spacing, r = finder.fields.spacing, finder.radius
    found = []
    for _ in range(20):
        x = sim.particles()["x"]   # where the step's contact test sees them (before_p2g, before G2P moves them)
        sim.step()
        n = sim._to_creation(finder.normal.to_numpy())
        state = sim._to_creation(finder.state.to_numpy())
        for p in np.nonzero(state == 2)[0]:
            d = x - x[p]
            facing = (np.linalg.norm(d, axis=1) < r) & (n @ n[p] < 1e-12) & (np.arange(len(x)) != p)
            assert facing.any() and np.linalg.norm(d[facing], axis=1).min() < 1.3 * spacing * (1 + 1e-9), p
        found.append(int((state == 2).sum()))
    assert found[0] == 0 and sum(found) > 0, found


def load_to_failure_cfg():
    cfg = make_cfg(2, dx=0.025, end_time=0.3, E=1.0e5, nu=0.2, model="neo_hookean", boundaries="free")
    cfg["materials"]["m"].update(tensile_strength=500.0, fracture_energy=0.035)
    cfg["bodies"] = [dict(name="bar", shape=dict(type="box", lower=[0.2, 0.4], upper=[0.8, 0.6]), material="m",
                          damage_regions=[dict(shape=dict(type="box", lower=[0.4875, 0.4], upper=[0.5125, 0.45]))])]
    cfg["crack"] = {}
    return cfg


# ---------------------------------------------------------------- cost
@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_report_step_cost(dim, capsys):
    """Step time with the crack finder (interface blocks) over the same scene without it; printed."""
    dx = 0.02 if dim == 2 else 0.05
    times = {}
    for crack in (False, True):
        sim = tm.Simulation(blocks_cfg(dim, v=0.2, crack=crack, dx=dx))
        for _ in range(3):
            sim.step()
        t0 = time.perf_counter()
        for _ in range(20):
            sim.step()
        ti.sync()
        times[crack] = (time.perf_counter() - t0) / 20 / sim.n
    with capsys.disabled():
        print(f"\n{dim}D crack finder step cost: {times[True] * 1e9:.0f} ns/particle vs {times[False] * 1e9:.0f} "
              f"plain, ratio {times[True] / times[False]:.2f}")
    assert times[True] > 0
