"""One field declared: its name, element type (a Taichi type, or "real": the scene's precision), element shape and
the feature that requires it; its bytes per element and its allocation. One grid declared: its node fields and
block fields. layout.py and the crack finder's fields declare theirs with them. Physics code only."""
from __future__ import annotations

import math
from dataclasses import dataclass

import taichi as ti

# bytes of one element of each Taichi type a field is declared with; "real" is the precision's float
TYPE_BYTES = {"f64": 8, "f32": 4, "i64": 8, "i32": 4, "u64": 8, "u32": 4, "u8": 1}
_TI_TYPES = {"f64": ti.f64, "f32": ti.f32, "i64": ti.i64, "i32": ti.i32, "u64": ti.u64, "u32": ti.u32, "u8": ti.u8}


@dataclass(frozen=True)
class FieldDecl:
    """One field: its attribute name, element type ("real": the scene's precision), shape of one element (() a
    scalar, (d,) a vector, (d, d) a matrix) and the feature that requires it."""
    name: str
    dtype: str
    shape: tuple = ()
    why: str = "always"

    def nbytes(self, precision: str) -> int:
        """Bytes of one element (one particle's, one node's)."""
        return math.prod(self.shape) * TYPE_BYTES[precision if self.dtype == "real" else self.dtype]

    def allocate(self, n):
        """The Taichi field of this element over index space `n` (an int, a shape, or None to place it later)."""
        dtype = float if self.dtype == "real" else _TI_TYPES[self.dtype]
        if not self.shape:
            return ti.field(dtype, n)
        if len(self.shape) == 1:
            return ti.Vector.field(self.shape[0], dtype, n)
        return ti.Matrix.field(*self.shape, dtype, n)


def scalar_decl(entry) -> FieldDecl:
    """A grid scalar's declaration: its entry is its name (a field of the scene's precision) or a FieldDecl (its own
    type)."""
    return FieldDecl(entry, "real") if isinstance(entry, str) else entry


def allocate(decls, n: int) -> dict:
    """name -> field of n elements, in declaration order."""
    return {f.name: f.allocate(n) for f in decls}


def nbytes(decls, precision: str) -> int:
    return sum(f.nbytes(precision) for f in decls)


@dataclass(frozen=True)
class GridDecl:
    """One grid (grid.Grid): its node fields besides the mass `m` (dim-vectors interleaved with it, dim-vectors
    and scalars in arrays of their own), its node extent (`nodes`: the velocity grid's; `linear`: the cell
    corners), whether it is sparse whatever domain.sparse says, and the i32 fields of each leaf block. A scalar is
    its name (of the scene's precision) or a FieldDecl of its own type."""
    name: str
    vectors: tuple = ()
    apart: tuple = ()
    scalars: tuple = ()
    extent: str = "nodes"
    always_sparse: bool = False
    block_ints: int = 0

    def node_bytes(self, dim: int, precision: str) -> int:
        size = TYPE_BYTES[precision]
        scalars = sum(scalar_decl(s).nbytes(precision) for s in self.scalars)
        return size * (1 + dim * (len(self.vectors) + len(self.apart))) + scalars
