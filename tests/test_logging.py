"""Decimated logging (``logging.every``, issue 14 point 5): the log keeps every N-th period,
the metrics are accumulated over every period inside the loop, and the memory a run
needs follows the log."""

import importlib.util
import math

import numpy as np
import pytest

import pkmctl
from pkmctl.io.results import load_result, save_result
from pkmctl.sim import metrics
from pkmctl.sim import simulate as sim

ARRAYS = ("t", "X", "Xdot", "X_desired", "Xdot_desired", "q", "q_desired", "F", "tau",
          "tau_desired", "disturbance", "X_measured", "Xdot_measured", "q_measured",
          "theta_hat")  # fmt: skip


def _scenario(name="paper", **changes):
    return pkmctl.Scenario.builtin(name).replace(**changes)


def _assert_rows(full, decimated, every):
    """Every array of ``decimated`` is every ``every``-th row of ``full``'s, bit for bit."""
    for name in ARRAYS:
        a, b = getattr(full, name), getattr(decimated, name)
        if a is None:
            assert b is None, name
            continue
        np.testing.assert_array_equal(a[::every], b, err_msg=name)
    for name, a in full.logs.items():
        np.testing.assert_array_equal(a[::every], decimated.logs[name], err_msg=name)
    for kind, state in full.final_state.items():
        np.testing.assert_array_equal(state, decimated.final_state[kind], err_msg=kind)


def _assert_same_loop_metrics(a, b):
    la, lb = a.loop_metrics, b.loop_metrics
    for name, v in la.__dict__.items():
        np.testing.assert_array_equal(np.asarray(v), np.asarray(getattr(lb, name)), err_msg=name)


def _close(a, b, rtol, path="summary"):
    """Nested dicts/lists of floats (or None) equal to ``rtol``."""
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            _close(a[k], b[k], rtol, f"{path}.{k}")
    elif a is None or b is None:
        assert a is None and b is None, path
    else:
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=rtol, atol=0, err_msg=path)


# ------------------------------------------------------------------ every = 1
@pytest.mark.parametrize(
    ("name", "controller", "duration"),
    [("paper", "afsmc", 0.3), ("prototype", "smc", 1.2)],
)
def test_loop_metrics_equal_the_log_metrics(name, controller, duration):
    """With every period logged, the loop's accumulators give the log's metrics.

    The loop adds e, e^2 (each rounded, no fused multiply-add) and |tau_k - tau_k-1| in
    time order, which is also how NumPy reduces an (N, 7) array along axis 0 (row by
    row, not pairwise): on this machine every error, force and chattering metric is equal
    bit for bit. The true limb speeds |J(X) Xdot| are computed by einsum in the log's
    version and by a compiled dot product in the loop's: they may differ in the last bit.
    The tolerance says what is promised: 1e-13 relative.
    """
    r = pkmctl.simulate(_scenario(name, **{"timing.duration": duration}), controller)
    log, loop = metrics.summary(r, source="log"), metrics.summary(r, source="loop")
    _close(log, loop, rtol=1e-13)
    # auto reads the accumulators (nothing computed twice), except the true limb speeds
    speeds = ("peak_limb_speed_m_per_s", "time_over_speed_limit_s")
    assert metrics.summary(r) == {**loop, **{k: log[k] for k in speeds}}
    assert {k: v for k, v in loop.items() if k not in speeds} == {
        k: v for k, v in log.items() if k not in speeds
    }  # bit for bit, as the docstring says
    for t_from in metrics.WINDOWS:
        if t_from <= r.t[-1]:
            _close(metrics.mean_error(r, t_from=t_from, source="log"),
                   metrics.mean_error(r, t_from=t_from, source="loop"), rtol=1e-13)  # fmt: skip
    if name == "prototype":  # the drive has limits: the loop counts against them
        assert loop["time_at_force_limit_s"] > 0 and loop["time_over_speed_limit_s"] > 0
        assert max(loop["peak_limb_speed_m_per_s"]) > 0.833
    else:
        assert loop["time_at_force_limit_s"] is None and loop["peak_limb_speed_m_per_s"] is None


# ------------------------------------------------------------------ every = N
@pytest.mark.parametrize(
    ("name", "controller", "duration", "every"),
    [("paper", "afsmc", 0.3, 7), ("prototype", "smc", 1.2, 10)],
)
def test_decimated_log_is_every_nth_row_and_metrics_unchanged(name, controller, duration, every):
    full = pkmctl.simulate(_scenario(name, **{"timing.duration": duration}), controller)
    dec = pkmctl.simulate(
        _scenario(name, **{"timing.duration": duration, "logging.every": every}), controller
    )
    assert dec.every == every and dec.t.size == math.ceil(full.t.size / every)
    assert dec.info["steps"] == full.info["steps"] == full.t.size
    _assert_rows(full, dec, every)
    _assert_same_loop_metrics(full, dec)  # the same sums, period by period
    # what a decimated run reports is its loop's metrics over every period: the full log's
    _close(metrics.summary(full), metrics.summary(dec), rtol=1e-13)
    assert dec.rmse() == metrics.rmse(full, source="loop")


def test_chunk_boundaries_do_not_show(monkeypatch):
    """The inputs of a decimated run come in chunks: any chunk size gives the same run."""
    sc = _scenario(**{"timing.duration": 0.1, "logging.every": 7})
    whole = pkmctl.simulate(sc, "pd")
    monkeypatch.setattr(sim, "CHUNK_PERIODS", 333)  # 2000 periods: 7 chunks, cut mid-stride
    cut = pkmctl.simulate(sc, "pd")
    _assert_rows(whole, cut, 1)
    _assert_same_loop_metrics(whole, cut)


def test_a_whole_runs_chunks_do_not_show_and_report_its_progress(monkeypatch):
    """A run logged every period also goes in chunks (its progress after each): any chunk
    size gives the same run, bit for bit."""
    sc = _scenario(**{"timing.duration": 0.1})  # 2000 periods
    whole = pkmctl.simulate(sc, "afsmc")
    monkeypatch.setattr(sim, "CHUNK_PERIODS", 333)
    seen: list[tuple[int, int]] = []
    cut = pkmctl.simulate(sc, "afsmc", progress=lambda done, total: seen.append((done, total)))
    _assert_rows(whole, cut, 1)
    _assert_same_loop_metrics(whole, cut)
    assert seen == [(min(k + 333, 2000), 2000) for k in range(0, 2000, 333)]


def test_a_watched_run_reports_about_every_hundredth_and_runs_the_same(monkeypatch):
    """With ``progress`` a run logged every period goes in chunks of 1 % of it (at least
    PROGRESS_MIN_PERIODS): a 0.5 s run's 10,000 periods in 5 reports, not one."""
    monkeypatch.setattr(sim, "PROGRESS_MIN_PERIODS", 2000)
    sc = _scenario(**{"timing.duration": 0.5})  # 10,000 periods: chunks of 2,000
    whole = pkmctl.simulate(sc, "afsmc")
    seen: list[tuple[int, int]] = []
    watched = pkmctl.simulate(sc, "afsmc", progress=lambda done, total: seen.append((done, total)))
    _assert_rows(whole, watched, 1)
    _assert_same_loop_metrics(whole, watched)
    assert seen == [(k, 10_000) for k in range(2000, 10_001, 2000)]
    monkeypatch.setattr(sim, "PROGRESS_STEPS", 4)  # 1/4 of the run: 2,500 periods a chunk
    seen.clear()
    pkmctl.simulate(sc, "pd", progress=lambda done, total: seen.append((done, total)))
    assert seen == [(k, 10_000) for k in range(2500, 10_001, 2500)]


def test_decimated_partial_result_of_a_diverged_run():
    absurd = {"gains.K": [1e9, 1e9, 1e9], "timing.duration": 0.5}
    with pytest.raises(pkmctl.SimulationDiverged) as full:
        pkmctl.simulate(_scenario(**absurd), controller="smc")
    with pytest.raises(pkmctl.SimulationDiverged) as dec:
        pkmctl.simulate(_scenario(**absurd, **{"logging.every": 4}), controller="smc")
    a, b = full.value.partial, dec.value.partial
    assert full.value.time == dec.value.time and b.info["steps"] == a.t.size
    _assert_rows(a, b, 4)
    _assert_same_loop_metrics(a, b)


def test_decimated_result_round_trips_with_its_metrics(tmp_path):
    r = pkmctl.simulate(_scenario(**{"timing.duration": 0.3, "logging.every": 50}), "smc")
    _, meta = save_result(r, tmp_path)
    back = load_result(meta)
    assert back.every == 50
    assert metrics.summary(back) == metrics.summary(r)


def _numbers(d) -> np.ndarray:
    """Every number of a (nested) summary, in order."""
    out = []
    for v in d.values():
        if isinstance(v, dict):
            out.extend(_numbers(v))
        elif isinstance(v, list | tuple):
            out.extend(math.nan if x is None else float(x) for x in v)
        else:
            out.append(math.nan if v is None else float(v))
    return np.array(out)


def test_campaign_paths_honour_decimation():
    """simulate_many (a campaign's workers reuse their buffers) and the precompiling
    workers (which shorten the run to one period) take a decimated scenario."""
    sc = _scenario(**{"timing.duration": 0.2, "logging.every": 100})
    alone = {"seed": 2, **metrics.summary(pkmctl.simulate(sc, "fsmc", seed=2))}
    runs = sim.simulate_many(sc, "fsmc", seeds=[1, 2], workers=2, keep="metrics", lanes=1)
    assert runs[1] == alone
    # in SIMD lanes (the default): within 1e-12 (LLVM fuses a few multiply-adds otherwise)
    lanes = sim.simulate_many(sc, "fsmc", seeds=[1, 2], workers=2, keep="metrics")
    a, b = _numbers(lanes[1]), _numbers(alone)
    assert len(a) == len(b) and np.allclose(a, b, rtol=1e-12, atol=0.0, equal_nan=True)
    assert sim._compile_group(sc.to_toml(), ("loops", ["fsmc"])) == ""
    assert sim._compile_group(sc.to_toml(), ("steps", ["fsmc"])) == ""


def test_windows_the_loop_did_not_accumulate_are_refused():
    r = pkmctl.simulate(_scenario(**{"timing.duration": 0.3, "logging.every": 10}), "smc")
    with pytest.raises(ValueError, match=r"t_from = 0.1: the loop accumulated .*one period in 10"):
        metrics.rmse(r, t_from=0.1)
    with pytest.raises(ValueError, match="logged one row every 10 periods"):
        metrics.rmse(r, source="log")
    assert metrics.rmse(r, t_from=0.2) == metrics.rmse(r, t_from=0.2, source="loop")
    # a log of every period: the loop's windows are not all there is (it said "the log
    # is decimated"; a tester)
    full = pkmctl.simulate(_scenario(**{"timing.duration": 0.3}), "smc")
    with pytest.raises(ValueError, match=r"0.1: the loop .* only; source='log' gives any"):
        metrics.rmse(full, t_from=0.1, source="loop")
    assert metrics.rmse(full, t_from=0.1)["z_mm"] > 0


@pytest.mark.parametrize("source", ["log", "loop"])
@pytest.mark.parametrize("metric", ["rmse", "max_error", "mean_error"])
def test_a_window_after_the_last_sample_is_one_line_from_either_source(metric, source):
    """max_error gave numpy's "zero-size array to reduction operation maximum", and
    mean_error NaN with two warnings, where rmse said "no samples after it" (a tester)."""
    import warnings

    r = pkmctl.simulate(_scenario(**{"timing.duration": 0.3}), "smc")
    call = getattr(metrics, metric)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for t_from in (0.2, 0.2999):  # the last sample (t = 0.29995) alone in the latter
            assert np.isfinite(list(call(r, t_from=t_from, source="log").values())).all()
        with pytest.raises(ValueError, match=r"^t_from = 1.0: no samples after it$"):
            call(r, t_from=1.0, source=source)  # a window of the loop's, after the end
        with pytest.raises(ValueError, match=r"^t_from = 0.5: "):
            call(r, t_from=0.5, source=source)
        assert call(r, t_from=0.2, source="auto") == call(r, t_from=0.2, source="log")


# ------------------------------------------------------------------ the stepped driver
needs_mujoco = pytest.mark.skipif(
    importlib.util.find_spec("mujoco") is None, reason="MuJoCo is not installed"
)


@needs_mujoco
def test_stepped_plant_decimates_and_accumulates_as_the_loop_does():
    base = {"plant.kind": "mujoco", "timing.duration": 0.02}
    full = pkmctl.simulate(_scenario(**base), "afsmc")
    dec = pkmctl.simulate(_scenario(**base, **{"logging.every": 3}), "afsmc")
    _assert_rows(full, dec, 3)
    _assert_same_loop_metrics(full, dec)
    _close(metrics.summary(full, source="log"), metrics.summary(full, source="loop"), 1e-13)


@needs_mujoco
def test_stepped_plant_logs_the_encoder():
    """On the MuJoCo plant the encoder's q^ is logged as in the compiled loop (issue 10)."""
    sc = _scenario(
        **{"plant.kind": "mujoco", "sensor.kind": "encoder", "timing.control_period": 1e-3,
           "timing.substeps": 20, "timing.duration": 0.1, "logging.every": 2}
    )  # fmt: skip
    r = pkmctl.simulate(sc, controller="pd")
    res = 0.01 / 160_000
    counts = r.q_measured / res
    np.testing.assert_allclose(counts, np.round(counts), rtol=0, atol=1e-6)  # on the grid
    # the encoder reads the lengths of the pose MuJoCo reports (the sensor sees the plant
    # state x = [X, Xdot]); MuJoCo's own slides differ from them by its soft closures,
    # which its stepper keeps under 1 um (here up to ~5e-8 m while PD pulls hard)
    q_of_X = sc.plant().inverse_kinematics(r.X)
    assert np.abs(r.q_measured - q_of_X).max() <= 0.5 * res * (1 + 1e-6) + 1e-15
    assert np.abs(r.q_measured - r.q).max() <= 0.5 * res + 1e-6
    assert not np.array_equal(r.q_measured, r.q)  # the encoder's reading, not the plant's
    J = sc.plant().jacobian(r.X)
    bound = 0.5 * res * np.abs(np.linalg.pinv(J)).sum(axis=2)
    assert np.all(np.abs(r.X_measured - r.X) <= bound * (1 + 1e-6) + 1e-12)
    assert r.q_measured.shape == (50, 4) and r.info["fk_max_iterations"] >= 1


# ------------------------------------------------------------------ memory
def test_one_hour_paper_run_fits_in_a_few_hundred_mb(monkeypatch):
    hour = _scenario(**{"timing.duration": 3600.0, "logging.every": 200})
    n, holds = hour.timing.periods, sim.disturbance_count(hour)
    assert n == 72_000_000
    need = sim.memory_needed(n, 36, every=200, disturbance_values=holds)  # AFSMC: Θ̂ logged
    assert 100 * 2**20 < need < 600 * 2**20, need / 2**20
    full = sim.memory_needed(n, 36, disturbance_values=holds)
    assert full > 30 * 2**30  # every period: tens of GiB
    monkeypatch.setattr(sim, "_available_memory", lambda: 2**30)
    prep = sim.prepare(hour, None)  # accepted: the check passes and the rows are prepared
    held = sum(a.nbytes for a in (prep.t, prep.reference, prep.q_des, prep.tau_des))
    assert prep.t.size == 360_000 and held < need
    with pytest.raises(pkmctl.errors.InsufficientMemory, match=r"logging\.every = 50 needs"):
        sim.prepare(hour.replace(**{"logging.every": 1}), None)
    # and a short run of the same scenario, logged every 200 periods, runs
    r = pkmctl.simulate(hour, "smc", duration=0.5)
    assert r.t.size == 50 and r.info["steps"] == 10_000


def test_simulates_memory_check_counts_its_controllers_log(monkeypatch):
    """An hour of AFSMC logs its 36 Theta^ every period: 48 GiB, not the 29 GiB of the
    shared arrays alone; the offered logging.every must fit with them (it offered 2,
    which needs 24 GiB, on a machine with 22.9)."""
    from pkmctl.sim.simulate import log_columns, resolve_parts

    hour = _scenario(**{"timing.duration": 3600.0})
    assert log_columns(hour, resolve_parts(hour, "afsmc")) == 36
    assert log_columns(hour, resolve_parts(hour, "pd")) == 0
    n, holds = hour.timing.periods, sim.disturbance_count(hour)
    have = sim.memory_needed(n, 36, every=2, disturbance_values=holds) - 2**20
    assert sim.memory_needed(n, every=2, disturbance_values=holds) < have  # without the log
    monkeypatch.setattr(sim, "_available_memory", lambda: have)
    with pytest.raises(pkmctl.errors.InsufficientMemory) as exc:
        pkmctl.simulate(hour, "afsmc")
    assert "logging.every = 5 needs" in str(exc.value), str(exc.value)
    with pytest.raises(pkmctl.errors.InsufficientMemory, match=r"logging\.every = 2 needs"):
        pkmctl.simulate(hour, "pd")


def test_the_encoders_noise_is_counted_before_it_is_drawn(monkeypatch):
    """The encoder draws its noise for the whole run up front, (periods, 4): an hour at
    1 kHz is 115 MB of it, whatever the log keeps."""
    quiet = pkmctl.Scenario.builtin("prototype").replace(
        **{"timing.duration": 3600.0, "logging.every": 1000, "sensor.noise": 0.0}
    )
    noisy = quiet.replace(**{"sensor.noise": 1e-6})
    assert sim.part_memory(quiet) == 0 and sim.part_memory(noisy) == 4
    n = noisy.timing.periods
    base = sim.memory_needed(n, every=1000, disturbance_values=sim.disturbance_count(noisy))
    with_noise = sim.memory_needed(n, every=1000, disturbance_values=sim.disturbance_count(noisy),
                                   part_values=4)  # fmt: skip
    assert with_noise - base == 8 * 4 * n
    # room for the logs but not for the noise: refused in one line, before any draw
    monkeypatch.setattr(sim, "_available_memory", lambda: (base + with_noise) // 2)
    sim.prepare(quiet, None)
    with pytest.raises(pkmctl.errors.InsufficientMemory, match="needs"):
        sim.prepare(noisy, None)


def test_memory_estimate_covers_what_a_decimated_run_allocates():
    sc = _scenario(**{"timing.duration": 0.5, "logging.every": 20})
    r = pkmctl.simulate(sc, "afsmc")
    arrays = [getattr(r, n) for n in ARRAYS if getattr(r, n) is not None]
    logged = sum(a.nbytes for a in arrays)
    need = sim.memory_needed(sc.timing.periods, 36, every=20,
                             disturbance_values=sim.disturbance_count(sc))  # fmt: skip
    assert logged < need


def test_a_cut_result_gives_its_own_metrics_not_the_whole_runs():
    """rmse() of a result cut to t >= 1 s (dataclasses.replace) gave the whole run's
    3.4 deg for beta, the loop's sums, where the rows give 0.005 (a tester). The loop's
    sums now stand only for the rows it logged; a decimated run cut is refused."""
    import dataclasses

    fields = ("t", "X", "Xdot", "X_desired", "Xdot_desired", "q", "q_desired", "F", "tau",
              "tau_desired", "disturbance", "X_measured", "Xdot_measured",
              "q_measured")  # fmt: skip

    def cut(r):
        keep = r.t >= 1.0
        return dataclasses.replace(r, **{f: getattr(r, f)[keep] for f in fields})

    whole = pkmctl.simulate(pkmctl.Scenario.builtin("paper", 1.5), "pd")
    part = cut(whole)
    mine = np.degrees(np.sqrt(np.mean((part.X_desired[:, 2] - part.X[:, 2]) ** 2)))
    assert part.rmse()["beta_deg"] == pytest.approx(mine, rel=1e-12)
    assert whole.rmse()["beta_deg"] > 100 * mine  # (the whole run's, as it was given)
    sc = pkmctl.Scenario.builtin("paper", 1.5).replace(**{"logging.every": 20})
    with pytest.raises(ValueError, match=r"rows are not the 1500 its loop logged"):
        cut(pkmctl.simulate(sc, "pd")).rmse()


def test_a_cgroup_v1_containers_limit_is_seen(tmp_path):
    """Only cgroup v2's memory.max was read: in a v1 container (this VM's kind) a limit
    went unseen by the up-front memory check (a tester)."""
    from pkmctl.sim.simulate import _cgroup_room

    v2, v1 = tmp_path / "v2", tmp_path / "v1"
    v1.mkdir()
    (v1 / "memory.limit_in_bytes").write_text("2147483648\n")
    (v1 / "memory.usage_in_bytes").write_text("536870912\n")
    cgroups = ((str(v2), "memory.max", "memory.current"),
               (str(v1), "memory.limit_in_bytes", "memory.usage_in_bytes"))  # fmt: skip
    assert _cgroup_room(cgroups) == 2**31 - 2**29
    (v1 / "memory.limit_in_bytes").write_text("9223372036854771712\n")  # v1's "no limit"
    assert _cgroup_room(cgroups) is None
    v2.mkdir()
    (v2 / "memory.max").write_text("max\n")
    (v2 / "memory.current").write_text("1\n")
    assert _cgroup_room(cgroups) is None  # v2 first: no limit there
    (v2 / "memory.max").write_text("1000\n")
    assert _cgroup_room(cgroups) == 999
