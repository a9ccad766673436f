"""Sums over particles in f64 without contended atomic adds.

Every thread adding into the same few f64 slots serialises on their cache line: the energy pass of 65 536
particles took 8 ms on two threads where the loop alone takes 0.3 ms (docs/performance.md, "Against the
reference kernel").
Two remedies, one per use:

- `Slots`: a few accumulators that hot kernels add into (external work, dissipation). Each is a 0-D field, which
  Taichi reduces in thread-local registers and adds once per thread (its thread-local pass applies to 0-D fields
  only).
- `ChunkSums`: diagnostics over all particles (energies, momenta, per-body moments). The particles are split into
  contiguous chunks; one thread sums a chunk in order into its own row, the host adds the rows. No atomics, any
  number of slots (a body index picks them at run time), and the same bits for any thread count (the chunks
  depend on the particle count only).

Physics code only: no CLI, rendering or file I/O here.
"""

import math

import numpy as np
import taichi as ti

MAX_ROW_VALUES = 1 << 21   # chunks x slots stays below 16 MB (scenes with thousands of bodies get fewer chunks)
CPU_TASK = 512             # Taichi's CPU range-for runs as tasks of min(1024, max(512, n / (32 threads))) iterations
CPU_CHUNKS = 4 * CPU_TASK  # chunk rows on a CPU: tasks for up to 4 threads, whatever the pool (same sums)
GPU_CHUNKS = 1 << 16


def cpu_threads() -> int:
    """Threads of Taichi's CPU pool (after ti.init); 0 on a GPU."""
    cfg = ti.lang.impl.current_cfg()
    return cfg.cpu_max_num_threads if cfg.arch in (ti.x64, ti.arm64) else 0


class Slots:
    """n f64 accumulators as 0-D fields: in a kernel `slots[k][None] += value` (k a Python int). The host reads and
    sets them all through one kernel each way (compiled at first use; each field's own accessor would compile one
    kernel per field)."""

    def __init__(self, n: int):
        self.fields = [ti.field(ti.f64, ()) for _ in range(n)]
        self._kernels = None

    def __getitem__(self, k: int):
        return self.fields[k]

    @property
    def shape(self):
        return (len(self.fields),)

    def _copy(self):
        if self._kernels is None:
            fields = self.fields

            @ti.kernel
            def read(out: ti.types.ndarray()):
                for k in ti.static(range(len(fields))):
                    out[k] = fields[k][None]

            @ti.kernel
            def write(values: ti.types.ndarray()):
                for k in ti.static(range(len(fields))):
                    fields[k][None] = values[k]

            self._kernels = read, write
        return self._kernels

    def to_numpy(self) -> np.ndarray:
        out = np.zeros(len(self.fields), dtype=np.float64)
        self._copy()[0](out)
        return out

    def from_numpy(self, values):
        self._copy()[1](np.ascontiguousarray(values, dtype=np.float64).reshape(len(self.fields)))


class ChunkSums:
    """Sums of per-particle values over `n` particles into `shape` f64 slots, chunk by chunk. In a kernel:

        for c in range(sums.chunks):              # parallel over chunks
            sums.clear(c)
            for p in range(sums.begin(c), sums.end(c)):   # in order within a chunk
                sums.add(c, slot, value)          # slot: a flat index (int, may be computed at run time)

    and `total()` on the host: the slots, shape `shape`."""

    def __init__(self, n: int, shape):
        self.shape = tuple(shape) if isinstance(shape, (tuple, list)) else (int(shape),)
        self.slots = math.prod(self.shape)
        self.chunks = max(1, min(CPU_CHUNKS if cpu_threads() else GPU_CHUNKS, n, MAX_ROW_VALUES // self.slots))
        self.size = -(-max(n, 1) // self.chunks)   # particles per chunk
        self.part = ti.field(ti.f64, (self.chunks, self.slots))
        part, size, slots = self.part, self.size, self.slots

        @ti.func
        def begin(c):
            return c * size

        @ti.func
        def end(c):
            return ti.min(n, (c + 1) * size)

        @ti.func
        def clear(c):
            for k in range(slots):
                part[c, k] = 0.0

        @ti.func
        def add(c, k, value):
            part[c, k] = part[c, k] + ti.cast(value, ti.f64)   # the chunk's own row: a plain add, no atomic

        chunks, serial = self.chunks, cpu_threads() > 0

        @ti.func
        def copy_rows(out: ti.template()):
            """The chunks' rows into `out` (a (chunks, slots) f64 ndarray), at the end of the kernel that summed
            them: no launch of its own (`to_numpy` is one, ~0.15 ms on 2 cores). A CPU copies on the calling
            thread (a parallel task would wake the pool), a GPU in parallel."""
            if ti.static(serial):
                ti.loop_config(serialize=True)
                for c in range(chunks):
                    for k in range(slots):
                        out[c, k] = part[c, k]
            else:
                for c, k in ti.ndrange(chunks, slots):
                    out[c, k] = part[c, k]

        self.begin, self.end, self.clear, self.add, self.copy_rows = begin, end, clear, add, copy_rows

    def rows(self) -> np.ndarray:
        """A host array for copy_rows."""
        return np.zeros((self.chunks, self.slots), dtype=np.float64)

    def total_of(self, rows: np.ndarray) -> np.ndarray:
        """The slots summed over the chunks' rows (in chunk order: the same bits for any thread count)."""
        return rows.sum(axis=0).reshape(self.shape)

    def total(self) -> np.ndarray:
        """The slots summed over chunks (in chunk order: the same bits for any thread count)."""
        return self.total_of(self.part.to_numpy())
