"""Multi-velocity-field contact (Bardenhagen et al. 2000, "The material-point method for granular materials"), a
step extension (step.moments): one velocity field per body or group of bodies (`contact.bodies`) beside the grid's
own, which stays the centre-of-mass field.

P2G: every particle adds its mass, momentum (with the force impulse), FLIP's old momentum, its mass gradient m_p
grad w and its mass moment about the node w m_p (x_p - x_i) to its own field (NodeFields.scatter), as well as to the
grid's. Grid solve (GridSolve.node_fields, after the grid's own chain): each field's velocity v_k = p_k / m_k plus
gravity, under the walls and its own bodies' grips; where two or more fields share a node, with v_cm = sum m_k v_k /
sum m_k (a grip's prescribed components where a field at the node is gripped: a gripped body is an infinitely heavy
one) and the outward normal of field k

    n_k = g_k / |g_k| for the field of the heaviest bodies at the node (their total mass in the scene), else
    n_k = -g_rest / |g_rest|,    g_k = sum_p in k m_p grad w_ip,  g_rest = sum_(j != k) g_j

(grad w_ip is the weight's gradient in the particle's position, minus its gradient in the node's: g_k points out of
body k, down its node mass; one side's normal, the larger body's, as Nairn 2013 discusses beside the average of
both: at a block's corner pressed on a flat face the corner's own gradient tilts, and the block sliding along the
face would read its own motion as approach there; for two fields n_b = -n_a exactly, so the correction conserves
momentum), a field approaching the others ((v_k - v_cm) . n_k > 0) and touching them (the gap between its surface
and theirs along n_k, each placed from its particles' centroid at the node as if flat (surface.py), closes within
the step to under TOUCH cells; at a wall node n_k drops its components across the wall: grid's wall condition
.tangential) loses that normal velocity and, by Coulomb's law (friction.friction_loss, the walls' law), mu times it
of its tangential velocity relative to v_cm, not below zero (the fields then stick); a field moving away is left
free. The walls and grips act again after the correction. G2P reads each particle's own field (NodeFields.velocity).

The energy the correction removes is summed per step (sums.Slots): friction's, the tangential impulse's work at
the slip velocity it leaves, m_k loss . (v_t - loss) (zero where the fields stick: the velocity gravity gives a
resting block each step and the correction takes back is no dissipation of its particles), reported by
`dissipation()` to the energy balance; and the normal part (the node-level impact of approaching fields,
`impact_loss()`, not a particle-level balance term).

Physics code only: no CLI, rendering or file I/O here.
"""

import numpy as np
import taichi as ti

from ...friction import friction_loss
from ...step.moments import Extension, GridSolve, NodeFields
from ..grips import grip_setter
from ...sums import Slots
from .fields import ContactNeeds
from .surface import TOUCH, particle_half_width, surface_gap, surface_offset


class MultiField(Extension):
    """The contact section's multi_field method (docs/contact.md); created by the step's extension list."""

    name = "contact"
    breaks_bodies = True   # bodies in contact separate by design: no numerical-fracture check across them

    @classmethod
    def create(cls, setup):
        return cls(setup) if setup.cfg.contact is not None else None

    def __init__(self, setup):
        cfg = setup.cfg
        self.dim = setup.dim
        self.mu = float(cfg.contact.friction)
        self.field_of_body = np.asarray(cfg.contact_fields(), dtype=np.int32)
        self.needs = ContactNeeds.of(cfg)
        self.K = self.needs.n_fields
        # contact.friction_pairs: the coefficient between each pair of fields (a pair of bodies sets its two
        # bodies' fields'); None: contact.friction between all
        self.pair_mu = None
        if cfg.contact.friction_pairs:
            bodies, f = cfg.friction_table(cfg.contact), self.field_of_body
            self.pair_mu = np.full((self.K, self.K), self.mu)
            for a in range(len(f)):
                for b in range(len(f)):
                    if f[a] != f[b] and bodies[a, b] != self.mu:
                        self.pair_mu[f[a], f[b]] = bodies[a, b]
        # per field, the grips (indices from 0) of its bodies
        body_of_grip = [int(setup.scene.body[g.particles[0]]) for g in setup.scene.grips]
        self.grips = [[j for j, b in enumerate(body_of_grip) if self.field_of_body[b] == k] for k in range(self.K)]
        self._dissipated = np.zeros(2)   # friction, normal; before the last set_state
        # each field's rank by its bodies' mass (0: the heaviest; ties: the first field): whose normal a node takes
        mass = np.bincount(self.field_of_body[setup.scene.body], weights=setup.scene.mass, minlength=self.K)
        order = sorted(range(self.K), key=lambda k: (-mass[k], k))
        self.rank = [order.index(k) for k in range(self.K)]

    def allocate(self, setup):
        g = setup.grid
        self.m = [g.scalar[f"contact_m{k}"] for k in range(self.K)]
        self.p = [g.vec[f"contact_p{k}"] for k in range(self.K)]
        self.g = [g.vec[f"contact_g{k}"] for k in range(self.K)]
        self.x = [g.vec[f"contact_x{k}"] for k in range(self.K)]
        self.surface = surface_offset(setup.basis.spec.degree,
                                      particle_half_width(setup.basis.spec, setup.scene.spacing / setup.dx))
        self.o = [g.vec[f"contact_o{k}"] for k in range(self.K)] if self.needs.flip else None
        self.table = ti.field(ti.i32, len(self.field_of_body))   # body -> field
        self.slots = Slots(2)   # the energy the correction removed: friction, normal

    def upload(self):
        self.table.from_numpy(self.field_of_body)

    def _sums(self) -> np.ndarray:
        return self.slots.to_numpy() + self._dissipated

    def dissipation(self) -> dict:
        """J friction removed since the start (the grid kinetic energy its tangential correction took), for the
        energy balance."""
        return {"friction": float(self._sums()[0])}

    def impact_loss(self) -> float:
        """J the normal correction removed from the grid's kinetic energy since the start: the node-level
        inelastic impact of approaching fields. Not a term of the particles' energy balance: the next P2G gives the
        fields their particles' velocities again, so a node's relative velocity is counted anew each step while
        the particles lose less (docs/contact.md)."""
        return float(self._sums()[1])

    def get_state(self) -> dict:
        return {"contact_dissipated": self._sums()}

    def check_state(self, state: dict):
        v = state.get("contact_dissipated")
        if v is not None and np.shape(v) != (2,):
            raise ValueError(f"state['contact_dissipated'] must hold 2 numbers, got shape {np.shape(v)}")

    def set_state(self, state: dict):
        v = state.get("contact_dissipated")
        self.slots.from_numpy(np.zeros(2))
        self._dissipated = np.zeros(2) if v is None else np.asarray(v, dtype=np.float64)

    def build(self, ctx):
        if ctx.body_id is None:
            raise ValueError("multi_field contact needs the body index of a scene with two bodies or more")
        scatter, velocity, velocity_old = self._transfer_funcs(ctx)
        ctx.contribute("node_fields", NodeFields(scatter=scatter, velocity=velocity, velocity_old=velocity_old))
        ctx.grid_solve.append(GridSolve(node_fields=self._node_solve(ctx)))

    def _transfer_funcs(self, ctx):
        K, flip, add = self.K, self.needs.flip, ctx.add
        body_id, table, m, p, g, o, xf = ctx.body_id, self.table, self.m, self.p, self.g, self.o, self.x

        @ti.func
        def scatter(q, I, w, gw, r, mp, momentum, momentum_old):
            k = table[body_id[q]]
            for j in ti.static(range(K)):
                if k == j:
                    add(m[j], I, w * mp)
                    add(p[j], I, momentum)
                    add(g[j], I, mp * gw)
                    add(xf[j], I, -w * mp * r)   # the centroid's moment about the node
                    if ti.static(flip):
                        add(o[j], I, momentum_old)

        def reader(fields):
            @ti.func
            def read(q, I):
                k = table[body_id[q]]
                out = ti.Vector.zero(float, ctx.dim)
                for j in ti.static(range(K)):
                    if k == j:
                        out = fields[j][I]
                return out
            return read

        return scatter, reader(p), reader(o) if flip else None

    def _grip_func(self, ctx):
        """@ti.func (I, vel, k: template) -> vel with the prescribed components of field k's own grips."""
        dim, grips, has_grips = self.dim, self.grips, ctx.feat.grips
        grid, grip_given, grip_v = ctx.grid, ctx.extra.get("grip_given", []), ctx.extra.get("grip_v")   # Grips

        setters = [grip_setter(dim, grip_given, grip_v, grips[k]) for k in range(self.K)]

        @ti.func
        def grip(I, vel, k: ti.template()):
            held = ti.Vector.zero(float, dim)   # 1 for the components a grip prescribes
            if ti.static(has_grips and len(grips[k]) > 0):
                vel, held = ti.static(setters[k])(ti.cast(grid.vec["grip"][I][0], ti.i32), vel)
            return vel, held
        return grip

    def _coefficient_func(self):
        """@ti.func (I, k: template) -> field k's Coulomb coefficient at node I: contact.friction, or with
        friction_pairs the pair's of k and the heaviest other field there."""
        K, mu, table, m = self.K, self.mu, self.pair_mu, self.m
        by_pair = table is not None

        @ti.func
        def coefficient(I, k: ti.template()):
            res = ti.cast(mu, float)
            if ti.static(by_pair):
                heaviest = 0.0
                for j in ti.static(range(K)):
                    if ti.static(j != k):
                        if m[j][I] > heaviest:
                            heaviest = m[j][I]
                            # (an expression: a Python constant assigned in a branch would be bound at compile
                            # time, whichever branch runs)
                            res = ti.cast(float(table[k][j]), float)
            return res
        return coefficient

    def _node_solve(self, ctx):
        dim, K, flip = self.dim, self.K, self.needs.flip
        friction = (self.mu if self.pair_mu is None else float(self.pair_mu.max())) > 0   # compiled in or not
        coefficient = self._coefficient_func()
        m, p, g, o, slots, rank = self.m, self.p, self.g, self.o, self.slots, self.rank
        xf, surface, inv_dx = self.x, self.surface, 1.0 / ctx.dx
        wall, gravity_kick, grip = ctx.wall, ctx.gravity_kick, self._grip_func(ctx)

        @ti.func
        def conditions(I, vel, k: ti.template()):
            """The walls and field k's grips: (vel, the components a grip holds)."""
            return grip(I, wall(I, vel), k)

        gap_between = surface_gap(surface, inv_dx)

        @ti.func
        def gap(I, k: ti.template(), n, mass, x_all):
            """Cells between field k's surface and the others' along n (< 0: overlap)."""
            mk = m[k][I]
            return gap_between(n, xf[k][I], mk, x_all - xf[k][I], mass - mk)

        @ti.func
        def correct(I, k: ti.template(), v_cm, g_all, first, mass, x_all, dt, held):
            """Field k's contact correction against the centre of mass; returns the energy it removed (friction,
            normal)."""
            mk = m[k][I]
            n = g[k][I]   # outward of field k: its own mass gradient where it is the heaviest body there, else
            if ti.static(rank[k]) != first:   # minus the others' (inward of them)
                n -= g_all
            n = wall.tangential(I, n)   # bodies flush with a wall: their gradient across it is no contact surface
            size = n.norm()
            lost = ti.Vector.zero(float, 2)
            if size > 0:
                n /= size
                v = p[k][I]
                rel = v - v_cm
                into = rel.dot(n)
                # the others' approach (into is against v_cm; a gripped field is infinitely heavy)
                closing = into * ti.select(held, 1.0, mass / (mass - mk))
                # approaching the others and touching them by the end of the step (Nairn's displacement check,
                # with the surfaces from the centroids): compressive contact. Without the gap, a field sharing nodes
                # with another a stencil away was stopped there: a rolling disk's front was held (docs/contact.md)
                if into > 0 and gap(I, k, n, mass, x_all) - dt * closing * inv_dx < TOUCH:
                    e0 = v.norm_sqr()
                    v -= into * n
                    lost[1] = 0.5 * mk * (e0 - v.norm_sqr())
                    if ti.static(friction and dim > 1):
                        slip = rel - into * n
                        loss = friction_loss(slip, into, coefficient(I, k))
                        v -= loss
                        # the friction impulse's work at the slip it leaves (none where the fields stick)
                        lost[0] = mk * loss.dot(slip - loss)
                    p[k][I], _ = conditions(I, v, k)
            return lost

        @ti.func
        def node_fields(I, kick_before, kick_after):
            kick_g = gravity_kick(kick_before, kick_after)
            mass, momentum, g_all = 0.0, ti.Vector.zero(float, dim), ti.Vector.zero(float, dim)
            x_all = ti.Vector.zero(float, dim)
            present, first = 0, K   # the fields at the node, the heaviest one's rank
            gripped, grip_v = ti.Vector.zero(float, dim), ti.Vector.zero(float, dim)   # a grip's components
            for k in ti.static(range(K)):
                mk = m[k][I]
                if mk > 0:
                    v, held = conditions(I, p[k][I] / mk + kick_g, k)
                    p[k][I] = v
                    grip_v = ti.select(held > 0, v, grip_v)
                    gripped = ti.max(gripped, held)
                    if ti.static(flip):
                        o[k][I] = o[k][I] / mk
                    mass += mk
                    momentum += mk * v
                    g_all += g[k][I]
                    x_all += xf[k][I]
                    present += 1
                    first = ti.min(first, ti.static(rank[k]))
            if present > 1:
                # a gripped field moves as if infinitely heavy: the centre of mass takes its prescribed components
                v_cm = ti.select(gripped > 0, grip_v, momentum / mass)
                lost = ti.Vector.zero(float, 2)
                for k in ti.static(range(K)):
                    if m[k][I] > 0:
                        lost += correct(I, k, v_cm, g_all, first, mass, x_all, 2.0 * kick_after,   # this step's dt
                                        gripped.max() > 0)
                slots[0][None] += lost[0]
                slots[1][None] += lost[1]
        return node_fields
