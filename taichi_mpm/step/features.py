"""The features a scene uses, decided once from its config: the compile-time switches of the step's kernels.

Every kernel builder reads these attributes (tested with `ti.static`), so an option the scene does not use is not
compiled at all. Physics code only: no CLI, rendering or file I/O here.
"""

from dataclasses import dataclass

import numpy as np

from .. import schemes
from ..bases import registry as bases
from ..materials import MODELS


@dataclass(frozen=True)
class Features:
    apic: bool                  # an affine transfer (apic, mls, asflip, tpic): the C field holds B_p or C_p
    taylor: bool                # solver.transfer tpic: the affine C_p is the velocity gradient sum v_i grad w^T
    flip: bool                  # flip, xpic, asflip: the grid keeps v before forces (v_old)
    xpic: bool                  # solver.transfer xpic: v_p = S (v_L - v + v*), v* on three grid vectors more
    asflip: bool                # solver.transfer asflip: APIC plus a FLIP part and the position correction
    mls: bool                   # the force and grad v through w D_p^-1 r (schemes/gradient.py)
    polynomial: bool            # solver.transfer polypic: each particle's velocity polynomial (step/polynomial.py)
    musl: bool                  # solver.update musl: a second P2G of the new momentum (grid v2)
    usf: bool                   # solver.update usf: F and the stress from the velocities before forces
    store_grad_v: bool          # a C field: APIC's B_p or C_p, or grad v (viscosity)
    own_grad_v: bool            # viscosity with an affine transfer: grad v kept in a field of its own (grad_v),
                                # since APIC's C_p (B_p D_p^-1) is not the grid's gradient
    multi_material: bool        # a per-particle material index
    body_force: bool            # Simulation(body_force=...): a per-particle body acceleration
    domain_per_particle: bool   # particle domains of more than one size (gimp, cpdi): a per-particle half-width
    viscosity: bool             # a material with viscosity > 0 (its stress reads grad v)
    tractions: bool             # particle forces of bodies[].tractions
    grips: bool                 # bodies[].prescribed_velocity on the nodes the grip touches
    initial_stress: bool        # bodies[].stress, a stored stress added to the model's
    plastic: bool               # a return mapping after the F update
    small_node_fold: float = 0.0   # ddmp: nodes whose dual domain is filled below this fraction fold into a
    #                                neighbour (extensions/ddmp_fill.py); 0: off

    @property
    def old_grid(self) -> bool:
        """The grid keeps the momentum before forces (v_old): FLIP's kind of transfer reads it, ddmp's fold too."""
        return self.flip or self.small_node_fold > 0

    @classmethod
    def of(cls, cfg, scene, materials: list, body_force: bool) -> "Features":
        """The features of a scene: its config, particles (scene.Scene), material configs in slot order."""
        transfer = schemes.get(cfg.solver.transfer)   # its declaration (schemes/)
        viscosity = any(getattr(m, "viscosity", 0.0) > 0 for m in materials)
        return cls(
            apic=transfer.affine,
            taylor=transfer.taylor,
            flip=transfer.keeps_old_grid,
            mls=transfer.moment_gradient,
            polynomial=transfer.polynomial,
            xpic=transfer.extended,
            asflip=transfer.separating,
            musl=cfg.solver.update == "musl",
            usf=cfg.solver.update == "usf",
            store_grad_v=transfer.affine or viscosity,
            own_grad_v=transfer.affine and viscosity,
            multi_material=len(materials) > 1,
            body_force=body_force,
            domain_per_particle=bases.get(cfg.solver.basis).particle_domains and len(np.unique(scene.spacing)) > 1,
            viscosity=viscosity,
            tractions=bool(scene.loads),
            grips=bool(scene.grips),
            initial_stress=scene.stress is not None,
            plastic=any(MODELS[m.model].plastic for m in materials),
            small_node_fold=small_node_fold(cfg),
        )


def small_node_fold(cfg) -> float:
    """solver.ddmp.fold_below where the scene folds ddmp's small nodes, else 0: not with grips (a grip prescribes
    its own nodes' velocity), multi-field contact (its body fields are not folded) or xpic (its v* passes divide by
    the node masses the fold moves)."""
    s = cfg.solver
    if not bases.get(s.basis).prepass_grid or schemes.get(s.transfer).extended or cfg.contact is not None:
        return 0.0
    return 0.0 if any(b.prescribed_velocity for b in cfg.bodies) else float(s.ddmp.fold_below)
