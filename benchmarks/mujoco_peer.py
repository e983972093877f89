"""MuJoCo stepping the 2RPU-2SPR machine: timing (DESIGN.md §10).

    python -m benchmarks.mujoco_peer

The model, its state helpers and the agreement checks live in :mod:`pkmctl.plants.mujoco`
(the module docstring has the model decisions and measured agreement); this file only
times open-loop stepping of it (:func:`steps_per_second`) and prints both.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import mujoco
import numpy as np
from mujoco import rollout

import pkmctl
from benchmarks.timing import best_time
from pkmctl.plants.mujoco import (
    _equality_rows,
    _slides,
    agreement,
    build_model,
    initial_qpos,
    platform_pose,
)

__all__ = ["python_afsmc_steps_per_second", "steps_per_second"]


def _best_of(repeats: int, run: Callable[[], None]) -> float:
    return best_time(run, repeats)


def steps_per_second(
    duration: float = 1.0, repeats: int = 3, **model_kwargs
) -> dict[str, float | int]:
    """Time open-loop RK4 stepping of the paper's machine from its initial pose.

    The model starts at rest at the paper's initial pose X(0) = home (DESIGN.md §4) with
    constant actuator forces ``robot.actuator_forces(X, robot.gravity(X))`` and is stepped
    for ``duration`` simulated seconds; each rate uses the best wall time of ``repeats``
    runs.

    Findings (MuJoCo 4.0.0, one core of a shared 2-core machine; the rates varied by a
    third between runs with the other core's load): 30 000 to 40 000 steps/s (25 to 33 us
    per RK4 step, i.e. 4 forward evaluations of nv = 14 with 12 constraint rows), the same
    in ``mujoco.rollout``'s C loop (the binding's per-call overhead is negligible); a Python
    control before each step costs 3 to 5 us (25 000 to 34 000 steps/s); as
    ``mjcb_control`` it runs 4 times per step (17 000 to 24 000 steps/s).
    Real time at 5e-5 s needs 20 000 steps/s. At rest under the gravity-compensating
    forces the platform moves 7e-11 in 1 s and the closures sag 1e-9 m.

    Parameters
    ----------
    duration : float
        Simulated time per run (s).
    repeats : int
        Runs per measurement.
    **model_kwargs
        Passed to :func:`build_mjcf`.

    Returns
    -------
    dict
        ``steps_per_s``: a Python loop of ``mj_step`` with constant ``ctrl``.
        ``steps_per_s_python_control``: the same loop setting ``ctrl`` from a trivial
        Python control law before every step (the plant backend's pattern: one control
        evaluation per step, held over the step).
        ``steps_per_s_mjcb_control``: the control law installed as ``mjcb_control``, which
        MuJoCo calls at each of RK4's 4 stages.
        ``steps_per_s_rollout``: ``mujoco.rollout`` with constant controls (the loop in C).
        ``timestep``, ``nv``, ``neq``, ``nefc``; ``drift_X_max``: max |X(duration) - X(0)|
        of the constant-force run (m or rad), the sag of the soft closures plus the
        integration error; ``closure_residual_end`` (m).
    """
    robot = pkmctl.Mechanism.paper()
    model = build_model(robot, **model_kwargs)
    data = mujoco.MjData(model)
    X0 = robot.home
    tau0 = robot.actuator_forces(X0, robot.gravity(X0))
    qpos0 = initial_qpos(model, robot, X0)
    nsteps = max(1, round(duration / model.opt.timestep))
    slide_dof = model.jnt_dofadr[_slides(model)]

    def reset() -> None:
        mujoco.mj_resetData(model, data)
        data.qpos[:] = qpos0
        data.ctrl[:] = tau0
        mujoco.mj_forward(model, data)

    def control(d: mujoco.MjData) -> np.ndarray:
        return tau0 - 1e-3 * d.qvel[slide_dof]  # trivial: gravity feed-forward, faint damping

    def set_control(m: mujoco.MjModel, d: mujoco.MjData) -> None:
        d.ctrl[:] = control(d)

    def open_loop() -> None:
        reset()
        for _ in range(nsteps):
            mujoco.mj_step(model, data)

    def python_control() -> None:
        reset()
        for _ in range(nsteps):
            data.ctrl[:] = control(data)
            mujoco.mj_step(model, data)

    def callback_control() -> None:
        reset()
        mujoco.set_mjcb_control(set_control)
        try:
            for _ in range(nsteps):
                mujoco.mj_step(model, data)
        finally:
            mujoco.set_mjcb_control(None)

    t_open = _best_of(repeats, open_loop)
    drift = float(np.max(np.abs(platform_pose(model, data.qpos) - X0)))
    r_end, _ = _equality_rows(model, data)
    t_py = _best_of(repeats, python_control)
    t_cb = _best_of(repeats, callback_control)

    reset()
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    ctrl = np.tile(tau0, (nsteps, 1))
    work = mujoco.MjData(model)
    t_roll = _best_of(repeats, lambda: rollout.rollout(model, work, state, ctrl, nstep=nsteps))
    return {
        "steps_per_s": nsteps / t_open,
        "steps_per_s_python_control": nsteps / t_py,
        "steps_per_s_mjcb_control": nsteps / t_cb,
        "steps_per_s_rollout": nsteps / t_roll,
        "timestep": float(model.opt.timestep),
        "nv": int(model.nv),
        "neq": int(model.neq),
        "nefc": int(data.nefc),
        "drift_X_max": drift,
        "closure_residual_end": float(np.max(np.abs(r_end))),
    }


def python_afsmc_steps_per_second(duration: float = 1.0, repeats: int = 3) -> float:
    """Steps/s of MuJoCo with AFSMC called from Python every step, as a MuJoCo user would.

    The paper scenario's trajectory, gains and controller model; every 50 us step reads
    X and Xdot from MuJoCo, calls ``pkmctl.make_controller("afsmc", ...).step`` (the
    compiled law behind a Python call), splits F into limb forces
    (``robot.actuator_forces``) and calls ``mj_step``. No disturbance, no logging.
    """
    from pkmctl.plants.mujoco import MujocoMachine

    sc = pkmctl.Scenario.builtin("paper")
    robot, Tc = sc.plant(), sc.timing.control_period
    traj = sc.trajectory.build()
    n = max(1, round(duration / Tc))
    Xd, Xdd, Xddd = traj.evaluate(np.arange(n) * Tc)
    machine = MujocoMachine(robot, timestep=Tc)
    x, q, zero = np.empty(6), np.empty(4), np.zeros(3)

    def make():
        return pkmctl.make_controller(
            "afsmc", sc.controller_mechanism(), sc.controller_gains(), period=Tc
        )

    make().step(Xd[0], zero, Xd[0], Xdd[0], Xddd[0])  # compile (or load the cache) untimed
    robot.actuator_forces(Xd[0], zero)

    fresh = iter([make() for _ in range(repeats)])  # built untimed, one per run

    def run() -> None:
        ctrl = next(fresh)
        machine.reset(np.concatenate([sc.initial.X, sc.initial.Xdot]))
        for k in range(n):
            machine.read(x, q)
            F = ctrl.step(x[:3], x[3:], Xd[k], Xdd[k], Xddd[k])
            machine.step(robot.actuator_forces(x[:3], F), zero)

    return n / _best_of(repeats, run)


def _main() -> None:
    robot = pkmctl.Mechanism.paper()
    agr = agreement(robot)
    print(f"MuJoCo {mujoco.__version__}: agreement with the closed form, {agr['n']} states")
    print(f"  model: nv = {agr['nv']}, neq = {agr['neq']}, constraint rows = {agr['nefc']}")
    print(f"  limb lengths       max |dq|     = {agr['q_err_max_m']:.2e} m")
    print(f"  closure residual   max          = {agr['closure_residual_max']:.2e} m")
    print(f"  closure velocity   max          = {agr['closure_velocity_max']:.2e} m/s")
    unit = ("m/s^2", "rad/s^2", "rad/s^2")
    err = ", ".join(f"{e:.2e} {u}" for e, u in zip(agr["xddot_err_max"], unit, strict=True))
    scale = ", ".join(f"{s:.3g} {u}" for s, u in zip(agr["xddot_scale"], unit, strict=True))
    print(f"  accelerations      max |dXddot| = {err}")
    print(f"                     (max |Xddot| = {scale})")
    print(f"                     max relative = {agr['xddot_rel_err_max']:.2e}")
    print(
        f"  trajectories (20 ms) max |dX|   = {agr['traj_err_max']:.2e} "
        f"(motion up to {agr['traj_motion_max']:.3g})"
    )
    sps = steps_per_second()
    print(f"timing: RK4, timestep {sps['timestep']:g} s, 1 s simulated, best of 3")
    print(f"  mj_step loop (constant ctrl)    {sps['steps_per_s']:10.0f} steps/s")
    print(f"  mj_step + Python control        {sps['steps_per_s_python_control']:10.0f} steps/s")
    print(f"  mj_step + mjcb_control (4/step) {sps['steps_per_s_mjcb_control']:10.0f} steps/s")
    print(f"  mujoco.rollout (C loop)         {sps['steps_per_s_rollout']:10.0f} steps/s")
    print(f"  drift after 1 s at constant gravity-compensating forces: {sps['drift_X_max']:.2e}")
    print(f"  closure residual after 1 s: {sps['closure_residual_end']:.2e} m")


if __name__ == "__main__":
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()  # --help says what it measures; no option
    _main()
