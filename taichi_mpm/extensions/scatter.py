"""P2G without atomic adds on CPUs: particles binned by grid block every step, blocks scattered in 2^d colours.

A CPU adds a float to memory atomically by a compare-and-swap loop: 3D quadratic P2G's 108 atomic adds per particle
took 44 ms for 65 536 particles on one thread, the same adds as plain stores 10.8 ms (docs/performance.md).

Each step `bin()` puts every particle in the grid leaf block (B nodes per axis) that holds its stencil's first node;
its stencil then covers that block and the next S - 1 nodes along each axis. Blocks whose coordinates have the same
parities (one of 2^d colours) are at least two blocks apart along some axis, so while S <= B + 1 the stencils of
their particles share no node. P2G then runs one colour after another; within a colour one thread takes a whole
block, in particle order, and adds to the nodes with plain loads and stores (`add`). Only stencils of bounded width
qualify (tensor products, and ck's two staggered cells, which lie in a window of 4 storage nodes per axis): a CPDI
domain or a mapped grid's stencil can reach any node, and a GPU's atomics are fast.

The order within a block is the particles' solver order (a counting sort, then an insertion sort of each block's
short run), so every node sums its contributions in the same order for any thread count.

Physics code only: no CLI, rendering or file I/O here.
"""

import math

import taichi as ti

from ..bases import registry as bases
from .. import layout
from ..grid import LEAF, Grid
from ..sums import CPU_TASK, cpu_threads


# Below these particle counts `solver.scatter: auto` adds atomically: binning every step and 2^d colour passes of few
# blocks each cost more than the atomic adds they save. Measured crossovers (benchmarks/scatter_crossover.py, 2 cores,
# medians of 3, docs/performance.md "Coloured or atomic"): 2D ~2 300 particles, 3D ~440, 1D none (within noise).
# Deterministic runs keep the colours at any size: their sums need one order.
ATOMIC_BELOW = {1: 0, 2: 2300, 3: 440}


def applies(gpu: bool, stencil_kind: str, width: int, dim: int, setting: str, particles: int,
            deterministic: bool = False) -> bool:
    """Whether P2G scatters by colours: `solver.scatter` auto (CPU, bounded tensor stencil, at least
    ATOMIC_BELOW[dim] particles or a deterministic run), coloured or atomic."""
    bounded = stencil_kind in bases.BOUNDED_KINDS and width <= LEAF[dim] + 1
    if setting == "atomic":
        return False
    if setting == "coloured":
        return bounded  # (config.py refuses coloured where the stencil is unbounded)
    return bounded and not gpu and (deterministic or particles >= ATOMIC_BELOW[dim])


def coloured(cfg, gpu: bool, particles: int) -> bool:
    """Whether a run of `cfg` with `particles` particles (on a GPU when `gpu`) bins them for the coloured scatter.
    The solver passes its count, budget.py its estimate of it."""
    from ..bases.shape_functions import configured_basis
    spec = bases.get(cfg.solver.basis)
    kind = "mapped" if cfg.domain.map is not None else spec.stencil_kind
    width = configured_basis(cfg).stencil   # its options included (ddmp's sub-points: one node wider); no fields
    return applies(gpu, kind, width, cfg.dim, cfg.solver.scatter, particles, cfg.solver.deterministic)


class BlockBins:
    """Particles binned by the leaf block of their stencil origin (`origin`: @ti.func p -> first node, storage
    index). After `bin()`, colour c's blocks are entries offset[c] .. offset[c + 1] - 1; entry j holds the particles
    order[lo[j]] .. order[hi[j] - 1]."""

    def __init__(self, dim: int, grid: Grid, n: int):
        self.dim, self.n, self.leaf = dim, n, grid.leaf
        self.colours = 2 ** dim
        cap = max(1, min(n, math.prod(grid.blocks)))   # occupied blocks: at most one per particle
        self.count = grid.block_field(ti.i32)   # particles per block (back to 0 after each bin())
        self.start = grid.block_field(ti.i32)   # first slot of the block's particles in `order`
        # per particle (layout.scatter_particle_fields): its slot in the bins' order and its block (the origin is
        # computed once)
        per_particle = layout.scatter_particle_fields(dim)
        self.order, self.home = layout.allocate(per_particle, max(n, 1)).values()
        # occupied blocks, in the order they were found, and their runs in `order`; the colour tables
        self.block, self.lo, self.hi = layout.allocate(layout.scatter_block_list(dim), cap).values()
        for f, shape in layout.scatter_tables(dim):
            setattr(self, f.name, f.allocate(shape))
        # the block lists are bounded by the occupied blocks (budget.py counts them with the grid)
        self.bytes_per_particle = layout.nbytes(per_particle, "f32")

    def build(self, origin):
        """Define `bin()`; origin: @ti.func (p) -> the first node of p's stencil."""
        dim, n, B = self.dim, self.n, self.leaf
        count, start, order, block, lo, hi = self.count, self.start, self.order, self.block, self.lo, self.hi
        home = self.home
        offset, filled, n_blocks, used, colours = self.offset, self.filled, self.n_blocks, self.used, self.colours

        @ti.func
        def colour(b):
            c = 0
            for a in ti.static(range(dim)):
                c += (b[a] & 1) << a
            return c

        @ti.func
        def sort_run(j, unused):
            """Insertion sort of block j's run: nearly sorted already (threads fill it almost in order)."""
            for i in range(lo[j] + 1, hi[j]):
                q = order[i]
                k = i - 1
                while k >= lo[j] and order[k] > q:
                    order[k + 1] = order[k]
                    k -= 1
                order[k + 1] = q

        sort_runs = across_threads(sort_run)

        @ti.kernel
        def bin():
            # top-level statements run on the calling thread; a `for _ in range(1)` is a parallel task of one
            # iteration that wakes the thread pool (a kernel of such a loop alone: 0.2 ms a launch on 2 cores,
            # 0.035 ms as statements; docs/performance.md, "Fixed costs of a step")
            n_blocks[None] = 0
            used[None] = 0
            for c in ti.static(range(colours + 1)):
                offset[c] = 0
            for c in ti.static(range(colours)):
                filled[c] = 0
            for p in range(n):   # count each block's particles; list the blocks
                b = origin(p) // B
                home[p] = b
                if ti.atomic_add(count[b], 1) == 0:
                    block[ti.atomic_add(n_blocks[None], 1)] = b
                    ti.atomic_add(offset[colour(b) + 1], 1)
            for c in ti.static(range(1, colours + 1)):   # where each colour's blocks start in the list
                offset[c] += offset[c - 1]
            # each block's run of `order`, listed under its colour: a short serial pass over the occupied blocks
            # (hundreds to a few thousand), one parallel task fewer
            ti.loop_config(serialize=True)
            for k in range(n_blocks[None]):
                b = block[k]
                c = colour(b)
                j = offset[c] + filled[c]   # serial: plain counters
                filled[c] += 1
                s = used[None]
                used[None] += count[b]
                start[b] = s
                lo[j], hi[j] = s, s + count[b]
                count[b] = 0
            for p in range(n):   # fill the runs (start[b] becomes the block's fill cursor)
                order[ti.atomic_add(start[home[p]], 1)] = p
            sort_runs(0, n_blocks[None], 0)   # each run in particle order

        self.bin = bin

    def colour_loop(self, body):
        """@ti.func (colour, arg) calling body(p, arg) for every particle of the blocks of `colour`, each block
        whole by one thread, its particles in order. Call it at a kernel's top level (its loop is the parallel one)."""
        lo, hi, order, offset = self.lo, self.hi, self.order, self.offset

        @ti.func
        def run(j, arg):
            for i in range(lo[j], hi[j]):
                body(order[i], arg)

        runs = across_threads(run)

        @ti.func
        def loop(colour, arg):
            runs(offset[colour], offset[colour + 1], arg)
        return loop


def across_threads(body):
    """@ti.func (first, last, arg) calling body(j, arg) for j in first .. last - 1, spread over the CPU threads.
    Call it at a kernel's top level. Taichi runs a CPU range-for as tasks of at least 512 iterations, so a loop over
    tens or hundreds of blocks would be one task on one thread; this loop has 512 iterations per thread
    instead, and the first of each 512 takes every threads-th j (neighbouring blocks, of similar fill, go to
    different threads)."""
    threads = max(1, cpu_threads())

    @ti.func
    def spread(first, last, arg):
        for t in range(CPU_TASK * threads):
            if t % CPU_TASK == 0:
                j = first + t // CPU_TASK
                while j < last:
                    body(j, arg)
                    j += threads
    return spread
