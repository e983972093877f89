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
time derivatives along ``Xdot`` applied to a vector. Everything is closed form;
nothing is finite-differenced.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import kernel

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


@kernel(inline="always")
def _cx(a0, a1, a2, b0, b1, b2):
    """a x b on scalars (no array views in the hot loop)."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@kernel
def body_jacobians(geom, X, Xd, v, com, Rb, Jv, Jw, av, aw, Jq, q, vec, mat):
    """Fill the kinematics of all 9 bodies and of the 4 limbs at (X, Xd).

    Besides the Jacobians, it gives their time derivatives (along Xd) applied to one
    vector v: ``av = dJ_v v`` and ``aw = dJ_w v``. Every dynamic quantity needs only
    that product (v = Xdot for the plant, v = Xr_dot for the controllers), which is
    three times cheaper than the full derivative matrices.

    Parameters
    ----------
    geom : ndarray, shape (11,)
    X, Xd, v : ndarray, shape (3,)
        Pose, pose rate, and the vector the Jacobian derivatives are applied to.
    com : ndarray, shape (9, 3)
        Out: centres of mass in B.
    Rb : ndarray, shape (9, 3, 3)
        Out: body frames (columns are the body axes in B).
    Jv, Jw : ndarray, shape (9, 3, 3)
        Out: linear and angular velocity Jacobians (v_b = Jv Xd, omega_b = Jw Xd).
    av, aw : ndarray, shape (9, 3)
        Out: dJv/dt v and dJw/dt v.
    Jq : ndarray, shape (4, 3)
        Out: the limb Jacobian J = dq/dX (eq. 8).
    q : ndarray, shape (4,)
        Out: limb lengths.
    vec, mat : ndarray, shape (9, 3) and (4, 3, 3)
        Scratch space, so that the control loop does not allocate.
    """
    r_a, r_b = geom[0], geom[1]
    z, zd, ad, bd = X[0], Xd[0], Xd[1], Xd[2]
    ca, sa, cb, sb = math.cos(X[1]), math.sin(X[1]), math.cos(X[2]), math.sin(X[2])
    ta = sa / ca
    sec2 = 1.0 / (ca * ca)
    # -- platform (eq. 1-3): p = [0, -z tan a, z], R = R_x(a) R_y(b),
    #    omega = a_dot e_x + b_dot R_x(a) e_y
    com[0, 0], com[0, 1], com[0, 2] = 0.0, -z * ta, z
    R = Rb[0]
    R[0, 0], R[0, 1], R[0, 2] = cb, 0.0, sb
    R[1, 0], R[1, 1], R[1, 2] = sa * sb, ca, -sa * cb
    R[2, 0], R[2, 1], R[2, 2] = -ca * sb, sa, ca * cb
    Jv[0, :, :] = 0.0
    Jw[0, :, :] = 0.0
    Jv[0, 1, 0], Jv[0, 2, 0] = -ta, 1.0
    Jv[0, 1, 1] = -z * sec2
    Jw[0, 0, 1] = 1.0
    Jw[0, 1, 2], Jw[0, 2, 2] = ca, sa
    av[0, 0], av[0, 2] = 0.0, 0.0
    av[0, 1] = -sec2 * ad * v[0] - (zd * sec2 + 2.0 * z * sec2 * ta * ad) * v[1]
    aw[0, 0], aw[0, 1], aw[0, 2] = 0.0, -sa * ad * v[2], ca * ad * v[2]
    w0x, w0y, w0z = ad, ca * bd, sa * bd  # platform angular velocity
    wv0x, wv0y, wv0z = v[1], ca * v[2], sa * v[2]  # J_w v
    u, ud, aP, au = vec[0], vec[1], vec[2], vec[3]
    JP, Ju = mat[0], mat[1]
    for i in range(4):
        cth, sth = _LIMB_DIR[i, 0], _LIMB_DIR[i, 1]
        rx = r_a * (R[0, 0] * cth + R[0, 1] * sth)  # rho = R a_i
        ry = r_a * (R[1, 0] * cth + R[1, 1] * sth)
        rz = r_a * (R[2, 0] * cth + R[2, 1] * sth)
        rdx, rdy, rdz = _cx(w0x, w0y, w0z, rx, ry, rz)  # rho_dot = omega x rho
        Px, Py, Pz = com[0, 0] + rx, com[0, 1] + ry, com[0, 2] + rz
        d0, d1, d2 = Px - r_b * cth, Py - r_b * sth, Pz
        qi = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        q[i] = qi
        iq = 1.0 / qi
        u[0], u[1], u[2] = d0 * iq, d1 * iq, d2 * iq
        # J_P: velocity of the platform joint, columns Jv0[:, j] + Jw0[:, j] x rho
        for j in range(3):
            t0, t1, t2 = _cx(Jw[0, 0, j], Jw[0, 1, j], Jw[0, 2, j], rx, ry, rz)
            JP[0, j] = Jv[0, 0, j] + t0
            JP[1, j] = Jv[0, 1, j] + t1
            JP[2, j] = Jv[0, 2, j] + t2
        # dJ_P v = av0 + aw0 x rho + (Jw0 v) x rho_dot
        t0, t1, t2 = _cx(aw[0, 0], aw[0, 1], aw[0, 2], rx, ry, rz)
        s0, s1, s2 = _cx(wv0x, wv0y, wv0z, rdx, rdy, rdz)
        aP[0], aP[1], aP[2] = av[0, 0] + t0 + s0, av[0, 1] + t1 + s1, av[0, 2] + t2 + s2
        # P_dot, q_dot = u . P_dot, u_dot = (I - u u^T) P_dot / q; P_v = J_P v
        Pd0 = JP[0, 0] * Xd[0] + JP[0, 1] * Xd[1] + JP[0, 2] * Xd[2]
        Pd1 = JP[1, 0] * Xd[0] + JP[1, 1] * Xd[1] + JP[1, 2] * Xd[2]
        Pd2 = JP[2, 0] * Xd[0] + JP[2, 1] * Xd[1] + JP[2, 2] * Xd[2]
        Pv0 = JP[0, 0] * v[0] + JP[0, 1] * v[1] + JP[0, 2] * v[2]
        Pv1 = JP[1, 0] * v[0] + JP[1, 1] * v[1] + JP[1, 2] * v[2]
        Pv2 = JP[2, 0] * v[0] + JP[2, 1] * v[1] + JP[2, 2] * v[2]
        qd = u[0] * Pd0 + u[1] * Pd1 + u[2] * Pd2
        ud[0], ud[1], ud[2] = (Pd0 - u[0] * qd) * iq, (Pd1 - u[1] * qd) * iq, (Pd2 - u[2] * qd) * iq
        # J_u = (I - u u^T) J_P / q, so u_dot = J_u Xd; J = u^T J_P (eq. 8)
        for j in range(3):
            uj = u[0] * JP[0, j] + u[1] * JP[1, j] + u[2] * JP[2, j]
            Jq[i, j] = uj
            for k in range(3):
                Ju[k, j] = (JP[k, j] - u[k] * uj) * iq
        # dJ_u v = d/dt[(I - u u^T)/q] P_v + (I - u u^T)/q dJ_P v
        uPv = u[0] * Pv0 + u[1] * Pv1 + u[2] * Pv2
        udPv = ud[0] * Pv0 + ud[1] * Pv1 + ud[2] * Pv2
        uaP = u[0] * aP[0] + u[1] * aP[1] + u[2] * aP[2]
        Juv0, Juv1, Juv2 = (Pv0 - u[0] * uPv) * iq, (Pv1 - u[1] * uPv) * iq, (Pv2 - u[2] * uPv) * iq
        for k in range(3):
            au[k] = (aP[k] - u[k] * (uaP + udPv) - ud[k] * uPv) * iq
        au[0] -= Juv0 * qd * iq
        au[1] -= Juv1 * qd * iq
        au[2] -= Juv2 * qd * iq
        lo, up = 1 + i, 5 + i
        l1, l2 = geom[2 + i], geom[6 + i]
        com[lo, 0], com[lo, 1], com[lo, 2] = r_b * cth + l1 * u[0], r_b * sth + l1 * u[1], l1 * u[2]
        com[up, 0], com[up, 1], com[up, 2] = Px - l2 * u[0], Py - l2 * u[1], Pz - l2 * u[2]
        for k in range(3):
            for j in range(3):
                Jv[lo, k, j] = l1 * Ju[k, j]
                Jv[up, k, j] = JP[k, j] - l2 * Ju[k, j]
            av[lo, k] = l1 * au[k]
            av[up, k] = aP[k] - l2 * au[k]
        # Limb frame [x_i, u_i x x_i, u_i]; x_i = e_x (RPU) or w = R_x(alpha) e_y (SPR).
        spr = _SPR[i]
        if spr:
            x0, x1, x2 = 0.0, ca, sa
        else:
            x0, x1, x2 = 1.0, 0.0, 0.0
        y0, y1, y2 = _cx(u[0], u[1], u[2], x0, x1, x2)
        Rb[lo, 0, 0], Rb[lo, 1, 0], Rb[lo, 2, 0] = x0, x1, x2
        Rb[lo, 0, 1], Rb[lo, 1, 1], Rb[lo, 2, 1] = y0, y1, y2
        Rb[lo, 0, 2], Rb[lo, 1, 2], Rb[lo, 2, 2] = u[0], u[1], u[2]
        # omega_i = u x u_dot + spin u; for SPR the spin (x_dot . y) is alpha_dot u_x,
        # so J_w = [u]x J_u (+ u u_x in the alpha column) and
        # dJ_w v = u_dot x (J_u v) + u x (dJ_u v) (+ v_alpha (u_dot_x u + u_x u_dot)).
        for j in range(3):
            t0, t1, t2 = _cx(u[0], u[1], u[2], Ju[0, j], Ju[1, j], Ju[2, j])
            Jw[lo, 0, j], Jw[lo, 1, j], Jw[lo, 2, j] = t0, t1, t2
        t0, t1, t2 = _cx(ud[0], ud[1], ud[2], Juv0, Juv1, Juv2)
        s0, s1, s2 = _cx(u[0], u[1], u[2], au[0], au[1], au[2])
        aw[lo, 0], aw[lo, 1], aw[lo, 2] = t0 + s0, t1 + s1, t2 + s2
        if spr:
            for k in range(3):
                Jw[lo, k, 1] += u[0] * u[k]
                aw[lo, k] += v[1] * (ud[0] * u[k] + u[0] * ud[k])
        Rb[up] = Rb[lo]
        Jw[up] = Jw[lo]
        aw[up] = aw[lo]


@kernel
def limb_kinematics(geom, X, Jq, q):
    """Limb lengths ``q`` (4,) and Jacobian ``Jq`` (4, 3) at pose X (eq. 4-8)."""
    z3 = np.zeros(3)
    m3 = np.empty((3, N_BODIES, 3, 3))  # Rb, Jv, Jw (must not alias: Jv, Jw are read back)
    m1 = np.empty((4, N_BODIES, 3))  # com, av, aw, scratch
    body_jacobians(
        geom, X, z3, z3, m1[0], m3[0], m3[1], m3[2], m1[1], m1[2], Jq, q, m1[3], np.empty((4, 3, 3))
    )


@kernel
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
