"""The fields a scene allocates, declared once from its features: the solver (and the crack finder, F-bar and the
coloured scatter) allocate from these declarations, and budget.py counts their bytes from the same ones, so the
size estimate cannot drift from what a run allocates (tests/test_layout_budget.py measures the allocated fields).

`Needs` says which optional fields a scene has. The solver derives it from its `Features` and scene
(`Needs.of_simulation`), budget.py from the config alone (`Needs.of_config`); the two agree for every config
(the test holds them to it). `particle_fields(needs)` lists the per-particle fields, `grids(needs)` the grids
(each: the fields of one node and of one leaf block). Physics code only: no CLI, rendering or file I/O here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from . import materials as material_models
from . import schemes as transfer_schemes
from .schemes.polypic import lower_terms, modes
from .bases import registry as bases
from .extensions.contact.fields import ContactNeeds
from .extensions.crack.fields import NODE_CACHE as CRACK_NODE_CACHE, CrackNeeds
from .field_decl import FieldDecl, GridDecl, allocate, nbytes  # noqa: F401 (allocate, nbytes: the layout's API)
from .step.features import small_node_fold

@dataclass(frozen=True)
class Needs:
    """What decides a scene's optional fields (Features' field switches and a few facts of the scene)."""
    dim: int
    precision: str
    store_grad_v: bool          # C: APIC's B_p or C_p, or grad v (viscosity)
    own_grad_v: bool            # grad_v: the last step's grid velocity gradient (viscosity with an affine transfer)
    multi_material: bool        # a material index
    multi_body: bool            # a body index (diagnostics per body)
    body_force: bool
    domain_per_particle: bool   # gimp/cpdi with particle domains of more than one size
    initial_stress: bool
    tractions: bool
    n_state: int                # material state floats (materials/), 0: no state field
    transfer_vectors: tuple     # the transfer's own node vectors (xpic's three: schemes/xpic.py)
    old_grid: bool              # the grid keeps v before forces, v_old (flip, xpic, asflip: schemes/; ddmp's fold)
    musl: bool
    grips: bool
    mapped: bool                # domain.map: parametric coordinates xi_p
    fbar: bool                  # solver.volumetric fbar (not 1D)
    fbar_linear: bool           # F-bar averages on the linear grid (quadratic, cubic)
    ddmp: bool                  # nodal volumes on a grid of their own
    ddmp_fold: bool             # and each node's fold code and shared sums (solver.ddmp.fold_below)
    coloured: bool              # the coloured scatter's bins (scatter.BlockBins)
    crack: CrackNeeds | None
    contact: ContactNeeds | None = None   # multi-field contact's node fields (its velocity fields)
    cpdi2: bool = False         # cpdi2's corners, each particle's own (extensions/domain_corners.py)
    stress_difference: bool = False   # the nodal stress sums (extensions/stress_difference.py)
    polynomial: tuple = ()      # polypic: (nodes per axis of the stencil, solver.polypic_modes)

    @classmethod
    def of_simulation(cls, sim, feat, coloured: bool) -> "Needs":
        """The solver's: from its Features and scene."""
        c = sim.cfg
        return cls(dim=sim.dim, precision=c.precision, store_grad_v=feat.store_grad_v,
                   own_grad_v=feat.own_grad_v,
                   multi_material=feat.multi_material, multi_body=bool(sim.scene.body.max(initial=0) > 0),
                   body_force=feat.body_force, domain_per_particle=feat.domain_per_particle,
                   initial_stress=feat.initial_stress, tractions=feat.tractions,
                   n_state=material_models.state_size(sim._materials, sim.dim),
                   old_grid=feat.old_grid,
                   transfer_vectors=transfer_schemes.get(c.solver.transfer).grid_vectors, musl=feat.musl,
                   grips=feat.grips, mapped=sim.mapped is not None, **_common(c, coloured),
                   crack=CrackNeeds.of(c, sim._materials, sim.basis) if c.crack is not None else None,
                   contact=ContactNeeds.of(c) if c.contact is not None else None)

    @classmethod
    def of_config(cls, cfg, body_force: bool, coloured: bool, basis) -> "Needs":
        """budget.py's: from the config alone (what Features.of and the scene decide from it)."""
        mats = [cfg.materials[name] for name in dict.fromkeys(b.material for b in cfg.bodies)]
        viscous = any(getattr(m, "viscosity", 0.0) > 0 for m in mats)
        spacings = {cfg.domain.dx / b.particles_per_cell for b in cfg.bodies}
        s = cfg.solver
        scheme = transfer_schemes.get(s.transfer)   # its declaration (schemes/)
        return cls(dim=cfg.dim, precision=cfg.precision, store_grad_v=scheme.affine or viscous,
                   own_grad_v=scheme.affine and viscous,
                   multi_material=len(mats) > 1, multi_body=len(cfg.bodies) > 1, body_force=body_force,
                   domain_per_particle=bases.get(s.basis).particle_domains and len(spacings) > 1,
                   initial_stress=any(b.stress is not None for b in cfg.bodies),
                   tractions=any(t.apply_to == "particles" for b in cfg.bodies for t in b.tractions),
                   n_state=material_models.state_size(mats, cfg.dim),
                   old_grid=scheme.keeps_old_grid or small_node_fold(cfg) > 0,
                   transfer_vectors=scheme.grid_vectors, musl=s.update == "musl",
                   grips=any(b.prescribed_velocity for b in cfg.bodies), mapped=cfg.domain.map is not None,
                   **_common(cfg, coloured), crack=CrackNeeds.of(cfg, mats, basis) if cfg.crack is not None else None,
                   contact=ContactNeeds.of(cfg) if cfg.contact is not None else None)


def _common(cfg, coloured: bool) -> dict:
    spec = bases.get(cfg.solver.basis)   # the basis' declaration (bases/registry.py)
    polynomial = ((spec.stencil, cfg.solver.polypic_modes) if transfer_schemes.get(cfg.solver.transfer).polynomial
                  else ())
    return dict(polynomial=polynomial, fbar=cfg.solver.volumetric == "fbar" and cfg.dim > 1,
                fbar_linear=spec.fbar_linear_grid,
                ddmp=spec.prepass_grid, ddmp_fold=small_node_fold(cfg) > 0, coloured=coloured,
                cpdi2=spec.stencil_kind == "corners" and cfg.solver.cpdi.variant == "cpdi2",
                stress_difference=cfg.solver.stress_difference)


def solver_particle_fields(n: Needs) -> list[FieldDecl]:
    """The solver's own per-particle fields (Simulation attributes of these names), in allocation order."""
    d = n.dim
    out = [FieldDecl("x", "real", (d,)), FieldDecl("v", "real", (d,)), FieldDecl("F", "real", (d, d)),
           FieldDecl("vol0", "real")]
    out += [FieldDecl("C", "real", (d, d), "apic or viscosity")] if n.store_grad_v else []
    out += [FieldDecl("grad_v", "real", (d, d), "viscosity with an affine transfer")] if n.own_grad_v else []
    out += [FieldDecl("mat", "u8", (), "more than one material")] if n.multi_material else []
    out += [FieldDecl("body_acc", "real", (d,), "body force")] if n.body_force else []
    out += [FieldDecl("half_width", "real", (), "particle domains of several sizes")] if n.domain_per_particle else []
    out += [FieldDecl("stress0", "real", (d, d), "initial stress")] if n.initial_stress else []
    out += [FieldDecl("state", "real", (n.n_state,), "material state")] if n.n_state else []
    out += [FieldDecl("load", "real", (d,), "tractions")] if n.tractions else []
    out += [FieldDecl("body_id", "i32", (), "more than one body")] if n.multi_body else []
    return out


def scatter_particle_fields(dim: int) -> list[FieldDecl]:
    """scatter.BlockBins' per-particle fields: the order of the bins and each particle's block."""
    return [FieldDecl("order", "i32", (), "coloured scatter"), FieldDecl("home", "i32", (dim,), "coloured scatter")]


def scatter_block_list(dim: int) -> list[FieldDecl]:
    """scatter.BlockBins' list of occupied blocks (block coordinates, the run's first and last slot): one entry per
    leaf block, at most one per particle."""
    return [FieldDecl("block", "i32", (dim,)), FieldDecl("lo", "i32"), FieldDecl("hi", "i32")]


def scatter_tables(dim: int) -> list[tuple[FieldDecl, tuple]]:
    """scatter.BlockBins' colour tables, with their shapes: each colour's first entry (and the end), the entries
    filled per colour, the blocks found and the slots used."""
    colours = 2 ** dim
    return [(FieldDecl("offset", "i32"), (colours + 1,)), (FieldDecl("filled", "i32"), (colours,)),
            (FieldDecl("n_blocks", "i32"), ()), (FieldDecl("used", "i32"), ())]


def scatter_fixed_bytes(dim: int, entries: int) -> int:
    """The block list of `entries` blocks and the colour tables."""
    tables = sum(f.nbytes("f32") * math.prod(shape) for f, shape in scatter_tables(dim))
    return entries * nbytes(scatter_block_list(dim), "f32") + tables


def MAPPED_XI(dim: int) -> FieldDecl:
    """domain.map: each particle's parametric coordinates."""
    return FieldDecl("xi", "real", (dim,), "domain.map")
FBAR_J = FieldDecl("J_start", "real", (), "fbar")            # det F at the start of the step


def polynomial_fields(dim: int, stencil: int, which: str) -> list[FieldDecl]:
    """polypic: each particle's modes' coefficients (a row per mode) and each axis' orthogonal polynomials below
    their leading term (step/polynomial.py)."""
    degree = stencil - 1
    return [FieldDecl("poly_c", "real", (len(modes(dim, degree, which)), dim), "polypic"),
            FieldDecl("poly_g", "real", (dim, len(lower_terms(degree))), "polypic")]


def cpdi2_corners(dim: int) -> FieldDecl:
    """cpdi2: each particle's 2^d domain corners, as the rows of a matrix."""
    return FieldDecl("corners", "real", (2 ** dim, dim), "cpdi2")


def particle_fields(n: Needs) -> list[FieldDecl]:
    """Every per-particle field of the scene: the solver's, the coloured scatter's, the mapped grid's, F-bar's,
    cpdi2's corners and the crack finder's."""
    out = solver_particle_fields(n)
    out += scatter_particle_fields(n.dim) if n.coloured else []
    out += [MAPPED_XI(n.dim)] if n.mapped else []
    out += [FBAR_J] if n.fbar else []
    out += [cpdi2_corners(n.dim)] if n.cpdi2 else []
    out += polynomial_fields(n.dim, *n.polynomial) if n.polynomial else []
    out += n.crack.particle_fields(n.dim) if n.crack is not None else []
    return out


def main_grid(n: Needs) -> GridDecl:
    vec = ("v",) + (("v_old",) if n.old_grid else ()) + (("v2",) if n.musl else ()) + n.transfer_vectors
    vec += ("grip",) if n.grips else ()   # component 0: the grip (from 1) whose particles touch the node
    apart: tuple[str, ...] = ()
    scalars: tuple[str, ...] = ()
    if n.stress_difference:   # every node with mass: the sums of V sigma w (by rows), V grad w and V w
        vec += STRESS_DIFFERENCE_ROWS[:n.dim] + ("lsd_g",)
        scalars += ("lsd_v",)
    if n.crack is not None:   # the crack finder's node fields: few particles touch them
        apart, scalars = tuple(n.crack.grid_vectors), tuple(n.crack.grid_scalars)
    if n.contact is not None:   # multi-field contact's body fields: mass, momentum, mass gradient (FLIP: v_old)
        apart, scalars = apart + tuple(n.contact.grid_vectors), scalars + tuple(n.contact.grid_scalars)
    # the coloured scatter's count and start per block (in the block's pointer cell)
    return GridDecl("grid", vec, apart, scalars, block_ints=2 if n.coloured else 0)


def ddmp_grid(fold: bool) -> GridDecl:
    """ddmp's node volumes; with the small-node fold (solver.ddmp.fold_below) each node's fold code and the force and
    mass per axis its small neighbours share with it (extensions/ddmp_fill.py)."""
    return GridDecl("ddmp nodal volumes", apart=("fold_force", "fold_mass") if fold else (),
                    scalars=("fold",) if fold else ())


STRESS_DIFFERENCE_ROWS = ("lsd_t0", "lsd_t1", "lsd_t2")   # the rows of sum V sigma w at a node


def fbar_grid(n: Needs) -> GridDecl:
    """F-bar's node volumes at the end and the start of the step: two of these."""
    return GridDecl("fbar volumes", extent="linear" if n.fbar_linear else "nodes")


def grids(n: Needs) -> list[GridDecl]:
    """Every grid of the scene, the main one first."""
    out = [main_grid(n)]
    out += [CRACK_NODE_CACHE] if n.crack is not None and n.crack.kept_normals else []   # normals kept between refreshes
    out += [ddmp_grid(n.ddmp_fold)] if n.ddmp else []
    out += [fbar_grid(n)] * 2 if n.fbar else []
    return out
