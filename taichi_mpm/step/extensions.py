"""The step's extensions: the protocol (step.moments: `Extension`, its moments, `Setup`, the contributions) and the
ordered list of what plugs in. The solver creates the extensions of a scene from this list, in its order, and calls
their moments in that order; it knows none of them by name.

The list: the ddmp pre-pass (nodal volumes), the coloured scatter's binning, the mapped grid's parametric
coordinates (before F-bar: its average reads the mapped stencil), cpdi2's domain corners, polypic's particle
polynomials, the crack finder (before
F-bar: the average leaves out the particles the finder takes), F-bar's volume average, multi-field contact, the
local stress difference (its force correction is a node acceleration), the tractions (on particles, then on
nodes: a node acceleration), the walls and the grips
(their conditions close the grid solve's chain in that order). A new extension is one module with an `Extension`
subclass whose `create(setup)` returns it (or None where the scene does not use it), added here or, from outside
the package (a plug-in, a test), by `register` (docs/architecture.md, "Adding a step extension").

Physics code only: no CLI, rendering or file I/O here.
"""
from ..extensions.coloured_scatter import ColouredScatter
from ..extensions.contact import MultiField
from ..extensions.crack import CrackFinder
from ..extensions.ddmp_fill import DualDomainFill
from ..extensions.domain_corners import DomainCorners
from ..extensions.fbar_average import VolumeAverage
from ..extensions.grips import Grips
from ..extensions.mapped_coordinates import MappedCoordinates
from ..extensions.node_loads import NodeLoads
from ..extensions.polynomial_velocity import PolynomialVelocity
from ..extensions.stress_difference import StressDifference
from ..extensions.tractions import Tractions
from ..extensions.walls import Walls
from .moments import Degradation, Extension, ForceSums, GridSolve, NodeFields, ParticleTransfer, Setup

__all__ = ["ColouredScatter", "CrackFinder", "Degradation", "DomainCorners", "DualDomainFill", "Extension",
           "ForceSums", "GridSolve", "Grips", "MappedCoordinates", "MultiField", "NodeFields", "NodeLoads", "ORDER",
           "ParticleTransfer", "PolynomialVelocity", "Setup", "StressDifference", "Tractions", "VolumeAverage", "Walls",
           "create", "register", "unregister"]

# Extension classes, in the order their moments run
ORDER: list[type] = [DualDomainFill, ColouredScatter, MappedCoordinates, DomainCorners, PolynomialVelocity, CrackFinder,
                     VolumeAverage, MultiField, StressDifference, Tractions, NodeLoads, Walls, Grips]


def register(cls: type, before: type = None) -> type:
    """Add an Extension class to the list: at its end, or before `before`. Returns it (usable as a decorator)."""
    if cls in ORDER:
        raise ValueError(f"{cls.__name__} is registered already")
    ORDER.insert(ORDER.index(before) if before is not None else len(ORDER), cls)
    return cls


def unregister(cls: type):
    ORDER.remove(cls)


def create(setup: Setup) -> list:
    """The extensions a scene uses, in the list's order."""
    made = [cls.create(setup) for cls in ORDER]
    return [e for e in made if e is not None]


def adds_in_thread_order(cfg) -> bool:
    """Whether an extension of the scene sums in the threads' order (solver.thread_independent)."""
    return any(cls.adds_in_thread_order(cfg) for cls in ORDER)
