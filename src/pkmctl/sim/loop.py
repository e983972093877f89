"""The closed loop of parts (DESIGN.md §6): sensor → controller → actuator → plant → log.

Every control period k (t_k = k T_c): the sensor reads the plant state, the controller
turns the measurement and the reference into F_k, the actuator into limb commands; over
the period the plant (and the actuator's continuous state, if any) is integrated by
fixed-step RK4 with ``substeps`` steps, under the actuator's limb forces and the
disturbance tau_d' (redrawn every ``disturbance.hold`` seconds, seeded, held).

:func:`run_parts` compiles one loop per combination of part types (cached on disk,
keyed by the parts' sources: :func:`pkmctl._jit.specialise`) and runs it. Nothing in
this file knows any part by name: the parts are selected by the types of their
parameter bundles (:mod:`pkmctl.parts`).
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba.core.errors import NumbaError

from pkmctl._jit import kernel, specialise, specialised_dir
from pkmctl.parts import (
    Part,
    PartError,
    actuator_command,
    actuator_derivative,
    actuator_force,
    controller_log,
    controller_step,
    plant_derivative,
    plant_observe,
    sensor_log,
    sensor_measure,
)

__all__ = [
    "LOG_NAMES",
    "LoopOutput",
    "STATUS",
    "Setup",
    "compile_error",
    "is_compiled",
    "loop_for",
    "pose_status",
    "run_parts",
    "setup",
]

#: Why a loop stopped early, by its status code.
STATUS = {
    1: "the state became non-finite",
    2: "the pose left the valid set",
    3: "the sensor could not measure (its forward kinematics failed or met a singular pose)",
    4: "the stepped plant blew up (MuJoCo: a fatal warning or a closure residual over 1 um)",
}


@kernel(inline="always", refcount=False)
def pose_status(x):
    for i in range(6):
        if not math.isfinite(x[i]):
            return 1
    if x[0] <= 0.0 or abs(x[1]) >= 0.5 * math.pi or abs(x[2]) >= 0.5 * math.pi:
        return 2
    return 0


def _run_loop(
    plant, x, pw, sensor, ss, sw, ctrl, cs, cw, act, ast, aw, n_z, Tc, substeps,
    ref, dist_values, dist_index, rk, ast_s, vec, logs, log_c, log_s,
):  # fmt: skip
    """The loop over len(ref) periods on preallocated arrays; returns (status, k).

    x, ss, cs, ast are the parts' states, advanced in place; ``rk`` (5 + 5, n) holds the
    RK4 stages of the plant (rows 0-4) and of the actuator's continuous state (rows 5-9);
    ``vec`` (6, 6) the per-period vectors y, F, cmd, tau, q, J^T tau; ``logs`` the
    (n, .) arrays X, Xdot, y, F, tau, q, disturbance; ``log_c`` the controller's log
    (n, m), or (0, m) for none, ``log_s`` the sensor's likewise. Returns status 0 when all
    periods ran, else the code of :data:`STATUS` with k the first period whose state (or
    measurement: status 3) is invalid.
    """
    n = ref.shape[0]
    nx = x.shape[0]
    y, F, cmd, tau, q, Fa = vec[0], vec[1, 0:3], vec[2, 0:4], vec[3, 0:4], vec[4, 0:4], vec[5, 0:3]
    xs = rk[4, 0:nx]
    log_X, log_Xd, log_y, log_F, log_tau, log_q, log_dist = logs
    h = Tc / substeps
    log_c_on = log_c.shape[0] == n
    log_s_on = log_s.shape[0] == n
    for k in range(n):
        status = pose_status(x)
        if status != 0:
            return status, k
        sensor_measure(sensor, ss, sw, x, y)
        for i in range(6):
            if not math.isfinite(y[i]):
                return 3, k
        if log_s_on:
            sensor_log(sensor, ss, log_s[k])
        if log_c_on:
            controller_log(ctrl, cs, log_c[k])  # the state used for F_k
        r = ref[k]
        controller_step(ctrl, cs, cw, y, r, F)
        actuator_command(act, ast, aw, y, F, cmd)
        dist = dist_values[dist_index[k]]
        for i in range(3):
            log_X[k, i] = x[i]
            log_Xd[k, i] = x[3 + i]
            log_dist[k, i] = dist[i]
        for i in range(6):
            log_y[k, i] = y[i]
        for sub in range(substeps):
            for st in range(4):  # the RK4 stages, with one call site per part function
                kx, kz = rk[st, 0:nx], rk[5 + st, 0:n_z]
                if st == 0:
                    for i in range(nx):
                        xs[i] = x[i]
                    for i in range(ast.shape[0]):
                        ast_s[i] = ast[i]
                else:
                    a = h if st == 3 else 0.5 * h
                    for i in range(nx):
                        xs[i] = x[i] + a * rk[st - 1, i]
                    for i in range(n_z):
                        ast_s[i] = ast[i] + a * rk[4 + st, i]
                actuator_force(act, ast_s, cmd, tau)
                plant_derivative(plant, xs, tau, dist, pw, kx)
                actuator_derivative(act, ast_s, cmd, kz)
                if sub == 0 and st == 0:
                    plant_observe(plant, xs, tau, pw, q, Fa)
                    for i in range(4):
                        log_tau[k, i] = tau[i]
                        log_q[k, i] = q[i]
                    for i in range(3):
                        log_F[k, i] = Fa[i]
            for i in range(nx):
                x[i] += h / 6.0 * (rk[0, i] + 2.0 * rk[1, i] + 2.0 * rk[2, i] + rk[3, i])
            for i in range(n_z):
                ast[i] += h / 6.0 * (rk[5, i] + 2.0 * rk[6, i] + 2.0 * rk[7, i] + rk[8, i])
            if pose_status(x) != 0:
                break
    return 0, n


@dataclass(frozen=True, eq=False)
class LoopOutput:
    """What :func:`run_parts` returns: status, periods run, logs and final states."""

    status: int
    steps: int
    logs: dict[str, np.ndarray]
    controller_log: np.ndarray | None
    sensor_log: np.ndarray | None
    final_state: dict[str, np.ndarray]
    kernel_seconds: float


class LogBuffers:
    """The arrays one run logs into, (n, ...) each; reusable from run to run."""

    def __init__(self, n: int, controller_log: int = 0, sensor_log: int = 0) -> None:
        self.n = n
        self.arrays = (
            np.empty((n, 3)),  # X
            np.empty((n, 3)),  # Xdot
            np.empty((n, 6)),  # y: what the sensor gave
            np.empty((n, 3)),  # F = J^T tau
            np.empty((n, 4)),  # tau
            np.empty((n, 4)),  # q
            np.empty((n, 3)),  # disturbance
        )
        self.controller = np.empty((n if controller_log else 0, max(1, controller_log)))
        self.sensor = np.empty((n if sensor_log else 0, max(1, sensor_log)))


LOG_NAMES = ("X", "Xdot", "y", "F", "tau", "q", "disturbance")


def _describe(parts: dict[str, Part]) -> str:
    users = [p for p in parts.values() if not p.builtin] or list(parts.values())
    return "the parts " + ", ".join(f"{p.kind} {p.name!r}" for p in users)


def _reason(exc: Exception) -> str:
    """The first informative line of a Numba error (its report runs to 50 lines)."""
    import re

    text = re.sub(r"\x1b\[[0-9;]*m", "", str(exc))
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith(("Failed in", "During:", "File", "^")):
            return line[:200]
    return type(exc).__name__


def _key(parts: dict[str, Part]) -> tuple[tuple, list[str]]:
    key = tuple(parts[k].params for k in ("plant", "sensor", "controller", "actuator"))
    return key, [s for p in parts.values() if not p.builtin for s in p.sources]


def loop_for(parts: dict[str, Part]):
    """The compiled loop for this combination of parts (one per process, cached on disk)."""
    key, sources = _key(parts)
    return specialise(_run_loop, key, sources, refcount=False)


_MARKER = "compiled"


def is_compiled(parts: dict[str, Part]) -> bool:
    """Whether this combination's loop has run on this machine with the current sources
    (a marker in its cache folder, written after its first successful run)."""
    key, sources = _key(parts)
    return (specialised_dir(_run_loop, key, sources) / _MARKER).exists()


def _mark_compiled(loop) -> None:
    folder = Path(loop._cache.cache_path)
    if not (folder / _MARKER).exists():
        with contextlib.suppress(OSError):
            (folder / _MARKER).touch()


@dataclass(eq=False)
class Setup:
    """What both loop drivers (this one and :mod:`pkmctl.sim.stepped`) take from the parts'
    bundles: (params, a copy of the state, work) per kind, the log buffers, and sizes."""

    bundles: dict[str, tuple]
    logs: LogBuffers
    n_z: int
    n_log: int
    n_slog: int

    def bundle(self, kind: str) -> tuple:
        return self.bundles[kind]

    def output(self, status: int, m: int, dt: float, *, sensor_log: bool = True) -> LoopOutput:
        """The LoopOutput of a run that stopped after m periods with ``status``."""
        logs = self.logs
        return LoopOutput(
            status=int(status),
            steps=int(m),
            logs={name: a[:m] for name, a in zip(LOG_NAMES, logs.arrays, strict=True)},
            controller_log=logs.controller[:m] if self.n_log else None,
            sensor_log=logs.sensor[:m] if self.n_slog and sensor_log else None,
            final_state={k: b[1] for k, b in self.bundles.items()},
            kernel_seconds=dt,
        )


def setup(
    parts: dict[str, Part], bundles: dict[str, tuple], n: int, buffers: LogBuffers | None
) -> Setup:
    """Copy the bundles' states (the loop advances the copies) and size the log buffers."""
    copied = {k: (p, s.copy(), w) for k, (p, s, w) in bundles.items()}
    n_log = int(parts["controller"].log_size(bundles["controller"][0]))
    n_slog = int(parts["sensor"].log_size(bundles["sensor"][0]))
    logs = LogBuffers(n, n_log, n_slog) if buffers is None else buffers
    if logs.sensor.shape != ((n, n_slog) if n_slog else (0, 1)):  # buffers of another sensor
        logs.sensor = np.empty((n if n_slog else 0, max(1, n_slog)))
    return Setup(copied, logs, parts["actuator"].continuous, n_log, n_slog)


def compile_error(parts: dict[str, Part], exc: Exception) -> PartError:
    """One line for a combination of parts that Numba cannot compile."""
    return PartError(f"{_describe(parts)} do not compile: {_reason(exc)}")


def run_parts(
    parts: dict[str, Part],
    bundles: dict[str, tuple],
    *,
    period: float,
    substeps: int,
    reference: np.ndarray,
    dist_values: np.ndarray,
    dist_index: np.ndarray,
    buffers: LogBuffers | None = None,
) -> LoopOutput:
    """Run the loop of ``parts`` (kind → :class:`~pkmctl.parts.Part`) from ``bundles``
    (kind → (params, initial state, work)) over ``len(reference)`` periods.

    ``reference`` (n, 9) is [X_d, Xdot_d, Xddot_d] at every t_k; ``dist_values``
    (m, 3) and ``dist_index`` (n,) the held disturbance. The states in ``bundles`` are
    copied, not changed.
    """
    n = reference.shape[0]
    run = setup(parts, bundles, n, buffers)
    (plant_p, x, pw), (sensor_p, ss, sw) = run.bundle("plant"), run.bundle("sensor")
    (ctrl_p, cs, cw), (act_p, ast, aw) = run.bundle("controller"), run.bundle("actuator")
    logs, n_z = run.logs, run.n_z
    rk = np.zeros((10, max(x.shape[0], n_z, 1)))
    vec = np.zeros((6, 6))
    ast_s = np.zeros(max(ast.shape[0], 1))[: ast.shape[0]]
    loop = loop_for(parts)
    t0 = time.perf_counter()
    try:
        status, k = loop(
            plant_p, x, pw, sensor_p, ss, sw, ctrl_p, cs, cw, act_p, ast, aw, n_z,
            float(period), int(substeps), reference, dist_values, dist_index, rk, ast_s, vec,
            logs.arrays, logs.controller, logs.sensor,
        )  # fmt: skip
    except NumbaError as exc:
        raise compile_error(parts, exc) from exc
    dt = time.perf_counter() - t0
    _mark_compiled(loop)
    return run.output(status, k if status else n, dt)
