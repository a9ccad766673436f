"""Crack finder: cracks and body interfaces inside one velocity field (seed talk, Part II).

Per step, before P2G (`CrackFinder.update`: kernels prepare, particle_normals, classify; at a refresh of the kept
normals also bin_cells and contact_list; details and reasons in docs/crack_finder.md):
  1. damage law (Rankine, materials.py) updates d_p; D_p = max(d_p, I_p) (I_p: interface flag);
     a cell list (cells of r/2, r = SPH support radius) bins the particles: counting sort, linear in N.
  2. particles whose neighbourhood holds varying D get the Shepard-normalised SPH gradient of D;
     a particle is *near* a discontinuity when D_p >= damage_threshold or |grad D_p| r >= gradient_threshold.
     Its normal is n_p = grad D_p / |grad D_p|, and it marks the grid nodes of its stencil.
  3. a damaged particle without a gradient (middle of an odd-width band) takes its neighbours' normal.
  4. marked nodes y_g get grad D(y_g) from the same SPH sums.
  5. per near particle and stencil node: across when n_p . n_g < -threshold, or when the node lies on
     the discontinuity itself (|grad D(y_g)| r < gradient_threshold with D(y_g) >= damage_threshold).
     The tangential functions drop nodes across; the normal ones keep them while the particle is in
     contact (trial normal traction n.sigma.n + rho c v_close < 0). Both families are rescaled to a
     partition of unity; their sums are stored per particle so P2G/G2P modify weights node by node.

Direction-dependent coupling: particle p couples to node i through the tensor
  W_ip = Nt_ip (I - n n^T) + Nn_ip n n^T        (Nt, Nn: rescaled tangential / normal functions)
so the node mass becomes a tensor M_i = sum_p m_p W_ip = m_i I + A_i (m_i scalar as usual; A_i from
particles in contact) and v_i = M_i^+ p_i. Linear momentum is conserved (docs/crack_finder.md).

Only created when the config has a `crack` section (`CrackFinder.create`, in the step's extension list,
step/extensions.py): a scene without one allocates and compiles nothing here.

Modules, one job each:
  view            what the finder reads of the extension setup (step.moments.Setup), gathered (view_of)
  fields          the finder's fields, its node fields in the solver's grid, bytes per particle (budget.py)
  context         what the kernel factories receive (CrackContext): fields, view, solver funcs, shared constants
  cells           the cell list (bin_cells) and its row searches
  sph             the cubic spline kernel and the Shepard-normalised SPH value and gradient of D
  damage          the Rankine damage law (prepare) and the degraded stress and energy
  normals         particle normals (kept between refreshes) and band middles' normals
  nodes           node normals and the node cache
  contact         the contact test's closing speed and impedance
  contact_lists   the contact lists and their pool
  classify        masks, family sums and the contact test per near particle (classify)
  shape_functions the modified (tangential / normal) functions node by node
  transfer        P2G / G2P of a particle near a discontinuity
  tensor_grid     the tensor node mass as the grid solve's node solve (step.moments.GridSolve)
  inspection      the partition-of-unity check (tests)
  state           the finder's part of a checkpoint
  finder          CrackFinder: the step extension (its moments), per-step driver, the composition of the kernels
"""

from .constants import CONTACT, MODIFIED, STANDARD
from .fields import grid_fields, particle_bytes
from .finder import CrackFinder

__all__ = ["CONTACT", "CrackFinder", "MODIFIED", "STANDARD", "grid_fields", "particle_bytes"]
