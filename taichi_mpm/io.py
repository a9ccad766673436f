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

SNAPSHOT = "particles_{:06d}"
PVD_NAME = "particles.pvd"
DIAGNOSTICS_NAME = "diagnostics.csv"
CHECKPOINT_NAME = "checkpoint.npz"
CONFIG_NAME = "config.yaml"

ALWAYS = ("velocity", "stress", "von_mises", "J", "body", "damage")  # written to every VTU ("damage" when present)


# ---------------------------------------------------------------- helpers
def _atomic(path: Path):
    """A temporary sibling of `path`; call os.replace(tmp, path) when it is complete."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp{os.getpid()}")


def _pad3(a: np.ndarray) -> np.ndarray:
    """(N, d) -> (N, 3) with zeros for the missing axes."""
    a = np.asarray(a, dtype=np.float64).reshape(len(a), -1)
    return np.pad(a, ((0, 0), (0, 3 - a.shape[1])))


def _tensor9(a: np.ndarray) -> np.ndarray:
    """(N, d, d) -> (N, 9), the 3x3 tensor padded with zeros, as ParaView expects a tensor."""
    n, d = a.shape[0], a.shape[1]
    out = np.zeros((n, 3, 3))
    out[:, :d, :d] = a
    return out.reshape(n, 9)


def von_mises(stress: np.ndarray) -> np.ndarray:
    """von Mises stress sqrt(3/2 s:s) of the (N, d, d) Cauchy stress, padded to 3x3 with zeros
    (plane stress in 2D, uniaxial stress in 1D: |sigma_xx|)."""
    s = _tensor9(stress).reshape(-1, 3, 3)
    dev = s - np.trace(s, axis1=1, axis2=2)[:, None, None] / 3.0 * np.eye(3)
    return np.sqrt(1.5 * np.einsum("nij,nij->n", dev, dev))


def derived_fields(p: dict, scene=None) -> dict:
    """Add J, von_mises, speed, pressure (and displacement/material/interface when the scene is given)
    to a particles() dict; returns a new dict."""
    out = dict(p)
    d = p["x"].shape[1]
    out["J"] = np.linalg.det(p["F"])
    out["von_mises"] = von_mises(p["stress"])
    out["speed"] = np.linalg.norm(p["v"], axis=1)
    out["pressure"] = -np.trace(p["stress"], axis1=1, axis2=2) / d
    if scene is not None:
        out["displacement"] = p["x"] - scene.x
        out["material"] = np.asarray(scene.material)
        out["interface"] = np.asarray(scene.interface)
        if "damage" not in out and getattr(scene, "damage", None) is not None and np.any(scene.damage):
            out["damage"] = np.asarray(scene.damage, float)
    return out


def point_data(p: dict, fields=()) -> dict:
    """VTU point data from a derived_fields() dict: the ALWAYS set plus `fields` (config output.fields)."""
    names = list(dict.fromkeys(list(ALWAYS) + list(fields)))
    source = {"velocity": "v"}
    out = {}
    for name in names:
        key = source.get(name, name)
        if key not in p:
            continue  # e.g. damage without a crack section, C without APIC
        a = np.asarray(p[key])
        if a.ndim == 3:
            a = _tensor9(a)
        elif a.ndim == 2:
            a = _pad3(a)
        elif np.issubdtype(a.dtype, np.integer):
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
    """Read a snapshot back: x (N, dim) plus the point data, tensors as (N, dim, dim)."""
    import meshio

    m = meshio.read(path)
    if dim is None:
        dim = 3 - int(np.all(m.points[:, 2] == 0)) - int(np.all(m.points[:, 1:] == 0))
    out = {"x": m.points[:, :dim].copy()}
    for name, a in m.point_data.items():
        if a.ndim == 2 and a.shape[1] == 9:
            a = a.reshape(-1, 3, 3)[:, :dim, :dim]
        elif a.ndim == 2 and a.shape[1] == 3:
            a = a[:, :dim]
        out[name] = a
    return out


def write_npz(path, p: dict, fields=()):
    """One particle snapshot as .npz: x, v, F, stress, mass, volume, body and the VTU fields, unpadded."""
    path = Path(path)
    names = ["x", "v", "F", "stress", "mass", "volume", "body"] + [f for f in list(ALWAYS) + list(fields) if f != "velocity"]
    arrays = {n: np.asarray(p[n]) for n in dict.fromkeys(names) if n in p}
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
    """(state for sim.set_state, metadata)."""
    with np.load(path, allow_pickle=False) as z:
        state = {k: z[k] for k in z.files if k != "__meta__"}
        meta = json.loads(str(z["__meta__"])) if "__meta__" in z.files else {}
    for k in ("time", "dt", "vmax"):
        if k in state:
            state[k] = float(state[k])
    if "n_steps" in state:
        state["n_steps"] = int(state["n_steps"])
    return state, meta


def config_dict(cfg) -> dict:
    """The resolved config as plain data; mesh files become absolute paths so the copy stays usable."""
    data = cfg.to_dict()
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
