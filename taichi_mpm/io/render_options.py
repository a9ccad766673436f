"""The settings of a rendered frame (`output.render`, the `--color-by`/`--camera` options): the names they accept
and their defaults. Plain Python over the output-field registry, no pyvista: config validation reads it as well as
the renderer (render.py), compare and the window."""
from __future__ import annotations

from . import colour_range
from .. import fields as registry

VELOCITY = ("vx", "vy", "vz")
ALIASES = {"velocity": "speed", "velocity_x": "vx", "velocity_y": "vy", "velocity_z": "vz", "mises": "von_mises",
           "stress": "von_mises"}
CATEGORICAL = ("body", "material", "interface")   # label fields: one colour per integer value
CAMERAS = ("iso", "xy", "xz", "yz", "front", "side", "top")  # 3D views; 2D and 1D frames are always seen along z


def scalar_fields() -> tuple[str, ...]:
    """The fields a frame can be coloured by: the registry's scalar and label fields (read now, so a field
    registered later counts) and the velocity components vx, vy, vz."""
    return tuple(n for n, f in registry.REGISTRY.items() if f.kind in ("scalar", "label")) + VELOCITY


def color_fields() -> list[str]:
    """Every name output.render.color_by and --color-by accept: the scalar fields, aliases, vx/vy/vz, sxx ... szz."""
    return list(scalar_fields()) + list(ALIASES) + [f"s{a}{b}" for a in "xyz" for b in "xyz"]


def window_fields(particles: dict, dim: int) -> list[str]:
    """The colour fields the window cycles through for a state: speed, then the registry's other scalar and label
    fields the particle dict has (in registry order), then the velocity components of its dimension."""
    names = [n for n, f in registry.REGISTRY.items()
             if f.kind in ("scalar", "label") and registry.available(particles, n)]
    return sorted(names, key=lambda n: n != "speed") + list(VELOCITY[:dim])


def options(render_cfg) -> dict:
    """A render section (the config model or a dict, possibly partial) as the renderer's settings, defaults filled
    in and the colour field's alias resolved."""
    rc = render_cfg.model_dump() if hasattr(render_cfg, "model_dump") else dict(render_cfg or {})
    name = rc.get("color_by") or "speed"
    return dict(color_by=ALIASES.get(name, name), size=tuple(int(s) for s in (rc.get("size") or (960, 720))),
                camera=rc.get("camera") or "iso", point_size=rc.get("point_size"),
                cmap=rc.get("colormap") or "viridis", clim=list(rc["clim"]) if rc.get("clim") else None,
                scale=rc.get("scale") or "linear",
                percentiles=tuple(rc.get("percentiles") or colour_range.DEFAULT_PERCENTILES),
                framing=rc.get("framing") or "run")


def known_in_advance(render_cfg, dim: int) -> bool:
    """Whether a run's frames can be drawn as its outputs come: the colour range is fixed before the run (`clim`,
    or a label field: one colour per body) and so is the camera (2D and 1D: the domain; 3D: `framing` domain or a
    box). Otherwise they are drawn at the end, over the range and bounds of the whole run."""
    o = options(render_cfg)
    return bool(o["clim"] or o["color_by"] in CATEGORICAL) and (int(dim) < 3 or o["framing"] != "run")
