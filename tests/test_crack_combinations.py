"""The crack finder with the rest of the sandbox (issue 27): grips (bodies[].prescribed_velocity), velocity walls and
wall probes act after its node solve in the grid solve's one chain (step.grid_update), as at every node."""
import warnings

import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm.config import ConfigWarning
from test_crack import push_bar

F_T, H, NOTCH = 500.0, 0.2, 0.05      # tensile strength (Pa), bar height and notch depth (m)

# What the same scenes give without the crack finder (or, for the disks, the finder's two-disk impact), measured
# once (f64). Each cracked scene is compared with these figures; test_references_without_the_finder_still_hold
# re-measures them, and with them the point of each comparison (the uncracked scene carries the stress, welded disks
# rebound slower): each reference run is a scene of its own. The default run keeps the 1D bar; the 2D combinations
# (each 6-15 s of a cold run, most of it the crack finder's kernels compiling) run under -m slow.
UNCRACKED = {
    "x_opening": 1.19e-4, "x_stress": 63.8,                  # X plate: each half-arm's stretch and normal stress
    "two_disks": 0.1673,                                      # the finder's two-disk rebound speed (m/s)
    "fbar_bar": (58.1, -55.8),                                # F-bar bar at nu 0.49: sigma_xx pulled, pushed (Pa)
    "ring": (128.0, 128.5, 0.0409),                           # hoop stress near, far; the band's angular gap
    "knots_bar": (76.4, -76.9),                               # the bar on graded knots: pulled, pushed
    "bar_1d": (77.6, -78.1, 0.0504),                          # the 1D bar: pulled, pushed, gap when pulled
}


def notched_bar(end_time, crack=True, **extra):
    """A brittle bar [0.2, 0.8] x [0.4, 0.6] (c = 10 m/s) with a notch a quarter of its height at x = 0.5, its ends
    held by grips that pull them apart at 0.02 m/s each after a smooth start over 0.04 s."""
    ramp = "0.02 * (1 - cos(pi * min(t / 0.04, 1))) / 2"
    mat = dict(model="neo_hookean", E=1.0e5, nu=0.2, density=1000, tensile_strength=F_T, fracture_energy=0.035)
    cfg = dict(name="grip_bar", dim=2, precision="f64", arch="cpu",
               domain=dict(lower=[0, 0], upper=[1, 1], dx=0.025, boundaries=dict(default="free")),
               solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=end_time),
               materials=dict(brittle=mat),
               bodies=[dict(name="bar", shape=dict(type="box", lower=[0.2, 0.4], upper=[0.8, 0.6]),
                            material="brittle",
                            damage_regions=[dict(shape=dict(type="box", lower=[0.4875, 0.4],
                                                            upper=[0.5125, 0.4 + NOTCH]))],
                            prescribed_velocity=[
                                dict(region=dict(type="box", lower=[0.2, 0.4], upper=[0.25, 0.6]),
                                     velocity=[f"-{ramp}", None]),
                                dict(region=dict(type="box", lower=[0.75, 0.4], upper=[0.8, 0.6]),
                                     velocity=[ramp, None])])])
    if crack:
        cfg["crack"] = {}
    cfg.update(extra)
    return cfg


def test_notched_bar_pulled_by_grips_cracks_through():   # in the default run: issue 27's fast test of its capability
    """The grips' force (the right grip's mean over 5 ms windows, Simulation.prescribed_impulse) climbs while the bar
    stretches, peaks when the crack runs from the notch and falls once the bar is cut. Measured: peak 63.0 N/m
    at t = 0.07 s, 0.84 of f_t times the net section (75 N/m; below it: the notch concentrates the stress), then
    -2.4 N/m 15 ms later; 15 of the notch column's 16 particle rows broken by t = 0.1 s. Asserted: the peak between
    0.4 and 1.2 of f_t h_net (an uncracking bar would pass 1.2 by t = 0.1 s, the strain then being 0.006 against
    f_t / E = 0.005; a finder that let the grips tear the bar at the start would stay below 0.4), the force after
    it below 0.2 of the peak, 15 rows broken and the halves moving apart."""
    sim = tm.Simulation(tm.load_config(notched_bar(0.1)))
    force, t_prev = [], 0.0
    while sim.time < 0.1 - 1e-12:
        sim.advance(0.005)
        force.append(sim.prescribed_impulse()[1, 0] / (sim.time - t_prev))
        t_prev = sim.time
    force = np.array(force)
    k = int(np.argmax(force))
    assert 0.4 * F_T * (H - NOTCH) < force[k] < 1.2 * F_T * (H - NOTCH), force
    assert force[k + 1:].min() < 0.2 * force[k], force
    p, X = sim.particles(), sim.scene.x
    column = np.abs(X[:, 0] - 0.5) < 0.0125
    rows = np.unique(np.round(X[column, 1], 6))
    broken = np.unique(np.round(X[column & (p["damage"] >= 0.99), 1], 6))
    assert len(rows) == 16 and len(broken) >= 15 and set(broken) <= set(rows)   # measured: 15
    halves = X[:, 0] > 0.5
    assert p["v"][halves, 0].mean() > 0.005 and p["v"][~halves, 0].mean() < -0.005   # the halves move apart


# ---------------------------------------------------------------- an X-shaped pre-crack
X_CENTRE = np.array([0.5, 0.5])
X_HALF_ARMS = (45.0, 135.0, 225.0, -45.0)   # directions (degrees) of the four half-arms from the crossing


def x_plate(crack=True, dx=0.025, half=0.12):
    """A plate [0.2, 0.8]^2 (E 10 kPa, c = 3.2 m/s) with two crossing damaged bands, +-45 deg, 0.24 long, half a
    cell wide: an X-shaped pre-crack."""
    mat = dict(model="neo_hookean", E=1.0e4, nu=0.3, density=1000)
    arms = [dict(shape=dict(type="box", lower=[0.5 - half, 0.5 - dx / 4], upper=[0.5 + half, 0.5 + dx / 4],
                            rotation=angle)) for angle in (45.0, -45.0)]
    cfg = dict(name="x_crack", dim=2, precision="f64", arch="cpu",
               domain=dict(lower=[0, 0], upper=[1, 1], dx=dx, boundaries=dict(default="free")),
               solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=1.0),
               materials=dict(m=mat),
               bodies=[dict(name="plate", shape=dict(type="box", lower=[0.2, 0.2], upper=[0.8, 0.8]), material="m",
                            damage_regions=arms)])
    if crack:
        cfg["crack"] = {}
    return cfg


def _x_arms(crack):
    """Per half-arm, at 0.06 from the crossing: the opening (normal displacement of the particles 0.008-0.03 on one
    side minus the other's) and the mean normal stress there, once a uniform expansion v = 0.05 (x - c) has
    loaded the plate for 0.075 s (the uncracked plate's tension is then at its peak, ~64 Pa)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConfigWarning)   # the plain run ignores the damage bands (warned)
        sim = tm.Simulation(tm.load_config(x_plate(crack)))
    X = sim.scene.x.copy()
    sim.set_particles(v=0.05 * (X - X_CENTRE))
    sim.advance(0.075)
    p = sim.particles()
    out = []
    for angle in X_HALF_ARMS:
        a = np.radians(angle)
        t = np.array([np.cos(a), np.sin(a)])
        n = np.array([-t[1], t[0]])
        along, across = (X - X_CENTRE) @ t, (X - X_CENTRE) @ n
        mid = np.abs(along - 0.06) < 0.015
        side = mid & (np.abs(across) > 0.008) & (np.abs(across) < 0.03)
        u = (p["x"] - X) @ n
        opening = u[side & (across > 0)].mean() - u[side & (across < 0)].mean()
        out.append((opening, np.einsum("i,pij,j->p", n, p["stress"][side], n).mean()))
    return np.array(out)


def test_x_shaped_precrack_opens_along_both_arms():   # in the default run: issue 27's fast test of its capability
    """The crack finder with two crossing cracks: the particle normals of the damage field at the crossing and along
    both arms. Measured: the four half-arms open by 8.13e-4 to 8.44e-4 m against 1.19e-4 m for the same particle
    pairs in the uncracked plate (7x), and carry 7.1-9.7 Pa of normal stress against its 63.8 Pa. Asserted: each
    half-arm opens more than 4x the uncracked stretch (a finder that missed one arm would leave that arm at 1x) and
    carries less than a quarter of the uncracked stress; the four agree within 10 % of their mean (the X is
    symmetric under the 90 deg rotation; the particle lattice only approximately: 4 % spread measured)."""
    cracked = _x_arms(True)
    assert (cracked[:, 0] > 4.0 * UNCRACKED["x_opening"]).all(), cracked
    assert (np.abs(cracked[:, 1]) < 0.25 * UNCRACKED["x_stress"]).all(), cracked
    assert np.ptp(cracked[:, 0]) < 0.10 * cracked[:, 0].mean(), cracked


# ---------------------------------------------------------------- three disks meeting at one point
DISK_R, DISK_V = 0.12, 0.2


def disks_meeting(n, crack=True):
    """n elastic disks (E 1 kPa, r 0.12) 0.01 apart around the centre, each moving at 0.2 m/s towards it: two
    meet head-on, three at one point (each touching the other two)."""
    bodies = []
    for k in range(n):
        d = np.array([np.cos(2 * np.pi * k / n), np.sin(2 * np.pi * k / n)])
        centre = 0.5 + (DISK_R + 0.01) / np.sin(np.pi / n) * d if n > 2 else 0.5 + (DISK_R + 0.01) * d
        bodies.append(dict(name=f"disk{k}", shape=dict(type="sphere", center=centre.tolist(), radius=DISK_R),
                           material="m", velocity=(-DISK_V * d).tolist(), interface=crack))
    cfg = dict(name="disks", dim=2, precision="f64", arch="cpu",
               domain=dict(lower=[0, 0], upper=[1, 1], dx=0.025, boundaries=dict(default="slip")),
               solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=1.0),
               materials=dict(m=dict(model="neo_hookean", E=1000.0, nu=0.3, density=1000)), bodies=bodies)
    if crack:
        cfg["crack"] = {}
    return cfg


def _rebound(n, crack, **crack_keys):
    """Each disk's centre-of-mass speed away from the centre at 0.7 s (the impact is over by 0.6 s); crack_keys:
    more of the crack section."""
    cfg = disks_meeting(n, crack)
    if crack:
        cfg["crack"].update(crack_keys)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConfigWarning)   # interface bodies without a crack section: one field
        sim = tm.Simulation(tm.load_config(cfg))
    sim.advance(0.7)
    p, m = sim.particles(), sim.scene.mass
    out = []
    for k in range(n):
        d = np.array([np.cos(2 * np.pi * k / n), np.sin(2 * np.pi * k / n)])
        mine = p["body"] == k
        out.append((m[mine, None] * p["v"][mine]).sum(0) @ d / m[mine].sum())
    return np.array(out)


@pytest.mark.slow
def test_three_disks_meeting_at_one_point_separate_without_welding():
    """Three interface disks pressed together at one point rebound as the two-disk impact does. Measured (crack
    finder): two disks 0.1673 m/s (0.84 of 0.2), three 0.1584, 0.1583, 0.1583 (0.947 of the two-disk value; the
    three-body impact keeps more energy in the disks' vibration: multi-field contact (`contact: multi_field`) gives
    0.143-0.145 for three against 0.158 for two, 0.150-0.157 and 0.1672 before its gap check). One velocity field,
    where the disks weld where they touch: three at 0.134-0.139 (0.80-0.82). Asserted: each of the three at >= 0.9
    of the finder's two-disk speed (welding costs 0.18), and within 2 % of each other (symmetric but for the
    particle lattice: 1 % measured). The two-disk and welded runs: test_references_without_the_finder_still_hold."""
    three = _rebound(3, crack=True)
    assert (three >= 0.9 * UNCRACKED["two_disks"]).all(), three
    assert np.ptp(three) < 0.02 * three.mean(), three


@pytest.mark.slow   # two crack scenes of 0.7 s
def test_three_disks_with_a_contact_gap_rebound_within_5_percent_of_two():
    """With crack.contact_gap 0.3 (contact only where the disks' surfaces meet, not across the SPH reach) the three
    disks keep their rebound within 5 % of the two-disk impact's (issue 27's bound). Measured: two disks 0.1615 m/s,
    three 0.1549-0.1561 (0.960-0.967 of it); without the gap 0.947 (test above)."""
    two, three = _rebound(2, True, contact_gap=0.3), _rebound(3, True, contact_gap=0.3)
    assert two.min() > 0.8 * DISK_V
    assert (np.abs(three / two.mean() - 1) < 0.05).all(), (three, two)


# ---------------------------------------------------------------- F-bar with a crack, nearly incompressible
def fbar_bar(crack, volumetric="fbar"):
    """A bar [0.1, 0.9] x [0.4, 0.6] at nu 0.49 (E 10 kPa) with a damaged column at x = 0.4875."""
    cfg = dict(name="fbar_bar", dim=2, precision="f64", arch="cpu",
               domain=dict(lower=[0, 0], upper=[1, 1], dx=0.05, boundaries=dict(default="free")),
               solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=1.0, volumetric=volumetric),
               materials=dict(m=dict(model="neo_hookean", E=1.0e4, nu=0.49, density=1000)),
               bodies=[dict(name="bar", shape=dict(type="box", lower=[0.1, 0.4], upper=[0.9, 0.6]), material="m",
                            damage_regions=[dict(shape=dict(type="box", lower=[0.475, 0.3], upper=[0.5, 0.7]))])])
    if crack:
        cfg["crack"] = {}
    return cfg


def both_loads(sim):
    """test_crack.push_bar pulling (v0 = -0.05) and pushing (+0.05), each from sim's initial state: one build for
    both loads. Per load (mean sigma_xx right of the crack, gap)."""
    start = sim.get_state()
    return [push_bar(sim, v0, start) for v0 in (-0.05, 0.05)]


def _bar_sim(cfg):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConfigWarning)
        return tm.Simulation(tm.load_config(cfg))


@pytest.mark.slow
def test_fbar_with_a_crack_opens_and_closes_at_nu_049():
    """F-bar (solver.volumetric: fbar) with the crack finder at nu 0.49: the particles the finder takes keep their
    own volume change, the others average with their own side only. Measured (sigma_xx right of the crack, Pa):
    open: -1.05 against 58.1 uncracked; closed: -52.8 against -55.8 uncracked (95 % carried across). Without
    F-bar the closed crack carries -46.8 of its uncracked -83.5 (56 %; the uncracked bar is the stiffer by
    locking: F-bar's 58 against 87 in tension). Asserted: the open crack carries < 5 % of the uncracked stress,
    the closed one 85-105 % (the 10 % the nu = 0 closed-crack test allows, a little more for the closed faces'
    contact at nu 0.49); under -m slow, that F-bar stays softer than the standard update (it is acting)."""
    plain = UNCRACKED["fbar_bar"]
    cracked = [stress for stress, _ in both_loads(_bar_sim(fbar_bar(True)))]
    assert abs(cracked[0]) < 0.05 * abs(plain[0]), (cracked, plain)
    assert 0.85 < cracked[1] / plain[1] < 1.05, (cracked, plain)


# ---------------------------------------------------------------- a crack on the annulus map
def cracked_ring(crack=True):
    """A ring r 0.55-0.95 on an annulus map (96 x 8 cells), a damaged radial band at angle 0 (0.025 wide)."""
    band = dict(shape=dict(type="box", lower=[0.5, -0.0125], upper=[1.0, 0.0125]))
    cfg = dict(name="cracked_ring", dim=2, precision="f64", arch="cpu",
               domain=dict(lower=[-1.1, -1.1], upper=[1.1, 1.1], dx=0.05, boundaries=dict(default="free"),
                           map=dict(type="annulus", inner_radius=0.5, outer_radius=1.0, angle=360.0,
                                    cells=[96, 8])),
               solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=1.0),
               materials=dict(m=dict(model="neo_hookean", E=1.0e4, nu=0.3, density=1000)),
               bodies=[dict(name="ring", shape=dict(type="ring", center=[0.0, 0.0], inner_radius=0.55,
                                                    outer_radius=0.95), material="m", damage_regions=[band])])
    if crack:
        cfg["crack"] = {}
    return cfg


def _expanded_ring(crack):
    """After 0.3 s of a uniform expansion v = 0.05 x: the mean hoop stress within 0.02-0.15 rad of the band, the
    same opposite it, and the angular gap between the particles just above and just below the band."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConfigWarning)
        sim = tm.Simulation(tm.load_config(cracked_ring(crack)))
    X = sim.scene.x.copy()
    sim.set_particles(v=0.05 * X)
    sim.advance(0.3)
    p = sim.particles()
    th = np.arctan2(X[:, 1], X[:, 0])
    hoop_dir = np.stack([-np.sin(th), np.cos(th)], 1)
    hoop = np.einsum("pi,pij,pj->p", hoop_dir, p["stress"], hoop_dir)
    now = np.arctan2(p["x"][:, 1], p["x"][:, 0])
    near, far = (np.abs(th) > 0.02) & (np.abs(th) < 0.15), np.abs(np.abs(th) - np.pi) < 0.15
    gap = now[(th > 0.02) & (th < 0.1)].min() - now[(th < -0.02) & (th > -0.1)].max()
    return hoop[near].mean(), hoop[far].mean(), gap


@pytest.mark.slow
def test_crack_on_the_annulus_map_opens():
    """The crack finder on a mapped grid (its node normals at the map's control points): a radial crack in an
    expanding ring opens. Measured at 0.3 s: hoop stress beside the crack 8.3 Pa against 128.0 uncracked, the
    same opposite it (128.5 in both: the unloading wave has not got there), the gap 0.0621 rad against 0.0409
    (the band's own width, unchanged without the finder). Asserted: < 0.15 of the uncracked stress beside the
    crack, the far side within 1 %, the gap opened by more than 0.015 rad (the uncracked one: < 1e-3, -m slow)."""
    plain, cracked = UNCRACKED["ring"], _expanded_ring(True)
    assert cracked[0] < 0.15 * plain[0], (cracked, plain)
    assert cracked[1] == pytest.approx(plain[1], rel=0.01)
    assert cracked[2] > plain[2] + 0.015, (cracked, plain)


# ---------------------------------------------------------------- a crack on non-uniform knot vectors
def knots_bar(crack):
    """test_crack's pre-cracked bar on graded knots (spans 1.3 to 0.7 of the mean, 20 per axis)."""
    from test_crack import bar_cfg
    from test_knots import graded

    cfg = bar_cfg(crack)
    cfg["domain"]["knots"] = {"x": graded(20), "y": graded(20)}
    return cfg


@pytest.mark.slow
def test_crack_on_graded_knots_opens_and_closes():
    """The crack finder with domain.knots (node normals at the knot vectors' Greville abscissae): test_crack's
    pre-cracked bar on graded knots (spans 1.3 to 0.7 of the mean, 20 per axis). Measured (sigma_xx right of the
    crack, Pa): open 2.48 against 76.4 uncracked (uniform grid: 1.39 against 77.6); closed -74.3 against -76.9
    (uniform: -76.8 against -78.1). Asserted as test_crack's bars: open < 5 %, closed within 10 % of uncracked."""
    (opened, _), (closed, _) = both_loads(_bar_sim(knots_bar(True)))
    pulled, pushed = UNCRACKED["knots_bar"]
    assert abs(opened) < 0.05 * pulled, (opened, pulled)
    assert closed == pytest.approx(pushed, rel=0.10), (closed, pushed)


# ---------------------------------------------------------------- 1D
def bar_1d(crack):
    """test_crack's pre-cracked bar as a 1D bar."""
    cfg = dict(name="bar1d", dim=1, precision="f64", arch="cpu",
               domain=dict(lower=[0.0], upper=[1.0], dx=0.05, boundaries=dict(default="free")),
               solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=1.0),
               materials=dict(m=dict(model="neo_hookean", E=1.0e4, nu=0.0, density=1000)),
               bodies=[dict(name="bar", shape=dict(type="box", lower=[0.1], upper=[0.9]), material="m",
                            damage_regions=[dict(shape=dict(type="box", lower=[0.475], upper=[0.5]))])])
    if crack:
        cfg["crack"] = {}
    return cfg


def test_crack_in_1d_opens_and_closes():
    """The crack finder in 1D (a crack is a point; the SPH normals are +-x): test_crack's pre-cracked bar as a 1D
    bar. Measured (sigma_xx right of the crack, Pa): open 0.00 against 77.6 uncracked, closed -77.8 against -78.1.
    Asserted as in 2D: open < 5 %, closed within 10 % of uncracked, and the open crack's gap grows (0.0527 against
    0.0504 uncracked) while the closed one's faces do not cross."""
    (opened, gap_open), (closed, gap_closed) = both_loads(_bar_sim(bar_1d(True)))
    pulled, pushed, gap_pulled = UNCRACKED["bar_1d"]
    assert abs(opened) < 0.05 * pulled, (opened, pulled)
    assert gap_open > gap_pulled + 1e-3
    assert closed == pytest.approx(pushed, rel=0.10) and gap_closed > 0.0


# ---------------------------------------------------------------- the references, re-measured
def _loads(cfg):
    """(sigma_xx pulled, pushed, gap pulled) of one of the bars above."""
    (pulled, gap), (pushed, _) = both_loads(_bar_sim(cfg))
    return pulled, pushed, gap


@pytest.mark.slow
@pytest.mark.parametrize("case", ["x", "disks", "fbar", "ring", "knots", "1d"])
def test_references_without_the_finder_still_hold(case):
    """UNCRACKED, re-measured: each within 2 % of the figure the default run compares with (the scenes are f64 and
    deterministic up to the order of additions: the figures agree to 4 digits between runs), and what makes each
    comparison mean something: the uncracked X plate stretches uniformly under tension above 50 Pa, welded disks
    rebound slower than the finder's pair (by 0.18 measured; asserted below 0.85 of it), F-bar is softer than the
    standard update (58 against 87 Pa pulled), the uncracked ring's band keeps its width, the uncracked bars carry
    tension and compression above 50 Pa."""
    ref = UNCRACKED
    if case == "x":
        plain = _x_arms(False)
        assert np.ptp(plain[:, 0]) < 1e-9 and plain[0, 1] > 50.0
        assert plain[0] == pytest.approx([ref["x_opening"], ref["x_stress"]], rel=0.02)
    elif case == "disks":
        two, welded = _rebound(2, crack=True), _rebound(3, crack=False)
        assert two.min() > 0.8 * DISK_V and two.mean() == pytest.approx(ref["two_disks"], rel=0.02)
        assert (welded < 0.85 * two.mean()).all(), welded     # the default test can tell welding apart
    elif case == "fbar":
        pulled, pushed, _ = _loads(fbar_bar(False))
        assert (pulled, pushed) == pytest.approx(ref["fbar_bar"], rel=0.02)
        assert abs(pushed) < 0.8 * abs(push_bar(_bar_sim(fbar_bar(False, "standard")), 0.05)[0])
    elif case == "ring":
        plain = _expanded_ring(False)
        assert plain == pytest.approx(ref["ring"], rel=0.02) and abs(plain[2] - 0.0409) < 1e-3
    elif case == "knots":
        pulled, pushed, _ = _loads(knots_bar(False))
        assert pulled > 50.0 and pushed < -50.0 and (pulled, pushed) == pytest.approx(ref["knots_bar"], rel=0.02)
    else:
        pulled, pushed, gap = _loads(bar_1d(False))
        assert pulled > 50.0 and pushed < -50.0 and (pulled, pushed, gap) == pytest.approx(ref["bar_1d"], rel=0.02)
