"""The controllers' model of the machine (DESIGN.md §7, docs/machine.md): rotor inertia and
friction given to the controllers add exactly the extended regressor's columns 36-47."""

from types import SimpleNamespace

import numpy as np
import pytest

import pkmctl
from pkmctl.control.base import make_controller
from pkmctl.control.sliding import machine_model


def _pair(name, sc):
    """The controller without and with the scenario's machine model, same everything else."""
    model, gains = sc.controller_mechanism(), sc.controller_gains()
    off = make_controller(name, model, gains, period=1e-3)
    on = make_controller(name, model, gains, period=1e-3)
    mm, flag = machine_model(SimpleNamespace(scenario=sc))
    assert flag == 1.0
    on.params = on.params._replace(mach=mm, mach_on=flag)
    return off, on, mm


@pytest.mark.parametrize("name", ["smc", "fsmc", "afsmc", "ctc", "pd"])
def test_machine_model_adds_the_extended_regressor_columns(name):
    sc = pkmctl.Scenario.builtin("prototype-model")
    off, on, mm = _pair(name, sc)
    rng = np.random.default_rng(3)
    robot, g = sc.controller_mechanism(), sc.controller_gains()
    for _ in range(5):
        X = np.array([0.7, 0.0, 0.0]) + rng.uniform(-1, 1, 3) * [0.03, 0.3, 0.3]
        Xd = rng.uniform(-1, 1, 3) * [0.05, 1.0, 1.0]
        Xdes = X + rng.uniform(-1, 1, 3) * [1e-3, 1e-2, 1e-2]
        Xddes, Xdddes = rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3)
        e, ed = Xdes - X, Xddes - Xd
        if name == "ctc":
            v, a = Xd, Xdddes + g.ctc_kd * ed + g.ctc_kp * e
        elif name == "pd":
            v = a = np.zeros(3)
        else:
            v, a = Xddes + g.lam * e, Xdddes + g.lam * ed
        Y = robot.extended_regressor(X, Xd, v, a, friction_velocity=mm[12])
        expected = Y[:, 36:] @ mm[:12]
        F_off = off.step(X, Xd, Xdes, Xddes, Xdddes).copy()
        F_on = on.step(X, Xd, Xdes, Xddes, Xdddes).copy()
        np.testing.assert_allclose(F_on - F_off, expected, rtol=1e-9, atol=1e-9)
        assert np.abs(expected).max() > 1.0  # the terms are not trivially small here


def test_without_a_scenario_or_the_fields_the_model_is_the_papers():
    assert machine_model(SimpleNamespace(scenario=None))[1] == 0.0
    assert machine_model(SimpleNamespace(scenario=pkmctl.Scenario.builtin("prototype")))[1] == 0.0


@pytest.mark.parametrize("field", ["rotor_inertia", "friction_coulomb", "friction_viscous"])
def test_bad_controller_model_is_one_line(field):
    sc = pkmctl.Scenario.builtin("prototype-model")
    with pytest.raises(pkmctl.ScenarioError, match=f"controller_model.{field}"):
        sc.replace(**{f"controller_model.{field}": -1.0})
