"""Several particle fields to and from numpy in one kernel each way.

Taichi's `field.from_numpy` / `to_numpy` compile one kernel per field (a template instance each). With an empty
kernel cache every instance costs a compile of ~50-70 ms, most of it the fixed cost of a kernel, and a scene
uploads five fields when it starts and reads four at each `particles()`: ~0.5 s of every new scene's first
second. Here the fields of one call share one kernel, which copies rows of one packed array (in chunks, so the
copy needs little memory beside the fields). The packed array is f64 when a field is, else f32 (a backend
without f64 still works); integer fields must hold values below 2^24 then (material and body indices). Each
entry is cast to the field's type as `from_numpy` casts it, and read back as `to_numpy` returns it.

Physics code only: no CLI, rendering or file I/O here.
"""

import numpy as np
import taichi as ti
from taichi.lang.util import to_numpy_type

CHUNK = 1 << 18   # rows per launch: the packed array stays below ~50 MB for any field set


def _layout(fields) -> tuple:
    """Per field (first column, rows, columns): rows = columns = 0 for a scalar field, columns = 0 for a vector."""
    out, col = [], 0
    for f in fields:
        if isinstance(f, ti.lang.matrix.MatrixField):
            n, m = (f.n, 0) if f.ndim == 1 else (f.n, f.m)
            out.append((col, n, m))
            col += n * max(m, 1)
        else:
            out.append((col, 0, 0))
            col += 1
    return tuple(out)


def _width(layout) -> int:
    col, n, m = layout[-1]
    return col + (n * max(m, 1) if n else 1)


def _shape(layout_entry) -> tuple:
    _, n, m = layout_entry
    return () if n == 0 else (n,) if m == 0 else (n, m)


@ti.kernel
def _unpack(fs: ti.template(), layout: ti.template(), a: ti.types.ndarray(ndim=2), start: ti.i32):
    for r in range(a.shape[0]):
        p = start + r
        for k in ti.static(range(len(fs))):
            c, n, m = ti.static(layout[k])
            if ti.static(n == 0):
                fs[k][p] = ti.cast(a[r, c], fs[k].dtype)
            elif ti.static(m == 0):
                for i in ti.static(range(n)):
                    fs[k][p][i] = ti.cast(a[r, c + i], fs[k].dtype)
            else:
                for i, j in ti.static(ti.ndrange(n, m)):
                    fs[k][p][i, j] = ti.cast(a[r, c + i * m + j], fs[k].dtype)


@ti.kernel
def _pack(fs: ti.template(), layout: ti.template(), a: ti.types.ndarray(ndim=2), start: ti.i32):
    for r in range(a.shape[0]):
        p = start + r
        for k in ti.static(range(len(fs))):
            c, n, m = ti.static(layout[k])
            if ti.static(n == 0):
                a[r, c] = fs[k][p]
            elif ti.static(m == 0):
                for i in ti.static(range(n)):
                    a[r, c + i] = fs[k][p][i]
            else:
                for i, j in ti.static(ti.ndrange(n, m)):
                    a[r, c + i * m + j] = fs[k][p][i, j]


def _packed_dtype(fields):
    return np.float64 if any(f.dtype == ti.f64 for f in fields) else np.float32


def upload(pairs: list) -> None:
    """[(field, array)]: array (N, *element shape) into each 1D particle field of N entries, in one kernel."""
    if not pairs:
        return
    fields = tuple(f for f, _ in pairs)
    layout = _layout(fields)
    n, dtype = fields[0].shape[0], _packed_dtype(fields)
    for f, a in pairs:
        if f.shape != (n,) or np.shape(a)[:1] != (n,) or int(np.prod(np.shape(a)[1:])) != _count(f):
            raise ValueError(f"host_copy.upload: array of shape {np.shape(a)} for a field of shape {f.shape}")
    for start in range(0, n, CHUNK):
        stop = min(n, start + CHUNK)
        packed = np.concatenate([np.asarray(a[start:stop], dtype=dtype).reshape(stop - start, -1)
                                 for _, a in pairs], axis=1)
        _unpack(fields, layout, np.ascontiguousarray(packed), start)


def download(fields: list) -> list:
    """The arrays of 1D particle fields of N entries, in one kernel: (N,) per scalar field, (N, n) per vector,
    (N, n, m) per matrix, each in the field's numpy dtype."""
    fields = tuple(fields)
    layout = _layout(fields)
    n = fields[0].shape[0]
    packed = np.empty((n, _width(layout)), dtype=_packed_dtype(fields))
    for start in range(0, n, CHUNK):
        stop = min(n, start + CHUNK)
        chunk = np.empty((stop - start, packed.shape[1]), dtype=packed.dtype)
        _pack(fields, layout, chunk, start)
        packed[start:stop] = chunk
    out = []
    for f, entry in zip(fields, layout):
        c, shape = entry[0], _shape(entry)
        size = int(np.prod(shape)) if shape else 1
        out.append(packed[:, c:c + size].reshape((n, *shape)).astype(to_numpy_type(f.dtype)))
    return out


def _count(f) -> int:
    return int(np.prod(_shape(_layout((f,))[0]))) if isinstance(f, ti.lang.matrix.MatrixField) else 1
