"""What the step's kernel builders receive: the shared kernel context (stencil_parts.KernelContext: constants, particle
and grid fields, the stencil) plus the fields only the solver's own kernels touch (material state, runtime
parameters, the tractions' particle forces, accumulators, diagnostics sums) and the extensions' contributions.
Built once by `Simulation._build_kernels`.

Physics code only: no CLI, rendering or file I/O here.
"""

from dataclasses import dataclass, field
from typing import Any, Optional

from ..bases.stencil_parts import KernelContext


@dataclass
class StepContext(KernelContext):
    materials: list = None           # each material slot's Taichi funcs (materials.base.Funcs), parameters baked in
    n_state: int = 1                 # length of a particle's material state vector (>= 1: a dummy without state)
    state: Any = None                # per-particle material state (plastic strain, J_p, ...) or None
    stress0: Any = None              # bodies[].stress: the stored 2nd Piola-Kirchhoff stress, or None
    body_acc: Any = None             # Simulation(body_force=...): per-particle body acceleration, or None
    grad_v: Any = None               # the last step's grid velocity gradient (viscosity with an affine transfer)
    # runtime parameters, read by the kernels (set_gravity, set_stiffness_scale, set_flip_blend)
    gravity: Any = None
    gravity_before: Any = None       # the last step's gravity (see gravity_kick)
    stiffness: Any = None            # per material slot
    flip_blend: Any = None
    asflip: tuple = (1.0, 0.0, 1.0)  # solver.asflip: FLIP part a, position correction b compressed, b otherwise
    # accumulators: work[0] external work, work[1] viscous, work[2] plastic dissipation (sums.Slots)
    work: Any = None
    fail: Any = None                 # smallest solver slot * codes + cause of a failed particle
    vmax2: Any = None                # largest squared particle speed of the step
    status: Any = None               # host_scalars.StepStatus: fail and vmax2's clear() and values() @ti.funcs
    fail_codes: int = 8
    load: Any = None                 # the per-particle external force (extensions/tractions.py writes it)
    # diagnostics
    diag: Any = None                 # sums.ChunkSums for energies and momenta
    moments: Any = None              # sums.ChunkSums per body (fracture check)
    body_id: Any = None
    bins: Any = None                 # scatter.BlockBins: the coloured P2G, or None
    project: Any = None              # @ti.func (p, F) -> F after the return mapping (step.materials)
    # what extensions contribute in their build moment (step.moments), read by the solver's kernel builders
    project_after_g2p: bool = False  # an extension runs the return mappings after G2P (F-bar's average)
    particle_transfer: Optional[Any] = None   # step.moments.ParticleTransfer: one extension's, or None
    degradation: Optional[Any] = None         # step.moments.Degradation, or None
    node_fields: Optional[Any] = None         # step.moments.NodeFields, or None
    force_sums: Optional[Any] = None          # step.moments.ForceSums, or None
    grid_solve: list = field(default_factory=list)   # step.moments.GridSolve parts, in the extensions' order

    def contribute(self, name: str, value):
        """Set a contribution only one extension may make (particle_transfer, degradation, node_fields,
        force_sums)."""
        if getattr(self, name) is not None:
            raise ValueError(f"two extensions contribute {name}: only one may")
        setattr(self, name, value)
