"""Files a run writes: particle snapshots (VTU via meshio, or NPZ), the ParaView series file (PVD),
diagnostics.csv, checkpoint.npz and the resolved config.yaml.

Reads solver state only through the public Simulation API (particles(), energy(), momentum(),
max_speed(), cfl_number(), get_state()). Every file is written to a temporary name first and then
renamed, so a run stopped at any moment leaves complete files behind.
"""
from __future__ import annotations

import csv
import json
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import yaml

from . import fields as registry

SNAPSHOT = "particles_{:06d}"
PVD_NAME = "particles.pvd"
DIAGNOSTICS_NAME = "diagnostics.csv"
CHECKPOINT_NAME = "checkpoint.npz"
CONFIG_NAME = "config.yaml"

ALWAYS = registry.ALWAYS  # written to every VTU ("damage" when present)
von_mises = registry.von_mises


# ---------------------------------------------------------------- helpers
def _atomic(path: Path):
    """A temporary sibling of `path`; call os.replace(tmp, path) when it is complete."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp{os.getpid()}")


def _pad3(a: np.ndarray) -> np.ndarray:
    """(N, d) -> (N, 3) with zeros for the missing axes."""
    a = np.asarray(a, dtype=np.float64).reshape(len(a), -1)
    return np.pad(a, ((0, 0), (0, 3 - a.shape[1])))


def derived_fields(p: dict, scene=None) -> dict:
    """A particles() dict with the output fields computed once (registry.REGISTRY: J, von_mises, speed, pressure,
    ... and, when the scene is given, displacement, material and interface); returns a new dict."""
    out = registry.with_scene(p, scene) if scene is not None else dict(p)
    for name in registry.REGISTRY:
        if name not in out and registry.available(out, name) and registry.REGISTRY[name].kind in ("scalar", "label"):
            out[name] = registry.values(out, name)
    return out


def point_data(p: dict, fields=()) -> dict:
    """VTU point data of a particle dict: the ALWAYS set plus `fields` (config output.fields), each as the
    registry computes it; vectors padded to 3 components, tensors written as full 3x3 (9 components)."""
    out = {}
    for name in dict.fromkeys(list(ALWAYS) + list(fields)):
        if not registry.available(p, name):
            continue  # e.g. damage without a crack section, C without APIC
        kind = registry.REGISTRY[name].kind
        a = np.asarray(registry.values(p, name))
        if kind == "tensor":
            a = a.reshape(len(a), 9).astype(np.float64)
        elif kind == "vector":
            a = _pad3(a)
        elif kind == "label" or np.issubdtype(a.dtype, np.integer):
            a = a.astype(np.int32)
        else:
            a = a.astype(np.float64)
        out[name] = a
    return out


# ---------------------------------------------------------------- snapshots
def write_vtu(path, p: dict, fields=()):
    """One particle snapshot as a VTU of vertex cells (points padded to 3D)."""
    import meshio

    path = Path(path)
    n = len(p["x"])
    mesh = meshio.Mesh(_pad3(p["x"]), [("vertex", np.arange(n, dtype=np.int64).reshape(n, 1))],
                       point_data=point_data(p, fields))
    tmp = _atomic(path)
    meshio.write(tmp, mesh, file_format="vtu", binary=True)
    os.replace(tmp, path)


def read_vtu(path, dim: int | None = None) -> dict:
    """Read a snapshot back: x (N, dim) plus the point data, vectors as (N, dim), tensors as (N, dim, dim), and
    the full 3x3 stress as stress3."""
    import meshio

    m = meshio.read(path)
    if dim is None:
        dim = 3 - int(np.all(m.points[:, 2] == 0)) - int(np.all(m.points[:, 1:] == 0))
    out = {"x": m.points[:, :dim].copy()}
    for name, a in m.point_data.items():
        if a.ndim == 2 and a.shape[1] == 9:
            if name == "stress":
                out["stress3"] = a.reshape(-1, 3, 3).copy()
            a = a.reshape(-1, 3, 3)[:, :dim, :dim]
        elif a.ndim == 2 and a.shape[1] == 3:
            a = a[:, :dim]
        out[name] = a
    return out


def write_npz(path, p: dict, fields=()):
    """One particle snapshot as .npz, unpadded: x, v, F, stress (N, d, d), stress3 (N, 3, 3), mass, volume, body, the
    scalar fields of the ALWAYS set and `fields` (vectors (N, d); the tensors F and C as (N, d, d))."""
    path = Path(path)
    arrays = {k: np.asarray(p[k]) for k in ("x", "v", "F", "stress", "stress3", "mass", "volume", "body") if k in p}
    if "stress3" not in arrays and "stress" in p:
        arrays["stress3"] = registry.stress3(p)
    for name in dict.fromkeys(list(ALWAYS) + list(fields)):
        if name in ("velocity", "stress") or not registry.available(p, name):
            continue
        arrays[name] = np.asarray(p[name]) if name in ("F", "C") else np.asarray(registry.values(p, name))
    tmp = _atomic(path)
    with open(tmp, "wb") as f:
        np.savez(f, **arrays)
    os.replace(tmp, path)


# ---------------------------------------------------------------- PVD series
def write_pvd(path, entries):
    """ParaView collection file: entries are (time, file name relative to the PVD)."""
    path = Path(path)
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    coll = ET.SubElement(root, "Collection")
    for time, name in entries:
        ET.SubElement(coll, "DataSet", timestep=repr(float(time)), group="", part="0", file=str(name))
    ET.indent(root)
    tmp = _atomic(path)
    ET.ElementTree(root).write(tmp, encoding="utf-8", xml_declaration=True)
    os.replace(tmp, path)


def read_pvd(path) -> list[tuple[float, str]]:
    path = Path(path)
    if not path.is_file():
        return []
    root = ET.parse(path).getroot()
    return [(float(ds.get("timestep")), ds.get("file")) for ds in root.iter("DataSet")]


def series(run_dir) -> list[tuple[float, Path]]:
    """(time, VTU path) of every snapshot of a run directory, in time order."""
    run_dir = Path(run_dir)
    return [(t, run_dir / f) for t, f in read_pvd(run_dir / PVD_NAME)]


# ---------------------------------------------------------------- diagnostics
def diagnostics_columns(dim: int) -> list[str]:
    cols = ["time", "step", "dt", "kinetic", "strain", "gravity", "total"]
    cols += [f"momentum_{a}" for a in "xyz"[:dim]]
    if dim > 1:
        cols += [f"angular_momentum_{a}" for a in "xyz"]
    return cols + ["max_speed", "cfl"]


def diagnostics_row(sim) -> dict:
    """One diagnostics row. dt is the step size in force at this time (the CFL rule or the fixed dt), not
    the last step, which is shortened to land on the output time; cfl = dt (wave speed + max speed) / dx."""
    e = sim.energy()
    m = sim.momentum()
    dt = sim.stable_dt()
    vmax = sim.max_speed()
    row = {"time": sim.time, "step": sim.n_steps, "dt": dt, "kinetic": e["kinetic"], "strain": e["strain"],
           "gravity": e["gravity"], "total": e["kinetic"] + e["strain"] + e["gravity"]}
    for a, c in enumerate("xyz"[: sim.dim]):
        row[f"momentum_{c}"] = float(m["linear"][a])
    if sim.dim > 1:
        for a, c in enumerate("xyz"):
            row[f"angular_momentum_{c}"] = float(m["angular"][a])
    row["max_speed"] = vmax
    row["cfl"] = dt * (sim.wave_speed + vmax) / sim.dx
    return row


class Diagnostics:
    """diagnostics.csv, one row per output time; `keep` rows survive when a run resumes."""

    def __init__(self, path, dim: int, keep: int | None = None):
        self.path, self.columns = Path(path), diagnostics_columns(dim)
        rows = []
        if keep and self.path.is_file():
            with open(self.path, newline="") as f:
                rows = list(csv.reader(f))[1: 1 + keep]
        tmp = _atomic(self.path)
        with open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(self.columns)
            w.writerows(rows)
        os.replace(tmp, self.path)

    def append(self, row: dict):
        with open(self.path, "a", newline="") as f:
            csv.writer(f).writerow([repr(float(row[c])) if c != "step" else int(row[c]) for c in self.columns])


def read_diagnostics(path) -> dict[str, np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in (rows[0] if rows else [])}


# ---------------------------------------------------------------- checkpoint and config
def save_checkpoint(path, state: dict, meta: dict | None = None):
    """sim.get_state() plus JSON metadata (output counter, config) in one .npz, replaced atomically."""
    path = Path(path)
    arrays = {k: np.asarray(v) for k, v in state.items()}
    arrays["__meta__"] = np.array(json.dumps(meta or {}))
    tmp = _atomic(path)
    with open(tmp, "wb") as f:
        np.savez(f, **arrays)
    os.replace(tmp, path)


def load_checkpoint(path) -> tuple[dict, dict]:
    """(state for sim.set_state, metadata). A file that is not a complete checkpoint (corrupt, truncated, another
    .npz, pickled objects) is a ConfigError naming it; whether the state fits the scene is set_state's check."""
    from .errors import ConfigError

    try:
        with np.load(path, allow_pickle=False) as z:
            state = {k: z[k] for k in z.files if k != "__meta__"}
            meta = json.loads(str(z["__meta__"])) if "__meta__" in z.files else None
        if not isinstance(meta, dict) or not isinstance(meta.get("config"), dict):
            raise ValueError("no metadata (output counter and config) in it")
        for k in ("time", "dt", "vmax", "half_dt"):
            if k in state:
                state[k] = float(state[k])
        if "n_steps" in state:
            state["n_steps"] = int(state["n_steps"])
    except Exception as e:  # BadZipFile, EOFError, OSError, ValueError, KeyError, JSONDecodeError, ...
        raise ConfigError(f"{path} is not a readable checkpoint ({type(e).__name__}: {str(e)[:200]}); it may be "
                          f"corrupt or truncated: run again without --resume") from None
    return state, meta


def config_dict(cfg) -> dict:
    """The resolved config as plain data, every key included (null where unset, so `validate` shows them and a
    null that turns a default off, e.g. solver.energy_growth_limit, survives); mesh files become absolute paths
    so the copy stays usable."""
    data = cfg.model_dump(mode="json")
    src = getattr(cfg, "_source", None)
    if src:
        base = Path(src).resolve().parent
        for body in data.get("bodies", []):
            shapes = [body.get("shape", {})] + [r.get("shape", {}) for r in body.get("damage_regions", [])]
            for s in shapes:
                if s.get("type") == "mesh" and not Path(s["file"]).is_absolute():
                    s["file"] = str(base / s["file"])
    return data


def write_config(path, cfg):
    path = Path(path)
    tmp = _atomic(path)
    tmp.write_text(yaml.safe_dump(config_dict(cfg), sort_keys=False, default_flow_style=None))
    os.replace(tmp, path)
