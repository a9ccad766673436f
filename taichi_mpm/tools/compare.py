"""`taichi-mpm compare CONFIG --vary KEY=A,B[,C]`: the same scene run with one setting changed, seen side by side.

Each variant runs to solver.end_time in this process (one Simulation at a time) and keeps, at every output time,
its frame data (positions, the colour field) and its energies and momentum. The frames are then rendered with one
colour range (robust percentiles over every variant and frame) and one camera, panel by panel, into
OUT/frames/frame_NNNNNN.png and OUT/movie.mp4; the curves of every variant go on one plot (OUT/curves.png) and the
numbers into OUT/summary.csv. A variant that blows up keeps its last good frame, marked unstable: seeing where a
setting breaks is part of the comparison.
"""
from __future__ import annotations

import csv
import re
import time
from pathlib import Path

import numpy as np

from ..config import ConfigError, apply_overrides, load_config, parse_value

MEMORY_LIMIT = 2 * 1024**3   # bytes of frame data kept for all variants together
MAX_VARIANTS = 8             # values of --vary: the panels of a frame, side by side (a longer sweep is a study)
MAX_WORK = 1e11              # particle-steps of all variants together (~1 h on a CPU at 3e7 particle-steps/s)
WRITTEN = ("frames/frame_*.png", "movie.mp4", "curves.png", "summary.csv")


def split_values(text: str) -> list[str]:
    """'linear,cubic' -> ['linear', 'cubic']; commas inside brackets stay ('[0,-9.81],[0,0]' -> two lists)."""
    out, depth, cur = [], 0, ""
    for ch in text:
        depth += ch in "[{(" and 1 or 0
        depth -= ch in "]})" and 1 or 0
        if ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
        else:
            cur += ch
    out.append(cur.strip())
    return out


def parse_vary(text: str) -> tuple[str, list[str]]:
    """'solver.basis=linear,cubic' -> ('solver.basis', ['linear', 'cubic']); ConfigError when malformed."""
    key, sep, values = (text or "").partition("=")
    key = key.strip()
    vals = split_values(values) if sep else []
    if not key or any(not part for part in key.split(".")) or len(vals) < 2 or any(v == "" for v in vals):
        raise ConfigError(f"--vary expects KEY=A,B[,C...] with a dotted KEY and at least two values "
                          f"(e.g. solver.basis=linear,cubic), got {text!r}")
    if len(vals) > MAX_VARIANTS:   # before any value is parsed or any config loaded
        raise ConfigError(f"--vary {key}: {len(vals)} values, at most {MAX_VARIANTS} (one panel each, side by side); "
                          f"compare fewer, or sweep them in a study (taichi-mpm study, docs/study.md)")
    if len(set(vals)) != len(vals):
        raise ConfigError(f"--vary {key}: the values repeat ({', '.join(vals)})", key=key)
    return key, vals


class Variant:
    """One run of the comparison: its label, config and what it recorded at each output time."""

    def __init__(self, key, value, cfg):
        self.key, self.value, self.cfg = key, value, cfg
        self.label = f"{key.split('.')[-1]} = {value}"
        self.times, self.x, self.values, self.rows = [], [], [], []
        self.spacing = float("nan")
        self.wall, self.steps, self.status = 0.0, 0, "ok"


def _record(v: Variant, sim, field):
    from ..io import files as io
    from ..io.render import field_values

    p = io.derived_fields(sim.particles(), sim.scene)
    if not np.isfinite(v.spacing):
        v.spacing = float(np.median(np.abs(p["volume"]))) ** (1.0 / sim.dim)
    v.times.append(sim.time)
    v.x.append(np.asarray(p["x"], np.float32))
    v.values.append(field_values(p, field, sim.dim).astype(np.float32))
    e, mom, bal = sim.energy(), sim.momentum(), sim.energy_balance()
    v.rows.append(dict(time=sim.time, kinetic=e["kinetic"], strain=e["strain"], gravity=e["gravity"],
                       total=e["kinetic"] + e["strain"] + e["gravity"], dissipated=e["dissipated"],
                       momentum=float(np.linalg.norm(mom["linear"])),
                       **{f"p{a}": float(c) for a, c in zip("xyz", mom["linear"])},
                       energy_error=bal["ratio"]))


def run_variant(v: Variant, field: str, log=None):
    from ..errors import InstabilityError
    from ..io.runner import Simulation

    t0 = time.perf_counter()
    sim = Simulation(v.cfg)
    try:
        sim.run(on_output=lambda s: _record(v, s, field), every=v.cfg.output.every)
    except InstabilityError as e:
        v.status = f"unstable at t={e.time:.4g} s: {e.cause}"
        if log:
            log(f"{v.label}: {e}")
    v.steps, v.wall = sim.n_steps, time.perf_counter() - t0
    if log:
        log(f"{v.label}: {v.steps} steps in {v.wall:.1f} s ({v.status})")


def _out_dir(cfg, key, out):
    if out is not None:
        return Path(out)
    base = Path(cfg.output.dir.replace("{name}", cfg.name))
    suffix = key.split(".")[-1]
    if not re.fullmatch(r"[A-Za-z0-9_-]+", suffix):  # a user-chosen name in the key never becomes a path
        suffix = "vary"
    return base.parent / f"{base.name}_compare_{suffix}"


def compare(config, vary: str, overrides: dict | None = None, out=None, overwrite: bool = False,
            color_by: str | None = None, size=None, camera: str | None = None, movie: bool = True,
            log=None) -> dict:
    """Run the variants of `config` (path, dict or Config) over `vary` ('KEY=A,B,...') and write the side-by-side
    frames, movie, curves and summary. Returns {"out", "frames", "movie", "curves", "summary", "variants",
    "render_seconds", "work"}."""
    key, values = parse_vary(vary)
    base = load_config(config, overrides or {})
    variants = _variants(base, key, values)
    rc, field = _render_settings(base, len(variants), color_by, size, camera)
    out = _out_dir(base, key, out)
    held = [p for p in WRITTEN if next(out.glob(p), None) is not None] if out.is_dir() else []
    if held and not overwrite:
        raise ConfigError(f"{out} already holds a comparison ({', '.join(held)}): add --overwrite to replace it")
    work = estimate_work(base, key, variants)
    if log:
        log(work["summary"])
    for v in variants:
        try:
            run_variant(v, field, log)
        except ValueError as e:  # a colour field this scene does not have (damage without a crack section)
            if isinstance(e, ConfigError):
                raise
            raise ConfigError(str(e), key="output.render.color_by") from None
    for pattern in WRITTEN:
        for f in out.glob(pattern):
            f.unlink()
    (out / "frames").mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    frames = render_frames(variants, rc, base, out / "frames")
    movie_path = None
    if movie and frames:
        from ..io.render import make_movie

        movie_path = make_movie(frames, out / "movie.mp4")
    render_seconds = time.perf_counter() - t0
    curves = plot_curves(variants, out / "curves.png", base.dim)
    summary = write_summary(variants, out / "summary.csv")
    if log:
        log(f"rendered {len(frames)} frames ({len(variants)} panels each) in {render_seconds:.1f} s")
    return dict(out=out, frames=frames, movie=movie_path, curves=curves, summary=summary, variants=variants,
                render_seconds=render_seconds, work=work)


def _variants(base, key: str, values: list) -> list[Variant]:
    """One validated config per value: every variant is checked before anything runs."""
    variants = []
    for value in values:
        data = apply_overrides(base.to_dict(), {key: value})
        try:
            cfg = load_config(data)
        except ConfigError as e:
            raise ConfigError(f"--vary {key}={value}: {e}", key=key) from None
        variants.append(Variant(key, parse_value(value) if isinstance(value, str) else value, cfg))
    return variants


def _render_settings(base, n_panels: int, color_by, size, camera) -> tuple[dict, str]:
    """The render section every panel shares (a panel's width: the frame's split n ways) and the colour field;
    an unknown field or camera is an input error before any run (a field the scene lacks: at its first frame)."""
    from ..io.render import FrameRenderer, color_fields, field_values
    from ..io.render_options import options

    rc = base.output.render.model_dump()
    if color_by and color_by != rc["color_by"]:
        rc["color_by"], rc["clim"] = color_by, None
    if camera:
        rc["camera"] = camera
    w, h = size or rc["size"]
    rc["size"] = [max(64, int(w) // n_panels), int(h)]
    field = options(rc)["color_by"]
    try:
        if field not in color_fields():
            field_values({"x": np.zeros((0, base.dim))}, field, base.dim)
        FrameRenderer(rc, base.dim, base.domain.lower, base.domain.upper)
    except ValueError as e:
        raise ConfigError(str(e), key="output.render") from None
    return rc, field


def estimate_work(base, key: str, variants: list[Variant]) -> dict:
    """What the comparison will do, from the size estimate alone (budget.check, which also refuses a variant too
    big to run): particle-steps over all variants, frames, and the frame data kept in memory. Refused (ConfigError)
    beyond MEMORY_LIMIT of frame data or MAX_WORK particle-steps (the latter unless limits.allow_large)."""
    from ..budget import check

    estimates = [check(v.cfg) for v in variants]
    n_outputs = int(base.solver.end_time / base.output.every) + 2
    need = sum(e.particles for e in estimates) * n_outputs * 16
    if need > MEMORY_LIMIT:
        raise ConfigError(f"the comparison would keep {need / 1024**3:.1f} GB of frame data; raise output.every "
                          f"(now {base.output.every:g} s) or coarsen the scene", key="output.every")
    particle_steps = float(sum(e.particles * e.steps for e in estimates))
    summary = (f"compare: {len(variants)} variants of {key}, about {particle_steps:.3g} particle-steps in all "
               f"({', '.join(f'{e.particles:,} particles x {e.steps:.3g} steps' for e in estimates)}), "
               f"{n_outputs - 1} frames")
    if particle_steps > MAX_WORK and not base.limits.allow_large:
        raise ConfigError(f"--vary {key}: {summary[len('compare: '):]}: more than {MAX_WORK:.3g} particle-steps; "
                          f"compare fewer values, coarsen the scene, or pass --allow-large (limits.allow_large: true)")
    return dict(particle_steps=particle_steps, frames=n_outputs - 1, frame_bytes=need, summary=summary)


def render_frames(variants, rc: dict, base, folder: Path) -> list[Path]:
    """Side-by-side frames, one panel per variant, with one colour range and one camera for every panel; a variant
    that stopped early keeps its last good frame, framed in red."""
    from ..io.render import FrameRenderer, grid_lines, sequence_bounds, sequence_limits, write_png

    limits = sequence_limits(rc, [a for v in variants for a in v.values])
    spacing = float(np.nanmedian([v.spacing for v in variants]))
    bounds = sequence_bounds([a for v in variants for a in v.x], spacing, base.dim) if base.dim == 3 else None
    renderers = [FrameRenderer(rc, base.dim, base.domain.lower, base.domain.upper, limits=limits, bounds=bounds,
                               title=v.label, lines=grid_lines(v.cfg)) for v in variants]
    frames = []
    try:
        for k in range(max(len(v.times) for v in variants)):
            panels = [_panel(v, r, k, rc, spacing) for v, r in zip(variants, renderers)]
            sep = np.full((rc["size"][1], 2, 3), 160, np.uint8)
            row = [panels[0]]
            for pnl in panels[1:]:
                row += [sep, pnl]
            path = folder / f"frame_{k:06d}.png"
            write_png(path, np.hstack(row))
            frames.append(path)
    finally:
        for r in renderers:
            r.close()
    return frames


def _panel(v: Variant, renderer, k: int, rc: dict, spacing: float) -> np.ndarray:
    j = min(k, len(v.times) - 1)   # a variant that stopped early keeps showing its last good frame
    if j < 0:
        return np.full((rc["size"][1], rc["size"][0], 3), 255, np.uint8)
    img = renderer.image(v.x[j], v.values[j], v.times[j], spacing=spacing)
    if j < k:                       # stopped: a red frame around the panel
        img = img.copy()
        img[:6], img[-6:], img[:, :6], img[:, -6:] = (200, 30, 30), (200, 30, 30), (200, 30, 30), (200, 30, 30)
    return img


def plot_curves(variants, path, dim) -> Path:
    """Energies, momentum and the energy-balance error of every variant over time, one colour per variant."""
    from ..io.plots import pyplot

    plt = pyplot()
    panels = (("kinetic", "kinetic energy"), ("strain", "strain energy"), ("total", "total energy (kinetic + "
              "strain + gravity)"), ("momentum", "|linear momentum|"), ("energy_error", "energy-balance error "
              "(fraction of the largest kinetic + strain)"))
    unit_e = "J" if dim == 3 else ("J/m" if dim == 2 else "J/m^2")
    unit_p = "kg m/s" if dim == 3 else ("kg/s" if dim == 2 else "kg/(m s)")
    fig, axes = plt.subplots(len(panels), 1, figsize=(7, 2.1 * len(panels)), sharex=True)
    for ax, (col, title) in zip(axes, panels):
        for v in variants:
            t = [r["time"] for r in v.rows]
            ax.plot(t, [r[col] for r in v.rows], label=v.label + ("" if v.status == "ok" else " (unstable)"))
        unit = unit_p if col == "momentum" else ("1" if col == "energy_error" else unit_e)
        ax.set_ylabel(f"[{unit}]", fontsize="small")
        ax.set_title(title, fontsize="small", loc="left")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize="small", loc="best")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def write_summary(variants, path) -> Path:
    cols = ["key", "value", "status", "steps", "wall_s", "outputs", "kinetic_end", "strain_end", "total_start",
            "total_end", "momentum_end", "max_abs_energy_error"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for v in variants:
            first, last = (v.rows[0], v.rows[-1]) if v.rows else ({}, {})
            err = max((abs(r["energy_error"]) for r in v.rows), default=float("nan"))
            w.writerow([v.key, v.value, v.status, v.steps, f"{v.wall:.3f}", len(v.rows), last.get("kinetic"),
                        last.get("strain"), first.get("total"), last.get("total"), last.get("momentum"), err])
    return Path(path)
