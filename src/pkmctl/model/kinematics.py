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

The body kinematics of the dynamics (9 bodies: 0 platform, 1-4 lower limbs, 5-8 upper
limbs) come limb by limb: :func:`platform_motion` gives what the platform contributes and
every limb reuses, :func:`limb_motion` one limb's frame, velocity Jacobians and their time
derivatives along ``Xdot`` applied to a vector, without a branch on the limb's kind, so
that the dynamics kernels run the four limbs as four SIMD lanes of one loop
(:mod:`pkmctl.model.dynamics`). Everything is closed form; nothing is finite-differenced.
"""

from __future__ import annotations

import math

import numpy as np

from pkmctl._jit import kernel

__all__ = [
    "GEOM_SIZE",
    "LIMB_ANGLES_DEG",
    "N_BODIES",
    "forward_kinematics_kernel",
    "limb_jacobian",
    "limb_jacobian_rate",
    "limb_motion",
    "platform_motion",
    "platform_point",
    "platform_rates",
]

#: Joint angles theta_i of limbs 1..4 around the z axis (DESIGN.md §1): +y, -x, -y, +x.
LIMB_ANGLES_DEG = (90.0, 180.0, 270.0, 0.0)
# cos/sin of those angles, exact (no 6e-17 residues).
_LIMB_DIR = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])
#: Limbs whose joint axis turns with the platform (SPR: limbs 2 and 4, zero-based 1 and 3).
_SPR = np.array([False, True, False, True])
# The same per limb, as arrays a loop over the limbs (SIMD lanes) indexes: cos theta_i,
# sin theta_i, and 1.0 for an SPR limb.
_LIMB_COS = np.ascontiguousarray(_LIMB_DIR[:, 0])
_LIMB_SIN = np.ascontiguousarray(_LIMB_DIR[:, 1])
_LIMB_SPR = _SPR.astype(np.float64)
N_BODIES = 9
GEOM_SIZE = 11


@kernel(inline="always")
def _cx(a0, a1, a2, b0, b1, b2):
    """a x b on scalars (no array views in the hot loop)."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@kernel(inline="always", refcount=False)
def _limb_at(r_a, r_b, z, ta, zs, ca, sa, cb, sb, cth, sth):
    """The limb at angle theta (cos cth, sin sth) at the platform pose: rho = R a, the
    length q, 1/q, the unit vector u and the non-trivial entries of J_P = dP/dX (eq. 4-8).
    R's first two columns are written from (ca, sa, cb, sb) here, as the callers store R:
    scalars stay in registers, where values read back from R would be reloaded after every
    store into the outputs."""
    rx = r_a * (cb * cth)  # rho = R a_i (R[0, 1] = 0)
    ry = r_a * (sa * sb * cth + ca * sth)
    rz = r_a * (-ca * sb * cth + sa * sth)
    Px, Py, Pz = rx, -z * ta + ry, z + rz  # P = p + rho
    d0, d1, d2 = Px - r_b * cth, Py - r_b * sth, Pz
    qi = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    iq = 1.0 / qi
    # J_P = Jv0 + [Jw0 columns] x rho, written out (the z column has no rotation,
    # the alpha column turns about e_x, the beta column about R_x(alpha) e_y)
    p02 = ca * rz - sa * ry
    p10, p11, p12 = -ta, -zs - rz, sa * rx
    p21, p22 = ry, -ca * rx
    return rx, ry, rz, qi, iq, d0 * iq, d1 * iq, d2 * iq, p02, p10, p11, p12, p21, p22


@kernel(inline="always", refcount=False)
def _limb(r_a, r_b, z, ta, zs, ca, sa, cb, sb, i):
    """:func:`_limb_at` of limb i (a constant index into the limb angles)."""
    return _limb_at(r_a, r_b, z, ta, zs, ca, sa, cb, sb, _LIMB_DIR[i, 0], _LIMB_DIR[i, 1])


@kernel(inline="always", refcount=False)
def _limb_row(u0, u1, u2, p02, p10, p11, p12, p21, p22):
    """The row J_i = u^T J_P of the limb Jacobian (eq. 8)."""
    return u1 * p10 + u2, u1 * p11 + u2 * p21, u0 * p02 + u1 * p12 + u2 * p22


@kernel(refcount=False)
def limb_jacobian(geom, X, R, Jq, q):
    """Limb lengths ``q`` (4,) and Jacobian ``Jq`` (4, 3) at pose X (eq. 4-8), without the
    body kinematics; ``R`` (3, 3) receives the platform orientation. Allocates nothing."""
    r_a, r_b, z = geom[0], geom[1], X[0]
    ca, sa, cb, sb = math.cos(X[1]), math.sin(X[1]), math.cos(X[2]), math.sin(X[2])
    ta = sa / ca
    zs = z * (1.0 / (ca * ca))  # as platform_motion rounds it
    R[0, 0], R[0, 1], R[0, 2] = cb, 0.0, sb
    R[1, 0], R[1, 1], R[1, 2] = sa * sb, ca, -sa * cb
    R[2, 0], R[2, 1], R[2, 2] = -ca * sb, sa, ca * cb
    for i in range(4):
        _, _, _, qi, _, u0, u1, u2, p02, p10, p11, p12, p21, p22 = _limb(
            r_a, r_b, z, ta, zs, ca, sa, cb, sb, i
        )
        q[i] = qi
        Jq[i, 0], Jq[i, 1], Jq[i, 2] = _limb_row(u0, u1, u2, p02, p10, p11, p12, p21, p22)


@kernel(inline="always", refcount=False)
def platform_point(z, ta, zs, sec2, ca, sa, R, ox, oy, oz, Xd, v):
    """A point fixed on the platform at ``o`` (platform frame): rho = R o, J_P = dP/dX and
    dJ_P/dt v along Xd (the derivative of eq. 4-8's J_P, applied to one vector v).

    Returns rho (3 scalars), the non-trivial entries p02, p10, p11, p12, p21, p22 of
    J_P = [[0, 0, p02], [p10, p11, p12], [1, p21, p22]] and dJ_P v (3 scalars).
    """
    zd, ad, bd = Xd[0], Xd[1], Xd[2]
    rx = R[0, 0] * ox + R[0, 1] * oy + R[0, 2] * oz
    ry = R[1, 0] * ox + R[1, 1] * oy + R[1, 2] * oz
    rz = R[2, 0] * ox + R[2, 1] * oy + R[2, 2] * oz
    p02 = ca * rz - sa * ry
    p10, p11, p12 = -ta, -zs - rz, sa * rx
    p21, p22 = ry, -ca * rx
    # dJ_P v = dJv0 v + (dJw0 v) x rho + (Jw0 v) x (omega x rho), as in limb_motion
    av1 = -sec2 * ad * v[0] - (zd * sec2 + 2.0 * z * sec2 * ta * ad) * v[1]
    t0, t1, t2 = _cx(0.0, -sa * ad * v[2], ca * ad * v[2], rx, ry, rz)
    rdx, rdy, rdz = _cx(ad, ca * bd, sa * bd, rx, ry, rz)
    s0, s1, s2 = _cx(v[1], ca * v[2], sa * v[2], rdx, rdy, rdz)
    return rx, ry, rz, p02, p10, p11, p12, p21, p22, t0 + s0, av1 + t1 + s1, t2 + s2


@kernel(refcount=False, llvm_inline=True)
def limb_jacobian_rate(geom, X, Xd, v, R, Jq, q, Jdv):
    """Limb lengths ``q`` (4,), Jacobian ``Jq`` (4, 3) and ``Jdv`` (4,) = (dJ/dt along Xd) v.

    With v = Xd, Jdv is the velocity part of the limb accelerations,
    qddot = J Xddot + Jdot Xdot. Row i: J_i = u_i^T J_P,i (eq. 8), so
    Jdot_i v = udot_i . (J_P,i v) + u_i . (dJ_P,i v) with udot = (I - u u^T) Pdot / q.
    ``R`` (3, 3) receives the platform orientation. Allocates nothing.
    """
    r_a, r_b, z = geom[0], geom[1], X[0]
    zd, ad, bd = Xd[0], Xd[1], Xd[2]
    ca, sa, cb, sb = math.cos(X[1]), math.sin(X[1]), math.cos(X[2]), math.sin(X[2])
    ta = sa / ca
    sec2 = 1.0 / (ca * ca)
    zs = z * sec2
    R[0, 0], R[0, 1], R[0, 2] = cb, 0.0, sb
    R[1, 0], R[1, 1], R[1, 2] = sa * sb, ca, -sa * cb
    R[2, 0], R[2, 1], R[2, 2] = -ca * sb, sa, ca * cb
    for i in range(4):
        ox, oy = r_a * _LIMB_DIR[i, 0], r_a * _LIMB_DIR[i, 1]
        rx, ry, rz, p02, p10, p11, p12, p21, p22, a0, a1, a2 = platform_point(
            z, ta, zs, sec2, ca, sa, R, ox, oy, 0.0, Xd, v
        )
        d0, d1, d2 = rx - r_b * _LIMB_DIR[i, 0], -z * ta + ry - r_b * _LIMB_DIR[i, 1], z + rz
        qi = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        iq = 1.0 / qi
        u0, u1, u2 = d0 * iq, d1 * iq, d2 * iq
        j0, j1, j2 = _limb_row(u0, u1, u2, p02, p10, p11, p12, p21, p22)
        q[i] = qi
        Jq[i, 0], Jq[i, 1], Jq[i, 2] = j0, j1, j2
        Pd0 = p02 * bd
        Pd1 = p10 * zd + p11 * ad + p12 * bd
        Pd2 = zd + p21 * ad + p22 * bd
        Pv0 = p02 * v[2]
        Pv1 = p10 * v[0] + p11 * v[1] + p12 * v[2]
        Pv2 = v[0] + p21 * v[1] + p22 * v[2]
        qd = u0 * Pd0 + u1 * Pd1 + u2 * Pd2
        qv = u0 * Pv0 + u1 * Pv1 + u2 * Pv2
        Jdv[i] = (Pd0 * Pv0 + Pd1 * Pv1 + Pd2 * Pv2 - qd * qv) * iq + (u0 * a0 + u1 * a1 + u2 * a2)


@kernel(inline="always", refcount=False)
def platform_rates(z, Xd, v, ca, sa):
    """The platform's values every limb reuses (eq. 1-3), from the pose's z, cos and sin
    of alpha, Xd and v (3 each, arrays or tuples): tan alpha, sec^2 alpha, z sec^2 alpha,
    the non-zero entries of dJ_v v and dJ_w v of the platform (body 0): av = (0, av01, 0),
    aw = (0, aw01, aw02), its angular velocity omega = a_dot e_x + b_dot R_x(alpha) e_y and
    J_w v."""
    zd, ad, bd = Xd[0], Xd[1], Xd[2]
    v0, v1, v2 = v[0], v[1], v[2]
    ta = sa / ca
    sec2 = 1.0 / (ca * ca)
    av01 = -sec2 * ad * v0 - (zd * sec2 + 2.0 * z * sec2 * ta * ad) * v1
    aw01, aw02 = -sa * ad * v2, ca * ad * v2
    w0 = (ad, ca * bd, sa * bd)  # platform angular velocity
    wv0 = (v1, ca * v2, sa * v2)  # J_w v
    return ta, sec2, z * sec2, av01, aw01, aw02, w0, wv0


@kernel(inline="always", refcount=False)
def platform_motion(X, Xd, v):
    """cos and sin of alpha and beta (libm), then :func:`platform_rates`."""
    ca, sa, cb, sb = math.cos(X[1]), math.sin(X[1]), math.cos(X[2]), math.sin(X[2])
    return (ca, sa, cb, sb) + platform_rates(X[0], Xd, v, ca, sa)


@kernel(inline="always", refcount=False)
def limb_motion(Xd, v, ca, sa, av01, aw01, aw02, w0, wv0, spr, limb):
    """The velocity kinematics of one limb, from its :func:`_limb_at` values ``limb``.

    The limb's two bodies share its frame R_i = [x_i, u_i x x_i, u_i] and angular
    velocity; the lower body's centre of mass is l1 u from the base joint, the upper
    body's l2 u before the platform joint, so both velocity Jacobians follow from J_P and
    J_u = du/dX = (I - u u^T) J_P / q:

        J_v,lower = l1 J_u,   J_v,upper = J_P - l2 J_u,   J_w = [u]x J_u (+ u u_x e_alpha^T)

    and their time derivatives along Xd applied to v from dJ_P v and dJ_u v (the product
    is all any dynamic quantity needs: v = Xdot for the plant, v = Xr_dot for the
    controllers). ``spr`` (a bool, possibly per SIMD lane) marks an SPR limb, whose joint
    axis x_i = R_x(alpha) e_y turns with the platform and adds the spin (x_dot . y) u =
    alpha_dot u_x u to omega; an RPU limb has x_i = e_x. Branch-free: the SPR terms are
    selects, so the four limbs vectorise as one loop.

    Returns ``(j, jdv, K, aP, au, x, y, Jw, aw)``: the row j = u^T J_P of the limb
    Jacobian (eq. 8), jdv = (dJ_i/dt along Xd) v = u_dot . (J_P v) + u . (dJ_P v) (the
    rotor inertia's term, §7), J_u (9, row by row), dJ_P v and dJ_u v (3 each), the frame
    axes x and y (3 each), J_w (9, row by row) and dJ_w v (3).
    """
    zd, ad, bd = Xd[0], Xd[1], Xd[2]
    v0, v1, v2 = v[0], v[1], v[2]
    rx, ry, rz, qi, iq, u0, u1, u2, p02, p10, p11, p12, p21, p22 = limb
    rdx, rdy, rdz = _cx(w0[0], w0[1], w0[2], rx, ry, rz)  # rho_dot = omega x rho
    # dJ_P v = av0 + aw0 x rho + (Jw0 v) x rho_dot
    t0, t1, t2 = _cx(0.0, aw01, aw02, rx, ry, rz)
    s0, s1, s2 = _cx(wv0[0], wv0[1], wv0[2], rdx, rdy, rdz)
    aP0, aP1, aP2 = t0 + s0, av01 + t1 + s1, t2 + s2
    # P_dot = J_P Xd, P_v = J_P v; q_dot = u . P_dot; u_dot = (I - u u^T) P_dot / q
    Pd0 = p02 * bd
    Pd1 = p10 * zd + p11 * ad + p12 * bd
    Pd2 = zd + p21 * ad + p22 * bd
    Pv0 = p02 * v2
    Pv1 = p10 * v0 + p11 * v1 + p12 * v2
    Pv2 = v0 + p21 * v1 + p22 * v2
    qd = u0 * Pd0 + u1 * Pd1 + u2 * Pd2
    ud0, ud1, ud2 = (Pd0 - u0 * qd) * iq, (Pd1 - u1 * qd) * iq, (Pd2 - u2 * qd) * iq
    # J = u^T J_P (eq. 8); J_u = (I - u u^T) J_P / q, so u_dot = J_u Xd
    j0, j1, j2 = _limb_row(u0, u1, u2, p02, p10, p11, p12, p21, p22)
    k00, k01, k02 = -u0 * j0 * iq, -u0 * j1 * iq, (p02 - u0 * j2) * iq
    k10, k11, k12 = (p10 - u1 * j0) * iq, (p11 - u1 * j1) * iq, (p12 - u1 * j2) * iq
    k20, k21, k22 = (1.0 - u2 * j0) * iq, (p21 - u2 * j1) * iq, (p22 - u2 * j2) * iq
    # dJ_u v = d/dt[(I - u u^T)/q] P_v + (I - u u^T)/q dJ_P v
    uPv = u0 * Pv0 + u1 * Pv1 + u2 * Pv2
    udPv = ud0 * Pv0 + ud1 * Pv1 + ud2 * Pv2
    uaP = u0 * aP0 + u1 * aP1 + u2 * aP2
    Juv0, Juv1, Juv2 = (Pv0 - u0 * uPv) * iq, (Pv1 - u1 * uPv) * iq, (Pv2 - u2 * uPv) * iq
    cc = uaP + udPv
    au0 = (aP0 - u0 * cc - ud0 * uPv - Juv0 * qd) * iq
    au1 = (aP1 - u1 * cc - ud1 * uPv - Juv1 * qd) * iq
    au2 = (aP2 - u2 * cc - ud2 * uPv - Juv2 * qd) * iq
    # Limb frame [x_i, u_i x x_i, u_i]; x_i = e_x (RPU) or w = R_x(alpha) e_y (SPR).
    x0 = 0.0 if spr else 1.0
    x1 = ca if spr else 0.0
    x2 = sa if spr else 0.0
    y0, y1, y2 = _cx(u0, u1, u2, x0, x1, x2)
    # omega_i = u x u_dot + spin u; for SPR the spin (x_dot . y) is alpha_dot u_x,
    # so J_w = [u]x J_u (+ u u_x in the alpha column) and
    # dJ_w v = u_dot x (J_u v) + u x (dJ_u v) (+ v_alpha (u_dot_x u + u_x u_dot)).
    w00, w10, w20 = _cx(u0, u1, u2, k00, k10, k20)
    w01, w11, w21 = _cx(u0, u1, u2, k01, k11, k21)
    w02, w12, w22 = _cx(u0, u1, u2, k02, k12, k22)
    t0, t1, t2 = _cx(ud0, ud1, ud2, Juv0, Juv1, Juv2)
    s0, s1, s2 = _cx(u0, u1, u2, au0, au1, au2)
    e0, e1, e2 = t0 + s0, t1 + s1, t2 + s2
    # (a + (m if spr else 0.0), not (a + m if spr else a): the same sum, and a select of
    # two operands where the other form vectorises to a masked load and store)
    w01 += (u0 * u0) if spr else 0.0
    w11 += (u0 * u1) if spr else 0.0
    w21 += (u0 * u2) if spr else 0.0
    e0 += (v1 * (ud0 * u0 + u0 * ud0)) if spr else 0.0
    e1 += (v1 * (ud0 * u1 + u0 * ud1)) if spr else 0.0
    e2 += (v1 * (ud0 * u2 + u0 * ud2)) if spr else 0.0
    return (
        (j0, j1, j2),
        cc,
        (k00, k01, k02, k10, k11, k12, k20, k21, k22),
        (aP0, aP1, aP2),
        (au0, au1, au2),
        (x0, x1, x2),
        (y0, y1, y2),
        (w00, w01, w02, w10, w11, w12, w20, w21, w22),
        (e0, e1, e2),
    )


@kernel
def forward_kinematics_kernel(geom, q_target, guess, tol, max_iter):
    """Levenberg-Marquardt on the four limb lengths, from ``guess``.

    Returns ``(X, residual_norm, iterations)``; the caller decides what is converged.
    """
    X = guess.copy()
    Jq = np.empty((4, 3))
    q = np.empty(4)
    R = np.empty((3, 3))
    mu = 1e-9
    limb_jacobian(geom, X, R, Jq, q)
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
            # keep inside the chart (z > 0, |angles| < pi/2) while searching (a bound of
            # 1.5 rad refused valid poses beyond it as "did not converge": a code reader)
            if Xn[0] <= 0.0 or abs(Xn[1]) >= 0.5 * math.pi or abs(Xn[2]) >= 0.5 * math.pi:
                mu *= 10.0
                continue
            limb_jacobian(geom, Xn, R, Jq, q)
            rn = q - q_target
            cn = rn @ rn
            if cn < cost:
                X, r, cost = Xn, rn, cn
                mu = max(mu * 0.1, 1e-15)
                break
            mu *= 10.0
        else:
            limb_jacobian(geom, X, R, Jq, q)
            return X, math.sqrt(cost), it
        limb_jacobian(geom, X, R, Jq, q)
    return X, math.sqrt(cost), it
