"""The lane loop (pkmctl.sim.lanes): L runs at once give what each run gives alone.

Every lane is compared with the single loop (pkmctl.sim.loop.run_parts) run on the same
bundles: logs, metrics' accumulators, final states and status; lanes differ in seeds and
in numbers of their bundles (gains), and a lane that diverges stops alone.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pkmctl.sim import simulate as S
from pkmctl.sim.lanes import in_batches, lane_batches, lane_count, run_lanes
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
    prep, parts, runs = _runs("afsmc", [1, 2, 3])
    p, s, w = runs[2].bundles["controller"]
    p = p._replace(K=_like(p.K, 1.5 * p.K), Ku=_like(p.Ku, 0.7 * p.Ku))
    runs[2].bundles["controller"] = (p, s, w)
    p, s, w = runs[1].bundles["plant"]
    runs[1].bundles["plant"] = (p._replace(payload=4.0, machine=1.0), s, w)  # a payload
    refs = [_single(parts, r, prep.scenario) for r in runs]
    outs = _lanes(parts, runs, prep.scenario)
    for out, ref in zip(outs, refs, strict=True):
        assert out.status == 0
        _same(out, ref)
    assert not np.array_equal(outs[0].logs["X"], outs[2].logs["X"])  # gains differ
    assert not np.array_equal(outs[0].logs["X"], outs[1].logs["X"])  # the payload


@pytest.mark.parametrize("bad", [1, 0])
def test_a_diverging_lane_stops_alone(bad):
    """bad = 0: the run whose copies fill the padding lanes diverges, and so do they."""
    prep, parts, runs = _runs("afsmc", [1, 2, 3], duration=0.3)
    p, s, w = runs[bad].bundles["controller"]
    runs[bad].bundles["controller"] = (p._replace(K=_like(p.K, -40.0 * p.K)), s, w)  # unstable
    refs = [_single(parts, r, prep.scenario) for r in runs]
    assert [ref.status != 0 for ref in refs] == [i == bad for i in range(3)]
    outs = _lanes(parts, runs, prep.scenario)
    for out, ref in zip(outs, refs, strict=True):
        _same(out, ref)


def test_a_short_batch_runs_padded_to_the_simd_width(monkeypatch):
    """Three runs go through a lane loop of lane_count() lanes (its vectorised code; the
    scalar remainder code of fewer lanes is slower), and give three outputs."""
    import pkmctl.sim.lanes as lanes_module

    widths = []
    compiled = lanes_module.lane_loop_for

    def spy(parts, bundles):
        loop = compiled(parts, bundles)

        def run(*args):
            widths.append(args[1].shape[1])  # x (nx, L)
            return loop(*args)

        return run

    monkeypatch.setattr(lanes_module, "lane_loop_for", spy)
    prep, parts, runs = _runs("afsmc", [1, 2, 3])
    refs = [_single(parts, r, prep.scenario) for r in runs]
    outs = _lanes(parts, runs, prep.scenario)
    w = lane_count()
    assert len(set(widths)) == 1 and widths[0] % w == 0 and 3 <= widths[0] < 3 + w
    assert len(outs) == 3
    for out, ref in zip(outs, refs, strict=True):
        _same(out, ref)


@given(n=st.integers(0, 200), lanes=st.integers(1, 64))
def test_lane_batches_cover_the_runs_once(n, lanes):
    sizes = lane_batches(n, lanes)
    assert sum(sizes) == n
    assert all(1 <= b <= lanes for b in sizes)
    assert sizes.count(lanes) >= n // lanes  # every full batch is one lane loop
    rest = [b for b in sizes if b not in (1, lanes)]
    assert all(2 * b > lanes for b in rest) and len(rest) <= 1  # one short batch, > half


def test_in_batches_cuts_the_items_in_order():
    items = list(range(10, 24))
    assert in_batches(items, 8) == [items[:8], items[8:]]
    assert in_batches(items[:10], 8) == [items[:8], [18], [19]]


def test_lane_batches_send_a_small_rest_one_at_a_time():
    assert lane_batches(10, 8) == [8, 1, 1]
    assert lane_batches(14, 8) == [8, 6]
    assert lane_batches(5, 8) == [5]
    assert lane_batches(4, 8) == [1, 1, 1, 1]
    assert lane_batches(7, 1) == [1] * 7


@pytest.mark.slow
@pytest.mark.parametrize(
    "controller", ["fsmc", "smc", "ctc", "pd"] if os.environ.get("PKMCTL_FULL") else ["fsmc"]
)
def test_every_controllers_lane_form_is_its_scalar_step(controller):
    """CI: fsmc (a lane loop compiles for about a minute); PKMCTL_FULL=1: all four others."""
    prep, parts, runs = _runs(controller, [1, 2])
    assert parts["controller"].lanes
    refs = [_single(parts, r, prep.scenario) for r in runs]
    for out, ref in zip(_lanes(parts, runs, prep.scenario), refs, strict=True):
        _same(out, ref)


def _lane_loop_signatures() -> dict[tuple, int]:
    """Per compiled lane loop of this process (one per combination of parts), how many
    times it was compiled (its signatures)."""
    from pkmctl._jit import _SPECIALISED
    from pkmctl.sim.lanes import _run_lanes

    return {key: len(d.signatures) for (fn, key, _), d in _SPECIALISED.items()
            if fn is _run_lanes}  # fmt: skip


def test_simulate_many_in_lanes_equals_one_at_a_time():
    seeds = [4, 5, 6, 7, 8]
    one = S.simulate_many("paper", "afsmc", seeds=seeds, duration=DURATION, lanes=1, workers=1)
    many = S.simulate_many("paper", "afsmc", seeds=seeds, duration=DURATION, lanes=3, workers=1)
    for a, b in zip(many, one, strict=True):
        _close(a.X, b.X)
        _close(a.tau, b.tau)
        assert a.scenario.disturbance.seed == b.scenario.disturbance.seed
    # batches of 3 and 2 lanes ran in one compiled loop: no argument's type depends on L
    assert set(_lane_loop_signatures().values()) == {1}


@pytest.mark.parametrize("lanes", [1, 4])
def test_simulate_many_names_the_seed_that_diverged_or_keeps_every_run(lanes):
    """Of 12 seeds with a huge disturbance, only seed 7 diverges (a tester's scan). The
    error said where but not which seed, and the 11 good runs were lost."""
    from pkmctl.errors import SimulationDiverged

    sc = S.Scenario.builtin("paper", 0.2).replace(**{"disturbance.amplitude": [2e5, 2e4, 2e4]})
    seeds = list(range(12))
    with pytest.raises(SimulationDiverged, match=r"^seed 7: simulation diverged at t = ") as err:
        S.simulate_many(sc, "pd", seeds=seeds, lanes=lanes, workers=1)
    assert err.value.seed == 7 and err.value.partial.scenario.disturbance.seed == 7
    alone = [S.simulate(sc, "pd", seed=s) for s in seeds if s != 7]
    kept = S.simulate_many(sc, "pd", seeds=seeds, lanes=lanes, workers=1, diverged="keep")
    assert [r.success for r in kept] == [s != 7 for s in seeds]
    assert 0 < err.value.time - kept[7].t[-1] < 1e-3  # the partial run: logged to there
    for a, b in zip([r for r in kept if r.success], alone, strict=True):
        _close(a.X, b.X)
    rows = S.simulate_many(sc, "pd", seeds=seeds, lanes=lanes, workers=1, diverged="keep",
                           keep="metrics")  # fmt: skip
    assert rows[7]["diverged_at"] == err.value.time and rows[7]["message"].startswith("seed 7")
    assert [r["seed"] for r in rows] == seeds and "rmse" in rows[6]
    with pytest.raises(ValueError, match="^diverged = 'skip': must be 'raise' or 'keep'$"):
        S.simulate_many(sc, "pd", seeds=seeds, diverged="skip")


@pytest.mark.parametrize("lanes", [0, 65, 2.5])
def test_simulate_many_refuses_bad_lane_counts(lanes):
    with pytest.raises(ValueError, match="lanes"):
        S.simulate_many("paper", "pd", seeds=[1], duration=DURATION, lanes=lanes)


def test_a_lane_whose_parts_refuse_to_build_is_that_runs_error_alone(monkeypatch):
    """A build that raised for one seed of a lane batch made every run of the batch an
    error (a campaign stored all of them with its message); now that lane alone."""
    from pkmctl.parts import PartError

    set_up = S._set_up

    def refusing(prep, parts, seed, *args):
        if seed == 5:
            raise PartError("controller 'pd': build failed: ValueError: not seed 5")
        return set_up(prep, parts, seed, *args)

    monkeypatch.setattr(S, "_set_up", refusing)
    sc = S.Scenario.builtin("paper", DURATION)
    prep, parts = S.prepare(sc, None), S.resolve_parts(sc, "pd")
    out = S.run_prepared_lanes(prep, parts, [4, 5, 6, 7])
    assert isinstance(out[1], PartError) and "not seed 5" in str(out[1])
    for r, seed in zip([out[0], *out[2:]], [4, 6, 7], strict=True):
        _close(r.X, S.simulate(sc, "pd", seed=seed).X)


def test_arguments_are_checked_alike():
    """NumPy integers are taken for lanes and workers as for seeds; workers=2.5 and
    duration="0.1" (which the scenario itself refuses) were taken; progress=5 was a bare
    TypeError from inside the run."""
    one = S.simulate_many("paper", "pd", seeds=[1, 2], duration=0.01, lanes=np.int64(2),
                          workers=np.int64(1))  # fmt: skip
    assert len(one) == 2
    with pytest.raises(ValueError, match=r"^workers = 2.5: must be an integer >= 1$"):
        S.simulate_many("paper", "pd", seeds=[1], duration=0.01, workers=2.5)
    with pytest.raises(TypeError, match=r"^duration = '0.1': must be a number of seconds$"):
        S.simulate_many("paper", "pd", seeds=[1], duration="0.1")
    with pytest.raises(TypeError, match=r"^progress = 5: must be a function"):
        S.simulate("paper", "pd", duration=0.01, progress=5)


CAMPAIGN = """
name = "lanes"
scenario = "paper"
controllers = ["afsmc"]
seeds = [3, 8, 11]
duration = 0.05
metrics = ["rmse", "max_error"]

[factors."payload.mass"]
values = [0.0, 8.0]
"""


def test_campaign_tasks_in_lanes_give_the_records_of_single_runs():
    from pkmctl.campaign import CampaignSpec
    from pkmctl.campaign.execute import run_task

    spec = CampaignSpec.from_toml(CAMPAIGN)
    task = spec.tasks()[-1]  # the payload cell, the three seeds
    assert len(task.runs) == 3
    one = run_task(spec, task, lanes=1).to_pylist()
    many = run_task(spec, task, lanes=3).to_pylist()
    for a, b in zip(many, one, strict=True):
        assert a["status"] == b["status"] == "ok"
        assert (a["seed"], a["cell"]) == (b["seed"], b["cell"])
        for k, v in b.items():
            if k.startswith(("rmse_", "max_error_")):
                assert abs(a[k] - v) <= 1e-12 * abs(v)


def test_the_prototype_mixes_lane_forms_and_parts_run_lane_by_lane():
    # the encoder sensor and the drive have no lane form; the controller's machine model
    # is on (lane_ok): they run lane by lane, the rigid plant with its options in lanes
    prep, parts, runs = _runs("pd", [1, 2, 3], duration=0.05, scenario="prototype")
    assert not parts["sensor"].lanes and not parts["actuator"].lanes and parts["plant"].lanes
    refs = [_single(parts, r, prep.scenario) for r in runs]
    outs = _lanes(parts, runs, prep.scenario) + _lanes(parts, runs[:2], prep.scenario)
    for out, ref in zip(outs, refs + refs[:2], strict=True):
        assert out.status == 0
        _same(out, ref)
        _close(out.sensor_log, ref.sensor_log)
    # 3 lanes, then 2, in one compiled loop: the parts run lane by lane are padded
    assert set(_lane_loop_signatures().values()) == {1}


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("PKMCTL_FULL"), reason="PKMCTL_FULL=1: compiles a loop")
def test_a_users_controller_with_a_lane_form(tmp_path, monkeypatch):
    """docs/parts.md, "Lanes": lanes= at registration; each lane equals its single run."""
    mod = tmp_path / "lane_law.py"
    mod.write_text(
        "from typing import NamedTuple\n"
        "import numpy as np\n"
        "import pkmctl\n"
        "class LaneLaw(NamedTuple):\n"
        "    kp: float\n"
        "    @classmethod\n"
        "    def from_context(cls, ctx):\n"
        "        return cls(2.0e4)\n"
        "def law_lanes(p, state, work, y, ref, F):\n"
        "    for i in range(3):\n"
        "        for l in range(F.shape[1]):\n"
        "            F[i, l] = p.kp[l] * (ref[i, l] - y[i, l]) + 300.0 * (i == 0)\n"
        "@pkmctl.register_controller('lane-law', params=LaneLaw, lanes={'step': law_lanes},\n"
        "                            lane_work=lambda p, L: (np.empty((3, L)),))\n"
        "def law(p, state, work, y, ref, F):\n"
        "    for i in range(3):\n"
        "        F[i] = p.kp * (ref[i] - y[i]) + 300.0 * (i == 0)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    __import__("lane_law")
    prep, parts, runs = _runs("lane-law", [1, 2], duration=0.02)
    assert parts["controller"].lanes
    refs = [_single(parts, r, prep.scenario) for r in runs]
    for out, ref in zip(_lanes(parts, runs, prep.scenario), refs, strict=True):
        _same(out, ref)


def test_lane_classes_come_back_from_another_process_as_the_same_classes():
    """Numba's disk cache keeps a compiled loop under the pickled types of its arguments;
    a lane bundle's class pickled in one process must load as the live class in the next,
    or every process compiles the lane loops again (a minute or more each)."""
    import pickle
    import subprocess
    import sys

    from pkmctl.parts import _LANE_CLASSES

    code = (
        "import sys, pkmctl; from numba.core import serialize; "
        "from pkmctl.parts import _LANE_CLASSES; "
        "sys.stdout.buffer.write(serialize.dumps(sorted(_LANE_CLASSES.values(), "
        "key=lambda c: c.__module__ + c.__name__)))"
    )
    blob = subprocess.run([sys.executable, "-c", code], capture_output=True, check=True).stdout
    theirs = pickle.loads(blob)
    ours = sorted((cls for params, cls in _LANE_CLASSES.items()  # pkmctl's: not a test's
                   if params.__module__.startswith("pkmctl.")),
                  key=lambda c: c.__module__ + c.__name__)  # fmt: skip
    assert len(ours) >= 8
    assert [c.__name__ for c in theirs] == [c.__name__ for c in ours]
    for a, b in zip(theirs, ours, strict=True):
        assert a is b, a


@pytest.mark.parametrize("L", [3, 8, 11])
def test_lane_metrics_are_the_scalar_metrics_of_each_lane(L):
    """accumulate_metrics_lanes adds to each lane what accumulate_metrics adds to its run,
    over periods that cross the window starts; lanes differ in scale, force threshold,
    speed limit (some none) and geometry, and some limbs sit at the force limit."""
    from pkmctl.model.lanes import make_lane_work
    from pkmctl.sim.loop import accumulate_metrics, accumulate_metrics_lanes, metric_params
    from pkmctl.sim.loop import metric_values as values
    from tests.conftest import random_poses

    rng = np.random.default_rng(L)
    geom = S.prepare("paper", 0.01).plant.geometry
    mps = []
    for l in range(L):
        g = geom * rng.uniform(0.95, 1.05, geom.shape)
        vlim = np.inf if l % 3 == 0 else rng.uniform(0.05, 0.3)
        mps.append(metric_params([0, 4], rng.uniform(0.5, 2.0, 7), 60.0 + l, vlim, g))
    mp = np.stack(mps)
    acc = np.zeros((L, 2 * 21 + 18))  # two windows of 21 accumulators, then 18
    accL, mpL = np.ascontiguousarray(acc.T), np.ascontiguousarray(mp.T)
    work = (np.empty((3, 3)), np.empty((4, 3)), np.empty(4), np.empty(7))
    workL = (make_lane_work(L), np.empty((4, 3, L)), np.empty((4, L)), np.empty((7, L)))
    for k in range(9):
        X = random_poses(rng, L).T
        x = np.ascontiguousarray(np.vstack([X, rng.normal(scale=0.5, size=(3, L))]))
        q, tau = rng.uniform(0.5, 0.9, (4, L)), rng.normal(scale=60.0, size=(4, L))
        Xd, qd = rng.normal(size=9), rng.uniform(0.5, 0.9, 4)
        for l in range(L):
            accumulate_metrics(acc[l], mp[l], k, Xd, col(x, l), qd, col(q, l), col(tau, l),
                               *work)  # fmt: skip
        accumulate_metrics_lanes(accL, mpL, k, Xd, x, qd, q, tau, workL)
    for l in range(L):
        _close(accL[:, l], acc[l])
    v = [values(acc[l], mp[l]) for l in range(L)]
    assert all(v[l]["periods_at_force_limit"] > 0 for l in range(L))
    assert all((v[l]["periods_over_speed_limit"] > 0) == (l % 3 != 0) for l in range(L))
    assert all((v[l]["peak_limb_speed"].max() > 0) == (l % 3 != 0) for l in range(L))


def col(a: np.ndarray, l: int) -> np.ndarray:
    return np.ascontiguousarray(a[..., l])


def test_afsmc_lanes_only_for_a_parameter_count_the_lane_update_handles():
    """The AFSMC lane step updates Θ^ four parameters per pass: a bundle whose count is not
    a multiple of 4 (or that has the machine model on) runs one run at a time instead."""
    from types import SimpleNamespace

    from pkmctl.control.lanes import _afsmc_lane_ok

    def bundle(n, mach_on=0.0):
        return SimpleNamespace(theta0=np.zeros(n), mach_on=mach_on)

    assert _afsmc_lane_ok(bundle(36))
    assert not _afsmc_lane_ok(bundle(37))
    assert not _afsmc_lane_ok(bundle(36, mach_on=1.0))
