"""solver.cpdi.variant cpdi2 as a step extension: each particle's 2^d domain corners, a particle field of their own.
The CPDI stencil (bases/corners.py) reads them for the weights and moves them in G2P; this extension declares and
allocates them, sets them from x and F where those are set from outside (x_p + F r0 s_c: the particle's initial
square / cube of half-width r0, half its spacing), keeps them in checkpoints and gives them to the outputs (the
domains as cells: io/files.py). Physics code only."""
import numpy as np
import taichi as ti

from .. import layout
from ..bases.corners import corner_signs, make_centroid
from ..bases.stencil_parts import domain_half_width
from ..step.moments import Extension

STATE_KEY = "cpdi_corners"   # the checkpoint's array: (particles, 2^d, d), creation order


class DomainCorners(Extension):
    name = "corners"

    def __init__(self, setup):
        self.dim, self.n, self.precision = setup.dim, setup.n, setup.precision
        self.to_solver, self.to_creation = setup.to_solver, setup.to_creation
        self.decl = layout.cpdi2_corners(self.dim)
        self.corners = self.decl.allocate(max(self.n, 1))

    @classmethod
    def create(cls, setup):
        return cls(setup) if setup.needs.cpdi2 else None

    def bytes_per_particle(self) -> int:
        return self.decl.nbytes(self.precision)   # declared in layout.py (budget reads it)

    def prepare(self, ctx):
        ctx.extra["corners"] = self.corners   # before the stencil is made: it reads them

    def build(self, ctx):
        x, F, corners, dim, dx = ctx.x, ctx.F, self.corners, self.dim, ctx.dx
        half_width = domain_half_width(ctx)
        signs = corner_signs(dim)

        @ti.kernel
        def reset():
            """Corners x_p + F_p r0 s_c: the particle's initial domain, deformed by F."""
            for p in x:
                A = F[p] * (half_width(p) * dx)
                for c in ti.static(range(2 ** dim)):
                    xc = x[p] + A @ ti.Vector(signs[c])
                    for a in ti.static(range(dim)):
                        corners[p][c, a] = xc[a]
        centroid = make_centroid(dim)

        @ti.kernel
        def recentre():
            """x_p at its domain's centroid (where the stencil takes it to be)."""
            for p in x:
                x[p] = centroid(corners[p])[0]
        self.reset, self.recentre = reset, recentre

    def particles_set(self, names: set):
        if self.n and names & {"x", "F"}:
            self.reset()

    def corner_positions(self) -> np.ndarray:
        """(particles, 2^d, d) in creation order."""
        a = self.corners.to_numpy()[:self.n].astype(np.float64)   # a 1D scene's (2, 1) matrices come as vectors
        return self.to_creation(a.reshape(self.n, 2 ** self.dim, self.dim))

    def outputs(self) -> dict:
        return {"domain_corners": self.corner_positions()}

    def get_state(self) -> dict:
        return {STATE_KEY: self.corner_positions()}

    def check_state(self, state: dict):
        if STATE_KEY not in state:
            return   # a state without them (saved by cpdi1): the corners follow x and F as set
        a = np.asarray(state[STATE_KEY], dtype=np.float64)
        want = (self.n, 2 ** self.dim, self.dim)
        if a.shape != want or not np.isfinite(a).all():
            raise ValueError(f"state {STATE_KEY} must be finite with shape {want}, got {a.shape}")

    def set_state(self, state: dict):
        if STATE_KEY in state and self.n:
            self.set_corners(state[STATE_KEY], recentre=False)

    def set_corners(self, corners, recentre: bool = True):
        """Set every particle's corners, (particles, 2^d, d) in creation order; recentre: each particle moves to
        its new domain's centroid (where the stencil takes it to be)."""
        a = self.to_solver(np.asarray(corners, dtype=np.float64))
        # a 1D scene's (2, 1) matrices are vectors to numpy; the field's own precision
        self.corners.from_numpy(a.reshape(self.n, -1) if self.dim == 1 else a)
        if recentre:
            self.recentre()
