"""The cell list: particles binned into cells of r / CELL_SPLIT by a counting sort (cell order fixed within a cell,
so every SPH sum runs in one order), and the row searches the SPH sums and contact tests walk."""

from typing import Callable, NamedTuple

import taichi as ti

from .constants import BIG, CELL_SPLIT, ROW_MARGIN


class CellList(NamedTuple):
    cell_of: Callable       # (x) -> the cell holding x (clamped to the list)
    flat: Callable          # (cell) -> flat cell index
    unflat: Callable
    cell_units: Callable    # (x) -> x in cell units from the lower corner
    row_cells: Callable     # (c, u, o, span, reach2) -> (first, last) flat cells of one row of a search
    cells_slice: Callable   # ((first, last)) -> [j0, j1) of the cell order
    row: Callable           # (c, u, o) -> one row of an SPH search (reach r) as [j0, j1)
    listed_at: Callable     # (p) -> where the cell list holds p


def cell_list_funcs(ctx) -> CellList:
    f, dim, lower, inv_cell = ctx.fields, ctx.fields.dim, ctx.lower, ctx.inv_cell
    cells, cell_start, cell_count = f.cells, f.cell_start, f.cell_count
    x, x_ref, cached = ctx.view.x, (f.x_ref if f.cached else None), f.cached

    @ti.func
    def cell_of(xq):
        c = ti.Vector.zero(int, dim)
        for a in ti.static(range(dim)):
            c[a] = ti.min(ti.max(int(ti.floor((xq[a] - lower[a]) * inv_cell)), 0), cells[a] - 1)
        return c

    @ti.func
    def flat(c):
        k = 0
        for a in ti.static(range(dim)):
            k = k * cells[a] + c[a]
        return k

    @ti.func
    def unflat(k):
        c = ti.Vector.zero(int, dim)
        for a in ti.static(range(dim)):
            c[dim - 1 - a] = k % cells[dim - 1 - a]
            k //= cells[dim - 1 - a]
        return c

    @ti.func
    def row_cells(c, u, o, span: ti.template(), reach2: ti.template()):
        """One row (along the last axis) of the (2 span + 1)^d cells around cell c, as the flat indices of its first
        and last cell (first > last: none). o: the row's offsets on the other axes; u: the query point in cell
        units. Cells that cannot hold a particle within sqrt(reach2) cells of u are cut (their particles would
        fail the distance test anyway), so sums keep their terms and their order."""
        rem = float(reach2)   # the reach squared in cell units, less the row's squared gap
        base, inside = 0, True
        for a in ti.static(range(dim - 1)):
            k = c[a] + o[a]
            if k < 0 or k >= cells[a]:
                inside = False
            gap = 0.0   # edge cells hold the particles beyond the domain too: no gap outwards there
            if u[a] < k and k > 0:
                gap = k - u[a]
            elif u[a] > k + 1 and k < cells[a] - 1:
                gap = u[a] - (k + 1)
            rem -= ti.max(gap - ROW_MARGIN, 0.0) ** 2
            base = base * cells[a] + k
        first, last = 0, -1
        if inside and rem > 0:
            z = ti.static(dim - 1)
            reach = ti.sqrt(rem) + ROW_MARGIN
            lo = ti.max(ti.min(int(ti.floor(u[z] - reach)), cells[z] - 1), 0, c[z] - span)
            hi = ti.min(ti.max(int(ti.floor(u[z] + reach)), 0), cells[z] - 1, c[z] + span)
            if lo <= hi:
                first, last = base * cells[z] + lo, base * cells[z] + hi
        return first, last

    @ti.func
    def cells_slice(cells_range):
        """The particles of cells first..last: a slice [j0, j1) of `ids` (consecutive cells are consecutive in
        the sorted order)."""
        first, last = cells_range
        j0, j1 = 0, 0
        if first <= last:
            j0, j1 = cell_start[first], cell_start[last] + cell_count[last]
        return j0, j1

    @ti.func
    def row(c, u, o):
        """The SPH searches' candidates in one row of cells (reach r)."""
        return cells_slice(row_cells(c, u, o, CELL_SPLIT, float(CELL_SPLIT * CELL_SPLIT)))

    @ti.func
    def listed_at(p):
        """Where the cell list holds p (from the particle normals on): with kept normals, its position at the
        last refresh; the node normals and band middles of the steps until the next are found there."""
        xp = x[p]
        if ti.static(cached):
            xp = x_ref[p]
        return xp

    @ti.func
    def cell_units(xq):
        return (xq - lower) * inv_cell

    return CellList(cell_of=cell_of, flat=flat, unflat=unflat, cell_units=cell_units, row_cells=row_cells,
                    cells_slice=cells_slice, row=row, listed_at=listed_at)


def _binning_funcs(ctx, cl: CellList):
    """rescan() (whether this step recomputes the normals) and binned_position(p, at_refresh)."""
    f, x, listed_at, cached = ctx.fields, ctx.view.x, cl.listed_at, ctx.fields.cached
    stale = f.stale if cached else None

    @ti.func
    def rescan():
        """Whether this step recomputes the normals, so needs where D varies (the gradient sums read it only)."""
        scan = True
        if ti.static(cached):
            scan = stale[None] != 0
        return scan

    @ti.func
    def binned_position(p, at_refresh):
        """Where bin_cells puts p: its position, or where the list held it (`at_refresh`: rebuilt between
        refreshes, after set_state)."""
        xp = x[p]
        if at_refresh:
            xp = listed_at(p)
        return xp

    return rescan, binned_position


def bin_cells_kernel(ctx, cl: CellList):
    """The kernel bin_cells(at_refresh)."""
    f, dim = ctx.fields, ctx.fields.dim
    x, D, vol0 = ctx.view.x, f.D, ctx.view.vol0
    cell_count, cell_fill, cell_start, pcell, ids = f.cell_count, f.cell_fill, f.cell_start, f.pcell, f.ids
    cell_lo, cell_hi, cell_varies, xs, vs, d_range = f.cell_lo, f.cell_hi, f.cell_varies, f.xs, f.vs, f.d_range
    n_cell_total, cells_v, nbr, cached = f.n_cell_total, ti.Vector(f.cells), ctx.nbr, f.cached
    x_ref, cell_dlo, cell_dhi, cell_drift = (f.x_ref, f.cell_dlo, f.cell_dhi, f.cell_drift) if cached else (None,) * 4
    side, ss, by_side = f.side, f.ss, f.ss is not None
    cell_of, flat, unflat = cl.cell_of, cl.flat, cl.unflat
    rescan, binned_position = _binning_funcs(ctx, cl)

    @ti.kernel
    def bin_cells(at_refresh: ti.i32):
        """The cell list (a counting sort), with positions and SPH weights in cell order, and on refreshes
        where D varies and how far particles within reach moved against each other. With kept normals it is
        built at refreshes only: until the next one, node normals and band middles are found in the
        configuration the particle normals were (particles have moved at most half the skin since)."""
        for c in cell_count:
            cell_count[c] = 0
            cell_fill[c] = 0
        for p in x:
            c = flat(cell_of(binned_position(p, at_refresh)))
            pcell[p] = c
            ti.atomic_add(cell_count[c], 1)
        ti.loop_config(serialize=True)
        for c in range(1, n_cell_total):
            cell_start[c] = cell_start[c - 1] + cell_count[c - 1]
        for p in x:
            c = pcell[p]
            ids[cell_start[c] + ti.atomic_add(cell_fill[c], 1)] = p
        for c in cell_count:  # insertion sort within each cell: sums in a fixed order, runs reproducible
            s0 = cell_start[c]
            for i in range(1, cell_count[c]):
                key = ids[s0 + i]
                j = i - 1
                while j >= 0:
                    if ids[s0 + j] > key:
                        ids[s0 + j + 1] = ids[s0 + j]
                        j -= 1
                    else:
                        break
                ids[s0 + j + 1] = key
        for j in ids:
            q = ids[j]
            xs[j] = binned_position(q, at_refresh)
            vs[j] = ti.Vector([vol0[q], vol0[q] * D[q]])
            if ti.static(by_side):
                ss[j] = side[q]
        # refresh steps only: the cells' min / max of D and box of motion since the last refresh, then over each
        # occupied cell's 5^d block (where D varies; how far particles that reach each other moved apart)
        d_range[0], d_range[1] = 1.0, 0.0
        for c in cell_count:
            if rescan():
                lo, hi = 1.0, 0.0
                dlo = ti.Vector([BIG] * dim)
                dhi = ti.Vector([-BIG] * dim)
                for j in range(cell_start[c], cell_start[c] + cell_count[c]):
                    q = ids[j]
                    lo, hi = ti.min(lo, D[q]), ti.max(hi, D[q])
                    if ti.static(cached):
                        dq = xs[j] - x_ref[q]
                        dlo, dhi = ti.min(dlo, dq), ti.max(dhi, dq)
                cell_lo[c], cell_hi[c] = lo, hi
                if ti.static(cached):
                    cell_dlo[c], cell_dhi[c] = dlo, dhi
                if cell_count[c] > 0:
                    ti.atomic_min(d_range[0], lo)
                    ti.atomic_max(d_range[1], hi)
        for c in cell_count:
            if rescan():
                cell_varies[c] = 0
                if ti.static(cached):
                    cell_drift[c] = 0.0
                if cell_count[c] > 0 and d_range[1] > d_range[0]:   # nothing to scan where D is one value
                    lo, hi = 1.0, 0.0
                    dlo = ti.Vector([BIG] * dim)
                    dhi = ti.Vector([-BIG] * dim)
                    cc = unflat(c)
                    for off in ti.grouped(ti.ndrange(*nbr)):
                        cn = cc + off
                        if (cn >= 0).all() and (cn < cells_v).all():
                            cid = flat(cn)
                            if cell_count[cid] > 0:
                                lo = ti.min(lo, cell_lo[cid])
                                hi = ti.max(hi, cell_hi[cid])
                                if ti.static(cached):
                                    dlo, dhi = ti.min(dlo, cell_dlo[cid]), ti.max(dhi, cell_dhi[cid])
                    cell_varies[c] = ti.cast(hi > lo, ti.i32)
                    if ti.static(cached):
                        cell_drift[c] = (dhi - dlo).norm()

    return bin_cells
