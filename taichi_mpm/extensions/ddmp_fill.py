"""ddmp's pre-pass as a step extension: the nodal volumes sum w V_p before P2G, which the smoothed gradient's blend
reads (stencils._dual_domain_fill). Physics code only: no CLI, rendering or file I/O here."""
from ..bases import registry as bases
from ..step.moments import Extension


class DualDomainFill(Extension):
    name = "ddmp"

    @classmethod
    def adds_in_thread_order(cls, cfg) -> bool:
        return bases.get(cfg.solver.basis).prepass_grid   # the nodal volumes' atomic sums

    @classmethod
    def create(cls, setup):
        basis = setup.basis
        return cls() if basis.kind == "tensor" and basis.smooth_1d is not None else None

    def build(self, ctx):
        self.prepare = ctx.stencil.prepare

    def before_p2g(self):
        self.prepare()
