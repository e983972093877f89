"""pkmctl's kinematics and dynamics against an independent finite-difference oracle.

The oracle (``oracle_model.py``) is written from DESIGN.md §1-§2 alone and shares no code
with pkmctl: it computes body poses only, and gets every velocity, M, G and the
Coriolis/centrifugal vector from central differences (refined by one Richardson step).
Only the public interface of DESIGN.md §5 is used here.

Tolerances come from the oracle's own measured accuracy (``test_oracle_self_consistency``
bounds it by comparing two step sizes): M and G to ~1e-11 relative, the Christoffel vector
(a nested difference) to ~1e-9. Each comparison allows about 100x that, and never more
than the ~1e-6 relative that a formula error would exceed by orders of magnitude.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import pkmctl

try:  # tests/ as a package
    from . import oracle_model as om
except ImportError:  # tests/ on sys.path (pytest's default rootdir-less layout)
    import oracle_model as om

SEEDS = list(range(8))

# Oracle accuracy, relative to the largest entry of the quantity, measured between FD steps
# 2e-3 and 1e-3 and over 50 random states: <= 2e-11 for M and G, <= 1.5e-9 for the
# Christoffel vector (a difference of differences: round-off eps*|M|/h^2 ~ 1e-9). The
# tolerances allow ~50-100x that.
RTOL_M = 1e-9
RTOL_G = 1e-9
RTOL_CORIOLIS = 1e-7
# Two closed forms of the same exact quantity differ only by round-off.
RTOL_EXACT = 1e-11


def random_pose(rng: np.random.Generator) -> np.ndarray:
    """z in [0.55, 0.85] m, alpha and beta in [-0.6, 0.6] rad (the valid workspace)."""
    return np.array([rng.uniform(0.55, 0.85), rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6)])


def random_state(seed: int) -> tuple[np.ndarray, np.ndarray, np.random.Generator]:
    rng = np.random.default_rng(seed)
    X = random_pose(rng)
    Xdot = rng.normal(size=3)  # m/s and rad/s of order 1
    return X, Xdot, rng


def random_theta(rng: np.random.Generator) -> np.ndarray:
    """Random physical parameters: each mass and each principal second moment of mass
    (s_x = (I_yy + I_zz - I_xx)/2, ...) scaled by its own factor in [0.2, 5], so that the
    inertias stay positive and satisfy the triangle inequality I_a + I_b >= I_c."""
    theta = om.THETA_PAPER.reshape(om.N_BODIES, 4).copy()
    inertia = theta[:, 1:]
    second_moments = 0.5 * (inertia.sum(axis=1, keepdims=True) - 2.0 * inertia)
    assert np.all(second_moments >= 0.0)
    second_moments = second_moments * rng.uniform(0.2, 5.0, size=second_moments.shape)
    theta[:, 0] *= rng.uniform(0.2, 5.0, size=om.N_BODIES)
    theta[:, 1:] = second_moments.sum(axis=1, keepdims=True) - second_moments
    return theta.ravel()


def assert_close_in_norm(actual, desired, rtol, scale=None, err_msg=""):
    """max |actual - desired| <= rtol * scale, scale = max |desired| unless given."""
    actual = np.asarray(actual, dtype=float)
    desired = np.asarray(desired, dtype=float)
    assert actual.shape == desired.shape, (actual.shape, desired.shape)
    if scale is None:
        scale = np.max(np.abs(desired))
    np.testing.assert_allclose(actual, desired, rtol=0.0, atol=rtol * scale, err_msg=err_msg)


@pytest.fixture(scope="module")
def robot():
    return pkmctl.Mechanism.paper()


# --------------------------------------------------------------------------- the oracle itself


def test_oracle_self_consistency():
    """The oracle agrees with itself across FD steps, its frames are rotations, and
    Xdot^T Mdot Xdot = 2 Xdot^T c (energy balance of its own M and c)."""
    for seed in SEEDS[:3]:
        X, Xdot, _ = random_state(seed)
        _, R = om.body_poses(X)
        np.testing.assert_allclose(
            R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-14
        )
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
        M, M2 = om.mass_matrix(X), om.mass_matrix(X, h=om.FD_STEP / 2)
        assert_close_in_norm(M2, M, rtol=RTOL_M / 10)
        G, G2 = om.gravity(X), om.gravity(X, h=om.FD_STEP / 2)
        assert_close_in_norm(G2, G, rtol=RTOL_G / 10)
        c, c2 = om.christoffel_vector(X, Xdot), om.christoffel_vector(X, Xdot, h=om.FD_STEP / 2)
        assert_close_in_norm(c2, c, rtol=RTOL_CORIOLIS / 10)
        M_dot = om.path_derivative(om.mass_matrix, X, Xdot)
        speed2 = Xdot @ Xdot
        assert Xdot @ M_dot @ Xdot == pytest.approx(
            2.0 * Xdot @ c, rel=0.0, abs=RTOL_CORIOLIS / 10 * np.linalg.norm(M_dot) * speed2
        )
        # T is a quadratic form in Xdot: 1/2 Xdot^T M Xdot at an arbitrary Xdot.
        assert om.kinetic_energy(X, Xdot) == pytest.approx(
            0.5 * Xdot @ M @ Xdot, rel=0.0, abs=RTOL_M / 10 * np.linalg.norm(M) * speed2
        )


def test_oracle_home_pose_matches_design():
    """DESIGN.md §1: limbs 0.71367 m, lower/upper CoM at heights 0.22 m / 0.49 m at home."""
    np.testing.assert_allclose(om.limb_lengths(om.HOME), om.HOME_LIMB_LENGTH, atol=1e-5)
    centres, _ = om.body_poses(om.HOME)
    np.testing.assert_allclose(centres[1:5, 2], 0.22, atol=1e-4)
    np.testing.assert_allclose(centres[5:9, 2], 0.49, atol=1e-4)


# --------------------------------------------------------------------------- 1. parameters


def test_theta_matches_design_table(robot):
    theta = np.asarray(robot.theta)
    assert theta.shape == (36,)
    assert theta.dtype == np.float64
    np.testing.assert_allclose(theta, om.THETA_PAPER, rtol=1e-12, atol=0.0)


def test_with_theta_keeps_the_given_parameters(robot):
    theta = random_theta(np.random.default_rng(11))
    other = robot.with_theta(theta)
    np.testing.assert_array_equal(np.asarray(other.theta), theta)
    # the original is untouched (no hidden mutation)
    np.testing.assert_allclose(np.asarray(robot.theta), om.THETA_PAPER, rtol=1e-12, atol=0.0)


# --------------------------------------------------------------------------- 2. kinematics


def test_home_limb_lengths(robot):
    q = robot.inverse_kinematics(om.HOME.copy())
    assert q.shape == (4,)
    np.testing.assert_allclose(q, om.HOME_LIMB_LENGTH, rtol=0.0, atol=1e-5)


@pytest.mark.parametrize("seed", SEEDS)
def test_inverse_kinematics_matches_oracle(robot, seed):
    X, _, _ = random_state(seed)
    # both are closed forms of |d_i|: only round-off may differ
    np.testing.assert_allclose(
        robot.inverse_kinematics(X), om.limb_lengths(X), rtol=RTOL_EXACT, atol=0.0
    )


@pytest.mark.parametrize("seed", SEEDS)
def test_jacobian_matches_finite_differences(robot, seed):
    X, Xdot, _ = random_state(seed)
    J = robot.jacobian(X)
    assert J.shape == (4, 3)
    J_fd = np.column_stack([om.path_derivative(om.limb_lengths, X, e) for e in np.eye(3)])
    # Richardson-refined central difference of smooth q(X): error ~1e-12 (h^4 and eps/h)
    assert_close_in_norm(J, J_fd, rtol=1e-9)
    assert_close_in_norm(J @ Xdot, om.path_derivative(om.limb_lengths, X, Xdot), rtol=1e-9)


@pytest.mark.parametrize("seed", SEEDS[:4])
def test_actuator_forces_are_minimum_norm(robot, seed):
    X, _, rng = random_state(seed)
    F = rng.normal(scale=[100.0, 10.0, 10.0])
    tau = robot.actuator_forces(X, F)
    assert tau.shape == (4,)
    J = np.column_stack([om.path_derivative(om.limb_lengths, X, e) for e in np.eye(3)])
    # J^T tau = F, and tau in the range of J (minimum norm) <=> tau = pinv(J^T) F.
    # J is the oracle's (FD, ~1e-12 accurate), so this is independent of pkmctl.jacobian.
    assert_close_in_norm(J.T @ tau, F, rtol=1e-9)
    assert_close_in_norm(tau, np.linalg.pinv(J.T) @ F, rtol=1e-9)


# --------------------------------------------------------------------------- 3. mass matrix


@pytest.mark.parametrize("seed", SEEDS)
def test_mass_matrix_is_hessian_of_kinetic_energy(robot, seed):
    X, Xdot, _ = random_state(seed)
    M = robot.mass_matrix(X)
    assert M.shape == (3, 3)
    scale = np.linalg.norm(M)
    np.testing.assert_allclose(M, M.T, rtol=0.0, atol=RTOL_EXACT * scale)
    assert np.all(np.linalg.eigvalsh(0.5 * (M + M.T)) > 0.0)
    assert_close_in_norm(M, om.mass_matrix(X), rtol=RTOL_M, scale=scale)
    # and T itself at an arbitrary velocity (not only at the polarisation vectors)
    # oracle error scales with |M| |Xdot|^2, not with T (T can be small along soft directions)
    # (floored at the smallest normal double: for a speed of ~1e-162 Xdot @ Xdot
    # underflows to 0 while Xdot M Xdot leaves a subnormal 1e-323, as Hypothesis found)
    tiny = np.finfo(float).tiny
    assert 0.5 * Xdot @ M @ Xdot == pytest.approx(
        om.kinetic_energy(X, Xdot), rel=0.0, abs=RTOL_M * scale * (Xdot @ Xdot) + tiny
    )


# --------------------------------------------------------------------------- 4. gravity


@pytest.mark.parametrize("seed", SEEDS)
def test_gravity_is_gradient_of_potential(robot, seed):
    X, _, _ = random_state(seed)
    G = robot.gravity(X)
    assert G.shape == (3,)
    assert_close_in_norm(G, om.gravity(X), rtol=RTOL_G)


# --------------------------------------------------------------------------- 5-6. Coriolis


@pytest.mark.parametrize("seed", SEEDS)
def test_coriolis_vector_matches_christoffel_form(robot, seed):
    X, Xdot, _ = random_state(seed)
    C = robot.coriolis_matrix(X, Xdot)
    assert C.shape == (3, 3)
    assert_close_in_norm(C @ Xdot, om.christoffel_vector(X, Xdot), rtol=RTOL_CORIOLIS)


@pytest.mark.parametrize("seed", SEEDS)
def test_mdot_minus_2c_is_skew_symmetric(robot, seed):
    X, Xdot, _ = random_state(seed)
    C = robot.coriolis_matrix(X, Xdot)
    # Mdot = dM(X + t Xdot)/dt by Richardson-refined central differences of pkmctl's M:
    # error ~1e-11 relative to |M| |Xdot|, far below the tolerance.
    M_dot = om.path_derivative(robot.mass_matrix, X, Xdot)
    N = M_dot - 2.0 * C
    scale = np.linalg.norm(M_dot) + 2.0 * np.linalg.norm(C)
    np.testing.assert_allclose(N + N.T, 0.0, rtol=0.0, atol=RTOL_CORIOLIS * scale)


# --------------------------------------------------------------------------- 7. regressor


def _inverse_dynamics(mech, X, Xdot, Xr_dot, Xr_ddot):
    return mech.mass_matrix(X) @ Xr_ddot + mech.coriolis_matrix(X, Xdot) @ Xr_dot + mech.gravity(X)


@pytest.mark.parametrize("seed", SEEDS)
def test_regressor_identity_with_pkmctl_model(robot, seed):
    X, Xdot, rng = random_state(seed)
    Xr_dot, Xr_ddot = rng.normal(size=3), rng.normal(scale=5.0, size=3)
    Y = robot.regressor(X, Xdot, Xr_dot, Xr_ddot)
    assert Y.shape == (3, 36)
    for theta in (om.THETA_PAPER, random_theta(rng)):
        mech = robot.with_theta(theta)
        expected = _inverse_dynamics(mech, X, Xdot, Xr_dot, Xr_ddot)
        scale = np.linalg.norm(np.abs(Y) @ theta)  # size of the terms summed in Y theta
        assert_close_in_norm(Y @ theta, expected, rtol=RTOL_EXACT * 10, scale=scale)
        # Y does not depend on the parameters
        np.testing.assert_allclose(
            mech.regressor(X, Xdot, Xr_dot, Xr_ddot),
            Y,
            rtol=0.0,
            atol=RTOL_EXACT * np.max(np.abs(Y)),
        )


@pytest.mark.parametrize("seed", SEEDS[:4])
def test_regressor_identity_with_oracle(robot, seed):
    """Y(X, Xd, Xd, Xr_dd) theta = M_or Xr_dd + c_or(Xd) + G_or at random positive theta,
    and column by column (each body parameter separately)."""
    X, Xdot, rng = random_state(seed)
    Xr_ddot = rng.normal(scale=5.0, size=3)
    Y = robot.regressor(X, Xdot, Xdot, Xr_ddot)
    # oracle regressor: column p = M_p Xr_dd + c_p(Xd) + G_p
    Y_oracle = (
        om.mass_matrix_basis(X) @ Xr_ddot + om.christoffel_basis(X, Xdot) + om.gravity_basis(X)
    ).T
    theta = random_theta(rng)
    expected = (
        om.mass_matrix(X, theta) @ Xr_ddot
        + om.christoffel_vector(X, Xdot, theta)
        + om.gravity(X, theta)
    )
    assert_close_in_norm(Y @ theta, expected, rtol=RTOL_CORIOLIS)
    for b in range(om.N_BODIES):
        cols = slice(4 * b, 4 * b + 4)
        assert_close_in_norm(
            Y[:, cols],
            Y_oracle[:, cols],
            rtol=RTOL_CORIOLIS,
            scale=np.max(np.abs(Y_oracle)),
            err_msg=f"regressor columns of body {b} (m, Ixx, Iyy, Izz)",
        )


# --------------------------------------------------------------------------- 8. energy


def _rk4(f, x, dt, n_steps, monitor, every):
    """Classical fixed-step RK4; calls monitor(x) at the start and every `every` steps."""
    monitor(x)
    for k in range(1, n_steps + 1):
        k1 = f(x)
        k2 = f(x + 0.5 * dt * k1)
        k3 = f(x + 0.5 * dt * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        if k % every == 0 or k == n_steps:
            monitor(x)
    return x


def _plant(robot, with_gravity):
    """x = [X, Xdot]; M Xdd + C Xd (+ G) = 0, from pkmctl's public methods only."""

    def f(x):
        X, Xdot = x[:3], x[3:]
        rhs = -robot.coriolis_matrix(X, Xdot) @ Xdot
        if with_gravity:
            rhs = rhs - robot.gravity(X)
        return np.concatenate([Xdot, np.linalg.solve(robot.mass_matrix(X), rhs)])

    return f


def _assert_pose_valid(X):
    assert 0.3 < X[0] < 1.1 and abs(X[1]) < 1.0 and abs(X[2]) < 1.0, X


def test_kinetic_energy_conserved_without_gravity(robot):
    # RK4 with dt = 1e-4 s at rates ~1/s: global error ~dt^4 ~ 1e-16, so any drift above
    # 1e-6 of T comes from C Xdot disagreeing with M (Mdot - 2C not skew, wrong c).
    rng = np.random.default_rng(2024)
    X0 = om.HOME + rng.uniform(-0.05, 0.05, size=3)
    Xdot0 = rng.normal(size=3)
    Xdot0 *= 0.4 / np.linalg.norm(Xdot0)
    energies = []

    def monitor(x):
        _assert_pose_valid(x[:3])
        energies.append(0.5 * x[3:] @ robot.mass_matrix(x[:3]) @ x[3:])

    _rk4(
        _plant(robot, with_gravity=False),
        np.concatenate([X0, Xdot0]),
        1e-4,
        10_000,
        monitor,
        every=500,
    )
    energies = np.array(energies)
    assert np.max(np.abs(energies - energies[0])) <= 1e-6 * energies[0]


def test_total_energy_conserved_with_gravity(robot):
    # Unsupported platform under gravity: thrown upwards at 2 m/s from z = 0.6 m it rises
    # ~0.2 m and falls back within 0.4 s, staying in the workspace. T uses pkmctl's M, V the
    # oracle's potential, so this also checks pkmctl's G against the oracle's V along a path.
    X0 = np.array([0.6, 0.1, -0.1])
    Xdot0 = np.array([2.0, 0.3, -0.3])
    kinetic, total = [], []

    def monitor(x):
        X, Xdot = x[:3], x[3:]
        _assert_pose_valid(X)
        T = 0.5 * Xdot @ robot.mass_matrix(X) @ Xdot
        kinetic.append(T)
        total.append(T + om.potential_energy(X))

    _rk4(
        _plant(robot, with_gravity=True),
        np.concatenate([X0, Xdot0]),
        1e-4,
        4_000,
        monitor,
        every=200,
    )
    total = np.array(total)
    assert min(kinetic) < 0.5 * kinetic[0]  # energy really was exchanged with V
    # relative to the largest kinetic energy (stricter than to |E|, which depends on datum)
    assert np.max(np.abs(total - total[0])) <= 1e-6 * max(kinetic)


# --------------------------------------------------------------------------- 9. properties

poses = st.tuples(st.floats(0.55, 0.85), st.floats(-0.6, 0.6), st.floats(-0.6, 0.6)).map(np.array)
velocities = st.tuples(*(st.floats(-3.0, 3.0),) * 3).map(np.array)


@settings(max_examples=25, deadline=None)
@given(X=poses, Xdot=velocities)
def test_property_mass_matrix_spd_and_matches_oracle(robot, X, Xdot):
    M = robot.mass_matrix(X)
    scale = np.linalg.norm(M)
    np.testing.assert_allclose(M, M.T, rtol=0.0, atol=RTOL_EXACT * scale)
    assert np.linalg.eigvalsh(0.5 * (M + M.T)).min() > 0.0
    assert_close_in_norm(M, om.mass_matrix(X), rtol=RTOL_M, scale=scale)
    # (floored at the smallest normal double: for a speed of ~1e-162 Xdot @ Xdot
    # underflows to 0 while Xdot M Xdot leaves a subnormal 1e-323, as Hypothesis found)
    tiny = np.finfo(float).tiny
    assert 0.5 * Xdot @ M @ Xdot == pytest.approx(
        om.kinetic_energy(X, Xdot), rel=0.0, abs=RTOL_M * scale * (Xdot @ Xdot) + tiny
    )


@settings(max_examples=20, deadline=None)
@given(
    X=poses,
    Xdot=velocities,
    seed=st.integers(0, 2**32 - 1),
    a=st.floats(0.1, 3.0),
    b=st.floats(0.1, 3.0),
)
def test_property_dynamics_linear_in_theta(robot, X, Xdot, seed, a, b):
    """M, C, G of with_theta(a th1 + b th2) = a (..)(th1) + b (..)(th2), and Y th linear."""
    rng = np.random.default_rng(seed)
    th1, th2 = random_theta(rng), random_theta(rng)
    Xr_dot, Xr_ddot = rng.normal(size=3), rng.normal(scale=5.0, size=3)
    theta12 = a * th1 + b * th2
    m1, m2, m12 = (robot.with_theta(t) for t in (th1, th2, theta12))
    for method, args in (
        ("mass_matrix", (X,)),
        ("coriolis_matrix", (X, Xdot)),
        ("gravity", (X,)),
    ):
        v1, v2, v12 = (getattr(m, method)(*args) for m in (m1, m2, m12))
        scale = a * np.max(np.abs(v1)) + b * np.max(np.abs(v2))
        assert_close_in_norm(v12, a * v1 + b * v2, rtol=RTOL_EXACT, scale=scale, err_msg=method)
    # Y is parameter-free, and Y theta reproduces the linear combination of the dynamics.
    Y1, Y12 = (m.regressor(X, Xdot, Xr_dot, Xr_ddot) for m in (m1, m12))
    assert_close_in_norm(Y12, Y1, rtol=RTOL_EXACT)
    tau1, tau2 = (_inverse_dynamics(m, X, Xdot, Xr_dot, Xr_ddot) for m in (m1, m2))
    scale = np.max(np.abs(Y12) @ theta12)
    assert_close_in_norm(Y12 @ theta12, a * tau1 + b * tau2, rtol=10 * RTOL_EXACT, scale=scale)
