"""The MPM solver: particle fields, and one kernel per phase (P2G, grid update, G2P).

Every option a scene does not use is left out when the kernels are built: the dimension, basis,
transfer, update scheme, material models and features (body force, viscosity, crack finder) are
compile-time constants captured by the kernel closures and tested with `ti.static`.

One step (USL):   clear grid -> P2G (mass, momentum, stress force) -> grid update (gravity, walls)
                  -> G2P (velocity by transfer, positions, F, checks)
MUSL adds, after the G2P velocity update, a second P2G of the new particle momentum, whose grid
velocities give the velocity gradient for F (Sulsky et al. 1995; Nairn 2003).

Physics code only: no CLI, rendering or file I/O here.
"""

import itertools
import math
from typing import Callable, Optional

import numpy as np
import taichi as ti

from .basis import make_basis
from .config import Config, ConfigError, load_config
from . import crack as crack_finder
from .errors import InstabilityError
from .grid import Grid, make_wall_condition
from .materials import MODELS, embed3, wave_speed
from .scene import Scene, build_scene

FAIL_CAUSES = {1: "inverted or collapsed particle (J <= 0)",
               2: "non-finite value (NaN or infinity) in velocity or deformation",
               3: "particle left the domain"}
_NO_FAIL = 2**31 - 1
ENERGY_CHECK_EVERY = 20  # steps between energy-growth checks

_live = {"id": 0, "key": None}


def resolve_arch(arch: str) -> str:
    """`auto` -> the first of cuda, vulkan, metal that Taichi finds, else cpu.

    Taichi's own `ti.gpu` list also probes OpenGL/GLES, which crashes the process (segmentation
    fault) on headless machines without a GL driver, so those are never probed here."""
    if arch != "auto":
        return arch
    from taichi.lang.misc import is_arch_supported

    ti.set_logging_level(ti.ERROR)  # no "libcuda.so not found" warning on machines without CUDA
    for name in ("cuda", "vulkan", "metal"):
        if is_arch_supported(getattr(ti, name)):
            return name
    return "cpu"


def init_taichi(arch: str, precision: str):
    """(Re)start Taichi for a new simulation; only the newest Simulation stays live."""
    fp = ti.f64 if precision == "f64" else ti.f32
    ti.init(arch=getattr(ti, resolve_arch(arch)), default_fp=fp, default_ip=ti.i32, offline_cache=True,
            log_level=ti.ERROR, random_seed=0)
    _live["id"] += 1
    return _live["id"]


class Simulation:
    """A running MPM simulation built from a config (the API contract is in docs/contract.md)."""

    def __init__(self, cfg, body_force: Optional[Callable] = None, scene: Optional[Scene] = None):
        self.cfg: Config = cfg if isinstance(cfg, Config) else load_config(cfg)
        self.body_force = body_force
        c = self.cfg
        self.dim, self.dx = c.dim, c.domain.dx
        self.lower = np.asarray(c.domain.lower, float)
        self.upper = np.asarray(c.domain.upper, float)
        self.n_cells = _cell_counts(self.lower, self.upper, self.dx)
        self.scene = scene if scene is not None else build_scene(c)
        self.n = self.scene.n
        self._id = init_taichi(c.arch, c.precision)
        self.basis = make_basis(c.solver.basis)
        self._materials = [c.materials[name] for name in self.scene.materials]
        self.wave_speed = max(wave_speed(m) for m in self._materials)
        self.time, self.n_steps, self.dt = 0.0, 0, 0.0
        self._energy_ref = None  # (total energy at the reference time, peak kinetic + strain energy since)
        self._allocate()
        self._build_kernels()
        self._upload()
        self._vmax = _max_speed(self.scene.v)

    # ------------------------------------------------------------------ fields
    def _features(self):
        c, s = self.cfg, self.scene
        uses_viscosity = any(m.model == "fluid" and m.viscosity > 0 for m in self._materials)
        spacing = np.unique(s.spacing)
        return dict(
            apic=c.solver.transfer == "apic",
            flip=c.solver.transfer == "flip",
            musl=c.solver.update == "musl",
            store_grad_v=c.solver.transfer == "apic" or uses_viscosity,  # C: APIC B_p or C_p, or grad v
            multi_material=len(self._materials) > 1,
            body_force=self.body_force is not None,
            gimp_per_particle=c.solver.basis == "gimp" and len(spacing) > 1,
            gravity=any(g != 0 for g in c.gravity),
            viscosity=uses_viscosity,
        )

    def _allocate(self):
        d, n = self.dim, self.n
        self.feat = f = self._features()
        self.x = ti.Vector.field(d, float, n)
        self.v = ti.Vector.field(d, float, n)
        self.F = ti.Matrix.field(d, d, float, n)
        self.vol0 = ti.field(float, n)
        self.C = ti.Matrix.field(d, d, float, n) if f["store_grad_v"] else None
        self.mat = ti.field(ti.u8, n) if f["multi_material"] else None
        self.body_acc = ti.Vector.field(d, float, n) if f["body_force"] else None
        self.half_width = ti.field(float, n) if f["gimp_per_particle"] else None
        vec = ["v"] + (["v_old"] if f["flip"] else []) + (["v2"] if f["musl"] else [])
        vec += crack_finder.grid_fields(d) if self.cfg.crack is not None else []  # tensor node mass rows
        shape = [self.basis.nodes(nc) for nc in self.n_cells]
        self.grid = Grid(d, shape, self.cfg.domain.sparse, vec)
        self.crack = crack_finder.CrackFinder(self) if self.cfg.crack is not None else None
        self.fail = ti.field(ti.i32, ())
        self.vmax2 = ti.field(float, ())
        self.diag = ti.field(ti.f64, 8)  # reduction slots for energies and momenta
        # wall impulses per face (x_min, x_max, y_min, ...), summed by the grid update; only for wall probes
        wall_probes = any(p.type == "wall" for p in self.cfg.output.probes)
        self.wall_reaction = ti.Vector.field(d, ti.f64, 2 * d) if wall_probes else None
        self.bytes_per_particle = self._bytes_per_particle()
        if self.crack is not None:
            self.bytes_per_particle += self.crack.bytes_per_particle()

    def _unroll(self) -> bool:
        """Unroll the stencil loop: always for `solver.unroll: true`, for auto when it has at most 16 nodes."""
        u = self.cfg.solver.unroll
        return u is True or (u == "auto" and self.basis.stencil ** self.dim <= 16)

    def _bytes_per_particle(self) -> int:
        size = 8 if self.cfg.precision == "f64" else 4
        d = self.dim
        floats = 2 * d + d * d + 1
        floats += d * d if self.C is not None else 0
        floats += d if self.body_acc is not None else 0
        floats += 1 if self.half_width is not None else 0
        return floats * size + (1 if self.mat is not None else 0)

    def _block_order(self) -> np.ndarray:
        """Solver slot -> creation index, sorting particles by grid block then cell, so that particles that
        share grid nodes are processed together (P2G scatters and G2P gathers hit the same cache lines)."""
        cell = np.floor((self.scene.x - self.lower) / self.dx).astype(np.int64)
        block = cell // 4
        keys = [cell[:, a] for a in reversed(range(self.dim))] + [block[:, a] for a in reversed(range(self.dim))]
        return np.lexsort(keys)

    def _to_solver(self, a: np.ndarray) -> np.ndarray:
        """Per-particle array in creation order -> solver order."""
        return np.ascontiguousarray(np.asarray(a)[self._perm])

    def _to_creation(self, a: np.ndarray) -> np.ndarray:
        out = np.empty_like(a)
        out[self._perm] = a
        return out

    def _upload(self):
        s, d = self.scene, self.dim
        self._perm = self._block_order()
        self.x.from_numpy(self._to_solver(s.x).astype(np.float64))
        self.v.from_numpy(self._to_solver(s.v).astype(np.float64))
        self.F.from_numpy(np.broadcast_to(np.eye(d), (self.n, d, d)).copy())
        self.vol0.from_numpy(self._to_solver(s.volume).astype(np.float64))
        if self.C is not None:
            self.C.fill(0)
        if self.mat is not None:
            self.mat.from_numpy(self._to_solver(s.material).astype(np.uint8))
        if self.half_width is not None:
            self.half_width.from_numpy(self._to_solver(0.5 * s.spacing / self.dx))
        if self.crack is not None:
            self.crack.upload()

    # ------------------------------------------------------------------ kernels
    def _build_kernels(self):
        dim, dx, inv_dx = self.dim, self.dx, 1.0 / self.dx
        basis, f = self.basis, self.feat
        S = basis.stencil
        n_cells = self.n_cells
        lower = ti.Vector(self.lower.tolist())
        upper = ti.Vector(self.upper.tolist())
        gravity = ti.Vector(list(self.cfg.gravity))
        mats = [(MODELS[m.model], m.mu, m.lam, m.viscosity, m.density) for m in self._materials]
        alpha = self.cfg.solver.flip_blend
        gimp_deforming = self.cfg.solver.gimp_domain == "deforming"
        gimp_lp0 = 0.5 * float(self.scene.spacing[0]) / dx
        x, v, F, C, vol0, mat = self.x, self.v, self.F, self.C, self.vol0, self.mat
        body_acc, half_width = self.body_acc, self.half_width
        has_C, has_body_acc, has_half_width = C is not None, body_acc is not None, half_width is not None
        store_B = f["apic"] and not basis.apic_gradient  # the C field holds APIC's B_p (see affine())
        grid = self.grid
        gm, gv = grid.m, grid.vec["v"]
        gv_old = grid.vec.get("v_old")
        gv2 = grid.vec.get("v2")
        fail, vmax2 = self.fail, self.vmax2
        walls = self.cfg.domain.boundaries
        faces = [(walls.face(a, 0), walls.face(a, 1)) for a in range(dim)]
        friction = [(walls.friction(a, 0), walls.friction(a, 1)) for a in range(dim)]
        wall = make_wall_condition(dim, n_cells, faces, basis, friction, self.wall_reaction)
        span = [S] * dim
        # The stencil loop: `for o in ti.grouped(ti.ndrange(*outer))` then `for k in ti.static(range(len(inner)))`
        # with off = o + inner[k]. Unrolled, the outer range is a single point and `inner` lists every node, so
        # the weights stay in registers (3D quadratic: P2G 37 against 43 ms, G2P 7.5 against 11 ms CPU time for
        # 65k particles) but compiling takes 29 s instead of 3 s cold; otherwise the loop runs at run time.
        unroll = self._unroll()
        outer = [1] * dim if unroll else span
        inner = [ti.Vector(list(o)) for o in itertools.product(range(S), repeat=dim)] if unroll else [ti.Vector([0] * dim)]

        @ti.func
        def density(p):
            rho = ti.cast(mats[0][4], float)
            if ti.static(len(mats) > 1):
                for k in ti.static(range(1, len(mats))):
                    if mat[p] == k:
                        rho = mats[k][4]
            return rho

        # Material dispatch: a single-material scene compiles one model and stores no material index.
        @ti.func
        def kirchhoff(p, Fp):
            Lp = ti.Matrix.zero(float, dim, dim)
            if ti.static(f["viscosity"]):
                Lp = velocity_gradient(p)
            return model_kirchhoff(p, Fp, Lp)

        @ti.func
        def kirchhoff3(p):
            """The full 3x3 Kirchhoff stress: the 3D model at F with the missing axes held fixed (materials.embed3)."""
            Lp = ti.Matrix.zero(float, dim, dim)
            if ti.static(f["viscosity"]):
                Lp = velocity_gradient(p)
            return model_kirchhoff(p, embed3(F[p], 1.0), embed3(Lp, 0.0))

        @ti.func
        def model_kirchhoff(p, Fp, Lp):
            tau = ti.Matrix.zero(float, Fp.n, Fp.n)
            if ti.static(len(mats) == 1):
                tau = mats[0][0].kirchhoff(Fp, Lp, mats[0][1], mats[0][2], mats[0][3])
            else:
                for k in ti.static(range(len(mats))):
                    if mat[p] == k:
                        tau = mats[k][0].kirchhoff(Fp, Lp, mats[k][1], mats[k][2], mats[k][3])
            return tau

        @ti.func
        def strain_energy(p, Fp):
            psi = 0.0
            if ti.static(len(mats) == 1):
                psi = mats[0][0].energy(Fp, mats[0][1], mats[0][2])
            else:
                for k in ti.static(range(len(mats))):
                    if mat[p] == k:
                        psi = mats[k][0].energy(Fp, mats[k][1], mats[k][2])
            return psi

        @ti.func
        def is_fluid(p):
            res = False
            if ti.static(len(mats) == 1):
                res = ti.static(mats[0][0].fluid)
            else:
                for k in ti.static(range(len(mats))):
                    if ti.static(mats[k][0].fluid):
                        if mat[p] == k:
                            res = True
            return res

        @ti.func
        def stencil(p):
            """Stencil origin (storage index), per-axis weights W[a, k], x-derivatives DW[a, k] and node offsets
            R[a, k] = (x_i - x_p)_a, so the node loop only multiplies."""
            u = (x[p] - lower) * inv_dx
            base = ti.Vector.zero(int, dim)
            W = ti.Matrix.zero(float, dim, S)
            DW = ti.Matrix.zero(float, dim, S)
            R = ti.Matrix.zero(float, dim, S)
            for a in ti.static(range(dim)):
                lp = 0.0
                if ti.static(basis.name == "gimp"):
                    lp = gimp_lp0
                    if ti.static(has_half_width):
                        lp = half_width[p]
                    if ti.static(gimp_deforming):
                        lp = ti.min(lp * ti.abs(F[p][a, a]), 0.5)
                b, w, dw = basis.weights_1d(u[a], n_cells[a], lp)
                base[a] = b
                for k in ti.static(range(S)):
                    W[a, k] = w[k]
                    DW[a, k] = dw[k] * inv_dx
                    R[a, k] = (basis.coord(b + k, n_cells[a]) - u[a]) * dx
            return base, W, DW, R

        @ti.func
        def node_weight(W, DW, off):
            w = 1.0
            grad = ti.Vector.zero(float, dim)
            for a in ti.static(range(dim)):
                w *= W[a, off[a]]
            for a in ti.static(range(dim)):
                g = DW[a, off[a]]
                for b in ti.static(range(dim)):
                    if ti.static(b != a):
                        g *= W[b, off[b]]
                grad[a] = g
            return w, grad

        @ti.func
        def node_offset(R, off):
            """x_i - x_p of the node at stencil offset `off`."""
            d = ti.Vector.zero(float, dim)
            for a in ti.static(range(dim)):
                d[a] = R[a, off[a]]
            return d

        @ti.func
        def inertia(W, R):
            """APIC's D_p = sum_i w_ip (x_i - x_p)(x_i - x_p)^T: diagonal for tensor-product weights."""
            D = ti.Matrix.zero(float, dim, dim)
            for a in ti.static(range(dim)):
                s = 0.0
                for k in ti.static(range(S)):
                    s += W[a, k] * R[a, k] * R[a, k]
                D[a, a] = s
            return D

        @ti.func
        def inertia_inverse(W, R):
            Dinv = ti.Matrix.zero(float, dim, dim)
            D = inertia(W, R)
            for a in ti.static(range(dim)):
                Dinv[a, a] = 1.0 / D[a, a]
            return Dinv

        @ti.func
        def affine(p, W, R):
            """APIC's C_p at the particle's current position. Where D_p varies with position (GIMP, B-splines
            next to walls) the field stores B_p and C_p = B_p D_p^-1 uses the current D_p: the affine part's
            angular momentum, eps : B_p, is then carried exactly when the particle moves (Jiang et al. 2015)."""
            A = ti.Matrix.zero(float, dim, dim)
            if ti.static(store_B):
                A = C[p] @ inertia_inverse(W, R)
            elif ti.static(f["apic"]):
                A = C[p]
            return A

        @ti.func
        def node_momentum(vp, Ap, R, off):
            """Particle velocity seen by a node: v_p, plus C_p (x_i - x_p) with APIC."""
            mom = vp
            if ti.static(f["apic"]):
                mom += Ap @ node_offset(R, off)
            return mom

        @ti.func
        def velocity_gradient(p):
            """grad v of the last step (viscosity reads it)."""
            L = C[p]
            if ti.static(store_B):
                base, W, DW, R = stencil(p)
                L = affine(p, W, R)
            return L

        crack = self.crack is not None  # crack finder (crack.py): modified shape functions near discontinuities
        crk = self.crack.build(stencil, node_weight, node_offset, inertia, kirchhoff, wall, gravity, f["gravity"],
                               gv2 if f["musl"] else gv, basis, mat) if crack else None

        @ti.kernel
        def p2g(dt: float):
            for p in x:
                base, W, DW, R = stencil(p)
                Fp = F[p]
                mp = density(p) * vol0[p]
                stress = -vol0[p] * kirchhoff(p, Fp)
                if ti.static(crack):
                    stress = -crk.degrade(p, -stress)
                vp = v[p]
                Ap = affine(p, W, R)
                force_density = ti.Vector.zero(float, dim)
                if ti.static(has_body_acc):
                    force_density = mp * body_acc[p]
                if ti.static(crack):
                    if crk.modified(p):
                        crk.p2g(p, base, W, DW, R, mp, stress, vp, Ap, force_density, dt)
                        continue
                for o in ti.grouped(ti.ndrange(*outer)):
                  for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil, see `unroll`)
                    off = o + inner[k]
                    w, gw = node_weight(W, DW, off)
                    I = base + off
                    gm[I] += w * mp
                    mom = node_momentum(vp, Ap, R, off)
                    gv[I] += w * mp * mom + dt * (stress @ gw + w * force_density)
                    if ti.static(f["flip"]):
                        gv_old[I] += w * mp * vp

        @ti.kernel
        def grid_update(dt: float):
            for I in ti.grouped(gm):
                m = gm[I]
                if m > 0:
                    vel = gv[I] / m
                    if ti.static(f["gravity"]):
                        vel += dt * gravity
                    gv[I] = wall.measured(I, vel, m)  # adds m dv per face to wall_reaction (wall probes only)
                    if ti.static(f["flip"]):
                        gv_old[I] = gv_old[I] / m

        @ti.kernel
        def p2g_momentum():
            """MUSL: map the updated particle momentum back to the grid (same weights as the first P2G)."""
            for p in x:
                base, W, DW, R = stencil(p)
                mp = density(p) * vol0[p]
                vp = v[p]
                Ap = affine(p, W, R)
                if ti.static(crack):
                    if crk.modified(p):
                        crk.p2g_momentum(p, base, W, DW, R, mp, vp, Ap)
                        continue
                for o in ti.grouped(ti.ndrange(*outer)):
                  for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil, see `unroll`)
                    off = o + inner[k]
                    w, gw = node_weight(W, DW, off)
                    I = base + off
                    mom = node_momentum(vp, Ap, R, off)
                    gv2[I] += w * mp * mom

        @ti.kernel
        def grid_remap():
            for I in ti.grouped(gm):
                m = gm[I]
                if m > 0:
                    gv2[I] = wall(I, gv2[I] / m)

        vgrad = gv2 if f["musl"] else gv  # MUSL takes grad v from the remapped velocities

        @ti.kernel
        def g2p(dt: float, velocity: ti.template(), deform: ti.template()):
            """Grid to particles. velocity: new v (PIC, FLIP or APIC) and APIC's C.
            deform: positions (with this step's grid velocity), F = (I + dt grad v) F, and checks.
            USL does both in one pass; MUSL does them in two passes around the momentum remap."""
            for p in x:
                base, W, DW, R = stencil(p)
                v_pic = ti.Vector.zero(float, dim)
                dv = ti.Vector.zero(float, dim)
                B = ti.Matrix.zero(float, dim, dim)
                G = ti.Matrix.zero(float, dim, dim)
                for o in ti.grouped(ti.ndrange(*outer)):
                  for k in ti.static(range(len(inner))):  # noqa: E111 (one loop over the stencil, see `unroll`)
                    off = o + inner[k]
                    w, gw = node_weight(W, DW, off)
                    I = base + off
                    vi = gv[I]
                    v_pic += w * vi
                    if ti.static(velocity and f["flip"]):
                        dv += w * (vi - gv_old[I])
                    if ti.static(velocity and f["apic"] and not basis.apic_gradient):
                        B += w * vi.outer_product(node_offset(R, off))
                    if ti.static(deform):
                        G += vgrad[I].outer_product(gw)
                    elif ti.static(f["apic"] and basis.apic_gradient):  # MUSL velocity pass: v2 is not mapped yet
                        G += vi.outer_product(gw)
                if ti.static(crack):
                    if crk.modified(p):
                        v_pic, dv, B, G = crk.g2p(p, base, W, DW, R, deform)
                if ti.static(velocity):
                    if ti.static(f["flip"]):
                        v[p] = alpha * (v[p] + dv) + (1.0 - alpha) * v_pic
                    else:
                        v[p] = v_pic
                    if ti.static(f["apic"]):
                        if ti.static(basis.apic_gradient):
                            C[p] = G
                        else:
                            C[p] = B  # store_B
                if ti.static(deform):
                    xp = x[p] + dt * v_pic
                    Fp = (ti.Matrix.identity(float, dim) + dt * G) @ F[p]
                    J = Fp.determinant()
                    if is_fluid(p):
                        Fp = ti.Matrix.identity(float, dim) * ti.pow(ti.abs(J), 1.0 / dim)
                    x[p] = xp
                    F[p] = Fp
                    if ti.static(has_C and not f["apic"]):
                        C[p] = G
                    speed2 = v[p].norm_sqr()
                    ti.atomic_max(vmax2[None], speed2)
                    code = 0
                    if not (ti.abs(J) < 1e30 and speed2 < 1e60 and xp.norm_sqr() < 1e60):  # false for NaN too
                        code = 2
                    elif J <= 0:
                        code = 1
                    elif (xp < lower).any() or (xp > upper).any():
                        code = 3
                    if code != 0:
                        ti.atomic_min(fail[None], p * 4 + code)

        # diagnostics ----------------------------------------------------
        acc = self.diag

        @ti.kernel
        def energies():
            for p in x:
                mp = density(p) * vol0[p]
                acc[0] += 0.5 * mp * v[p].norm_sqr()
                acc[1] += vol0[p] * strain_energy(p, F[p])
                acc[2] -= mp * gravity.dot(x[p])

        @ti.kernel
        def momenta():
            """Linear momentum (dim) and angular momentum about the origin (3), APIC's affine part included."""
            for p in x:
                mp = density(p) * vol0[p]
                for a in ti.static(range(dim)):
                    acc[a] += mp * v[p][a]
                if ti.static(dim > 1):
                    x3 = ti.Vector.zero(float, 3)
                    v3 = ti.Vector.zero(float, 3)
                    for a in ti.static(range(dim)):
                        x3[a] = x[p][a]
                        v3[a] = v[p][a]
                    Lp = mp * x3.cross(v3)
                    if ti.static(f["apic"]):
                        base, W, DW, R = stencil(p)
                        B = C[p]  # store_B: the affine part's angular momentum is eps : B
                        if ti.static(not store_B):
                            B = C[p] @ inertia(W, R)  # sum_i w (x_i - x_p) x C (x_i - x_p) = eps : (C D)^T
                        B3 = ti.Matrix.zero(float, 3, 3)
                        for a, b in ti.static(ti.ndrange(dim, dim)):
                            B3[a, b] = B[a, b]
                        Lp += mp * ti.Vector([B3[2, 1] - B3[1, 2], B3[0, 2] - B3[2, 0], B3[1, 0] - B3[0, 1]])
                    for a in ti.static(range(3)):
                        acc[dim + a] += Lp[a]

        @ti.kernel
        def cauchy_stress(out: ti.types.ndarray()):
            """(N, 3, 3) Cauchy stress, out-of-plane normal stresses included (plane strain in 2D, uniaxial strain
            in 1D); the upper-left d x d block is the stress the step uses."""
            for p in x:
                tau = kirchhoff3(p) / F[p].determinant()
                if ti.static(crack):
                    tau = crk.degrade(p, tau)
                for a, b in ti.static(ti.ndrange(3, 3)):
                    out[p, a, b] = tau[a, b]

        self._k = dict(p2g=p2g, grid_update=grid_update, g2p=g2p, p2g_momentum=p2g_momentum, grid_remap=grid_remap, energies=energies, momenta=momenta,
                       cauchy_stress=cauchy_stress)
        if crack:
            self._k.update(crk.grid_kernels())

    # ------------------------------------------------------------------ stepping
    def _check_live(self):
        if _live["id"] != self._id:
            raise RuntimeError("this Simulation is no longer live: a newer Simulation restarted Taichi")

    def stable_dt(self) -> float:
        s = self.cfg.solver
        if s.dt is not None:
            return s.dt
        return s.cfl * self.dx / (self.wave_speed + self._vmax)

    def step(self, dt: Optional[float] = None) -> float:
        """Advance one step (dt from the CFL rule unless given); returns dt."""
        self._check_live()
        k = self._k
        dt = float(dt if dt is not None else self.stable_dt())
        watch_energy = self.cfg.solver.energy_growth_limit is not None and self.body_acc is None
        if watch_energy and self._energy_ref is None:
            self._energy_ref = self._energy_reference()
        if self.body_acc is not None:
            acc = np.asarray(self.body_force(self.scene.x, self.time), dtype=np.float64)
            self.body_acc.from_numpy(self._to_solver(acc))
        self.grid.clear()
        if self.crack is not None:
            self.crack.update()
        k["p2g"](dt)
        k["grid_update"](dt)
        self.fail[None] = _NO_FAIL
        self.vmax2[None] = 0.0
        if self.feat["musl"]:
            k["g2p"](dt, True, False)
            k["p2g_momentum"]()
            k["grid_remap"]()
            k["g2p"](dt, False, True)
        else:
            k["g2p"](dt, True, True)
        self.dt = dt
        self.n_steps += 1
        self.time += dt
        code = self.fail[None]
        self._vmax = math.sqrt(max(float(self.vmax2[None]), 0.0))
        if code != _NO_FAIL:
            p, cause = int(self._perm[code // 4]), FAIL_CAUSES[code % 4]
            raise InstabilityError(cause, self.n_steps, self.time, particle=p,
                                   detail=f"dt={dt:.3g}, max speed={self._vmax:.3g}")
        if watch_energy and self.n_steps % ENERGY_CHECK_EVERY == 0:
            self._check_energy_growth()
        return dt

    def _energy_reference(self):
        e = self.energy()
        return sum(e.values()), e["kinetic"] + e["strain"]

    def _check_energy_growth(self):
        """An explicit step past its stability limit can grow energy without any NaN or inverted particle."""
        total, mech = self._energy_reference()
        ref_total, peak = self._energy_ref
        peak = max(peak, mech)
        self._energy_ref = (ref_total, peak)
        limit = self.cfg.solver.energy_growth_limit
        if total - ref_total > limit * peak and peak > 0:
            speed = np.sum(self._read("v") ** 2, axis=1)
            raise InstabilityError(
                f"energy growth: total energy rose by {(total - ref_total) / peak:.0%} of the peak kinetic + "
                f"strain energy (limit {limit:.0%}); the time step is past its stability limit, lower solver.cfl",
                self.n_steps, self.time, particle=int(np.argmax(speed)), detail="particle named: the fastest")

    @property
    def at_step_limit(self) -> bool:
        """solver.max_steps reached."""
        m = self.cfg.solver.max_steps
        return bool(m) and self.n_steps >= m

    def advance_to(self, target: float, on_step: Optional[Callable] = None) -> int:
        """Step until simulation time `target`, shortening the last step to land on it exactly; stop early at
        solver.max_steps. on_step(self) runs after every step. Returns the number of steps taken.
        (Every stepping loop uses this one, so a resumed run takes exactly the steps of an uninterrupted one.)"""
        steps = 0
        while self.time < target - 1e-12 * max(1.0, abs(target)):
            if self.at_step_limit:
                return steps
            self.step(min(self.stable_dt(), target - self.time))
            steps += 1
            if on_step is not None:
                on_step(self)
        self.time = target
        return steps

    def advance(self, duration: float, on_step: Optional[Callable] = None) -> int:
        """Advance by `duration` of simulation time (see advance_to)."""
        return self.advance_to(self.time + duration, on_step)

    def run(self, on_output: Optional[Callable] = None, every: Optional[float] = None):
        """Run to solver.end_time (or solver.max_steps), calling on_output(self) at t=0 and every `every` seconds."""
        end = self.cfg.solver.end_time
        every = every or self.cfg.output.every
        if on_output:
            on_output(self)
        while self.time < end - 1e-12 * end and not self.at_step_limit:
            self.advance_to(min(self.time + every, end))
            if on_output:
                on_output(self)
        return self

    # ------------------------------------------------------------------ state access
    def particles(self) -> dict:
        """Particle state as numpy arrays in creation order: x, v, F, C (when stored), stress (N, d, d), stress3
        (N, 3, 3: the full Cauchy stress, out-of-plane normal stresses of plane strain / uniaxial strain included),
        mass, volume, body, damage (with a crack section)."""
        self._check_live()
        s = self.scene
        out = {name: self._read(name) for name in self._state_fields()}
        stress3 = np.zeros((self.n, 3, 3), dtype=np.float64)
        self._k["cauchy_stress"](stress3)
        stress3 = self._to_creation(stress3)
        d = self.dim
        out.update(stress=np.ascontiguousarray(stress3[:, :d, :d]), stress3=stress3, mass=s.mass.copy(),
                   volume=s.volume * np.linalg.det(out["F"]), body=s.body.copy())
        if self.crack is not None:
            out["damage"] = self.crack.damage()
        return out

    def _state_fields(self) -> dict:
        fields = {"x": self.x, "v": self.v, "F": self.F}
        if self.C is not None:
            fields["C"] = self.C
        return fields

    def _read(self, name) -> np.ndarray:
        a = self._state_fields()[name].to_numpy()
        shape = (self.n, self.dim) if name in ("x", "v") else (self.n, self.dim, self.dim)
        return self._to_creation(a.reshape(shape))  # 1x1 matrix fields come back as (N, 1)

    def set_particles(self, **arrays):
        """Set per-particle state (x, v, F, C) in creation order."""
        self._check_live()
        fields = self._state_fields()
        for name, value in arrays.items():
            if name not in fields:
                raise ValueError(f"cannot set '{name}' (settable: {', '.join(fields)})")
            value = np.asarray(value, dtype=np.float64)
            want = (self.n, self.dim) if name in ("x", "v") else (self.n, self.dim, self.dim)
            if value.shape != want:
                raise ValueError(f"{name} must have shape {want}, got {value.shape}")
            value = self._to_solver(value)
            fields[name].from_numpy(value.reshape(self.n, 1) if self.dim == 1 and name in ("F", "C") else value)
        self._energy_ref = None  # a new state: energy is measured afresh
        if "v" in arrays:
            self._vmax = _max_speed(arrays["v"])

    def get_state(self) -> dict:
        """Everything needed to continue bit for bit: particle fields (creation order), clock, CFL speed estimate."""
        self._check_live()
        state = {name: self._read(name) for name in self._state_fields()}
        state.update(time=self.time, n_steps=self.n_steps, dt=self.dt, vmax=self._vmax)
        if self.crack is not None:
            state.update(self.crack.get_state())  # damage (and the damage law's history)
        return state

    def set_state(self, state: dict):
        self.set_particles(**{k: state[k] for k in self._state_fields() if k in state})
        self.time, self.n_steps = float(state["time"]), int(state["n_steps"])
        self.dt, self._vmax = float(state["dt"]), float(state["vmax"])
        if self.crack is not None:
            self.crack.set_state(state)

    def energy(self) -> dict:
        self._check_live()
        self.diag.fill(0)
        self._k["energies"]()
        e = self.diag.to_numpy()
        return {"kinetic": float(e[0]), "strain": float(e[1]), "gravity": float(e[2])}

    def momentum(self) -> dict:
        """Total linear momentum (dim) and angular momentum about the origin (3 components)."""
        self._check_live()
        self.diag.fill(0)
        self._k["momenta"]()
        m = self.diag.to_numpy()
        return {"linear": m[: self.dim], "angular": m[self.dim: self.dim + 3]}

    def wall_impulse(self, reset: bool = True) -> np.ndarray:
        """(2 dim, dim) impulse (N s; per metre of depth in 2D) each domain face (x_min, x_max, y_min, ...) gave
        the material at its grid nodes since the last reset: the momentum the wall condition changed in the grid
        update. Divided by the time since the reset it is the mean wall reaction force. Needs a wall probe in
        output.probes (otherwise nothing is accumulated and this raises)."""
        self._check_live()
        if self.wall_reaction is None:
            raise RuntimeError("no wall reaction is accumulated: the config has no wall probe in output.probes")
        out = self.wall_reaction.to_numpy().reshape(2 * self.dim, self.dim)
        if reset:
            self.wall_reaction.fill(0)
        return out

    def max_speed(self) -> float:
        return _max_speed(self._read("v"))

    def cfl_number(self) -> float:
        return self.dt * (self.wave_speed + self._vmax) / self.dx


def _max_speed(v) -> float:
    return float(np.sqrt(np.max(np.sum(np.asarray(v) ** 2, axis=1))))


def _cell_counts(lower, upper, dx) -> list[int]:
    counts = []
    for a, (l, u) in enumerate(zip(lower, upper)):
        n = (u - l) / dx
        if abs(n - round(n)) > 1e-6 * max(1.0, n):
            raise ConfigError(f"the domain extent {u - l:g} along axis {a} is not a whole number of cells of dx={dx:g} "
                              f"({n:.4g}); choose dx = {(u - l) / max(1, round(n)):.6g}", key="domain.dx")
        counts.append(int(round(n)))
    return counts
