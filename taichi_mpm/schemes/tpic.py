"""TPIC, Taylor particle-in-cell (Nakamura, Matsumura & Mikami 2023, as in GeoTaichi's "Taylor" projection): the
particle velocity field is its first-order Taylor expansion about x_p, v(x) = v_p + L_p (x - x_p), with L_p the
particle's velocity gradient L_p = sum v_i (grad w_ip)^T that G2P computes for the F update anyway. P2G maps
m_p w_ip (v_p + L_p (x_i - x_p)); G2P is PIC's v_p = sum w_ip v_i. For multilinear weights L_p is APIC's C_p
(B_p D_p^-1 = sum v_i grad w^T there), so TPIC is APIC; for B-splines and GIMP it differs from APIC but, like
it, transfers an affine velocity field exactly (sum w = 1, sum w r = 0, sum grad w = 0, sum x_i grad w^T = I)."""
from .base import Scheme, register

TPIC = register(Scheme(
    name="tpic", summary="Taylor PIC: v_p and L_p = sum v_i grad w^T, mapped as v_p + L_p (x_i - x_p)",
    reference="Nakamura, Matsumura & Mikami 2023, CMAME 403, 115720",
    accuracy=3,
    cost="a d x d matrix per particle (L_p, the velocity gradient G2P forms anyway); no D_p",
    affine=True, taylor=True))
