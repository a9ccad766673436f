"""Files a run writes: particle snapshots (VTU via meshio, or NPZ), the ParaView series file (PVD),
diagnostics.csv, checkpoint.npz and the resolved config.yaml.

Reads solver state only through the public Simulation API (particles(), energy(), momentum(),
max_speed(), cfl_number(), get_state()). Every file is written to a temporary name first and then
renamed, so a run stopped at any moment leaves complete files behind.

The file-system helpers below are the only way the run folder is written or cleaned (runner, probes, plots,
render): `atomic_write` / `atomic_path` (a temporary created exclusively, never through a link, then renamed over
the real name, which replaces a link there instead of following it), `ensure_folder` (a real folder, never a link
or a file), `remove_file` (unlinks a name, never what a link points to), `files_in` (a real folder's entries) and
`refuse_links` (a run folder with a symbolic link or a special file at a name the run uses is refused before
anything is written). Every operating-system failure of a write is a `FileError` naming the file and the cause
(disk full, file-size limit, permission, something in the way): the CLI's exit code 4.
"""
from __future__ import annotations

import contextlib
import csv
import errno
import fnmatch
import json
import os
import stat
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import yaml

from .. import fields as registry

SNAPSHOT = "particles_{:06d}"
PVD_NAME = "particles.pvd"
DOMAINS_PVD = "domains.pvd"          # cpdi2: the particle domains' series (one *_domains.vtu per snapshot)
DIAGNOSTICS_NAME = "diagnostics.csv"
CHECKPOINT_NAME = "checkpoint.npz"
CONFIG_NAME = "config.yaml"

ALWAYS = registry.ALWAYS  # written to every VTU ("damage" when present)
von_mises = registry.von_mises


# ---------------------------------------------------------------- the file system
class FileError(OSError):
    """A file or folder that cannot be read or written: an operating-system error (disk full, file-size limit,
    permission) or something in the way (a symbolic link or a special file in a run folder, a file where a folder
    goes). The message names the path and the cause; the CLI prints it on one line and exits 4."""

    def __init__(self, message: str, path=None, cause: int | None = None):
        super().__init__(message)
        self.message, self.filename, self.cause = message, None if path is None else str(path), cause

    def __str__(self):
        return self.message


def describe(e: OSError, verb: str = "write", path=None) -> str:
    """One line for an OSError: 'cannot write PATH: No space left on device'."""
    if isinstance(e, FileError):
        return e.message
    where = path if path is not None else (e.filename if e.filename is not None else None)
    why = e.strerror or str(e) or type(e).__name__
    if e.errno == errno.EFBIG:
        why += " (the file-size limit, ulimit -f)"
    return f"cannot {verb} {where}: {why}" if where is not None else f"cannot {verb}: {why}"


def as_file_error(e: OSError, verb: str = "write", path=None) -> FileError:
    return e if isinstance(e, FileError) else FileError(describe(e, verb, path), path or e.filename, e.errno)


_TMP = "{name}.tmp{pid}"   # ".NAME.tmpPID[.SUFFIX]": the only names the run folder's clean-up removes


def temporary_name(path: Path, suffix: str = "") -> Path:
    """The temporary sibling of `path` that this process writes before renaming it over `path`."""
    path = Path(path)
    return path.with_name("." + _TMP.format(name=path.name, pid=os.getpid()) + suffix)


def _link_target(path: Path) -> str:
    try:
        return os.readlink(path)
    except OSError:
        return "?"


def _check_folders(path: Path, root) -> None:
    """Every folder between `root` (a run folder, which may itself be or lie under a link the user made) and
    `path` must be a real folder: a link there would take the write outside the run folder."""
    if root is None:
        return
    root, parent = Path(root), Path(path).parent
    try:
        rel = parent.relative_to(root)
    except ValueError:
        return
    cur = root
    for part in rel.parts:
        cur = cur / part
        if os.path.islink(cur):
            raise FileError(f"{cur} is a symbolic link (to {_link_target(cur)}): nothing is written or deleted "
                            f"through links in a run folder; remove the link", cur)


def _create_exclusive(tmp: Path) -> int:
    """A new file at `tmp`, never through a link (O_EXCL | O_NOFOLLOW); a leftover of that name (a dead process
    with this pid, or a planted link) is removed first: unlink removes a link, not what it points to."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        return os.open(tmp, flags, 0o644)
    except FileExistsError:
        os.unlink(tmp)
        return os.open(tmp, flags, 0o644)


@contextlib.contextmanager
def atomic_path(path, suffix: str = "", root=None, verb: str = "write"):
    """A fresh temporary path beside `path` for a writer that opens files by name (meshio, imageio, matplotlib);
    on success it is renamed over `path` (a link at `path` is replaced, not followed); on failure it is removed and
    `path` keeps its old content. An OSError becomes a FileError naming `path`."""
    path = Path(path)
    tmp = temporary_name(path, suffix)
    try:
        _check_folders(path, root)
        os.close(_create_exclusive(tmp))
        yield tmp
        if os.path.islink(tmp) or not os.path.isfile(tmp):  # replaced behind our back
            raise FileError(f"cannot write {path}: its temporary file {tmp} was replaced while it was written", path)
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(OSError):
            if os.path.lexists(tmp) and not os.path.isdir(tmp):
                os.unlink(tmp)
        if isinstance(e, OSError):
            raise as_file_error(e, verb, path) from None
        raise


@contextlib.contextmanager
def atomic_write(path, mode: str = "wb", root=None, fsync: bool = False, newline=None, keep_open: bool = False):
    """An open file at a fresh temporary name beside `path` (created exclusively, never through a link); when the
    block ends it is flushed (and fsync'ed with `fsync`) and renamed over `path`. With keep_open the file stays open
    for appending after the rename (the caller closes it). OSError -> FileError naming `path`; `path` then keeps
    its old content and the temporary is removed."""
    path = Path(path)
    tmp = temporary_name(path)
    f = None
    try:
        _check_folders(path, root)
        fd = _create_exclusive(tmp)
        f = os.fdopen(fd, mode, newline=newline) if "b" not in mode else os.fdopen(fd, mode)
        yield f
        f.flush()
        if fsync:
            os.fsync(f.fileno())
        os.replace(tmp, path)
        if not keep_open:
            f.close()
    except BaseException as e:
        if f is not None:
            with contextlib.suppress(OSError):
                f.close()
        with contextlib.suppress(OSError):
            if os.path.lexists(tmp) and not os.path.isdir(tmp):
                os.unlink(tmp)
        if isinstance(e, OSError):
            raise as_file_error(e, "write", path) from None
        raise


def open_append(path):
    """`path` opened for appending, never through a link (O_NOFOLLOW)."""
    flags = os.O_WRONLY | os.O_APPEND | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        return os.fdopen(os.open(path, flags), "a", newline="")
    except OSError as e:
        if os.path.islink(path):
            raise FileError(f"{path} is a symbolic link (to {_link_target(Path(path))}): nothing is written "
                            f"through links in a run folder; remove the link", path) from None
        raise as_file_error(e, "write", path) from None


def read_regular(path, newline: str | None = "") -> str:
    """The text of a regular file, never read through a link or from a FIFO (which would block)."""
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError as e:
        if os.path.islink(path):
            raise FileError(f"{path} is a symbolic link (to {_link_target(Path(path))}): nothing is read "
                            f"through links in a run folder; remove the link", path) from None
        raise as_file_error(e, "read", path) from None
    with os.fdopen(fd, "r", newline=newline, errors="replace") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise FileError(f"cannot read {path}: not a regular file", path)
        try:
            return f.read()
        except OSError as e:
            raise as_file_error(e, "read", path) from None


def ensure_folder(path, root=None, parents: bool = False) -> Path:
    """`path` as a real folder (created when missing, with its parents if `parents`): a link or a file in its
    place is a FileError."""
    path = Path(path)
    _check_folders(path, root)
    if os.path.islink(path):
        raise FileError(f"{path} is a symbolic link (to {_link_target(path)}): nothing is written or deleted "
                        f"through links in a run folder; remove the link", path)
    if os.path.lexists(path) and not path.is_dir():
        raise FileError(f"{path} is a file, not a folder: remove or rename it (the outputs go into a folder of "
                        f"that name)", path)
    try:
        path.mkdir(exist_ok=True, parents=parents)
    except FileExistsError:  # a file in place of one of the parents
        raise FileError(f"cannot create the folder {path}: a file is in the way", path) from None
    except OSError as e:
        raise as_file_error(e, "create the folder", path) from None
    return path


def files_in(folder, pattern: str = "*", root=None) -> list[Path]:
    """Entries of a real folder whose names match `pattern`, in name order (none when the folder is missing);
    a link in the folder's place is a FileError (its entries are somebody else's)."""
    folder = Path(folder)
    _check_folders(folder / "x", root)
    if os.path.islink(folder):
        raise FileError(f"{folder} is a symbolic link (to {_link_target(folder)}): nothing is written or deleted "
                        f"through links in a run folder; remove the link", folder)
    if not folder.is_dir():
        return []
    with os.scandir(folder) as it:
        return sorted(Path(e.path) for e in it if fnmatch.fnmatchcase(e.name, pattern))


def remove_file(path, root=None) -> None:
    """Remove a file of the run folder: a link is removed itself, never what it points to; a folder is left."""
    path = Path(path)
    _check_folders(path, root)
    try:
        if os.path.isdir(path) and not os.path.islink(path):
            return
        os.unlink(path)
    except FileNotFoundError:
        pass
    except OSError as e:
        raise as_file_error(e, "remove", path) from None


# names a run, `plot` and `render` write, read or remove at the top of a run folder, and the folders whose every
# entry is theirs
RUN_NAMES = ("run.lock", "config.yaml", "checkpoint.npz", "particles.pvd", "diagnostics.csv", "particles_*.vtu",
             "particles_*.npz", "movie.*", ".*.tmp*")
RUN_FOLDERS = ("probes", "frames", "plots")


def unsafe_entries(run_dir) -> list[tuple[Path, str]]:
    """(path, what) for each symbolic link or special file (FIFO, socket, device) at a name of RUN_NAMES, at one of
    RUN_FOLDERS or inside one of them."""
    run_dir = Path(run_dir)
    found = []

    def look(entry, path):
        if entry.is_symlink():
            found.append((path, f"a symbolic link (to {_link_target(path)})"))
            return False
        mode = entry.stat(follow_symlinks=False).st_mode
        if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
            found.append((path, "not a regular file"))
            return False
        return True

    if not run_dir.is_dir():
        return found
    with os.scandir(run_dir) as it:
        top = sorted(it, key=lambda e: e.name)
    for e in top:
        path = run_dir / e.name
        if e.name in RUN_FOLDERS:
            if look(e, path) and e.is_dir(follow_symlinks=False):
                with os.scandir(path) as inner:
                    for i in sorted(inner, key=lambda x: x.name):
                        look(i, path / i.name)
        elif any(fnmatch.fnmatchcase(e.name, p) for p in RUN_NAMES):
            look(e, path)
    return found


def refuse_links(run_dir) -> None:
    """FileError when the run folder holds a link or a special file where a run writes, reads or deletes: nothing
    is written, read or deleted through one (it could point outside the run folder)."""
    bad = unsafe_entries(run_dir)
    if bad:
        path, what = bad[0]
        more = f" (and {len(bad) - 1} more such entr{'y' if len(bad) == 2 else 'ies'})" if len(bad) > 1 else ""
        raise FileError(f"{path} is {what}{more}: taichi-mpm writes, reads and deletes only regular files and "
                        f"folders in a run folder, never through links; remove it", path)



def _pad3(a: np.ndarray, dtype=np.float64) -> np.ndarray:
    """(N, d) -> (N, 3) with zeros for the missing axes."""
    a = np.asarray(a, dtype=dtype).reshape(len(a), -1)
    return np.pad(a, ((0, 0), (0, 3 - a.shape[1])))


def derived_fields(p: dict, scene=None) -> dict:
    """A particles() dict with the output fields computed once (registry.REGISTRY: J, von_mises, speed, pressure,
    ... and, when the scene is given, displacement, material and interface); returns a new dict."""
    out = registry.with_scene(p, scene) if scene is not None else dict(p)
    for name in registry.REGISTRY:
        if name not in out and registry.available(out, name) and registry.REGISTRY[name].kind in ("scalar", "label"):
            out[name] = registry.values(out, name)
    return out


def snapshot_fields(fields=(), only: bool = False) -> list[str]:
    """The fields a VTU snapshot holds (config output.fields and output.only_fields): the ALWAYS set plus
    `fields`, or with `only` exactly `fields`."""
    return list(dict.fromkeys(list(fields) if only else list(ALWAYS) + list(fields)))


def point_data(p: dict, fields=(), dtype=np.float64, only: bool = False) -> dict:
    """VTU point data of a particle dict: the ALWAYS set plus `fields` (config output.fields; with `only`, just
    `fields`), each as the registry computes it; vectors padded to 3 components, tensors written as full 3x3
    (9 components); floating values as `dtype` (float32 in an f32 run: the state's own precision)."""
    out = {}
    for name in snapshot_fields(fields, only):
        if not registry.available(p, name):
            continue  # e.g. damage without a crack section, C without APIC
        kind = registry.REGISTRY[name].kind
        a = np.asarray(registry.values(p, name))
        if kind == "tensor":
            a = a.reshape(len(a), 9).astype(dtype)
        elif kind == "vector":
            a = _pad3(a, dtype)
        elif kind == "label" or np.issubdtype(a.dtype, np.integer):
            a = a.astype(np.int32)
        else:
            a = a.astype(dtype)
        out[name] = a
    return out


# ---------------------------------------------------------------- snapshots
_VTK_TYPES = {np.dtype(np.float32): "Float32", np.dtype(np.float64): "Float64", np.dtype(np.int32): "Int32",
              np.dtype(np.int64): "Int64", np.dtype(np.uint8): "UInt8"}
_BLOCK = 1 << 15   # uncompressed bytes per zlib block (what VTK and meshio use)


def _compressed(a: np.ndarray, level: int) -> bytes:
    """One array in VTK's zlib block layout: UInt32 header (blocks, block size, last block size, compressed
    sizes), then the blocks."""
    import zlib

    raw = np.ascontiguousarray(a).tobytes()
    blocks = [zlib.compress(raw[i:i + _BLOCK], level) for i in range(0, len(raw), _BLOCK)] or [zlib.compress(b"")]
    last = len(raw) - (len(blocks) - 1) * _BLOCK if raw else 0
    header = np.array([len(blocks), _BLOCK, last] + [len(b) for b in blocks], dtype="<u4")
    return header.tobytes() + b"".join(blocks)


def vtu_bytes(points: np.ndarray, point_data: dict, level: int = 1) -> bytes:
    """A VTU file (UnstructuredGrid of vertex cells) with raw appended, zlib-compressed arrays: what ParaView and
    meshio read, without base64 (a third smaller) and written in one pass. Level 1: on float data the higher
    levels gain almost nothing at several times the time."""
    n = len(points)
    arrays = [("Points", None, points)]
    arrays += [(name, "P", a) for name, a in point_data.items()]
    cells = [("connectivity", "C", np.arange(n, dtype=np.int32)), ("offsets", "C", np.arange(1, n + 1, dtype=np.int32)),
             ("types", "C", np.ones(n, dtype=np.uint8))]   # VTK_VERTEX = 1
    blobs, offset, tags = [], 0, {"Points": [], "P": [], "C": []}
    for name, where, a in arrays + cells:
        a = np.asarray(a)
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        comps = a.shape[1] if a.ndim == 2 else 1
        blob = _compressed(a, level)
        tag = (f'<DataArray type="{_VTK_TYPES[a.dtype.newbyteorder("=")]}" Name="{name}"'
               + (f' NumberOfComponents="{comps}"' if a.ndim == 2 else "") + f' format="appended" offset="{offset}"/>')
        tags[where or "Points"].append(tag)
        blobs.append(blob)
        offset += len(blob)
    head = ('<?xml version="1.0"?>\n'
            '<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian" header_type="UInt32" '
            'compressor="vtkZLibDataCompressor">\n<UnstructuredGrid>\n'
            f'<Piece NumberOfPoints="{n}" NumberOfCells="{n}">\n'
            '<Points>\n' + "\n".join(tags["Points"]) + '\n</Points>\n'
            '<Cells>\n' + "\n".join(tags["C"]) + '\n</Cells>\n'
            '<PointData>\n' + "\n".join(tags["P"]) + '\n</PointData>\n'
            '</Piece>\n</UnstructuredGrid>\n<AppendedData encoding="raw">\n_')
    return head.encode() + b"".join(blobs) + b"\n</AppendedData>\n</VTKFile>\n"


def write_vtu(path, p: dict, fields=(), dtype=np.float64, only: bool = False):
    """One particle snapshot as a VTU of vertex cells (points padded to 3D), floating values as `dtype`."""
    with atomic_write(Path(path)) as f:
        f.write(vtu_bytes(_pad3(p["x"], dtype), point_data(p, fields, dtype, only)))


# VTK's corner order of a line, quad and hexahedron, from the bit order of bases.corners.corner_signs
_DOMAIN_CELLS = {1: ("line", [0, 1]), 2: ("quad", [0, 1, 3, 2]), 3: ("hexahedron", [0, 1, 3, 2, 4, 5, 7, 6])}


def domains_name(snapshot: str) -> str:
    """The domains file of a snapshot's VTU: particles_000012.vtu -> particles_000012_domains.vtu."""
    return snapshot[:-len(".vtu")] + "_domains.vtu"


def write_domains_vtu(path, p: dict, fields=(), dtype=np.float64, only: bool = False):
    """cpdi2: each particle's domain as one cell (line, quad or hexahedron of its corners, p["domain_corners"]),
    with the snapshot's fields as cell data, so that ParaView shows the domains as they deform."""
    import meshio

    corners = np.asarray(p["domain_corners"])
    n, nc, dim = corners.shape
    kind, order = _DOMAIN_CELLS[dim]
    points = _pad3(corners.reshape(n * nc, dim), dtype)
    cells = (np.arange(n * nc, dtype=np.int64).reshape(n, nc))[:, order]
    data = {k: [v] for k, v in point_data(p, fields, dtype, only).items()}
    with atomic_path(Path(path), ".vtu") as tmp:
        meshio.write(tmp, meshio.Mesh(points, [(kind, cells)], cell_data=data), file_format="vtu",
                     compression="zlib")


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
    with atomic_write(path) as f:
        np.savez(f, **arrays)


# ---------------------------------------------------------------- PVD series
def write_pvd(path, entries):
    """ParaView collection file: entries are (time, file name relative to the PVD)."""
    path = Path(path)
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    coll = ET.SubElement(root, "Collection")
    for time, name in entries:
        ET.SubElement(coll, "DataSet", timestep=repr(float(time)), group="", part="0", file=str(name))
    ET.indent(root)
    with atomic_write(path) as f:
        ET.ElementTree(root).write(f, encoding="utf-8", xml_declaration=True)


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
        if keep and os.path.lexists(self.path):
            rows = list(csv.reader(read_regular(self.path).splitlines()))[1: 1 + keep]
        with atomic_write(self.path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(self.columns)
            w.writerows(rows)

    def append(self, row: dict):
        line = [repr(float(row[c])) if c != "step" else int(row[c]) for c in self.columns]
        with open_append(self.path) as f:
            try:
                csv.writer(f).writerow(line)
                f.flush()
            except OSError as e:
                raise as_file_error(e, "write", self.path) from None


def read_csv_columns(path, required=(), what: str = "CSV file") -> dict[str, np.ndarray]:
    """A CSV of numbers with one header line as {column: values}. An empty file, a missing header or required
    column, a row of the wrong length or a value that is not a number is a ValueError naming the file, the row
    (line number) and the column; an unreadable file is a FileError. Empty trailing lines are ignored."""
    text = read_regular(path)
    try:
        rows = list(csv.reader(text.splitlines()))
    except csv.Error as e:  # a NUL byte, ...: not a CSV file
        raise ValueError(f"{path} is not a {what} ({e})") from None
    while rows and not rows[-1]:
        rows.pop()
    if not rows or not any(h.strip() for h in rows[0]):
        raise ValueError(f"{path} is empty: no header line (a {what} starts with its column names)")
    header = rows[0]
    missing = [c for c in required if c not in header]
    if missing:
        raise ValueError(f"{path} is not a {what}: its header has no column {missing[0]!r} "
                         f"(it has: {', '.join(header[:8])}{', ...' if len(header) > 8 else ''})")
    if len(set(header)) != len(header):
        raise ValueError(f"{path}: the header names a column twice")
    out = {h: np.empty(len(rows) - 1) for h in header}
    for i, r in enumerate(rows[1:]):
        line = i + 2
        if len(r) != len(header):
            raise ValueError(f"{path}, line {line}: {len(r)} values, the header has {len(header)} columns (a "
                             f"truncated or edited file)")
        for h, v in zip(header, r):
            try:
                out[h][i] = float(v)
            except ValueError:
                raise ValueError(f"{path}, line {line}, column {h!r}: {v[:40]!r} is not a number") from None
    return out


def read_diagnostics(path) -> dict[str, np.ndarray]:
    """diagnostics.csv as {column: values}; a malformed file is a ValueError naming the file and the line."""
    return read_csv_columns(path, required=("time",), what="diagnostics file")


# ---------------------------------------------------------------- checkpoint and config
def save_checkpoint(path, state: dict, meta: dict | None = None):
    """sim.get_state() plus JSON metadata (output counter, config) in one .npz, replaced atomically."""
    path = Path(path)
    arrays = {k: np.asarray(v) for k, v in state.items()}
    arrays["__meta__"] = np.array(json.dumps(meta or {}))
    with atomic_write(path, fsync=True) as f:   # the state a --resume needs: on disk before it replaces the last
        np.savez(f, **arrays)


def load_checkpoint(path) -> tuple[dict, dict]:
    """(state for sim.set_state, metadata). A file that is not a complete checkpoint (corrupt, truncated, another
    .npz, pickled objects) is a ConfigError naming it; whether the state fits the scene is set_state's check."""
    from ..errors import ConfigError

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


def config_text(cfg) -> str:
    """What write_config writes."""
    return yaml.safe_dump(config_dict(cfg), sort_keys=False, default_flow_style=None)


def write_config(path, cfg):
    text = config_text(cfg)
    with atomic_write(path, "w") as f:
        f.write(text)
