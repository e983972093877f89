"""The machine as built (DESIGN.md §7): reflected rotor inertia, joint friction, a payload.

Terms added to the rigid model of §2, each in task space:

- rotor inertia: every motor adds 1/2 m_r,i qdot_i^2 to the kinetic energy, with
  m_r = J_m (2 pi / l)^2 (kg, l the screw lead), so M += J^T diag(m_r) J and
  C v += J^T diag(m_r) (Jdot v), Jdot along Xdot (Mdot - 2C stays skew);
- friction at the actuated joints: f_i = F_c,i tanh(qdot_i / v_s) + F_v,i qdot_i (N),
  opposing motion, J^T f in task space;
- a payload: a point mass m at o in the platform frame, P = p + R o:
  M += m J_P^T J_P, C v += m J_P^T (dJ_P v), G += m g (dP_z/dX).

The extended regressor Y_ext (3, 48) adds columns for m_r (4), F_c (4) and F_v (4) to
the rigid model's Y (3, 36): Y_ext Theta_ext = M Xr_ddot + C Xr_dot + G + rotor + friction
with Theta_ext = [Theta, m_r, F_c, F_v] (DESIGN.md §7). All kernels allocate nothing.
"""

from __future__ import annotations

import math

from pkmctl._jit import kernel
from pkmctl.model.dynamics import JDV, JQ, N_THETA, regressor_kernel
from pkmctl.model.kinematics import limb_jacobian_rate, platform_point

__all__ = [
    "N_MACHINE_MODEL",
    "N_THETA_EXT",
    "add_machine_model",
    "add_payload",
    "add_rotor_inertia",
    "extended_regressor_kernel",
    "friction_law",
    "reflected_inertia",
]

#: Length of Theta_ext = [Theta (36), m_r (4), F_c (4), F_v (4)].
N_THETA_EXT = N_THETA + 12


def reflected_inertia(rotor_inertia: float, screw_lead: float) -> float:
    """m_r = J_m (2 pi / l)^2 (kg): a rotor of inertia J_m (kg m^2) on a screw of lead l (m)."""
    return rotor_inertia * (2.0 * math.pi / screw_lead) ** 2


@kernel(inline="always", refcount=False)
def friction_law(fc, fv, vs, qd):
    """f = F_c tanh(qdot / v_s) + F_v qdot (N): the smooth Coulomb + viscous law of §7."""
    return fc * math.tanh(qd / vs) + fv * qd


@kernel(inline="always", refcount=False)
def add_rotor_inertia(m_r, Jq, Jdv, M, Cv):
    """M += J^T diag(m_r) J (3, 3) and C v += J^T diag(m_r) Jdv (3,), Jdv = Jdot v (4,)."""
    for i in range(4):
        m = m_r[i]
        for a in range(3):
            ma = m * Jq[i, a]
            Cv[a] += ma * Jdv[i]
            for b in range(a, 3):  # the upper triangle, mirrored: M stays exactly symmetric
                M[a, b] += ma * Jq[i, b]
    M[1, 0], M[2, 0], M[2, 1] = M[0, 1], M[0, 2], M[1, 2]


@kernel(refcount=False, llvm_inline=True)
def add_payload(geom, mass, offset, X, Xd, v, R, M, Cv, G):
    """Add a point mass ``mass`` (kg) at ``offset`` (3,) in the platform frame to M (3, 3),
    C(X, Xd) v (3,) and G (3,). ``R`` (3, 3) is scratch (receives the orientation)."""
    z = X[0]
    ca, sa, cb, sb = math.cos(X[1]), math.sin(X[1]), math.cos(X[2]), math.sin(X[2])
    ta = sa / ca
    sec2 = 1.0 / (ca * ca)
    R[0, 0], R[0, 1], R[0, 2] = cb, 0.0, sb
    R[1, 0], R[1, 1], R[1, 2] = sa * sb, ca, -sa * cb
    R[2, 0], R[2, 1], R[2, 2] = -ca * sb, sa, ca * cb
    _, _, _, p02, p10, p11, p12, p21, p22, a0, a1, a2 = platform_point(
        z, ta, z * sec2, sec2, ca, sa, R, offset[0], offset[1], offset[2], Xd, v
    )
    # columns of J_P: c0 = (0, p10, 1), c1 = (0, p11, p21), c2 = (p02, p12, p22)
    m = mass
    M[0, 0] += m * (p10 * p10 + 1.0)
    M[0, 1] += m * (p10 * p11 + p21)
    M[0, 2] += m * (p10 * p12 + p22)
    M[1, 1] += m * (p11 * p11 + p21 * p21)
    M[1, 2] += m * (p11 * p12 + p21 * p22)
    M[2, 2] += m * (p02 * p02 + p12 * p12 + p22 * p22)
    M[1, 0], M[2, 0], M[2, 1] = M[0, 1], M[0, 2], M[1, 2]
    Cv[0] += m * (p10 * a1 + a2)
    Cv[1] += m * (p11 * a1 + p21 * a2)
    Cv[2] += m * (p02 * a0 + p12 * a1 + p22 * a2)
    g = geom[10]
    G[0] += m * g
    G[1] += m * g * p21
    G[2] += m * g * p22


@kernel(refcount=False, llvm_inline=True)
def extended_regressor_kernel(geom, X, Xd, Xr_d, Xr_dd, vs, work, Y):
    """Fill Y_ext (3, 48): Y_ext Theta_ext = M Xr_dd + C(X, Xd) Xr_d + G + rotor + friction.

    Columns 0-35: the rigid regressor (eq. 24); 36-39: J_i^T (J_i Xr_dd + Jdot_i Xr_d)
    (rotor inertia m_r,i); 40-43: J_i^T tanh(qdot_i / vs) (Coulomb F_c,i); 44-47:
    J_i^T qdot_i (viscous F_v,i), qdot = J Xd the actual limb rates. ``work`` is a
    dynamics workspace (:func:`~pkmctl.model.dynamics.make_work`): the regressor leaves
    J and Jdot Xr_d there.
    """
    regressor_kernel(geom, X, Xd, Xr_d, Xr_dd, work, Y)
    Jq, Jdv = work[JQ], work[JDV]
    for i in range(4):
        qa = Jq[i, 0] * Xr_dd[0] + Jq[i, 1] * Xr_dd[1] + Jq[i, 2] * Xr_dd[2] + Jdv[i]
        qd = Jq[i, 0] * Xd[0] + Jq[i, 1] * Xd[1] + Jq[i, 2] * Xd[2]
        th = math.tanh(qd / vs)
        for a in range(3):
            Y[a, N_THETA + i] = Jq[i, a] * qa
            Y[a, N_THETA + 4 + i] = Jq[i, a] * th
            Y[a, N_THETA + 8 + i] = Jq[i, a] * qd


#: Length of a controller's machine model: m_r (4), F_c (4), F_v (4), v_s.
N_MACHINE_MODEL = 13


@kernel(refcount=False, llvm_inline=True)
def add_machine_model(geom, mm, X, Xd, v, a, R, Jq, q, Jdv, F):
    """F += J^T diag(m_r) (J a + Jdot v) + J^T f(J Xd): a controller's model of the rotors
    and the friction (columns 36-47 of the extended regressor times [m_r, F_c, F_v], with
    Xr_dot = v and Xr_ddot = a). ``mm`` = [m_r (4), F_c (4), F_v (4), v_s] (13,); Jdot is
    along Xd; R (3, 3), Jq (4, 3), q (4,), Jdv (4,) scratch. Allocates nothing."""
    limb_jacobian_rate(geom, X, Xd, v, R, Jq, q, Jdv)
    for i in range(4):
        qa = Jq[i, 0] * a[0] + Jq[i, 1] * a[1] + Jq[i, 2] * a[2] + Jdv[i]
        qd = Jq[i, 0] * Xd[0] + Jq[i, 1] * Xd[1] + Jq[i, 2] * Xd[2]
        fi = mm[i] * qa + friction_law(mm[4 + i], mm[8 + i], mm[12], qd)
        for k in range(3):
            F[k] += Jq[i, k] * fi
