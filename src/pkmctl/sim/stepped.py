"""The loop for a plant stepped outside compiled code (DESIGN.md §10): MuJoCo's.

Compiled code cannot call MuJoCo, so this loop is cut at the plant. Every period k a
compiled function, specialised to the sensor, controller and actuator types exactly as
:func:`pkmctl.sim.loop.loop_for` does, runs sensor → controller → actuator command, the
actuator's limb forces for each sub-step (its continuous state, e.g. a drive's lag,
integrated by RK4 over the sub-step: it does not depend on the plant) and the log of the
period; then Python steps the plant's stepper ``substeps`` times with those forces and
the held disturbance, and reads the state back. The limb forces are held over each
sub-step (the closed-form loop evaluates them at each RK4 stage: the same for an ideal
actuator, whose forces are constant over the period).

The status codes are those of :data:`pkmctl.sim.loop.STATUS`; a stepper adds 4 (its
state blew up: for MuJoCo a fatal warning or a closure residual over 1 um).
"""

from __future__ import annotations

import time

import numpy as np
from numba.core.errors import NumbaError

from pkmctl._jit import specialise
from pkmctl.parts import (
    Part,
    PartContext,
    actuator_command,
    actuator_derivative,
    actuator_force,
    controller_log,
    controller_step,
    plant_observe,
    sensor_measure,
)
from pkmctl.sim.loop import LOG_NAMES, LogBuffers, LoopOutput, compile_error, pose_status, setup

__all__ = ["run_stepped"]


def _period(
    plant, x, pw, sensor, ss, sw, ctrl, cs, cw, act, ast, aw, n_z, h, k,
    ref, dist, taus, rk, ast_s, vec, logs, log_c,
):  # fmt: skip
    """Period k up to the plant: returns the status of x (0: valid) and fills ``taus``.

    ``taus`` (substeps, 4): the limb forces at the start of each sub-step; ``rk`` (5, n_z)
    the actuator's RK4 stages; ``vec`` (6, 6) the period's y, F, cmd, tau, q, J^T tau;
    ``logs`` and ``log_c`` as in :func:`pkmctl.sim.loop._run_loop`.
    """
    status = pose_status(x)
    if status != 0:
        return status
    y, F, cmd, q, Fa = vec[0], vec[1, 0:3], vec[2, 0:4], vec[4, 0:4], vec[5, 0:3]
    log_X, log_Xd, log_y, log_F, log_tau, log_q, log_dist = logs
    sensor_measure(sensor, ss, sw, x, y)
    if log_c.shape[0] == log_X.shape[0]:
        controller_log(ctrl, cs, log_c[k])
    controller_step(ctrl, cs, cw, y, ref, F)
    actuator_command(act, ast, aw, y, F, cmd)
    for i in range(3):
        log_X[k, i] = x[i]
        log_Xd[k, i] = x[3 + i]
        log_dist[k, i] = dist[i]
    for i in range(6):
        log_y[k, i] = y[i]
    for sub in range(taus.shape[0]):
        tau = taus[sub]
        actuator_force(act, ast, cmd, tau)
        if sub == 0:
            plant_observe(plant, x, tau, pw, q, Fa)
            for i in range(4):
                log_tau[k, i] = tau[i]
                log_q[k, i] = q[i]
            for i in range(3):
                log_F[k, i] = Fa[i]
        if n_z > 0:  # RK4 of the actuator's continuous state over the sub-step
            for st in range(4):
                if st == 0:
                    for i in range(ast.shape[0]):
                        ast_s[i] = ast[i]
                else:
                    a = h if st == 3 else 0.5 * h
                    for i in range(n_z):
                        ast_s[i] = ast[i] + a * rk[st - 1, i]
                actuator_derivative(act, ast_s, cmd, rk[st, 0:n_z])
            for i in range(n_z):
                ast[i] += h / 6.0 * (rk[0, i] + 2.0 * rk[1, i] + 2.0 * rk[2, i] + rk[3, i])
    return 0


def period_for(parts: dict[str, Part]):
    """The compiled period of this combination of parts (one per process, cached on disk)."""
    key = tuple(parts[k].params for k in ("plant", "sensor", "controller", "actuator"))
    sources = [s for p in parts.values() if not p.builtin for s in p.sources]
    return specialise(_period, key, sources, refcount=False)


def run_stepped(
    parts: dict[str, Part],
    bundles: dict[str, tuple],
    ctx: PartContext,
    *,
    period: float,
    substeps: int,
    reference: np.ndarray,
    dist_values: np.ndarray,
    dist_index: np.ndarray,
    buffers: LogBuffers | None = None,
) -> LoopOutput:
    """Run the parts over ``len(reference)`` periods with the plant's stepper.

    Arguments as :func:`pkmctl.sim.loop.run_parts`, plus ``ctx`` for the stepper. The log's
    q is the stepper's own (MuJoCo's slide positions), not ``observe``'s.
    """
    n = reference.shape[0]
    run = setup(parts, bundles, n, buffers)
    (plant_p, x, pw), (sensor_p, ss, sw) = run.bundle("plant"), run.bundle("sensor")
    (ctrl_p, cs, cw), (act_p, ast, aw) = run.bundle("controller"), run.bundle("actuator")
    logs, n_z = run.logs, run.n_z
    h = period / substeps
    machine = parts["plant"].stepper(plant_p, ctx, h)
    taus = np.zeros((substeps, 4))
    rk = np.zeros((4, max(n_z, 1)))
    vec = np.zeros((6, 6))
    ast_s = np.zeros(max(ast.shape[0], 1))[: ast.shape[0]]
    q = np.empty(4)
    log_q = logs.arrays[LOG_NAMES.index("q")]
    step = period_for(parts)
    args = (plant_p, x, pw, sensor_p, ss, sw, ctrl_p, cs, cw, act_p, ast, aw, n_z, float(h))
    tail = (taus, rk, ast_s, vec, logs.arrays, logs.controller)
    machine.reset(x[:6])
    status, m = machine.read(x, q), n
    t0 = time.perf_counter()
    try:
        for k in range(n if status == 0 else 0):
            dist = dist_values[dist_index[k]]
            status = step(*args, k, reference[k], dist, *tail)
            if status:
                m = k
                break
            log_q[k] = q
            for sub in range(substeps):
                machine.step(taus[sub], dist)
            status = machine.read(x, q)
            if status:
                m = k + 1
                break
        else:
            m = n if status == 0 else 0
    except NumbaError as exc:
        raise compile_error(parts, exc) from exc
    dt = time.perf_counter() - t0
    # this driver does not log a sensor's row (q_measured is the stepper's q)
    return run.output(status, m, dt, sensor_log=False)
