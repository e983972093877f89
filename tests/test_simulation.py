"""The closed loop: determinism, convergence in the sub-step, physics of the logged run, errors."""

import os
from pathlib import Path

import numpy as np
import pytest

import pkmctl
from pkmctl import metrics
from pkmctl.io.results import load_result, save_result

FULL = os.environ.get("PKMCTL_FULL") == "1"
SHORT = 0.3


@pytest.fixture(scope="module")
def paper():
    return pkmctl.Scenario.builtin("paper")


@pytest.mark.parametrize("controller", ["smc", "fsmc", "afsmc"])
def test_result_shapes_and_content(paper, controller):
    r = pkmctl.simulate(paper, controller=controller, duration=SHORT)
    n = int(round(SHORT / 5e-5))
    assert r.t.shape == (n,) and r.success
    for name in ("X", "Xdot", "X_desired", "F"):
        assert getattr(r, name).shape == (n, 3), name
    for name in ("q", "q_desired", "tau", "tau_desired"):
        assert getattr(r, name).shape == (n, 4), name
    assert (r.theta_hat is not None) == (controller == "afsmc")
    if r.theta_hat is not None:
        assert r.theta_hat.shape == (n, 36)
        np.testing.assert_array_equal(r.theta_hat[0], paper.controller_mechanism().theta)
    assert r.controller == controller and r.scenario.timing.duration == SHORT
    np.testing.assert_array_equal(r.X[0], paper.initial.X)
    assert set(r.rmse()) == set(metrics.RMSE_KEYS)
    plant = paper.plant()
    # the logged q and F are the plant's, at the logged poses
    np.testing.assert_allclose(r.q[::500], plant.inverse_kinematics(r.X[::500]), rtol=1e-12)
    JT_tau = np.einsum("nij,ni->nj", plant.jacobian(r.X[::500]), r.tau[::500])
    np.testing.assert_allclose(r.F[::500], JT_tau, rtol=1e-10, atol=1e-9)


def test_same_seed_bit_identical_other_seed_differs(paper):
    a = pkmctl.simulate(paper, controller="afsmc", duration=SHORT, seed=3)
    b = pkmctl.simulate(paper, controller="afsmc", duration=SHORT, seed=3)
    c = pkmctl.simulate(paper, controller="afsmc", duration=SHORT, seed=4)
    for name in ("X", "Xdot", "tau", "F", "theta_hat", "disturbance"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.disturbance, c.disturbance)
    assert not np.array_equal(a.X, c.X)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["paper", "paper-1khz"])
@pytest.mark.parametrize("controller", ["smc", "fsmc", "afsmc"])
def test_halving_rk4_substep_changes_rmse_under_1_percent(name, controller):
    sc = pkmctl.Scenario.builtin(name)
    sc = sc.replace(**{"timing.duration": 10.0 if FULL else 1.0})
    finer = sc.replace(**{"timing.substeps": 2 * sc.timing.substeps})
    a = pkmctl.simulate(sc, controller=controller).rmse()
    b = pkmctl.simulate(finer, controller=controller).rmse()
    for k in a:
        assert abs(a[k] - b[k]) < 0.01 * abs(b[k]), (k, a[k], b[k])


@pytest.mark.parametrize("controller", ["smc", "afsmc"])
def test_logged_run_satisfies_the_plant_equation(paper, controller):
    """M Xdd + C Xd + G - F recomputed from the log with the true model is the disturbance.

    Over period k the actuator forces and the disturbance are held, so the mean
    acceleration (Xdot_{k+1} - Xdot_k) / T_c at the period's midpoint satisfies the plant
    equation to O(T_c^2).
    """
    r = pkmctl.simulate(paper, controller=controller, duration=SHORT)
    plant = paper.plant()
    Tc = paper.timing.control_period
    k = np.arange(100, r.t.size - 1, 37)  # away from the first kilonewton transient
    Xm = 0.5 * (r.X[k] + r.X[k + 1])
    Vm = 0.5 * (r.Xdot[k] + r.Xdot[k + 1])
    A = (r.Xdot[k + 1] - r.Xdot[k]) / Tc
    F_mid = np.einsum("nij,ni->nj", plant.jacobian(Xm), r.tau[k])
    residual = plant.inverse_dynamics(Xm, Vm, A) - F_mid
    assert np.all(np.abs(residual) <= 2.0 + 1e-3)
    assert np.abs(residual).max() > 0.5  # a disturbance was applied
    np.testing.assert_allclose(residual, r.disturbance[k], atol=2e-3)


def test_diverging_run_raises_with_time_state_and_partial(paper):
    absurd = paper.replace(**{"gains.K": [1e9, 1e9, 1e9]})
    with pytest.raises(pkmctl.SimulationDiverged) as info:
        pkmctl.simulate(absurd, controller="smc", duration=0.5)
    err = info.value
    assert "diverged at t = " in str(err) and "X = " in str(err)
    assert 0 <= err.time < 0.5
    assert err.state.shape == (6,)
    assert err.partial is not None and not err.partial.success
    assert err.partial.t.size == int(round(err.time / 5e-5))
    assert np.all(np.isfinite(err.partial.X))


def test_force_limit_option(paper):
    lim = paper.replace(**{"actuators.force_limit": 300.0})
    r = pkmctl.simulate(lim, controller="afsmc", duration=0.05)
    assert np.abs(r.tau).max() <= 300.0 + 1e-12
    free = pkmctl.simulate(paper, controller="afsmc", duration=0.05)
    assert np.abs(free.tau).max() > 1000.0  # the paper's unbounded actuators ask for kN


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_save_and_load_round_trip(paper, tmp_path, fmt):
    r = pkmctl.simulate(paper, controller="afsmc", duration=0.02)
    table_path, json_path = save_result(r, tmp_path, fmt=fmt)
    back = load_result(json_path)
    for name in ("t", "X", "Xdot", "X_desired", "q", "q_desired", "F", "tau", "theta_hat"):
        np.testing.assert_array_equal(getattr(back, name), getattr(r, name), err_msg=name)
    assert back.scenario == r.scenario and back.controller == "afsmc"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f"afsmc.{fmt}", "afsmc.json"])
    with pytest.raises(ValueError, match="fmt = 'xlsx'"):
        save_result(r, tmp_path, fmt="xlsx")


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
@pytest.mark.parametrize("name", ["paper", "prototype"])
def test_save_and_load_keep_what_the_controller_saw(tmp_path, fmt, name):
    """What the sensor gave the controller (an encoder's pose and velocity differ from
    the truth by up to 1.5e-7 on prototype), the parts and ``info`` come back; with the
    ideal sensor the measured arrays are the true ones, as the run gave them. They used
    to come back None and {}."""
    r = pkmctl.simulate(pkmctl.Scenario.builtin(name, 0.05), controller="pd")
    back = load_result(save_result(r, tmp_path, fmt=fmt)[1])
    for field in ("X_measured", "Xdot_measured", "q_measured", "tau_desired", "disturbance"):
        np.testing.assert_array_equal(getattr(back, field), getattr(r, field), err_msg=field)
    assert back.parts == r.parts and back.info == r.info
    if name == "prototype":
        assert not np.array_equal(back.X_measured, back.X)


def _strict_json(path):
    """The file parsed as standard JSON: NaN and Infinity are not numbers there."""
    import json

    def refuse(name):
        raise ValueError(f"{path.name}: {name} is not JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_the_json_is_standard_and_round_trips_what_null_stands_for(paper, tmp_path):
    """An unbounded actuator's force limit was written as Infinity, a limb speed not
    measured as NaN: JavaScript's JSON.parse refuses both, jq changes them."""
    r = pkmctl.simulate(paper, controller="pd", duration=0.01)
    assert r.loop_metrics.force_limit == np.inf
    _, json_path = save_result(r, tmp_path)
    meta = _strict_json(json_path)
    assert meta["loop_metrics"]["force_limit"] is None
    back = load_result(json_path)
    assert back.loop_metrics.force_limit == np.inf and back.loop_metrics.speed_limit == np.inf
    np.testing.assert_array_equal(back.loop_metrics.peak_limb_speed, r.loop_metrics.peak_limb_speed)


def test_a_run_logging_one_row_keeps_its_metrics(paper, tmp_path):
    r = pkmctl.simulate(paper.replace(**{"logging.every": 10_000}), "pd", duration=0.5)
    assert r.t.size == 1
    meta = _strict_json(save_result(r, tmp_path)[1])
    assert meta["metrics"]["rmse"] == pytest.approx(r.rmse(), rel=0, abs=0)


def test_a_result_reads_back_after_its_fis_moved_or_changed(tmp_path):
    """The JSON carries the .fis text: the result of a run with a scenario's own .fis
    reads back with the system it ran, wherever the file went."""
    from pkmctl.fuzzy.fis import read_fis

    fis = tmp_path / "my.fis"
    paper_fis = Path(pkmctl.__file__).parent / "fuzzy" / "data" / "paper_flc.fis"
    fis.write_text(paper_fis.read_text())
    sc = pkmctl.Scenario.builtin("paper").replace(**{"fuzzy.fis": str(fis)})
    r = pkmctl.simulate(sc, "fsmc", duration=0.01)
    out = tmp_path / "out"
    _, json_path = save_result(r, out)
    original = fis.read_text()
    fis.write_text(original.replace("Range=[-1 1]", "Range=[-2 2]", 1))  # changed ...
    changed = load_result(json_path)
    fis.unlink()  # ... and gone
    gone = load_result(json_path)
    for back in (changed, gone):
        assert read_fis(back.scenario.fuzzy.fis) == read_fis(paper_fis)
        np.testing.assert_array_equal(back.X, r.X)


def test_unknown_controller(paper):
    with pytest.raises(ValueError, match="controller = 'pid'"):
        pkmctl.simulate(paper, controller="pid", duration=0.01)


def test_simulate_many_equals_simulate_per_seed(paper):
    from pkmctl.sim.simulate import simulate_many

    runs = simulate_many(paper, "fsmc", seeds=[1, 2, 1], duration=0.05, workers=2)
    single = pkmctl.simulate(paper, controller="fsmc", duration=0.05, seed=2)
    # in SIMD lanes: equal to the single run within 1e-12 of its size (DESIGN.md §6; the
    # vectorised controller rounds a few sums differently, ~1e-16 relative)
    assert np.max(np.abs(runs[1].X - single.X)) <= 1e-12 * np.max(np.abs(single.X))
    np.testing.assert_array_equal(runs[0].tau, runs[2].tau)
    assert runs[0].scenario.disturbance.seed == 1 and runs[1].scenario.disturbance.seed == 2
    with pytest.raises(pkmctl.ScenarioError, match="disturbance.seed = -1"):
        simulate_many(paper, "fsmc", seeds=[3, -1], duration=0.05)


def test_desired_forces_match_the_mechanism_methods(paper):
    # Figures 13-16 and 23-26: the compiled pass equals IK and J (J^T J)^-1 (M Xdd + C Xd + G)
    r = pkmctl.simulate(paper, controller="smc", duration=0.05)
    plant = paper.plant()
    k = slice(None, None, 97)
    Xdd = -4.0 * (
        r.X_desired[k] - np.asarray(paper.trajectory.offset)
    )  # eq. 54: X'' = -w^2 (X - c)
    F = plant.inverse_dynamics(r.X_desired[k], r.Xdot_desired[k], Xdd)
    np.testing.assert_allclose(
        r.tau_desired[k], plant.actuator_forces(r.X_desired[k], F), rtol=1e-10
    )
    np.testing.assert_allclose(r.q_desired[k], plant.inverse_kinematics(r.X_desired[k]), rtol=1e-13)


def test_desired_forces_are_the_true_machines(paper):
    """On the machine as built (rotor inertia, friction, a payload) tau_d drives that
    machine, not the rigid model (it used to leave the options out: ~90 N per limb less
    than the prototype needs while it tracks). Oracles: the extended regressor with the
    true Theta_ext (another derivation of the rotor and friction terms), and the plant's
    own machine_dynamics for the payload; the rigid plant's tau_d is unchanged."""
    from pkmctl.ident.excite import _machine
    from pkmctl.sim.plants import RigidPlant, machine_dynamics
    from pkmctl.sim.simulate import _desired

    sc = pkmctl.Scenario.builtin("prototype-tuned", 0.5)
    plant, k = sc.plant(), np.arange(0, 500, 7)
    _, ref, _, tau = _desired(sc, plant, k)
    X, Xd, Xdd = ref[:, 0:3], ref[:, 3:6], ref[:, 6:9]
    theta_ext, v_s = _machine(sc)
    Y = plant.extended_regressor(X, Xd, Xd, Xdd, friction_velocity=v_s)
    J = plant.jacobian(X)
    need = np.einsum("nij,j->ni", Y, theta_ext)
    np.testing.assert_allclose(np.einsum("nij,ni->nj", J, tau), need, rtol=1e-9, atol=1e-9)
    rigid = plant.actuator_forces(X, plant.inverse_dynamics(X, Xd, Xdd))
    assert np.max(np.abs(tau - rigid)) > 50.0  # the options matter here
    # a payload off centre: the plant's own M, C v, G and friction at each state
    heavy = sc.replace(**{"payload.mass": 5.0, "payload.offset": [0.05, -0.02, 0.03]})
    _, ref, _, tau = _desired(heavy, plant, k)
    machine = RigidPlant.from_context(pkmctl.PartContext(plant, plant, None, 0.0, None, heavy))
    for n in range(0, k.size, 10):
        M, Cv, G, f = machine_dynamics(machine, ref[n, 0:3], ref[n, 3:6], ref[n, 3:6])
        F = M @ ref[n, 6:9] + Cv + G + f
        np.testing.assert_allclose(J[n].T @ tau[n], F, rtol=1e-11, atol=1e-9)
    # the rigid machine of the paper: the kernel of its runs, bit for bit
    _, ref, _, tau = _desired(paper, paper.plant(), k)
    assert np.array_equal(tau, sim_desired_rigid(paper, ref))


def sim_desired_rigid(sc, ref):
    from pkmctl.sim.simulate import _desired_kernel

    plant = sc.plant()
    q, tau = np.empty((ref.shape[0], 4)), np.empty((ref.shape[0], 4))
    X, Xd, Xdd = (np.ascontiguousarray(ref[:, i : i + 3]) for i in (0, 3, 6))
    _desired_kernel(plant.geometry, plant.theta, X, Xd, Xdd, q, tau)
    return tau


def test_desired_limb_lengths_are_those_of_desired_forces_bit_for_bit(paper):
    from pkmctl.sim.simulate import desired_forces, desired_limb_lengths

    rng = np.random.default_rng(7)
    n = 20_000
    X = np.column_stack([rng.uniform(0.4, 1.0, n), rng.uniform(-1.3, 1.3, (n, 2))])
    X[:1000] = paper.trajectory.build().evaluate(np.arange(1000) * 1e-2)[0]
    plant = paper.plant()
    q, _ = desired_forces(plant, X, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
    np.testing.assert_array_equal(desired_limb_lengths(plant, X), q)


def test_metrics_only_runs_log_t0_and_keep_every_metric(paper):
    from pkmctl.sim.simulate import metrics_only, prepare, resolve_parts, run_prepared

    sc = paper.replace(**{"timing.duration": 0.3})
    light = metrics_only(sc)
    assert light.logging.every == sc.timing.periods and light.replace() == light  # valid
    assert light.model_dump(exclude={"logging"}) == sc.model_dump(exclude={"logging"})
    parts = resolve_parts(sc, "fsmc")
    full = run_prepared(prepare(sc, None), parts, 5)
    one = run_prepared(prepare(light, None), parts, 5)
    assert one.t.tolist() == [0.0] and one.X.shape == (1, 3)
    for name in ("X", "tau", "q_desired", "tau_desired", "F"):
        np.testing.assert_array_equal(getattr(one, name)[0], getattr(full, name)[0])
    np.testing.assert_array_equal(one.final_state["plant"], full.final_state["plant"])
    assert metrics.summary(one) == metrics.summary(full, source="loop")


def test_a_decimated_runs_chunks_of_inputs_are_prepared_once(paper):
    """A decimated run up to CACHED_PERIODS has its chunks computed by prepare, once for
    all its runs, bit for bit the rows of the full preparation; a longer one computes
    them as the loop goes."""
    from pkmctl.sim.simulate import CACHED_PERIODS, CHUNK_PERIODS, prepare

    sc = paper.replace(**{"timing.duration": 0.3})
    full = prepare(sc, None)
    dec = prepare(sc.replace(**{"logging.every": 7}), None)
    n = sc.timing.periods
    assert list(dec.cached) == [(0, n)] and dec.chunk(0, n) is dec.cached[0, n]
    for a, b in zip(dec.chunk(0, n), full.chunk(0, n), strict=True):
        np.testing.assert_array_equal(a, b)  # the rows of the full preparation, bit for bit
    for a, b in zip(dec.chunk(5, 99), full.chunk(5, 99), strict=True):
        np.testing.assert_array_equal(a, b)
    # two chunks (a paper-claims run is 84,000 periods): both kept, as the loop asks them
    two = paper.replace(**{"timing.duration": (CHUNK_PERIODS + 10) * 5e-5, "logging.every": 7})
    p2 = prepare(two, None)
    m = two.timing.periods
    assert list(p2.cached) == [(0, CHUNK_PERIODS), (CHUNK_PERIODS, m)]
    assert p2.chunk(CHUNK_PERIODS, m) is p2.cached[CHUNK_PERIODS, m]
    ref = prepare(two.replace(**{"logging.every": 1}), None)
    for a, b in zip(p2.chunk(CHUNK_PERIODS, m), ref.chunk(CHUNK_PERIODS, m), strict=True):
        np.testing.assert_array_equal(a, b)
    long = paper.replace(**{"timing.duration": (CACHED_PERIODS + 1) * 5e-5, "logging.every": 7})
    assert prepare(long, None).cached is None  # too long to keep: computed as the loop goes


def test_summary_of_some_groups_is_the_metrics_bit_for_bit(paper):
    from pkmctl.sim import metrics

    r = pkmctl.simulate(paper, "fsmc", duration=1.2, seed=2)
    every = metrics.summary(r)
    assert list(every) == list(metrics.SUMMARY_GROUPS)
    assert every["rmse"] == metrics.rmse(r) and every["max_error"] == metrics.max_error(r)
    assert every["rmse_after_1s"] == metrics.rmse(r, t_from=1.0)
    assert every["peak_force_N"] == metrics.peak_forces(r).tolist()
    assert metrics.summary(r, ["max_error", "rmse_after_1s"]) == {
        "rmse_after_1s": every["rmse_after_1s"],
        "max_error": every["max_error"],
    }
    with pytest.raises(ValueError, match="'rms' unknown"):
        metrics.summary(r, ["rms"])


def test_simulate_many_metrics_mode_equals_full_results(paper):
    from pkmctl.sim.metrics import summary
    from pkmctl.sim.simulate import simulate_many

    seeds = [4, 5, 6]
    full = simulate_many(paper, "afsmc", seeds=seeds, duration=0.05, workers=2)
    light = simulate_many(paper, "afsmc", seeds=seeds, duration=0.05, workers=2, keep="metrics")
    for s, r, m in zip(seeds, full, light, strict=True):
        assert m["seed"] == s
        # no log, no desired forces, reused buffers: the loop's metrics of the full run
        assert m == {"seed": s, **summary(r, source="loop")}
        assert m["rmse"] == summary(r)["rmse"] and m["max_error"] == summary(r)["max_error"]
    with pytest.raises(ValueError, match="keep = 'all'"):
        simulate_many(paper, "afsmc", seeds=[1], duration=0.05, keep="all")


def test_simulate_many_returns_at_an_error_without_waiting_for_running_batches(monkeypatch):
    """A Ctrl-C (or a diverged run, raised) came back only when the batches already
    running had ended, their compiled loops not interruptible: 14 s after the signal for
    16 runs of 60 s (a tester). It now returns at once; those batches end in the
    background."""
    import threading
    import time

    from pkmctl.sim import simulate as sim

    started = threading.Event()
    t0 = []

    def one_fails_one_runs(*args, **kwargs):
        if not started.is_set():
            started.set()
            t0.append(time.perf_counter())  # (after any compiling prepare needed)
            time.sleep(0.2)  # the other batch is running by now
            raise RuntimeError("stop here")
        time.sleep(3.0)  # a long run, its loop not interruptible

    monkeypatch.setattr(sim, "run_prepared", one_fails_one_runs)
    with pytest.raises(RuntimeError, match="stop here"):
        pkmctl.simulate_many("paper", "pd", seeds=range(2), duration=0.01, workers=2, lanes=1)
    assert time.perf_counter() - t0[0] < 1.5  # not the 3 s of the other batch


def test_simulate_many_reports_progress_as_batches_end():
    """A notebook's 100 seeds showed nothing until all had run (a tester)."""
    seen = []

    def note(done: int, n: int) -> None:
        seen.append((done, n))

    runs = pkmctl.simulate_many(
        "paper", "pd", seeds=range(5), duration=0.01, workers=1, lanes=1, progress=note
    )
    assert len(runs) == 5 and seen == [(k, 5) for k in range(1, 6)]
    with pytest.raises(TypeError, match="progress = 3: must be a function"):
        pkmctl.simulate_many("paper", "pd", seeds=[1], progress=3)  # type: ignore[arg-type]
