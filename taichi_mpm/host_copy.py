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

import math

import numpy as np
import taichi as ti
from taichi.lang.util import to_numpy_type

CHUNK = 1 << 18   # rows per launch: the packed array stays below ~50 MB for any field set


def _element_shape(f) -> tuple:
    """() for a scalar field, (n,) for a vector field, (n, m) for a matrix field."""
    if not isinstance(f, ti.lang.matrix.MatrixField):
        return ()
    return (f.n,) if f.ndim == 1 else (f.n, f.m)


def _layout(fields) -> tuple:
    """Per field (its first column in the packed rows, its element shape); and the row width."""
    out, col = [], 0
    for f in fields:
        shape = _element_shape(f)
        out.append((col, shape))
        col += math.prod(shape)
    return tuple(out), col


@ti.kernel
def _copy(fs: ti.template(), layout: ti.template(), a: ti.types.ndarray(ndim=2), start: ti.i32,
          into_fields: ti.template()):
    """Rows of `a` to particles start.. of the fields (into_fields) or back, entry by entry in row-major order."""
    for r in range(a.shape[0]):
        p = start + r
        for k in ti.static(range(len(fs))):
            c, shape = ti.static(layout[k])
            if ti.static(len(shape) == 0):
                if ti.static(into_fields):
                    fs[k][p] = ti.cast(a[r, c], fs[k].dtype)
                else:
                    a[r, c] = fs[k][p]
            elif ti.static(len(shape) == 1):
                for i in ti.static(range(shape[0])):
                    if ti.static(into_fields):
                        fs[k][p][i] = ti.cast(a[r, c + i], fs[k].dtype)
                    else:
                        a[r, c + i] = fs[k][p][i]
            else:
                for i, j in ti.static(ti.ndrange(*shape)):
                    if ti.static(into_fields):
                        fs[k][p][i, j] = ti.cast(a[r, c + i * shape[1] + j], fs[k].dtype)
                    else:
                        a[r, c + i * shape[1] + j] = fs[k][p][i, j]


def _packed_dtype(fields):
    return np.float64 if any(f.dtype == ti.f64 for f in fields) else np.float32


def upload(pairs: list) -> None:
    """[(field, array)]: array (N, *element shape) into each 1D particle field of N entries, in one kernel."""
    if not pairs:
        return
    fields = tuple(f for f, _ in pairs)
    layout, _ = _layout(fields)
    n, dtype = fields[0].shape[0], _packed_dtype(fields)
    for (f, a), (_, shape) in zip(pairs, layout):
        if f.shape != (n,) or np.shape(a)[:1] != (n,) or math.prod(np.shape(a)[1:]) != math.prod(shape):
            raise ValueError(f"host_copy.upload: array of shape {np.shape(a)} for a field of shape {f.shape}")
    for start in range(0, n, CHUNK):
        stop = min(n, start + CHUNK)
        packed = np.concatenate([np.asarray(a[start:stop], dtype=dtype).reshape(stop - start, -1)
                                 for _, a in pairs], axis=1)
        _copy(fields, layout, packed, start, True)


def download(fields: list) -> list:
    """The arrays of 1D particle fields of N entries, in one kernel: (N,) per scalar field, (N, n) per vector,
    (N, n, m) per matrix, each in the field's numpy dtype."""
    fields = tuple(fields)
    layout, width = _layout(fields)
    n = fields[0].shape[0]
    packed = np.empty((n, width), dtype=_packed_dtype(fields))
    for start in range(0, n, CHUNK):
        _copy(fields, layout, packed[start:start + CHUNK], start, False)   # a block of rows: contiguous
    return [packed[:, c:c + math.prod(shape)].reshape((n, *shape)).astype(to_numpy_type(f.dtype))
            for f, (c, shape) in zip(fields, layout)]
