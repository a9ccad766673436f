"""The probes' earlier import path, kept for the contract (`taichi_mpm.probes.read_probe`); the probes live in
`taichi_mpm.io.probes`."""
from .io.probes import read_probe

__all__ = ["read_probe"]
