"""Parts of the step that plug in at its named moments: the solver calls every extension's moments in the order
of its list, and knows none of them by name.

The moments of a step, in order (`Simulation`):

    bytes_per_particle()     declare: the extension's memory per particle (its fields are allocated on creation)
    build(ctx)               build its kernels from the step context (step.StepContext), before the solver's own
    before_p2g()             after the grid is cleared, before the first P2G
    after_g2p()              after the last G2P pass: new positions and F
    particles_set(names)     particle fields were set from outside (upload, set_particles, set_state): names of them

Here: the ddmp pre-pass (nodal volumes), the coloured scatter's binning, the mapped grid's parametric coordinates
and F-bar's volume average. The crack finder (crack.py) keeps hooks of its own.

Physics code only: no CLI, rendering or file I/O here.
"""
import numpy as np
import taichi as ti

from .. import layout
from ..errors import ConfigError
from ..bases.mapped import make_locate


class Extension:
    """A part of the step; each moment does nothing unless the extension overrides it."""

    p2g_passes = 1   # P2G runs once per pass, each over a part of the particles (the coloured scatter's colours)

    def bytes_per_particle(self) -> int:
        return 0

    def build(self, ctx):
        pass

    def before_p2g(self):
        pass

    def after_g2p(self):
        pass

    def particles_set(self, names: set):
        pass


class DualDomainFill(Extension):
    """ddmp: the nodal volumes sum w V_p before P2G, the smoothed gradient's blend (stencils._dual_domain_fill)."""

    def build(self, ctx):
        self.prepare = ctx.stencil.prepare

    def before_p2g(self):
        self.prepare()


class ColouredScatter(Extension):
    """P2G without atomic adds (scatter.BlockBins): particles binned by grid block before P2G; the solver runs the
    P2G kernels once per colour (`p2g_passes`)."""

    def __init__(self, bins):
        self.bins = bins
        self.p2g_passes = bins.colours

    def bytes_per_particle(self) -> int:
        return self.bins.bytes_per_particle

    def build(self, ctx):
        self.bins.build(ctx.stencil.origin)

    def before_p2g(self):
        self.bins.bin()


class MappedCoordinates(Extension):
    """domain.map: every particle's parametric coordinates xi_p, found again after each position update (Newton
    from the old xi_p; a failure stops the step with cause code 6) and from the map's samples when positions are
    set from outside (a particle outside the mapped region is a config error)."""

    FAIL_CODE = 6

    def __init__(self, mapped, x, n: int, precision: str):
        self.mapped, self.x, self.n = mapped, x, n
        self.precision = precision

    def bytes_per_particle(self) -> int:
        return layout.MAPPED_XI.nbytes(self.precision)

    def build(self, ctx):
        self.locate, self.locate_from = make_locate(ctx, self.mapped, ctx.fail, ctx.fail_codes, self.FAIL_CODE)

    def after_g2p(self):
        self.locate()

    def particles_set(self, names: set):
        if "x" not in names or self.n == 0:
            return
        x = self.x.to_numpy().astype(np.float64)
        missed = self.locate_from(self.mapped.initial_guess(x))
        if missed:
            raise ConfigError(f"{missed} particles lie outside the mapped grid (domain.map): bodies must lie inside "
                              "the annulus", key="domain.map")


class VolumeAverage(Extension):
    """solver.volumetric fbar (fbar.FBar): after G2P the step's volume change averaged over the grid, then the
    return mappings of plastic models (they wait for the average: ctx.fbar) and F-bar's J^n from the projected F."""

    def __init__(self, fbar):
        self.fbar = fbar

    def bytes_per_particle(self) -> int:
        return self.fbar.bytes_per_particle()

    def build(self, ctx):
        self.fbar.build(ctx)
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
