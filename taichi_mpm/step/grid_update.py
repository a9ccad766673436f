"""The grid update between the transfers, one chain every extension takes part in (step.moments.GridSolve): node
velocities from momenta (an extension may give its own: the crack finder's tensor node mass), gravity over the
leapfrog kick, the extensions' accelerations, then their boundary conditions (the walls', extensions/walls.py,
then the grips', extensions/grips.py), then the extensions' own node fields (multi-field contact's body fields);
MUSL's remap and USF's first pass under the same conditions.

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


def make_conditions(ctx):
    """@ti.func (I, vel, m, measure: template) -> vel under every extension's GridSolve.condition, in order (the
    walls, then the grips)."""
    terms = [g.condition for g in ctx.grid_solve if g.condition is not None]

    @ti.func
    def conditions(I, vel, m, measure: ti.template()):
        for k in ti.static(range(len(terms))):
            vel = terms[k](I, vel, m, measure)
        return vel
    return conditions


def make_grid_update(ctx):
    """Kernels grid_update(kick_before, kick_after, special), grid_remap(special) (MUSL) and grid_velocity(special)
    (USF's first pass): the grid solve, one chain for every node and every extension (step.moments.GridSolve): node
    velocity from momentum, gravity, the extensions' accelerations, their conditions (walls, grips); the remap and
    USF's first pass take the same chain without the forces (gravity, accelerations). special: some extension's
    node solve acts this step."""
    gm, gv, gv_old, gv2 = ctx.gm, ctx.gv, ctx.gv_old, ctx.gv2
    flip, gravity_kick = ctx.feat.flip, ctx.gravity_kick
    conditions = make_conditions(ctx)
    has_mass, node_velocity = make_node_solve(ctx)
    accelerations = make_accelerations(ctx)
    own_fields = [g.node_fields for g in ctx.grid_solve if g.node_fields is not None]
    images = [g.images for g in ctx.grid_solve if g.images is not None]
    if len(images) > 1:
        raise ValueError("two extensions fold ghost nodes: only one may")

    own_solve = any(g.velocity is not None for g in ctx.grid_solve)
    # the step's failure flag and speed maximum are reset for G2P at the end of the grid update (one launch fewer a
    # step; docs/performance.md, "Fixed costs of a step"), except under USF, whose first pass resets them earlier
    clears, clear_status = not ctx.feat.usf, ctx.status.clear
    mirrors = bool(images) and images[0][1] is not None

    @ti.func
    def folded(g: ti.template(), gkick, measure: ti.template(), special: ti.template()):
        """Ghost nodes' sums into their image nodes (ck's walls), before the chain: FLIP's old momenta first, while
        the momentum still tells a slip face's ghosts whether the material moves into it, then the momentum and
        the mass (once: a folded ghost has none left, so a second pass adds only its new momentum). gkick: the
        gravity the chain then adds per unit mass; measure: the step's update (wall probes). Not on a step where an
        extension solves the nodes itself (the crack finder's tensor node mass has rows of its own, which the fold
        does not move): B's ghosts then keep the node-wise wall conditions."""
        if ti.static(images and not (special and own_solve)):
            if ti.static(flip and measure):
                images[0][0](gm, g, gv_old, False, gkick, False)
            images[0][0](gm, g, g, True, gkick, measure)

    @ti.func
    def mirrored(g: ti.template(), measure: ti.template()):
        """Ghost nodes from their image nodes, once every node has its velocity (a loop of its own); FLIP's old
        velocities in the step's update, where they were folded."""
        if ti.static(mirrors):
            images[0][1](gm, g)
            if ti.static(flip and measure):
                images[0][1](gm, gv_old)

    @ti.kernel
    def grid_update(kick_before: float, kick_after: float, special: ti.template()):
        folded(gv, gravity_kick(kick_before, kick_after), True, special)
        for I in ti.grouped(gm):
            m = gm[I]
            if has_mass(I, m, special):
                # always compiled, so that set_gravity can switch gravity on (adding 0 changes nothing)
                vel = node_velocity(I, m, gv[I], special) + gravity_kick(kick_before, kick_after)
                vel = accelerations(I, vel, m, kick_before, kick_after)
                gv[I] = conditions(I, vel, m, True)   # measured: reactions and work
                if ti.static(flip):
                    gv_old[I] = node_velocity(I, m, gv_old[I], special)
                for k in ti.static(range(len(own_fields))):   # the extensions' own node fields (multi-field contact)
                    own_fields[k](I, kick_before, kick_after)
        mirrored(gv, True)
        if ti.static(clears):
            clear_status()

    @ti.func
    def velocities(g: ti.template(), special: ti.template()):
        """The chain without forces, unmeasured (the step's measured update is grid_update): g = the node solve of
        the momentum g under the walls and grips."""
        folded(g, ti.Vector.zero(float, ctx.dim), False, special)
        for I in ti.grouped(gm):
            m = gm[I]
            if has_mass(I, m, special):
                g[I] = conditions(I, node_velocity(I, m, g[I], special), m, False)
        mirrored(g, False)

    @ti.kernel
    def grid_remap(special: ti.template()):
        """MUSL: the remapped momentum's velocities."""
        velocities(gv2, special)

    @ti.kernel
    def grid_velocity(special: ti.template()):
        """USF's first pass: the velocities before forces, from which it updates F and the stress."""
        velocities(gv, special)

    return dict(grid_update=grid_update, grid_remap=grid_remap, grid_velocity=grid_velocity)
