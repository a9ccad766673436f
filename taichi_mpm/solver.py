"""The MPM solver: particle fields, and the order of one step's kernels (P2G, grid update, G2P; built in step/).

Every option a scene does not use is left out when the kernels are built: the dimension, basis,
transfer, update scheme, material models and features (body force, viscosity, the extensions) are
compile-time constants captured by the kernel closures and tested with `ti.static`. Three parameters are
runtime values instead (small fields the kernels read, set from Python without a recompile, e.g. by the
interactive window's sliders): gravity (`set_gravity`), a per-material stiffness scale (`set_stiffness_scale`)
and FLIP's blend (`set_flip_blend`).

One step (USL):   clear grid -> P2G (mass, momentum, stress force) -> grid update (gravity, walls)
                  -> G2P (velocity by transfer, positions, F, checks)
MUSL adds, after the G2P velocity update, a second P2G of the new particle momentum, whose grid
velocities give the velocity gradient for F (Sulsky et al. 1995; Nairn 2003).

Physics code only: no CLI, rendering or file I/O here.
"""

import math
import warnings
from typing import Callable, Optional

import numpy as np
import taichi as ti

from . import budget, host_copy, states, tearing   # states: the API's refusals (states.py)
from .budget import VISCOUS_DIFFUSION  # noqa: F401 (the dt rule's constant, shared with the estimate)
from .backend import GPU_ARCHS, _live, available_archs, choose as choose_backend, init_taichi, resolve_arch  # noqa: F401
from .bases import registry as bases
from .bases.shape_functions import configured_basis
from .bases.knots import smallest_span
from .bases.mapped import MappedGrid
from .bases.stencils import make_stencil, resolve_unroll
from . import layout as field_layout   # the declared fields (layout.py)
from .sums import ChunkSums, Slots
from .extensions import scatter
from .config import Config, ConfigError, load_config
from .causes import load_scale_causes
from .errors import InstabilityError
from .grid import LEAF, Grid
from .host_scalars import RuntimeParams, StepStatus
from . import materials as material_models
from .materials import MODELS, wave_speed
from .scene import Scene, build_scene
from . import step as step_kernels
from .step import Features, StepContext
from .step import extensions as step_extensions
from .step.moments import Extension
from .step.transfers import DEFORM_F, DEFORM_X, FLUID_J_MIN

FAIL_CAUSES = {1: "inverted or collapsed particle (J <= 0)",
               2: "non-finite value (NaN or infinity) in velocity or deformation",
               3: "particle left the domain",
               4: "fluid volume collapse",
               5: "particle domain corner left the domain (cpdi)",
               6: "particle left the mapped grid (domain.map could not be inverted there)",
               7: "particle domain folded (cpdi2: its corners crossed over)"}
ENERGY_GROWTH = "energy growth beyond the work done on the system"
NUMERICAL_FRACTURE = "numerical fracture (a body tore apart on the grid)"
CAUSES = (*FAIL_CAUSES.values(), ENERGY_GROWTH, NUMERICAL_FRACTURE)  # every InstabilityError.cause the solver raises
_NO_FAIL = 2**31 - 1
_CODES = 8  # fail flag = solver slot * _CODES + code
DT_LIMITS = ("elastic", "speed", "gravity", "body_force", "viscosity", "fixed")  # Simulation.dt_limit
ENERGY_CHECK_EVERY = 4      # steps between energy-balance checks (every step while the energy is above the balance)
# energy above the balance by less than this (relative) is round-off: checking it every step only costs the checks'
# passes (ck's APIC in f32 keeps a uniformly moving block at +4e-7..+7e-7, quadratic's at -1e-6)
ENERGY_NOISE = {"f32": 1e-5, "f64": 1e-12}
FRACTURE_SPREAD = 1.3       # body spread / spread its particles' F accounts for, past which the body tore on the grid


class StabilityWarning(UserWarning):
    """A scene that is likely to go wrong numerically (e.g. a weakly compressible fluid that is too soft)."""


def thread_independent(cfg: Config, particles: int, body_force: bool = False) -> bool:
    """Whether every sum a CPU step and its diagnostics make has one order whatever the threads: P2G by the coloured
    scatter (scatter.py), energies and momenta by chunks (sums.py), and none of the parts that still add in the
    threads' order (the extensions that say so: ddmp's nodal volumes, F-bar's averages, the crack finder's node
    sums; the tractions', grips' and walls' work and impulses; and the accumulators of body forces' work and of
    dissipation). tests/test_scatter.py checks 1 and 2 threads bit-identical."""
    if not scatter.coloured(cfg, gpu=False, particles=particles):
        return False
    mats = [cfg.materials[b.material] for b in cfg.bodies]
    return not (step_extensions.adds_in_thread_order(cfg) or body_force
                or any(getattr(m, "viscosity", 0.0) > 0 or MODELS[m.model].plastic for m in mats))


class Simulation:
    """A running MPM simulation built from a config (the API contract is in docs/contract.md)."""

    def __init__(self, cfg, body_force: Optional[Callable] = None, scene: Optional[Scene] = None):
        self.cfg: Config = cfg if isinstance(cfg, Config) else load_config(cfg)
        self.body_force = body_force
        c = self.cfg
        self.dim, self.dx = c.dim, c.domain.dx
        self.lower = np.asarray(c.domain.lower, float)
        self.upper = np.asarray(c.domain.upper, float)
        self.n_cells = _cell_counts(self.lower, self.upper, self.dx)
        budget.check(c, body_force=body_force is not None)  # refuse absurd sizes before allocating anything
        self.scene = scene if scene is not None else build_scene(c)
        self.n = self.scene.n
        self.backend = choose_backend(c, size_check=_fits)  # arch and grid, and why
        self._id = init_taichi(self.backend, c.precision, c.solver.deterministic,
                               c.solver.deterministic and thread_independent(c, self.n, body_force is not None))
        self.basis = configured_basis(c)   # domain.knots' per-axis knot vectors, the basis' options
        self.basis.materialize()
        self.h_cfl = smallest_span(c)   # dx, or the shortest knot span of domain.knots
        self.mapped = MappedGrid(c) if c.domain.map is not None else None   # domain.map: a curvilinear grid
        if self.mapped is not None:
            self.basis = self.mapped.basis()
            self.mapped.materialize()
            self.h_cfl = self.mapped.h_min
        self._materials = [c.materials[name] for name in self.scene.materials]
        self._wave_speeds = np.array([wave_speed(m) for m in self._materials])  # at stiffness scale 1
        # the runtime parameters' host copies (their fields: _allocate); the config's values to start with
        self._gravity = np.asarray(c.gravity, dtype=np.float64)
        self._stiffness = np.ones(len(self._materials))
        self._flip_blend = float(c.solver.flip_blend)
        self.wave_speed = self._wave_speed()
        self.time, self.n_steps, self.dt = 0.0, 0, 0.0
        self._half_dt = 0.0  # half the last step: the leapfrog velocities' lag behind the clock (0: in step)
        self.dt_limit = None  # which rate limited the last CFL-rule dt (one of DT_LIMITS)
        self._balance = None  # energy balance reference (see _check_energy_balance)
        self._energy_rows = self._work_row = None   # host arrays the energies kernel fills (_energy_parts)
        self._potentials = {}  # step -> strain + gravity potential of that state (energy_balance's pairing)
        self._body_acc_time, self._body_acc_max = None, 0.0
        self._vmax = _max_speed(self.scene.v) if self.n else 0.0
        self._allocate()
        self.unroll = resolve_unroll(c.solver.unroll, self._expected_particle_steps())
        self._build_kernels()
        self._upload()
        self._shape_ref = None  # per-body spread reference (see _check_fracture)
        self._warn_weak_fluids()

    # ------------------------------------------------------------------ fields
    def _features(self) -> Features:
        return Features.of(self.cfg, self.scene, self._materials, body_force=self.body_force is not None)

    def _allocate(self):
        self.feat = self._features()
        gpu = ti.lang.impl.current_cfg().arch not in (ti.x64, ti.arm64)
        # the fields this scene needs, declared once (layout.py; budget.py counts the same declaration)
        self.needs = field_layout.Needs.of_simulation(self, self.feat, coloured=scatter.coloured(self.cfg, gpu, self.n))
        self._allocate_particles(self.needs)
        self._allocate_globals()
        self._allocate_grid(self.feat)
        self.bytes_per_particle = self._bytes_per_particle()

    def _allocate_particles(self, needs: field_layout.Needs):
        """x, v, F, vol0 and the optional per-particle fields (C, mat, body_acc, half_width, stress0, state, load,
        body_id: None when the scene does without), as field_layout.solver_particle_fields declares them."""
        fields = field_layout.allocate(field_layout.solver_particle_fields(needs), self.n)
        for name in ("x", "v", "F", "vol0", "C", "grad_v", "mat", "body_acc", "half_width", "stress0", "state", "load",
                     "body_id"):
            setattr(self, name, fields.get(name))
        # per-particle material state (plastic strain, J_p, ...): only when a model of the scene has any (materials/)
        self.state_layout = material_models.state_layout(self._materials, self.dim)
        self.n_state = needs.n_state

    def _allocate_grid(self, f: Features):
        """The grid, the coloured scatter's bins, and the extensions (step/extensions.py): created, their node
        fields declared, allocated once the grid exists."""
        d, n = self.dim, self.n
        shape = [self.basis.axis(a).nodes(nc) for a, nc in enumerate(self.n_cells)]
        if self.mapped is not None:
            shape = self.mapped.shape    # control points of the map, in parameter space
            self.mapped.allocate_particles(n)
        setup = self._setup(f, coloured=self.needs.coloured)
        self.extensions = step_extensions.create(setup)
        self._acts_after_g2p = any(type(e).after_g2p is not Extension.after_g2p for e in self.extensions)
        # v (v_old: FLIP, XPIC, ASFLIP; XPIC's three; v2: MUSL; grip) by the mass, and apart, few touched, the crack
        # finder's node fields (tensor node mass rows, normals, marks): all declared in layout.main_grid; then the
        # node fields of an extension layout.py does not know (a plug-in's grid_fields)
        g = field_layout.main_grid(self.needs)
        declared = [e.grid_fields() for e in self.extensions]
        apart = list(g.apart) + [name for vectors, _ in declared for name in vectors]
        scalars = list(g.scalars) + [name for _, more in declared for name in more]
        self.grid = Grid(d, shape, self.backend.sparse, list(g.vectors), apart, scalars,
                         leaf=LEAF[d] * self.basis.spec.nodes_per_cell)
        self.bins = scatter.BlockBins(d, self.grid, n) if setup.coloured else None  # atomic-free P2G (scatter.py)
        setup.grid, setup.bins = self.grid, self.bins
        for e in self.extensions:
            e.allocate(setup)
        self._p2g_passes = max([e.p2g_passes for e in self.extensions], default=1)

    def _setup(self, f: Features, coloured: bool) -> step_extensions.Setup:
        """What the extensions are handed (step.moments.Setup): never the Simulation itself."""
        return step_extensions.Setup(
            cfg=self.cfg, scene=self.scene, dim=self.dim, n=self.n, dx=self.dx, lower=self.lower, upper=self.upper,
            n_cells=self.n_cells, basis=self.basis, mapped=self.mapped, feat=f, materials=self._materials, x=self.x,
            v=self.v, F=self.F, vol0=self.vol0, to_solver=self._to_solver, to_creation=self._to_creation,
            perm=lambda: self._perm, coloured=coloured, needs=self.needs, work=self.work, load=self.load)

    def extension(self, name: str):
        """The scene's extension of that name (step.moments.Extension.name: "crack", "fbar", ...), or None."""
        return next((e for e in self.extensions if e.name == name), None)

    def _allocate_globals(self):
        """Flags, runtime parameters, accumulators and diagnostics sums."""
        d, n = self.dim, self.n
        self.status = StepStatus(_NO_FAIL)
        self.fail, self.vmax2 = self.status.fail, self.status.vmax2
        # runtime parameters (set_gravity, set_stiffness_scale, set_flip_blend): read by the kernels, no recompile
        self.runtime = RuntimeParams(d, len(self._materials))
        self.gravity_field = self.runtime.gravity
        self.gravity_before_field = self.runtime.gravity_before  # the last step's gravity (see gravity_kick)
        self.stiffness_field, self.flip_blend_field = self.runtime.stiffness, self.runtime.flip_blend
        self._gravity_before = self._gravity.copy()
        self._upload_runtime()
        self.diag = ChunkSums(n, 8)  # reduction slots for energies and momenta
        # accumulated per step: external work (body forces, tractions, prescribed velocities), viscous and plastic
        # dissipation (the plastic work of the return mappings, docs/materials.md)
        self.work = Slots(3)
        self.n_bodies = int(self.scene.body.max(initial=0)) + 1
        self.moments = ChunkSums(n, (self.n_bodies, 1 + d + 2 * d * d))  # per body: m, m x, m x x^T, m F

    def _upload_runtime(self):
        self.runtime.upload(self._gravity, self._gravity_before, self._flip_blend, self._stiffness)

    def _bytes_per_particle(self) -> int:
        """The solver's declared particle fields (layout.py) and the extensions'."""
        out = field_layout.nbytes(field_layout.solver_particle_fields(self.needs), self.cfg.precision)
        return out + sum(e.bytes_per_particle() for e in self.extensions)

    def _block_order(self) -> np.ndarray:
        """Solver slot -> creation index, sorting particles by grid block then cell, so that particles that
        share grid nodes are processed together (P2G scatters and G2P gathers hit the same cache lines)."""
        cell = np.floor((self.scene.x - self.lower) / self.dx).astype(np.int64)
        block = cell // 4
        keys = [cell[:, a] for a in reversed(range(self.dim))] + [block[:, a] for a in reversed(range(self.dim))]
        return np.lexsort(keys)

    def _to_solver(self, a: np.ndarray) -> np.ndarray:
        """Per-particle array in creation order -> solver order."""
        return np.ascontiguousarray(np.asarray(a)[self._perm])

    def _to_creation(self, a: np.ndarray) -> np.ndarray:
        out = np.empty_like(a)
        out[self._perm] = a
        return out

    def _upload(self):
        s, d, n = self.scene, self.dim, self.n
        self._perm = self._block_order()
        F = np.broadcast_to(np.eye(d), (n, d, d))
        if s.geostatic:   # bodies[].geostatic: the elastic F of their K0 stress
            F = F.copy()
            for particles, Fg, _ in s.geostatic:
                F[particles] = Fg
        pairs = [(self.x, self._to_solver(s.x)), (self.v, self._to_solver(s.v)),
                 (self.F, self._to_solver(F)), (self.vol0, self._to_solver(s.volume))]
        for affine in (self.C, self.grad_v):
            if affine is not None:
                pairs.append((affine, np.zeros((n, d, d))))
        if self.mat is not None:
            pairs.append((self.mat, self._to_solver(s.material)))
        if self.half_width is not None:
            pairs.append((self.half_width, self._to_solver(0.5 * s.spacing / self.dx)))
        if self.body_id is not None:
            pairs.append((self.body_id, self._to_solver(s.body)))
        if self.stress0 is not None:  # S0 = the initial Cauchy stress (F = I at t = 0), held as a 2nd P-K stress
            pairs.append((self.stress0, self._to_solver(s.stress).reshape(n, d, d)))
        if self.state is not None:
            pairs.append((self.state, self._to_solver(self._initial_state())))
        if n:
            host_copy.upload(pairs)   # one kernel for all (host_copy.py: a compile saved per field)
        for e in self.extensions:
            e.particles_set({"x", "v", "F"})
        for e in self.extensions:
            e.upload()   # the crack finder's initial damage and interface flags, the loaded and gripped particles

    # ------------------------------------------------------------------ kernels
    def _build_kernels(self):
        """The step's kernels (step/): the context, the stencil, the material funcs, then the extensions' kernels
        (which read them and add their contributions to the context), then the solver's own kernels with those."""
        ctx = self.ctx = self._step_context()
        for e in self.extensions:
            e.prepare(ctx)   # what the stencil reads: the walls' condition (ctx.wall)
        ctx.stencil = make_stencil(ctx)
        funcs = step_kernels.make_funcs(ctx)   # sets ctx.density, ctx.kirchhoff, ctx.project, ctx.add
        for e in self.extensions:
            e.build(ctx)
        self._k = step_kernels.make_kernels(ctx, funcs)

    def _step_context(self) -> StepContext:
        dim, dx, c = self.dim, self.dx, self.cfg
        asf = c.solver.asflip
        nq = max(1, self.n_state)
        return StepContext(
            dim=dim, dx=dx, lower=ti.Vector(self.lower.tolist()), upper=ti.Vector(self.upper.tolist()),
            n_cells=self.n_cells, basis=self.basis, feat=self.feat, precision=c.precision,
            x=self.x, v=self.v, F=self.F, C=self.C, grad_v=self.grad_v, vol0=self.vol0, mat=self.mat,
            half_width=self.half_width,
            domain_lp0=0.5 * float(self.scene.spacing[0]) / dx if self.n else 0.5,
            gimp_deforming=c.solver.gimp_domain == "deforming", unroll=self.unroll, grid=self.grid,
            gravity_kick=step_kernels.make_gravity_kick(self.gravity_field, self.gravity_before_field),
            extra=dict(mapped=self.mapped),
            # each material's Taichi funcs, its parameters compile-time constants (materials/: the model registry)
            materials=[MODELS[m.model].build(m, dim, nq) for m in self._materials], n_state=nq,
            state=self.state, stress0=self.stress0, body_acc=self.body_acc,
            gravity=self.gravity_field, gravity_before=self.gravity_before_field, stiffness=self.stiffness_field,
            flip_blend=self.flip_blend_field, work=self.work, fail=self.fail, vmax2=self.vmax2,
            status=self.status, fail_codes=_CODES,
            asflip=(asf.flip, asf.position_min, asf.position), load=self.load,
            diag=self.diag, moments=self.moments, body_id=self.body_id, bins=self.bins)

    # ------------------------------------------------------------------ stepping
    def _check_live(self):
        if _live["id"] != self._id:
            raise RuntimeError("this Simulation is no longer live: a newer Simulation restarted Taichi")

    def _expected_particle_steps(self) -> float:
        """Particles times the steps to end_time at the starting dt (solver.max_steps caps it; a body force, not
        yet evaluated, is left out): the run length solver.unroll auto weighs against the compile."""
        s = self.cfg.solver
        dt = s.dt if s.dt is not None else min(self.dt_limits(body_force=False).values())
        steps = s.end_time / dt if dt > 0 else math.inf
        if s.max_steps is not None:
            steps = min(steps, s.max_steps)
        return self.n * steps

    def dt_limits(self, body_force: bool = True) -> dict:
        """The time-step bound of every rate in the scene (seconds), by name (see DT_LIMITS):
        elastic waves + particle speed: cfl dx / (c + |v|max), named `elastic` or `speed` by the larger;
        acceleration: cfl sqrt(dx / |a|), |a| = |g| + max |b| (named `body_force` when b dominates);
        viscosity: cfl rho dx^2 / (VISCOUS_DIFFUSION d mu) per viscous material.
        The runtime parameters count as they are now: gravity (set_gravity), c and mu times the stiffness scale's
        square root and the scale itself (set_stiffness_scale)."""
        cfl, dx = self.cfg.solver.cfl * self.basis.spec.cfl_factor, self.h_cfl
        c, v = self.wave_speed, self._vmax
        out = {"elastic" if c >= v else "speed": cfl * dx / (c + v) if c + v > 0 else math.inf}
        g = self._g_norm
        b = self._body_acc_now() if body_force else 0.0
        if g + b > 0:
            out["body_force" if b > g else "gravity"] = cfl * math.sqrt(dx / (g + b))
        for m, scale in zip(self._materials, self._stiffness):
            if getattr(m, "viscosity", 0.0) > 0:
                visc = m.viscosity * scale  # the stiffness scale scales the viscous stress too
                dt_v = cfl * m.density * dx * dx / (VISCOUS_DIFFUSION * self.dim * visc)
                out["viscosity"] = min(out.get("viscosity", math.inf), dt_v)
        return out

    def stable_dt(self) -> float:
        """solver.dt when fixed, else the smallest of dt_limits(); sets dt_limit to the limiting term."""
        s = self.cfg.solver
        if s.dt is not None:
            self.dt_limit = "fixed"
            return s.dt
        limits = self.dt_limits()
        self.dt_limit = min(limits, key=limits.get)
        return limits[self.dt_limit]

    @property
    def _g_norm(self) -> float:
        return float(np.linalg.norm(self._gravity))

    def _body_acc_now(self) -> float:
        """Evaluate body_force at the current time (once per time), upload it; returns max |b|."""
        if self.body_acc is None:
            return 0.0
        if self._body_acc_time != self.time:
            acc = np.asarray(self.body_force(self.scene.x, self.time), dtype=np.float64)
            if acc.shape != (self.n, self.dim):
                raise ValueError(f"body_force must return an array of shape {(self.n, self.dim)}, got {acc.shape}")
            if not np.isfinite(acc).all():
                raise ValueError(f"body_force returned non-finite values at t={self.time:g}")
            self.body_acc.from_numpy(self._to_solver(acc))
            self._body_acc_time, self._body_acc_max = self.time, _max_speed(acc) if self.n else 0.0
        return self._body_acc_max

    def _scatter(self, kernel: str, *args):
        """Run a P2G kernel: once, or once per colour of the coloured scatter (scatter.py)."""
        for colour in range(self._p2g_passes):
            self._k[kernel](*args, colour)

    def _extend_velocities(self):
        """solver.transfer xpic: v* to order solver.xpic_order, one particle and one grid pass per order above 1."""
        self._k["xpic_start"]()
        for _ in range(self.cfg.solver.xpic_order - 1):
            self._scatter("xpic_pass")
            self._k["xpic_update"]()

    def _update_stress_first(self, dt: float):
        """solver.update usf, its first pass: mass and momentum to the grid (no forces), the node velocities under
        walls and grips, and F and the stress from them; the step then maps the new stress's forces as USL does."""
        self.grid.clear()
        for e in self.extensions:
            e.before_p2g()
        self._scatter("p2g", 0.0)
        for e in self.extensions:
            e.after_p2g()
        self._k["grid_velocity"](any(e.node_solve_active() for e in self.extensions))   # the chain, no forces
        self.status.reset()
        self._k["g2p"](dt, 0.0, velocity=False, deform=DEFORM_F)

    @states.stepping   # a failed simulation is not stepped again (states.py)
    def step(self, dt: Optional[float] = None) -> float:
        """Advance one step (dt from the CFL rule unless given); returns dt."""
        self._check_live()
        k = self._k
        if dt is None:
            dt = self.stable_dt()
        else:
            dt = states.check_dt(self, dt)   # finite, > 0, and one the kernels and the clock can step by
        dt = float(dt)
        watch = self.cfg.solver.energy_growth_limit is not None
        if self._balance is None:  # the balance is kept (energy_balance()) even with the check off
            self._balance = self._energy_balance_reference()
        if watch and self._balance["due"] <= self.n_steps + 1 and self.n_steps not in self._potentials:
            self._energy_parts()  # the potential of the state this step leaves: the check after it averages both
        self._body_acc_now()
        # Leapfrog: velocities live at half steps. The forces at the positions of time t kick the velocity of
        # t - dt_prev/2 to t + dt/2, over (dt_prev + dt)/2; the positions then drift by dt with it. The first step
        # (and the first after set_particles gave velocities) kicks over dt/2. Second order in dt, exact for a
        # uniform acceleration at any sequence of steps (docs/accuracy.md, "Time integration").
        kick_before, kick_after = self._half_dt, 0.5 * dt
        kick = kick_before + kick_after
        for e in self.extensions:   # this step's tractions, grip and wall velocities
            e.before_step(self.time, dt, self._half_dt)
        if self.feat.usf:
            self._update_stress_first(dt)
        self.grid.clear()
        for e in self.extensions:
            e.before_p2g()   # ddmp's nodal volumes, the coloured scatter's bins, the crack finder's normals
        self._scatter("p2g", kick)
        for e in self.extensions:
            e.after_p2g()   # grips mark their nodes
        # an extension's own node solve (the crack finder's tensor node mass, only with particles in contact)
        special = any(e.node_solve_active() for e in self.extensions)
        k["grid_update"](kick_before, kick_after, special)
        if self.feat.xpic:
            self._extend_velocities()
        # grid_update reset the failure flag and speed maximum (USF's first pass did, and may have found a failed
        # particle)
        if self.feat.musl:
            k["g2p"](dt, kick, velocity=True, deform=False)
            self._scatter("p2g_momentum")  # the first g2p pass left the positions: the same bins
            k["grid_remap"](special)
            status = k["g2p"](dt, kick, velocity=False, deform=True)
        else:   # USF updated F in its first pass: the positions only
            status = k["g2p"](dt, kick, velocity=True, deform=DEFORM_X if self.feat.usf else True)
        for e in self.extensions:
            e.after_g2p()   # the mapped grid's xi_p, F-bar's volume average
        self.dt, self._half_dt = dt, 0.5 * dt
        if not np.array_equal(self._gravity_before, self._gravity):  # the gravity of this step, for the next kick
            self._gravity_before = self._gravity.copy()
            self._upload_runtime()
        self.n_steps += 1
        self.time += dt
        # the last G2P pass's status, or read after the extensions' passes (the mapped grid's may find a failure)
        code, vmax2 = self.status.read() if self._acts_after_g2p else self.status.decode(status)
        self._vmax = math.sqrt(max(vmax2, 0.0))
        if code != _NO_FAIL:
            self._raise_particle_failure(code, dt)
        if watch and self._balance["due"] <= self.n_steps:
            self._check_energy_balance()
        return dt

    # ------------------------------------------------------------------ checks
    def _hint(self, dt: float) -> str:
        """Which rate limited dt and at what CFL number, for error messages."""
        if self.dt_limit == "fixed":
            return (f"solver.dt is fixed at {dt:.3g} s, {dt / self.stable_dt_rule():.2g} x the CFL-rule step "
                    f"(cfl {self.cfg.solver.cfl:g})")
        return (f"dt={dt:.3g} s limited by {self.dt_limit or 'the caller'}, CFL number {self.cfl_number():.2f} "
                f"(solver.cfl {self.cfg.solver.cfl:g})")

    def stable_dt_rule(self) -> float:
        limits = self.dt_limits()
        return min(limits.values())

    def _raise_particle_failure(self, code: int, dt: float):
        p, kind = int(self._perm[code // _CODES]), code % _CODES
        cause = FAIL_CAUSES[kind]
        s = self.cfg.solver
        detail = f"dt={dt:.3g}, max speed={self._vmax:.3g}; {self._hint(dt)}"
        hint = bases.get(s.basis).inversion_hint
        causes = load_scale_causes(self.cfg, self._gravity) if kind in (1, 2, 3, 5) else []
        if causes:   # a load no time step can follow: that, not the step, is what to fix (causes.py)
            detail += "; likely cause: " + causes[0]
        elif kind == 1 and hint:
            detail += "; " + hint
        elif kind == 5:
            detail += ("; a corner of the particle's CPDI domain crossed a wall, where the linear grid "
                       "functions end; fix: keep bodies half a particle spacing off walls they stretch towards, "
                       "or a larger domain")
        elif kind == 7:
            detail += ("; the grid velocity moved two corners of the domain across each other within one step "
                       "(a particle squeezed or sheared faster than the step follows); fix: lower solver.cfl")
        elif kind in (1, 2):
            detail += f"; fix: lower solver.cfl (measured stable limits per basis and transfer: docs/accuracy.md)"
        elif kind == 4:
            detail += (f"; fluid J fell below {FLUID_J_MIN}: the bulk modulus K is too small for the pressure "
                       f"(rule of thumb: K >= 100 rho g H, Mach < 0.1); raise K")
        raise InstabilityError(cause, self.n_steps, self.time, particle=p, detail=detail)

    def _energy_parts(self):
        if self._energy_rows is None:
            self._energy_rows, self._work_row = self.diag.rows(), np.zeros(self.work.shape[0], dtype=np.float64)
        self._k["energies"](self._energy_rows, self._work_row)   # the sums and the work slots in one launch
        e = self.diag.total_of(self._energy_rows)
        w = self._work_row.copy()
        # slot 4: the stored initial stress's energy S0 : E, part of the strain energy; it falls below zero as a
        # pre-stressed body relaxes, so the balance's scale (slot 5) counts its size, not its sign
        e[5] = e[0] + e[1] + abs(e[4])
        e[1] += e[4]
        # the potential (strain + gravity) of the last two states measured, for the leapfrog pairing in
        # energy_balance
        self._potentials = {k: v for k, v in self._potentials.items() if k == self.n_steps - 1}
        self._potentials[self.n_steps] = float(e[1] + e[2])
        return e, w

    def _energy_balance_reference(self) -> dict:
        e, w = self._energy_parts()
        floor = self._energy_floor(e[3])
        return dict(total=e[0] + e[1] + e[2], work=w[0], dissipated=w[1] + w[2], scale=max(e[5], floor),
                    floor=floor, due=self.n_steps + ENERGY_CHECK_EVERY, steps=self.n_steps, time=self.time,
                    extensions=self._extension_dissipation())

    def _extension_dissipation(self) -> dict:
        """The energy the extensions removed since the start, by name (multi-field contact: friction, contact)."""
        out = {}
        for e in self.extensions:
            for name, value in e.dissipation().items():
                out[name] = out.get(name, 0.0) + value
        return out

    def _energy_floor(self, potential_scale: float) -> float:
        """Round-off scale of the balance: below it a 'growth' is precision noise, not physics."""
        f32 = self.cfg.precision == "f32"
        stiffness = float(np.sum(self.scene.volume * self._stiffness_per_particle()))
        return (1e-8 if f32 else 1e-12) * stiffness + (1e-6 if f32 else 1e-12) * potential_scale + 1e-300

    def _stiffness_per_particle(self) -> np.ndarray:
        mod = np.array([m.modulus for m in self._materials]) * self._stiffness
        return mod[self.scene.material] if len(mod) > 1 else np.full(self.n, mod[0])

    def energy_balance(self) -> dict:
        """The energy balance since its reference time (first step, or the last set_particles/set_state):
        growth = E(t) + dissipated - E(ref) - work, with E = kinetic + potential (strain + gravity), work the
        external work (body forces, tractions, grips and velocity walls), dissipated the viscous and plastic
        dissipation (the plastic work of the return mappings) and what extensions removed (multi-field contact:
        its `friction`, also given apart under that name); scale = largest kinetic + strain energy seen.
        Leapfrog's velocities lag the positions by half a step, so the kinetic energy (of time t - dt/2) is
        paired with the mean potential of the last two states, t - dt and t, where the solver measured both
        (every checked step, the last step of advance_to): paired with the potential of t alone, a body rising
        under gravity would read m |g| |v| dt / 2 of growth. Free fall then balances to -m |g|^2 dt^2 / 8 (dt: the
        last step). Walls and PIC/APIC/FLIP transfers only remove energy, so growth > 0 is numerical."""
        self._check_live()
        ref = self._balance or self._energy_balance_reference()
        e, w = self._energy_parts()
        potential = e[1] + e[2]
        if self.n_steps - 1 in self._potentials:   # (cleared with the balance: never from before its reference)
            potential = 0.5 * (potential + self._potentials[self.n_steps - 1])
        total = e[0] + potential
        work, dissipated = w[0] - ref["work"], w[1] + w[2] - ref["dissipated"]
        own = {name: value - ref["extensions"].get(name, 0.0) for name, value in self._extension_dissipation().items()}
        dissipated += sum(own.values())
        scale = max(ref["scale"], e[5])
        growth = total + dissipated - ref["total"] - work
        return dict(growth=growth, ratio=growth / scale, scale=scale, work=work, dissipated=dissipated,
                    total=total, initial=ref["total"], **own)

    def _check_energy_balance(self):
        """An explicit step past its stability limit can grow energy without any NaN or inverted particle."""
        bal = self.energy_balance()
        ref = self._balance
        ref["scale"], ref["steps"] = bal["scale"], self.n_steps
        limit = self.cfg.solver.energy_growth_limit
        # every step while energy is above the balance by more than round-off: a blow-up (x1.5-2 per step at CFL
        # 1.2) is then stopped within a step of crossing the limit
        above = bal["ratio"] > ENERGY_NOISE[self.cfg.precision]
        ref["due"] = self.n_steps + (1 if above else ENERGY_CHECK_EVERY)
        if not any(e.breaks_bodies for e in self.extensions):   # (the crack finder: bodies may separate)
            self._check_fracture()
        if bal["ratio"] > limit and bal["growth"] > ref["floor"]:
            speed = np.sum(self._read("v") ** 2, axis=1)
            terms = ["gravity"] if self._g_norm > 0 else []
            terms += ["body forces"] if self.body_acc is not None else []
            terms += list(dict.fromkeys(e.work_term for e in self.extensions if e.work_term))
            terms += ["viscous dissipation"] if self.feat.viscosity else []
            terms += ["plastic dissipation"] if self.feat.plastic else []
            raise InstabilityError(
                ENERGY_GROWTH, self.n_steps, self.time, particle=int(np.argmax(speed)),
                detail=(f"total energy {bal['total']:.4g} exceeds initial {bal['initial']:.4g} + work "
                        f"{bal['work']:.4g} - dissipated {bal['dissipated']:.4g} by {bal['ratio']:.0%} of the "
                        f"largest kinetic + strain energy (limit {limit:.0%}; balance includes "
                        f"{', '.join(terms) or 'no external work'}); particle named: the fastest. Likely cause: "
                        f"{self._energy_growth_cause()}"))

    def _energy_growth_cause(self) -> str:
        causes = load_scale_causes(self.cfg, self._gravity)
        if causes:
            return causes[0]
        return (f"the time step is past the stability limit of basis {self.cfg.solver.basis} with "
                f"{self.cfg.solver.transfer}: {self._hint(self.dt)}. Fix: lower solver.cfl (or solver.dt); "
                f"largest stable CFL per basis and transfer: docs/accuracy.md")

    def _check_fracture(self):
        """Numerical fracture: a solid body whose particles spread apart further than their own F says (a body
        stretched until its particles no longer share grid nodes breaks into clumps while each clump's F stays
        near its old value). Compares the spread tr(M2) of each body with the spread its particles' mean stretch
        predicts from the reference state, M2_pred = A M2_ref A^T with A = mean U (mean U at the reference)^-1,
        U = R^T F the stretch of F's polar decomposition (the spread is rotation-free, and so is U; a mean of F
        itself shrinks where the rotations vary over a body, bent or twisted, and took such a body for torn). The
        message says whether the body also forms more groups on the grid than it started with (tearing.py)."""
        if all(MODELS[m.model].fluid or MODELS[m.model].plastic for m in self._materials):
            return  # no solid body to check: skip the moments pass
        shapes = self._body_shapes()
        if self._shape_ref is None:
            self._shape_ref = shapes
            return
        for b, (mass, M2, Um, solid) in shapes.items():
            if not solid or b not in self._shape_ref:
                continue
            _, M2r, Ur, _ = self._shape_ref[b]
            try:
                A = Um @ np.linalg.inv(Ur)
            except np.linalg.LinAlgError:
                continue
            pred = np.trace(A @ M2r @ A.T)
            ratio = np.trace(M2) / pred if pred > 0 else 1.0
            if ratio > FRACTURE_SPREAD ** 2:
                raise InstabilityError(
                    NUMERICAL_FRACTURE, self.n_steps, self.time, particle=int(np.flatnonzero(self.scene.body == b)[0]),
                    detail=(f"body {b} spread {math.sqrt(ratio):.2f} x as far as its particles' deformation "
                            f"gradients account for (mean stretch U {np.array2string(Um, precision=3)}); "
                            f"{self._groups_message(b)}. Fix: a finer grid (smaller domain.dx) or more "
                            f"particles_per_cell, basis cpdi (particle domains that follow F; cpdi2 where the "
                            f"stretch is large and uneven), or a crack section if the body is meant to break"))

    def _groups_message(self, b: int) -> str:
        """Which of the two ways a body spreads beyond its F: it tore into groups on the grid, or it is one group
        whose F no longer follows its particles (tearing.py counts the groups)."""
        sel = self.scene.body == b
        start = tearing.groups(tearing.domain_points(self.scene.x[sel], self._domain_corners(sel, self.scene.x[sel],
                                                                                              creation=True)),
                               self.lower, self.dx)
        x = self._read("x")[sel]
        now = tearing.groups(tearing.domain_points(x, self._domain_corners(sel, x, creation=False)), self.lower,
                             self.dx)
        if now is not None and start is not None and now > start:
            return (f"it tore into {now} separate groups of particles on the grid (it started as {start}): "
                    f"stretched material that no longer shares grid nodes stops feeling its own tension")
        return ("its particles still share grid nodes, but F no longer follows their positions (a body one "
                "particle thick: its F shrinks while the particles keep their spacing)")

    def _domain_corners(self, sel: np.ndarray, x: np.ndarray, creation: bool):
        """The domain corners (N, 2^d, d) of the selected particles at positions x (creation order) for bases with
        particle domains: cpdi2's tracked ones (its corners now), cpdi1's x + F r0 s, gimp's x + r0 s; None for
        the others. creation: those of the scene as created (F = I)."""
        spec = bases.get(self.cfg.solver.basis)
        if not spec.particle_domains:
            return None
        tracked = self.extension("corners")
        if tracked is not None and not creation:
            return tracked.corner_positions()[sel]
        s = np.array([[2.0 * ((c >> a) & 1) - 1.0 for a in range(self.dim)] for c in range(2 ** self.dim)])
        r0 = 0.5 * self.scene.spacing[sel, None, None]
        F = self._read("F")[sel] if spec.stencil_kind == "corners" and not creation else np.eye(self.dim)[None]
        return x[:, None, :] + r0 * np.einsum("pab,cb->pca", np.broadcast_to(F, (len(x), self.dim, self.dim)), s)

    def _body_shapes(self) -> dict:
        """body -> (mass, second moment of position about the centre, mass-mean stretch U, solid?)."""
        self._k["body_moments"]()
        m = self.moments.total()
        d = self.dim
        # fluids and plastic models: F (the elastic part) does not predict the shape, so no fracture check
        fluid = np.array([MODELS[mm.model].fluid or MODELS[mm.model].plastic for mm in self._materials])
        out = {}
        for b in range(self.n_bodies):
            mass = m[b, 0]
            if mass <= 0:
                continue
            mean = m[b, 1:1 + d] / mass
            M2 = m[b, 1 + d:1 + d + d * d].reshape(d, d) / mass - np.outer(mean, mean)
            Um = m[b, 1 + d + d * d:].reshape(d, d) / mass
            mats = np.unique(self.scene.material[self.scene.body == b])
            out[b] = (mass, M2, Um, not fluid[mats].any())
        return out

    def _warn_weak_fluids(self):
        """Weakly compressible fluids: K >= 100 rho g H (Mach < 0.1) keeps volume changes near 1 %."""
        g = self._g_norm
        c_speed = _max_speed(self.scene.v) if self.n else 0.0
        for i, m in enumerate(self._materials):
            if m.model != "fluid":
                continue
            sel = self.scene.material == i
            if not sel.any():
                continue
            H = 0.0
            if g > 0:
                down = -self._gravity / g
                h = self.scene.x[sel] @ down
                H = float(h.max() - h.min()) + float(np.min(self.scene.spacing))
            c = math.sqrt(m.K / m.density)
            if m.K < 100 * m.density * g * H or c_speed > 0.1 * c:
                warnings.warn(
                    f"fluid material {self.scene.materials[i]!r}: K = {m.K:g} Pa is too soft for this scene "
                    f"(fluid height H = {H:.3g} m, rho g H = {m.density * g * H:.3g} Pa, initial speed "
                    f"Mach {c_speed / c:.2f}); a weakly compressible fluid needs K >= 100 rho g H = "
                    f"{100 * m.density * g * H:.3g} Pa and speeds below Mach 0.1, or its volume collapses (the run "
                    f"stops when J < {FLUID_J_MIN})", StabilityWarning, stacklevel=3)

    @property
    def at_step_limit(self) -> bool:
        """solver.max_steps reached."""
        m = self.cfg.solver.max_steps
        return bool(m) and self.n_steps >= m

    @states.stepping
    def advance_to(self, target: float, on_step: Optional[Callable] = None) -> int:
        """Step until simulation time `target`, shortening the last step to land on it exactly; stop early at
        solver.max_steps. on_step(self) runs after every step. Returns the number of steps taken.
        (Every stepping loop uses this one, so a resumed run takes exactly the steps of an uninterrupted one.)
        Every step obeys the CFL rule (dt_limits), whatever the duration; the energy balance is checked after
        the last step too."""
        if not _is_real(target) or not math.isfinite(target):
            raise ValueError(f"advance_to(target): target must be a finite time, got {target!r}")
        if target < self.time - 1e-12 * max(1.0, abs(self.time)):
            raise ValueError(f"advance_to({target!r}) lies before the current time {self.time!r}: "
                             "simulation time only moves forward")
        steps = 0
        while self.time < target - 1e-12 * max(1.0, abs(target)):
            if self.at_step_limit:
                break
            dt = min(self.stable_dt(), target - self.time)
            if dt == target - self.time and self._balance is not None:  # the last step: measure the state before
                self._balance["due"] = min(self._balance["due"], self.n_steps + 1)  # it for the check after it
            self.step(dt)
            steps += 1
            if on_step is not None:
                on_step(self)
        else:
            self.time = max(self.time, float(target))
        if steps and self._balance is not None and self._balance["steps"] != self.n_steps \
                and self.cfg.solver.energy_growth_limit is not None:
            self._check_energy_balance()  # after the last step, whatever the check interval
        return steps

    def advance(self, duration: float, on_step: Optional[Callable] = None) -> int:
        """Advance by `duration` (finite, >= 0) of simulation time (see advance_to)."""
        if not _is_real(duration) or not math.isfinite(duration) or duration < 0:
            raise ValueError(f"advance(duration): duration must be a finite number >= 0, got {duration!r}")
        return self.advance_to(self.time + duration, on_step)

    def run(self, on_output: Optional[Callable] = None, every: Optional[float] = None):
        """Run to solver.end_time (or solver.max_steps), calling on_output(self) at t=0 and every `every` seconds."""
        end = self.cfg.solver.end_time
        every = every or self.cfg.output.every
        if on_output:
            on_output(self)
        while self.time < end - 1e-12 * end and not self.at_step_limit:
            self.advance_to(min(self.time + every, end))
            if on_output:
                on_output(self)
        return self

    # ------------------------------------------------------------------ state access
    def particles(self) -> dict:
        """Particle state as numpy arrays in creation order: x, v, F, C and grad_v (when stored), stress (N, d, d),
        stress3 (N, 3, 3: the full Cauchy stress, out-of-plane normal stresses of plane strain / uniaxial strain
        included), mass, volume, body, damage (with a crack section), and the output states of the scene's material
        models (plastic_strain, Jp: materials/) when any has state; particles of other materials hold the initial
        value."""
        self._check_live()
        s = self.scene
        out = self._read_all()
        stress3 = np.zeros((self.n, 3, 3), dtype=np.float64)
        self._k["cauchy_stress"](stress3)
        stress3 = self._to_creation(stress3)
        d = self.dim
        if self.state is None:
            J = np.linalg.det(out["F"])
        else:  # plastic volume change (J_p) included
            J = np.zeros(self.n, dtype=np.float64)
            self._k["volume_ratios"](J)
            J = self._to_creation(J)
            out.update(self._output_states())
        out.update(stress=np.ascontiguousarray(stress3[:, :d, :d]), stress3=stress3, mass=s.mass.copy(),
                   volume=s.volume * J, body=s.body.copy())
        for e in self.extensions:
            out.update(e.outputs())   # the crack finder's damage
        return out

    # ------------------------------------------------------------------ material state (materials/: State)
    def _initial_state(self) -> np.ndarray:
        """(N, n_state) initial material state in creation order: each material's State.init in its slots, a
        geostatic body's consolidated state in its model's (bodies[].geostatic)."""
        q = np.zeros((self.n, self.n_state))
        for k, layout in enumerate(self.state_layout):
            sel = self.scene.material == k
            for j, st in enumerate(layout):
                q[sel, j] = st.init
        for particles, _, qg in self.scene.geostatic:
            q[particles, :qg.shape[1]] = qg
        return q

    def _material_state(self) -> np.ndarray:
        return self._to_creation(self.state.to_numpy().reshape(self.n, self.n_state))

    def _output_states(self) -> dict:
        """name -> (N,) of every output state of the scene's models (the initial value where a material lacks it)."""
        q = self._material_state()
        out = {}
        for st in dict.fromkeys(st for layout in self.state_layout for st in layout if st.output):
            a = np.full(self.n, st.init)
            for k, layout in enumerate(self.state_layout):
                names = [x.name for x in layout]
                if st.name in names:
                    sel = self.scene.material == k
                    a[sel] = q[sel, names.index(st.name)]
            out[st.name] = a
        return out

    def _state_fields(self) -> dict:
        fields = {"x": self.x, "v": self.v, "F": self.F}
        if self.C is not None:
            fields["C"] = self.C
        if self.grad_v is not None:   # viscous stresses read it: a resumed run continues bit for bit
            fields["grad_v"] = self.grad_v
        return fields

    def _read(self, name) -> np.ndarray:
        return self._read_all([name])[name]

    def _read_all(self, names=None) -> dict:
        """name -> (N, d) or (N, d, d) in creation order, of x, v, F, C (all stored ones by default), in one
        kernel (host_copy.py)."""
        fields = self._state_fields()
        names = list(fields) if names is None else list(names)
        d = self.dim
        if not self.n:
            return {k: np.zeros((0, d) if k in ("x", "v") else (0, d, d)) for k in names}
        arrays = host_copy.download([fields[k] for k in names])
        return {k: self._to_creation(a.reshape((self.n, d) if k in ("x", "v") else (self.n, d, d)))
                for k, a in zip(names, arrays)}

    def set_particles(self, **arrays):
        """Set per-particle state (x, v, F, C) in creation order."""
        self._check_live()
        fields = self._state_fields()
        checked = self._validated_particles(arrays)  # everything is checked before anything is written
        if self.n:
            host_copy.upload([(fields[name], self._to_solver(value)) for name, value in checked.items()])
        self._balance = self._shape_ref = None  # a new state: the balance and body shapes are measured afresh
        self._potentials = {}
        for e in self.extensions:
            e.particles_set(set(checked))   # the mapped grid's xi_p, F-bar's start-of-step J, crack normals
        if "v" in checked:
            self._vmax = _max_speed(checked["v"])
            self._half_dt = 0.0  # velocities given at the clock's time: the next step kicks over half a step
        states.restored(self)   # a failed simulation whose state is good again may step

    def _validated_particles(self, arrays: dict) -> dict:
        fields = self._state_fields()
        out = {}
        for name, value in arrays.items():
            if name not in fields:
                raise ValueError(f"cannot set '{name}' (settable: {', '.join(fields)})")
            try:
                value = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError) as e:
                raise ValueError(f"{name} must be a numeric array: {e}") from None
            want = (self.n, self.dim) if name in ("x", "v") else (self.n, self.dim, self.dim)
            if value.shape != want:
                raise ValueError(f"{name} must have shape {want}, got {value.shape}")
            if not np.isfinite(value).all():
                raise ValueError(f"{name} holds non-finite values (NaN or infinity)")
            out[name] = value
        states.check_particles(self, out)   # positions inside the domain, J = det F > 0
        return out

    def get_state(self) -> dict:
        """Everything needed to continue bit for bit: particle fields (creation order), clock, CFL speed estimate."""
        self._check_live()
        state = self._read_all()
        state.update(time=self.time, n_steps=self.n_steps, dt=self.dt, vmax=self._vmax, half_dt=self._half_dt,
                     work=self.work.to_numpy().astype(np.float64))
        if self.state is not None:
            state["material_state"] = self._material_state()  # plastic strain, J_p, ... (materials/: State)
        for e in self.extensions:
            state.update(e.get_state())  # the crack finder's damage (and the damage law's history)
        return state

    def set_state(self, state: dict):
        """Restore a get_state() dict. Everything is validated first, so a bad state changes nothing."""
        self._check_live()
        missing = [k for k in ("time", "n_steps", "dt", "vmax") if k not in state]
        if missing:
            raise ValueError(f"state lacks {', '.join(missing)}")
        try:
            clock = dict(time=float(state["time"]), n_steps=int(state["n_steps"]), dt=float(state["dt"]),
                         vmax=float(state["vmax"]))
            # the velocities' half-step lag; a state saved before leapfrog lacks it: its velocities belong to its dt
            clock["half_dt"] = float(state.get("half_dt", 0.5 * clock["dt"] if clock["n_steps"] > 0 else 0.0))
        except (TypeError, ValueError) as e:
            raise ValueError(f"state clock values must be numbers: {e}") from None
        if not all(math.isfinite(clock[k]) for k in ("time", "dt", "vmax", "half_dt")) or clock["n_steps"] < 0 \
                or clock["time"] < 0 or clock["dt"] < 0 or clock["vmax"] < 0 or clock["half_dt"] < 0:
            raise ValueError(f"state clock must be finite and non-negative, got {clock}")
        particles = self._validated_particles({k: state[k] for k in self._state_fields() if k in state})
        for e in self.extensions:
            e.check_state(state)
        q = None
        if self.state is not None:
            if "material_state" not in state:
                raise ValueError("state lacks material_state (the plastic models' per-particle history)")
            q = np.asarray(state["material_state"], dtype=np.float64)
            if q.shape != (self.n, self.n_state) or not np.isfinite(q).all():
                raise ValueError(f"state material_state must be finite with shape {(self.n, self.n_state)}, "
                                 f"got {q.shape}")
        work = None
        if "work" in state:
            work = np.asarray(state["work"], dtype=np.float64)
            if work.shape != (self.work.shape[0],) or not np.isfinite(work).all():
                raise ValueError(f"state work must be {self.work.shape[0]} finite numbers, got {work.shape}")
        if q is not None:
            self.state.from_numpy(self._to_solver(q))
        if work is not None:
            self.work.from_numpy(work)
        self.set_particles(**particles)
        self.time, self.n_steps, self.dt, self._vmax = clock["time"], clock["n_steps"], clock["dt"], clock["vmax"]
        self._half_dt = clock["half_dt"]
        for e in self.extensions:
            e.set_state(state)

    def energy(self) -> dict:
        """Kinetic, strain (the stored energy: the degraded energy where the crack finder damaged a particle, the
        hardening energy of plastic models), gravity potential; dissipated: viscous + plastic dissipation since the
        start (plastic: the plastic work of the return mappings, docs/materials.md)."""
        self._check_live()
        e, w = self._energy_parts()
        return {"kinetic": float(e[0]), "strain": float(e[1]), "gravity": float(e[2]),
                "dissipated": float(w[1] + w[2]), "plastic": float(w[2])}

    def momentum(self) -> dict:
        """Total linear momentum (dim) and angular momentum about the origin (3 components)."""
        self._check_live()
        self._k["momenta"]()
        m = self.diag.total()
        return {"linear": m[: self.dim], "angular": m[self.dim: self.dim + 3]}

    def wall_impulse(self, reset: bool = True) -> np.ndarray:
        """(2 dim, dim) impulse (N s; per metre of depth in 2D) each domain face (x_min, x_max, y_min, ...) gave
        the material at its grid nodes since the last reset: the momentum the wall condition changed in the grid
        update. Divided by the time since the reset it is the mean wall reaction force. Needs a wall probe in
        output.probes (otherwise nothing is accumulated and this raises)."""
        self._check_live()
        return self.extension("walls").impulse(reset)

    def prescribed_impulse(self, reset: bool = True) -> np.ndarray:
        """(K, dim) impulse (N s; per metre of depth in 2D) each bodies[].prescribed_velocity entry (in body order)
        gave the material at the grid nodes it holds since the last reset: divided by the elapsed time, the mean
        force the grip exerts (the reaction a testing machine would measure)."""
        self._check_live()
        grips = self.extension("grips")
        if grips is None:
            raise RuntimeError("the scene has no prescribed velocities (bodies[].prescribed_velocity)")
        return grips.impulse(reset)

    def max_speed(self) -> float:
        return _max_speed(self._read("v"))

    @property
    def velocity_time(self) -> float:
        """The time the particle velocities belong to: leapfrog keeps them half a step behind the positions
        (time - dt/2 after a step; `time` itself before the first step or after set_particles gave them)."""
        return self.time - self._half_dt

    # ------------------------------------------------------------------ runtime parameters (no recompile)
    @property
    def gravity(self) -> np.ndarray:
        """The gravity acceleration now (dim,): the config's solver.gravity until set_gravity changes it."""
        return self._gravity.copy()

    def set_gravity(self, g):
        """Change gravity from the next step on (dim numbers, m/s^2), without recompiling. The time step
        (dt_limits), the gravity potential of energy() and the energy balance use the new value from then on; the
        balance's reference moves with the potential's jump (a change of g does no work at that instant), so the
        energy check stays right across the change. The kick after the change takes the old g over its first half
        and the new one over its second (exact for a piecewise constant g)."""
        try:
            value = np.asarray(g, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise ValueError(f"set_gravity: gravity must be {self.dim} numbers, got {g!r}") from None
        if value.shape != (self.dim,) or not np.isfinite(value).all():
            raise ValueError(f"set_gravity: gravity must be {self.dim} finite numbers, got {g!r}")

        def apply():
            self._gravity = value
            self._upload_runtime()
        self._change_live(apply)

    def stiffness_scale(self, material: Optional[str] = None) -> float:
        """The stiffness scale of a material (by its name in the config; the only one when omitted)."""
        return float(self._stiffness[self._material_slots(material)[0]])

    def set_stiffness_scale(self, scale: float, material: Optional[str] = None):
        """Scale a material's stiffness (every material's when `material` is None) by `scale` > 0 from the next
        step on, without recompiling: the stress the model gives at any deformation times `scale`, i.e. every
        stress-like parameter (moduli, yield stress, cohesion, hardening, viscosity) scaled alike; the model's
        strain-space behaviour (yield strain, friction angle) is unchanged. Not scaled: the crack finder's Rankine
        law (tensile_strength, fracture_energy), so a stiffened material starts to crack at a smaller strain, and
        bodies[].stress. Waves travel sqrt(scale) times faster,
        so the CFL time step shrinks with it; the stored energy scales too, and the energy balance's reference moves
        with that jump. 1 is the config's material, bit for bit."""
        if not _is_real(scale) or not math.isfinite(scale) or scale <= 0:
            raise ValueError(f"set_stiffness_scale: scale must be a finite number > 0, got {scale!r}")
        slots = self._material_slots(material) if material is not None else range(len(self._materials))

        def apply():
            for k in slots:
                self._stiffness[k] = float(scale)
            self._upload_runtime()
            self.wave_speed = self._wave_speed()
        self._change_live(apply)

    @property
    def flip_blend(self) -> float:
        """FLIP's blend now: v = a (v + grid change) + (1 - a) v_grid (solver.flip_blend until set_flip_blend)."""
        return self._flip_blend

    def set_flip_blend(self, a: float):
        """Change FLIP's blend (0: PIC's velocity, 1: pure FLIP) from the next step on, without recompiling.
        Only for solver.transfer: flip (other transfers have no blend: ValueError)."""
        if self.cfg.solver.transfer != "flip":
            raise ValueError(f"set_flip_blend: the blend belongs to transfer flip; this simulation uses "
                             f"{self.cfg.solver.transfer}")
        if not _is_real(a) or not 0.0 <= a <= 1.0:
            raise ValueError(f"set_flip_blend: the blend must be a number in [0, 1], got {a!r}")
        self._check_live()
        self._flip_blend = float(a)
        self._upload_runtime()

    def _material_slots(self, material: Optional[str]) -> list[int]:
        names = list(self.scene.materials)
        if material is None:
            if len(names) != 1:
                raise ValueError(f"name the material (this scene has {', '.join(names)})")
            return [0]
        if material not in names:
            raise ValueError(f"no material {material!r} in this scene (it has {', '.join(names)})")
        return [names.index(material)]

    def _wave_speed(self) -> float:
        """The fastest P-wave speed at the present stiffness scales (the CFL rule's c)."""
        return float(np.max(self._wave_speeds * np.sqrt(self._stiffness)))

    def _change_live(self, apply: Callable):
        """Apply a runtime parameter change that makes the potential or stored energy jump, keeping the energy
        balance: its reference total moves by the jump (nothing did work at that instant), its round-off floor and
        scale follow the new values."""
        self._check_live()
        if self._balance is None:
            apply()
            return
        before, _ = self._energy_parts()
        previous = self._potentials.get(self.n_steps - 1)
        apply()
        after, _ = self._energy_parts()
        ref = self._balance
        jump = float(after[1] + after[2] - before[1] - before[2])
        ref["total"] += jump
        if previous is not None:  # the pairing's earlier state jumps alike (its positions are not kept)
            self._potentials[self.n_steps - 1] = previous + jump
        ref["floor"] = max(ref["floor"], self._energy_floor(after[3]))
        ref["scale"] = max(ref["scale"], after[5])

    def cfl_number(self) -> float:
        return self.dt * (self.wave_speed + self._vmax) / self.h_cfl


def _is_real(x) -> bool:
    return isinstance(x, (int, float, np.floating, np.integer)) and not isinstance(x, bool)


def _max_speed(v) -> float:
    return float(np.sqrt(np.max(np.sum(np.asarray(v) ** 2, axis=1))))


def _cell_counts(lower, upper, dx) -> list[int]:
    counts = []
    for a, (l, u) in enumerate(zip(lower, upper)):
        n = (u - l) / dx
        if abs(n - round(n)) > 1e-6 * max(1.0, n):
            raise ConfigError(f"the domain extent {u - l:g} along axis {a} is not a whole number of cells of dx={dx:g} "
                              f"({n:.4g}); choose dx = {(u - l) / max(1, round(n)):.6g}", key="domain.dx")
        counts.append(int(round(n)))
    return counts


def _fits(cfg: Config):
    """backend's size check of a dense grid: budget.check without its warnings."""
    budget.check(cfg, warn=False)
