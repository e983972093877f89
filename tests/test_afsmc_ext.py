"""AFSMC over Theta_ext (DESIGN.md §7): the force it uses is Y_ext Theta_ext^, its bounds keep
the machine's parameters >= 0, and on `prototype` it leaves a smaller z error than AFSMC."""

from types import SimpleNamespace

import numpy as np
import pytest

import pkmctl
from pkmctl.control.adaptive import AFSMCExtParams
from pkmctl.control.base import make_controller
from pkmctl.control.gains import Gains
from pkmctl.control.sliding import SLIDING_STATE
from pkmctl.sim.metrics import rmse


def _controller(gamma=5.0):
    sc = pkmctl.Scenario.builtin("prototype-model")
    gains = Gains(K=np.zeros(3), Ku=np.zeros(3), gamma=gamma)  # F = Y_ext Theta^ alone
    c = make_controller("afsmc-ext", sc.controller_mechanism(), gains, period=1e-3)
    ctx = SimpleNamespace(
        model=sc.controller_mechanism(), gains=gains, period=1e-3, flc=c.flc, scenario=sc
    )
    c.params = AFSMCExtParams.from_context(ctx)
    c._state[SLIDING_STATE:] = c.params.theta0
    return c, sc


def test_the_force_is_the_extended_regressor_times_the_estimate_in_use():
    c, sc = _controller()
    robot, lam = sc.controller_mechanism(), c.params.lam
    assert c.params.theta0.shape == (48,) and np.all(c.params.theta0[36:] > 0)
    rng = np.random.default_rng(5)
    moved = 0.0
    for _ in range(20):
        X = np.array([0.7, 0.0, 0.0]) + rng.uniform(-1, 1, 3) * [0.03, 0.3, 0.3]
        Xd = rng.uniform(-1, 1, 3) * [0.05, 1.0, 1.0]
        Xdes = X + rng.uniform(-1, 1, 3) * [1e-2, 1e-1, 1e-1]
        Xddes, Xdddes = rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3)
        theta = c.state.theta_hat
        F = c.step(X, Xd, Xdes, Xddes, Xdddes).copy()
        xr_d = Xddes + lam * (Xdes - X)
        xr_dd = Xdddes + lam * (Xddes - Xd)
        Y = robot.extended_regressor(X, Xd, xr_d, xr_dd, friction_velocity=c.params.v_s)
        np.testing.assert_allclose(F, Y @ theta, rtol=1e-10, atol=1e-9)
        moved = max(moved, np.abs(c.state.theta_hat - theta).max())
    assert moved > 0  # the estimate does adapt


def test_the_machine_estimates_stay_non_negative():
    c, _ = _controller(gamma=1e6)  # a huge gain: the projection must hold them
    assert np.all(c.params.theta_min[36:] == 0)
    for k in range(50):
        sgn = 1.0 if k % 2 else -1.0
        c.step([0.7, 0, 0], [sgn * 0.05, 0, 0], [0.7 - sgn * 0.01, 0, 0], [0, 0, 0], [0, 0, 0])
        th = c.state.theta_hat
        assert np.all(th[36:] >= 0) and np.all(th <= c.params.theta_max)


@pytest.mark.slow
def test_on_prototype_it_leaves_a_smaller_steady_z_error_than_afsmc():
    sc = pkmctl.Scenario.builtin("prototype").replace(**{"timing.duration": 4.0})
    plain = rmse(pkmctl.simulate(sc, controller="afsmc"), t_from=1.0)["z_mm"]
    ext = rmse(pkmctl.simulate(sc, controller="afsmc-ext"), t_from=1.0)["z_mm"]
    assert ext < 0.5 * plain, (ext, plain)
