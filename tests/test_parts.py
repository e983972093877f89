"""The loop of parts: users' own parts (docs/parts.md, run as written), registration errors,
final states, and the baselines PD and CTC against the model's own terms."""

import inspect
import re
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from conftest import random_poses

import pkmctl
from pkmctl.parts import PartError, get_part, names

DOC = Path(__file__).resolve().parents[1] / "docs" / "parts.md"


def _blocks():
    return re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.S)


@pytest.fixture(scope="module")
def doc_modules(tmp_path_factory):
    """The doc's `# my_*.py` blocks saved as the user's own files, importable."""
    folder = tmp_path_factory.mktemp("user")
    for code in _blocks():
        first = code.splitlines()[0]
        if first.startswith("# ") and first.endswith(".py"):
            (folder / first[2:]).write_text(code, encoding="utf-8")
    sys.path.insert(0, str(folder))
    yield folder
    sys.path.remove(str(folder))


def test_docs_parts_examples_run_as_written(doc_modules, capsys):
    blocks = [b for b in _blocks() if not b.startswith("# my_")]
    assert len(blocks) == 2
    for code in blocks:
        ns: dict = {}
        exec(compile(code, str(DOC), "exec"), ns)  # noqa: S102
    out = capsys.readouterr().out.split()
    assert out[-1] == "True"  # the quantised pose is within half a step of the true one
    assert "my-law" in names("controller") and "quantised-pose" in names("sensor")


def test_a_users_law_runs_in_the_loop_and_matches_the_same_law_from_python(doc_modules):
    import my_law  # noqa: F401

    sc = pkmctl.Scenario.builtin("paper")
    r = pkmctl.simulate(sc, controller="my-law", duration=0.05)
    assert r.controller == "my-law" and r.success and r.final_state["controller"].shape == (0,)
    # the same law, evaluated from Python at the logged samples, gives the logged command
    model = sc.controller_mechanism()
    g = sc.controller_gains()
    k = np.arange(0, r.t.size, 97)
    e, ed = r.X_desired[k] - r.X[k], r.Xdot_desired[k] - r.Xdot[k]
    F = g.pd_kp * e + g.pd_kd * ed + model.gravity(r.X_desired[k])
    tau = np.stack([model.actuator_forces(x, f) for x, f in zip(r.X[k], F, strict=True)])
    np.testing.assert_allclose(r.tau[k], tau, rtol=1e-9, atol=1e-9)
    ctrl = pkmctl.make_controller("my-law", model, g, period=sc.timing.control_period)
    np.testing.assert_allclose(
        ctrl.step(r.X[k[3]], r.Xdot[k[3]], r.X_desired[k[3]], r.Xdot_desired[k[3]], np.zeros(3)),
        F[3],
        rtol=1e-12,
    )


def test_a_run_of_a_users_part_records_its_version(doc_modules, tmp_path):
    """A run's JSON said nothing of which version of the user's controller made it: an
    edited plugin gave other numbers under the same provenance (a tester)."""
    import json

    import my_law  # noqa: F401

    from pkmctl.io.results import load_result, save_result

    r = pkmctl.simulate("paper", controller="my-law", duration=0.002)
    users = r.info["software"]["user_parts"]
    assert list(users) == ["controller my-law"]
    assert users["controller my-law"]["files"] == [str(doc_modules / "my_law.py")]
    assert len(users["controller my-law"]["sha256"]) == 16
    _, meta = save_result(r, tmp_path)
    assert json.loads(meta.read_text())["software"]["user_parts"] == users
    assert load_result(meta).info["software"]["user_parts"] == users
    assert "user_parts" not in pkmctl.simulate("paper", "pd", duration=0.002).info["software"]


class _P(NamedTuple):
    a: float


def test_registration_errors_are_one_line():
    def ok(p, state, work, y, ref, F):
        pass

    def short(p, state, y, F):
        pass

    def keyword(p, state, work, y, ref, *, F):  # six, one of them not plain
        pass

    cases = [
        (lambda: pkmctl.register_controller("smc", params=_P, build=lambda c: _P(1.0))(ok),
         "controller 'smc': a controller of that name is already registered \\(one of "
         "pkmctl's own\\)"),
        (lambda: pkmctl.register_controller("x-short", params=_P, build=lambda c: _P(1.0))(short),
         r"takes 4 arguments, the contract needs 6 plain ones \(p, state, work, y, ref, F\)$"),
        # six, one keyword-only: "takes 6 arguments, the contract needs 6" said nothing
        (lambda: pkmctl.register_controller("x-kw", params=_P, build=lambda c: _P(1.0))(keyword),
         r"takes 6 arguments, the contract needs 6 plain ones \(p, state, work, y, ref, F\); "
         r"no keyword-only, default or \* arguments$"),
        (lambda: pkmctl.register_controller("x-dict", params=dict, build=lambda c: {})(ok),
         "must be a typing.NamedTuple class"),
        (lambda: pkmctl.register_sensor("x-nobuild", params=_P)(ok),
         "give build=... or a classmethod _P.from_context"),
    ]  # fmt: skip
    for make, message in cases:
        with pytest.raises(PartError, match=message) as info:
            make()
        assert "\n" not in str(info.value)
    with pytest.raises(PartError, match=r"controller = 'nope': must be one of .*afsmc"):
        pkmctl.simulate("paper", controller="nope", duration=0.01)
    # how a part of one's own is found, a Dask worker's too (a tester's campaign records
    # said "must be one of ..." where the workers lacked the plugin)
    with pytest.raises(PartError, match=r"worker's --preload FILE.py, or an import in Python\)$"):
        pkmctl.simulate("paper", controller="nope", duration=0.01)


class _Zero(NamedTuple):
    k: float


def test_a_refused_registration_registers_nothing():
    """A typo in ``lanes=`` was refused, but the part stayed registered and ran, and the
    corrected registration was then refused as "already registered"."""
    from pkmctl.parts import names

    def zero(p, state, work, y, ref, F):
        for i in range(3):
            F[i] = 0.0

    def zero_lanes(p, state, work, y, ref, F):
        for i in range(3):
            for lane in range(F.shape[1]):
                F[i, lane] = 0.0

    def register(**lanes):
        return pkmctl.register_controller("x-zero", params=_Zero, build=lambda c: _Zero(1.0),
                                          **lanes)(zero)  # fmt: skip

    before = names("controller")
    with pytest.raises(PartError, match="'stepp'"):
        register(lanes={"stepp": zero_lanes}, lane_work=lambda p, n: ())
    with pytest.raises(PartError, match="lane_work"):
        register(lanes={"step": zero_lanes})
    assert names("controller") == before
    with pytest.raises(PartError, match="controller = 'x-zero': must be one of"):
        pkmctl.simulate("paper", controller="x-zero", duration=0.01)
    register(lanes={"step": zero_lanes}, lane_work=lambda p, n: ())  # the corrected one
    assert "x-zero" in names("controller")


class _Log(NamedTuple):
    k: float


class _Listed(NamedTuple):
    gains: list


def test_a_bundle_field_compiled_code_cannot_take_is_named():
    """A list in the bundle failed to compile the loop with Numba's "NRT required but not
    enabled", naming no field."""

    @pkmctl.register_controller("x-listed", params=_Listed, build=lambda c: _Listed([1.0, 2.0]))
    def listed(p, state, work, y, ref, F):
        for i in range(3):
            F[i] = p.gains[0]

    with pytest.raises(PartError, match=r"^controller 'x-listed': its bundle's field 'gains' "
                                        r"is a list; compiled code takes numbers"):  # fmt: skip
        pkmctl.simulate("paper", controller="x-listed", duration=0.01)


def test_wiring_mistakes_are_refused_at_registration():
    """``log`` without ``log_size`` was never called; ``log_size`` without ``log`` gave an
    all-zero array in ``result.logs`` that looked like data; an initial state given as an
    array failed only at run time."""

    def law(p, state, work, y, ref, F):
        pass

    def log(p, state, row):
        row[0] = 1.0

    for options, message in (
        ({"log": log}, "a log function needs log_size = m"),
        ({"log_size": 3}, "log_size = 3 needs a log function"),
        ({"state_size": 2, "initial_state": np.ones(2)},  # failed at run time: not callable
         r"initial_state = array\(\[1., 1.\]\): must be a function of the bundle"),
    ):  # fmt: skip
        with pytest.raises(PartError, match=f"^controller 'x-log': {message}"):
            pkmctl.register_controller("x-log", params=_Log, build=lambda c: _Log(1.0),
                                       **options)(law)  # fmt: skip


@pytest.mark.parametrize("controller", ["smc", "fsmc", "afsmc", "afsmc-ext", "pd", "ctc"])
def test_the_limb_jacobian_a_controller_leaves_is_the_actuators(controller):
    """The contract behind sharing it (parts.py): after each step, the work entry the
    controller declares holds the limb Jacobian at y[:3] with the controllers' model,
    bit for bit what the actuator would compute; the actuator's command_at gives the
    same command from it as its command."""
    from pkmctl.fuzzy import FLC
    from pkmctl.model.kinematics import limb_jacobian
    from pkmctl.parts import PartContext

    sc = pkmctl.Scenario.builtin("prototype" if controller == "afsmc-ext" else "paper")
    ctx = PartContext(sc.plant(), sc.controller_mechanism(), sc.controller_gains(),
                      sc.timing.control_period, FLC(), sc)  # fmt: skip
    part = get_part("controller", controller)
    assert part.limb_jacobian is not None
    p, state, work = part.make(ctx)
    ap, astate, awork = get_part("actuator", "ideal").make(ctx)
    step = part.compiled["step"]
    act = get_part("actuator", "ideal").compiled
    rng = np.random.default_rng(8)
    for X in random_poses(rng, 20):
        y = np.concatenate([X, rng.normal(size=3)])
        ref = np.concatenate([X + 1e-3 * rng.normal(size=3), rng.normal(size=6)])
        F = np.empty(3)
        step(p, state, work, y, ref, F)
        shared = work
        for i in part.limb_jacobian:
            shared = shared[i]
        R, Jq, q = np.empty((3, 3)), np.empty((4, 3)), np.empty(4)
        limb_jacobian(ctx.model.geometry, y[:3], R, Jq, q)
        assert np.array_equal(shared, Jq)
        a, b = np.empty(4), np.empty(4)
        act["command"](ap, astate, awork, y, F, a)
        act["command_at"](ap, astate, awork, y, F, shared, b)
        assert np.array_equal(a, b)


def test_limb_jacobian_is_a_controllers_path_into_its_work():
    def ok(p, state, work, y, ref, F):
        pass

    for bad in ((), (0, -1), "0,5", (0, 1.5)):
        with pytest.raises(PartError, match=r"limb_jacobian = .*: a controller's path") as info:
            pkmctl.register_controller("x-jac", params=_P, build=lambda c: _P(1.0),
                                       limb_jacobian=bad)(ok)  # fmt: skip
        assert "\n" not in str(info.value)
    assert "x-jac" not in names("controller")


def test_a_limb_jacobian_path_to_no_limb_jacobian_is_named_before_compiling():
    """A path to the work's (3,) array failed to compile as "cannot index array(float64,
    1d, C) with 2 indices", naming neither limb_jacobian nor the shape (a tester)."""
    from pkmctl.model.dynamics import JQ, make_work

    def law(p, state, work, y, ref, F):
        for i in range(3):
            F[i] = 0.0

    cases = {
        (1,): r"work\[1\] is float64 \(3,\); it must be the \(4, 3\) float64 array",
        (2,): r"work is a tuple of 2, which has no \[2\]",
        (0, JQ, 0): rf"work\[0\]\[{JQ}\] is an array, which has no \[0\]",
        (0,): r"work\[0\] is a tuple of \d+; it must be",
    }

    def register(name, path):
        class P(NamedTuple):  # one class per part
            gain: float

        pkmctl.register_controller(name, params=P, build=lambda c: P(1.0), limb_jacobian=path,
                                   work=lambda p: (make_work(), np.empty(3)))(law)  # fmt: skip

    for i, (path, said) in enumerate(cases.items()):
        register(f"x-badjac{i}", path)
        with pytest.raises(
            PartError, match=rf"^controller 'x-badjac{i}': limb_jacobian = .*{said}"
        ):
            pkmctl.simulate("paper", f"x-badjac{i}", duration=0.001)
    # (the built-in controllers' paths pass it in every run)


def test_a_step_that_does_not_compile_names_the_part():
    class Bad(NamedTuple):
        gain: float

    @pkmctl.register_controller("x-bad", params=Bad, build=lambda ctx: Bad(1.0))
    def bad(p, state, work, y, ref, F):
        F[0] = p.no_such_field

    with pytest.raises(PartError, match=r"the part controller 'x-bad' does not compile: ") as info:
        pkmctl.simulate("paper", controller="x-bad", duration=0.001)
    assert "\n" not in str(info.value)
    # the cause and where, not "No implementation of function controller_step found"
    source, first = inspect.getsourcelines(getattr(bad, "py_func", bad))
    line = first + next(i for i, text in enumerate(source) if "= p.no_such_field" in text)
    assert str(info.value).endswith(
        "Unknown attribute 'no_such_field' of type Bad(float64 x 1) "
        f"(test_parts.py, line {line}: F[0] = p.no_such_field)"
    ), str(info.value)


def test_scenario_names_unknown_parts_in_one_line():
    with pytest.raises(pkmctl.ScenarioError, match=r"sensor.kind: 'nope': unknown sensor"):
        pkmctl.Scenario.builtin("paper").replace(**{"sensor.kind": "nope"})
    # a long kind is cut (a fuzzer's 100,000 characters made a line of 100,200)
    for field in ("sensor.kind", "plant.kind", "actuators.kind"):
        with pytest.raises(pkmctl.ScenarioError) as info:
            pkmctl.Scenario.builtin("paper").replace(**{field: "x" * 100_000})
        assert len(str(info.value)) < 400 and "'xxx" in str(info.value), str(info.value)[:500]
    with pytest.raises(pkmctl.ScenarioError) as info:
        pkmctl.Scenario.from_toml(pkmctl.Scenario.builtin("paper").to_toml().replace(
            'kind = "sinusoid"', f'kind = "{"y" * 100_000}"', 1))  # fmt: skip
    assert len(str(info.value)) < 200 and "must be one of sinusoid, fourier" in str(info.value)
    with pytest.raises(PartError) as info:
        get_part("sensor", "z" * 100_000)
    assert len(str(info.value)) < 400
    text = pkmctl.Scenario.builtin("paper").to_toml()
    assert '[plant]\nkind = "rigid"' in text and pkmctl.Scenario.from_toml(text).plant_spec.kind


def test_result_carries_every_parts_final_state():
    r = pkmctl.simulate("paper", controller="afsmc", duration=0.01)
    fs = r.final_state
    assert set(fs) == {"plant", "sensor", "controller", "actuator"}
    np.testing.assert_allclose(fs["plant"][:3], r.X[-1], atol=1e-3)  # one period later
    assert fs["plant"].shape == (6,) and fs["controller"].shape == (7 + 36,)
    # the controller's final estimate is one adaptation step past the last logged one
    assert not np.array_equal(fs["controller"][7:], r.theta_hat[-1])
    assert r.parts == {"plant": "rigid", "sensor": "ideal", "controller": "afsmc",
                       "actuator": "ideal"}  # fmt: skip
    np.testing.assert_array_equal(r.X_measured, r.X)  # the ideal sensor
    assert get_part("controller", "afsmc").adaptive


# ---------------------------------------------------------------- baselines


def test_ctc_with_the_exact_model_and_zero_error_gives_inverse_dynamics(robot):
    rng = np.random.default_rng(30)
    for X in random_poses(rng, 10):
        Xd, Xdd = rng.normal(size=3), rng.normal(size=3) * 3
        F = pkmctl.CTC(robot, period=5e-5).step(X, Xd, X, Xd, Xdd)
        expected = robot.mass_matrix(X) @ Xdd + robot.coriolis_matrix(X, Xd) @ Xd
        expected += robot.gravity(X)
        np.testing.assert_allclose(F, expected, rtol=1e-12, atol=1e-10)


def test_ctc_law_away_from_zero_error(robot):
    rng = np.random.default_rng(31)
    g = pkmctl.Gains()
    for Xdes in random_poses(rng, 10):
        X = Xdes + rng.normal(size=3) * [0.002, 0.02, 0.02]
        Xdot, Xd_des, Xdd_des = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
        F = pkmctl.CTC(robot, g, period=5e-5).step(X, Xdot, Xdes, Xd_des, Xdd_des)
        a = Xdd_des + g.ctc_kd * (Xd_des - Xdot) + g.ctc_kp * (Xdes - X)
        expected = robot.mass_matrix(X) @ a + robot.coriolis_matrix(X, Xdot) @ Xdot
        np.testing.assert_allclose(F, expected + robot.gravity(X), rtol=1e-11, atol=1e-9)


def test_pd_law(robot):
    rng = np.random.default_rng(32)
    g = pkmctl.Gains()
    for Xdes in random_poses(rng, 10):
        X, Xdot, Xd_des = Xdes + rng.normal(size=3) * 0.01, rng.normal(size=3), rng.normal(size=3)
        F = pkmctl.PD(robot, g, period=5e-5).step(X, Xdot, Xdes, Xd_des, np.zeros(3))
        expected = g.pd_kp * (Xdes - X) + g.pd_kd * (Xd_des - Xdot) + robot.gravity(X)
        np.testing.assert_allclose(F, expected, rtol=1e-12, atol=1e-9)


def test_pd_steady_error_under_a_gravity_mismatch_is_dG_over_Kp():
    # hold the home pose (no motion, no disturbance) with a model 15 % light: at rest
    # K_p e = G(X) - G^(X), so e = dG / K_p, axis by axis (G^ is evaluated at X itself)
    sc = pkmctl.Scenario.builtin("paper").replace(
        **{
            "trajectory.amplitude": [0.0, 0.0, 0.0],
            "trajectory.offset": [0.7, 0.05, -0.05],
            "initial.X": [0.7, 0.05, -0.05],
            "disturbance.amplitude": [0.0, 0.0, 0.0],
            "timing.duration": 4.0,  # the slowest closed-loop mode is ~8 1/s
        }
    )
    r = pkmctl.simulate(sc, controller="pd")
    X = r.X[-1]
    dG = sc.plant().gravity(X) - sc.controller_mechanism().gravity(X)
    e = sc.trajectory.offset - X
    np.testing.assert_allclose(e, dG / sc.controller_gains().pd_kp, rtol=1e-6, atol=1e-12)
    assert abs(e[0]) > 1e-5  # the mismatch is visible: 25 N over 50 kN/m is 0.5 mm
    np.testing.assert_allclose(r.Xdot[-1], 0.0, atol=1e-9)  # and the plant is at rest


@pytest.mark.parametrize("controller", ["pd", "ctc"])
def test_baselines_track_the_paper_trajectory(controller):
    r = pkmctl.simulate("paper", controller=controller, duration=2.0)
    after = pkmctl.metrics.rmse(r, t_from=1.0)
    assert after["z_mm"] < 1.0 and after["beta_deg"] < 0.5, after


def test_precompile_plans_each_kernel_once_and_skips_what_is_compiled():
    from pkmctl.sim.loop import is_compiled
    from pkmctl.sim.simulate import _plan, precompile, resolve_parts

    five = ["smc", "fsmc", "afsmc", "pd", "ctc"]
    # first the plant's kernels (one loop) beside the fuzzy controllers' own (no loop),
    # then the other loops from the cache
    assert _plan(five, {"fsmc", "afsmc"}, 2) == [
        [("loops", ["smc"]), ("steps", ["fsmc", "afsmc"])],
        [("loops", ["fsmc", "pd"]), ("loops", ["afsmc", "ctc"])],
    ]
    assert _plan(["fsmc", "afsmc"], {"fsmc", "afsmc"}, 2) == [
        [("loops", ["fsmc"]), ("loops", ["afsmc"])]
    ]
    assert _plan(["smc", "pd", "ctc"], set(), 2) == [[("loops", ["smc", "ctc"]), ("loops", ["pd"])]]
    sc = pkmctl.Scenario.builtin("paper")
    pkmctl.simulate(sc, controller="smc", duration=0.001)
    assert is_compiled(resolve_parts(sc, "smc"))  # a run leaves its marker ...
    assert precompile(sc, ["smc"]) == []  # ... so nothing is compiled again


@pytest.mark.parametrize(
    "name", ["", " x", "my law", "law\tb", "ab/../../evil", "..", ".hidden", "a\\b", "x" * 65]
)
def test_a_part_name_is_a_safe_file_name(name):
    """The message said "without spaces" and let "my law" through; a name is also a file
    name (simulate writes NAME.parquet): "ab/../../evil" wrote outside --out."""
    with pytest.raises(PartError, match="must be 1-64 letters, digits, '_', '.' or '-'"):
        pkmctl.register_controller(name, params=tuple)(lambda p, state, work, y, ref, F: None)


class _Contact(NamedTuple):
    lim: float

    @classmethod
    def from_context(cls, ctx):
        return cls(1000.0)


def _contact_force(p, state, cmd, tau):
    for i in range(4):
        tau[i] = state[i]


def _contact_derivative(p, state, cmd, dstate):
    for i in range(4):
        dstate[i] = (cmd[i] - state[i]) * 1000.0


def test_more_continuous_entries_than_state_is_refused_before_the_run(tmp_path):
    """continuous = 4 with state_size = 1 ran: the loop integrated past the state's end
    (a free() abort, or "diverged" blaming the controller)."""

    @pkmctl.register_actuator(
        "x-contact", params=_Contact, force=_contact_force, derivative=_contact_derivative,
        continuous=4, state_size=1,
    )  # fmt: skip
    def command(p, state, work, y, F, cmd):
        for i in range(4):
            cmd[i] = 0.0

    sc = pkmctl.Scenario.builtin("paper").replace(**{"actuators.kind": "x-contact"})
    with pytest.raises(PartError) as info:
        pkmctl.simulate(sc, "pd", duration=0.01)
    assert str(info.value) == (
        "actuator 'x-contact': continuous = 4: more than its state_size (1); the loop "
        "integrates the first `continuous` state entries"
    )


@pytest.mark.parametrize(("k", "size"), list(enumerate([2.5, -3, "4", True])))
def test_a_size_function_giving_no_count_is_refused_naming_it(k, size):
    """state_size=lambda p: 2.5 was cut to 2, -3 failed in np.zeros."""

    class Sized(NamedTuple):  # (a new class each time: a params class belongs to one part)
        a: float

    params = Sized
    pkmctl.register_sensor(
        f"x-size-{k}", params=params, build=lambda c: params(1.0), state_size=lambda p: size
    )(lambda p, state, work, x, y: None)
    part = pkmctl.parts.get_part("sensor", f"x-size-{k}")
    with pytest.raises(PartError, match=rf"state_size gave {re.escape(repr(size))}: must be an "
                                        "integer >= 0"):  # fmt: skip
        part.make(None)


class _Raising(NamedTuple):
    a: float

    @classmethod
    def from_context(cls, ctx):
        return cls(1.0)


def test_an_exception_a_users_part_raises_as_the_loop_runs_names_the_part(monkeypatch):
    """raise ValueError("boom") in a user's step read "error: boom", a RuntimeError "an
    internal error"; now one line naming the part, the exception and when. (The loop is
    replaced by one that raises as a compiled one does: Numba re-raises the part's own
    exception class and message.)"""
    from pkmctl.sim import loop as loop_module

    @pkmctl.register_controller("x-raising", params=_Raising)
    def raising(p, state, work, y, ref, F):
        raise ValueError("boom")

    def run(*args):
        raise ValueError("boom")

    monkeypatch.setattr(loop_module, "loop_for", lambda parts: run)
    monkeypatch.setattr(loop_module, "ready", lambda *a: None)
    with pytest.raises(PartError) as info:
        pkmctl.simulate("paper", controller="x-raising", duration=0.001)
    assert str(info.value) == (
        "the part controller 'x-raising' raises ValueError: boom (in the period starting at "
        "t = 0 s or later)"
    )
    # pkmctl's own parts alone: the exception as it is (an internal error, with its type)
    with pytest.raises(ValueError, match="^boom$") as info:
        pkmctl.simulate("paper", controller="pd", duration=0.001)
    assert info.value.__cause__ is not info.value

    # what the progress callback raises is the caller's, not the part's
    class Cancel(Exception):
        pass

    def stop(done, total):
        raise Cancel("stop")

    monkeypatch.setattr(loop_module, "loop_for", lambda parts: lambda *args: (0, 0))
    with pytest.raises(Cancel):
        pkmctl.simulate("paper", controller="x-raising", duration=0.001, progress=stop)


def test_build_limits_and_options_of_a_users_part_fail_in_one_line_naming_them():
    class NeedsKp(NamedTuple):
        kp: float

        @classmethod
        def from_context(cls, ctx):
            return cls({}["kp"])

    pkmctl.register_controller("x-keyerror", params=NeedsKp)(lambda p, state, work, y, ref, F: None)
    with pytest.raises(PartError, match=r"^controller 'x-keyerror': build failed: KeyError: 'kp'$"):
        pkmctl.simulate("paper", controller="x-keyerror", duration=0.001)

    class Fast(NamedTuple):
        a: float

    pkmctl.register_actuator(
        "x-fast-limits", params=Fast, build=lambda c: Fast(1.0), limits=lambda p: "fast",
        force=lambda p, state, cmd, tau: None,
    )(lambda p, state, work, y, F, cmd: None)  # fmt: skip
    sc = pkmctl.Scenario.builtin("paper").replace(**{"actuators.kind": "x-fast-limits"})
    said = r"^actuator 'x-fast-limits': limits gave 'fast': must be two numbers > 0 \(force N"
    with pytest.raises(PartError, match=said + r", speed m/s; inf: none\)$"):
        pkmctl.simulate(sc, "pd", duration=0.001)
    said = r"^controller 'x-foo': unknown option 'foo'; the options are .*state_size"
    with pytest.raises(PartError, match=said + r".* and its functions step, log$"):
        pkmctl.register_controller("x-foo", params=_P, foo=1)


def test_a_plugin_that_fails_to_load_says_where_and_a_taken_name_by_whom(tmp_path):
    from pkmctl.plugins import PluginError, load_plugins

    bad = tmp_path / "zd_plugin.py"
    bad.write_text("import pkmctl\nx = 1\ny = x / 0\n")
    with pytest.raises(PluginError) as info:
        load_plugins([str(bad)])
    assert str(info.value) == (
        f"--plugin {bad}: ZeroDivisionError: division by zero (zd_plugin.py, line 3: y = x / 0)"
    )
    bad = tmp_path / "json_plugin.py"  # raised in the standard library: the plugin's line
    bad.write_text('import json\nCONFIG = json.loads("{not json")\n')
    with pytest.raises(PluginError, match=r"\(json_plugin.py, line 2: CONFIG = json.loads"):
        load_plugins([str(bad)])
    pkmctl.register_controller("x-taken", params=_P, build=lambda c: _P(1.0))(
        lambda p, state, work, y, ref, F: None
    )
    with pytest.raises(PartError, match=r"a controller of that name is already registered "
                                        rf"\(by {re.escape(__file__)}\)$"):  # fmt: skip
        pkmctl.register_controller("x-taken", params=NamedTuple("Q", [("a", float)]))(
            lambda p, state, work, y, ref, F: None
        )


class _Integral(NamedTuple):
    ki: float
    period: float

    @classmethod
    def from_context(cls, ctx):
        return cls(50.0, ctx.period)


def _integral_log(p, state, row):
    for i in range(3):
        row[i] = state[i]


@pkmctl.register_controller("test-integral", params=_Integral, state_size=3,
                            log=_integral_log, log_size=3, log_name="integral")  # fmt: skip
def _integral_step(p, state, work, y, ref, F):
    for i in range(3):
        state[i] += p.period * (ref[i] - y[i])
        F[i] = 2000.0 * (ref[i] - y[i]) + p.ki * state[i]


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_a_parts_own_log_and_the_final_states_are_saved_and_loaded(tmp_path, fmt):
    """save_result dropped a part's own log (result.logs) and the parts' final states;
    load_result gave {} for both, without a word (a tester). Both come back bit for bit,
    the log under columns log_<name>_k."""
    from pkmctl.io.results import load_result, save_result

    r = pkmctl.simulate("paper", controller="test-integral", duration=0.01)
    assert set(r.logs) == {"integral"} and r.logs["integral"].shape == (r.t.size, 3)
    # the log is the integral of the logged error, by the step's own rule (row k: the
    # state before step k)
    err = r.X_desired - r.X_measured
    np.testing.assert_allclose(r.logs["integral"][1:], np.cumsum(err, axis=0)[:-1] * 5e-5,
                               rtol=0, atol=1e-15)  # fmt: skip
    table, meta = save_result(r, tmp_path, fmt=fmt)
    back = load_result(meta)
    np.testing.assert_array_equal(back.logs["integral"], r.logs["integral"])
    assert set(back.final_state) == set(r.final_state)
    for kind, state in r.final_state.items():
        np.testing.assert_array_equal(back.final_state[kind], state, err_msg=kind)
    import json

    assert json.loads(meta.read_text())["columns"][-3:] == [f"log_integral_{k}" for k in range(3)]


class _Bias(NamedTuple):
    b: float

    @classmethod
    def from_context(cls, ctx):
        return cls(1e-4)


def _bias_log(p, state, row):
    for i in range(row.shape[0]):
        row[i] = p.b


def _bias_measure(p, state, work, x, y):
    for i in range(6):
        y[i] = x[i]
    y[0] += p.b


class _Bias3(NamedTuple):  # (a params class belongs to one part)
    b: float

    @classmethod
    def from_context(cls, ctx):
        return cls(1e-4)


def test_logs_a_result_cannot_keep_apart_are_refused():
    """A sensor and a controller logging under one name: the sensor's rows replaced the
    controller's without a word; a log named q_measured of 3 columns ran, then save_result
    failed with a bare "zip() argument 2 is shorter" (a tester)."""
    pkmctl.register_sensor("test-bias-integral", params=_Bias, log=_bias_log, log_size=3,
                           log_name="integral")(_bias_measure)  # fmt: skip
    pkmctl.register_sensor("test-bias-q3", params=_Bias3, log=_bias_log, log_size=3,
                           log_name="q_measured")(_bias_measure)  # fmt: skip
    sc = pkmctl.Scenario.builtin("paper", 0.01)
    with pytest.raises(PartError) as info:
        pkmctl.simulate(sc.replace(**{"sensor.kind": "test-bias-integral"}), "test-integral")
    assert str(info.value) == (
        "sensor 'test-bias-integral' and controller 'test-integral' both log as 'integral': "
        "give one of them another log_name"
    )
    with pytest.raises(PartError) as info:
        pkmctl.simulate(sc.replace(**{"sensor.kind": "test-bias-q3"}), "pd")
    assert str(info.value) == (
        "sensor 'test-bias-q3': log_name 'q_measured' is the result's field of 4 columns, its "
        "log_size gives 3: another name, or 4 columns"
    )
    # alone, the same sensor's log is kept under its name
    r = pkmctl.simulate(sc.replace(**{"sensor.kind": "test-bias-integral"}), "pd")
    assert np.all(r.logs["integral"] == 1e-4)


def test_an_installed_package_of_ones_own_is_in_the_loops_key():
    """Every installed package's files were left out of a part's sources: a helper of the
    user's own package, installed (docs/parts.md: what Dask workers import), was edited and
    the old compiled loop ran (a tester: z RMSE 0.462 where the edit gives 0.626). Now
    only Python's, pkmctl's and the packages pkmctl stands on are left out."""
    import os
    import sysconfig

    from pkmctl.parts import _is_library, _library_folders, user_sources

    fuzzylite = pytest.importorskip("fuzzylite")  # installed apart, no requirement of ours
    where = _library_folders()
    site_packages = os.path.join(os.path.realpath(sysconfig.get_paths()["purelib"]), "")
    assert site_packages not in where.packages
    assert os.path.join(os.path.dirname(os.path.realpath(np.__file__)), "") in where.packages
    assert _is_library(np.__file__) and _is_library(os.__file__)
    assert not _is_library(fuzzylite.__file__)
    from fuzzylite import engine

    # the modules of its own package it uses count (is_ready names fuzzylite's classes)
    reached = user_sources(engine.Engine.is_ready)
    assert len(reached) > 1 and all("fuzzylite" in f for f in reached), reached
    assert not any("numpy" in f for f in user_sources(engine.Engine.is_ready))


def test_pythons_own_folder_holding_site_packages_leaves_them_the_users():
    """Outside a venv (pyenv, a Python built from source) site-packages is inside Python's
    own lib/python3.11, and a prefix test counted every installed package as Python's: the
    user's own installed package was left out of the loop's key again (CI, on pyenv)."""
    from pkmctl.parts import _is_library, _Library

    lib = "/opt/py/lib/python3.11/"
    where = _Library(
        python=(lib,),
        sites=(lib + "site-packages/",),
        packages=("/src/pkmctl/", lib + "site-packages/numpy/"),
    )
    assert _is_library(lib + "os.py", where)
    assert _is_library(lib + "json/decoder.py", where)
    assert _is_library(lib + "site-packages/numpy/linalg/__init__.py", where)
    assert _is_library("/src/pkmctl/parts.py", where)
    assert not _is_library(lib + "site-packages/mypkg/helper.py", where)
    assert not _is_library(lib + "site-packages/mypkg.py", where)
    assert not _is_library("/home/me/plugin.py", where)


class _Copy(NamedTuple):
    kp: np.ndarray

    @classmethod
    def from_context(cls, ctx):
        return cls(ctx.gains.pd_kp)


def test_array_arithmetic_in_a_step_is_named_an_allocation():
    """`e = ref[0:3] - y[0:3]` in a step read "does not compile: NRT required but not
    enabled", no hint (np.empty had one; a tester)."""

    @pkmctl.register_controller("test-slice-copy", params=_Copy)
    def _slice_copy(p, state, work, y, ref, F):
        e = ref[0:3] - y[0:3]
        for i in range(3):
            F[i] = p.kp[i] * e[i]

    with pytest.raises(PartError) as info:
        pkmctl.simulate("paper", controller="test-slice-copy", duration=0.01)
    msg = str(info.value)
    assert msg.startswith("the part controller 'test-slice-copy' does not compile: "), msg
    assert "(a step must not allocate: no array arithmetic or copies, loop over the elements" in msg


def test_a_notebook_cell_that_registers_a_part_can_run_again():
    """A function with no file (an ipykernel cell) had no stamp, so running the cell again
    was refused as a name clash, and only a kernel restart helped (a tester). The code
    itself is now its stamp: the same cell again registers again, an edited one is
    refused."""
    import pkmctl

    cell = (
        "from typing import NamedTuple\n"
        "import pkmctl\n"
        "class NbLaw(NamedTuple):\n"
        "    k: float\n"
        "@pkmctl.register_controller('x-nb-law', params=NbLaw, build=lambda ctx: NbLaw(1.0))\n"
        "def law(p, state, work, y, ref, F):\n"
        "    for i in range(3):\n"
        "        F[i] = {gain} * p.k * (ref[i] - y[i])\n"
    )
    name = "/tmp/ipykernel_1/cell.py"  # as ipykernel names a cell: no such file
    exec(compile(cell.format(gain="2.0"), name, "exec"), {})
    exec(compile(cell.format(gain="2.0"), name, "exec"), {})  # the same cell, run again
    with pytest.raises(pkmctl.PartError, match="already registered"):
        exec(compile(cell.format(gain="3.0"), name, "exec"), {})  # edited
