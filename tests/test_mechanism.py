"""The Mechanism data: Table 2, validation, with_theta."""

import numpy as np
import pytest

import pkmctl
from pkmctl.model.mechanism import Body


def test_paper_theta_order_and_values(robot):
    th = robot.theta
    assert th.shape == (36,)
    np.testing.assert_array_equal(th[:4], [12.75, 0.077, 0.107, 0.183])
    for i in range(4):
        np.testing.assert_array_equal(th[4 + 4 * i : 8 + 4 * i], [0.95, 2.88e-2, 2.89e-2, 0.05e-2])
        np.testing.assert_array_equal(
            th[20 + 4 * i : 24 + 4 * i], [1.10, 2.65e-2, 2.67e-2, 0.03e-2]
        )
    assert not th.flags.writeable


def test_home_pose_limb_lengths_and_com_heights(robot):
    # DESIGN.md §1: all four limbs 0.71367 m at home; l_1, l_2 put the limb centres of
    # mass at 0.22 m and 0.49 m (Table 2 to its rounding).
    q = robot.inverse_kinematics(robot.home)
    np.testing.assert_allclose(q, 0.71367, atol=5e-6)
    u_z = 0.7 / q[0]
    assert round(0.2243 * u_z, 2) == 0.22
    assert round(0.7 - 0.2141 * u_z, 2) == 0.49


def test_with_theta_keeps_geometry(robot):
    new = robot.with_theta(0.85 * robot.theta)
    np.testing.assert_array_equal(new.geometry, robot.geometry)
    np.testing.assert_allclose(new.theta, 0.85 * robot.theta)
    X = np.array([0.7, 0.2, -0.1])
    np.testing.assert_allclose(new.mass_matrix(X), 0.85 * robot.mass_matrix(X), rtol=1e-13)


def test_user_built_mechanism():
    m = pkmctl.Mechanism.from_bodies(
        r_a=0.15,
        r_b=0.3,
        platform=Body(5.0, (0.05, 0.05, 0.09)),
        lower_limb=Body(0.5, (0.01, 0.01, 0.001)),
        upper_limb=[Body(0.6, (0.01, 0.01, 0.001))] * 4,
        l1=0.1,
        l2=[0.1, 0.12, 0.1, 0.12],
    )
    assert m.total_mass == pytest.approx(5 + 4 * 0.5 + 4 * 0.6)
    assert np.all(np.linalg.eigvalsh(m.mass_matrix([0.5, 0.1, 0.1])) > 0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"r_a": 0.4}, "need 0 < r_a < r_b"),
        ({"r_a": -0.1}, "need 0 < r_a < r_b"),
        ({"platform": Body(-1.0, (0.1, 0.1, 0.1))}, "platform mass"),
        ({"platform": Body(1.0, (0.1, 0.1, 0.5))}, "triangle inequality"),
        ({"lower_limb": Body(1.0, (0.0, 0.1, 0.1))}, "lower limb 1 inertia"),
        ({"l1": -0.1}, "l1"),
        ({"g": -1.0}, "g = -1.0"),
    ],
)
def test_invalid_mechanism_rejected(kwargs, match):
    base = dict(
        r_a=0.2,
        r_b=0.339,
        platform=Body(12.75, (0.077, 0.107, 0.183)),
        lower_limb=Body(0.95, (2.88e-2, 2.89e-2, 0.05e-2)),
        upper_limb=Body(1.1, (2.65e-2, 2.67e-2, 0.03e-2)),
        l1=0.2243,
        l2=0.2141,
    )
    base.update(kwargs)
    with pytest.raises(ValueError, match=match):
        pkmctl.Mechanism.from_bodies(**base)


def test_with_theta_validation(robot):
    with pytest.raises(ValueError, match=r"shape \(36,\)"):
        robot.with_theta(np.ones(35))
    bad = robot.theta.copy()
    bad[4] = 0.0
    with pytest.raises(ValueError, match="lower limb 1 mass"):
        robot.with_theta(bad)
    odd = robot.theta.copy()
    odd[3] = 1.0  # platform I_zz beyond I_xx + I_yy
    with pytest.raises(ValueError, match="triangle"):
        robot.with_theta(odd)
    assert robot.with_theta(odd, physical=False).theta[3] == 1.0
