"""Tensor helpers of the constitutive models (Taichi funcs, any dimension unless said): embedding a d-dimensional
state in 3D, the polar rotation, symmetric eigen-decompositions, the Hencky (logarithmic) strain of the elastic left
Cauchy-Green tensor, and the Rankine damage funcs of the crack finder."""
import taichi as ti


@ti.func
def embed3(A, fill):
    """The 3x3 matrix with A (d x d) in its upper-left block and `fill` on the rest of the diagonal: F or L of a
    plane-strain (2D) or uniaxial-strain (1D) state as a 3D tensor (fill 1 for F, 0 for L)."""
    out = ti.Matrix.identity(float, 3) * fill
    for a, b in ti.static(ti.ndrange(A.n, A.n)):
        out[a, b] = A[a, b]
    return out


POLAR_ITERATIONS = 12  # most scaled Newton steps (quadratic convergence: stretches up to ~1e3 need 8)


@ti.func
def rotation(F):
    """Rotation of the polar decomposition F = R S (J > 0; 1D: the identity).

    2D: Taichi's closed form. 3D: Newton's iteration X <- (g X + X^-T / g) / 2 with determinant scaling
    g = |det X|^(-1/3) (Higham 1986) while det X is more than 1 % from 1 (g is then ~1 and its pow costs more than
    the step), until a step moves X by less than the square root of the precision's epsilon: convergence is
    quadratic, so X is then within round-off of R. A body near rest needs 2-3 steps in f32, a stretch of 2-3x 5-7
    (a fixed 8 cost 2-4x more; tests/test_materials.py checks R against numpy's SVD)."""
    R = ti.Matrix.identity(float, F.n)
    if ti.static(F.n == 2):
        R, _ = ti.polar_decompose(F)
    elif ti.static(F.n == 3):
        tol2 = ti.static(1e-7 if ti.lang.impl.get_runtime().default_fp == ti.f32 else 2e-16)  # epsilon
        R = F
        k = 0
        while k < POLAR_ITERATIONS:
            det = R.determinant()
            g = 1.0
            if ti.abs(det - 1.0) > 1e-2:
                g = ti.pow(ti.abs(det), -1.0 / 3.0)
            step = 0.5 * (g * R + R.inverse().transpose() / g) - R
            R += step
            k += 1
            if step.norm_sqr() < tol2:
                break
    return R


@ti.func
def embed_held(F, held):
    """3x3 of a d x d F with `held` on the held axes' diagonal (z in 2D, y and z in 1D): the elastic stretch a
    plastic model keeps there, since plastic flow out of the plane changes it while the total F_zz stays 1."""
    out = ti.Matrix.identity(float, 3) * held
    for a, b in ti.static(ti.ndrange(F.n, F.n)):
        out[a, b] = F[a, b]
    return out


@ti.func
def top_left(A, d: ti.template()):
    """The upper-left d x d block of a 3x3 matrix."""
    out = ti.Matrix.zero(float, d, d)
    for a, b in ti.static(ti.ndrange(d, d)):
        out[a, b] = A[a, b]
    return out


EIGH_SWEEPS = 6  # cyclic Jacobi converges quadratically: 6 sweeps reach f64 round-off for 3x3 (tests/test_plasticity.py)


@ti.func
def eigh(A):
    """Eigenvalues (vector) and orthonormal eigenvectors (columns of Q) of a symmetric 2x2 or 3x3 matrix, A = Q diag Q^T,
    by cyclic Jacobi rotations applied to the two rows and columns they touch (each rotation zeroes its entry
    exactly, so a block-diagonal A, e.g. a plane-strain tensor, keeps its zero blocks)."""
    n = ti.static(A.n)
    M = A
    Q = ti.Matrix.identity(float, n)
    for _ in range(1 if n == 2 else EIGH_SWEEPS):
        for pqr in ti.static([(0, 1, 2), (0, 2, 1), (1, 2, 0)] if n == 3 else [(0, 1, -1)]):
            p, q, r = ti.static(pqr[0], pqr[1], pqr[2])
            apq = M[p, q]
            if apq != 0:
                theta = (M[q, q] - M[p, p]) / (2.0 * apq)
                t = 1.0 / (ti.abs(theta) + ti.sqrt(theta * theta + 1.0))
                if theta < 0:
                    t = -t
                c = 1.0 / ti.sqrt(t * t + 1.0)
                s = t * c
                M[p, p] -= t * apq
                M[q, q] += t * apq
                M[p, q] = 0.0
                M[q, p] = 0.0
                if ti.static(r >= 0):
                    mrp, mrq = M[r, p], M[r, q]
                    M[r, p] = c * mrp - s * mrq
                    M[p, r] = M[r, p]
                    M[r, q] = s * mrp + c * mrq
                    M[q, r] = M[r, q]
                for k in ti.static(range(n)):
                    qkp, qkq = Q[k, p], Q[k, q]
                    Q[k, p] = c * qkp - s * qkq
                    Q[k, q] = s * qkp + c * qkq
    ev = ti.Vector([M[k, k] for k in ti.static(range(n))])
    return ev, Q


@ti.func
def principal_matrix(Q, d):
    """Q diag(d) Q^T."""
    out = ti.Matrix.zero(float, Q.n, Q.n)
    for k in ti.static(range(Q.n)):
        q = ti.Vector([Q[a, k] for a in ti.static(range(Q.n))])
        out += d[k] * q.outer_product(q)
    return out


@ti.func
def hencky(F):
    """Logarithmic (Hencky) strain of the left stretch V of F = V R: eps_k = ln(lambda_k) = ln(eig(F F^T)) / 2, with the
    principal directions (columns of Q). A plastic model's trial state in its return mapping."""
    b, Q = eigh(F @ F.transpose())
    eps = ti.Vector.zero(float, F.n)
    for k in ti.static(range(F.n)):
        eps[k] = 0.5 * ti.log(ti.max(b[k], 1e-30))
    return eps, Q


@ti.func
def rescale_principal(F, Q, eps_trial, eps_new):
    """F with its left stretches moved from exp(eps_trial) to exp(eps_new) along the principal directions Q and its
    rotation kept: Q diag(exp(eps_new - eps_trial)) Q^T F (the return mapping's elastic F)."""
    return principal_matrix(Q, ti.exp(eps_new - eps_trial)) @ F


@ti.func
def hencky_energy(eps, mu, lam):
    """psi = mu |eps|^2 + lam/2 (tr eps)^2 (quadratic in the Hencky strain)."""
    tr = eps.sum()
    return mu * eps.dot(eps) + 0.5 * lam * tr * tr


def elastic_full(dim: int, held: int):
    """The 3D elastic F of a particle as a Taichi func of F and the state q: F itself in 3D; in 1D/2D embedded with
    the held axes' elastic stretch, state slot `held` (the Hencky-strain plastic models and cam_clay)."""

    @ti.func
    def full(F, q):
        F3 = ti.Matrix.identity(float, 3)
        if ti.static(dim == 3):
            F3 = F
        else:
            F3 = embed_held(F, q[held])
        return F3

    return full


def hencky_elasticity(mu: float, lam: float, dim: int, held: int):
    """The elastic part shared by the Hencky-strain plastic models (von_mises, drucker_prager), as Taichi funcs of the
    elastic F and the state q: `full` (the 3D elastic F; in 1D/2D the held axes' elastic stretch is state slot `held`),
    the model's `kirchhoff3`/`kirchhoff` (tau = Q (2 mu eps + lam tr eps) Q^T of the full F) and `energy` (the
    elastic energy density)."""
    full = elastic_full(dim, held)

    @ti.func
    def tau3(F3):
        eps, Q = hencky(F3)
        return principal_matrix(Q, 2.0 * mu * eps + lam * eps.sum())

    @ti.func
    def kirchhoff3(F, L, q):
        return tau3(full(F, q))

    @ti.func
    def kirchhoff(F, L, q):
        return top_left(tau3(full(F, q)), dim)

    @ti.func
    def energy(F, q):
        eps, Q = hencky(full(F, q))
        return hencky_energy(eps, mu, lam)

    return full, kirchhoff3, kirchhoff, energy


# ---------------------------------------------------------------- damage law (crack growth, crack.py)
@ti.func
def sym_eig(A):
    """Eigenvalues and eigenvectors (columns) of a symmetric 1x1, 2x2 or 3x3 matrix by cyclic Jacobi rotations
    (ti.sym_eig in Taichi 1.7 returns NaN for some diagonal 2x2 matrices)."""
    n = ti.static(A.n)
    V = ti.Matrix.identity(float, n)
    M = A
    pairs = ti.static({1: [], 2: [(0, 1)], 3: [(0, 1), (0, 2), (1, 2)]}[n])
    for _ in range(1 if n < 3 else 8):
        for pq in ti.static(pairs):
            i, j = ti.static(pq[0], pq[1])
            if M[i, j] != 0:
                theta = (M[j, j] - M[i, i]) / (2.0 * M[i, j])
                t = 1.0 / (ti.abs(theta) + ti.sqrt(theta * theta + 1.0))
                if theta < 0:
                    t = -t
                c = 1.0 / ti.sqrt(t * t + 1.0)
                s = t * c
                J = ti.Matrix.identity(float, n)
                J[i, i] = c
                J[j, j] = c
                J[i, j] = s
                J[j, i] = -s
                M = J.transpose() @ M @ J
                V = V @ J
    ev = ti.Vector([M[k, k] for k in ti.static(range(n))])
    return ev, V


@ti.func
def rankine_damage(sigma, kappa, E, eps0, eps_f):
    """Rankine criterion with linear softening: kappa = max over time of (max principal stress / E);
    d = eps_f (kappa - eps0) / (kappa (eps_f - eps0)), so the stress (1 - d) E kappa falls linearly from
    f_t at eps0 to 0 at eps_f. Returns (d, kappa)."""
    ev, _ = sym_eig(0.5 * (sigma + sigma.transpose()))
    k = ti.max(kappa, ev.max() / E)
    d = 0.0
    if k > eps0:
        d = 1.0
        if eps_f > eps0:
            d = ti.min(1.0, eps_f * (k - eps0) / (k * (eps_f - eps0)))
    return d, k


@ti.func
def degrade_tension(tau, d):
    """Damaged stress: tensile principal stresses scaled by (1 - d), compressive ones kept, so a damaged
    particle still carries compression (closed cracks) but not tension."""
    sym = 0.5 * (tau + tau.transpose())
    ev, Q = sym_eig(sym)
    for k in ti.static(range(tau.n)):
        if ev[k] > 0:
            ev[k] *= 1.0 - d
    out = (1.0 - d) * (tau - sym)
    for k in ti.static(range(tau.n)):
        q = ti.Vector([Q[a, k] for a in ti.static(range(tau.n))])
        out += ev[k] * q.outer_product(q)
    return out
