"""Kinematics of the 2RPU-2SPR manipulator (DESIGN.md §1; the paper's eq. 1-8).

Pose ``X = [z, alpha, beta]``; platform centre ``p = [0, -z tan(alpha), z]`` (eq. 1-3,
with the misprint of eq. 2 corrected), orientation ``R = R_x(alpha) R_y(beta)``.
Limb ``i`` joins the base point ``b_i`` to the platform point ``p + R a_i``; its length
is ``q_i`` and its unit vector ``u_i`` (eq. 4, without the misprinted division by s_i).

The compiled kernels here work on a geometry vector ``geom`` (see
:data:`GEOM_SIZE`) so they can be called from other compiled code; the
:class:`pkmctl.Mechanism` methods wrap them for users.

``geom = [r_a, r_b, l1_1..l1_4, l2_1..l2_4, g]``: platform and base radii, the
distance of the lower-limb centre of mass from its base joint and of the upper-limb
centre of mass from its platform joint, and the gravitational acceleration.

The body kernel :func:`body_jacobians` returns, for the 9 bodies (0 platform,
1-4 lower limbs, 5-8 upper limbs), the centre-of-mass position, the body frame
``R_b``, the Jacobians ``J_v`` (v = J_v Xdot) and ``J_w`` (omega = J_w Xdot) and their
time derivatives along ``Xdot``. Everything is closed form; nothing is
finite-differenced.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "GEOM_SIZE",
    "LIMB_ANGLES_DEG",
    "N_BODIES",
    "body_jacobians",
    "forward_kinematics_kernel",
    "limb_kinematics",
]

#: Joint angles theta_i of limbs 1..4 around the z axis (DESIGN.md §1): +y, -x, -y, +x.
LIMB_ANGLES_DEG = (90.0, 180.0, 270.0, 0.0)
# cos/sin of those angles, exact (no 6e-17 residues).
_LIMB_DIR = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])
#: Limbs whose joint axis turns with the platform (SPR: limbs 2 and 4, zero-based 1 and 3).
_SPR = np.array([False, True, False, True])
N_BODIES = 9
GEOM_SIZE = 11


@njit(cache=True, nogil=True, inline="always")
def _cx(a0, a1, a2, b0, b1, b2):
    """a x b on scalars (no array views in the hot loop)."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, nogil=True)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=True, nogil=True)
def _platform(X, Xd, p, R, Jv, Jw, dJv, dJw):
    """Platform centre, frame and Jacobians (eq. 1-3), with their time derivatives."""
    z, a, b = X[0], X[1], X[2]
    zd, ad = Xd[0], Xd[1]
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    ta = sa / ca
    sec2 = 1.0 / (ca * ca)
    p[0], p[1], p[2] = 0.0, -z * ta, z
    # R = R_x(alpha) R_y(beta)
    R[0, 0], R[0, 1], R[0, 2] = cb, 0.0, sb
    R[1, 0], R[1, 1], R[1, 2] = sa * sb, ca, -sa * cb
    R[2, 0], R[2, 1], R[2, 2] = -ca * sb, sa, ca * cb
    Jv[:, :] = 0.0
    Jw[:, :] = 0.0
    dJv[:, :] = 0.0
    dJw[:, :] = 0.0
    # dp/dz and dp/dalpha
    Jv[1, 0], Jv[2, 0] = -ta, 1.0
    Jv[1, 1] = -z * sec2
    dJv[1, 0] = -sec2 * ad
    dJv[1, 1] = -(zd * sec2 + 2.0 * z * sec2 * ta * ad)
    # omega = alpha_dot e_x + beta_dot R_x(alpha) e_y
    Jw[0, 1] = 1.0
    Jw[1, 2], Jw[2, 2] = ca, sa
    dJw[1, 2], dJw[2, 2] = -sa * ad, ca * ad


@njit(cache=True, nogil=True)
def body_jacobians(geom, X, Xd, com, Rb, Jv, Jw, dJv, dJw, Jq, q, vec, mat):
    """Fill the kinematics of all 9 bodies and of the 4 limbs at (X, Xd).

    Parameters
    ----------
    geom : ndarray, shape (11,)
    X, Xd : ndarray, shape (3,)
        Pose and pose rate.
    com : ndarray, shape (9, 3)
        Out: centres of mass in B.
    Rb : ndarray, shape (9, 3, 3)
        Out: body frames (columns are the body axes in B).
    Jv, Jw, dJv, dJw : ndarray, shape (9, 3, 3)
        Out: linear and angular velocity Jacobians and their time derivatives.
    Jq : ndarray, shape (4, 3)
        Out: the limb Jacobian J = dq/dX (eq. 8).
    q : ndarray, shape (4,)
        Out: limb lengths.
    vec, mat : ndarray, shape (9, 3) and (4, 3, 3)
        Scratch space, so that the control loop does not allocate.
    """
    r_a, r_b = geom[0], geom[1]
    ca, sa = math.cos(X[1]), math.sin(X[1])
    p = com[0]
    _platform(X, Xd, p, Rb[0], Jv[0], Jw[0], dJv[0], dJw[0])
    R = Rb[0]
    rho, rhod, P, u, ud = vec[0], vec[1], vec[2], vec[3], vec[4]
    tmp, tmp2, w0 = vec[5], vec[6], vec[8]
    JP, dJP, Ju, dJu = mat[0], mat[1], mat[2], mat[3]
    for k in range(3):  # platform angular velocity
        w0[k] = Jw[0, k, 0] * Xd[0] + Jw[0, k, 1] * Xd[1] + Jw[0, k, 2] * Xd[2]
    for i in range(4):
        cth, sth = _LIMB_DIR[i, 0], _LIMB_DIR[i, 1]
        for k in range(3):
            rho[k] = r_a * (R[k, 0] * cth + R[k, 1] * sth)
        _cross(w0, rho, rhod)
        for k in range(3):
            P[k] = p[k] + rho[k]
        d0, d1, d2 = P[0] - r_b * cth, P[1] - r_b * sth, P[2]
        qi = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        q[i] = qi
        iq = 1.0 / qi
        u[0], u[1], u[2] = d0 * iq, d1 * iq, d2 * iq
        # J_P: velocity of the platform joint point; dJ_P its time derivative
        for j in range(3):
            wj0, wj1, wj2 = Jw[0, 0, j], Jw[0, 1, j], Jw[0, 2, j]
            dw0, dw1, dw2 = dJw[0, 0, j], dJw[0, 1, j], dJw[0, 2, j]
            t0, t1, t2 = _cx(wj0, wj1, wj2, rho[0], rho[1], rho[2])
            s0, s1, s2 = _cx(dw0, dw1, dw2, rho[0], rho[1], rho[2])
            c0, c1, c2 = _cx(wj0, wj1, wj2, rhod[0], rhod[1], rhod[2])
            JP[0, j] = Jv[0, 0, j] + t0
            JP[1, j] = Jv[0, 1, j] + t1
            JP[2, j] = Jv[0, 2, j] + t2
            dJP[0, j] = dJv[0, 0, j] + s0 + c0
            dJP[1, j] = dJv[0, 1, j] + s1 + c1
            dJP[2, j] = dJv[0, 2, j] + s2 + c2
        # q_dot = u . P_dot ; u_dot = (I - u u^T) P_dot / q
        Pd = tmp
        for k in range(3):
            Pd[k] = JP[k, 0] * Xd[0] + JP[k, 1] * Xd[1] + JP[k, 2] * Xd[2]
        qd = u[0] * Pd[0] + u[1] * Pd[1] + u[2] * Pd[2]
        for k in range(3):
            ud[k] = (Pd[k] - u[k] * qd) * iq
        for j in range(3):
            uv = u[0] * JP[0, j] + u[1] * JP[1, j] + u[2] * JP[2, j]
            udv = ud[0] * JP[0, j] + ud[1] * JP[1, j] + ud[2] * JP[2, j]
            udP = u[0] * dJP[0, j] + u[1] * dJP[1, j] + u[2] * dJP[2, j]
            Jq[i, j] = uv
            for k in range(3):
                ju = (JP[k, j] - u[k] * uv) * iq
                Ju[k, j] = ju
                # d/dt[(I - u u^T)/q] v  +  (I - u u^T)/q  dJ_P v
                dJu[k, j] = (dJP[k, j] - u[k] * udP - ud[k] * uv - u[k] * udv) * iq - ju * qd * iq
        lo, up = 1 + i, 5 + i
        l1, l2 = geom[2 + i], geom[6 + i]
        for k in range(3):
            com[lo, k] = r_b * (cth if k == 0 else (sth if k == 1 else 0.0)) + l1 * u[k]
            com[up, k] = P[k] - l2 * u[k]
            for j in range(3):
                Jv[lo, k, j] = l1 * Ju[k, j]
                dJv[lo, k, j] = l1 * dJu[k, j]
                Jv[up, k, j] = JP[k, j] - l2 * Ju[k, j]
                dJv[up, k, j] = dJP[k, j] - l2 * dJu[k, j]
        # Limb frame [x_i, u_i x x_i, u_i]; x_i = e_x (RPU) or w = R_x(alpha) e_y (SPR).
        spr = _SPR[i]
        if spr:
            tmp[0], tmp[1], tmp[2] = 0.0, ca, sa
        else:
            tmp[0], tmp[1], tmp[2] = 1.0, 0.0, 0.0
        _cross(u, tmp, tmp2)
        for k in range(3):
            Rb[lo, k, 0] = tmp[k]
            Rb[lo, k, 1] = tmp2[k]
            Rb[lo, k, 2] = u[k]
        # omega_i = u x u_dot + spin u; for SPR the spin (x_dot . y) is alpha_dot * u_x.
        for j in range(3):
            t0, t1, t2 = _cx(u[0], u[1], u[2], Ju[0, j], Ju[1, j], Ju[2, j])
            s0, s1, s2 = _cx(ud[0], ud[1], ud[2], Ju[0, j], Ju[1, j], Ju[2, j])
            c0, c1, c2 = _cx(u[0], u[1], u[2], dJu[0, j], dJu[1, j], dJu[2, j])
            Jw[lo, 0, j] = t0
            Jw[lo, 1, j] = t1
            Jw[lo, 2, j] = t2
            dJw[lo, 0, j] = s0 + c0
            dJw[lo, 1, j] = s1 + c1
            dJw[lo, 2, j] = s2 + c2
        if spr:
            for k in range(3):
                Jw[lo, k, 1] += u[0] * u[k]
                dJw[lo, k, 1] += ud[0] * u[k] + u[0] * ud[k]
        Rb[up] = Rb[lo]
        Jw[up] = Jw[lo]
        dJw[up] = dJw[lo]


@njit(cache=True, nogil=True)
def limb_kinematics(geom, X, Jq, q):
    """Limb lengths ``q`` (4,) and Jacobian ``Jq`` (4, 3) at pose X (eq. 4-8)."""
    com = np.empty((N_BODIES, 3))
    Rb = np.empty((N_BODIES, 3, 3))
    Jv, Jw = np.empty((N_BODIES, 3, 3)), np.empty((N_BODIES, 3, 3))
    dJv, dJw = np.empty((N_BODIES, 3, 3)), np.empty((N_BODIES, 3, 3))
    body_jacobians(
        geom,
        X,
        np.zeros(3),
        com,
        Rb,
        Jv,
        Jw,
        dJv,
        dJw,
        Jq,
        q,
        np.empty((9, 3)),
        np.empty((4, 3, 3)),
    )


@njit(cache=True, nogil=True)
def forward_kinematics_kernel(geom, q_target, guess, tol, max_iter):
    """Levenberg-Marquardt on the four limb lengths, from ``guess``.

    Returns ``(X, residual_norm, iterations)``; the caller decides what is converged.
    """
    X = guess.copy()
    Jq = np.empty((4, 3))
    q = np.empty(4)
    mu = 1e-9
    limb_kinematics(geom, X, Jq, q)
    r = q - q_target
    cost = r @ r
    it = 0
    for it in range(1, max_iter + 1):
        if math.sqrt(cost) < tol:
            break
        A = Jq.T @ Jq
        g = Jq.T @ r
        for _ in range(30):
            step = np.linalg.solve(A + mu * np.eye(3), -g)
            Xn = X + step
            # keep inside the chart (z > 0, |angles| < pi/2) while searching
            if Xn[0] <= 0.0 or abs(Xn[1]) >= 1.5 or abs(Xn[2]) >= 1.5:
                mu *= 10.0
                continue
            limb_kinematics(geom, Xn, Jq, q)
            rn = q - q_target
            cn = rn @ rn
            if cn < cost:
                X, r, cost = Xn, rn, cn
                mu = max(mu * 0.1, 1e-15)
                break
            mu *= 10.0
        else:
            limb_kinematics(geom, X, Jq, q)
            return X, math.sqrt(cost), it
        limb_kinematics(geom, X, Jq, q)
    return X, math.sqrt(cost), it
