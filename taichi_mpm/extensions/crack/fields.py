"""The crack finder's fields: the node fields it adds to the solver's grid, its own per-particle, cell-list and
kept-normal fields (allocated only with a crack section). Its per-particle fields are declared (`CrackNeeds`:
field_decl.FieldDecl) and allocated from the declaration; layout.py and budget.py read the same declaration."""

import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from ...errors import ConfigError
from ...field_decl import FieldDecl, GridDecl, allocate, nbytes
from ...grid import Grid
from ...materials import MODELS, rankine_params
from ...schemes import get as transfer_scheme
from .constants import ALL, CELL_SPLIT, MAX_CELLS


def grid_fields(dim: int, sides: int = 0, friction: bool = False, flip: bool = False,
                pairs: bool = False) -> tuple[list[str], list]:
    """The crack finder's fields in the solver's grid (cleared with it each step): vectors (the rows of the
    anisotropic node mass A_i, the node normal; with friction, the second velocity field of each node, the particles
    in contact across it: their momentum with its force impulse (then their velocity), their normals, FLIP's old
    momentum (then velocity), the node's velocity before walls and grips, and both fields' mass moments about the
    node, for the gap between their surfaces) and scalars (the node's mark: 1 in a
    near particle's stencil, 2 on the discontinuity; with two or more interface bodies, the largest weight an
    interface body's particle has at the node and that body, its owner, as one i64 key (nodes.owner_key_funcs);
    with friction, the across field's mass, and with friction_pairs its body)."""
    owners = [FieldDecl("crack_owner", "i64")] if sides else []
    far = (["crack_pf", "crack_nf", "crack_vc", "crack_xm", "crack_xf"] + (["crack_of"] if flip else [])
           if friction else [])
    vectors = [f"A{a}" for a in range(dim)] + ["crack_n"] + far
    return vectors, ["crack_mark"] + owners + (["crack_mf"] if friction else []) + (["crack_sf"] if pairs else [])


def interface_sides(bodies) -> list[int]:
    """Per body of the config, its side among the interface bodies (0, 1, ...; -1 for others); all -1 unless
    two or more bodies are interface bodies (one alone has no other body to be told apart from)."""
    flags = [bool(getattr(b, "interface", False)) for b in bodies]
    if sum(flags) < 2:
        return [-1] * len(flags)
    order = iter(range(len(flags)))
    return [next(order) if f else -1 for f in flags]


# the node normals kept between refreshes: a sparse grid of their own, whatever domain.sparse says
NODE_CACHE = GridDecl("crack node normals", ("n",), always_sparse=True)


def has_damage_law(materials) -> bool:
    """Whether a material of the scene has a Rankine law (materials.rankine_params is not None for it)."""
    return any(getattr(m, "tensile_strength", None) is not None and MODELS[m.model].damage for m in materials)


@dataclass(frozen=True)
class CrackNeeds:
    """What decides the finder's per-particle fields: the config's crack section, the transfer, the damage laws and
    the stencil's size (its mask's bits)."""
    dim: int
    apic: bool
    has_law: bool
    stencil_nodes: int
    contact: bool          # crack.contact_in_compression: normals in cell order, contact lists
    kept_normals: bool     # crack.normal_refresh > 0
    sides: int = 0         # interface bodies when two or more: each node's owner tells them apart (classify)
    friction: bool = False  # crack.friction > 0 (with contact): the second velocity field at the nodes
    flip: bool = False      # a transfer that keeps the grid's old velocity (FLIP): the second field's too
    pairs: bool = False     # crack.friction_pairs (with friction): the second field's body at each node

    @classmethod
    def of(cls, cfg, materials, basis) -> "CrackNeeds":
        cc = cfg.crack
        # an affine transfer's centroid field (config allows apic only of the affine ones with a crack section)
        scheme = transfer_scheme(cfg.solver.transfer)
        return cls(dim=cfg.dim, apic=scheme.affine, flip=scheme.keeps_old_grid, has_law=has_damage_law(materials),
                   stencil_nodes=basis.contributions(cfg.dim), sides=max(interface_sides(cfg.bodies)) + 1,
                   **cls.switches(cc))

    @staticmethod
    def switches(cc) -> dict:
        """What the crack section itself switches on (from the config or the allocated fields alike)."""
        contact = bool(cc.contact_in_compression)
        friction = contact and (cc.friction > 0 or any(p.mu > 0 for p in cc.friction_pairs))
        return dict(contact=contact, kept_normals=cc.normal_refresh > 0, friction=friction,
                    pairs=friction and bool(cc.friction_pairs))

    @property
    def grid_vectors(self) -> list[str]:
        return grid_fields(self.dim, self.sides, self.friction, self.flip, self.pairs)[0]

    @property
    def grid_scalars(self) -> list:
        return grid_fields(self.dim, self.sides, self.friction, self.flip, self.pairs)[1]

    def mask_type(self) -> str:
        return "u64" if self.stencil_nodes > 32 else "u32"   # bit k: stencil node k lies across the discontinuity

    def own_fields(self, d: int) -> list[FieldDecl]:
        """Per particle: damage, D, interface flag, Rankine history, normal, state, mask and the family sums."""
        return ([FieldDecl("d", "real"), FieldDecl("D", "real"), FieldDecl("iface", "f32")]
                + ([FieldDecl("kappa", "real")] if self.has_law else [])
                + [FieldDecl("normal", "real", (d,)), FieldDecl("state", "i32"), FieldDecl("mask", self.mask_type()),
                   FieldDecl("sums", "real", (2,)), FieldDecl("gsum", "real", (2, d))]
                + ([FieldDecl("cent", "real", (2, d), "apic")] if self.apic else [])
                + ([FieldDecl("side", "i32", (), "two or more interface bodies")] if self.sides else [])
                + ([FieldDecl("cnormal", "real", (d,), "contact between interface bodies")]
                   if self.sides and self.contact else []))

    def cell_order_fields(self, d: int) -> list[FieldDecl]:
        """Per particle: its cell, the cell order, positions, SPH weights (and normals, interface sides) in cell
        order."""
        return ([FieldDecl("pcell", "i32"), FieldDecl("ids", "i32"), FieldDecl("xs", "real", (d,)),
                 FieldDecl("vs", "real", (2,))]
                + ([FieldDecl("ns", "real", (d,), "contact in compression")] if self.contact else [])
                + ([FieldDecl("ss", "i32", (), "two or more interface bodies")] if self.sides else []))

    def kept_fields(self, d: int) -> list[FieldDecl]:
        """Per particle, with kept normals: the kept normal and state, positions at the refresh, drift, the
        contact list's count and start, each mask's origin and period."""
        if not self.kept_normals:
            return []
        return ([FieldDecl("n_cache", "real", (d,)), FieldDecl("s_cache", "i32"), FieldDecl("x_ref", "real", (d,)),
                 FieldDecl("drift", "real")]
                + ([FieldDecl("contact_count", "i32"), FieldDecl("contact_start", "i32")] if self.contact else [])
                + [FieldDecl("mask_at", "i64"), FieldDecl("mask_epoch", "i32")])

    def particle_fields(self, d: int) -> list[FieldDecl]:
        return self.own_fields(d) + self.cell_order_fields(d) + self.kept_fields(d)


def particle_bytes(d: int, precision: str, apic: bool, has_law: bool, stencil_nodes: int, cc) -> int:
    """Bytes per particle of the finder's fields (CrackFinder.bytes_per_particle), from their declaration."""
    needs = CrackNeeds(dim=d, apic=apic, has_law=has_law, stencil_nodes=stencil_nodes,
                       contact=bool(cc.contact_in_compression), kept_normals=cc.normal_refresh > 0)
    return nbytes(needs.particle_fields(d), precision)


class CrackFields:
    """The SPH support and cell list's geometry, the damage laws, and the fields the finder's kernels share."""

    def __init__(self, view, cc):
        d, n = view.dim, view.n
        self.dim = d
        self.spacing = float(np.min(view.spacing))
        # a particle whose stencil reaches across the discontinuity must see it: the support radius is at
        # least the stencil reach (S/2 cells; ck: its window of S storage nodes, half a cell apart, reaches a cell)
        # plus one particle spacing (cpdi: its undeformed domains' reach, 1.5 cells; a domain stretched beyond it
        # sees the discontinuity only once it is within that reach)
        self.reach = 0.5 * view.basis.stencil / view.basis.spec.nodes_per_cell * view.dx
        self.radius = max(cc.kernel_radius * self.spacing, self.reach + self.spacing)
        extent = view.upper - view.lower
        self.cells = [max(1, int(math.ceil(e * CELL_SPLIT / self.radius))) for e in extent]  # cell = r / CELL_SPLIT
        self.n_cell_total = int(np.prod(self.cells))
        if self.n_cell_total > MAX_CELLS:
            raise ConfigError(f"the crack finder's cell list would need {self.n_cell_total} cells; "
                              "raise crack.kernel_radius or shrink the domain", key="crack.kernel_radius")
        self.laws = [rankine_params(m, view.dx) for m in view.materials]
        self.has_law = any(law is not None for law in self.laws)
        self.n_nodes = view.basis.contributions(d)       # contributions per particle (stencils.py)
        self.apic = view.apic
        self.needs = CrackNeeds(dim=d, apic=view.apic, flip=view.flip, has_law=self.has_law, stencil_nodes=self.n_nodes,
                                sides=int(view.side.max(initial=-1)) + 1, **CrackNeeds.switches(cc))
        self.sides = self.needs.sides
        # per side, the mass of its body: in contact, a particle takes the normal of a heavier body it faces (Nairn
        # 2013), so a block's corner pressed on a flat face couples along the face's normal, not along its own
        # tilted one; facing a body of its own mass (within 0.1 %), the mean of both normals
        self.side_mass = [float(view.mass[view.side == k].sum()) for k in range(self.sides)]
        self._particle_fields(d, n, cc)
        self._cell_list(d, n, cc)
        # normals kept between steps (crack.normal_refresh). Once a particle has moved half the skin since the last
        # refresh, each particle's neighbourhood is checked: a normal is recomputed where the particles around it
        # have moved against each other by the skin (summed over refreshes; a body moving as a whole keeps its
        # normals), all of them where D changed; the cache is part of the state (checkpoints)
        self.skin = float(cc.normal_refresh) * self.radius
        self.cached = self.skin > 0
        self.listed = False
        if self.cached:
            self._kept_normals(d, n, cc, view.grid.shape)

    def _particle_fields(self, d, n, cc):
        for name, f in allocate(self.needs.own_fields(d), n).items():
            setattr(self, name, f)                      # d_p, D_p = max(d_p, I_p), I_p, kappa, n_p, ...
        self.kappa = getattr(self, "kappa", None)
        self.cent = getattr(self, "cent", None)         # rows: sum_i N~ (x_i - x_p), APIC only
        self.side = getattr(self, "side", None)         # the particle's interface body (-1: none), sides only
        self.cnormal = getattr(self, "cnormal", None)   # a particle in contact: the normal its transfers use
        self.contacts = ti.field(ti.i32, ())            # particles in contact this step (CONTACT)
        self.mask_t = ti.u64 if self.needs.mask_type() == "u64" else ti.u32

    def _cell_list(self, d, n, cc):
        nc = self.n_cell_total
        self.cell_count = ti.field(ti.i32, nc)
        self.cell_fill = ti.field(ti.i32, nc)
        self.cell_start = ti.field(ti.i32, nc)
        self.cell_lo = ti.field(float, nc)              # min / max of D in the cell
        self.cell_hi = ti.field(float, nc)
        self.cell_varies = ti.field(ti.i32, nc)         # D varies within the cell's 5^d block (prepare)
        self.d_range = ti.field(float, 2)               # min / max of D over all particles
        # per particle: its cell and the cell order; positions x[ids[j]], SPH weights (V, V D) and (with contact
        # in compression) normals in cell order, so the searches stream
        for name, f in allocate(self.needs.cell_order_fields(d), n).items():
            setattr(self, name, f)
        self.ns = getattr(self, "ns", None)
        self.ss = getattr(self, "ss", None)   # the interface side in cell order (the SPH sums stream it)

    def _kept_normals(self, d, n, cc, grid_shape):
        # per particle: n_p as the gradient sums gave it (before band normals) and the state they gave, positions at
        # the last refresh, the bound on the neighbours' motion against p since n_p was found; with contact lists,
        # each particle's list (count -1: search each step, a band particle whose normal follows its neighbours;
        # start: in a growing pool); each mask's stencil origin (+1, flat) and period of kept normals (`epoch`)
        # when it was found (same origin and period: the same mask, as a node's side depends only on the kept
        # node and particle normals)
        for name, f in allocate(self.needs.kept_fields(d), n).items():
            setattr(self, name, f)
        self.stale = ti.field(ti.i32, ())              # KEEP, DRIFTED (a particle moved) or ALL (D changed)
        self.stale[None] = ALL
        self.recomputed = ti.field(ti.i64, ())         # normals recomputed in all (diagnostics, tests)
        # per cell: the box of its particles' motion since the last refresh, and the box's size over its 5^d block
        self.cell_dlo = ti.Vector.field(d, float, self.n_cell_total)
        self.cell_dhi = ti.Vector.field(d, float, self.n_cell_total)
        self.cell_drift = ti.field(float, self.n_cell_total)
        # contact lists: the particles that could face each one within reach until the next refresh, found when
        # the normals are computed; the contact test sums over them instead of searching each step
        self.listed = bool(cc.contact_in_compression)
        if self.listed:
            self.contact_fill = ti.field(ti.i32, ())
            self.contact_over = ti.field(ti.i32, ())   # slots the lists that outgrew theirs need
            self.cell_dir = ti.Vector.field(d, float, self.n_cell_total)   # the cells' normal cones (build)
            self.cell_spread = ti.field(float, self.n_cell_total)
        # node normals computed since: m = 1 (normal in n) or 2 (on the discontinuity); 0: not yet
        self.node_cache = Grid(d, grid_shape, NODE_CACHE.always_sparse, list(NODE_CACHE.vectors))
        self.node_cache_fill = ti.field(ti.i32, ())
