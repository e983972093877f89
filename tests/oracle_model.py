"""Independent, deliberately simple oracle for the 2RPU-2SPR dynamics (DESIGN.md §1-§2).

This module shares no code with ``pkmctl``. It is written from DESIGN.md §1 alone and
works at the *position level only*: for a pose ``X = [z, alpha, beta]`` it returns the
centre of mass ``c_b`` and the rotation ``R_b`` of each of the 9 bodies (0 platform,
1-4 lower limbs of limbs 1-4, 5-8 upper limbs of limbs 1-4). Every velocity is obtained
by central finite differences along the path ``X + t Xdot``, refined by one Richardson
step, so the oracle never differentiates anything by hand:

    v_b   = d c_b(X + t Xdot) / dt            at t = 0
    [w_b] = skew( dR_b(X + t Xdot)/dt  R_b^T )    (spatial angular velocity, vee of it)

Kinetic and potential energy are linear in the 36 parameters
``Theta_b = [m_b, I_xx,b, I_yy,b, I_zz,b]``, so they are returned as *features*
``phi`` with ``T = phi . Theta`` and ``V = psi . Theta``. The mass matrix follows by
polarisation of ``T`` at unit velocities, gravity and the Christoffel vector by central
differences (again with one Richardson step) of ``V`` and of the oracle's own ``M``.

Accuracy (measured in ``test_dynamics_oracle.py::test_oracle_self_consistency``): the
Richardson-refined central difference with step ``h`` has truncation error ``O(h^4)`` and
round-off ``O(eps / h)``; with ``h = 2e-3`` both are ~1e-13 relative for velocities and M,
and ~1e-9 relative for the nested differences (gravity, Christoffel vector).
"""

from __future__ import annotations

import numpy as np

GRAVITY = 9.807  # m/s^2, DESIGN.md §1 (g = [0, 0, -9.807])

R_BASE = 0.339  # m, base joint radius r_b
R_PLATFORM = 0.2  # m, platform joint radius r_a
L1 = 0.2243  # m, lower-limb CoM offset from b_i along u_i
L2 = 0.2141  # m, upper-limb CoM offset from the platform joint along -u_i
JOINT_ANGLES = np.deg2rad([90.0, 180.0, 270.0, 0.0])  # theta_i, limbs 1..4

N_BODIES = 9
HOME = np.array([0.7, 0.0, 0.0])
HOME_LIMB_LENGTH = 0.71367  # m, DESIGN.md §1

# DESIGN.md §1 table: mass, then I_xx, I_yy, I_zz in the body frame.
_PLATFORM = (12.75, 0.077, 0.107, 0.183)
_LOWER = (0.95, 2.88e-2, 2.89e-2, 0.05e-2)
_UPPER = (1.10, 2.65e-2, 2.67e-2, 0.03e-2)

# Theta = [Theta_0 ... Theta_8], Theta_b = [m_b, I_xx, I_yy, I_zz] (36,)
THETA_PAPER = np.array(_PLATFORM + _LOWER * 4 + _UPPER * 4, dtype=float)

E_X = np.array([1.0, 0.0, 0.0])
E_Y = np.array([0.0, 1.0, 0.0])

# Joint points, rows i = 0..3 for limbs 1..4.
BASE_POINTS = R_BASE * np.stack([np.cos(JOINT_ANGLES), np.sin(JOINT_ANGLES), np.zeros(4)], axis=1)
PLATFORM_POINTS = R_PLATFORM * np.stack(
    [np.cos(JOINT_ANGLES), np.sin(JOINT_ANGLES), np.zeros(4)], axis=1
)

FD_STEP = 2e-3  # base step of the Richardson-refined central differences


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def platform_pose(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Platform centre p (3,) and orientation R = R_x(alpha) R_y(beta) (3, 3)."""
    z, alpha, beta = X
    p = np.array([0.0, -z * np.tan(alpha), z])
    return p, rot_x(alpha) @ rot_y(beta)


def limb_vectors(X: np.ndarray) -> np.ndarray:
    """d_i = p + R a_i - b_i, shape (4, 3)."""
    p, R = platform_pose(X)
    return p + PLATFORM_POINTS @ R.T - BASE_POINTS


def limb_lengths(X: np.ndarray) -> np.ndarray:
    """q_i = |d_i|, shape (4,)."""
    return np.linalg.norm(limb_vectors(X), axis=1)


def body_poses(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres of mass (9, 3) and rotations (9, 3, 3) of the 9 bodies at pose X."""
    X = np.asarray(X, dtype=float)
    p, R = platform_pose(X)
    centres = np.empty((N_BODIES, 3))
    rotations = np.empty((N_BODIES, 3, 3))
    centres[0] = p
    rotations[0] = R
    w = rot_x(X[1]) @ E_Y  # platform revolute axis of the SPR limbs 2 and 4
    for i in range(4):
        joint = p + R @ PLATFORM_POINTS[i]
        d = joint - BASE_POINTS[i]
        u = d / np.linalg.norm(d)
        x = E_X if i in (0, 2) else w  # limbs 1, 3 (RPU) | limbs 2, 4 (SPR)
        R_limb = np.column_stack([x, np.cross(u, x), u])
        centres[1 + i] = BASE_POINTS[i] + L1 * u
        centres[5 + i] = joint - L2 * u
        rotations[1 + i] = R_limb
        rotations[5 + i] = R_limb
    return centres, rotations


def path_derivative(f, X: np.ndarray, direction: np.ndarray, h: float = FD_STEP):
    """d/dt f(X + t direction) at t = 0: central differences + one Richardson step.

    The derivative is linear in ``direction``, so it is taken along the unit direction
    (a step of h in X whatever the speed) and scaled back: this keeps the accuracy
    independent of |direction|, down to velocities far below the resolution of X.
    """
    X = np.asarray(X, dtype=float)
    direction = np.asarray(direction, dtype=float)
    speed = np.linalg.norm(direction)
    if speed == 0.0:
        return 0.0 * np.asarray(f(X), dtype=float)
    unit = direction / speed

    def central(step):
        return (f(X + step * unit) - f(X - step * unit)) / (2.0 * step)

    d_h = central(h)
    d_h2 = central(h / 2.0)
    return speed * (4.0 * d_h2 - d_h) / 3.0


def _vee(S: np.ndarray) -> np.ndarray:
    """Vector of the skew-symmetric part of S (..., 3, 3) -> (..., 3)."""
    A = 0.5 * (S - np.swapaxes(S, -1, -2))
    return np.stack([A[..., 2, 1], A[..., 0, 2], A[..., 1, 0]], axis=-1)


def body_velocities(X: np.ndarray, Xdot: np.ndarray, h: float = FD_STEP):
    """CoM velocities (9, 3) and spatial angular velocities (9, 3), by finite differences."""
    X = np.asarray(X, dtype=float)
    Xdot = np.asarray(Xdot, dtype=float)

    def stacked(Xs):
        c, R = body_poses(Xs)
        return np.concatenate([c.ravel(), R.ravel()])

    rate = path_derivative(stacked, X, Xdot, h)
    v = rate[: 3 * N_BODIES].reshape(N_BODIES, 3)
    R_dot = rate[3 * N_BODIES :].reshape(N_BODIES, 3, 3)
    _, R = body_poses(X)
    omega = _vee(R_dot @ np.swapaxes(R, -1, -2))
    return v, omega


def kinetic_features(X: np.ndarray, Xdot: np.ndarray, h: float = FD_STEP) -> np.ndarray:
    """phi (36,) with T(X, Xdot, Theta) = phi . Theta.

    T = sum_b 1/2 m_b |v_b|^2 + 1/2 w_b^T R_b I_b R_b^T w_b, and with I_b diagonal the
    rotational term is sum_k 1/2 I_k,b ((R_b^T w_b)_k)^2.
    """
    v, omega = body_velocities(X, Xdot, h)
    _, R = body_poses(X)
    omega_body = np.einsum("bji,bj->bi", R, omega)  # R_b^T w_b
    phi = np.empty((N_BODIES, 4))
    phi[:, 0] = 0.5 * np.sum(v * v, axis=1)
    phi[:, 1:] = 0.5 * omega_body**2
    return phi.ravel()


def potential_features(X: np.ndarray) -> np.ndarray:
    """psi (36,) with V(X, Theta) = psi . Theta = sum_b m_b g z_b."""
    c, _ = body_poses(X)
    psi = np.zeros((N_BODIES, 4))
    psi[:, 0] = GRAVITY * c[:, 2]
    return psi.ravel()


def kinetic_energy(X, Xdot, theta=THETA_PAPER, h: float = FD_STEP) -> float:
    return float(kinetic_features(X, Xdot, h) @ np.asarray(theta, dtype=float))


def potential_energy(X, theta=THETA_PAPER) -> float:
    return float(potential_features(X) @ np.asarray(theta, dtype=float))


def mass_matrix_basis(X: np.ndarray, h: float = FD_STEP) -> np.ndarray:
    """M_k (36, 3, 3) with M(X, Theta) = sum_k Theta_k M_k, by polarisation of T.

    M_jj = 2 T(e_j) and M_jk = T(e_j + e_k) - T(e_j) - T(e_k).
    """
    eye = np.eye(3)
    single = [kinetic_features(X, eye[j], h) for j in range(3)]
    basis = np.empty((36, 3, 3))
    for j in range(3):
        basis[:, j, j] = 2.0 * single[j]
        for k in range(j + 1, 3):
            pair = kinetic_features(X, eye[j] + eye[k], h) - single[j] - single[k]
            basis[:, j, k] = pair
            basis[:, k, j] = pair
    return basis


def mass_matrix(X, theta=THETA_PAPER, h: float = FD_STEP) -> np.ndarray:
    """M(X) (3, 3) = Hessian of T in Xdot."""
    return np.tensordot(np.asarray(theta, dtype=float), mass_matrix_basis(X, h), axes=1)


def gravity_basis(X: np.ndarray, h: float = FD_STEP) -> np.ndarray:
    """(36, 3): G(X, Theta) = Theta @ gravity_basis = grad_X V, by central differences."""
    X = np.asarray(X, dtype=float)
    eye = np.eye(3)
    return np.stack([path_derivative(potential_features, X, eye[i], h) for i in range(3)], axis=1)


def gravity(X, theta=THETA_PAPER, h: float = FD_STEP) -> np.ndarray:
    """G(X) (3,) = dV/dX."""
    return np.asarray(theta, dtype=float) @ gravity_basis(X, h)


def mass_matrix_derivative_basis(X: np.ndarray, h: float = FD_STEP) -> np.ndarray:
    """(36, 3, 3, 3): [k, i, a, b] = d(M_k)_ab / dX_i, by central differences of M."""
    X = np.asarray(X, dtype=float)
    eye = np.eye(3)
    out = np.empty((36, 3, 3, 3))
    for i in range(3):
        out[:, i] = path_derivative(mass_matrix_basis, X, eye[i], h)
    return out


def christoffel_basis(X, Xdot, h: float = FD_STEP) -> np.ndarray:
    """(36, 3): Coriolis/centrifugal vector c(X, Xdot, Theta) = Theta @ christoffel_basis.

    c_k = sum_ij (dM_kj/dX_i - 1/2 dM_ij/dX_k) Xdot_i Xdot_j, with dM from central
    differences of the oracle's own M (itself from T), never from pkmctl.
    """
    Xdot = np.asarray(Xdot, dtype=float)
    dM = mass_matrix_derivative_basis(X, h)  # [p, i, a, b] = d(M_p)_ab / dX_i
    term1 = np.einsum("pikj,i,j->pk", dM, Xdot, Xdot)
    term2 = np.einsum("pkij,i,j->pk", dM, Xdot, Xdot)
    return term1 - 0.5 * term2


def christoffel_vector(X, Xdot, theta=THETA_PAPER, h: float = FD_STEP) -> np.ndarray:
    """Coriolis/centrifugal vector (3,) for the parameters theta."""
    return np.asarray(theta, dtype=float) @ christoffel_basis(X, Xdot, h)
