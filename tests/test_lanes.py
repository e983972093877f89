"""The lane loop (pkmctl.sim.lanes): L runs at once give what each run gives alone.

Every lane is compared with the single loop (pkmctl.sim.loop.run_parts) run on the same
bundles: logs, metrics' accumulators, final states and status; lanes differ in seeds and
in numbers of their bundles (gains), and a lane that diverges stops alone.
"""

from __future__ import annotations

import numpy as np
import pytest

from pkmctl.sim import simulate as S
from pkmctl.sim.lanes import lane_count, run_lanes
from pkmctl.sim.loop import run_parts

DURATION = 0.05


def _like(a, b):
    """b with a's writeable flag (the flag is part of Numba's type of an array)."""
    b = np.array(b)
    b.flags.writeable = a.flags.writeable
    return b


def _runs(controller: str, seeds, duration: float = DURATION, scenario: str = "paper"):
    prep = S.prepare(scenario, duration)
    parts = S.resolve_parts(prep.scenario, controller)
    return prep, parts, [S._set_up(prep, parts, s, True) for s in seeds]


def _single(parts, run, sc):
    bundles = {k: (p, s.copy(), w) for k, (p, s, w) in run.bundles.items()}
    return run_parts(parts, bundles, period=sc.timing.control_period,
                     substeps=sc.timing.substeps, inputs=run.inputs)  # fmt: skip


def _lanes(parts, runs, sc):
    return run_lanes(parts, [r.bundles for r in runs], period=sc.timing.control_period,
                     substeps=sc.timing.substeps, inputs=[r.inputs for r in runs])  # fmt: skip


def _close(a, b, rel=1e-12):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    scale = max(float(np.max(np.abs(b), initial=0.0)), 1e-300)
    assert float(np.max(np.abs(a - b), initial=0.0)) <= rel * scale


def _same(out, ref):
    assert out.status == ref.status
    assert out.steps == ref.steps
    for name in ref.logs:
        _close(out.logs[name], ref.logs[name])
    for kind in ref.final_state:
        _close(out.final_state[kind], ref.final_state[kind])
    _close(out.metrics, ref.metrics)
    if ref.controller_log is not None:
        _close(out.controller_log, ref.controller_log)


def test_lane_count_is_a_simd_width():
    assert lane_count() in (2, 4, 8)


def test_each_lane_is_its_single_run_and_lanes_may_differ_in_numbers():
    prep, parts, runs = _runs("pd", [1, 2, 3])
    p, s, w = runs[2].bundles["controller"]
    p = p._replace(kd=_like(p.kd, 1.5 * p.kd), kp=_like(p.kp, 0.7 * p.kp))
    runs[2].bundles["controller"] = (p, s, w)
    refs = [_single(parts, r, prep.scenario) for r in runs]
    outs = _lanes(parts, runs, prep.scenario)
    for out, ref in zip(outs, refs, strict=True):
        assert out.status == 0
        _same(out, ref)
    assert not np.array_equal(outs[0].logs["X"], outs[2].logs["X"])  # gains differ


def test_a_diverging_lane_stops_alone():
    prep, parts, runs = _runs("pd", [1, 2, 3], duration=0.3)
    p, s, w = runs[1].bundles["controller"]
    runs[1].bundles["controller"] = (p._replace(kp=_like(p.kp, -4.0 * p.kp)), s, w)  # unstable
    refs = [_single(parts, r, prep.scenario) for r in runs]
    assert refs[1].status != 0 and refs[0].status == refs[2].status == 0
    outs = _lanes(parts, runs, prep.scenario)
    for out, ref in zip(outs, refs, strict=True):
        _same(out, ref)


def test_simulate_many_in_lanes_equals_one_at_a_time():
    one = S.simulate_many("paper", "pd", seeds=[4, 5, 6], duration=DURATION, lanes=1, workers=1)
    many = S.simulate_many("paper", "pd", seeds=[4, 5, 6], duration=DURATION, lanes=2)
    for a, b in zip(many, one, strict=True):
        _close(a.X, b.X)
        _close(a.tau, b.tau)
        assert a.scenario.disturbance.seed == b.scenario.disturbance.seed


@pytest.mark.parametrize("lanes", [0, 65, 2.5])
def test_simulate_many_refuses_bad_lane_counts(lanes):
    with pytest.raises(ValueError, match="lanes"):
        S.simulate_many("paper", "pd", seeds=[1], duration=DURATION, lanes=lanes)
