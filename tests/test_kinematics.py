"""Kinematics: Jacobian against finite differences, forward o inverse, valid set, batches."""

import numpy as np
import pytest
from conftest import random_poses
from hypothesis import given, settings
from hypothesis import strategies as st

import pkmctl


def test_jacobian_matches_central_differences(robot):
    rng = np.random.default_rng(1)
    h = 1e-6  # central differences: truncation ~h^2 |q'''| ~ 1e-12, rounding ~1e-16/h ~ 1e-10
    for X in random_poses(rng, 50):
        J = robot.jacobian(X)
        Jfd = np.column_stack(
            [
                (robot.inverse_kinematics(X + h * e) - robot.inverse_kinematics(X - h * e))
                / (2 * h)
                for e in np.eye(3)
            ]
        )
        np.testing.assert_allclose(J, Jfd, atol=1e-8)


def test_home_jacobian_structure(robot):
    # At home limbs 1/3 (RPU, in the y-z plane) do not feel beta; limbs 2/4 do not feel alpha.
    J = robot.jacobian(robot.home)
    assert J[0, 2] == 0 and J[2, 2] == 0 and J[1, 1] == 0 and J[3, 1] == 0
    np.testing.assert_allclose(J[:, 0], 0.7 / 0.713667, rtol=1e-5)
    np.testing.assert_allclose(J[0, 1], -J[2, 1])


def test_forward_inverse_round_trip(robot):
    rng = np.random.default_rng(2)
    X = random_poses(rng, 40)
    Xfk = robot.forward_kinematics(robot.inverse_kinematics(X))
    np.testing.assert_allclose(Xfk, X, atol=1e-10)


@settings(max_examples=40, deadline=None)
@given(
    z=st.floats(0.5, 0.9),
    a=st.floats(-0.7, 0.7),
    b=st.floats(-0.7, 0.7),
)
def test_forward_inverse_property(robot, z, a, b):
    X = np.array([z, a, b])
    np.testing.assert_allclose(robot.forward_kinematics(robot.inverse_kinematics(X)), X, atol=1e-9)


@pytest.mark.parametrize("X", [[0.7, 0.0, 1.52], [0.7, 0.0, -1.55], [0.7, 1.52, 0.0]])
def test_forward_kinematics_finds_poses_beyond_1_5_rad(robot, X):
    """The search was bounded at |angle| < 1.5 rad, inside the valid set's pi/2: a valid,
    well-conditioned pose at 1.52 rad was "did not converge", even from 1 mrad away (a code
    reader)."""
    X = np.array(X)
    q = robot.inverse_kinematics(X)
    assert robot.condition_number(X) < 1e6
    near = X - 1e-3 * np.sign(X) * (np.abs(X) > 1.0)  # 1 mrad nearer 0 on the big angle
    np.testing.assert_allclose(robot.forward_kinematics(q, guess=near), X, atol=1e-9)
    np.testing.assert_allclose(robot.forward_kinematics(q, guess=[0.7, 0.0, 0.0]), X, atol=1e-9)


def test_forward_kinematics_of_rounded_lengths_is_their_least_squares_pose(robot):
    """Encoder counts (62.5 nm) fit no pose: forward_kinematics raised "did not converge"
    on 200 of 200 such sets (a tester), at a converged least-squares pose. It now names
    them as lengths no pose has, and ``least_squares=True`` gives the pose nearest them:
    scipy's least_squares on the same residual is the oracle."""
    from scipy.optimize import least_squares

    res = 0.01 / 160000
    rng = np.random.default_rng(3)
    for _ in range(20):
        X = np.array([rng.uniform(0.5, 0.9), *rng.uniform(-0.5, 0.5, 2)])
        q = res * np.round(robot.inverse_kinematics(X) / res)
        with pytest.raises(
            pkmctl.ConvergenceError,
            match=r"^no pose has the limb lengths q = "
            r".*: the nearest misses them by .* m \(tol 1e-12 m\); for measured "
            r"or rounded lengths, forward_kinematics\(q, least_squares=True\)",
        ):
            robot.forward_kinematics(q)  # fmt: skip
        Xls = robot.forward_kinematics(q, least_squares=True)
        oracle = least_squares(lambda x, q=q: robot.inverse_kinematics(x) - q, X, xtol=1e-15,
                               ftol=1e-15, gtol=1e-15, method="lm").x  # fmt: skip
        np.testing.assert_allclose(Xls, oracle, rtol=0, atol=1e-10)
        assert np.abs(Xls - X).max() < 1e-6  # rounding moves the pose by ~0.1 um
    with pytest.raises(pkmctl.ConvergenceError, match="did not converge"):  # far from any
        robot.forward_kinematics(np.array([3.0, 0.5, 0.1, 0.5]), least_squares=True)


def test_forward_kinematics_no_convergence(robot):
    # Lengths no pose can have (limb 1 far longer than limb 3 allows).
    with pytest.raises(pkmctl.ConvergenceError, match="residual") as info:
        robot.forward_kinematics(np.array([3.0, 0.5, 0.1, 0.5]))
    assert info.value.residual > 1e-3


def test_min_norm_actuator_forces(robot):
    rng = np.random.default_rng(3)
    for X in random_poses(rng, 20):
        F = rng.normal(size=3) * [100, 10, 10]
        tau = robot.actuator_forces(X, F)
        J = robot.jacobian(X)
        np.testing.assert_allclose(J.T @ tau, F, atol=1e-10)
        # minimum norm: tau lies in range(J), so it is orthogonal to J's null space
        null = np.linalg.svd(J.T)[2][-1]
        assert abs(null @ tau) < 1e-10 * np.linalg.norm(tau)
        np.testing.assert_allclose(tau, np.linalg.pinv(J.T) @ F, atol=1e-10)


@pytest.mark.parametrize(
    ("X", "match"),
    [
        ([0.0, 0.0, 0.0], "z > 0"),
        ([-0.1, 0.0, 0.0], "z > 0"),
        ([0.7, np.pi / 2, 0.0], r"\|alpha\| < pi/2"),
        ([0.7, 0.0, -2.0], r"\|beta\| < pi/2"),
        ([np.nan, 0.0, 0.0], "finite"),
    ],
)
def test_invalid_poses_raise(robot, X, match):
    with pytest.raises(pkmctl.InvalidPoseError, match=match):
        robot.inverse_kinematics(np.array(X))


def test_singular_pose_raises(robot):
    # z -> 0 with beta at 0: the platform lies in the base plane, limbs 1 and 3 horizontal,
    # their rows of J lose the z direction. Far from the workspace, J's condition blows up.
    X = np.array([1e-9, 0.0, 0.0])
    with pytest.raises(pkmctl.InvalidPoseError, match="near-singular"):
        robot.jacobian(X)


def test_wrong_shapes(robot):
    with pytest.raises(ValueError, match=r"shape \(3,\) or \(N, 3\)"):
        robot.jacobian(np.zeros(4))
    with pytest.raises(ValueError, match="q: expected"):
        robot.forward_kinematics(np.zeros(3))


def test_condition_number(robot):
    c = robot.condition_number(robot.home)
    assert c == pytest.approx(np.linalg.cond(robot.jacobian(robot.home)))
    assert robot.condition_number(np.array([robot.home, [0.7, 0.4, 0.4]])).shape == (2,)


def test_checked_condition_numbers_check_and_equal_condition_number(robot):
    rng = np.random.default_rng(5)
    X = random_poses(rng, 50)
    assert np.array_equal(robot.checked_condition_numbers(X), robot.condition_number(X))
    bad = np.vstack([X, [[robot.home[0], 2.0, 0.0]]])  # |alpha| >= pi/2
    with pytest.raises(pkmctl.InvalidPoseError, match="alpha"):
        robot.checked_condition_numbers(bad)


def test_batch_equals_single(robot):
    rng = np.random.default_rng(4)
    X = random_poses(rng, 7)
    Xd, Xr, Xrr = (rng.normal(size=(7, 3)) for _ in range(3))
    F = rng.normal(size=(7, 3))
    for name, args in [
        ("inverse_kinematics", (X,)),
        ("jacobian", (X,)),
        ("mass_matrix", (X,)),
        ("coriolis_matrix", (X, Xd)),
        ("gravity", (X,)),
        ("regressor", (X, Xd, Xr, Xrr)),
        ("actuator_forces", (X, F)),
    ]:
        fn = getattr(robot, name)
        batch = fn(*args)
        assert batch.shape[0] == 7, name
        for n in range(7):
            np.testing.assert_array_equal(batch[n], fn(*(a[n] for a in args)), err_msg=name)
    # a batch of one keeps its leading axis
    assert robot.mass_matrix(X[:1]).shape == (1, 3, 3)
    np.testing.assert_array_equal(
        robot.forward_kinematics(robot.inverse_kinematics(X[:2])).shape, (2, 3)
    )


@pytest.mark.parametrize(
    ("kw", "error", "message"),
    [
        ({"guess": np.zeros(2)}, ValueError, r"^guess: expected shape \(3,\) or \(1, 3\) as q"),
        (
            {"guess": [np.nan, 0.0, 0.0]},
            pkmctl.errors.InvalidPoseError,
            r"^guess: pose must be finite",
        ),
        ({"guess": [-0.7, 0.0, 0.0]}, pkmctl.errors.InvalidPoseError, r"^guess\[0\]: z = -0.7 m"),
        ({"tol": -1.0}, ValueError, r"^tol = -1.0: must be a finite number > 0"),
        ({"max_iter": 0}, ValueError, r"^max_iter = 0: must be an integer >= 1"),
    ],
)
def test_forward_kinematics_names_a_bad_option(kw, error, message):
    """numpy's "operands could not be broadcast", "X: pose must be finite" for a NaN
    guess, and a negative tol run to "did not converge" were what they used to say."""
    robot = pkmctl.Mechanism.paper()
    q = robot.inverse_kinematics(np.array([0.7, 0.1, 0.1]))
    with pytest.raises(error, match=message):
        robot.forward_kinematics(q, **kw)


def test_forward_kinematics_at_a_tolerance_below_rounding_returns_the_pose(robot):
    """Exact lengths with tol = 1e-16 were called lengths "no pose has" (a review): the
    residual 1.1e-16 m is their rounding, not an inconsistency."""
    X = np.array([0.7, 0.1, -0.2])
    np.testing.assert_allclose(
        robot.forward_kinematics(robot.inverse_kinematics(X), tol=1e-16), X, atol=1e-12
    )
