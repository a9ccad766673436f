"""CrackFinder: the finder's host side, a step extension (step.moments.Extension). It owns the fields, runs the
per-step kernels before P2G (`update`), builds its kernels from the factories of this package (`build`) and hands
the solver's kernels its contributions through the step context: the modified transfers of particles near a
discontinuity (ParticleTransfer), the damaged stress and energy (Degradation) and the tensor node mass as the grid
solve's node solve on steps with contact (GridSolve)."""

import numpy as np

from ...field_decl import nbytes
from ...sums import Slots

from .cells import bin_cells_kernel, cell_list_funcs
from .classify import classify_kernel
from .constants import ALL, KEEP
from .contact import contact_test_funcs
from .contact_lists import ContactPool, contact_list_kernel
from .context import crack_context
from .damage import damage_funcs
from .fields import CrackFields, interface_sides
from .inspection import partition_check_kernel
from .nodes import node_cache_kernels, node_normals_func
from .normals import particle_normal_funcs
from .shape_functions import shape_function_funcs
from .sph import sph_funcs
from .state import check_state, get_state, set_state
from .tensor_grid import tensor_grid_solve
from .transfer import transfer_funcs
from .view import view_of
from ...step.moments import Degradation, Extension, NodeFields, ParticleTransfer


class CrackFinder(Extension):
    """The crack section's finder (docs/crack_finder.md); created by the step's extension list (`create`)."""

    name = "crack"
    breaks_bodies = True   # bodies separate along cracks by design: no numerical-fracture check

    @classmethod
    def adds_in_thread_order(cls, cfg) -> bool:
        return cfg.crack is not None   # its node sums

    @classmethod
    def create(cls, setup):
        return cls(setup) if setup.cfg.crack is not None else None

    def __init__(self, setup):
        self.dim = setup.dim
        self.cc = setup.cfg.crack
        # crack.friction_pairs: the coefficients between interface bodies, by their sides (fields.interface_sides)
        iface = [i for i, side in enumerate(interface_sides(setup.cfg.bodies)) if side >= 0]
        self.pair_mu = (setup.cfg.friction_table(self.cc)[np.ix_(iface, iface)] if self.cc.friction_pairs
                        else None)
        self.epoch = 0             # periods of kept normals (masks found in another belong to other normals)
        self.refreshes = 0         # steps that refreshed the kept normals (diagnostics, tests)
        self._cells_due = True     # the cell list must be built before the next step's searches
        self._list_due = True      # the contact lists too (with kept normals and contact)
        self.pool = ContactPool()  # the contact lists' pool
        self._k = {}               # kernels by name (build)

    # ------------------------------------------------------------------ the step's moments
    def allocate(self, setup):
        self.view = view_of(setup)   # everything the finder reads of the scene and the solver's fields
        self.fields = CrackFields(self.view, self.cc)
        # the energy friction dissipated (crack.friction): this run's sum, and what a state set before it held
        self.friction_lost = Slots(1) if self.fields.needs.friction else None
        self._friction_before = 0.0

    def before_p2g(self):
        self.update()

    def node_solve_active(self) -> bool:
        return self.in_contact()

    def particles_set(self, names: set):
        if "x" in names:
            self.invalidate()   # its normals kept between steps belong to the old positions

    def outputs(self) -> dict:
        return {"damage": self.damage()}

    def dissipation(self) -> dict:
        """J friction dissipated since the start (crack.friction), for the energy balance."""
        if self.friction_lost is None:
            return {}
        return {"friction": float(self.friction_lost.to_numpy()[0]) + self._friction_before}

    def get_state(self) -> dict:
        state = get_state(self)
        if self.friction_lost is not None:
            state["crack_friction_dissipated"] = self.dissipation()["friction"]
        return state

    def check_state(self, state: dict):
        check_state(self, state)

    def set_state(self, state: dict):
        set_state(self, state)
        if self.friction_lost is not None:
            self.friction_lost.from_numpy(np.zeros(1))
            self._friction_before = float(state.get("crack_friction_dissipated", 0.0))

    # what tests, probes and benchmarks inspect
    @property
    def radius(self) -> float:
        return self.fields.radius

    @property
    def cached(self) -> bool:
        return self.fields.cached

    @property
    def listed(self) -> bool:
        return self.fields.listed

    @property
    def D(self):
        return self.fields.D

    @property
    def normal(self):
        return self.fields.normal

    @property
    def state(self):
        return self.fields.state

    @property
    def recomputed(self):
        return self.fields.recomputed

    def bytes_per_particle(self) -> int:
        f = self.fields
        return nbytes(f.needs.particle_fields(self.dim), self.view.precision)

    def upload(self):
        f, view = self.fields, self.view
        f.d.from_numpy(view.to_solver(view.damage).astype(np.float64))
        f.iface.from_numpy(view.to_solver(view.interface).astype(np.float32))
        if f.side is not None:
            f.side.from_numpy(view.to_solver(view.side).astype(np.int32))
        if f.kappa is not None:
            f.kappa.fill(0)

    def damage(self) -> np.ndarray:
        return self.view.to_creation(self.fields.d.to_numpy())

    def invalidate(self):
        """Recompute the normals at the next step (particles were set from outside)."""
        if self.cached:
            self.fields.stale[None] = ALL
            self._list_due = self._cells_due = True
            self.epoch += 1   # masks found before belong to other normals

    def update(self):
        """The crack finder's per-step work, before P2G."""
        self._k["prepare"]()
        level = ALL
        if self.cached:
            level = int(self.fields.stale[None])   # prepare raised it if a particle moved too far or D grew
            if level != KEEP:
                self.fields.node_cache.clear()     # node normals are recomputed with the particles'
                self.refreshes += 1
                self.epoch += 1
        fresh = level != KEEP
        if fresh or self._cells_due:   # between refreshes: rebuilt as it was at the last one (after set_state)
            self._k["bin_cells"](int(not fresh))
            self._cells_due = False
        self._k["particle_normals"](level)
        if self.cached:
            if fresh:
                self.fields.stale[None] = KEEP
            if self.listed and (fresh or self._list_due):
                self.pool.build(self._k["contact_list"])
                self._list_due = False
        self._k["classify"](self.epoch, self.pool.ids)

    def in_contact(self) -> bool:
        """Whether a particle is in contact this step (after `update`): only then is a node mass a tensor."""
        return self.cc.contact_in_compression and self.fields.contacts[None] > 0

    def contact_lists(self) -> list:
        """Per particle in creation order: the creation indices its contact test sums over until the next refresh,
        or None where it searches each step (inspection, tests)."""
        count, start = self.fields.contact_count.to_numpy(), self.fields.contact_start.to_numpy()
        ids, perm = self.pool.ids.to_numpy(), self.view.perm()
        lists = [None if k < 0 else perm[ids[s:s + k]] for k, s in zip(count, start)]
        return [lists[slot] for slot in np.argsort(perm)]

    def build(self, kernel_ctx):
        """Build the crack finder's funcs and kernels from the step context (step.StepContext): its stencil of
        (node, weight, gradient, offset) contributions and material funcs; add its contributions to it."""
        ctx = crack_context(self.fields, self.view, self.cc, kernel_ctx, self.friction_lost, self.pair_mu)
        cells = cell_list_funcs(ctx)
        sph = sph_funcs(ctx, cells)
        damage = damage_funcs(ctx)
        normals = particle_normal_funcs(ctx, cells, sph)
        contact = contact_test_funcs(ctx, cells, sph)
        shape = shape_function_funcs(ctx)
        moves = transfer_funcs(ctx, shape)
        node_cache = node_cache_kernels(ctx)
        classify = classify_kernel(ctx, normals, contact, node_normals_func(ctx, sph), damage.effective_stress)
        self._k = dict(prepare=damage.prepare, bin_cells=bin_cells_kernel(ctx, cells),
                       particle_normals=normals.particle_normals, contact_list=contact_list_kernel(ctx, cells),
                       classify=classify, partition_check=partition_check_kernel(ctx, shape),
                       node_cache_size=node_cache.size, node_cache_read=node_cache.read,
                       node_cache_write=node_cache.write)
        kernel_ctx.contribute("particle_transfer", ParticleTransfer(
            takes=shape.modified, p2g=moves.p2g, p2g_momentum=moves.p2g_momentum, g2p=moves.g2p,
            own_side=shape.own_side, second_field=moves.second_field))
        if moves.standard_moment is not None:   # with friction: the node's own field's mass moment (its gap)
            kernel_ctx.contribute("node_fields", NodeFields(scatter=moves.standard_moment))
        kernel_ctx.contribute("degradation", Degradation(stress=damage.degrade, energy=damage.degrade_energy))
        kernel_ctx.grid_solve.append(tensor_grid_solve(ctx))   # the tensor node mass, on steps with contact

    def partition_check(self) -> np.ndarray:
        """(N, 7) per particle in creation order: state, sum Nt, sum Nn, max|sum grad Nt|, max|sum grad Nn|,
        max|sum_i W_ip - I|, any node across. Runs the crack finder on the current state first."""
        self.update()
        out = np.zeros((self.view.n, 7), dtype=np.float64)
        self._k["partition_check"](out)
        return self.view.to_creation(out)
