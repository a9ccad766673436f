"""PIC: the particle takes the grid velocity interpolated at its position (v_p = sum w_i v_i)."""
from .base import Scheme, register

PIC = register(Scheme(
    name="pic", summary="particle-in-cell: v_p = sum w v_i (stable, dissipative)",
    reference="Harlow 1964; Sulsky et al. 1994",
    cost="the baseline: one P2G and one G2P per step, no extra field"))
