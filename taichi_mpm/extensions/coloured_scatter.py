"""The coloured scatter's binding to the step (scatter.BlockBins: P2G without atomic adds): particles binned by
grid block before P2G; the solver runs the P2G kernels once per colour (`p2g_passes`). Physics code only."""
from ..step.moments import Extension


class ColouredScatter(Extension):
    name = "scatter"

    @classmethod
    def create(cls, setup):
        return cls() if setup.coloured else None

    def allocate(self, setup):
        self.bins = setup.bins
        self.p2g_passes = self.bins.colours

    def bytes_per_particle(self) -> int:
        return self.bins.bytes_per_particle

    def build(self, ctx):
        self.bins.build(ctx.stencil.origin)

    def before_p2g(self):
        self.bins.bin()
