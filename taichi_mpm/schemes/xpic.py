"""XPIC(m) (Hammerquist & Nairn 2017): PIC whose particle velocity keeps the part of v_p the grid can represent,
estimated to order m: v_p = S (v_L - v + v*), v* = sum_{k=1..m} (I - S+S)^(k-1) v, where v is the lumped grid
velocity of the particles before forces, S interpolates grid to particles and S+ maps back mass-weighted. Order 1
is PIC; larger m removes less of the velocity field (less numerical dissipation), each order one more
particle-grid pass (step/xpic.py)."""
from .base import Scheme, register

XPIC = register(Scheme(
    name="xpic", summary="XPIC(m): PIC with the grid-representable part of v_p kept to order solver.xpic_order",
    reference="Hammerquist & Nairn 2017, CMAME 318, 724-738",
    accuracy=2,
    cost="FLIP's grid vector plus three; m - 1 extra particle passes (a G2P and P2G each) per step",
    parameters=("solver.xpic_order",), keeps_old_grid=True, extended=True,
    grid_vectors=("xpic_sum", "xpic_inc", "xpic_map")))   # v*, the current increment dv_k, S+ S dv_k's sums
