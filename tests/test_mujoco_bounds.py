"""The MuJoCo model's pure-Python parts at their bounds: the timestep limit, a zero
payload, option names in messages, the merged payload inertia, number printing, the
platform's free-joint velocity (a tester's mutation round)."""

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pkmctl.plants import mujoco as mj  # noqa: E402
from pkmctl.plants import mujoco_max_timestep  # noqa: E402


def test_a_timestep_of_exactly_half_the_closures_time_constant_is_accepted(robot):
    top = mujoco_max_timestep()
    assert top == pytest.approx(2.5e-4, rel=1e-8)
    assert "<mujoco" in mj.build_mjcf(robot, timestep=top)
    with pytest.raises(ValueError) as exc:
        mj.build_mjcf(robot, timestep=3e-4)
    assert str(exc.value) == (
        "timestep = 0.0003: must be <= 0.00025 s, half the closures' time constant (solref "
        "0.0005 s), which MuJoCo would raise to twice a longer step, the closures then lagging"
    )


def test_a_payload_of_zero_is_accepted_and_a_negative_one_refused(robot):
    assert mj.build_mjcf(robot, payload_mass=0.0) == mj.build_mjcf(robot)
    with pytest.raises(ValueError, match=r"^payload_mass = -1.0: must be finite and >= 0$"):
        mj.build_mjcf(robot, payload_mass=-1.0)


def test_scenario_error_names_the_option_as_the_user_gave_it():
    msg = "rotor_inertia = -1.0: must be finite and >= 0"
    assert mj.scenario_error(msg) == "plant.rotor_inertia = -1.0: must be finite and >= 0"
    assert mj.scenario_error(msg, {"rotor_inertia": "--rotor-inertia"}) == (
        "--rotor-inertia = -1.0: must be finite and >= 0"
    )
    assert mj.scenario_error("something else") == "something else"


def test_a_payload_moves_the_platforms_centre_of_mass_to_the_weighted_mean():
    out = mj._platform_inertial(np.array([2.0, 0.1, 0.1, 0.1]), 2.0, np.array([0.0, 0.0, 0.1]))
    attrs = dict(a.split('="') for a in out.removeprefix("<inertial ").rstrip('"/>').split('" '))
    np.testing.assert_allclose([float(v) for v in attrs["pos"].split()], [0, 0, 0.05])
    assert float(attrs["mass"]) == 4.0
    # about the joint centre: 0.1 + 2 (0.05)^2 x 2 about x and y, 0.1 about z
    np.testing.assert_allclose(
        [float(v) for v in attrs["fullinertia"].split()], [0.11, 0.11, 0.1, 0, 0, 0], atol=1e-15
    )


def test_numbers_are_printed_round_trip_and_minus_zero_as_zero():
    assert mj._f(-0.0, 0.1, 1e-300) == "0.0 0.1 1e-300"


def test_the_platforms_free_joint_velocity_is_the_derivative_of_its_position():
    # p_y = -z tan(alpha) along a path X(t); its rate is the qvel's second entry
    X0, Xd = np.array([0.7, 0.3, -0.2]), np.array([0.05, 0.4, -0.3])
    h = 1e-6
    py = [-(X0[0] + s * Xd[0]) * np.tan(X0[1] + s * Xd[1]) for s in (-h, h)]
    v = mj._platform_qvel(X0, Xd)
    assert v[1] == pytest.approx((py[1] - py[0]) / (2 * h), rel=1e-7)
    np.testing.assert_allclose(v[[0, 2, 3, 4, 5]],
                               [0, 0.05, 0.4 * np.cos(-0.2), -0.3, 0.4 * np.sin(-0.2)])  # fmt: skip
