"""Geometry of the config's analytic shapes (box, sphere, ring, cylinder), numpy only: rotations and bounding
boxes. Read by config validation and by scene.py (which adds the mesh shapes, whose bounds need their file), so it
names shapes by their `type` and imports neither."""
from __future__ import annotations

import numpy as np


def rotation(rot, d):
    """Rotation matrix from degrees: scalar (2D) or [rx, ry, rz] Euler angles (3D, applied x then y then z)."""
    if rot is None or d == 1:
        return np.eye(d)
    if d == 2:
        a = np.radians(rot if np.isscalar(rot) else rot[0])
        return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    rx, ry, rz = np.radians(rot if not np.isscalar(rot) else [0, 0, rot])
    Rx = np.array([[1, 0, 0], [0, np.cos(rx), -np.sin(rx)], [0, np.sin(rx), np.cos(rx)]])
    Ry = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    Rz = np.array([[np.cos(rz), -np.sin(rz), 0], [np.sin(rz), np.cos(rz), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def bounds(shape, d) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box of an analytic shape (rotations included)."""
    if shape.type == "box":
        lo, hi = np.asarray(shape.lower, float), np.asarray(shape.upper, float)
        if shape.rotation is None:
            return lo, hi
        c, R = 0.5 * (lo + hi), rotation(shape.rotation, d)
        corners = np.array(np.meshgrid(*[[l, h] for l, h in zip(lo, hi)], indexing="ij")).reshape(d, -1).T
        pts = (corners - c) @ R.T + c
        return pts.min(0), pts.max(0)
    if shape.type in ("sphere", "ring"):
        r = shape.radius if shape.type == "sphere" else shape.outer_radius
        c = np.asarray(shape.center, float)
        return c - r, c + r
    if shape.type == "cylinder":
        # exact: along world axis i the cap circles reach |u_i| h / 2 + r sqrt(1 - u_i^2) (u: the unit axis), so a
        # column standing on the floor fits a domain that starts at the floor
        c = np.asarray(shape.center, float)
        u = rotation(shape.rotation, 3)[:, "xyz".index(shape.axis)]
        ext = np.abs(u) * shape.height / 2 + shape.radius * np.sqrt(np.clip(1 - u**2, 0, None))
        return c - ext, c + ext
    raise TypeError(shape)
