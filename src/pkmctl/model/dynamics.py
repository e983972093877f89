"""Dynamics of the 2RPU-2SPR manipulator in task space (DESIGN.md §2; the paper's eq. 9-24).

    M(X) Xddot + C(X, Xdot) Xdot + G(X) = F + tau_d',      F = J^T tau_a

Every term is a sum over the 9 bodies of :func:`pkmctl.model.kinematics.body_jacobians`:

    M = sum  m J_v^T J_v + J_w^T (R I R^T) J_w
    C = sum  m J_v^T dJ_v + J_w^T ((R I R^T) dJ_w + [omega]x (R I R^T) J_w)
    G = sum  m g J_v[z]^T

The kernels compute C v for one vector v (the plant needs C Xdot, the controllers
C Xr_dot), from the Jacobian derivatives applied to v; the matrix C is C e_j.

This C makes Mdot - 2C skew-symmetric. T and V are linear in the body parameters
Theta_b = [m, I_xx, I_yy, I_zz], so with the columns r_k of R_b,
R I R^T = sum_k I_k r_k r_k^T and the regressor Y (3, 36) follows body by body:
Y Theta = M Xr_ddot + C Xr_dot + G.

The kernels take a workspace :class:`Workspace`-like tuple of arrays so the control
loop can call them without allocating.
"""

from __future__ import annotations

import numpy as np

from pkmctl._jit import kernel
from pkmctl.model.kinematics import N_BODIES, body_jacobians

__all__ = [
    "JQ",
    "N_THETA",
    "Q",
    "WORK_SHAPES",
    "WORK_SIZE",
    "actuator_forces_kernel",
    "dynamics_kernel",
    "forward_dynamics",
    "gravity_kernel",
    "inverse_dynamics",
    "make_work",
    "regressor_kernel",
    "solve_spd3",
    "task_force",
    "work_views",
]

N_THETA = 4 * N_BODIES


#: Positions in the workspace tuple of :func:`make_work` (named, not magic numbers).
RB, JV, JW, AV, AW, JQ, Q, SCRATCH = range(8)
#: Shapes of the workspace arrays, at those positions.
WORK_SHAPES = ((N_BODIES, 3, 3),) * 3 + ((N_BODIES, 3),) * 2 + ((4, 3), (4,), (5, 3))
_SIZES = tuple(int(np.prod(shape)) for shape in WORK_SHAPES)
_OFFSETS = tuple(int(sum(_SIZES[:i])) for i in range(len(_SIZES) + 1))
#: Length of a flat float64 buffer that holds one workspace (:func:`work_views`).
WORK_SIZE = _OFFSETS[-1]


@kernel
def make_work():
    """Arrays for one pose, at the indices RB, JV, JW, AV, AW, JQ, Q, SCRATCH.

    Body frames, Jacobians and dJ/dt v of :func:`~pkmctl.model.kinematics.body_jacobians`,
    the limb Jacobian and lengths, and a (5, 3) scratch for the dynamics kernels.
    """
    return (
        np.empty((N_BODIES, 3, 3)),
        np.empty((N_BODIES, 3, 3)),
        np.empty((N_BODIES, 3, 3)),
        np.empty((N_BODIES, 3)),
        np.empty((N_BODIES, 3)),
        np.empty((4, 3)),
        np.empty(4),
        np.empty((5, 3)),
    )


@kernel(inline="always", refcount=False)
def work_views(buf):
    """The workspace of :func:`make_work` as views into a flat buffer of WORK_SIZE floats."""
    o = _OFFSETS
    return (
        buf[o[0] : o[1]].reshape((N_BODIES, 3, 3)),
        buf[o[1] : o[2]].reshape((N_BODIES, 3, 3)),
        buf[o[2] : o[3]].reshape((N_BODIES, 3, 3)),
        buf[o[3] : o[4]].reshape((N_BODIES, 3)),
        buf[o[4] : o[5]].reshape((N_BODIES, 3)),
        buf[o[5] : o[6]].reshape((4, 3)),
        buf[o[6] : o[7]],
        buf[o[7] : o[8]].reshape((5, 3)),
    )


@kernel(inline="always", refcount=False)
def inverse_dynamics(M, Cv, G, a, out):
    """out = M a + C v + G (3,) from filled M, C v and G: eq. 24 solved for the force.

    The one place this sum is written: the controllers' model terms, computed torque
    and the desired forces all call it.
    """
    for i in range(3):
        out[i] = G[i] + (M[i, 0] * a[0] + M[i, 1] * a[1] + M[i, 2] * a[2] + Cv[i])


@kernel(inline="always", refcount=False)
def forward_dynamics(M, Cv, G, f, out):
    """out = M^-1 (f - C Xdot - G) (3,): eq. 24 solved for Xddot, f the task-space force."""
    for i in range(3):
        out[i] = f[i] - Cv[i] - G[i]
    solve_spd3(M, out)


@kernel(inline="always", refcount=False)
def task_force(Jq, tau, out):
    """out = J^T tau (3,): the task-space force of limb forces tau (4,) (eq. 22)."""
    for i in range(3):
        out[i] = Jq[0, i] * tau[0] + Jq[1, i] * tau[1] + Jq[2, i] * tau[2] + (Jq[3, i] * tau[3])


@kernel(inline="always")
def _kinematics(geom, X, Xd, v, work):
    Rb, Jv, Jw, av, aw, Jq, q, _ = work
    body_jacobians(geom, X, Xd, v, Rb, Jv, Jw, av, aw, Jq, q)


@kernel(inline="always")
def _assemble(geom, theta, Xd, v, work, M, Cv, G):
    """M, C(X, Xd) v and G from filled body kinematics (the sums of the module docstring).

    The two bodies of a limb share its frame and angular velocity, so their rotational
    terms are summed once with the summed inertia (5 rotating frames, not 9). Sums are
    kept in scalars so that they stay in registers.
    """
    Rb, Jv, Jw, av, aw = work[RB], work[JV], work[JW], work[AV], work[AW]
    m00 = m01 = m02 = m11 = m12 = m22 = 0.0
    c0 = c1 = c2 = 0.0
    g0 = g1 = g2 = 0.0
    for b in range(N_BODIES):  # translation: m J_v^T J_v, m J_v^T (dJ_v v), m dz/dX
        m = theta[4 * b]
        a00, a01, a02 = Jv[b, 0, 0], Jv[b, 0, 1], Jv[b, 0, 2]
        a10, a11, a12 = Jv[b, 1, 0], Jv[b, 1, 1], Jv[b, 1, 2]
        a20, a21, a22 = Jv[b, 2, 0], Jv[b, 2, 1], Jv[b, 2, 2]
        m00 += m * (a00 * a00 + a10 * a10 + a20 * a20)
        m01 += m * (a00 * a01 + a10 * a11 + a20 * a21)
        m02 += m * (a00 * a02 + a10 * a12 + a20 * a22)
        m11 += m * (a01 * a01 + a11 * a11 + a21 * a21)
        m12 += m * (a01 * a02 + a11 * a12 + a21 * a22)
        m22 += m * (a02 * a02 + a12 * a12 + a22 * a22)
        x0, x1, x2 = m * av[b, 0], m * av[b, 1], m * av[b, 2]
        c0 += a00 * x0 + a10 * x1 + a20 * x2
        c1 += a01 * x0 + a11 * x1 + a21 * x2
        c2 += a02 * x0 + a12 * x1 + a22 * x2
        g0 += m * a20
        g1 += m * a21
        g2 += m * a22
    for f in range(5):  # rotation, in the body frame: Jb = R^T J_w, M += Jb^T I Jb, ...
        i0, i1, i2 = theta[4 * f + 1], theta[4 * f + 2], theta[4 * f + 3]
        if f > 0:  # both bodies of a limb turn together: their inertias add
            i0 += theta[4 * (f + 4) + 1]
            i1 += theta[4 * (f + 4) + 2]
            i2 += theta[4 * (f + 4) + 3]
        # rows of Jb = R^T J_w (row n is r_n^T J_w), and body-frame omega, J_w v, dJ_w v
        b00 = Rb[f, 0, 0] * Jw[f, 0, 0] + Rb[f, 1, 0] * Jw[f, 1, 0] + Rb[f, 2, 0] * Jw[f, 2, 0]
        b01 = Rb[f, 0, 0] * Jw[f, 0, 1] + Rb[f, 1, 0] * Jw[f, 1, 1] + Rb[f, 2, 0] * Jw[f, 2, 1]
        b02 = Rb[f, 0, 0] * Jw[f, 0, 2] + Rb[f, 1, 0] * Jw[f, 1, 2] + Rb[f, 2, 0] * Jw[f, 2, 2]
        b10 = Rb[f, 0, 1] * Jw[f, 0, 0] + Rb[f, 1, 1] * Jw[f, 1, 0] + Rb[f, 2, 1] * Jw[f, 2, 0]
        b11 = Rb[f, 0, 1] * Jw[f, 0, 1] + Rb[f, 1, 1] * Jw[f, 1, 1] + Rb[f, 2, 1] * Jw[f, 2, 1]
        b12 = Rb[f, 0, 1] * Jw[f, 0, 2] + Rb[f, 1, 1] * Jw[f, 1, 2] + Rb[f, 2, 1] * Jw[f, 2, 2]
        b20 = Rb[f, 0, 2] * Jw[f, 0, 0] + Rb[f, 1, 2] * Jw[f, 1, 0] + Rb[f, 2, 2] * Jw[f, 2, 0]
        b21 = Rb[f, 0, 2] * Jw[f, 0, 1] + Rb[f, 1, 2] * Jw[f, 1, 1] + Rb[f, 2, 2] * Jw[f, 2, 1]
        b22 = Rb[f, 0, 2] * Jw[f, 0, 2] + Rb[f, 1, 2] * Jw[f, 1, 2] + Rb[f, 2, 2] * Jw[f, 2, 2]
        m00 += i0 * b00 * b00 + i1 * b10 * b10 + i2 * b20 * b20
        m01 += i0 * b00 * b01 + i1 * b10 * b11 + i2 * b20 * b21
        m02 += i0 * b00 * b02 + i1 * b10 * b12 + i2 * b20 * b22
        m11 += i0 * b01 * b01 + i1 * b11 * b11 + i2 * b21 * b21
        m12 += i0 * b01 * b02 + i1 * b11 * b12 + i2 * b21 * b22
        m22 += i0 * b02 * b02 + i1 * b12 * b12 + i2 * b22 * b22
        w0 = b00 * Xd[0] + b01 * Xd[1] + b02 * Xd[2]  # omega in the body frame
        w1 = b10 * Xd[0] + b11 * Xd[1] + b12 * Xd[2]
        w2 = b20 * Xd[0] + b21 * Xd[1] + b22 * Xd[2]
        h0 = i0 * (b00 * v[0] + b01 * v[1] + b02 * v[2])  # I (R^T J_w v)
        h1 = i1 * (b10 * v[0] + b11 * v[1] + b12 * v[2])
        h2 = i2 * (b20 * v[0] + b21 * v[1] + b22 * v[2])
        # R^T (dJ_w v): the body-frame image of the world-frame dJ_w v
        e0 = Rb[f, 0, 0] * aw[f, 0] + Rb[f, 1, 0] * aw[f, 1] + Rb[f, 2, 0] * aw[f, 2]
        e1 = Rb[f, 0, 1] * aw[f, 0] + Rb[f, 1, 1] * aw[f, 1] + Rb[f, 2, 1] * aw[f, 2]
        e2 = Rb[f, 0, 2] * aw[f, 0] + Rb[f, 1, 2] * aw[f, 1] + Rb[f, 2, 2] * aw[f, 2]
        t0 = i0 * e0 + w1 * h2 - w2 * h1  # R^T (Iw dJ_w v + omega x Iw J_w v)
        t1 = i1 * e1 + w2 * h0 - w0 * h2
        t2 = i2 * e2 + w0 * h1 - w1 * h0
        c0 += b00 * t0 + b10 * t1 + b20 * t2
        c1 += b01 * t0 + b11 * t1 + b21 * t2
        c2 += b02 * t0 + b12 * t1 + b22 * t2
    g = geom[10]
    M[0, 0], M[0, 1], M[0, 2] = m00, m01, m02
    M[1, 0], M[1, 1], M[1, 2] = m01, m11, m12
    M[2, 0], M[2, 1], M[2, 2] = m02, m12, m22
    Cv[0], Cv[1], Cv[2] = c0, c1, c2
    G[0], G[1], G[2] = g * g0, g * g1, g * g2


@kernel(refcount=False, llvm_inline=True)
def dynamics_kernel(geom, theta, X, Xd, v, work, M, Cv, G):
    """Fill M (3, 3), C(X, Xd) v (3,) and G (3,) (eq. 9-24).

    v = Xd gives the Coriolis/centrifugal vector of the plant; v = Xr_dot the
    controllers' C Xr_dot. The matrix C is C e_j column by column.
    """
    _kinematics(geom, X, Xd, v, work)
    _assemble(geom, theta, Xd, v, work, M, Cv, G)


@kernel(refcount=False, llvm_inline=True)
def gravity_kernel(geom, theta, X, work, G):
    """Fill G (3,) at X: sum of m g dz_b/dX (eq. 24), without the velocity terms."""
    z3 = work[SCRATCH][4]
    z3[0], z3[1], z3[2] = 0.0, 0.0, 0.0  # not z3[:] = 0: a call of memset
    _kinematics(geom, X, z3, z3, work)
    Jv = work[JV]
    g = geom[10]
    g0 = g1 = g2 = 0.0  # scalars: a sum in G would be stored and reloaded per body
    for b in range(N_BODIES):
        mg = theta[4 * b] * g
        g0 += mg * Jv[b, 2, 0]
        g1 += mg * Jv[b, 2, 1]
        g2 += mg * Jv[b, 2, 2]
    G[0], G[1], G[2] = g0, g1, g2


@kernel(inline="always")
def _regressor_from_work(geom, Xd, Xr_d, Xr_dd, work, Y):
    # Scalars, not scratch arrays: LLVM cannot tell a scratch row from Y, so every store
    # into Y would reload them (0.38 -> 0.30 us per regressor). Same sums, same order.
    Rb, Jv, Jw, av, aw = work[RB], work[JV], work[JW], work[AV], work[AW]
    g = geom[10]
    d0, d1, d2 = Xd[0], Xd[1], Xd[2]
    r0d, r1d, r2d = Xr_d[0], Xr_d[1], Xr_d[2]
    r0dd, r1dd, r2dd = Xr_dd[0], Xr_dd[1], Xr_dd[2]
    for b in range(N_BODIES):
        # mass column: J_v^T (J_v Xr_dd + dJ_v Xr_d) + g dz/dX
        v00, v01, v02 = Jv[b, 0, 0], Jv[b, 0, 1], Jv[b, 0, 2]
        v10, v11, v12 = Jv[b, 1, 0], Jv[b, 1, 1], Jv[b, 1, 2]
        v20, v21, v22 = Jv[b, 2, 0], Jv[b, 2, 1], Jv[b, 2, 2]
        a0 = v00 * r0dd + v01 * r1dd + v02 * r2dd + av[b, 0]
        a1 = v10 * r0dd + v11 * r1dd + v12 * r2dd + av[b, 1]
        a2 = v20 * r0dd + v21 * r1dd + v22 * r2dd + av[b, 2]
        m0 = v00 * a0 + v10 * a1 + v20 * a2 + g * v20
        m1 = v01 * a0 + v11 * a1 + v21 * a2 + g * v21
        m2 = v02 * a0 + v12 * a1 + v22 * a2 + g * v22
        Y[0, 4 * b], Y[1, 4 * b], Y[2, 4 * b] = m0, m1, m2
        if b >= 5:  # an upper limb turns with its lower limb: same inertia columns
            for i in range(3):
                for n in range(1, 4):
                    Y[i, 4 * b + n] = Y[i, 4 * (b - 4) + n]
            continue
        # inertia columns: J_w^T (r_k a_k + b_k omega x r_k)
        w00, w01, w02 = Jw[b, 0, 0], Jw[b, 0, 1], Jw[b, 0, 2]
        w10, w11, w12 = Jw[b, 1, 0], Jw[b, 1, 1], Jw[b, 1, 2]
        w20, w21, w22 = Jw[b, 2, 0], Jw[b, 2, 1], Jw[b, 2, 2]
        c0 = aw[b, 0] + w00 * r0dd + w01 * r1dd + w02 * r2dd
        c1 = aw[b, 1] + w10 * r0dd + w11 * r1dd + w12 * r2dd
        c2 = aw[b, 2] + w20 * r0dd + w21 * r1dd + w22 * r2dd
        e0 = w00 * r0d + w01 * r1d + w02 * r2d
        e1 = w10 * r0d + w11 * r1d + w12 * r2d
        e2 = w20 * r0d + w21 * r1d + w22 * r2d
        o0 = w00 * d0 + w01 * d1 + w02 * d2
        o1 = w10 * d0 + w11 * d1 + w12 * d2
        o2 = w20 * d0 + w21 * d1 + w22 * d2
        R = Rb[b]
        for n in range(3):
            x0, x1, x2 = R[0, n], R[1, n], R[2, n]
            a_n = x0 * c0 + x1 * c1 + x2 * c2
            b_n = x0 * e0 + x1 * e1 + x2 * e2
            u0 = x0 * a_n + b_n * (o1 * x2 - o2 * x1)
            u1 = x1 * a_n + b_n * (o2 * x0 - o0 * x2)
            u2 = x2 * a_n + b_n * (o0 * x1 - o1 * x0)
            Y[0, 4 * b + 1 + n] = w00 * u0 + w10 * u1 + w20 * u2
            Y[1, 4 * b + 1 + n] = w01 * u0 + w11 * u1 + w21 * u2
            Y[2, 4 * b + 1 + n] = w02 * u0 + w12 * u1 + w22 * u2


@kernel(refcount=False, llvm_inline=True)
def regressor_kernel(geom, X, Xd, Xr_d, Xr_dd, work, Y):
    """Fill the regressor Y (3, 36) with Y Theta = M Xr_dd + C(X, Xd) Xr_d + G (eq. 24)."""
    _kinematics(geom, X, Xd, Xr_d, work)
    _regressor_from_work(geom, Xd, Xr_d, Xr_dd, work, Y)


@kernel(inline="always")
def actuator_forces_kernel(Jq, F, tau):
    """Minimum-norm actuator forces tau (4,) with J^T tau = F: tau = J (J^T J)^-1 F (eq. 22)."""
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    for r in range(4):
        a00 += Jq[r, 0] * Jq[r, 0]
        a01 += Jq[r, 0] * Jq[r, 1]
        a02 += Jq[r, 0] * Jq[r, 2]
        a11 += Jq[r, 1] * Jq[r, 1]
        a12 += Jq[r, 1] * Jq[r, 2]
        a22 += Jq[r, 2] * Jq[r, 2]
    y0, y1, y2 = cholesky_solve3(a00, a01, a02, a11, a12, a22, F[0], F[1], F[2])
    for i in range(4):
        tau[i] = Jq[i, 0] * y0 + Jq[i, 1] * y1 + Jq[i, 2] * y2


@kernel(inline="always")
def cholesky_solve3(a00, a01, a02, a11, a12, a22, b0, b1, b2):
    """x with A x = b for a symmetric positive definite 3x3 A given by its upper triangle.

    The square-root-free Cholesky factorisation A = L D L^T (L unit lower triangular):
    three divisions (the pivots' reciprocals) and no square root, where A = L L^T took
    nine divisions and three square roots: the slow instructions, here in one long
    dependent chain (docs/performance.md). A pivot that is not positive (A not positive
    definite, or NaN) gives NaN, as the square root did.
    """
    r0 = 1.0 / a00 if a00 > 0.0 else np.nan
    l10 = a01 * r0
    l20 = a02 * r0
    d1 = a11 - l10 * a01
    r1 = 1.0 / d1 if d1 > 0.0 else np.nan
    t21 = a12 - l20 * a01  # l21 d1
    l21 = t21 * r1
    d2 = a22 - l20 * a02 - l21 * t21
    r2 = 1.0 / d2 if d2 > 0.0 else np.nan
    z1 = b1 - l10 * b0
    z2 = b2 - l20 * b0 - l21 * z1
    x2 = z2 * r2
    x1 = z1 * r1 - l21 * x2
    x0 = b0 * r0 - l10 * x1 - l20 * x2
    return x0, x1, x2


@kernel(inline="always")
def solve_spd3(A, b):
    """Solve A x = b in place (b <- x) for a symmetric positive definite 3x3 A."""
    b[0], b[1], b[2] = cholesky_solve3(
        A[0, 0], A[0, 1], A[0, 2], A[1, 1], A[1, 2], A[2, 2], b[0], b[1], b[2]
    )
