"""Dynamics of the 2RPU-2SPR manipulator in task space (DESIGN.md §2; the paper's eq. 9-24).

    M(X) Xddot + C(X, Xdot) Xdot + G(X) = F + tau_d',      F = J^T tau_a

Every term is a sum over the 9 bodies (:mod:`pkmctl.model.kinematics`: the platform, and
per limb a lower and an upper body sharing the limb's frame):

    M = sum  m J_v^T J_v + J_w^T (R I R^T) J_w
    C = sum  m J_v^T dJ_v + J_w^T ((R I R^T) dJ_w + [omega]x (R I R^T) J_w)
    G = sum  m g J_v[z]^T

The kernels compute C v for one vector v (the plant needs C Xdot, the controllers
C Xr_dot), from the Jacobian derivatives applied to v; the matrix C is C e_j.

This C makes Mdot - 2C skew-symmetric. T and V are linear in the body parameters
Theta_b = [m, I_xx, I_yy, I_zz], so with the columns r_k of R_b,
R I R^T = sum_k I_k r_k r_k^T and the regressor Y (3, 36) follows body by body:
Y Theta = M Xr_ddot + C Xr_dot + G.

The kernels take a workspace tuple of arrays (:func:`make_work`) so the control loop
can call them without allocating; they run the four limbs as SIMD lanes of one loop
(below, and docs/performance.md).
"""

from __future__ import annotations

import math

import numpy as np

from pkmctl._jit import kernel
from pkmctl.model.kinematics import (
    _LIMB_COS,
    _LIMB_SIN,
    _LIMB_SPR,
    N_BODIES,
    _limb_at,
    _limb_row,
    limb_motion,
    platform_motion,
)
from pkmctl.model.simd import limb_vectors, stack_block

__all__ = [
    "JDV",
    "JQ",
    "limb_columns",
    "limb_gravity",
    "limb_sums",
    "platform_columns",
    "platform_sums",
    "N_THETA",
    "Q",
    "WORK_SHAPES",
    "actuator_forces_kernel",
    "cholesky_solve3",
    "dynamics_kernel",
    "forward_dynamics",
    "gravity_kernel",
    "inverse_dynamics",
    "make_work",
    "regressor_kernel",
    "solve_spd3",
    "task_force",
]

N_THETA = 4 * N_BODIES


#: Positions in the workspace tuple of :func:`make_work` (named, not magic numbers).
JQ, Q, JDV = range(3)
#: Shapes of the workspace arrays, at those positions.
WORK_SHAPES = ((4, 3), (4,), (4,))


@kernel
def make_work():
    """The arrays the dynamics kernels leave for their caller, at the indices JQ, Q, JDV:
    the limb Jacobian J (4, 3) and the limb lengths q (4,) at X (the plant's J^T tau and
    the controllers' force split read them), and (dynamics and regressor) Jdot v (4,),
    Jdot along Xd (the rotor inertia of §7 reads it). Everything else lives on the stack."""
    return np.empty((4, 3)), np.empty(4), np.empty(4)


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


# ---------------------------------------------------------------- the limbs as SIMD lanes
# The kernels below run the four limbs as one loop whose iterations are the same
# branch-free code (kinematics.limb_motion), which LLVM vectorises four limbs at a time.
# The loop reads the limb count from the work's q at run time: over a constant 4 LLVM
# would unroll it into scalar code before its vectoriser saw it. Each iteration writes its
# limb's results into a row of a stack block (row r of limb i at 4 r + i); the scalar code
# after the loop adds the four limbs' partial sums to the platform's.
_L1, _L2, _MLO, _MUP, _I0, _I1, _I2 = range(7)  # limb parameters (l1, l2, masses, inertias)
_OQ, _OJ, _OJDV = 7, 8, 11  # q, the row of J (3 rows), Jdot v
_OS = 12  # the limb's outputs: 12 sums of M, C v, G, or 15 columns of Y
_BLOCK = 4 * (_OS + 15)


@kernel(inline="always", refcount=False)
def _limbs(q):
    """The limb loops' trip count: 4, read at run time from the work's q (a constant 4
    would be unrolled into scalar code before LLVM's vectoriser saw the loop), and never
    more than the block's rows hold."""
    return min(q.shape[0], 4)


@kernel(inline="always", refcount=False)
def _row(r, i):
    """The index of limb (lane) i of block row r."""
    return np.uint64(4 * r) + i


@kernel(inline="always", refcount=False)
def _limb_lengths(geom, W):
    """l1 and l2 of every limb into the block (contiguous rows the limb loop reads)."""
    for i in range(4):
        W[4 * _L1 + i] = geom[2 + i]
        W[4 * _L2 + i] = geom[6 + i]


@kernel(inline="always", refcount=False)
def _limb_parameters(geom, theta, W):
    """l1, l2 of every limb, the masses of its two bodies and the sums of their principal
    inertias (both bodies turn with the limb frame, so their rotational terms are summed
    once with the summed inertia), into the block."""
    _limb_lengths(geom, W)
    for i in range(4):
        lo, up = 4 * (1 + i), 4 * (5 + i)
        W[4 * _MLO + i] = theta[lo]
        W[4 * _MUP + i] = theta[up]
        W[4 * _I0 + i] = theta[lo + 1] + theta[up + 1]
        W[4 * _I1 + i] = theta[lo + 2] + theta[up + 2]
        W[4 * _I2 + i] = theta[lo + 3] + theta[up + 3]


@kernel(inline="always", refcount=False)
def _limbs_out(W, Jq, q):
    """The limb Jacobian and lengths from the block."""
    for i in range(4):
        q[i] = W[4 * _OQ + i]
        Jq[i, 0], Jq[i, 1], Jq[i, 2] = W[4 * _OJ + i], W[4 * (_OJ + 1) + i], W[4 * (_OJ + 2) + i]


@kernel(inline="always", refcount=False)
def _jdv_out(W, Jdv):
    """Jdot v from the block."""
    for i in range(4):
        Jdv[i] = W[4 * _OJDV + i]


@kernel(inline="always", refcount=False)
def _put3(W, r, i, a):
    """Rows r, r + 1, r + 2 of limb i <- a (3 values)."""
    W[_row(r, i)], W[_row(r + 1, i)], W[_row(r + 2, i)] = a


@kernel(inline="always", refcount=False)
def _put_limb(W, i, limb, j):
    W[_row(_OQ, i)] = limb[3]
    W[_row(_OJ, i)], W[_row(_OJ + 1, i)], W[_row(_OJ + 2, i)] = j


@kernel(inline="always", refcount=False)
def _translation(m, a, av, s):
    """s + body terms m J_v^T J_v (upper triangle), m J_v^T (dJ_v v), m dz/dX, for a body
    with J_v = a (9, row by row) and dJ_v v = av."""
    m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2 = s
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = a
    m00 += m * (a00 * a00 + a10 * a10 + a20 * a20)
    m01 += m * (a00 * a01 + a10 * a11 + a20 * a21)
    m02 += m * (a00 * a02 + a10 * a12 + a20 * a22)
    m11 += m * (a01 * a01 + a11 * a11 + a21 * a21)
    m12 += m * (a01 * a02 + a11 * a12 + a21 * a22)
    m22 += m * (a02 * a02 + a12 * a12 + a22 * a22)
    x0, x1, x2 = m * av[0], m * av[1], m * av[2]
    c0 += a00 * x0 + a10 * x1 + a20 * x2
    c1 += a01 * x0 + a11 * x1 + a21 * x2
    c2 += a02 * x0 + a12 * x1 + a22 * x2
    g0 += m * a20
    g1 += m * a21
    g2 += m * a22
    return m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2


@kernel(inline="always", refcount=False)
def _rotation(i0, i1, i2, R, Jw, aw, Xd, v, s):
    """s + a rotating frame's terms: with Jb = R^T J_w (the body-frame Jacobian) and the
    principal inertias I = (i0, i1, i2), M += Jb^T I Jb and C v += Jb^T (I R^T dJ_w v +
    omega_b x I Jb v), omega_b = Jb Xd. R (9, row by row), its columns the body axes."""
    m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2 = s
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R
    J00, J01, J02, J10, J11, J12, J20, J21, J22 = Jw
    b00 = R00 * J00 + R10 * J10 + R20 * J20  # rows of Jb = R^T J_w
    b01 = R00 * J01 + R10 * J11 + R20 * J21
    b02 = R00 * J02 + R10 * J12 + R20 * J22
    b10 = R01 * J00 + R11 * J10 + R21 * J20
    b11 = R01 * J01 + R11 * J11 + R21 * J21
    b12 = R01 * J02 + R11 * J12 + R21 * J22
    b20 = R02 * J00 + R12 * J10 + R22 * J20
    b21 = R02 * J01 + R12 * J11 + R22 * J21
    b22 = R02 * J02 + R12 * J12 + R22 * J22
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
    e0 = R00 * aw[0] + R10 * aw[1] + R20 * aw[2]  # R^T (dJ_w v)
    e1 = R01 * aw[0] + R11 * aw[1] + R21 * aw[2]
    e2 = R02 * aw[0] + R12 * aw[1] + R22 * aw[2]
    t0 = i0 * e0 + w1 * h2 - w2 * h1  # R^T (Iw dJ_w v + omega x Iw J_w v)
    t1 = i1 * e1 + w2 * h0 - w0 * h2
    t2 = i2 * e2 + w0 * h1 - w1 * h0
    c0 += b00 * t0 + b10 * t1 + b20 * t2
    c1 += b01 * t0 + b11 * t1 + b21 * t2
    c2 += b02 * t0 + b12 * t1 + b22 * t2
    return m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2


@kernel(inline="always", refcount=False)
def _platform_body(pm):
    """The platform's frame R (9), J_v (9), dJ_v v, J_w (9) and dJ_w v (body 0), from
    :func:`~pkmctl.model.kinematics.platform_motion`'s values ``pm``."""
    ca, sa, cb, sb, ta, _, zs, av01, aw01, aw02, _, _ = pm
    R = (cb, 0.0, sb, sa * sb, ca, -sa * cb, -ca * sb, sa, ca * cb)
    Jv = (0.0, 0.0, 0.0, -ta, -zs, 0.0, 1.0, 0.0, 0.0)
    Jw = (0.0, 1.0, 0.0, 0.0, 0.0, ca, 0.0, 0.0, sa)
    return R, Jv, (0.0, av01, 0.0), Jw, (0.0, aw01, aw02)


@kernel(inline="always", refcount=False)
def _limb_bodies(l1, l2, limb, K, aP, au):
    """J_v and dJ_v v of a limb's lower body (l1 J_u, l1 dJ_u v) and upper body
    (J_P - l2 J_u, dJ_P v - l2 dJ_u v); J_P = [[0, 0, p02], [p10, p11, p12], [1, p21, p22]]."""
    p02, p10, p11, p12, p21, p22 = limb[8:14]
    k00, k01, k02, k10, k11, k12, k20, k21, k22 = K
    lower = (l1 * k00, l1 * k01, l1 * k02, l1 * k10, l1 * k11, l1 * k12,
             l1 * k20, l1 * k21, l1 * k22)  # fmt: skip
    upper = (-l2 * k00, -l2 * k01, p02 - l2 * k02,
             p10 - l2 * k10, p11 - l2 * k11, p12 - l2 * k12,
             1.0 - l2 * k20, p21 - l2 * k21, p22 - l2 * k22)  # fmt: skip
    av_lo = (l1 * au[0], l1 * au[1], l1 * au[2])
    av_up = (aP[0] - l2 * au[0], aP[1] - l2 * au[1], aP[2] - l2 * au[2])
    return lower, av_lo, upper, av_up


@kernel(inline="always", refcount=False)
def _frame(x, y, limb):
    """The limb frame R_i = [x, y, u] (9, row by row)."""
    u0, u1, u2 = limb[5], limb[6], limb[7]
    return x[0], y[0], u0, x[1], y[1], u1, x[2], y[2], u2


@kernel(inline="always", refcount=False)
def _mass_column(g, a, av, r_dd):
    """A body's mass column of Y: J_v^T (J_v Xr_dd + dJ_v Xr_d) + g dz/dX."""
    v00, v01, v02, v10, v11, v12, v20, v21, v22 = a
    a0 = v00 * r_dd[0] + v01 * r_dd[1] + v02 * r_dd[2] + av[0]
    a1 = v10 * r_dd[0] + v11 * r_dd[1] + v12 * r_dd[2] + av[1]
    a2 = v20 * r_dd[0] + v21 * r_dd[1] + v22 * r_dd[2] + av[2]
    m0 = v00 * a0 + v10 * a1 + v20 * a2 + g * v20
    m1 = v01 * a0 + v11 * a1 + v21 * a2 + g * v21
    m2 = v02 * a0 + v12 * a1 + v22 * a2 + g * v22
    return m0, m1, m2


@kernel(inline="always", refcount=False)
def _inertia_column(x0, x1, x2, c, e, o, Jw):
    """The inertia column of Y for the body axis x: J_w^T (x a + b omega x x), a = x . c,
    b = x . e (see :func:`_inertia_columns`)."""
    w00, w01, w02, w10, w11, w12, w20, w21, w22 = Jw
    a_n = x0 * c[0] + x1 * c[1] + x2 * c[2]
    b_n = x0 * e[0] + x1 * e[1] + x2 * e[2]
    u0 = x0 * a_n + b_n * (o[1] * x2 - o[2] * x1)
    u1 = x1 * a_n + b_n * (o[2] * x0 - o[0] * x2)
    u2 = x2 * a_n + b_n * (o[0] * x1 - o[1] * x0)
    y0 = w00 * u0 + w10 * u1 + w20 * u2
    y1 = w01 * u0 + w11 * u1 + w21 * u2
    return y0, y1, w02 * u0 + w12 * u1 + w22 * u2


@kernel(inline="always", refcount=False)
def _inertia_columns(R, Jw, aw, Xd, r_d, r_dd):
    """A frame's three inertia columns of Y, one per body axis x = R[:, n] (R 9, row by
    row): J_w^T (x a_n + b_n omega x x), a_n = x . (dJ_w Xr_d + J_w Xr_dd),
    b_n = x . (J_w Xr_d), omega = J_w Xd (T is linear in I_n: R I R^T = sum I_n x x^T)."""
    w00, w01, w02, w10, w11, w12, w20, w21, w22 = Jw
    c = (aw[0] + w00 * r_dd[0] + w01 * r_dd[1] + w02 * r_dd[2],
         aw[1] + w10 * r_dd[0] + w11 * r_dd[1] + w12 * r_dd[2],
         aw[2] + w20 * r_dd[0] + w21 * r_dd[1] + w22 * r_dd[2])  # fmt: skip
    e = (w00 * r_d[0] + w01 * r_d[1] + w02 * r_d[2],
         w10 * r_d[0] + w11 * r_d[1] + w12 * r_d[2],
         w20 * r_d[0] + w21 * r_d[1] + w22 * r_d[2])  # fmt: skip
    o = (w00 * Xd[0] + w01 * Xd[1] + w02 * Xd[2],
         w10 * Xd[0] + w11 * Xd[1] + w12 * Xd[2],
         w20 * Xd[0] + w21 * Xd[1] + w22 * Xd[2])  # fmt: skip
    return (
        _inertia_column(R[0], R[3], R[6], c, e, o, Jw),
        _inertia_column(R[1], R[4], R[7], c, e, o, Jw),
        _inertia_column(R[2], R[5], R[8], c, e, o, Jw),
    )


@kernel(inline="always", refcount=False)
def limb_sums(l1, l2, masses, inertias, Xd, v, pm, spr, limb):
    """One limb's terms of M (upper triangle), C v and G, its two bodies and its frame
    (12 sums, :func:`_translation`'s order), its row of J and Jdot v: what the limb loops of the
    scalar and the lane kernels add up. ``masses`` (lower, upper), ``inertias`` the summed
    principal inertias (3), ``pm`` :func:`~pkmctl.model.kinematics.platform_motion`'s
    values, ``limb`` :func:`~pkmctl.model.kinematics._limb_at`'s."""
    ca, sa, _, _, _, _, _, av01, aw01, aw02, w0, wv0 = pm
    motion = limb_motion(Xd, v, ca, sa, av01, aw01, aw02, w0, wv0, spr, limb)
    j, jdv, K, aP, au, x, y, Jw, aw = motion
    lower, av_lo, upper, av_up = _limb_bodies(l1, l2, limb, K, aP, au)
    s = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    s = _translation(masses[0], lower, av_lo, s)
    s = _translation(masses[1], upper, av_up, s)
    s = _rotation(inertias[0], inertias[1], inertias[2], _frame(x, y, limb), Jw, aw, Xd, v, s)
    return j, jdv, s


@kernel(inline="always", refcount=False)
def platform_sums(theta0, Xd, v, pm):
    """The platform's terms of M (upper triangle), C v and G (12 sums): body 0 with
    Theta_0 = ``theta0`` (4: m, I_xx, I_yy, I_zz)."""
    R0, Jv0, av0, Jw0, aw0 = _platform_body(pm)
    s = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    s = _translation(theta0[0], Jv0, av0, s)
    return _rotation(theta0[1], theta0[2], theta0[3], R0, Jw0, aw0, Xd, v, s)


@kernel(inline="always", refcount=False)
def limb_gravity(l1, l2, mg_lo, mg_up, limb):
    """One limb's terms of G (3) and its row of J: m g dz/dX of its two bodies, whose rows
    2 of J_v are those of l1 J_u and J_P - l2 J_u, J_u = (I - u u^T) J_P / q."""
    _, _, _, _, iq, u0, u1, u2, p02, p10, p11, p12, p21, p22 = limb
    j = _limb_row(u0, u1, u2, p02, p10, p11, p12, p21, p22)
    k20, k21, k22 = (1.0 - u2 * j[0]) * iq, (p21 - u2 * j[1]) * iq, (p22 - u2 * j[2]) * iq
    g0 = mg_lo * (l1 * k20) + mg_up * (1.0 - l2 * k20)
    g1 = mg_lo * (l1 * k21) + mg_up * (p21 - l2 * k21)
    g2 = mg_lo * (l1 * k22) + mg_up * (p22 - l2 * k22)
    return j, (g0, g1, g2)


@kernel(inline="always", refcount=False)
def limb_columns(l1, l2, g, Xd, r_d, r_dd, pm, spr, limb):
    """One limb's columns of Y: the mass columns of its lower and upper bodies (3 each) and
    its frame's three inertia columns (9, column n's rows at 3 n), its row of J and
    Jdot Xr_d (``pm`` with v = Xr_d)."""
    ca, sa, _, _, _, _, _, av01, aw01, aw02, w0, wv0 = pm
    motion = limb_motion(Xd, r_d, ca, sa, av01, aw01, aw02, w0, wv0, spr, limb)
    j, jdv, K, aP, au, x, y, Jw, aw = motion
    lower, av_lo, upper, av_up = _limb_bodies(l1, l2, limb, K, aP, au)
    m_lo = _mass_column(g, lower, av_lo, r_dd)
    m_up = _mass_column(g, upper, av_up, r_dd)
    return j, jdv, m_lo, m_up, _inertia_columns(_frame(x, y, limb), Jw, aw, Xd, r_d, r_dd)


@kernel(inline="always", refcount=False)
def platform_columns(g, Xd, r_d, r_dd, pm):
    """The platform's mass column (3) and its three inertia columns of Y."""
    R0, Jv0, av0, Jw0, aw0 = _platform_body(pm)
    return _mass_column(g, Jv0, av0, r_dd), _inertia_columns(R0, Jw0, aw0, Xd, r_d, r_dd)


@kernel(inline="always", refcount=False)
def _limb_at_lane(geom, X, pm, i):
    """:func:`~pkmctl.model.kinematics._limb_at` of limb (lane) i."""
    ca, sa, cb, sb, ta, _, zs = pm[0:7]
    return _limb_at(geom[0], geom[1], X[0], ta, zs, ca, sa, cb, sb, _LIMB_COS[i], _LIMB_SIN[i])


@kernel(refcount=False, llvm_inline=True)
def dynamics_kernel(geom, theta, X, Xd, v, work, M, Cv, G):
    """Fill M (3, 3), C(X, Xd) v (3,) and G (3,) (eq. 9-24); the limb Jacobian and lengths
    at X and Jdot v go to ``work`` (:func:`make_work`).

    v = Xd gives the Coriolis/centrifugal vector of the plant; v = Xr_dot the
    controllers' C Xr_dot. The matrix C is C e_j column by column. The four limbs run as
    SIMD lanes (see above): each limb's two bodies and frame give one partial sum
    (:func:`limb_sums`), added to the platform's in the order of the limbs.
    """
    limb_vectors()
    W = stack_block(_BLOCK)
    Jq, q = work[JQ], work[Q]
    pm = platform_motion(X, Xd, v)
    _limb_parameters(geom, theta, W)
    for ii in range(_limbs(q)):
        i = np.uint64(ii)
        masses = (W[_row(_MLO, i)], W[_row(_MUP, i)])
        inertias = (W[_row(_I0, i)], W[_row(_I1, i)], W[_row(_I2, i)])
        limb = _limb_at_lane(geom, X, pm, i)
        j, jdv, s = limb_sums(W[_row(_L1, i)], W[_row(_L2, i)], masses, inertias, Xd, v,
                              pm, _LIMB_SPR[i] > 0.0, limb)  # fmt: skip
        W[_row(_OJDV, i)] = jdv
        _put3(W, _OS, i, s[0:3])
        _put3(W, _OS + 3, i, s[3:6])
        _put3(W, _OS + 6, i, s[6:9])
        _put3(W, _OS + 9, i, s[9:12])
        _put_limb(W, i, limb, j)
    s = platform_sums(theta[0:4], Xd, v, pm)
    for i in range(4):
        s = (s[0] + W[4 * _OS + i], s[1] + W[4 * (_OS + 1) + i], s[2] + W[4 * (_OS + 2) + i],
             s[3] + W[4 * (_OS + 3) + i], s[4] + W[4 * (_OS + 4) + i],
             s[5] + W[4 * (_OS + 5) + i], s[6] + W[4 * (_OS + 6) + i],
             s[7] + W[4 * (_OS + 7) + i], s[8] + W[4 * (_OS + 8) + i],
             s[9] + W[4 * (_OS + 9) + i], s[10] + W[4 * (_OS + 10) + i],
             s[11] + W[4 * (_OS + 11) + i])  # fmt: skip
    m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2 = s
    g = geom[10]
    M[0, 0], M[0, 1], M[0, 2] = m00, m01, m02
    M[1, 0], M[1, 1], M[1, 2] = m01, m11, m12
    M[2, 0], M[2, 1], M[2, 2] = m02, m12, m22
    Cv[0], Cv[1], Cv[2] = c0, c1, c2
    G[0], G[1], G[2] = g * g0, g * g1, g * g2
    _limbs_out(W, Jq, q)
    _jdv_out(W, work[JDV])


@kernel(refcount=False, llvm_inline=True)
def gravity_kernel(geom, theta, X, work, G):
    """Fill G (3,) at X: sum of m g dz_b/dX (eq. 24), without the velocity terms; the limb
    Jacobian and lengths at X go to ``work``."""
    limb_vectors()
    W = stack_block(_BLOCK)
    Jq, q = work[JQ], work[Q]
    _limb_parameters(geom, theta, W)
    g = geom[10]
    ca, sa, cb, sb = math.cos(X[1]), math.sin(X[1]), math.cos(X[2]), math.sin(X[2])
    ta = sa / ca
    zs = X[0] * (1.0 / (ca * ca))  # as platform_motion rounds it
    pm = (ca, sa, cb, sb, ta, 0.0, zs)
    for ii in range(_limbs(q)):
        i = np.uint64(ii)
        limb = _limb_at_lane(geom, X, pm, i)
        j, gl = limb_gravity(W[_row(_L1, i)], W[_row(_L2, i)], W[_row(_MLO, i)] * g,
                             W[_row(_MUP, i)] * g, limb)  # fmt: skip
        _put3(W, _OS, i, gl)
        _put_limb(W, i, limb, j)
    g0, g1, g2 = theta[0] * g, 0.0, 0.0  # the platform: dz/dX = e_z
    for i in range(4):
        g0 += W[4 * _OS + i]
        g1 += W[4 * (_OS + 1) + i]
        g2 += W[4 * (_OS + 2) + i]
    G[0], G[1], G[2] = g0, g1, g2
    _limbs_out(W, Jq, q)


@kernel(refcount=False, llvm_inline=True)
def regressor_kernel(geom, X, Xd, Xr_d, Xr_dd, work, Y):
    """Fill the regressor Y (3, 36) with Y Theta = M Xr_dd + C(X, Xd) Xr_d + G (eq. 24);
    the limb Jacobian and lengths at X and Jdot Xr_d go to ``work``.

    Column by column the dynamics of :func:`dynamics_kernel` with v = Xr_d and Xddot =
    Xr_dd, linear in Theta_b = [m, I_xx, I_yy, I_zz]: a body's mass column and its frame's
    three inertia columns (an upper limb turns with its lower limb: the same columns).
    """
    limb_vectors()
    W = stack_block(_BLOCK)
    Jq, q = work[JQ], work[Q]
    pm = platform_motion(X, Xd, Xr_d)
    _limb_lengths(geom, W)
    g = geom[10]
    for ii in range(_limbs(q)):
        i = np.uint64(ii)
        limb = _limb_at_lane(geom, X, pm, i)
        j, jdv, m_lo, m_up, cols = limb_columns(W[_row(_L1, i)], W[_row(_L2, i)], g, Xd,
                                                Xr_d, Xr_dd, pm, _LIMB_SPR[i] > 0.0,
                                                limb)  # fmt: skip
        W[_row(_OJDV, i)] = jdv
        _put3(W, _OS, i, m_lo)
        _put3(W, _OS + 3, i, m_up)
        _put3(W, _OS + 6, i, cols[0])
        _put3(W, _OS + 9, i, cols[1])
        _put3(W, _OS + 12, i, cols[2])
        _put_limb(W, i, limb, j)
    m, cols = platform_columns(g, Xd, Xr_d, Xr_dd, pm)
    for r in range(3):
        Y[r, 0], Y[r, 1], Y[r, 2], Y[r, 3] = m[r], cols[0][r], cols[1][r], cols[2][r]
    for i in range(4):
        for r in range(3):
            lo, up = 4 * (1 + i), 4 * (5 + i)
            Y[r, lo] = W[4 * (_OS + r) + i]
            Y[r, up] = W[4 * (_OS + 3 + r) + i]
            for n in range(3):
                Y[r, lo + 1 + n] = Y[r, up + 1 + n] = W[4 * (_OS + 6 + 3 * n + r) + i]
    _limbs_out(W, Jq, q)
    _jdv_out(W, work[JDV])


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
