"""Coulomb friction across body interfaces in the crack finder (crack.friction, issue 27): a block slides down a
gripped base (2D plane strain, gravity tilted by theta). docs/crack_finder.md, "Friction", has the figures."""
import numpy as np
import pytest

import taichi_mpm as tm
from conftest import body_motion, fast_subset

G, T = 9.81, 0.15


def incline_config(theta_deg, mu, gripped=True, transfer="pic", dx=0.05):
    """A 0.2 x 0.1 m block on a 1 x 0.1 m base held by a grip (or lying free on a sticky floor), both interface
    bodies (their contact is the crack finder's)."""
    a = np.radians(theta_deg)
    mat = dict(model="neo_hookean", E=2.0e5, nu=0.3, density=1000)
    cfg = dict(name="incline", dim=2, precision="f64", arch="cpu",
               domain=dict(lower=[0, 0], upper=[1.0, 0.3], dx=dx,
                           boundaries=dict(default="free") if gripped else dict(default="slip", y_min="sticky")),
               solver=dict(basis="quadratic", transfer=transfer, cfl=0.4, end_time=T,
                           gravity=[G * np.sin(a), -G * np.cos(a)]), materials=dict(m=mat),
               bodies=[dict(name="base", shape=dict(type="box", lower=[0, 0], upper=[1.0, 0.1]), material="m",
                            interface=True, prescribed_velocity=[dict(velocity=[0.0, 0.0])]),
                       dict(name="block", shape=dict(type="box", lower=[0.1, 0.1], upper=[0.3, 0.2]),
                            material="m", interface=True)],
               crack=dict(threshold=0.0, contact_in_compression=True, friction=mu))
    if not gripped:
        del cfg["bodies"][0]["prescribed_velocity"]
    return cfg


def incline(theta_deg, mu, dx=0.025):
    """Mass-weighted velocity history along the slope of the block on the gripped base. dx 0.025: the block is
    four cells (eight particles) thick; at 0.05 its own top and bottom faces lie within one SPH support of each
    other and the frictionless block slides 1.5 % slow (docs/crack_finder.md, "Friction")."""
    sim = tm.Simulation(tm.load_config(incline_config(theta_deg, mu, dx=dx)))
    t, v, _ = body_motion(sim, 1, T)
    return t, v, sim


@pytest.mark.parametrize("mu", fast_subset([0.0, 0.3], []))
def test_block_slides_down_an_incline_with_coulomb_friction(mu):
    """At theta = 30 deg the block's acceleration (a line fitted to its velocity after 0.05 s) against Coulomb's
    g (sin theta - mu cos theta). Measured: 1.0001 of it at mu 0 (0.914 before the interface bodies' normals were
    their own surfaces'), 1.042 at mu 0.3 (friction at the nodes takes 0.96 of mu N; 1.158 with the per-particle
    friction before). Asserted: within 1 % at mu 0, 0.9 to 1.1 at mu 0.3: a welded interface gives 0 (the base
    does not move), a frictionless one at mu 0.3 2.08, friction twice too strong 0. The friction work at mu 0.3
    (measured 0.94 of mu N times the distance slid) between 0.8 and 1.1 of it; none at mu 0."""
    t, v, sim = incline(30.0, mu)
    a = np.radians(30.0)
    ref = G * (np.sin(a) - mu * np.cos(a))
    late = t > 0.05
    accel = np.polyfit(t[late], v[late], 1)[0]
    if mu == 0:
        assert accel == pytest.approx(ref, rel=0.01), (accel, ref)
    else:
        assert 0.9 * ref < accel < 1.1 * ref, (accel, ref)
    slid = np.trapezoid(v, t) if hasattr(np, "trapezoid") else np.trapz(v, t)
    block_mass = sim.scene.mass[sim.scene.body == 1].sum()
    work = sim.energy_balance().get("friction", 0.0)
    if mu == 0:
        assert work == 0.0
    else:
        normal_work = mu * block_mass * G * np.cos(a) * slid
        print(f"friction work {work:.3f} J, mu N d {normal_work:.3f} J")
        assert 0.8 * normal_work < work < 1.1 * normal_work, (work, normal_work)


@pytest.mark.slow
def test_friction_is_counted_once_between_two_free_bodies():
    """Both sides of a contact feel friction when neither is held: the dissipation reported is the kinetic energy
    friction takes from the particles, which over both sides is the impulse times the relative slip, once. The
    block on a free base (lying on a sticky floor), APIC, 0.15 s: the friction counted against the energy the
    friction run loses beyond the frictionless one's (the numerical dissipation both share). Measured 0.926 J
    against 0.922 J (1.004; 0.972 at dx 0.025): the balance closes to 3 %. Asserted 0.85 to 1.15: the impulse's
    work at each side's own slip, counted before, gave 0.64 here (and 4.2 on a coarser-threshold scene)."""
    lost = {}
    for mu in (0.0, 0.3):
        sim = tm.Simulation(tm.load_config(incline_config(30.0, mu, gripped=False, transfer="apic")))
        sim.advance(T)
        b = sim.energy_balance()
        lost[mu] = (b["initial"] - b["total"], b.get("friction", 0.0))
    by_friction = lost[0.3][0] - lost[0.0][0]
    assert by_friction > 0.5   # the friction acted (the block's mu N d is ~1.4 J)
    assert 0.85 * by_friction < lost[0.3][1] < 1.15 * by_friction, (lost, by_friction)


def incline_3d_config(theta_deg, mu, dx=0.025):
    """The incline in 3D: the block 0.2 x 0.1 x 0.1 m on the gripped base 1 x 0.1 x 0.1 m, both spanning the domain's
    depth (flush with its free z faces)."""
    cfg = incline_config(theta_deg, mu, dx=dx)
    a = np.radians(theta_deg)
    cfg.update(dim=3, name="incline3d")
    cfg["domain"].update(lower=[0, 0, 0], upper=[1.0, 0.3, 0.1])
    cfg["solver"]["gravity"] = [G * np.sin(a), -G * np.cos(a), 0.0]
    for body, (lo, hi) in zip(cfg["bodies"], [([0, 0, 0], [1.0, 0.1, 0.1]), ([0.1, 0.1, 0], [0.3, 0.2, 0.1])]):
        body["shape"].update(lower=lo, upper=hi)
    cfg["bodies"][0]["prescribed_velocity"] = [dict(velocity=[0.0, 0.0, 0.0])]
    return cfg


@pytest.mark.slow
@pytest.mark.parametrize("mu", [0.0, 0.3])
def test_block_slides_down_an_incline_in_3d(mu):
    """The 3D incline (6144 particles, ~20 s each on 2 cores): measured 1.0000 of g sin 30 frictionless and 0.9926
    of g (sin 30 - mu cos 30) at mu 0.3. Asserted within 2 % (the issue's bar) and 1 % frictionless."""
    sim = tm.Simulation(tm.load_config(incline_3d_config(30.0, mu)))
    t, v, _ = body_motion(sim, 1, T)
    a = np.radians(30.0)
    ref = G * (np.sin(a) - mu * np.cos(a))
    late = t > 0.05
    accel = np.polyfit(t[late], v[late], 1)[0]
    assert accel == pytest.approx(ref, rel=0.01 if mu == 0 else 0.02), (accel, ref)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="the crack finder's friction does not hold a block that should stick: it "
                   "creeps (docs/crack_finder.md, 'Friction')")
def test_block_stays_at_rest_where_friction_holds_it():
    """At 20 deg with mu 0.5 > tan 20 the block should stay at rest: drift below 1e-3 of g t^2 / 2 (the issue's bar).
    Measured: 2.0e-2 at dx 0.025 in 2D (1.9e-2 in 3D; 5.2e-2 at dx 0.05), a steady creep of ~0.011 m/s: friction
    stops the nodes where the sides meet, but the particles' tangential functions, renormalised over their own
    side's nodes, read the nodes above them, which gravity moves each step (docs/crack_finder.md, "Friction")."""
    t, v, sim = incline(20.0, 0.5)
    x = np.cumsum(np.diff(np.concatenate([[0.0], t])) * v)
    assert abs(x[-1]) < 1e-3 * 0.5 * G * T**2, x[-1] / (0.5 * G * T**2)
