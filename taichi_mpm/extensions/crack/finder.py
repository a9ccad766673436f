"""CrackFinder: the finder's host side. It owns the fields, runs the per-step kernels before P2G (`update`), and
builds its kernels from the factories of this package (`build`), returning the hooks the solver's kernels call."""

import numpy as np

from .cells import bin_cells_kernel, cell_list_funcs
from .classify import classify_kernel
from .constants import ALL, KEEP
from .contact import contact_test_funcs
from .contact_lists import ContactPool, contact_list_kernel
from .context import crack_context
from .damage import damage_funcs
from .fields import CrackFields, particle_bytes
from .hooks import CrackHooks
from .inspection import partition_check_kernel
from .nodes import node_cache_kernels, node_normals_func
from .normals import particle_normal_funcs
from .shape_functions import shape_function_funcs
from .sim_view import view_of
from .sph import sph_funcs
from .state import get_state, set_state
from .tensor_grid import tensor_grid_kernels
from .transfer import transfer_funcs


class CrackFinder:
    def __init__(self, sim):
        self.view = view_of(sim)   # everything the finder reads of the Simulation
        self.cc = self.view.crack
        self.fields = CrackFields(self.view, self.cc)
        self.dim = self.fields.dim
        self.epoch = 0             # periods of kept normals (masks found in another belong to other normals)
        self.refreshes = 0         # steps that refreshed the kept normals (diagnostics, tests)
        self._cells_due = True     # the cell list must be built before the next step's searches
        self._list_due = True      # the contact lists too (with kept normals and contact)
        self.pool = ContactPool()  # the contact lists' pool
        self._k = {}               # kernels by name (build)

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
        return particle_bytes(self.dim, self.view.precision, f.apic, f.has_law, f.n_nodes, self.cc)

    def upload(self):
        f, view = self.fields, self.view
        f.d.from_numpy(view.to_solver(view.damage).astype(np.float64))
        f.iface.from_numpy(view.to_solver(view.interface).astype(np.float32))
        if f.kappa is not None:
            f.kappa.fill(0)

    def damage(self) -> np.ndarray:
        return self.view.to_creation(self.fields.d.to_numpy())

    def get_state(self) -> dict:
        return get_state(self)

    def set_state(self, state: dict):
        set_state(self, state)

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

    def build(self, kernel_ctx) -> CrackHooks:
        """Build the crack finder's funcs and kernels from the solver's kernel context (stencils.KernelContext):
        its stencil of (node, weight, gradient, offset) contributions, material funcs and wall conditions.
        Returns the hooks the solver calls (CrackHooks)."""
        ctx = crack_context(self.fields, self.view, self.cc, kernel_ctx)
        cells = cell_list_funcs(ctx)
        sph = sph_funcs(ctx, cells)
        damage = damage_funcs(ctx)
        normals = particle_normal_funcs(ctx, cells, sph)
        contact = contact_test_funcs(ctx, cells, sph)
        shape = shape_function_funcs(ctx)
        moves = transfer_funcs(ctx, shape)
        tensor = tensor_grid_kernels(ctx)
        node_cache = node_cache_kernels(ctx)
        classify = classify_kernel(ctx, normals, contact, node_normals_func(ctx, sph), damage.effective_stress)
        self._k = dict(prepare=damage.prepare, bin_cells=bin_cells_kernel(ctx, cells),
                       particle_normals=normals.particle_normals, contact_list=contact_list_kernel(ctx, cells),
                       classify=classify, grid_update=tensor.grid_update, grid_remap=tensor.grid_remap,
                       partition_check=partition_check_kernel(ctx, shape), node_cache_size=node_cache.size,
                       node_cache_read=node_cache.read, node_cache_write=node_cache.write)
        return CrackHooks(modified=shape.modified, degrade=damage.degrade, degrade_energy=damage.degrade_energy,
                          p2g=moves.p2g, p2g_momentum=moves.p2g_momentum, g2p=moves.g2p,
                          kernels={"grid_update_tensor": tensor.grid_update, "grid_remap_tensor": tensor.grid_remap})

    def partition_check(self) -> np.ndarray:
        """(N, 7) per particle in creation order: state, sum Nt, sum Nn, max|sum grad Nt|, max|sum grad Nn|,
        max|sum_i W_ip - I|, any node across. Runs the crack finder on the current state first."""
        self.update()
        out = np.zeros((self.view.n, 7), dtype=np.float64)
        self._k["partition_check"](out)
        return self.view.to_creation(out)
