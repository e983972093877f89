"""The closed loop: sampling, zero-order hold, RK4, disturbances -> :class:`Result` (DESIGN.md §4).

Every control period T_c the controller reads the plant state (X_k, Xdot_k) and the
desired trajectory, and returns F_k; the actuator forces tau_a = J (J^T J)^-1 F_k
(computed with the controller model's geometry at X_k) are held over the period, so
the plant sees J(X(t))^T tau_a + tau_d'. The plant (the true model) is integrated by
fixed-step RK4 with ``substeps`` steps per period. The disturbance tau_d' is redrawn
every ``disturbance.hold`` seconds from ``numpy.random.default_rng(seed)`` and held.

The whole loop is one compiled function, :func:`_run_kernel`; the controller step is
:func:`pkmctl.controllers.control_step`, the same code a user's hardware loop calls.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from ._jit import kernel
from .controllers import CONTROLLERS, MEM_SIZE, control_step, make_controller
from .dynamics import JQ, Q, actuator_forces_kernel, dynamics_kernel, make_work, solve_spd3
from .errors import SimulationDiverged
from .fuzzy import FLC, MamdaniSystem
from .mechanism import Mechanism
from .metrics import RMSE_KEYS
from .scenario import Scenario, ScenarioError

__all__ = ["RMSE_KEYS", "Result", "desired_forces", "simulate", "simulate_many"]


_STATUS = {1: "the state became non-finite", 2: "the pose left the valid set"}


@dataclass(frozen=True, eq=False)
class Result:
    """One closed-loop run, sampled at every control period (N samples).

    Carries its scenario and controller name. Arrays: ``t`` (N,); ``X``, ``Xdot``,
    ``X_desired``, ``F`` (N, 3) (F: task-space force applied by the actuators);
    ``q``, ``q_desired``, ``tau``, ``tau_desired`` (N, 4); ``disturbance`` (N, 3) the
    tau_d' acting over each period; ``theta_hat`` (N, 36) for AFSMC, else None.
    ``success`` is False only for a partial result kept in a
    :class:`~pkmctl.SimulationDiverged`; ``message`` says why. ``info`` holds
    ``kernel_seconds`` (wall time of the compiled loop) and ``steps``.
    """

    scenario: Scenario
    controller: str
    t: np.ndarray
    X: np.ndarray
    Xdot: np.ndarray
    X_desired: np.ndarray
    Xdot_desired: np.ndarray
    q: np.ndarray
    q_desired: np.ndarray
    F: np.ndarray
    tau: np.ndarray
    tau_desired: np.ndarray
    disturbance: np.ndarray
    theta_hat: np.ndarray | None = None
    success: bool = True
    message: str = "ok"
    info: dict = field(default_factory=dict)

    def rmse(self) -> dict[str, float]:
        """RMSE over all control samples (eq. 55-57): z in mm, angles in degrees, q in m."""
        from .metrics import rmse

        return rmse(self)

    def __repr__(self) -> str:
        return (
            f"Result(controller={self.controller!r}, scenario={self.scenario.name!r}, "
            f"N={self.t.size}, success={self.success})"
        )


@kernel(inline="always")
def _plant_accel(geom, theta, X, Xd, tau, dist, work, M, C, G, out):
    """Xddot = M^-1 (J^T tau + tau_d' - C Xdot - G) for the true plant (eq. 24)."""
    dynamics_kernel(geom, theta, X, Xd, Xd, work, M, C, G)  # C holds C Xdot
    Jq = work[JQ]
    for i in range(3):
        out[i] = (
            Jq[0, i] * tau[0]
            + Jq[1, i] * tau[1]
            + Jq[2, i] * tau[2]
            + Jq[3, i] * tau[3]
            + dist[i]
            - C[i]
            - G[i]
        )
    solve_spd3(M, out)


@kernel(inline="always")
def _valid(X, Xd):
    for i in range(3):
        if not (math.isfinite(X[i]) and math.isfinite(Xd[i])):
            return 1
    if X[0] <= 0.0 or abs(X[1]) >= 0.5 * math.pi or abs(X[2]) >= 0.5 * math.pi:
        return 2
    return 0


@kernel
def _run_kernel(
    kind,
    plant_geom,
    plant_theta,
    model_geom,
    model_theta,
    gains,
    eps,
    flc_tables,
    Tc,
    alpha_f,
    substeps,
    force_limit,
    X0,
    Xd0,
    Xdes,
    Xddes,
    Xdddes,
    dist_values,
    dist_index,
    gamma_vec,
    th_min,
    th_max,
    log_X,
    log_Xd,
    log_F,
    log_tau,
    log_q,
    log_dist,
    log_theta,
):
    """Run the loop for len(Xdes) control periods.

    Returns (status, k, X, Xdot): status 0 when all periods ran, else the code of
    :data:`_STATUS` with k the first period whose state (X, Xdot) is invalid.
    This shell allocates; :func:`_run_loop` runs without reference counting.
    """
    X = X0.copy()
    Xd = Xd0.copy()
    mem = np.zeros(MEM_SIZE)
    theta_hat = model_theta.copy()
    status, k = _run_loop(
        kind, plant_geom, plant_theta, model_geom, model_theta, gains, eps, flc_tables,
        Tc, alpha_f, substeps, force_limit, Xdes, Xddes, Xdddes, dist_values, dist_index,
        gamma_vec, th_min, th_max, log_X, log_Xd, log_F, log_tau, log_q, log_dist, log_theta,
        X, Xd, mem, theta_hat, make_work(), make_work(), np.empty((3, 3)),
        np.empty((3, model_theta.shape[0])), np.empty((13, 3)), np.empty(4),
    )  # fmt: skip
    return status, k, X, Xd


@kernel(refcount=False)
def _run_loop(
    kind,
    plant_geom,
    plant_theta,
    model_geom,
    model_theta,
    gains,
    eps,
    flc_tables,
    Tc,
    alpha_f,
    substeps,
    force_limit,
    Xdes,
    Xddes,
    Xdddes,
    dist_values,
    dist_index,
    gamma_vec,
    th_min,
    th_max,
    log_X,
    log_Xd,
    log_F,
    log_tau,
    log_q,
    log_dist,
    log_theta,
    X,
    Xd,
    mem,
    theta_hat,
    work,
    pwork,
    M,
    Y,
    vecs,
    tau,
):
    """The loop of :func:`_run_kernel` on its preallocated arrays; returns (status, k).

    X, Xd, mem and theta_hat are the state, advanced in place; ``vecs`` (13, 3) holds
    C, G, F and the RK4 stage vectors.
    """
    n = Xdes.shape[0]
    C, G, F = vecs[0], vecs[1], vecs[2]
    k1x, k1v, k2x, k2v = vecs[3], vecs[4], vecs[5], vecs[6]
    k3x, k3v, k4x, k4v = vecs[7], vecs[8], vecs[9], vecs[10]
    Xs, Vs = vecs[11], vecs[12]
    h = Tc / substeps
    log_theta_on = log_theta.shape[0] == n
    for k in range(n):
        status = _valid(X, Xd)
        if status != 0:
            return status, k
        if log_theta_on:
            for j in range(theta_hat.shape[0]):  # the estimate used for F_k
                log_theta[k, j] = theta_hat[j]
        control_step(
            kind, model_geom, model_theta, gains, eps, flc_tables, Tc, alpha_f,
            X, Xd, Xdes[k], Xddes[k], Xdddes[k], mem, theta_hat, gamma_vec, th_min, th_max,
            work, M, C, G, Y, F,
        )  # fmt: skip
        actuator_forces_kernel(work[JQ], F, tau)  # J of the model at X_k (kinematics ran last)
        if force_limit > 0.0:
            for i in range(4):
                tau[i] = min(force_limit, max(-force_limit, tau[i]))
        dist = dist_values[dist_index[k]]
        for i in range(3):
            log_X[k, i] = X[i]
            log_Xd[k, i] = Xd[i]
            log_dist[k, i] = dist[i]
        for i in range(4):
            log_tau[k, i] = tau[i]
        for _ in range(substeps):
            _plant_accel(plant_geom, plant_theta, X, Xd, tau, dist, pwork, M, C, G, k1v)
            if _ == 0:
                for i in range(4):
                    log_q[k, i] = pwork[Q][i]
                Jq = pwork[JQ]
                for i in range(3):
                    log_F[k, i] = (
                        Jq[0, i] * tau[0]
                        + Jq[1, i] * tau[1]
                        + Jq[2, i] * tau[2]
                        + (Jq[3, i] * tau[3])
                    )
            for i in range(3):
                k1x[i] = Xd[i]
                Xs[i] = X[i] + 0.5 * h * k1x[i]
                Vs[i] = Xd[i] + 0.5 * h * k1v[i]
            _plant_accel(plant_geom, plant_theta, Xs, Vs, tau, dist, pwork, M, C, G, k2v)
            for i in range(3):
                k2x[i] = Vs[i]
                Xs[i] = X[i] + 0.5 * h * k2x[i]
                Vs[i] = Xd[i] + 0.5 * h * k2v[i]
            _plant_accel(plant_geom, plant_theta, Xs, Vs, tau, dist, pwork, M, C, G, k3v)
            for i in range(3):
                k3x[i] = Vs[i]
                Xs[i] = X[i] + h * k3x[i]
                Vs[i] = Xd[i] + h * k3v[i]
            _plant_accel(plant_geom, plant_theta, Xs, Vs, tau, dist, pwork, M, C, G, k4v)
            for i in range(3):
                k4x[i] = Vs[i]
                X[i] += h / 6.0 * (k1x[i] + 2.0 * k2x[i] + 2.0 * k3x[i] + k4x[i])
                Xd[i] += h / 6.0 * (k1v[i] + 2.0 * k2v[i] + 2.0 * k3v[i] + k4v[i])
            if _valid(X, Xd) != 0:
                break
    return 0, n


def desired_forces(plant: Mechanism, Xd, Xdd, Xddd) -> tuple[np.ndarray, np.ndarray]:
    """q_d (N, 4) and tau_a,d = J (J^T J)^-1 [M Xddot_d + C Xdot_d + G](X_d) (N, 4).

    The desired limb lengths and driving forces of Figures 13-16 and 23-26, from the
    true model, along a trajectory (N, 3) that the scenario has already validated.
    """
    Xd, Xdd, Xddd = (np.ascontiguousarray(a, dtype=float) for a in (Xd, Xdd, Xddd))
    q_des, tau_des = np.empty((Xd.shape[0], 4)), np.empty((Xd.shape[0], 4))
    _desired_kernel(plant.geometry, plant.theta, Xd, Xdd, Xddd, q_des, tau_des)
    return q_des, tau_des


@kernel
def _desired_kernel(geom, theta, Xd, Xdd, Xddd, q_out, tau_out):
    """q_d and tau_a,d along a desired trajectory already validated by the scenario."""
    work = make_work()
    M, Cv, G, F = np.empty((3, 3)), np.empty(3), np.empty(3), np.empty(3)
    for k in range(Xd.shape[0]):
        dynamics_kernel(geom, theta, Xd[k], Xdd[k], Xdd[k], work, M, Cv, G)
        for i in range(3):
            F[i] = M[i, 0] * Xddd[k, 0] + M[i, 1] * Xddd[k, 1] + M[i, 2] * Xddd[k, 2]
            F[i] += Cv[i] + G[i]
        actuator_forces_kernel(work[JQ], F, tau_out[k])
        q_out[k, :] = work[Q]


def _disturbance(scenario: Scenario, n: int, Tc: float):
    d = scenario.disturbance
    t_end = n * Tc
    n_hold = int(math.floor(t_end / d.hold + 1e-9)) + 1
    rng = np.random.default_rng(d.seed)
    values = np.asarray(d.amplitude) * rng.uniform(-1.0, 1.0, size=(n_hold, 3))
    # period k starts at k Tc; the value held then is number floor(k Tc / hold)
    index = np.floor(np.arange(n) * Tc / d.hold + 1e-9).astype(np.int64)
    return values, index


@dataclass(frozen=True, eq=False)
class _Prepared:
    """What every run of one scenario shares, whatever the seed: built once."""

    scenario: Scenario
    plant: Mechanism
    model: Mechanism
    t: np.ndarray
    Xdes: np.ndarray
    Xddes: np.ndarray
    Xdddes: np.ndarray
    q_des: np.ndarray
    tau_des: np.ndarray
    flc: MamdaniSystem


def _prepare(scenario: Scenario | str, duration: float | None) -> _Prepared:
    if isinstance(scenario, str):
        scenario = Scenario.builtin(scenario)
    if duration is not None:
        scenario = scenario.replace(**{"timing.duration": float(duration)})
    plant = scenario.plant()
    Tc = scenario.timing.control_period
    n = int(round(scenario.timing.duration / Tc))
    if n < 1:
        raise ScenarioError("timing.duration: shorter than one control period")
    t = np.arange(n) * Tc
    Xdes, Xddes, Xdddes = scenario.trajectory.build().evaluate(t)
    q_des, tau_des = desired_forces(plant, Xdes, Xddes, Xdddes)
    model = scenario.controller_mechanism()
    return _Prepared(scenario, plant, model, t, Xdes, Xddes, Xdddes, q_des, tau_des, FLC())


def _with_seed(scenario: Scenario, seed: int) -> Scenario:
    """The scenario with another disturbance seed (validated here: nothing else changes)."""
    if not (isinstance(seed, int | np.integer) and 0 <= seed <= 2**63 - 1):
        raise ScenarioError(f"disturbance.seed = {seed!r}: must be an integer in [0, 2^63 - 1]")
    dist = scenario.disturbance.model_copy(update={"seed": int(seed)})
    return scenario.model_copy(update={"disturbance": dist})


def simulate(
    scenario: Scenario | str,
    controller: str = "afsmc",
    *,
    duration: float | None = None,
    seed: int | None = None,
) -> Result:
    """Run one closed-loop experiment; ``duration`` and ``seed`` override the scenario's.

    Raises :class:`~pkmctl.SimulationDiverged` (with the partial result) if the
    state becomes non-finite or the pose leaves the valid set.
    """
    if controller not in CONTROLLERS:
        raise ValueError(f"controller = {controller!r}: must be one of {sorted(CONTROLLERS)}")
    return _run(_prepare(scenario, duration), controller, seed)


class _LogBuffers:
    """The arrays one run logs into, (n, ...) each; reusable from run to run."""

    def __init__(self, n: int, theta: bool = True) -> None:
        self.X, self.Xd, self.F = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        self.tau, self.q, self.dist = np.empty((n, 4)), np.empty((n, 4)), np.empty((n, 3))
        self.theta = np.empty((n, 36) if theta else (0, 36))


def _run(
    prep: _Prepared, controller: str, seed: int | None, buffers: _LogBuffers | None = None
) -> Result:
    scenario = prep.scenario if seed is None else _with_seed(prep.scenario, seed)
    plant, model = prep.plant, prep.model
    ctrl = make_controller(
        controller,
        model,
        scenario.controller_gains(),
        period=scenario.timing.control_period,
        flc=prep.flc,
    )
    Tc = scenario.timing.control_period
    t, Xdes, Xddes, Xdddes = prep.t, prep.Xdes, prep.Xddes, prep.Xdddes
    n = t.size
    dvals, didx = _disturbance(scenario, n, Tc)
    afsmc = ctrl.kind == 2
    logs = _LogBuffers(n, afsmc) if buffers is None else buffers
    log_X, log_Xd, log_F, log_tau, log_q, log_dist = (
        logs.X,
        logs.Xd,
        logs.F,
        logs.tau,
        logs.q,
        logs.dist,
    )
    log_theta = logs.theta if afsmc else np.empty((0, 36))
    limit = scenario.actuators.force_limit
    t_kernel = time.perf_counter()
    status, last, X_end, Xd_end = _run_kernel(
        ctrl.kind, plant.geometry, plant.theta, model.geometry, model.theta,
        ctrl.gains.matrix(), ctrl.gains.eps, ctrl._tables, Tc, 1.0 / ctrl.gains.filter_periods,
        scenario.timing.substeps, -1.0 if limit is None else float(limit),
        np.asarray(scenario.initial.X, float), np.asarray(scenario.initial.Xdot, float),
        Xdes, Xddes, Xdddes, dvals, didx, ctrl.gamma_vec, ctrl.theta_min, ctrl.theta_max,
        log_X, log_Xd, log_F, log_tau, log_q, log_dist, log_theta,
    )  # fmt: skip
    t_kernel = time.perf_counter() - t_kernel
    m = last if status else n
    result = Result(
        scenario=scenario,
        controller=controller,
        t=t[:m],
        X=log_X[:m],
        Xdot=log_Xd[:m],
        X_desired=Xdes[:m],
        Xdot_desired=Xddes[:m],
        q=log_q[:m],
        q_desired=prep.q_des[:m],
        F=log_F[:m],
        tau=log_tau[:m],
        tau_desired=prep.tau_des[:m],
        disturbance=log_dist[:m],
        theta_hat=log_theta[:m] if afsmc else None,
        success=status == 0,
        message="ok" if status == 0 else _STATUS[status],
        info={"kernel_seconds": t_kernel, "steps": m},
    )
    if status:
        tk = last * Tc
        raise SimulationDiverged(
            f"simulation diverged at t = {tk:.6g} s ({controller}): {_STATUS[status]}, "
            f"X = {np.array2string(X_end, precision=4)}, Xdot = "
            f"{np.array2string(Xd_end, precision=4)}",
            time=tk,
            state=np.concatenate([X_end, Xd_end]),
            partial=result,
        )
    return result


def simulate_many(
    scenario: Scenario | str,
    controller: str = "afsmc",
    *,
    seeds,
    duration: float | None = None,
    workers: int | None = None,
    keep: str = "results",
) -> list:
    """Run one scenario for several disturbance seeds in parallel threads.

    The scenario, its desired trajectory and desired forces are prepared once; the
    compiled loop releases the GIL, so ``workers`` threads (default: the number of
    cores) run side by side in one process. Results come back in the order of
    ``seeds``; the first failing run's error is raised.

    ``keep="results"`` returns the :class:`Result` of every run. ``keep="metrics"``
    returns ``{"seed": s, **metrics.summary(result)}`` per run instead, and each
    worker logs every run into the same buffers: a campaign of many seeds then never
    touches fresh memory after its first runs (first-touch page faults of ~45 MB per
    10 s run are what limits thread scaling otherwise; see docs/performance.md).
    """
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from .metrics import summary

    if controller not in CONTROLLERS:
        raise ValueError(f"controller = {controller!r}: must be one of {sorted(CONTROLLERS)}")
    if keep not in ("results", "metrics"):
        raise ValueError(f"keep = {keep!r}: must be 'results' or 'metrics'")
    seeds = list(seeds)
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers = {workers}: must be >= 1")
    prep = _prepare(scenario, duration)
    for s in seeds:
        _with_seed(prep.scenario, s)  # fail fast on a bad seed, before any run
    local = threading.local()

    def one(seed):
        if keep == "results":
            return _run(prep, controller, seed)
        if not hasattr(local, "buffers"):
            local.buffers = _LogBuffers(prep.t.size)
        result = _run(prep, controller, seed, local.buffers)
        return {"seed": int(seed), **summary(result)}

    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(one, seeds))
