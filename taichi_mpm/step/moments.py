"""The extension protocol: the named moments of a step, what an extension is handed at creation (`Setup`) and what
it may contribute to the step's kernels through the step context (`ParticleTransfer`, `Degradation`,
`NodeFields`, `GridSolve`). The solver calls every extension's moments in the order of step.extensions' list and
knows none of them by name; a moment an extension does not override does nothing.

The moments, in the order a simulation meets them (`Simulation`):

    adds_in_thread_order(cfg)  before Taichi starts: whether the scene's extension sums in the threads' order
                             (then solver.deterministic keeps one CPU thread)
    create(setup)            the extension, or None when the scene does not use it
    grid_fields()            declare: node fields it adds to the solver's grid (vectors, scalars), before allocation
    allocate(setup)          its own fields, once the grid exists (setup.grid)
    bytes_per_particle()     declare: its memory per particle
    prepare(ctx)             the step context exists, before the stencil and the material funcs are made: what those
                             read (the walls' condition, ctx.wall, whose holding faces the B-spline stencil keeps
                             particles inside of)
    build(ctx)               its kernels from the step context (step.StepContext), before the solver's own; this is
                             where it adds contributions the solver's kernels compile in (ctx.particle_transfer,
                             ctx.degradation, ctx.node_fields, ctx.force_sums, ctx.grid_solve)
    upload()                 the scene's initial values into its fields (after the solver's own)
    before_step(t, dt, lag)  a step from time t by dt begins (lag: the leapfrog velocities' half step behind t):
                             this step's values of time functions (tractions' ramps, grip and wall velocities)
    before_p2g()             after the grid is cleared, before the first P2G
    after_p2g()              after a P2G scatter of mass and momentum, before the grid solve (grips mark their
                             nodes)
    node_solve_active()      after P2G: whether its GridSolve.velocity acts this step (the grid solve's variant)
    after_g2p()              after the last G2P pass: new positions and F
    particles_set(names)     particle fields were set from outside (upload, set_particles, set_state): their names
    outputs()                per-particle arrays particles() adds (creation order)
    dissipation()            energy it removed since the start, by name (J): the energy balance counts it
    get_state()              its part of a checkpoint; check_state(state) refuses a bad one before anything changes,
    set_state(state)         set_state restores it after the solver's own state

`breaks_bodies`: bodies may separate by design (the numerical-fracture check is then off). `work_term`: what the
work it does on the material is called in the energy balance's message (it adds that work to ctx.work slot 0).

Physics code only: no CLI, rendering or file I/O here.
"""
from dataclasses import dataclass
from typing import Any, Callable, Optional


@dataclass
class Setup:
    """What an extension is handed at creation and allocation: the scene's constants, its particle fields, the
    order maps between creation order and solver slots; `grid` and `bins` once the grid is allocated."""
    cfg: Any                        # config.Config
    scene: Any                      # scene.Scene
    dim: int
    n: int                          # particles
    dx: float
    lower: Any                      # np.ndarray, domain corners
    upper: Any
    n_cells: list
    basis: Any                      # bases.shape_functions.Basis (or the mapped grid's)
    mapped: Any                     # bases.mapped.MappedGrid or None
    feat: Any                       # step.Features
    materials: list                 # material configs by slot
    x: Any
    v: Any
    F: Any
    vol0: Any
    to_solver: Callable             # per-particle array: creation order -> solver slots
    to_creation: Callable           # and back
    perm: Callable                  # () -> the solver slots' creation indices (set when particles are uploaded)
    coloured: bool = False          # P2G scatters by colours (scatter.BlockBins)
    work: Any = None                # sums.Slots: slot 0 the external work, 1 viscous, 2 plastic dissipation
    load: Any = None                # the per-particle external force P2G adds (layout's "load"), or None
    needs: Any = None               # layout.Needs: the fields the scene declares (layout.py)
    grid: Any = None                # grid.Grid, with every extension's grid_fields (allocate on)
    bins: Any = None                # scatter.BlockBins or None (allocate on)

    @property
    def precision(self) -> str:
        return self.cfg.precision


class Extension:
    """A part of the step; each moment does nothing unless the extension overrides it."""

    name = ""              # what Simulation.extension(name) finds it by
    p2g_passes = 1         # P2G runs once per pass, each over a part of the particles (the coloured scatter's colours)
    breaks_bodies = False  # bodies may separate by design: no numerical-fracture check
    work_term = ""         # the name of the work it does in the energy balance's message ("" none)

    @classmethod
    def adds_in_thread_order(cls, cfg) -> bool:
        return False

    @classmethod
    def create(cls, setup: Setup) -> Optional["Extension"]:
        raise NotImplementedError(f"{cls.__name__}.create(setup): the extension, or None where the scene has none")

    def grid_fields(self) -> tuple[list, list]:
        return [], []

    def allocate(self, setup: Setup):
        pass

    def bytes_per_particle(self) -> int:
        return 0

    def prepare(self, ctx):
        pass

    def build(self, ctx):
        pass

    def upload(self):
        pass

    def before_step(self, t: float, dt: float, lag: float):
        pass

    def before_p2g(self):
        pass

    def after_p2g(self):
        pass

    def node_solve_active(self) -> bool:
        return False

    def after_g2p(self):
        pass

    def particles_set(self, names: set):
        pass

    def outputs(self) -> dict:
        return {}

    def dissipation(self) -> dict:
        return {}

    def get_state(self) -> dict:
        return {}

    def check_state(self, state: dict):
        pass

    def set_state(self, state: dict):
        pass


@dataclass(frozen=True)
class ParticleTransfer:
    """An extension that takes some particles' transfers over (the crack finder's modified functions): the
    solver's P2G and G2P call these for a particle where `takes(p)`. st: the particle's stencil data."""
    takes: Callable          # (p) -> whether the extension transfers this particle
    p2g: Callable            # (p, st, mp, stress, vp, Ap, force_density, kick)
    p2g_momentum: Callable   # (p, st, mp, vp, Ap): MUSL's remap
    g2p: Callable            # (p, st, deform) -> (v_pic, FLIP increment, APIC B, velocity gradient)
    # (p, off) -> whether node `off` of p's stencil is on p's own side (the crack finder: not across its
    # discontinuity); grips hold only such nodes of their particles. None: every node is
    own_side: Optional[Callable] = None
    # (p, off, I) -> whether node I (`off` of p's stencil) holds p in a second velocity field of its own (the crack
    # finder's friction: a particle in contact, across the node); grips hold that field too. None: no node does
    second_field: Optional[Callable] = None


@dataclass(frozen=True)
class Degradation:
    """A per-particle change of the stress and stored energy (the crack finder's damage)."""
    stress: Callable         # (p, tau) -> degraded Kirchhoff stress
    energy: Callable         # (p, F, psi, tau) -> degraded strain energy density


@dataclass(frozen=True)
class NodeFields:
    """Node fields of an extension's own that every particle's standard transfer also writes (P2G) and, where it
    gives `velocity`, reads instead of the grid's velocity (G2P): multi-field contact's velocity field per body (the
    grid's own fields still get every particle's mass and momentum: the centre-of-mass field); the crack finder's
    node mass moments with friction (written only)."""
    scatter: Callable        # (p, I, w, gw, r = x_i - x_p, mp, momentum, momentum_old): P2G's node contribution
    velocity: Optional[Callable] = None       # (p, I) -> the node velocity G2P gives particle p (v_i, grad v from it)
    velocity_old: Optional[Callable] = None   # (p, I) -> FLIP's v_old_i for particle p


@dataclass(frozen=True)
class ForceSums:
    """Node sums of what P2G's internal force integrates (the local stress difference): the solver's standard
    transfer calls `scatter` for every node of a particle's stencil."""
    # (p, I, w, force_gradient, stress_volume, volume): stress_volume = V_p sigma_p (= V0 tau), the particle's
    # (degraded) stress times its volume; force_gradient the gradient its force term multiplies (grad w, or MLS's)
    scatter: Callable


@dataclass(frozen=True)
class GridSolve:
    """An extension's part of the grid solve (step.grid_update), the one chain every node goes through:
    node velocity from momentum (the solver's m^-1 p unless one extension gives `velocity`, compiled in on steps
    where its node_solve_active() says so), gravity, the extensions' `accelerate` terms in list order, then their
    `condition`s in list order (walls, then grips); then the extensions' `node_fields` (their own fields at the
    node, in list order); `images` fold nodes into others before the chain and set them from others after it. Each
    field may be None."""
    has_mass: Optional[Callable] = None     # (I, m) -> whether node I takes part (with `velocity`)
    velocity: Optional[Callable] = None     # (I, m, p) -> node velocity from momentum p (a tensor mass, say)
    accelerate: Optional[Callable] = None   # (I, vel, m, kick_before, kick_after) -> vel after a body acceleration
    # (I, vel, m, measure: template) -> vel under a boundary condition; measure (the step's update, not MUSL's
    # remap or USF's first pass): it may add its impulse m dv to its reaction sums and its work to ctx.work
    condition: Optional[Callable] = None
    node_fields: Optional[Callable] = None  # (I, kick_before, kick_after): its own node fields' solve at node I,
    #                                         after the grid's chain (multi-field contact)
    # (fold, mirror), loops of their own before the chain (fold(gm, decide, g, with_mass, gkick, measure): sums of
    # nodes into others) and after it (mirror(gm, g): those nodes' velocities from the others', or None), in the
    # step's update, MUSL's remap, USF's pass: ck's ghost nodes as images across the walls
    # (compact_kernel.make_ghost_images), ddmp's small nodes sharing their force (extensions/ddmp_fill.py; no mirror)
    images: Optional[tuple] = None
