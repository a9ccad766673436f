"""Loads out of scale with a body's material: the cause a solver stop names before "lower solver.cfl" (issue 30,
"a solver stop's advice names the real cause"). An initial stress, a traction or pressure, or a body's own weight
(rho |g| H over its height along gravity) of the order of the material's stiffness M = lam + 2 mu (K for a fluid)
or more asks for a strain of 100 % or more: particles invert, collapse or are thrown out of the domain at any time
step, so a smaller step is no fix; the units of the load or of the material are. Values the precision cannot carry
at all are config errors already (config._check_ranges); these are in range and still no scene a step can follow.
"""
from __future__ import annotations

import numpy as np

from .expressions import largest_magnitude
from .geometry import bounds

STRAIN_LIMIT = 1.0   # load / stiffness at and above which no time step helps (a strain of 100 %)


def _flat(stress):
    for row in stress or []:
        yield from (row if isinstance(row, list) else [row])


def _loads(cfg, i, b, g):
    """(value in Pa, key, what) of body i's initial stress, tractions and weight."""
    from .config import SPACE, TIME

    key, at, ts = f"bodies.{i}", cfg._space_samples(b.shape), cfg._time_samples
    yield max((largest_magnitude(v, SPACE, **at) for v in _flat(b.stress)), default=0.0), f"{key}.stress", \
        "its initial stress"
    for j, t in enumerate(b.tractions):
        ramp = largest_magnitude(t.ramp, TIME, t=ts)
        size = abs(t.pressure) if t.pressure is not None else float(np.linalg.norm(t.traction))
        yield size * ramp, f"{key}.tractions.{j}", "its traction" if t.pressure is None else "its pressure"
    gn = float(np.linalg.norm(g))
    if gn > 0:
        try:
            lo, hi = bounds(b.shape, cfg.dim)
        except Exception:   # a mesh: the domain's height bounds it
            lo, hi = np.asarray(cfg.domain.lower, float), np.asarray(cfg.domain.upper, float)
        height = abs(float(np.dot(np.asarray(hi) - np.asarray(lo), np.asarray(g, float) / gn)))
        yield cfg.materials[b.material].density * gn * height, "solver.gravity", \
            f"its weight over its height (rho |g| H, H = {height:.3g} m)"


def load_scale_causes(cfg, gravity=None) -> list[str]:
    """The loads at or above STRAIN_LIMIT x their body's stiffness, largest ratio first, each as one clause."""
    g = np.asarray(gravity if gravity is not None else (cfg.solver.gravity or [0.0] * cfg.dim), float)
    found = []
    for i, b in enumerate(cfg.bodies):
        m = cfg.materials.get(b.material)
        if m is None:
            continue
        stiffness = float(m.modulus)
        for value, key, what in _loads(cfg, i, b, g):
            ratio = value / stiffness if stiffness > 0 else np.inf
            if value > 0 and ratio >= STRAIN_LIMIT:
                found.append((ratio, f"{key}: {what}, {value:.3g} Pa, is {ratio:.3g} x the stiffness of material "
                                     f"'{b.material}' (M = {stiffness:.3g} Pa): a strain of that size inverts "
                                     f"particles or throws them apart at any time step (check the units of {key} "
                                     f"and materials.{b.material}; a smaller solver.cfl does not help)"))
    return [text for _, text in sorted(found, key=lambda r: -r[0])]
