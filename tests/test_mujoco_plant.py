"""The loop on the MuJoCo plant (DESIGN.md §10, issue 13 point 3)."""

import os
from typing import NamedTuple

import numpy as np
import pytest

import pkmctl

pytest.importorskip("mujoco", reason="MuJoCo is not installed (pkmctl[mujoco])")

FULL = os.environ.get("PKMCTL_FULL") == "1"
CONTROLLERS = ("smc", "fsmc", "afsmc", "pd", "ctc")


def _on_mujoco(scenario):
    return scenario.replace(**{"plant.kind": "mujoco"})


@pytest.mark.slow
@pytest.mark.parametrize("controller", CONTROLLERS)
def test_paper_scenario_gives_the_closed_form_rmse(controller):
    """Every RMSE within 1 % of the closed-form plant's (CI: the first 0.1 s; PKMCTL_FULL=1:
    the paper's 10 s)."""
    sc = pkmctl.Scenario.builtin("paper")
    duration = None if FULL else 0.1
    rigid = pkmctl.simulate(sc, controller, duration=duration)
    mj = pkmctl.simulate(_on_mujoco(sc), controller, duration=duration)
    assert mj.parts["plant"] == "mujoco" and mj.success
    a, b = rigid.rmse(), mj.rmse()
    for k in a:
        assert abs(b[k] - a[k]) <= 0.01 * abs(a[k]), (k, a[k], b[k])
    # and the runs themselves: the closures' sag (~1e-9 m) is all that differs
    assert np.max(np.abs(mj.X - rigid.X)) <= 1e-7
    np.testing.assert_allclose(mj.tau, rigid.tau, rtol=0, atol=1e-3 * np.abs(rigid.tau).max())


@pytest.mark.parametrize("controller", ["pd", "afsmc"])
def test_the_scenarios_machine_options_and_payload_reach_the_mujoco_plant(controller):
    """Rotor inertia, viscous friction and a 5 kg payload off the centre (DESIGN.md §7) on
    both plants, under a 50 N disturbance: the runs agree as the plain machine's do. The
    disturbance's wrench is moved to the payload-shifted centre of mass MuJoCo applies it
    at; without that the poses differ by 2.5e-5."""
    sc = pkmctl.Scenario.builtin("paper").replace(
        **{"plant.rotor_inertia": 2.77e-5, "plant.friction_viscous": 300.0, "payload.mass": 5.0,
           "payload.offset": [0.06, -0.04, 0.03], "disturbance.amplitude": [50.0] * 3}
    )  # fmt: skip
    rigid = pkmctl.simulate(sc, controller, duration=0.1)
    mj = pkmctl.simulate(_on_mujoco(sc), controller, duration=0.1)
    assert np.max(np.abs(mj.X - rigid.X)) <= 1e-7
    np.testing.assert_allclose(mj.tau, rigid.tau, rtol=0, atol=1e-4 * np.abs(rigid.tau).max())


def test_coulomb_friction_on_the_mujoco_plant_is_refused_naming_the_field():
    """When the scenario is read, not when a run builds the plant."""
    with pytest.raises(
        pkmctl.ScenarioError,
        match=r"^plant\.friction_coulomb = 30\.0: plant\.kind = 'mujoco' cannot model it "
        r"\(MuJoCo's dry friction, frictionloss, is a soft constraint",
    ):
        _on_mujoco(pkmctl.Scenario.builtin("prototype"))  # F_c = 30 N
    sc = _on_mujoco(pkmctl.Scenario.builtin("paper"))
    with pytest.raises(pkmctl.ScenarioError, match=r"^plant\.friction_coulomb = 5\.0: "):
        sc.replace(**{"plant.friction_coulomb": 5.0})
    sc.replace(**{"plant.friction_coulomb": 0.0, "plant.friction_viscous": 300.0})  # allowed


class _Kick(NamedTuple):
    force: float


@pkmctl.register_controller("x-mujoco-kick", params=_Kick, build=lambda ctx: _Kick(1e7))
def _kick(p, state, work, y, ref, F):
    F[0] = p.force  # 10 MN along z: the platform leaves the workspace within a few periods
    F[1] = 0.0
    F[2] = 0.0


def test_divergence_is_reported_not_logged_as_nan():
    with pytest.raises(pkmctl.SimulationDiverged, match="x-mujoco-kick") as info:
        pkmctl.simulate(_on_mujoco(pkmctl.Scenario.builtin("paper")), "x-mujoco-kick",
                        duration=0.05)  # fmt: skip
    partial = info.value.partial
    assert 0 < partial.t.size < 1000
    assert np.all(np.isfinite(partial.X)) and np.all(np.isfinite(partial.q))


def test_a_blown_up_mujoco_state_is_status_4(robot, tmp_path, monkeypatch):
    from pkmctl.plants.mujoco import MujocoMachine

    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warning to MUJOCO_LOG.TXT here

    machine = MujocoMachine(robot)
    x, q = np.empty(6), np.empty(4)
    machine.reset(np.r_[robot.home, 0.0, 0.0, 0.0])
    assert machine.read(x, q) == 0
    np.testing.assert_allclose(x, np.r_[robot.home, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(q, robot.inverse_kinematics(robot.home), atol=1e-12)
    machine.data.qvel[0] = np.nan  # MuJoCo warns and resets its state to qpos0
    machine.step(np.zeros(4), np.zeros(3))
    assert machine.read(x, q) == 4


def test_simulate_many_with_lanes_runs_a_stepped_plant_one_at_a_time():
    sc = _on_mujoco(pkmctl.Scenario.builtin("paper"))
    many = pkmctl.simulate_many(sc, "pd", seeds=[1, 2], duration=0.01, lanes=2)
    one = [pkmctl.simulate(sc, "pd", duration=0.01, seed=s) for s in (1, 2)]
    for a, b in zip(many, one, strict=True):
        assert a.parts["plant"] == "mujoco"
        np.testing.assert_array_equal(a.X, b.X)


def test_a_run_on_the_mujoco_plant_reports_its_progress(monkeypatch):
    from pkmctl.sim import stepped

    monkeypatch.setattr(stepped, "PROGRESS_PERIODS", 30)
    seen: list[tuple[int, int]] = []
    sc = _on_mujoco(pkmctl.Scenario.builtin("paper"))
    pkmctl.simulate(sc, "pd", duration=0.005, progress=lambda *a: seen.append(a))  # 100
    assert seen == [(30, 100), (60, 100), (90, 100), (100, 100)]


def test_a_run_on_the_mujoco_plant_leaves_its_compiled_marker():
    """reproduce's precompile skips what has run: for a stepped plant the compiled code is
    the stepped loop's period (it used to spawn two compiling processes on every run,
    3.5 s of a warm reproduce on MuJoCo)."""
    from pkmctl.sim.loop import is_compiled
    from pkmctl.sim.simulate import precompile, resolve_parts

    sc = _on_mujoco(pkmctl.Scenario.builtin("paper"))
    pkmctl.simulate(sc, "smc", duration=0.001)
    assert is_compiled(resolve_parts(sc, "smc"))
    assert precompile(sc, ["smc"]) == []
    # the closed-form plant's loop is another function, with its own marker
    assert resolve_parts(sc, "smc")["plant"].stepper is not None


def test_a_sub_step_over_half_the_closures_time_constant_is_refused():
    """MuJoCo raises a solref time constant under two steps to two steps, silently: at a
    1 ms sub-step the unforced machine gained 2.6e-4 J in 0.3 s (a tester's oracle)."""
    from pkmctl.plants import mujoco as mj

    sc = pkmctl.Scenario.builtin("paper").replace(**{"timing.control_period": 1e-3})
    with pytest.raises(
        pkmctl.ScenarioError,
        match=r"^timing\.substeps = 1: with plant\.kind = 'mujoco' the RK4 sub-step "
        r"\(timing\.control_period / substeps = 0\.001 s\) must be <= 0\.00025 s, .*"
        r"set timing\.substeps >= 4$",
    ):
        _on_mujoco(sc)
    _on_mujoco(sc.replace(**{"timing.substeps": 4}))  # 0.25 ms: allowed
    robot = pkmctl.Mechanism.paper()
    with pytest.raises(ValueError, match=r"^timestep = 0\.001: must be <= 0\.00025 s, half"):
        mj.build_mjcf(robot, timestep=1e-3)
    mj.build_mjcf(robot, timestep=2.5e-4)
    # why: stepped at 1 ms, closures of time constant 0.5 ms move exactly as at 2 ms
    import mujoco

    qpos = []
    for tc in (5e-4, 2e-3):
        model = mj.build_model(robot, timestep=2.5e-4, solref=(tc, 1.0))
        model.opt.timestep = 1e-3
        data = mujoco.MjData(model)
        for _ in range(50):  # the machine falling from home: the closures take the load
            mujoco.mj_step(model, data)
        qpos.append(data.qpos.copy())
    assert np.array_equal(qpos[0], qpos[1])
    assert np.abs(qpos[0]).max() > 1e-3  # it moved
