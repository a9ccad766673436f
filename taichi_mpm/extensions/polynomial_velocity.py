"""solver.transfer polypic's particle fields as a step extension: each particle's modes' coefficients and axis
polynomials (layout.polynomial_fields), which step/polynomial.py fits in G2P and evaluates in P2G. This extension
declares and allocates them, makes a particle's polynomial its constant v_p wherever v is set from outside (the
start, set_particles), and keeps them in checkpoints. Physics code only."""
import numpy as np
import taichi as ti

from .. import layout
from ..step.moments import Extension

STATE_KEYS = ("polypic_c", "polypic_g")   # the checkpoint's arrays, creation order: (particles, modes, d), (.., d, G)


class PolynomialVelocity(Extension):
    name = "polypic"

    def __init__(self, setup):
        self.dim, self.n, self.precision = setup.dim, setup.n, setup.precision
        self.to_solver, self.to_creation = setup.to_solver, setup.to_creation
        self.which = setup.needs.polynomial[1]
        self.decls = layout.polynomial_fields(self.dim, *setup.needs.polynomial)
        self.fields = [d.allocate(max(self.n, 1)) for d in self.decls]
        self.shapes = [d.shape for d in self.decls]

    @classmethod
    def create(cls, setup):
        return cls(setup) if setup.needs.polynomial else None

    def bytes_per_particle(self) -> int:
        return layout.nbytes(self.decls, self.precision)   # declared in layout.py (budget reads it)

    def prepare(self, ctx):
        ctx.extra["polynomial"] = (*self.fields, self.which)   # before the step's funcs are made: they read them

    def build(self, ctx):
        v, (poly_c, poly_g), dim = ctx.v, self.fields, self.dim
        n_modes, n_terms = self.shapes[0][0], self.shapes[1][1]

        @ti.kernel
        def constant():
            """Each particle's polynomial: its v_p (the constant mode, the first row), every other mode 0."""
            for p in v:
                for m, b in ti.static(ti.ndrange(n_modes, dim)):
                    poly_c[p][m, b] = v[p][b] if m == 0 else 0.0
                for a, t in ti.static(ti.ndrange(dim, n_terms)):
                    poly_g[p][a, t] = 0.0
        self.constant = constant

    def particles_set(self, names: set):
        if self.n and "v" in names:
            self.constant()

    def _read(self, field, shape) -> np.ndarray:
        a = field.to_numpy()[:self.n].astype(np.float64)   # 1 x k or k x 1 matrices come as vectors
        return self.to_creation(a.reshape((self.n,) + shape))

    def get_state(self) -> dict:
        return {key: self._read(f, shape) for key, f, shape in zip(STATE_KEYS, self.fields, self.shapes)}

    def check_state(self, state: dict):
        for key, shape in zip(STATE_KEYS, self.shapes):
            if key not in state:
                continue   # a state saved by another transfer: the polynomials start from v_p
            a = np.asarray(state[key], dtype=np.float64)
            if a.shape != (self.n,) + shape or not np.isfinite(a).all():
                raise ValueError(f"state {key} must be finite with shape {(self.n,) + shape}, got {a.shape}")

    def set_state(self, state: dict):
        if not self.n or not all(key in state for key in STATE_KEYS):
            return
        for key, f, shape in zip(STATE_KEYS, self.fields, self.shapes):
            a = self.to_solver(np.asarray(state[key], dtype=np.float64))
            f.from_numpy(a.reshape((self.n,) + shape) if 1 not in shape else a.reshape(self.n, -1))
