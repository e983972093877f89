"""Dynamics: the regressor identity (Pinocchio-style), Mdot - 2C skew, batches.

The independent body-by-body oracle (kinetic energy from finite-differenced body
positions and frames) lives in test_dynamics_oracle.py.
"""

import numpy as np
from conftest import random_poses


def _states(seed, n):
    rng = np.random.default_rng(seed)
    return rng, random_poses(rng, n), *(rng.normal(size=(n, 3)) for _ in range(3))


def test_regressor_identity_paper_theta(robot):
    _, X, Xd, Xr, Xrr = _states(10, 30)
    Y = robot.regressor(X, Xd, Xr, Xrr)
    M, C, G = robot.mass_matrix(X), robot.coriolis_matrix(X, Xd), robot.gravity(X)
    rhs = np.einsum("nij,nj->ni", M, Xrr) + np.einsum("nij,nj->ni", C, Xr) + G
    np.testing.assert_allclose(Y @ robot.theta, rhs, rtol=1e-12, atol=1e-11)


def test_regressor_identity_random_theta(robot):
    rng, X, Xd, Xr, Xrr = _states(11, 30)
    for _ in range(5):
        theta = robot.theta * rng.uniform(0.2, 5.0, size=36)
        other = robot.with_theta(theta, physical=False)
        Y = robot.regressor(X, Xd, Xr, Xrr)  # Y does not depend on theta
        rhs = (
            np.einsum("nij,nj->ni", other.mass_matrix(X), Xrr)
            + np.einsum("nij,nj->ni", other.coriolis_matrix(X, Xd), Xr)
            + other.gravity(X)
        )
        np.testing.assert_allclose(Y @ theta, rhs, rtol=1e-12, atol=1e-10)


def test_mdot_minus_2c_skew(robot):
    _, X, Xd, _, _ = _states(12, 20)
    h = 1e-6  # central difference of M along Xdot: error ~1e-10 relative
    for x, xd in zip(X, Xd, strict=True):
        Mdot = (robot.mass_matrix(x + h * xd) - robot.mass_matrix(x - h * xd)) / (2 * h)
        S = Mdot - 2 * robot.coriolis_matrix(x, xd)
        np.testing.assert_allclose(S + S.T, 0, atol=1e-7)


def test_inverse_dynamics_equals_regressor_at_state(robot):
    _, X, Xd, _, Xdd = _states(13, 10)
    np.testing.assert_allclose(
        robot.inverse_dynamics(X, Xd, Xdd),
        robot.regressor(X, Xd, Xd, Xdd) @ robot.theta,
        rtol=1e-12,
    )


def test_work_shapes_describe_make_work():
    from pkmctl.model.dynamics import WORK_SHAPES, make_work

    assert tuple(a.shape for a in make_work()) == WORK_SHAPES
