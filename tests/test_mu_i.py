"""mu_i (materials/mu_i.py) on one material point, f64, driven by small Taichi kernels: steady simple shear at a
prescribed shear rate and normal stress against tau / p = mu(I) of Jop, Forterre & Pouliquen 2006, in plane strain
and 3D over I = 1e-3 .. 2; the granular gas of Dunatunga & Kamrin 2015 (stress-free when looser than the initial
packing, density tracked, load borne again once compacted back); no excess stress below yield; the schema's
ranges."""
import math

import numpy as np
import pytest
import taichi as ti

from taichi_mpm.config import Material
from taichi_mpm.materials import MODELS
from taichi_mpm.materials.mu_i import friction

from conftest import fast_subset

E, NU, RHO = 1.0e8, 0.3, 1500.0
MU_S, MU_2, I0, D, PHI = 0.38, 0.64, 0.279, 1.0e-3, 0.6
RHO_S = RHO / PHI


def material(**over):
    keys = dict(model="mu_i", density=RHO, E=E, nu=NU, mu_s=MU_S, mu_2=MU_2, I0=I0, grain_diameter=D,
                solid_fraction=PHI, max_pressure=1.0e5)
    keys.update(over)
    return Material(**keys)


def _init(fp=ti.f64):
    ti.init(arch=ti.cpu, default_fp=fp, offline_cache=True, log_level=ti.ERROR)


def simple_shear(dim, rates, pressures, steps=400, shear=2e-3):
    """Each (rate, pressure) case: a point compressed isotropically to the normal stress p, then sheared at the
    rate (L = rate e_x e_y) by `shear` in `steps` steps, the vertical stretch rate found by the secant method so that
    the returned (elastic) tau_yy = -p. Returns the final total Kirchhoff stress (3x3, the excess of the final L
    included) and the volume ratio."""
    _init()
    m = material()
    cls = MODELS["mu_i"]
    nq = len(cls.state(dim))
    funcs = cls.build(m, dim, nq)
    n = len(rates)
    rate, pres = ti.field(float, n), ti.field(float, n)
    rate.from_numpy(np.asarray(rates, float))
    pres.from_numpy(np.asarray(pressures, float))
    out = ti.Matrix.field(3, 3, float, n)
    vol = ti.field(float, n)
    K = m.E / (3 * (1 - 2 * m.nu))
    q0 = [s.init for s in cls.state(dim)]

    @ti.func
    def velocity_gradient(g, x):
        L = ti.Matrix.zero(float, dim, dim)
        L[0, 1] = g
        L[1, 1] = x
        return L

    @ti.func
    def step(F, q, g, x, dt):
        return funcs.project((ti.Matrix.identity(float, dim) + dt * velocity_gradient(g, x)) @ F, q)

    @ti.func
    def controlled_step(F, q, g, dt, p0):
        """The step whose returned tau_yy is -p0: the secant method on the vertical stretch rate, one inlined
        return map (each call site of a func compiles it again). Returns F, q and the rate."""
        Fk, qk = F, q
        x, x_prev, r_prev = 0.0, 0.0, 0.0
        for it in range(30):
            Fn, qn, dd = step(F, q, g, x, dt)
            Fk, qk = Fn, qn
            r = funcs.kirchhoff3(Fn, ti.Matrix.zero(float, dim, dim), qn)[1, 1] + p0
            if ti.abs(r) <= 1e-12 * p0 or (it > 0 and r == r_prev):
                break
            x_new = g
            if it > 0:
                x_new = x - r * (x - x_prev) / (r - r_prev)
            x_prev, r_prev = x, r
            x = x_new
        return Fk, qk, x

    @ti.kernel
    def go():
        for c in range(n):
            g, p0 = rate[c], pres[c]
            dt = shear / (steps * g)
            e0 = -p0 / (3.0 * K)
            F = ti.exp(e0) * ti.Matrix.identity(float, dim)
            q = ti.Vector(q0, float)
            if ti.static(dim < 3):
                q[2] = ti.exp(e0)
            x1 = 0.0
            for s in range(steps):
                F, q, x1 = controlled_step(F, q, g, dt, p0)
            out[c] = funcs.kirchhoff3(F, velocity_gradient(g, x1), q)
            vol[c] = funcs.volume_ratio(F, q)

    go()
    return out.to_numpy(), vol.to_numpy()


@pytest.mark.parametrize("dim", fast_subset([2, 3], [2]))
def test_simple_shear_friction_is_mu_of_I(dim):
    """Steady simple shear at rates giving I = 1.6e-3 .. 2 under normal stresses 1 and 10 kPa: tau_xy / sigma_n on
    the shear plane against mu(I), I = rate d sqrt(rho_s / p) with p the Cauchy normal stress. Tolerance 1e-3
    relative: the elastic strain (p / E = 1e-5, 1e-4) turns with the material in simple shear; measured max error
    4.7e-6 at 1 kPa and 3.8e-5 at 10 kPa, in 2D and 3D alike (docs/materials.md)."""
    rates = np.array([1.0, 30.0, 200.0, 1300.0, 3.0, 100.0])
    pressures = np.array([1e3, 1e3, 1e3, 1e3, 1e4, 1e4])
    t, J = simple_shear(dim, rates, pressures)
    sigma_n = -t[:, 1, 1] / J
    inertial = rates * D * np.sqrt(RHO_S / sigma_n)
    ratio = t[:, 0, 1] / -t[:, 1, 1]
    expect = np.array([friction(i, MU_S, MU_2, I0) for i in inertial])
    assert inertial.min() < 2e-3 and inertial.max() > 1.5
    assert np.abs(ratio / expect - 1).max() < 1e-3, (ratio, expect)
    assert np.allclose(-t[:, 1, 1], pressures, rtol=1e-3)


def project_path(dim, Fs, q0):
    """The states of one point through a sequence of total F increments (Fs: (n, dim, dim) increments): per step the
    Kirchhoff stress (3x3), the volume ratio and J_p."""
    _init()
    m = material()
    cls = MODELS["mu_i"]
    funcs = cls.build(m, dim, len(q0))
    n = len(Fs)
    dF = ti.Matrix.field(dim, dim, float, n)
    dF.from_numpy(Fs)
    tau = ti.Matrix.field(3, 3, float, n)
    vol, jp = ti.field(float, n), ti.field(float, n)

    @ti.kernel
    def go():
        F = ti.Matrix.identity(float, dim)
        q = ti.Vector(q0, float)
        for _ in range(1):
            for s in range(n):
                Fn, qn, dd = funcs.project(dF[s] @ F, q)
                F = Fn
                q = qn
                tau[s] = funcs.kirchhoff3(F, ti.Matrix.zero(float, dim, dim), q)
                vol[s] = funcs.volume_ratio(F, q)
                jp[s] = q[1]

    go()
    return tau.to_numpy(), vol.to_numpy(), jp.to_numpy()


def test_granular_gas_is_stress_free_when_loose_and_tracks_the_density():
    """3D point: isotropic stretch to J = 1.2 with shear (20 steps) is stress-free (|tau| < 1e-9 of K ln J), its
    volume ratio (density rho0 / J) follows det F exactly and J_p takes it; compressed back (20 steps to J = 0.995)
    it stays stress-free until the initial packing is reached, then bears the pressure K (-ln J)."""
    up = [np.diag([1.2 ** (1 / 60)] * 3) @ (np.eye(3) + 1e-3 * np.array([[0, 1, 0], [0, 0, 0], [0, 0, 0]]))
          for _ in range(20)]
    down = [np.diag([(0.995 / 1.2) ** (1 / 60)] * 3)] * 20
    Fs = np.array(up + down)
    tau, vol, jp = project_path(3, Fs, [0.0, 1.0])
    total = np.cumprod([np.linalg.det(f) for f in Fs])
    assert np.allclose(vol, total, rtol=1e-12)
    K = E / (3 * (1 - 2 * NU))
    scale = K * math.log(1.2)
    loose = total > 1.0 + 1e-12
    assert np.abs(tau[loose]).max() < 1e-9 * scale
    assert (jp[:20] > 1).all() and jp[-1] == pytest.approx(1.0, abs=1e-12)
    p = -np.trace(tau[-1]) / 3
    assert p == pytest.approx(-K * math.log(0.995), rel=1e-9)


def test_granular_gas_has_no_excess_stress():
    """Sand loosened at the apex (J_p > 1) is stress-free: no viscous excess either, even where its elastic stress,
    round-off after the apex return, reads a positive pressure on the yield surface (before, J 2 eta dev D with
    J = det F_e J_p took that round-off times J_p). Plane strain, f64: a strain of 1e-7 (round-off's size) past
    yield, L = 3000 / s; the same point packed (J_p = 1) gets the excess."""
    _init()
    funcs = MODELS["mu_i"].build(material(), 2, 3)
    F = ti.Matrix.field(2, 2, float, 2)
    q = ti.Vector.field(3, float, 2)
    ex, pw = ti.Matrix.field(3, 3, float, 2), ti.field(float, 2)
    F.from_numpy(np.repeat(np.diag([1 - 2e-7, 1 + 1e-7])[None], 2, 0))
    q.from_numpy(np.array([[0.0, 1.0, 1.0], [0.0, 1.0e6, 1.0]]))   # packed; loosened a million times

    @ti.kernel
    def excess():
        for i in F:
            L = ti.Matrix([[3000.0, 0.0], [0.0, 2000.0]])
            ex[i] = funcs.kirchhoff3(F[i], L, q[i]) - funcs.kirchhoff3(F[i], ti.Matrix.zero(float, 2, 2), q[i])
            pw[i] = funcs.viscous_power(F[i], L, q[i])

    excess()
    e, p = ex.to_numpy(), pw.to_numpy()
    assert np.abs(e[0]).max() > 0 and p[0] > 0      # packed: the excess of a flowing particle
    assert (e[1] == 0).all() and p[1] == 0.0         # the gas: none


@pytest.mark.slow
def test_no_excess_stress_below_yield():
    """An elastic point (pressure 1 kPa, shear far below mu_s p) with a large velocity gradient: the stress is the
    elastic one (bit for bit) and the excess power zero; at yield it is 2 J eta dev D with power tau_ex : L > 0."""
    _init()
    m = material()
    funcs = MODELS["mu_i"].build(m, 3, 2)
    K = m.E / (3 * (1 - 2 * m.nu))
    F = np.exp(-1e3 / (3 * K)) * np.repeat(np.eye(3)[None], 2, 0)
    F[0, 0, 1], F[1, 0, 1] = 1e-7, 1e-4                  # below yield; far past it (returned to the cone first)
    Fi, Fp = ti.Matrix.field(3, 3, float, 2), ti.Matrix.field(3, 3, float, 4)
    qi, qp = ti.Vector.field(2, float, 2), ti.Vector.field(2, float, 4)
    Lp = ti.Matrix.field(3, 3, float, 4)
    out, pw = ti.Matrix.field(3, 3, float, 4), ti.field(float, 4)
    Fi.from_numpy(F)
    qi.from_numpy(np.tile([0.0, 1.0], (2, 1)))

    @ti.kernel
    def project():
        for i in Fi:
            Fn, qn, dd = funcs.project(Fi[i], qi[i])
            Fp[i], qp[i] = Fn, qn

    @ti.kernel
    def stress():
        for i in Fp:
            out[i] = funcs.kirchhoff3(Fp[i], Lp[i], qp[i])
            pw[i] = funcs.viscous_power(Fp[i], Lp[i], qp[i])

    project()
    Fr, qr = Fp.to_numpy()[:2], qp.to_numpy()[:2]
    assert (Fr[0] == F[0]).all() and not np.allclose(Fr[1], F[1])
    L = np.zeros((3, 3))
    L[0, 1] = 50.0
    Fp.from_numpy(np.concatenate([Fr, Fr]))
    qp.from_numpy(np.concatenate([qr, qr]))
    Lp.from_numpy(np.stack([L, L, 0 * L, 0 * L]))
    stress()
    t, power = out.to_numpy(), pw.to_numpy()
    assert (t[0] == t[2]).all() and power[0] == 0.0
    ex = t[1] - t[3]
    assert ex[0, 1] > 0 and np.abs(np.diag(ex)).max() < 1e-12 * ex[0, 1]
    assert power[1] == pytest.approx(50.0 * ex[0, 1], rel=1e-12)


def test_schema_ranges_name_the_key():
    """Out-of-range parameters are a ConfigError naming the key (materials.<name>.<key>)."""
    from taichi_mpm.config import ConfigError, load_config
    from conftest import make_cfg

    good = dict(model="mu_i", density=RHO, E=E, nu=NU, mu_s=MU_S, mu_2=MU_2, grain_diameter=D, max_pressure=1e4)
    for key, bad in (("mu_2", 0.3), ("mu_s", 0.0), ("grain_diameter", 0.0), ("solid_fraction", 1.5), ("I0", -1.0),
                     ("max_pressure", 0.0)):
        cfg = make_cfg()
        cfg["materials"]["m"] = dict(good, **{key: bad})
        with pytest.raises(ConfigError) as info:
            load_config(cfg)
        assert info.value.key == f"materials.m.{key}", (key, info.value)
    cfg = make_cfg()
    cfg["materials"]["m"] = good
    m = load_config(cfg).materials["m"]
    assert m.viscosity == pytest.approx((MU_2 - MU_S) * D * math.sqrt(RHO / 0.6 * 1e4) / I0)


def bagnold_mean_velocity(h, theta, d=D, phi=PHI, mu_s=MU_S, mu_2=MU_2, i0=I0, g=9.81):
    """Depth-averaged velocity of steady mu(I) flow down a plane inclined at theta (no slip at the base, free
    surface at h; GDR MiDi 2004, Jop et al. 2006). Momentum balance of the uniform layer: tau(z) = rho g sin(theta)
    (h - z), p(z) = rho g cos(theta) (h - z) (rho = phi rho_s the bulk density), so tau / p = tan(theta) = mu(I)
    at every depth: I_theta = I0 (tan(theta) - mu_s) / (mu_2 - tan(theta)) is uniform. The shear rate is then
    du/dz = I_theta sqrt(p / rho_s) / d = (I_theta / d) sqrt(phi g cos(theta) (h - z)), and with u(0) = 0
    u(z) = (2/3) (I_theta / d) sqrt(phi g cos(theta)) (h^(3/2) - (h - z)^(3/2)) (the Bagnold profile), whose depth
    average is (1/h) int_0^h u dz = (2/5) (I_theta / d) sqrt(phi g cos(theta)) h^(3/2)."""
    t = math.tan(theta)
    inertial = i0 * (t - mu_s) / (mu_2 - t)
    return 0.4 * inertial / d * math.sqrt(phi * g * math.cos(theta)) * h ** 1.5


@pytest.mark.slow
def test_inclined_plane_flow_follows_bagnold():
    """A layer h = 1 cm thick (10 cells, 2 x 2 particles per cell, quadratic APIC, f64) and 0.6 m long on a rough
    (sticky) floor, gravity tilted by 24 deg (tan = 0.445 between mu_s = 0.38 and mu_2 = 0.64: I_theta = 0.093),
    grains d = 1 mm, starting at rest; no wall ahead (the front runs free) and a slip wall behind. The mean velocity of
    the particles in the window 0.3 .. 0.42 m (the depth average there) against the Bagnold law at the window's
    thickness (its particles' volume / width): measured 0.3468 of it at 0.05 s, 0.97 at 0.7 s, 1.0020 at 0.9 s,
    1.0074 at 1.0 s (0.08579 m/s against 0.08516 at h = 9.88 mm), changing by 0.2 % over the last 0.1 s. The layer
    has no periodic boundary: the rarefaction from the tail (kinematic waves at 2.5 u) reaches the window after
    ~1.1 s, so the check is at 1.0 s. 24 000 particles, ~10 600 steps, 170 s on 2 shared cores."""
    from conftest import make_cfg
    import taichi_mpm as tm

    h, theta, length = 0.01, math.radians(24.0), 0.6
    cfg = make_cfg(2, precision="f64", dx=h / 10, model="mu_i", E=2e4, nu=0.3, density=RHO, lower=[0.0, 0.0],
                   upper=[length, h], end_time=1.0)
    cfg["domain"]["upper"] = [2 * length, 2 * h]
    cfg["domain"]["boundaries"] = dict(default="slip", y_min="sticky", x_max="free", y_max="free")
    cfg["solver"]["gravity"] = [9.81 * math.sin(theta), -9.81 * math.cos(theta)]
    cfg["materials"]["m"].update(mu_s=MU_S, mu_2=MU_2, I0=I0, grain_diameter=D, solid_fraction=PHI,
                                 max_pressure=1.5 * RHO * 9.81 * h)
    cfg["bodies"][0]["particles_per_cell"] = 2
    sim = tm.Simulation(cfg)
    ratios, speeds = [], []
    for _ in range(2):
        sim.advance_to(0.9 if not speeds else 1.0)
        p = sim.particles()
        x, v, vol = p["x"], p["v"], p["volume"]
        win = (x[:, 0] > 0.5 * length) & (x[:, 0] < 0.7 * length)
        h_win = vol[win].sum() / (0.2 * length)
        speeds.append(v[win, 0].mean())
        ratios.append(speeds[-1] / bagnold_mean_velocity(h_win, theta))
    assert abs(ratios[-1] - 1.0) < 0.05, ratios
    assert abs(speeds[1] / speeds[0] - 1.0) < 0.02, speeds       # steady
