"""solver.volumetric fbar as a step extension (fbar.FBar): after G2P the step's volume change averaged over the
grid, then the return mappings of plastic models (they wait for the average: the extension sets
ctx.project_after_g2p, so G2P leaves them out) and F-bar's J^n from the projected F. Physics code only."""
import taichi as ti

from . import fbar as fbar_module
from ..step.moments import Extension


class VolumeAverage(Extension):
    name = "fbar"

    @classmethod
    def adds_in_thread_order(cls, cfg) -> bool:
        return cfg.solver.volumetric == "fbar"   # the average's node sums

    @classmethod
    def create(cls, setup):
        return cls() if setup.cfg.solver.volumetric == "fbar" and setup.dim > 1 else None

    def allocate(self, setup):
        self.fbar = fbar_module.create(setup)   # (reads the setup's cfg, dim, n, n_cells, grid, particle fields)

    def bytes_per_particle(self) -> int:
        return self.fbar.bytes_per_particle()

    def build(self, ctx):
        self.fbar.build(ctx)
        ctx.project_after_g2p = True
        self.project_all = _project_all(ctx) if ctx.feat.plastic else None

    def after_g2p(self):
        self.fbar.apply()
        if self.project_all is not None:
            self.project_all()
            self.fbar.sync()

    def particles_set(self, names: set):
        if "F" in names:
            self.fbar.sync()  # F-bar's start-of-step J follows the new F


def _project_all(ctx):
    x, F, project = ctx.x, ctx.F, ctx.project

    @ti.kernel
    def project_all():
        """The return mappings after F-bar's volume average (solver.volumetric: fbar)."""
        for p in x:
            F[p] = project(p, F[p])
    return project_all
