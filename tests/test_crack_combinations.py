"""The crack finder with the rest of the sandbox (issue 27): grips (bodies[].prescribed_velocity), velocity walls and
wall probes act after its node solve in the grid solve's one chain (step.grid_update), as at every node."""
import numpy as np

import taichi_mpm as tm

F_T, H, NOTCH = 500.0, 0.2, 0.05      # tensile strength (Pa), bar height and notch depth (m)


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


def test_notched_bar_pulled_by_grips_cracks_through():
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
