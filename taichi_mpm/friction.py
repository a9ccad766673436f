"""Coulomb friction for a contact impulse, written once: walls (grid.make_wall_condition), body interfaces and crack
faces use the same law (Bardenhagen et al. 2000, "The material-point method for granular materials", eq. 27-29).

A contact removes a velocity `into` >= 0 along the unit normal n (a compressive impulse m into); the tangential
velocity relative to the other side is then reduced by mu into, and not below zero (the contact sticks). A contact
that pulls apart (tension) gives `into` = 0 and no friction."""

import taichi as ti


@ti.func
def friction_loss(vt, into, mu):
    """What friction mu takes off the tangential relative velocity vt when the contact removed a normal velocity
    `into` >= 0: vt min(1, mu into / |vt|) (all of it: the contact sticks). Subtract it from the velocity."""
    loss = ti.Vector.zero(float, vt.n)
    speed = vt.norm()
    if speed > 0.0:
        loss = vt * ti.min(1.0, mu * into / speed)
    return loss
