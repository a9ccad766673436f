"""Closed-form problems for verification tests and speed/accuracy studies.

Each `Problem` gives a full config dict (`config()`), an optional body force
`body_force(X0, t) -> (N, d)` acceleration at reference positions, custom initial conditions
(`setup(sim)`), and error norms against the exact solution (`errors(sim)`). Studies apply dotted
overrides (domain.dx, solver.basis, ...) on top of `config()`; everything that depends on dx
(time step) is given through `solver.cfl` so it follows such overrides.

Problems
- vibrating_bar: Bardenhagen's 1D bar (E = 100, rho = 1, L = 25, v0 = 0.1), ends fixed-fixed
  (u = v0/w sin(w t) sin(pi X/L), w = pi c/L) or fixed-free (u = v0/w sin(w t) sin(beta X),
  beta = pi/(2L), w = beta c; centre-of-mass velocity v0/(beta L) cos(w t)).
- mms_axis_aligned: manufactured solution u_i = G sin(pi X_i) sin(c pi t), c = sqrt(E/rho0), for the
  solver's neo-Hookean model in 1D/2D/3D (body force derived below, for any nu).
- generalized_vortex: 2D ring 0.75 <= R <= 1.25 rotated by alpha = G sin(pi t/T) h(R),
  h = (1 - 16 (R-1)^2)^2 (neo-Hookean, incompressible motion, traction-free edges).
- colliding_disks: two elastic disks (Sulsky et al. 1994); no exact solution, errors() gives energy measures.
- hertz: 3D elastic sphere dropped on a rigid wall; contact duration against Hertz theory.

Physics only: no I/O.
"""

import math
from typing import Callable, Optional

import numpy as np

from .bases import registry as bases
from .config import load_config
from .solver import Simulation


# ---------------------------------------------------------------- helpers
def neo_hookean_pk1(F: np.ndarray, mu: float, lam: float) -> np.ndarray:
    """First Piola-Kirchhoff stress of the solver's neo-Hookean model, P = mu (F - F^-T) + lam ln J F^-T.
    F: (..., d, d)."""
    J = np.linalg.det(F)
    FinvT = np.swapaxes(np.linalg.inv(F), -1, -2)
    return mu * (F - FinvT) + (lam * np.log(J))[..., None, None] * FinvT


def lame(E: float, nu: float) -> tuple[float, float]:
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def _norms(err: np.ndarray) -> dict:
    """RMS and max over particles of the error vector length."""
    e = np.linalg.norm(err, axis=-1) if err.ndim > 1 else np.abs(err)
    return {"error_rms": float(np.sqrt(np.mean(e**2))), "error_max": float(np.max(e))}


def _base_config(name, dim, lower, upper, dx, bodies, materials, end_time, *, basis=bases.DEFAULT,
                 transfer="flip", flip_blend=1.0, cfl=0.4, boundaries=None, precision="f64", **solver):
    return dict(
        name=name, dim=dim, precision=precision, arch="cpu",
        domain=dict(lower=list(map(float, lower)), upper=list(map(float, upper)), dx=float(dx),
                    boundaries=boundaries or {"default": "slip"}),
        solver=dict(basis=basis, transfer=transfer, flip_blend=flip_blend, cfl=cfl, end_time=float(end_time),
                    **solver),   # other solver keys as given (solver.quadrature)
        materials=materials, bodies=bodies,
        output=dict(formats=[]),
    )


class Problem:
    """Base class: subclasses set `name`, `end_time` and implement config/setup/errors."""

    name: str = "problem"
    end_time: float = 1.0
    body_force: Optional[Callable] = None

    def config(self) -> dict:
        raise NotImplementedError

    def setup(self, sim) -> None:
        """Custom initial conditions before stepping (default: none)."""

    def observe(self, sim) -> None:
        """Called by run_problem after every step (problems with history-based measures use it)."""

    def errors(self, sim) -> dict:
        raise NotImplementedError


# ---------------------------------------------------------------- vibrating bar
class VibratingBar(Problem):
    """Bardenhagen's 1D bar, fixed-fixed or fixed-free, linear elastic (nu = 0)."""

    def __init__(self, ends="fixed-fixed", E=100.0, density=1.0, length=25.0, v0=0.1, cells=16,
                 particles_per_cell=2, end_time=2.5, **solver):
        if ends not in ("fixed-fixed", "fixed-free"):
            raise ValueError(f"vibrating_bar ends must be fixed-fixed or fixed-free, got {ends!r}")
        self.name = "vibrating_bar" if ends == "fixed-fixed" else "vibrating_bar_fixed_free"
        self.ends, self.E, self.rho, self.L, self.v0 = ends, E, density, length, v0
        self.cells, self.ppc, self.end_time, self.solver = cells, particles_per_cell, end_time, solver
        self.c = math.sqrt(E / density)
        self.k = math.pi / length if ends == "fixed-fixed" else math.pi / (2 * length)  # wave number
        self.omega = self.k * self.c

    def config(self) -> dict:
        L = self.L
        upper = L if self.ends == "fixed-fixed" else 2 * L  # room for the free end to move
        bounds = {"default": "sticky"} if self.ends == "fixed-fixed" else {"default": "free", "x_min": "sticky"}
        body = dict(name="bar", shape=dict(type="box", lower=[0.0], upper=[L]), material="bar",
                    particles_per_cell=self.ppc)
        mats = {"bar": dict(model="linear_elastic", E=self.E, nu=0.0, density=self.rho)}
        kw = dict(transfer="flip", flip_blend=1.0, cfl=0.1)
        kw.update(self.solver)
        return _base_config(self.name, 1, [0.0], [upper], L / self.cells, [body], mats, self.end_time,
                            boundaries=bounds, **kw)

    def exact_displacement(self, X, t):
        return (self.v0 / self.omega) * math.sin(self.omega * t) * np.sin(self.k * X)

    def exact_com_velocity(self, t):
        """Centre-of-mass velocity (1/L) int v dX."""
        return self.v0 * math.cos(self.omega * t) * (1 - math.cos(self.k * self.L)) / (self.k * self.L)

    def setup(self, sim):
        X = sim.scene.x[:, 0]
        sim.set_particles(v=(self.v0 * np.sin(self.k * X))[:, None])

    def errors(self, sim):
        X = sim.scene.x[:, 0]
        p = sim.particles()
        out = _norms(p["x"][:, 0] - X - self.exact_displacement(X, sim.time))
        out["error_rel"] = out["error_rms"] / (self.v0 / self.omega)   # relative to the displacement amplitude
        vcm = float(np.sum(p["mass"] * p["v"][:, 0]) / np.sum(p["mass"]))
        out["error_com_velocity"] = abs(vcm - self.exact_com_velocity(sim.time))
        return out


# ---------------------------------------------------------------- axis-aligned MMS
class AxisAlignedMMS(Problem):
    """u_i = G sin(pi X_i) sin(c pi t), c = sqrt(E/rho0), neo-Hookean.

    With F = diag(F_1..F_d), F_i = 1 + pi G cos(pi X_i) sin(c pi t), J = prod F_i, the solver's model
    gives P_ii = mu (F_i - 1/F_i) + lam ln J / F_i, and since d(ln J)/dX_i = F_i'/F_i,
        dP_ii/dX_i = F_i' [mu (1 + 1/F_i^2) + lam (1 - ln J)/F_i^2],   F_i' = -pi^2 u_i.
    The body force b = u_tt - Div P / rho0 with u_tt = -c^2 pi^2 u_i = -(E/rho0) pi^2 u_i is
        b_i = (pi^2 u_i / rho0) [lam (1 - ln J)/F_i^2 + mu (1 + 1/F_i^2) - E].
    In 1D (J = F) this is the published form; in 2D/3D ln J replaces ln F_i (the difference only
    matters for nu != 0).

    Layout: 1D and `layout="walls"`: body = domain = [0, L]^d, u = 0 on the walls (sticky in 1D).
    In 2D/3D the walls would need a two-sided slip condition (normal velocity zero both ways, tangent
    free), which the grid does not offer (`slip` lets the body separate), so the default there is
    `layout="free"`: body [L/2, 3L/2]^d in a domain [0, 2L]^d with free walls. On those faces
    F_i = 1 and, for nu = 0, P_ii = 0: the exact solution is traction free, so free surfaces are exact.
    """

    L = 1.0  # unit length: u = G sin(pi X)

    def __init__(self, dim=1, amplitude=1e-4, E=1e7, nu=0.0, density=1000.0, end_time=0.02,
                 cells=16, particles_per_cell=2, layout=None, **solver):
        self.dim, self.G, self.E, self.nu, self.rho = dim, amplitude, E, nu, density
        self.mu, self.lam = lame(E, nu)
        self.c = math.sqrt(E / density)
        self.end_time, self.cells, self.ppc, self.solver = end_time, cells, particles_per_cell, solver
        self.layout = layout or ("walls" if dim == 1 else "free")
        if self.layout not in ("walls", "free"):
            raise ValueError(f"mms layout must be walls or free, got {self.layout!r}")
        self.name = f"mms_axis_aligned_{dim}d"
        self.body_force = self._body_force

    def config(self) -> dict:
        d, L = self.dim, self.L
        if self.layout == "free" and self.nu != 0:
            raise ValueError("the free-surface MMS layout is traction free only for nu = 0")
        if self.layout == "walls" and d > 1:
            raise ValueError("mms layout 'walls' in 2D/3D needs a two-sided slip wall the grid does not have; "
                             "use layout 'free' (nu = 0)")
        if self.layout == "walls":
            lo, hi, dlo, dhi, bounds = [0.0] * d, [L] * d, [0.0] * d, [L] * d, {"default": "sticky"}
        else:
            lo, hi, dlo, dhi, bounds = [L / 2] * d, [1.5 * L] * d, [0.0] * d, [2 * L] * d, {"default": "free"}
        body = dict(name="block", shape=dict(type="box", lower=lo, upper=hi), material="m",
                    particles_per_cell=self.ppc)
        mats = {"m": dict(model="neo_hookean", E=self.E, nu=self.nu, density=self.rho)}
        kw = dict(transfer="flip", flip_blend=1.0, cfl=0.2)
        kw.update(self.solver)
        return _base_config(self.name, d, dlo, dhi, L / self.cells, [body], mats, self.end_time,
                            boundaries=bounds, **kw)

    def _phase(self, t):
        return math.sin(self.c * math.pi * t)

    def exact_displacement(self, X, t):
        return self.G * np.sin(math.pi * X) * self._phase(t)

    def exact_velocity(self, X, t):
        return self.G * np.sin(math.pi * X) * self.c * math.pi * math.cos(self.c * math.pi * t)

    def _body_force(self, X, t):
        u = self.G * np.sin(math.pi * X) * self._phase(t)
        Fi = 1.0 + math.pi * self.G * np.cos(math.pi * X) * self._phase(t)
        lnJ = np.sum(np.log(Fi), axis=1, keepdims=True)
        return (math.pi**2 * u / self.rho) * (self.lam * (1 - lnJ) / Fi**2 + self.mu * (1 + 1 / Fi**2) - self.E)

    def setup(self, sim):
        sim.set_particles(v=self.exact_velocity(sim.scene.x, 0.0))

    def errors(self, sim):
        X = sim.scene.x
        out = _norms(sim.particles()["x"] - X - self.exact_displacement(X, sim.time))
        out["error_rel"] = out["error_rms"] / self.G   # relative to the displacement amplitude
        return out


# ---------------------------------------------------------------- generalized vortex
class GeneralizedVortex(Problem):
    """2D ring 0.75 <= R <= 1.25 (centre at the origin) whose material circles rotate by
    alpha(R, t) = g(t) h(R), g = G sin(pi t / T), h = (1 - 16 (R-1)^2)^2:  x = Q(alpha) X.

    Derivation (current polar basis e_r, e_theta at theta = Theta + alpha; r = R):
      F = Q (I + gamma E_Theta (x) E_R), gamma = R dalpha/dR = R g h', J = 1, so the solver's
      neo-Hookean gives sigma = tau = mu (B - I) = mu [gamma (e_r e_th + e_th e_r) + gamma^2 e_th e_th].
      div sigma = -mu gamma^2 / r e_r + mu (gamma' + 2 gamma / r) e_th
                = -mu R g^2 h'^2 e_r + mu g (3 h' + R h'') e_th.
      Acceleration x_tt = -R (h dg/dt)^2 e_r + R h d2g/dt2 e_th.
      b = x_tt - div sigma / rho0:
        b_r  = -R (h dg/dt)^2 + (mu/rho0) R g^2 h'^2
        b_th =  R h d2g/dt2   - (mu/rho0) g (3 h' + R h'')
    (In the reference basis E_R, E_Theta the R (h dg/dt)^2 term enters the tangential component as
    -R (h dg/dt)^2 sin(alpha); the widely circulated form has it with a + sign.)
    sigma = 0 on R = 0.75 and 1.25 (h' = 0 there): the ring edges are traction free.

    Defaults: E = 1e3, rho0 = 1000, nu = 0.3, T = 1, so inertia and elastic forces are of one order
    (with E = 1e6 the body force is ~1e3 times the acceleration and any O(dx^2) stress error swamps
    the motion). G = 0.05 (peak shear R g h' ~ 0.3) converges with 2 particles per cell; G >= 0.25
    (shear >= 1.5) is measured to lose accuracy under refinement and G = 1 to blow up at t ~ 0.4-0.7
    with every transfer at 48 and 96 cells over [-1.5, 1.5]^2.
    """

    name = "generalized_vortex"

    def __init__(self, amplitude=0.05, period=1.0, E=1e3, nu=0.3, density=1000.0, cells=48,
                 particles_per_cell=2, end_time=None, grid="cartesian", **solver):
        if grid not in ("cartesian", "polar"):
            raise ValueError(f"generalized_vortex grid must be cartesian or polar, got {grid!r}")
        if grid == "polar" and cells % 4:
            raise ValueError(f"the polar grid of generalized_vortex needs cells divisible by 4, got {cells}")
        self.grid = grid
        self.G, self.T, self.E, self.nu, self.rho = amplitude, period, E, nu, density
        self.mu, self.lam = lame(E, nu)
        self.cells, self.ppc, self.solver = cells, particles_per_cell, solver
        self.end_time = period if end_time is None else end_time
        self.body_force = self._body_force

    def config(self) -> dict:
        body = dict(name="ring", shape=dict(type="ring", center=[0.0, 0.0], inner_radius=0.75, outer_radius=1.25),
                    material="m", particles_per_cell=self.ppc)
        mats = {"m": dict(model="neo_hookean", E=self.E, nu=self.nu, density=self.rho)}
        kw = dict(transfer="flip", flip_blend=1.0, cfl=0.3)
        kw.update(self.solver)
        cfg = _base_config(self.name, 2, [-1.5, -1.5], [1.5, 1.5], 3.0 / self.cells, [body], mats,
                           self.end_time, boundaries={"default": "free"}, **kw)
        if self.grid == "polar":
            # the body-fitted grid (domain.map): an annulus a quarter of the ring's width wider on each side (free
            # edges move a little in the discrete solution and must stay on the grid), radial cells of dx
            # (cells / 4 over 0.625..1.375), 2 cells angular cells (2 pi / (2 cells) ~ dx at R = 1); particles as
            # on the Cartesian grid
            cfg["domain"]["map"] = dict(type="annulus", inner_radius=0.625, outer_radius=1.375, angle=360.0,
                                        cells=[2 * self.cells, self.cells // 4])
        return cfg

    # g(t) and derivatives, h(R) and derivatives
    def g(self, t):
        w = math.pi / self.T
        return self.G * math.sin(w * t), self.G * w * math.cos(w * t), -self.G * w * w * math.sin(w * t)

    @staticmethod
    def h(R):
        s = R - 1.0
        q = 1.0 - 16.0 * s**2
        return q**2, -64.0 * s * q, -64.0 * q + 2048.0 * s**2

    def exact_position(self, X, t):
        R = np.linalg.norm(X, axis=1)
        a = self.g(t)[0] * self.h(R)[0]
        c, s = np.cos(a), np.sin(a)
        return np.stack([c * X[:, 0] - s * X[:, 1], s * X[:, 0] + c * X[:, 1]], axis=1)

    def exact_velocity(self, X, t):
        R = np.linalg.norm(X, axis=1)
        h = self.h(R)[0]
        x = self.exact_position(X, t)
        return self.g(t)[1] * h[:, None] * np.stack([-x[:, 1], x[:, 0]], axis=1)

    def _body_force(self, X, t):
        R = np.linalg.norm(X, axis=1)
        g, dg, d2g = self.g(t)
        h, dh, d2h = self.h(R)
        k = self.mu / self.rho
        b_r = -R * (h * dg) ** 2 + k * R * g**2 * dh**2
        b_t = R * h * d2g - k * g * (3 * dh + R * d2h)
        x = self.exact_position(X, t)
        er = x / R[:, None]
        et = np.stack([-er[:, 1], er[:, 0]], axis=1)
        return b_r[:, None] * er + b_t[:, None] * et

    def setup(self, sim):
        sim.set_particles(v=self.exact_velocity(sim.scene.x, 0.0))

    def errors(self, sim):
        X = sim.scene.x
        return _norms(sim.particles()["x"] - self.exact_position(X, sim.time))


# ---------------------------------------------------------------- colliding disks
class CollidingDisks(Problem):
    """Two elastic disks meeting head on (Sulsky, Chen & Schreyer 1994): radius 0.2 at (0.2, 0.2) and
    (0.8, 0.8) in the unit square, velocities +-(v, v). No exact solution: errors() reports energy
    measures from the history recorded by observe(): the total energy ratio E(t)/E(0) at the end and
    its minimum, and `error_energy` = 1 - E(end)/E(0)."""

    name = "colliding_disks"

    def __init__(self, E=1000.0, nu=0.3, density=1000.0, speed=0.1, cells=20, particles_per_cell=2,
                 end_time=3.0, model="neo_hookean", **solver):
        self.E, self.nu, self.rho, self.speed, self.model = E, nu, density, speed, model
        self.cells, self.ppc, self.end_time, self.solver = cells, particles_per_cell, end_time, solver
        self.history: list[tuple[float, float, float]] = []

    def config(self) -> dict:
        v = self.speed
        bodies = [dict(name=f"disk{i}", shape=dict(type="sphere", center=[c, c], radius=0.2), material="m",
                       particles_per_cell=self.ppc, velocity=[s * v, s * v])
                  for i, (c, s) in enumerate([(0.2, 1.0), (0.8, -1.0)])]
        mats = {"m": dict(model=self.model, E=self.E, nu=self.nu, density=self.rho)}
        kw = dict(transfer="apic", flip_blend=0.99, cfl=0.4)
        kw.update(self.solver)
        return _base_config(self.name, 2, [0.0, 0.0], [1.0, 1.0], 1.0 / self.cells, bodies, mats, self.end_time,
                            boundaries={"default": "slip"}, **kw)

    def setup(self, sim):
        self.history = []
        self.observe(sim)

    def observe(self, sim):
        e = sim.energy()
        self.history.append((sim.time, e["kinetic"], e["strain"]))

    def errors(self, sim):
        if not self.history or self.history[-1][0] != sim.time:
            self.observe(sim)
        h = np.asarray(self.history)
        total = h[:, 1] + h[:, 2]
        ratio = total / total[0]
        return {"energy_ratio_end": float(ratio[-1]), "energy_ratio_min": float(ratio.min()),
                "error_energy": float(abs(1.0 - ratio[-1]))}


# ---------------------------------------------------------------- Hertz contact
class HertzSphere(Problem):
    """3D elastic sphere (radius R, speed v) hitting the rigid slip wall y = 0.

    Hertz: t_c = 2.87 (m_eff^2 / (R_eff E_eff^2 v))^(1/5) with m_eff = m, R_eff = R and
    E_eff = E / (1 - nu^2) for a rigid wall. The contact interval is where the wall force on the sphere
    (mass times the rate of change of its mean vertical velocity, recorded each step) exceeds
    `threshold` of its peak (the contiguous interval around the peak, so wave ringing after separation
    does not count); errors() gives the relative error of that duration."""

    name = "hertz"

    def __init__(self, radius=0.1, E=1e6, nu=0.3, density=1000.0, speed=1.0, cells=20, gap=0.04,
                 particles_per_cell=2, end_time=None, threshold=0.01, **solver):
        self.R, self.E, self.nu, self.rho, self.speed, self.gap = radius, E, nu, density, speed, gap
        self.cells, self.ppc, self.threshold, self.solver = cells, particles_per_cell, threshold, solver
        self.mass = density * 4.0 / 3.0 * math.pi * radius**3
        E_eff = E / (1 - nu**2)
        self.t_contact = 2.87 * (self.mass**2 / (radius * E_eff**2 * speed)) ** 0.2
        self.end_time = end_time if end_time is not None else gap / speed + 1.5 * self.t_contact + gap / speed
        self.history: list[tuple[float, float]] = []

    def config(self) -> dict:
        R, ext = self.R, 4 * self.R   # a cube of side 4R, so any dx that divides 4R fits (studies override dx)
        height = ext
        body = dict(name="ball", shape=dict(type="sphere", center=[ext / 2, R + self.gap, ext / 2], radius=R),
                    material="m", particles_per_cell=self.ppc, velocity=[0.0, -self.speed, 0.0])
        mats = {"m": dict(model="neo_hookean", E=self.E, nu=self.nu, density=self.rho)}
        kw = dict(transfer="apic", cfl=0.4)
        kw.update(self.solver)
        return _base_config(self.name, 3, [0, 0, 0], [ext, height, ext], ext / self.cells, [body], mats,
                            self.end_time, boundaries={"default": "slip"}, **kw)

    def setup(self, sim):
        self.history = []
        self.observe(sim)

    def observe(self, sim):
        p = sim.momentum()["linear"]
        self.history.append((sim.time, float(p[1])))

    def contact_duration(self) -> float:
        h = np.asarray(self.history)
        t, py = h[:, 0], h[:, 1]
        force = np.diff(py) / np.diff(t)
        peak = int(np.argmax(force))
        if force[peak] <= 0:
            return 0.0
        off = np.nonzero(force <= self.threshold * force[peak])[0]
        before, after = off[off < peak], off[off > peak]
        start = before[-1] + 1 if len(before) else 0          # contiguous interval around the peak
        end = after[0] if len(after) else len(force)
        return float(t[end] - t[start])

    def errors(self, sim):
        tc = self.contact_duration()
        return {"contact_time": tc, "contact_time_hertz": self.t_contact,
                "error_contact_time": abs(tc - self.t_contact) / self.t_contact}


# ---------------------------------------------------------------- registry
PROBLEMS: dict[str, type] = {
    "vibrating_bar": VibratingBar,
    "mms_axis_aligned": AxisAlignedMMS,
    "generalized_vortex": GeneralizedVortex,
    "colliding_disks": CollidingDisks,
    "hertz": HertzSphere,
}


def make_problem(spec: dict) -> Problem:
    """spec = {"type": "mms_axis_aligned", "dim": 1, "amplitude": 0.05, ...}; other keys go to the problem."""
    spec = dict(spec)
    kind = spec.pop("type", None)
    if kind not in PROBLEMS:
        raise ValueError(f"unknown analytic problem {kind!r} (known: {', '.join(PROBLEMS)})")
    return PROBLEMS[kind](**spec)


def run_problem(problem: Problem, overrides: Optional[dict] = None):
    """load_config(problem.config(), overrides) -> Simulation -> setup -> step to end_time -> errors.
    Returns (sim, errors)."""
    cfg = load_config(problem.config(), overrides)
    sim = Simulation(cfg, body_force=problem.body_force)
    problem.setup(sim)
    sim.advance_to(cfg.solver.end_time, on_step=problem.observe)
    return sim, problem.errors(sim)
