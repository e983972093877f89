"""The loop for a plant stepped outside compiled code (DESIGN.md §10): MuJoCo's.

Compiled code cannot call MuJoCo, so this loop is cut at the plant. Every period k a
compiled function, specialised to the sensor, controller and actuator types exactly as
:func:`pkmctl.sim.loop.loop_for` does, runs sensor → controller → actuator command, the
actuator's limb forces for each sub-step (its continuous state, e.g. a drive's lag,
integrated by RK4 over the sub-step: it does not depend on the plant), the metrics'
accumulators and, every ``logging.every`` periods, the log of the period (the sensor's
and the controller's rows included); then Python steps the plant's stepper ``substeps``
times with those forces and the held disturbance, and reads the state back. The limb
forces are held over each sub-step (the closed-form loop evaluates them at each RK4
stage: the same for an ideal actuator, whose forces are constant over the period). The
logged and measured-against limb lengths q are the stepper's own (MuJoCo's slides).

The status codes are those of :data:`pkmctl.sim.loop.STATUS`; a stepper adds 4 (its
state blew up: for MuJoCo a fatal warning or a closure residual over 1 um).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from pkmctl._jit import ready, specialise
from pkmctl.parts import (
    Part,
    PartContext,
    actuator_command_after,
    actuator_derivative,
    actuator_force,
    controller_log,
    controller_step,
    plant_observe,
    sensor_log,
    sensor_measure,
)
from pkmctl.sim.loop import (
    Inputs,
    LogBuffers,
    LoopOutput,
    _key,
    _mark_compiled,
    accumulate_metrics,
    blame,
    pose_status,
    setup,
)

__all__ = ["run_stepped"]

#: A stepped run (stepped from Python, e.g. MuJoCo) reports its progress this often.
PROGRESS_PERIODS = 1000


def _period(
    plant, x, pw, sensor, ss, sw, ctrl, cs, cw, act, ast, aw, n_z, h, k, row,
    ref, qdes, dist, qs, taus, rk, ast_s, vec, logs, log_c, log_s, acc, mp, mw,
):  # fmt: skip
    """Period k up to the plant: returns the status of x (0: valid, 3: the sensor could
    not measure) and fills ``taus``.

    ``row``: the log's row of this period, -1 if it is not logged; ``ref`` (9,) and
    ``qdes`` (4,) its reference and desired limb lengths; ``qs`` (4,) the stepper's limb
    lengths at t_k (logged, and measured against); ``taus`` (substeps, 4): the limb
    forces at the start of each sub-step; ``rk`` (5, n_z) the actuator's RK4 stages;
    ``vec`` (6, 6) the period's y, F, cmd, tau, q, J^T tau; ``logs``, ``log_c``,
    ``log_s``, ``acc``, ``mp``, ``mw`` as in :func:`pkmctl.sim.loop._run_loop`.
    """
    status = pose_status(x)
    if status != 0:
        return status
    y, F, cmd, q, Fa = vec[0], vec[1, 0:3], vec[2, 0:4], vec[4, 0:4], vec[5, 0:3]
    log_X, log_Xd, log_y, log_F, log_tau, log_q, log_dist = logs
    sensor_measure(sensor, ss, sw, x, y)
    for i in range(6):
        if not math.isfinite(y[i]):
            return 3
    logged = row >= 0
    if logged and log_s.shape[0] > 0:
        sensor_log(sensor, ss, log_s[row])
    if logged and log_c.shape[0] > 0:
        controller_log(ctrl, cs, log_c[row])
    controller_step(ctrl, cs, cw, y, ref, F)
    actuator_command_after(act, ast, aw, y, F, ctrl, cw, cmd)
    if logged:
        for i in range(3):
            log_X[row, i] = x[i]
            log_Xd[row, i] = x[3 + i]
            log_dist[row, i] = dist[i]
        for i in range(6):
            log_y[row, i] = y[i]
    R, Jm, qm, ev = mw
    for sub in range(taus.shape[0]):
        tau = taus[sub]
        actuator_force(act, ast, cmd, tau)
        if sub == 0:
            plant_observe(plant, x, tau, pw, q, Fa)
            if logged:
                for i in range(4):
                    log_tau[row, i] = tau[i]
                    log_q[row, i] = qs[i]
                for i in range(3):
                    log_F[row, i] = Fa[i]
            accumulate_metrics(acc, mp, k, ref, x, qdes, qs, tau, R, Jm, qm, ev)
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
    key, sources, values = _key(parts)
    return specialise(_period, key, sources, refcount=False, values=values)


def run_stepped(
    parts: dict[str, Part],
    bundles: dict[str, tuple],
    ctx: PartContext,
    *,
    period: float,
    substeps: int,
    inputs: Inputs,
    buffers: LogBuffers | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LoopOutput:
    """Run the parts over ``inputs.periods`` periods with the plant's stepper.

    Arguments as :func:`pkmctl.sim.loop.run_parts`, plus ``ctx`` for the stepper
    (``progress`` is called every :data:`PROGRESS_PERIODS` periods). The log's q is the
    stepper's own (MuJoCo's slide positions), not ``observe``'s.
    """
    run = setup(parts, bundles, inputs, buffers)
    (plant_p, x, pw), (sensor_p, ss, sw) = run.bundle("plant"), run.bundle("sensor")
    (ctrl_p, cs, cw), (act_p, ast, aw) = run.bundle("controller"), run.bundle("actuator")
    logs, n_z, every = run.logs, run.n_z, run.every
    h = period / substeps
    machine = parts["plant"].stepper(plant_p, ctx, h)
    taus = np.zeros((substeps, 4))
    rk = np.zeros((4, max(n_z, 1)))
    vec = np.zeros((6, 6))
    ast_s = np.zeros(max(ast.shape[0], 1))[: ast.shape[0]]
    q = np.empty(4)
    step = period_for(parts)
    args = (plant_p, x, pw, sensor_p, ss, sw, ctrl_p, cs, cw, act_p, ast, aw, n_z, float(h))
    tail = (q, taus, rk, ast_s, vec, logs.arrays, logs.controller, logs.sensor, run.metrics,
            inputs.metrics, run.metric_work)  # fmt: skip
    dist_values = inputs.dist_values
    machine.reset(x[:6])
    status, m = machine.read(x, q), 0
    t0 = time.perf_counter()
    k, in_parts = 0, False  # in_parts: in the parts' compiled code (not the stepper's)
    try:
        for k0, ref, qdes, dist_index in inputs.chunks() if status == 0 else ():
            for j in range(ref.shape[0]):
                k = k0 + j
                dist = dist_values[dist_index[j]]
                row = k // every if k % every == 0 else -1
                in_parts = True
                if k == 0:  # compiling or loading the period is not the run's time
                    ready(step, *args, k, row, ref[j], qdes[j], dist, *tail)
                    t0 = time.perf_counter()
                status = step(*args, k, row, ref[j], qdes[j], dist, *tail)
                in_parts = False
                if status:
                    m = k
                    break
                for sub in range(substeps):
                    machine.step(taus[sub], dist)
                status = machine.read(x, q)
                m = k + 1
                if status:
                    break
                if progress is not None and m % PROGRESS_PERIODS == 0:
                    progress(m, inputs.periods)
            if status:
                break
    except Exception:
        if not in_parts:  # the stepper's (MuJoCo's) or progress's own: as it is
            raise
        with blame(parts, k, period):
            raise
    dt = time.perf_counter() - t0
    if progress is not None and status == 0:
        progress(inputs.periods, inputs.periods)
    _mark_compiled(step)
    return run.output(status, m, dt)
