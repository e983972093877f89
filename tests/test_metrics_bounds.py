"""Bounds of the Table 4 metrics, the Result object and the cost model: what a mutation of
each left every other test passing (a tester's mutation round)."""

from types import SimpleNamespace

import numpy as np
import pytest

import pkmctl
from pkmctl.sim import cost, metrics


def _run(controller="pd", duration=0.05, **changes):
    sc = pkmctl.Scenario.builtin("paper").replace(**{"timing.duration": duration, **changes})
    return pkmctl.simulate(sc, controller)


@pytest.fixture(scope="module")
def pd_run():
    return _run("pd")


def _hand_errors(r, t_from=0.0):
    e = np.hstack([r.X_desired - r.X, r.q_desired - r.q])
    e = e[r.t >= t_from - 1e-12]
    return e * np.array([1e3, 180 / np.pi, 180 / np.pi, 1, 1, 1, 1])


def test_rmse_max_and_mean_from_the_log_are_table_4s_units_by_hand(pd_run):
    r = pd_run
    e = _hand_errors(r)
    want_rmse = np.sqrt(np.mean(e**2, axis=0))
    got = metrics.rmse(r, source="log")
    assert list(got) == list(metrics.RMSE_KEYS)
    np.testing.assert_allclose(list(got.values()), want_rmse, rtol=1e-12)
    np.testing.assert_allclose(
        list(metrics.max_error(r, source="log").values()), np.abs(e).max(axis=0), rtol=1e-12
    )
    # the signed mean, not the mean of |e|: a bias of one sign stays one sign
    mean = np.array(list(metrics.mean_error(r, source="log").values()))
    np.testing.assert_allclose(mean, e.mean(axis=0), rtol=1e-12, atol=1e-300)
    assert np.any(mean < 0) and np.any(mean > 0)


def test_a_window_from_a_sample_time_includes_that_sample(pd_run):
    r = pd_run
    Tc = r.scenario.timing.control_period
    t_from = 200 * Tc  # a logged sample's time, not a loop window
    n = r.t.size - metrics.first_period(t_from, Tc)
    assert metrics.first_period(t_from, Tc) == 200
    assert metrics.sample_count(r, t_from=t_from, source="log") == n
    e = _hand_errors(r, t_from)
    assert e.shape[0] == n
    np.testing.assert_allclose(
        list(metrics.rmse(r, t_from=t_from, source="log").values()),
        np.sqrt(np.mean(e**2, axis=0)),
        rtol=1e-12,
    )


def test_a_window_after_the_run_holds_no_samples_and_is_refused(pd_run):
    r = pd_run
    assert metrics.sample_count(r, t_from=1.0, source="loop") == 0
    assert r.loop_metrics.count.tolist() == [r.t.size, 0, 0]
    for f in (metrics.rmse, metrics.max_error, metrics.mean_error):
        with pytest.raises(ValueError, match=r"^t_from = 1.0: no samples after it$"):
            f(r, t_from=1.0, source="loop")


def test_rmse_after_1s_is_none_for_a_run_shorter_than_a_second():
    r = _run("pd", duration=0.55)
    s = metrics.summary(r, ["rmse", "rmse_after_1s"])
    assert s["rmse_after_1s"] is None
    assert s["rmse"] == metrics.rmse(r)


def test_time_at_a_force_limit_counts_forces_exactly_at_the_limit():
    r = _run("smc", duration=0.02, **{"actuators.force_limit": 50.0})
    Tc = r.scenario.timing.control_period
    at = np.any(np.abs(r.tau) >= 50.0 * (1 - 1e-9), axis=1).sum()
    assert at > 0 and np.max(np.abs(r.tau)) == 50.0  # clipped to exactly the limit
    assert metrics.time_at_force_limit(r, source="log") == at * Tc
    assert metrics.time_at_force_limit(r, source="loop") == at * Tc
    # a force limit is not a speed limit: the ideal actuator has none
    assert metrics.limb_speed(r) is None
    assert metrics.time_over_speed_limit(r) is None
    assert metrics.summary(r)["peak_limb_speed_m_per_s"] is None


def test_result_rmse_is_the_whole_runs_and_its_repr_names_every_only_when_decimated(pd_run):
    r = pd_run
    assert r.rmse() == metrics.rmse(r) == metrics.rmse(r, t_from=0.0, source="log")
    assert repr(r) == "Result(controller='pd', scenario='paper', N=1000, success=True)"
    dec = _run("pd", duration=0.01, **{"logging.every": 4})
    assert repr(dec) == "Result(controller='pd', scenario='paper', N=50, every=4, success=True)"


def _parts(actuator="ideal", sensor="ideal"):
    return {"actuator": SimpleNamespace(name=actuator), "sensor": SimpleNamespace(name=sensor)}


def test_cost_of_a_period_counts_the_substeps_beyond_the_first_and_the_drive():
    assert cost.period_seconds(_parts(), 1, "single") == cost.PERIOD["single"]
    assert cost.period_seconds(_parts(), 3, "lanes") == pytest.approx(0.6e-6 + 2 * 0.25e-6)
    assert cost.period_seconds(_parts("drive"), 3, "single") == pytest.approx(
        2e-6 + 2 * 0.5e-6 * 1.4
    )
    assert cost.period_seconds(_parts(sensor="encoder"), 1, "single") == pytest.approx(8e-6)


def test_cost_of_a_run_adds_what_it_costs_outside_its_loop():
    sc = pkmctl.Scenario.builtin("paper").replace(**{"timing.duration": 0.5})
    periods = round(0.5 / sc.timing.control_period)
    want = periods * cost.period_seconds(_parts(), sc.timing.substeps, "single") + 4e-3
    assert cost.run_seconds(sc, _parts()) == pytest.approx(want, rel=1e-12)


def test_first_period_takes_a_sample_within_1e_12_s_before_t_from():
    # 1.0 s is "from 1.0 + 1e-12 s on" (the tolerance every metric selects samples with)
    assert metrics.first_period(1.0 + 1e-12, 0.5) == 2
    assert metrics.first_period(1.0 + 3e-12, 0.5) == 3
    assert metrics.first_period(0.2, 5e-5) == 4000
    assert metrics.first_period(1.0, 5e-5) == 20000
    assert metrics.first_period(0.0, 1e-3) == 0
