"""The drive actuator and the encoder sensor of the machine as built (DESIGN.md §7, issue 10)."""

from typing import NamedTuple

import numpy as np
import pytest

import pkmctl
from pkmctl.sim.sensors import EncoderSensor, encoder_measure, encoder_sensor, fk_gauss_newton

PEAK_FORCE = 2 * np.pi * 0.9 * 3.82 / 0.01  # N: f = 2 pi eta T / l at the peak torque


class ConstantForce(NamedTuple):
    """A controller that asks for one constant task-space force (a step at t = 0)."""

    F: np.ndarray

    @classmethod
    def from_context(cls, ctx):
        return cls(np.array([300.0, 5.0, -5.0]))


@pkmctl.register_controller("test-constant-force", params=ConstantForce)
def constant_force(p, state, work, y, ref, F):
    for i in range(3):
        F[i] = p.F[i]


def _scenario(**changes):
    return pkmctl.Scenario.builtin("paper").replace(**changes)


def test_drive_step_reaches_63_percent_in_tau_d():
    lag, Tc = 5e-4, 1e-4
    sc = _scenario(
        **{"actuators.kind": "drive", "actuators.lag": lag, "timing.control_period": Tc,
           "timing.substeps": 5, "timing.duration": 3e-3}
    )  # fmt: skip
    r = pkmctl.simulate(sc, controller="test-constant-force")
    robot = sc.plant()
    k = int(round(lag / Tc))
    # the torque starts at 0 and follows the (constant) command through the lag
    wanted = robot.actuator_forces(r.X_measured[k], np.array([300.0, 5.0, -5.0]))
    np.testing.assert_allclose(r.tau[0], 0.0)
    np.testing.assert_allclose(r.tau[k] / wanted, 1 - np.exp(-1), rtol=2e-4)
    np.testing.assert_allclose(r.tau[4 * k] / wanted, 1 - np.exp(-4), rtol=2e-4)


def test_drive_lag_below_the_substep_is_refused_and_one_substep_is_followed():
    Tc, sub = 1e-4, 5  # h = 20 us
    drive = {"actuators.kind": "drive", "timing.control_period": Tc, "timing.substeps": sub,
             "timing.duration": 2e-3}  # fmt: skip
    with pytest.raises(pkmctl.ScenarioError, match=r"actuators\.lag = 1e-05: must be 0 .*>= 2e-05"):
        _scenario(**drive, **{"actuators.lag": 1e-5})  # RK4: a third a sub-step, not exp(-2)
    with pytest.raises(pkmctl.ScenarioError, match=r"no lag below 1e-07 s can be followed"):
        _scenario(**drive, **{"actuators.lag": 1e-8})  # would need 10,000 sub-steps: > 1000
    lag = 2e-5  # h, the shortest allowed
    sc = _scenario(**drive, **{"actuators.lag": lag})
    r = pkmctl.simulate(sc, controller="test-constant-force")
    wanted = sc.plant().actuator_forces(r.X_measured[1], np.array([300.0, 5.0, -5.0]))
    # after one period (5 lags) the force's gap to the command is RK4's 0.375^5 = 0.0074
    # of the step where the exact lag leaves exp(-5) = 0.0067 (at h / 2: 0.0041 for 5e-5)
    np.testing.assert_allclose(r.tau[1] / wanted, 1 - np.exp(-Tc / lag), atol=1e-3)


def test_drive_never_exceeds_the_peak_force_and_counts_speed():
    sc = pkmctl.Scenario.builtin("prototype").replace(**{"timing.duration": 0.3})
    r = pkmctl.simulate(sc, controller="smc")
    assert np.abs(r.tau).max() <= PEAK_FORCE * (1 + 1e-12)
    assert np.abs(r.tau).max() >= PEAK_FORCE * (1 - 1e-6)  # and SMC does reach it here
    assert r.info["speed_limit"] == pytest.approx(5000 / 60 * 0.01)
    assert isinstance(r.info["speed_violations"], int)


def test_drive_without_lag_and_limits_is_the_ideal_actuator():
    base = {"timing.duration": 0.2, "timing.substeps": 10}  # h = 5 us: RK4 resolves the lags
    ideal = pkmctl.simulate(_scenario(**base), controller="afsmc")
    drive = {"actuators.kind": "drive", "actuators.lag": 0.0, "actuators.peak_torque": 1e4,
             "actuators.max_speed": 1e6}  # fmt: skip
    r = pkmctl.simulate(_scenario(**base, **drive), controller="afsmc")
    # f = gain * (f / gain): equal to rounding, then the closed loop carries it on
    np.testing.assert_allclose(r.tau, ideal.tau, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(r.X, ideal.X, rtol=0, atol=1e-12)
    # a short lag converges to it: the gap shrinks in proportion to the lag
    gaps = []
    for lag in (2e-5, 1e-5):
        r = pkmctl.simulate(_scenario(**{**base, **drive, "actuators.lag": lag}), "afsmc")
        gaps.append(np.abs(r.X - ideal.X).max())
    assert gaps[1] < 0.6 * gaps[0]


# ------------------------------------------------------------------ encoder
def test_encoder_pose_error_within_the_resolution_bound():
    sc = _scenario(
        **{"sensor.kind": "encoder", "timing.control_period": 1e-3, "timing.substeps": 20,
           "timing.duration": 2.0}
    )  # fmt: skip
    r = pkmctl.simulate(sc, controller="pd")
    res = 0.01 / 160_000
    assert res == pytest.approx(62.5e-9)
    # q^ is on the count grid and within half a count of the true length
    counts = r.q_measured / res
    np.testing.assert_allclose(counts, np.round(counts), rtol=0, atol=1e-6)
    assert np.abs(r.q_measured - r.q).max() <= 0.5 * res * (1 + 1e-9)
    # X^ - X = J^+ (q^ - q) to first order, |q^_i - q_i| <= res / 2, so per coordinate
    # |X^_j - X_j| <= res / 2 sum_i |J^+_ji| (plus second order, ~|J^+| |H| res^2, ~1e-15)
    J = sc.plant().jacobian(r.X)
    bound = 0.5 * res * np.abs(np.linalg.pinv(J)).sum(axis=2)
    err = np.abs(r.X_measured - r.X)
    assert np.all(err <= bound * (1 + 1e-6) + 1e-14)
    assert err.max() > 0.2 * bound.max()  # the bound is not vacuous
    assert r.info["fk_max_iterations"] <= 6


def test_encoder_forward_kinematics_is_converged_to_its_tolerance():
    """The encoder stops Gauss-Newton as soon as the error it predicts is below the 1e-12
    step tolerance (two iterations from its extrapolated warm start, where waiting for a
    step under 1e-12 took three and a fourth J): X^ must still be the least-squares pose
    of q^ to that tolerance, and Xdot^ = J^+(X^) qdot^ with J within 1e-11 of X^."""
    sc = _scenario(
        **{"sensor.kind": "encoder", "timing.control_period": 1e-3, "timing.substeps": 20,
           "timing.duration": 2.0}
    )  # fmt: skip
    r = pkmctl.simulate(sc, controller="pd")
    model = sc.controller_mechanism()  # the geometry the forward kinematics assumes
    X = r.X_measured.copy()
    for _ in range(4):  # Gauss-Newton on |q(X) - q^|^2 from X^, to full convergence
        residual = model.inverse_kinematics(X) - r.q_measured
        X -= np.einsum("nij,nj->ni", np.linalg.pinv(model.jacobian(X)), residual)
    assert np.abs(r.X_measured - X).max() <= 1e-12
    # velocity_filter = 0, no delay: qdot^ is the backward difference of q^
    qdot = np.diff(r.q_measured, axis=0) / 1e-3
    rate = np.einsum("nij,nj->ni", np.linalg.pinv(model.jacobian(X[1:])), qdot)
    np.testing.assert_allclose(r.Xdot_measured[1:], rate, rtol=1e-9, atol=1e-10)
    assert r.info["fk_max_iterations"] <= 3


def test_encoder_noise_is_seeded():
    sc = _scenario(
        **{"sensor.kind": "encoder", "sensor.noise": 1e-6, "timing.control_period": 1e-3,
           "timing.substeps": 20, "timing.duration": 0.2}
    )  # fmt: skip
    a, b = (pkmctl.simulate(sc, controller="pd") for _ in range(2))
    np.testing.assert_array_equal(a.X_measured, b.X_measured)
    c = pkmctl.simulate(sc.replace(**{"sensor.seed": 1}), controller="pd")
    assert not np.array_equal(a.X_measured, c.X_measured)
    assert np.abs(a.q_measured - a.q).max() > 1e-6  # noise of 1 um is there


def test_encoder_delay_gives_the_previous_sample():
    base = {"sensor.kind": "encoder", "timing.control_period": 1e-3, "timing.substeps": 20,
            "timing.duration": 0.05, "controller_model.theta_scale": 1.0}  # fmt: skip
    res = 0.01 / 160_000
    now = pkmctl.simulate(_scenario(**base), controller="pd")
    late = pkmctl.simulate(_scenario(**base, **{"sensor.delay_periods": 1}), "pd")

    def counts(q):
        return np.floor(q / res + 0.5) * res

    # q^ given at t_k is the encoders' reading at t_k, or at t_k-1 with the delay
    np.testing.assert_allclose(now.q_measured, counts(now.q), rtol=0, atol=1e-3 * res)
    np.testing.assert_allclose(late.q_measured[1:], counts(late.q[:-1]), rtol=0, atol=1e-3 * res)
    np.testing.assert_allclose(late.X_measured[1:], late.X[:-1], rtol=0, atol=1e-6)
    assert np.abs(late.X_measured[1:] - late.X[1:]).max() > 1e-5


def test_forward_kinematics_fails_cleanly(robot):
    R, Jq, q, r = np.empty((3, 3)), np.empty((4, 3)), np.empty(4), np.empty(4)
    qh = robot.inverse_kinematics(np.array([0.7, 0.1, 0.2]))
    X = np.array([0.7, 0.0, 0.0])
    assert 0 < fk_gauss_newton(robot.geometry, qh, X, R, Jq, q, r, 1e-12, 1e-15, 20) <= 6
    np.testing.assert_allclose(X, [0.7, 0.1, 0.2], atol=1e-13)
    X = np.array([0.7, 0.0, 0.0])  # lengths no pose has: it leaves the chart, -1
    assert fk_gauss_newton(robot.geometry, np.full(4, 0.01), X, R, Jq, q, r, 1e-12, 1e-15, 20) < 0
    X = np.array([1e-9, 0.0, 0.0])  # from the singular flat pose: diverges, -1
    assert fk_gauss_newton(robot.geometry, qh, X, R, Jq, q, r, 1e-12, 1e-15, 20) < 0


class PoisonedEncoder(NamedTuple):
    """The built-in encoder, with a NaN in its noise at sample 37 (forward kinematics fails)."""

    enc: EncoderSensor

    @classmethod
    def from_context(cls, ctx):
        p = encoder_sensor(ctx.plant, ctx.model, period=ctx.period, noise=1e-9, samples=100)
        p.noise[37, 2] = np.nan
        return cls(p)


def _encoder_work(p):
    from pkmctl.parts import get_part

    return get_part("sensor", "encoder").make_work(p.enc)


@pkmctl.register_sensor(
    "test-poisoned-encoder", params=PoisonedEncoder, state_size=28, work=_encoder_work
)
def poisoned(p, state, work, x, y):
    encoder_measure(p.enc, state, work, x, y)


def test_sensor_failure_is_simulation_diverged_naming_the_time():
    sc = _scenario(
        **{"sensor.kind": "test-poisoned-encoder", "timing.control_period": 1e-3,
           "timing.substeps": 20, "timing.duration": 0.08}
    )  # fmt: skip
    with pytest.raises(pkmctl.SimulationDiverged, match=r"t = 0\.037 s .*sensor could not measure"):
        pkmctl.simulate(sc, controller="pd")
