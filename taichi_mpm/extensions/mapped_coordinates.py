"""domain.map as a step extension: every particle's parametric coordinates xi_p, found again after each position
update (Newton from the old xi_p; a failure stops the step with cause code 6) and from the map's samples when
positions are set from outside (a particle outside the mapped region is a config error). Physics code only."""
import numpy as np

from .. import layout
from ..bases.mapped import make_locate
from ..errors import ConfigError
from ..step.moments import Extension


class MappedCoordinates(Extension):
    name = "map"
    FAIL_CODE = 6

    def __init__(self, mapped, x, n: int, precision: str):
        self.mapped, self.x, self.n = mapped, x, n
        self.precision = precision

    @classmethod
    def create(cls, setup):
        return cls(setup.mapped, setup.x, setup.n, setup.precision) if setup.mapped is not None else None

    def bytes_per_particle(self) -> int:
        return layout.MAPPED_XI(self.mapped.dim).nbytes(self.precision)   # declared in layout.py (budget reads it)

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
                              "the map's image", key="domain.map")
