"""The grid update between the transfers, one chain every extension takes part in (step.moments.GridSolve): node
velocities from momenta (an extension may give its own: the crack finder's tensor node mass), gravity over the
leapfrog kick, the extensions' accelerations, wall conditions (grid.make_wall_condition) and grips
(bodies[].prescribed_velocity), then the extensions' own node fields (multi-field contact's body fields), MUSL's
remap under the same conditions; and the kernels that set this step's loads and motions (tractions' particle
forces, grip and velocity-wall velocities; loads.py evaluates their time functions).

Physics code only: no CLI, rendering or file I/O here.
"""

import taichi as ti


def make_gravity_kick(gravity, gravity_before):
    @ti.func
    def gravity_kick(kick_before, kick_after):
        """The velocity gravity adds over a kick: the gravity of the last step over its half, the current one
        over this step's half, so a set_gravity between steps acts from that instant (exact for a piecewise
        constant g)."""
        return kick_before * gravity_before[None] + kick_after * gravity[None]
    return gravity_kick


def make_grip_condition(ctx):
    """@ti.func (I, vel, m, measure: template) -> the node velocity with the grips' prescribed components."""
    dim, grid, has_grips = ctx.dim, ctx.grid, ctx.feat.grips
    grip_given, grip_v, grip_impulse, work = ctx.grip_given, ctx.grip_v, ctx.grip_impulse, ctx.work

    @ti.func
    def grip_condition(I, vel, m, measure: ti.template()):
        """bodies[].prescribed_velocity: a node touched by a gripped particle (flag_grip_nodes) takes the grip's
        prescribed components; measured: the impulse m dv goes to grip_impulse and m dv . v to the work."""
        if ti.static(has_grips):
            g = ti.cast(grid.vec["grip"][I][0], ti.i32)
            if g > 0:
                before = vel
                for k in ti.static(range(len(grip_given))):
                    if g == k + 1:
                        for c in ti.static(range(dim)):
                            if ti.static(grip_given[k][c]):
                                vel[c] = grip_v[k][c]
                        if ti.static(measure):
                            grip_impulse[k] += m * (vel - before)
                if ti.static(measure):
                    work[0][None] += m * (vel - before).dot(vel)
        return vel
    return grip_condition


def make_node_solve(ctx):
    """The first link of the grid solve: (has_mass(I, m, special), velocity(I, m, p, special)). The node velocity
    is m^-1 p, or where an extension gives its own (GridSolve.velocity: the crack finder's tensor node mass) and
    `special` (a compile-time switch: some extension's node_solve_active() this step), that one."""
    own = [g for g in ctx.grid_solve if g.velocity is not None]
    if len(own) > 1:
        raise ValueError("two extensions replace the grid's node solve: only one may")
    solve = own[0] if own else None
    has_solve = solve is not None

    @ti.func
    def has_mass(I, m, special: ti.template()):
        active = m > 0
        if ti.static(special and has_solve):
            active = solve.has_mass(I, m)
        return active

    @ti.func
    def velocity(I, m, p, special: ti.template()):
        if ti.static(special and has_solve):
            p = solve.velocity(I, m, p)
        else:
            p = p / m
        return p
    return has_mass, velocity


def make_accelerations(ctx):
    """@ti.func (I, vel, m, kick_before, kick_after) -> vel with every extension's GridSolve.accelerate, in order."""
    terms = [g.accelerate for g in ctx.grid_solve if g.accelerate is not None]

    @ti.func
    def accelerations(I, vel, m, kick_before, kick_after):
        for k in ti.static(range(len(terms))):
            vel = terms[k](I, vel, m, kick_before, kick_after)
        return vel
    return accelerations


def make_grid_update(ctx):
    """Kernels grid_update(kick_before, kick_after, special), grid_remap(special) (MUSL) and grid_velocity(special)
    (USF's first pass): the grid solve, one chain for every node and every extension (step.moments.GridSolve): node
    velocity from momentum, gravity, the extensions' accelerations, walls, grips; the remap and USF's first pass take
    the same chain without the forces (gravity, accelerations). special: some extension's node solve acts this
    step."""
    gm, gv, gv_old, gv2 = ctx.gm, ctx.gv, ctx.gv_old, ctx.gv2
    flip, wall, gravity_kick = ctx.feat.flip, ctx.wall, ctx.gravity_kick
    grip_condition = make_grip_condition(ctx)
    has_mass, node_velocity = make_node_solve(ctx)
    accelerations = make_accelerations(ctx)
    own_fields = [g.node_fields for g in ctx.grid_solve if g.node_fields is not None]

    @ti.kernel
    def grid_update(kick_before: float, kick_after: float, special: ti.template()):
        for I in ti.grouped(gm):
            m = gm[I]
            if has_mass(I, m, special):
                # always compiled, so that set_gravity can switch gravity on (adding 0 changes nothing)
                vel = node_velocity(I, m, gv[I], special) + gravity_kick(kick_before, kick_after)
                vel = accelerations(I, vel, m, kick_before, kick_after)
                vel = wall.measured(I, vel, m)  # adds m dv per face to wall_reaction (wall probes only)
                gv[I] = grip_condition(I, vel, m, measure=True)
                if ti.static(flip):
                    gv_old[I] = node_velocity(I, m, gv_old[I], special)
                for k in ti.static(range(len(own_fields))):   # the extensions' own node fields (multi-field contact)
                    own_fields[k](I, kick_before, kick_after)

    @ti.func
    def velocities(g: ti.template(), special: ti.template()):
        """The chain without forces, unmeasured (the step's measured update is grid_update): g = the node solve of
        the momentum g under the walls and grips."""
        for I in ti.grouped(gm):
            m = gm[I]
            if has_mass(I, m, special):
                g[I] = grip_condition(I, wall(I, node_velocity(I, m, g[I], special)), m, measure=False)

    @ti.kernel
    def grid_remap(special: ti.template()):
        """MUSL: the remapped momentum's velocities."""
        velocities(gv2, special)

    @ti.kernel
    def grid_velocity(special: ti.template()):
        """USF's first pass: the velocities before forces, from which it updates F and the stress."""
        velocities(gv, special)

    return dict(grid_update=grid_update, grid_remap=grid_remap, grid_velocity=grid_velocity)


def make_motion(ctx):
    """Kernels apply_loads(ramps), set_motion(values) and flag_grip_nodes()."""
    dim, grid, sten = ctx.dim, ctx.grid, ctx.stencil
    outer, inner = sten.outer, sten.inner
    load, load_slot, load_index, load_force = ctx.load, ctx.load_slot, ctx.load_index, ctx.load_force
    grip_slot, grip_index, grip_v, wall_v = ctx.grip_slot, ctx.grip_index, ctx.grip_v, ctx.wall_v
    has_grips, moving_walls = ctx.feat.grips, ctx.feat.moving_walls
    n_grip_rows = len(ctx.grip_given)

    @ti.kernel
    def apply_loads(ramps: ti.types.vector(max(ctx.n_loads, 1), float)):
        """Particle forces of the tractions: the sum of ramp x force at ramp 1 (one launch: the loops run in
        order)."""
        for p in load:
            load[p] = ti.Vector.zero(float, dim)
        for e in load_slot:
            load[load_slot[e]] += ramps[load_index[e]] * load_force[e]

    @ti.kernel
    def set_motion(values: ti.types.matrix(max(n_grip_rows + 2 * dim, 1), dim, float)):
        """This step's grip velocities (rows 0..K-1) and velocity-wall velocities (rows K.., per face slot)."""
        for _ in range(1):
            if ti.static(has_grips):
                for k in ti.static(range(n_grip_rows)):
                    for c in ti.static(range(dim)):
                        grip_v[k][c] = values[k, c]
            if ti.static(moving_walls):
                for slot in ti.static(range(2 * dim)):
                    for c in ti.static(range(dim)):
                        wall_v[slot][c] = values[n_grip_rows + slot, c]

    @ti.kernel
    def flag_grip_nodes():
        """Mark every node in the support (w > 0) of a gripped particle with its grip (the largest wins)."""
        for e in grip_slot:
            p = grip_slot[e]
            st = sten.at(p)
            for o in ti.grouped(ti.ndrange(*outer)):
              for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil, see `unroll`)
                I, w, gw, r = sten.node(st, o + inner[k])
                if w > 0:
                    ti.atomic_max(grid.vec["grip"][I][0], ti.cast(grip_index[e], float))

    return dict(apply_loads=apply_loads, set_motion=set_motion, flag_grip_nodes=flag_grip_nodes)
