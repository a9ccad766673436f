"""FLIP, blended with PIC: v_p = a (v_p + sum w (v_i - v_i_old)) + (1 - a) sum w v_i (solver.flip_blend)."""
from .base import Scheme, register

FLIP = register(Scheme(
    name="flip", summary="FLIP blended with PIC by solver.flip_blend (little dissipation, noisy)",
    reference="Brackbill & Ruppel 1986",
    accuracy=2,
    cost="one grid vector more (v before forces) and its sum in G2P",
    parameters=("solver.flip_blend",), keeps_old_grid=True))
