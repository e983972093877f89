"""The edges of the scenario's ranges: each bound a message states is allowed itself
(a closed end), the value just past it refused in one line naming field, value and range."""

from __future__ import annotations

import pytest

from pkmctl import Scenario, ScenarioError

THETA = "(multiples of Theta_0; lo in (0, 1], hi in [1, 1e+06])"


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return Scenario.builtin("paper", 0.01)


def _refusal(sc: Scenario, changes: dict) -> str:
    with pytest.raises(ScenarioError) as err:
        sc.replace(**changes)
    assert "\n" not in str(err.value)
    return str(err.value)


@pytest.mark.parametrize(
    "changes",
    [
        {"gains.theta_bounds": [1.0, 1.0]},  # lo in (0, 1], hi in [1, 1e6]: both ends 1
        {"gains.theta_bounds": [1e-9, 1e6]},
        {"timing.duration": 5e-5},  # one control period: duration >= control_period
        {"logging.every": 200},  # the run's 200 periods: every in [1, periods]
        {"payload.offset": [10.0, -10.0, 0.0]},  # [-10, 10] m
        {"disturbance.hold": 5e-5},  # hold >= control_period
        {"actuators.kind": "drive", "actuators.lag": 5e-5},  # lag >= the RK4 sub-step
    ],
)
def test_a_value_on_a_closed_bound_is_allowed(paper, changes):
    sc = paper.replace(**changes)
    for field, value in changes.items():
        section, name = field.split(".")
        spec = getattr(sc, "plant_spec" if section == "plant" else section)
        assert getattr(spec, name) == value


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {"gains.theta_bounds": [1.5, 2.0]},
            f"gains.theta_bounds[0] = 1.5: must be a finite number in (0, 1] {THETA}",
        ),
        (
            {"gains.theta_bounds": [0.5, 0.99]},
            f"gains.theta_bounds[1] = 0.99: must be a finite number in [1, 1e+06] {THETA}",
        ),
        (
            {"payload.offset": [10.5, 0.0, 0.0]},
            "payload.offset[0] = 10.5: must be a finite number in [-10, 10] (m)",
        ),
        (
            {"logging.every": 201},
            "logging.every = 201: must be an integer in [1, 200] (control periods; 200 is the "
            "run's length, timing.duration 0.01 s / control_period 5e-05 s)",
        ),
        (
            {"timing.control_period": 1e-4, "disturbance.hold": 9.9e-5},
            "disturbance.hold = 9.9e-05: must be >= timing.control_period (0.0001 s): the loop "
            "holds one value over each control period (or a timing.control_period <= 9.9e-05 s)",
        ),
    ],
)
def test_a_value_just_past_a_bound_is_one_line_with_the_range(paper, changes, message):
    assert _refusal(paper, changes) == message


def test_a_lag_that_needs_the_most_substeps_says_to_raise_them(paper):
    """1000 sub-steps (MAX_SUBSTEPS) can follow a lag of control_period / 1000: the
    message says to raise substeps to 1000, not that no substeps can."""
    head = (
        "must be 0 (no lag) or >= 5e-05 s, the plant's RK4 sub-step "
        "(timing.control_period / substeps), which cannot follow a shorter lag; "
    )
    said = _refusal(paper, {"actuators.kind": "drive", "actuators.lag": 5e-8})
    assert said == f"actuators.lag = 5e-08: {head}or raise timing.substeps to >= 1000"
    paper.replace(**{"actuators.kind": "drive", "actuators.lag": 5e-8, "timing.substeps": 1000})
    said = _refusal(paper, {"actuators.kind": "drive", "actuators.lag": 4.99e-8})
    assert said == (
        f"actuators.lag = 4.99e-08: {head}at this control period no lag below 5e-08 s can be "
        "followed (1000 sub-steps at most)"
    )


def test_several_errors_say_how_many_more(paper):
    said = _refusal(paper, {"timing.duration": -1, "gains.eps": 0})
    assert said == "gains.eps = 0: must be a finite number in (0, 1000] (and 1 more)"
    said = _refusal(paper, {"timing.duration": -1, "gains.eps": 0, "mechanism.r_a": -1})
    assert said.endswith(" (and 2 more)")
