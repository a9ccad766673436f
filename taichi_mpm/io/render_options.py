"""The settings of a rendered frame (`output.render`, the `--color-by`/`--camera` options): the names they accept
and their defaults. Plain Python over the output-field registry, no pyvista: config validation reads it as well as
the renderer (render.py), compare and the window."""
from __future__ import annotations

from . import colour_range
from .. import fields as registry

# Scalar fields a frame can be coloured by: the registry's scalar and label fields, velocity components vx, vy, vz
# and the components sxx, sxy, ..., szz of the full 3x3 stress.
FIELDS = tuple(n for n, f in registry.REGISTRY.items() if f.kind in ("scalar", "label")) + ("vx", "vy", "vz")
ALIASES = {"velocity": "speed", "velocity_x": "vx", "velocity_y": "vy", "velocity_z": "vz", "mises": "von_mises",
           "stress": "von_mises"}
CAMERAS = ("iso", "xy", "xz", "yz", "front", "side", "top")  # 3D views; 2D and 1D frames are always seen along z


def color_fields() -> list[str]:
    """Every name output.render.color_by and --color-by accept: the scalar fields, aliases, vx/vy/vz, sxx ... szz."""
    return list(FIELDS) + list(ALIASES) + [f"s{a}{b}" for a in "xyz" for b in "xyz"]


def options(render_cfg) -> dict:
    """A render section (the config model or a dict, possibly partial) as the renderer's settings, defaults filled
    in and the colour field's alias resolved."""
    rc = render_cfg.model_dump() if hasattr(render_cfg, "model_dump") else dict(render_cfg or {})
    name = rc.get("color_by") or "speed"
    return dict(color_by=ALIASES.get(name, name), size=tuple(int(s) for s in (rc.get("size") or (960, 720))),
                camera=rc.get("camera") or "iso", point_size=rc.get("point_size"),
                cmap=rc.get("colormap") or "viridis", clim=list(rc["clim"]) if rc.get("clim") else None,
                scale=rc.get("scale") or "linear",
                percentiles=tuple(rc.get("percentiles") or colour_range.DEFAULT_PERCENTILES))
