"""ASFLIP (Fei et al. 2021): APIC with a FLIP part, v_p = v_PIC + a (v_p - sum w v_old_i), and a position
correction x_p += dt (v_PIC + b_p (v_p_new - v_PIC)) with b_p = solver.asflip.position for particles whose
volume is not compressed (J >= 1) and solver.asflip.position_min otherwise: the FLIP part moves particles too,
so bodies can leave walls and each other, which APIC's grid-velocity positions cannot."""
from .base import Scheme, register

ASFLIP = register(Scheme(
    name="asflip", summary="ASFLIP: APIC plus a FLIP part with position correction (bodies separate)",
    reference="Fei, Guo, Wu, Huang & Gao 2021, ACM TOG 40(4) 109",
    accuracy=3,
    cost="APIC's B_p and FLIP's grid vector; no extra pass",
    parameters=("solver.asflip",), affine=True, keeps_old_grid=True, separating=True))
