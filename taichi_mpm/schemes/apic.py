"""APIC: the particle carries an affine velocity C_p (B_p D_p^-1) besides v_p; angular momentum is conserved."""
from .base import Scheme, register

APIC = register(Scheme(
    name="apic", summary="affine particle-in-cell: v_p and C_p = B_p D_p^-1 (conserves angular momentum)",
    reference="Jiang et al. 2015",
    accuracy=3,
    cost="a d x d matrix per particle (B_p) and its sum in G2P", affine=True))
