"""MLS-MPM (Hu et al. 2018): APIC's affine velocity, and the internal force and the F update taken through the
same affine moment matrix: grad w_i is replaced by w_i D_p^-1 (x_i - x_p). The scheme of Taichi's mpm88/mpm3d
and taichi_elements. It needs a D_p that is never singular: multilinear weights (degree 1 without a particle
domain: linear, ddmp) make it singular where a particle sits on a node; the hats averaged over a particle's domain
(gimp, cpdi), the B-splines of degree 2 and above and ck's two staggered cells do not."""
from .base import Scheme, register

MLS = register(Scheme(
    name="mls", summary="MLS-MPM: APIC with the force and grad v through w D_p^-1 (x_i - x_p)",
    reference="Hu et al. 2018, ACM TOG 37(4) 150",
    accuracy=3,
    cost="APIC's B_p; no shape-function gradients (w D_p^-1 r instead)",
    basis_need=lambda spec: spec.regular_inertia,
    basis_why="a D_p that is never singular (weights of degree above 1, averaged over particle domains, or ck's)",
    affine=True, moment_gradient=True))
