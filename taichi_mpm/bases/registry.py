"""The bases registry: each basis is one declaration (`Spec`) of what it is and what it supports, registered by name.

Config validation, the solver's factories, budget, advise, the GUI's basis switch and the studies read these
declarations; none of them compares a basis name. No Taichi here (config validation imports this module): a
declaration names the factory of its shape functions by its dotted path, imported when a simulation is built
(or holds the callable itself, for a basis defined outside the package). docs/bases.md, "Adding a basis".
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable, Optional, Union

GRIDS = ("bspline", "ghost", "staggered")     # the node layouts of shape_functions.py (see Spec.grid)
STENCIL_KINDS = ("tensor", "corners", "staggered")   # how stencils.make_stencil builds a particle's contributions
# kinds whose stencil lies in a window of `stencil` storage nodes per axis from an origin (the coloured scatter's
# bound; cpdi's corners can reach any node)
BOUNDED_KINDS = ("tensor", "staggered")


@dataclass(frozen=True)
class Spec:
    name: str
    description: str            # one line, for docs and the config reference
    # shape_functions.Basis of this spec for a list of per-axis knot vectors (grid units) or None:
    # "module:function" (imported lazily) or the callable, called as factory(spec, knots)
    factory: Union[str, Callable]
    degree: int                 # polynomial degree of the 1D functions (B-splines: of their knot vectors)
    stencil: int                # nodes per axis a particle's stencil spans (budget, advise's work count, scatter)
    # "bspline": n + degree control points on an open knot vector, the first and last on the walls;
    # "ghost": nodes 0..n plus one ghost node beyond each wall; "staggered": two grids half a cell apart, stored on
    # one grid of half the spacing (compact_kernel.py)
    grid: str
    stencil_kind: str = "tensor"    # a tensor product of per-axis weights, or the corners of particle domains (cpdi)
    dims: tuple = (1, 2, 3)
    knots: bool = False         # takes domain.knots (a knot vector of `degree` per axis)
    map: bool = False           # is the basis of domain.map's mapped grid
    crack: Optional[str] = None     # why the crack finder refuses it (measured); None: the finder supports it
    # why solver.stress_difference refuses it (measured); None: its force gradient is its weights' derivative, whose
    # integral over a node's support the local stress difference takes from the walls' values
    stress_difference: Optional[str] = None
    fbar: bool = True           # takes solver.volumetric fbar
    fbar_linear_grid: bool = False  # F-bar averages on the linear grid, one degree below the velocity space
    particle_domains: bool = False  # each particle has a domain whose half-width comes from its spacing
    options: tuple = ()         # the solver keys read by this basis only (solver.gimp_domain, solver.cpdi,
                                # solver.quadrature: the B-splines' shape_functions.Basis.averaged_1d)
    prepass_grid: bool = False  # a scalar grid filled before P2G each step (ddmp's nodal volumes), in thread order
    cfl_factor: float = 1.0     # the dt rule's step is cfl_factor x solver.cfl x (the CFL step)
    accuracy: Optional[int] = None  # rank in the tools' sweeps (advise, the GUI's switch, the CFL table); None: unswept
    inversion_hint: str = ""    # what the particle-inversion error adds for this basis (empty: lower solver.cfl)
    nodes_per_cell: int = 1     # storage nodes per cell and axis (the staggered grids' half spacing: 2)

    def __post_init__(self):
        if self.grid not in GRIDS or self.stencil_kind not in STENCIL_KINDS:
            raise ValueError(f"basis {self.name}: grid must be one of {GRIDS} and stencil_kind one of "
                             f"{STENCIL_KINDS}, got {self.grid!r} and {self.stencil_kind!r}")
        if not (self.cfl_factor > 0 and self.stencil >= self.degree + 1):
            raise ValueError(f"basis {self.name}: cfl_factor must be positive and the stencil at least degree + 1")

    @property
    def coloured_scatter(self) -> bool:
        """P2G can add by colours: a tensor (or ck's staggered) stencil reaches a bounded box of nodes (cpdi's corners
        can reach any)."""
        return self.stencil_kind in BOUNDED_KINDS

    @property
    def regular_inertia(self) -> bool:
        """APIC's D_p = sum w r r^T is never singular: weights of degree above 1, hats averaged over particle
        domains, or ck's two staggered cells (multilinear weights alone make it singular on a node)."""
        return self.degree > 1 or self.particle_domains or self.stencil_kind == "staggered"

    @property
    def wall_layer(self) -> bool:
        """Particles on a face that holds material are transferred from inside it (stencils.WALL_LAYER): the
        tensor B-splines, whose first interior control point gets full gradient but no mass from a wall particle."""
        return self.grid == "bspline" and self.stencil_kind == "tensor"

    def nodes_per_particle(self, dim: int) -> int:
        """The (node, weight, gradient) contributions of one particle (shape_functions.Basis.contributions)."""
        if self.stencil_kind == "staggered":
            return 2 * 2 ** dim
        return 4 ** dim if self.stencil_kind == "corners" else self.stencil ** dim

    def build(self, knots=None):
        """The shape functions (shape_functions.Basis) of this basis; knots per axis in grid units, or None."""
        factory = self.factory
        if isinstance(factory, str):
            module, _, name = factory.partition(":")
            factory = getattr(importlib.import_module(module), name)
        return factory(self, knots)


_REGISTRY: dict[str, Spec] = {}
DEFAULT = "quadratic"   # the config's solver.basis when none is given


def register(spec: Spec) -> Spec:
    if spec.name in _REGISTRY:
        raise ValueError(f"basis {spec.name!r} is registered already")
    _REGISTRY[spec.name] = spec
    return spec


def unregister(name: str):
    if name in BUILT_IN:
        raise ValueError(f"basis {name!r} is built in")
    del _REGISTRY[name]


def get(name: str) -> Spec:
    return _REGISTRY[name]


def names(**where) -> tuple:
    """Registered names in registration order, optionally those whose declared attributes equal `where`."""
    return tuple(n for n, s in _REGISTRY.items() if all(getattr(s, k) == v for k, v in where.items()))


def swept() -> tuple:
    """The bases the tools sweep (advise, the GUI's basis switch, the CFL table), cheapest stencil first."""
    return tuple(sorted((n for n, s in _REGISTRY.items() if s.accuracy is not None),
                        key=lambda n: (_REGISTRY[n].stencil, _REGISTRY[n].accuracy)))


def listed(names_, last: str = "or") -> str:
    """'a, b or c': names in a message."""
    names_ = list(names_)
    return names_[0] if len(names_) == 1 else f"{', '.join(names_[:-1])} {last} {names_[-1]}"


_SF = "taichi_mpm.bases.shape_functions:"
_LINEAR_INVERSION = ("the linear basis inverts particles that cross a cell boundary under stress (the node they "
                     "enter has a tiny mass and a full weight gradient): use basis quadratic or gimp, or "
                     "solver.update: musl")
_DDMP_CRACK = ("two interface blocks pulled apart kept only 0.185 of their 0.2 m/s (measured; the finder's "
               "separation bound is 5 %)")
_DDMP_LSD = ("ddmp's blended gradient is not its weights' derivative: near a free surface (where its blend turns to "
             "linear's) its integral over a node's support is not what the correction assumes, and the 1D manufactured "
             "solution with free ends grew 3-13-fold in error with it (measured; docs/accuracy.md)")
_CORNERS_LSD = "cpdi's corner stencil has no per-axis functions to integrate a node's support from"

BUILT_IN = tuple(register(s).name for s in (
    Spec("linear", "linear B-splines (hat functions)", _SF + "make_bspline_basis", 1, 2, "bspline",
         knots=True, options=("quadrature",), accuracy=1, inversion_hint=_LINEAR_INVERSION),
    Spec("gimp", "uGIMP, the linear hats averaged over particle domains of the initial spacing", _SF + "make_gimp",
         1, 3, "ghost", particle_domains=True, options=("gimp_domain",), accuracy=2),
    Spec("quadratic", "quadratic B-splines on open knot vectors", _SF + "make_bspline_basis", 2, 3, "bspline",
         knots=True, options=("quadrature",), map=True, fbar_linear_grid=True, accuracy=3),
    Spec("cubic", "cubic B-splines on open knot vectors", _SF + "make_bspline_basis", 3, 4, "bspline",
         knots=True, options=("quadrature",), map=True, fbar_linear_grid=True, accuracy=4),
    Spec("cpdi", "CPDI1, the linear hats sampled at the corners of each particle's deformed domain", _SF + "make_cpdi",
         1, 3, "bspline", stencil_kind="corners", particle_domains=True, options=("cpdi",),
         stress_difference=_CORNERS_LSD,
         inversion_hint="the particle's CPDI domain (half-edges F r0) inverted: det F <= 0; fix: lower solver.cfl"),
    Spec("ddmp", "DDMP, linear weights with the gradient blended with its dual-domain average", _SF + "make_ddmp",
         1, 4, "ghost", crack=_DDMP_CRACK, prepass_grid=True, stress_difference=_DDMP_LSD,
         options=("ddmp",)),
    Spec("ck", "CK-MPM's compact kernel: the particle's cell on each of two grids staggered by half a cell",
         "taichi_mpm.bases.compact_kernel:make_compact", 1, 4, "staggered", stencil_kind="staggered",
         nodes_per_cell=2, fbar_linear_grid=True),
))
