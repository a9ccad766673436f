"""The transfer-scheme registry (issue 28): one module per particle-grid transfer, each registering a `Scheme` that
declares its name, its config parameters, the bases it works with, its cost and the @ti.func pieces it adds to
P2G and G2P. The step's kernels (step/transfers.py, step/affine.py) are written once and compose these pieces
under `ti.static`, so a scheme never copies a kernel.

Config validation reads the declarations (names, bases, parameters) without Taichi; the pieces are factories the
kernel builders call with their context. Physics and config both import this module: it imports neither (only
the bases' declarations, bases/registry.py, which a scheme's basis_need reads).
"""
from .base import SCHEMES, Scheme, bases_for, get, names, register, works_with
from . import pic, flip, apic, mls, xpic, asflip, tpic, polypic  # noqa: E402,F401  (each module registers its scheme, in this order)

__all__ = ["SCHEMES", "Scheme", "bases_for", "get", "names", "register", "works_with"]
