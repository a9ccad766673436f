"""Grid storage (sparse or dense) and wall conditions.

Sparse: pointer blocks over dense leaf blocks; P2G's atomic adds activate the blocks the particles
touch, and `clear()` deactivates them every step, so memory and time follow the particles, not the
domain. A domain with many blocks gets a second pointer level so the top pointer array stays small.
"""

import math

import taichi as ti

from .field_decl import scalar_decl
from .friction import friction_loss

LEAF = {1: 64, 2: 8, 3: 4}          # nodes per axis of a dense leaf block
MAX_TOP_POINTERS = 1 << 16          # pointer slots at the top level before a second level is added


class Grid:
    def __init__(self, dim: int, shape: list[int], sparse: bool, vector_fields: list[str], apart: list[str] = (),
                 apart_scalars: list[str] = (), leaf: int = 0):
        """`shape`: nodes per axis; `leaf`: nodes per axis of a leaf block (0: LEAF[dim]; ck's half-spacing grid
        takes twice that, so that a block spans the same cells). Allocates `m` (mass) and one dim-vector field per
        name. The fields of `vector_fields` lie interleaved node by node (P2G touches them together: one cache
        line); those of `apart` (dim-vectors) and `apart_scalars` (`scalar`), read by few particles, in arrays of
        their own in the same blocks, so they do not dilute the others; a scalar's entry is its name (of the scene's
        precision) or a field_decl.FieldDecl of its own type."""
        self.dim, self.shape, self.sparse = dim, list(shape), sparse
        self.m = ti.field(float)
        self.vec = {name: ti.Vector.field(dim, float) for name in [*vector_fields, *apart]}
        self.scalar = {d.name: d.allocate(None) for d in map(scalar_decl, apart_scalars)}   # placed below
        axes = ti.axes(*range(dim))
        places = [self.m, *(self.vec[name] for name in vector_fields)]
        groups = [places] + [[self.vec[name]] for name in apart] + [[f] for f in self.scalar.values()]
        self.levels = []
        self.leaf = leaf = leaf or LEAF[dim]
        self.blocks = [math.ceil(s / leaf) for s in self.shape]   # leaf blocks per axis
        if not sparse:
            for group in groups:
                ti.root.dense(axes, self.shape).place(*group)
            return
        # power-of-two pointer extents: Taichi 1.7 drops writes in some non-power-of-two 3D pointer grids
        blocks = [_pow2(math.ceil(s / leaf)) for s in self.shape]
        if math.prod(blocks) <= MAX_TOP_POINTERS:
            top = ti.root.pointer(axes, blocks)
            self.levels = [top]
        else:
            mid_n = 8 if dim == 3 else 64  # 2D: 16 made the clear 10x slower at 16384^2 cells
            tops = [_pow2(math.ceil(b / mid_n)) for b in blocks]
            top = ti.root.pointer(axes, tops)
            mid = top.pointer(axes, mid_n)
            self.levels = [top, mid]
        for group in groups:
            self.levels[-1].dense(axes, leaf).place(*group)

    def block_field(self, dtype):
        """A field with one value per leaf block (indexed by block coordinates, node // LEAF): on a sparse grid it
        lives in the block's pointer cell, so it is allocated with the block and cleared with it."""
        f = ti.field(dtype)
        if self.sparse:
            self.levels[-1].place(f)
        else:
            ti.root.dense(ti.axes(*range(self.dim)), self.blocks).place(f)
        return f

    def clear(self):
        if self.sparse:
            for level in reversed(self.levels):
                level.deactivate_all()
        else:
            for f in [self.m, *self.vec.values(), *self.scalar.values()]:
                f.fill(0)


def _pow2(n: int) -> int:
    return 1 << max(0, (n - 1).bit_length())


def make_wall_condition(dim: int, n_cells: list[int], faces: list[tuple[str, str]], basis, friction=None,
                        reaction=None, moving=None, mapped=None):
    """@ti.func (I, v) -> v with each face's condition applied at nodes on or beyond that wall.

    `reaction`: an optional dim-vector field of 2 dim entries (x_min, x_max, y_min, ...). `apply.measured(I, v, m)`
    applies the same conditions and adds the impulse each face gives the node, m (v_after - v_before): summed over
    the face's nodes and divided by the time, the force the wall exerts on the material. A node on two faces (a
    corner) gives each face the change that face's own condition makes.

    faces[a] = (kind at the lower wall, kind at the upper wall) of axis a:
    sticky: v = 0; slip: no flow into the wall (may separate); roller: no normal velocity either way
    (bilateral); free: nothing. friction[a] = (mu at the lower wall, mu at the upper wall), default 0.
    Every condition acts along the face's outward unit normal n: the axis direction on the box, the node's
    normal (mapped.MappedGrid.normal, per control point) on the faces of a mapped grid (`mapped`), where a node
    is on a face when its index is the first or last along that axis (a periodic map has no x faces).

    Coulomb friction at a slip or roller node (Bardenhagen et al. 2000): when the wall removes a velocity dv_n
    flowing into it (a compressive contact impulse m dv_n), the tangential velocity is reduced by mu dv_n, and
    not below zero (then the node sticks). A roller pulling a node back from outside the wall (tension) adds no
    friction.

    velocity (moving wall, driven lid): `moving = (given, values, work, spin)`: given[2 axis + side] is a
    tuple of dim bools (the prescribed components; the others stay free), values a dim-vector field of 2 dim
    entries holding the current wall velocities (set by the solver each step), work the solver's accumulators
    (sums.Slots) whose slot 0 gets the work the wall does on the grid in the measured pass: the impulse
    m (v_after - v_before) times the wall velocity v_after. The face itself does not move: a normal component
    pushes or pulls material through a fixed plane. spin (mapped grids, or None): (a field of 2 dim angular
    velocities, per face slot the point its axis +z passes through or None): a turning face's control point P_i
    gets omega e_z x (P_i - point) in x and y on top of the given velocity (a cylinder or sphere turning in place).
    """

    on_box = mapped is None
    axes = [basis.axis(a) for a in range(dim)] if on_box else None  # 1D bases (knots of domain.knots)
    kind = {"free": 0, "sticky": 1, "slip": 2, "roller": 3, "velocity": 4}
    codes = [(kind[lo], kind[hi]) for lo, hi in faces]
    mus = [(float(lo), float(hi)) for lo, hi in (friction or [(0.0, 0.0)] * dim)]
    measuring = reaction is not None
    given, wall_v, work, spin = moving if moving is not None else ([(False,) * dim] * (2 * dim), None, None, None)
    wall_w, axes_at = spin if spin is not None else (None, [None] * (2 * dim))
    turning = [a is not None for a in axes_at]
    # box faces: outward normals -e_a (lower) and +e_a (upper), constants of the kernel
    box_normal = [[(-1.0 if slot % 2 == 0 else 1.0) * (c == slot // 2) for c in range(dim)] for slot in range(2 * dim)]
    normal, periodic, last = (None, False, None) if on_box else (mapped.normal, mapped.periodic,
                                                                  [s - 1 for s in mapped.shape])

    @ti.func
    def contact(v, n, code: ti.template(), mu: ti.template()):
        """Slip (2) or roller (3) wall with outward unit normal n, Coulomb friction mu."""
        vn = v.dot(n)
        into = ti.max(vn, 0.0)  # speed into the wall
        if ti.static(code == 2):
            v -= into * n
        else:
            v -= vn * n
        if ti.static(mu > 0 and dim > 1):
            v -= friction_loss(v - v.dot(n) * n, into, mu)
        return v

    @ti.func
    def prescribed(I, v, slot: ti.template()):
        """Velocity wall: the given components take the wall's current velocity; a turning face (mapped grids)
        adds omega e_z x (P_i - axis point) at its control point P_i."""
        for c in ti.static(range(dim)):
            if ti.static(given[slot][c]):
                v[c] = wall_v[slot][c]
        if ti.static(turning[slot]):
            r = mapped.map.ctrl[I] - ti.Vector(axes_at[slot], dt=float)
            v[0] -= wall_w[slot] * r[1]
            v[1] += wall_w[slot] * r[0]
        return v

    @ti.func
    def face(I, v, m, a: ti.template(), side: ti.template(), measure: ti.template()):
        slot = ti.static(2 * a + side)
        code = ti.static(codes[a][side])
        before = v
        if ti.static(code == 1):
            v = ti.Vector.zero(float, dim)
        elif ti.static(code == 2 or code == 3):
            if ti.static(on_box):
                v = contact(v, ti.Vector(box_normal[slot], dt=float), code, mus[a][side])
            else:
                v = contact(v, normal[I, slot], code, mus[a][side])
        elif ti.static(code == 4):
            v = prescribed(I, v, slot)
        if ti.static(measure and measuring):
            reaction[slot] += m * (v - before)
        if ti.static(measure and code == 4):
            work[0][None] += m * (v - before).dot(v)
        return v

    @ti.func
    def conditions(I, v, m, measure: ti.template()):
        for a in ti.static(range(dim)):
            if ti.static(on_box):
                c = axes[a].coord(I[a], n_cells[a])
                if c <= 0.0:
                    v = face(I, v, m, a, 0, measure)
                if c >= ti.static(float(n_cells[a])):
                    v = face(I, v, m, a, 1, measure)
            elif ti.static(not (a == 0 and periodic)):
                if I[a] == 0:
                    v = face(I, v, m, a, 0, measure)
                if I[a] == ti.static(last[a]):
                    v = face(I, v, m, a, 1, measure)
        return v

    @ti.func
    def apply(I, v):
        return conditions(I, v, 0.0, False)

    @ti.func
    def apply_measured(I, v, m):
        """apply, adding the impulse m dv each face gives the node to reaction[2 axis + side] (wall probes) and
        the work of velocity walls to work[0]."""
        return conditions(I, v, m, True)

    apply.measured = apply_measured
    # per axis (lower, upper): does the face forbid flow out of the domain (slip, roller, sticky, a velocity wall
    # with its normal component prescribed)? B-spline particles next to such a face are transferred from a point
    # inside it and kept inside (stencils.py, make_wall_hold; docs/bases.md "Bodies flush against walls")
    apply.holds = [tuple(on_box and (codes[a][s] in (1, 2, 3) or (codes[a][s] == 4 and given[2 * a + s][a]))
                         for s in (0, 1)) for a in range(dim)]
    apply.tangential = _face_tangential(dim, n_cells, axes, apply.holds)   # for contact normals
    return apply


def _face_tangential(dim, n_cells, axes, holds):
    """@ti.func (I, n) -> n without its components along the outward normals of the holding box faces (`holds`)
    that node I lies on. A body flush with such a face has a mass gradient across it at the face's nodes (its mass
    ends at the wall), which is no surface of the body: contact normals drop it (extensions/contact)."""

    @ti.func
    def tangential(I, n):
        for a in ti.static(range(dim)):
            if ti.static(holds[a][0] or holds[a][1]):   # box faces only (holds is False off the box)
                c = axes[a].coord(I[a], n_cells[a])
                if ti.static(holds[a][0]):
                    if c <= 0.0:
                        n[a] = 0.0
                if ti.static(holds[a][1]):
                    if c >= ti.static(float(n_cells[a])):
                        n[a] = 0.0
        return n
    return tangential
