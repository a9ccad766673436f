"""Rankine damage law with linear softening (crack growth, crack.py): the parameters, per material. The Taichi side
(rankine_damage, degrade_tension) is in tensor.py. A model takes part when its class has `damage = True` and the
material sets tensile_strength (models that cannot carry tension, fluid and drucker_prager, have no such key or
ignore it)."""
from __future__ import annotations

from .base import MODELS


def rankine_params(mat, dx: float):
    """(E, eps0, eps_f) of the Rankine law with linear softening, or None when the material has no
    tensile_strength (or its model takes no damage). The softening is regularised by the grid spacing (crack band,
    Bazant & Oh 1983): eps_f = 2 G_f / (f_t dx), so the energy dissipated per unit crack area is G_f at any dx.
    Without fracture_energy the material is brittle (damage jumps to 1 at f_t)."""
    ft = getattr(mat, "tensile_strength", None)
    if ft is None or not MODELS[mat.model].damage:
        return None
    eps0 = ft / mat.E
    eps_f = eps0 if mat.fracture_energy is None else 2.0 * mat.fracture_energy / (ft * dx)
    if mat.fracture_energy is not None and eps_f <= eps0:
        from ..errors import ConfigError
        raise ConfigError(f"fracture_energy {mat.fracture_energy:g} is too small for dx={dx:g}: softening would snap back; "
                          f"need fracture_energy > tensile_strength^2 dx / (2 E) = {ft * eps0 * dx / 2:.4g}",
                          key="materials.fracture_energy")
    return (float(mat.E), float(eps0), float(eps_f))
