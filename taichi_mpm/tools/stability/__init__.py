"""Stability at the extremes: scenarios for the stability map, and the largest stable CFL number.

Each scenario is a problem in the sense of `taichi_mpm.analytic` (config(), setup(sim),
observe(sim), errors(sim), body_force) so a study runs it like any other problem
(`problem: {type: impact, E: 2.0e11, mach: 0.5}`). Times scale with the elastic wave speed c, so a
case takes about the same number of steps whatever E, nu and density are.

Scenarios (2D by default, `dim` 1-3 where it makes sense; unit square domain, `cells` per side):
- impact:       a block hits the slip wall y = 0 at `mach` x c (up to 0.5), then `transits` wave transits.
- compression:  a block starts isotropically compressed to volume ratio J (down to 0.05) and springs
                back in free space (free walls far away).
- rotation:     a disk spins with rim speed `mach` x c for `turns` revolutions, free walls.
- thin:         a plate one particle thick (particles_per_cell 1, thickness dx) with a bending velocity
                profile of peak `mach` x c, free walls.
- edge:         a block moves at `mach` x c toward the x_max wall (`boundary`: free | slip | sticky) and
                reaches it; with a free wall the particles leave the domain.

Every scenario takes `model` (any constitutive model: `model_parameters` gives its material on the stiffness of E
and nu, so the granular and clay models run the same scenarios; configs/studies/stability_map_materials.yaml) and
`material` (the model's own keys to set instead; the stiffness and density the times scale with stay E, nu and
density).

A case is *stable* when it reaches its end time with finite state and mechanical energy at most
`energy_limit` x its initial value; otherwise it must have stopped with `InstabilityError` (cause in
the record). A finished case that breaks the energy bound is "undetected" garbage (see study/case.py).

`python -m taichi_mpm.tools.stability cfl` measures the largest stable CFL number per basis and transfer by
bisection, each trial in its own process (stability/cfl.py, which runs the trials as study cases: the scenarios
here are what a study runs, so this module imports no study code); `python -m taichi_mpm.tools.stability map` draws a
stability study's results (stability/picture.py).
"""

import math

import numpy as np

from ...bases import registry as basis_registry


def _lame(E, nu):
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def model_parameters(model: str, E: float, nu: float) -> dict:
    """The material of a scenario for `model`, with the stiffness of E and nu (so times scale alike): elastic
    models take E and nu; the granular and clay models their typical parameters (dry sand phi 30 deg, no cohesion;
    Jop et al.'s glass beads, 1 mm; a normally consolidated clay with Borja & Tamagnini's indices) on that
    stiffness. cam_clay has no E: its shear modulus is E's, its bulk modulus p0 / kappa* is E's at the initial
    pressure p0 = K kappa*, so the body starts consolidated at p0 (and springs out where nothing holds it).
    mu_i's viscosity is capped at the pressure 0.1 E (a stiff impact's order; it sets only its viscous step)."""
    elastic = dict(E=E, nu=nu)
    if model in ("drucker_prager", "mohr_coulomb"):
        return dict(elastic, friction_angle=30.0)
    if model == "mu_i":
        return dict(elastic, mu_s=0.38, mu_2=0.64, grain_diameter=1e-3, max_pressure=0.1 * E)
    if model == "cam_clay":
        mu, lam = _lame(E, nu)
        kappa = 0.02
        return dict(shear_modulus=mu, kappa_star=kappa, lambda_star=0.1, critical_state_slope=1.2,
                    initial_pressure=(lam + 2.0 * mu / 3.0) * kappa)
    return elastic


class Scenario:
    """Common parts: one material, unit-cube domain of `cells` cells per side, times in units of dx-free c."""

    name = "scenario"
    body_force = None
    boundaries = "free"

    def __init__(self, dim=2, E=1.0e6, nu=0.3, density=1000.0, model="neo_hookean", cells=32, ppc=2,
                 mach=0.1, transits=4.0, precision="f64", material=None, **solver):
        if not 1 <= int(dim) <= 3:
            raise ValueError(f"dim must be 1, 2 or 3, got {dim}")
        self.dim, self.E, self.nu, self.rho, self.model = int(dim), float(E), float(nu), float(density), model
        self.cells, self.ppc, self.mach, self.transits = int(cells), int(ppc), float(mach), float(transits)
        self.precision, self.solver = precision, solver
        # the material: model_parameters' for the model, then `material`'s keys (any of the model's)
        self.material = dict(model_parameters(model, self.E, self.nu), **(material or {}))
        mu, lam = _lame(self.E, self.nu)
        self.c = math.sqrt((lam + 2 * mu) / self.rho)  # the solver's CFL speed
        self.speed = self.mach * self.c
        self.min_J = 1.0

    @property
    def dx(self) -> float:
        return 1.0 / self.cells

    def bodies(self) -> list:
        raise NotImplementedError

    @property
    def end_time(self) -> float:
        raise NotImplementedError

    def config(self) -> dict:
        d = self.dim
        solver = dict(basis=basis_registry.DEFAULT, transfer="apic", cfl=0.4, end_time=self.end_time)
        solver.update(self.solver)
        return dict(name=self.name, dim=d, precision=self.precision, arch="cpu",
                    domain=dict(lower=[0.0] * d, upper=[1.0] * d, dx=self.dx,
                                boundaries=self.boundary_config()),
                    solver=solver,
                    materials=dict(m=dict(model=self.model, density=self.rho, **self.material)),
                    bodies=self.bodies(), output=dict(formats=[]))

    def boundary_config(self) -> dict:
        return {"default": self.boundaries}

    def box(self, lo, hi, **kw) -> dict:
        return dict(name=self.name, shape=dict(type="box", lower=list(lo), upper=list(hi)), material="m",
                    particles_per_cell=self.ppc, **kw)

    def setup(self, sim):
        self.n_observed = 0

    def observe(self, sim):
        self.n_observed += 1

    def errors(self, sim) -> dict:
        p = sim.particles()
        J = np.linalg.det(p["F"])
        speed = np.sqrt(np.sum(p["v"] ** 2, axis=1))
        return {"j_min": float(J.min()), "j_max": float(J.max()), "speed_over_c": float(speed.max() / self.c)}


class Impact(Scenario):
    """A block of side 0.25 a gap of 2 cells above the slip floor, moving down at mach x c."""

    name = "impact"
    boundaries = "slip"

    def bodies(self):
        d, dx = self.dim, self.dx
        lo = [0.375] * d
        hi = [0.625] * d
        axis = 1 if d > 1 else 0
        lo[axis], hi[axis] = 2 * dx, 2 * dx + 0.25
        v = [0.0] * d
        v[axis] = -self.speed
        return [self.box(lo, hi, velocity=v)]

    @property
    def end_time(self):
        return 2 * self.dx / self.speed + self.transits * 0.25 / self.c


class Compression(Scenario):
    """A block of side 0.0625 (4 cells of 64) at the centre with F = J^(1/d) I at t = 0 (free walls far away)."""

    name = "compression"

    def __init__(self, J=0.2, **kw):
        kw.setdefault("cells", 64)
        kw.setdefault("transits", 2.0)  # released from J = 0.05 it expands at ~2c: end before it reaches the walls
        super().__init__(**kw)
        if not 0 < J <= 1:
            raise ValueError(f"J must be in (0, 1], got {J}")
        self.J0 = float(J)

    def bodies(self):
        return [self.box([0.46875] * self.dim, [0.53125] * self.dim)]

    @property
    def end_time(self):
        return self.transits * 0.0625 / self.c

    def setup(self, sim):
        super().setup(sim)
        F = np.broadcast_to(np.eye(self.dim) * self.J0 ** (1.0 / self.dim), (sim.n, self.dim, self.dim)).copy()
        sim.set_particles(F=F)


class Rotation(Scenario):
    """A disk of radius 0.2 at the centre spinning with rim speed mach x c for `turns` turns (2D/3D about z)."""

    name = "rotation"

    def __init__(self, turns=0.5, **kw):
        kw.setdefault("dim", 2)
        super().__init__(**kw)
        if self.dim == 1:
            raise ValueError("rotation needs dim 2 or 3")
        self.turns, self.radius = float(turns), 0.2

    def bodies(self):
        w = self.speed / self.radius
        b = dict(name="disk", shape=dict(type="sphere", center=[0.5] * self.dim, radius=self.radius),
                 material="m", particles_per_cell=self.ppc,
                 angular_velocity=w if self.dim == 2 else [0.0, 0.0, w])
        return [b]

    @property
    def end_time(self):
        return self.turns * 2 * math.pi * self.radius / self.speed


class Thin(Scenario):
    """A plate one particle thick (thickness dx, one particle per cell) of length 0.5 with the bending
    velocity profile v_y = mach c sin(pi s), s along the plate in [0, 1]."""

    name = "thin"

    def __init__(self, **kw):
        kw.setdefault("dim", 2)
        kw["ppc"] = 1
        super().__init__(**kw)
        if self.dim == 1:
            raise ValueError("thin needs dim 2 or 3")

    def bodies(self):
        d, dx = self.dim, self.dx
        lo, hi = [0.25] * d, [0.75] * d
        lo[1], hi[1] = 0.5, 0.5 + dx
        return [self.box(lo, hi)]

    @property
    def end_time(self):
        return self.transits * 0.5 / self.c

    def setup(self, sim):
        super().setup(sim)
        X = sim.scene.x
        v = np.zeros_like(X)
        v[:, 1] = self.speed * np.sin(np.pi * (X[:, 0] - 0.25) / 0.5)
        sim.set_particles(v=v)


class Edge(Scenario):
    """A block of side 0.25 moving at mach x c toward x_max, starting 2 cells from it; runs until it
    would have travelled 4 cells further."""

    name = "edge"

    def __init__(self, boundary="free", **kw):
        super().__init__(**kw)
        if boundary not in ("free", "slip", "sticky"):
            raise ValueError(f"boundary must be free, slip or sticky, got {boundary!r}")
        self.wall = boundary

    def boundary_config(self):
        return {"default": "slip", "x_max": self.wall}

    def bodies(self):
        d, dx = self.dim, self.dx
        lo, hi = [0.375] * d, [0.625] * d
        hi[0] = 1.0 - 2 * dx
        lo[0] = hi[0] - 0.25
        v = [0.0] * d
        v[0] = self.speed
        return [self.box(lo, hi, velocity=v)]

    @property
    def end_time(self):
        return 6 * self.dx / self.speed


SCENARIOS = {"impact": Impact, "compression": Compression, "rotation": Rotation, "thin": Thin, "edge": Edge}


def make_scenario(spec: dict) -> Scenario:
    spec = dict(spec)
    kind = spec.pop("type")
    if kind not in SCENARIOS:
        raise ValueError(f"unknown stability scenario {kind!r} (known: {', '.join(SCENARIOS)})")
    return SCENARIOS[kind](**spec)
