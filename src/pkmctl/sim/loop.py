"""The closed loop of parts (DESIGN.md §6): sensor → controller → actuator → plant → log.

Every control period k (t_k = k T_c): the sensor reads the plant state, the controller
turns the measurement and the reference into F_k, the actuator into limb commands; over
the period the plant (and the actuator's continuous state, if any) is integrated by
fixed-step RK4 with ``substeps`` steps, under the actuator's limb forces and the
disturbance tau_d' (redrawn every ``disturbance.hold`` seconds, seeded, held).

Every ``every``-th period (k = 0, every, 2 every, ...) is logged; every period adds to the
metrics' accumulators (:func:`accumulate_metrics`), so a decimated log changes no metric.
The per-period inputs (reference, desired limb lengths, disturbance index) come in chunks
(:class:`Inputs`): the whole run at once when every period is logged (the prepared arrays
are then the log's own), a few seconds at a time otherwise, so that memory grows with the
log, not with the run.

:func:`run_parts` compiles one loop per combination of part types (cached on disk,
keyed by the parts' sources: :func:`pkmctl._jit.specialise`) and runs it. Nothing in
this file knows any part by name: the parts are selected by the types of their
parameter bundles (:mod:`pkmctl.parts`).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba.core.errors import NumbaError

from pkmctl._jit import kernel, ready, specialise, specialised_dir
from pkmctl.model.kinematics import limb_jacobian
from pkmctl.model.lanes import disjoint_arrays, lane_limb_jacobian, wide_vectors
from pkmctl.model.simd import flat_view, unsigned
from pkmctl.parts import (
    Part,
    PartError,
    actuator_command_after,
    actuator_derivative,
    actuator_force,
    controller_log,
    controller_step,
    global_values,
    plant_derivative,
    plant_observe,
    sensor_log,
    sensor_measure,
)

__all__ = [
    "LOG_NAMES",
    "Inputs",
    "LoopOutput",
    "STATUS",
    "Setup",
    "accumulate_metrics",
    "accumulate_metrics_lanes",
    "compile_error",
    "is_compiled",
    "loop_for",
    "metric_params",
    "metric_windows",
    "metric_values",
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


# ------------------------------------------------------------------ in-loop metrics
# The metrics' parameters (float64, :func:`metric_params`): the number of windows W, the
# scale of the 7 errors to Table 4's units, the force at which a limb counts as at its
# limit and the limb speed limit (inf: none), the true machine's geometry (11), the first
# period of each window (W). The accumulators (:func:`metric_values` reads them): per
# window [sum e (7), sum e^2 (7), max |e| (7)], then sum |tau(k) - tau(k-1)| (4), tau of
# the previous period (4), max |tau| (4), periods at the force limit, max limb speed (4),
# periods over the speed limit.
_MP_SCALE, _MP_FLIM, _MP_VLIM, _MP_GEOM, _MP_START = 1, 8, 9, 10, 21
_PER_WINDOW = 21
_A_CHAT, _A_PREV, _A_PEAK, _A_AT, _A_SPEED, _A_OVER = 0, 4, 8, 12, 13, 17
_A_TAIL = 18


def metric_params(
    starts, scale, force_threshold: float, speed_limit: float, geometry
) -> np.ndarray:
    """The metrics' parameter vector: window starts (periods) (W,), scale (7,) of the
    errors [z, alpha, beta, q1..q4], the force threshold and speed limit (inf: none), the
    true machine's geometry (11,)."""
    starts = [float(s) for s in starts]
    head = [float(len(starts)), *map(float, scale), float(force_threshold), float(speed_limit)]
    return np.array([*head, *map(float, geometry), *starts])


def metric_windows(mp: np.ndarray) -> np.ndarray:
    """The first period of each metric window in the parameter vector(s) ``mp`` (.., W)."""
    return mp[..., _MP_START:]


def _accumulators(mp: np.ndarray) -> np.ndarray:
    return np.zeros(int(mp[0]) * _PER_WINDOW + _A_TAIL)


def metric_values(acc: np.ndarray, mp: np.ndarray) -> dict[str, np.ndarray | int]:
    """The accumulators by name: sum_error, sum_squared_error, max_abs_error (W, 7),
    chattering_sum, peak_force, peak_limb_speed (4,), periods_at_force_limit,
    periods_over_speed_limit."""
    w = int(mp[0])
    per = acc[: w * _PER_WINDOW].reshape(w, 3, 7)
    tail = acc[w * _PER_WINDOW :]
    return {
        "sum_error": per[:, 0].copy(),
        "sum_squared_error": per[:, 1].copy(),
        "max_abs_error": per[:, 2].copy(),
        "chattering_sum": tail[_A_CHAT : _A_CHAT + 4].copy(),
        "peak_force": tail[_A_PEAK : _A_PEAK + 4].copy(),
        "periods_at_force_limit": int(tail[_A_AT]),
        "peak_limb_speed": tail[_A_SPEED : _A_SPEED + 4].copy(),
        "periods_over_speed_limit": int(tail[_A_OVER]),
    }


# Without FMA contraction: the sums then add exactly the terms NumPy's reductions add, in
# the same order (each e, each e * e rounded), and the metrics of a decimated run equal
# those the log of a full one gives. LLVM inlines it, keeping these flags.
@kernel(refcount=False, fastmath=False, llvm_inline=True)
def accumulate_metrics(acc, mp, k, Xd, x, qd, q, tau, R, Jq, qw, e):
    """Add period k to the accumulators ``acc``: errors e (7,) = (X_d - X, q_d - q) scaled,
    tau (4,) the limb forces at t_k, x the plant state at t_k (true limb speeds
    |J(X) Xdot| when a speed limit is set; R, Jq, qw scratch). Branch-free inner loops
    of fixed length, so that LLVM can vectorise them."""
    for i in range(3):
        e[i] = (Xd[i] - x[i]) * mp[_MP_SCALE + i]
    for i in range(4):
        e[3 + i] = (qd[i] - q[i]) * mp[_MP_SCALE + 3 + i]
    nw = int(mp[0])
    for w in range(nw):
        if k >= mp[_MP_START + w]:
            b = w * _PER_WINDOW
            for i in range(7):
                acc[b + i] += e[i]
                acc[b + 7 + i] += e[i] * e[i]
                acc[b + 14 + i] = max(acc[b + 14 + i], abs(e[i]))
    t = nw * _PER_WINDOW
    if k > 0:
        for i in range(4):
            acc[t + _A_CHAT + i] += abs(tau[i] - acc[t + _A_PREV + i])
    at = 0
    for i in range(4):
        acc[t + _A_PREV + i] = tau[i]
        acc[t + _A_PEAK + i] = max(acc[t + _A_PEAK + i], abs(tau[i]))
        at += abs(tau[i]) >= mp[_MP_FLIM]
    if at > 0:
        acc[t + _A_AT] += 1.0
    if mp[_MP_VLIM] < math.inf:
        limb_jacobian(mp[_MP_GEOM : _MP_GEOM + 11], x[0:3], R, Jq, qw)
        over = 0
        for i in range(4):
            v = abs(Jq[i, 0] * x[3] + Jq[i, 1] * x[4] + Jq[i, 2] * x[5])
            acc[t + _A_SPEED + i] = max(acc[t + _A_SPEED + i], v)
            over += v > mp[_MP_VLIM]
        if over > 0:
            acc[t + _A_OVER] += 1.0


@kernel(refcount=False, llvm_inline=True)
def accumulate_metrics_lanes(acc, mp, k, Xd, x, qd, q, tau, work):
    """:func:`accumulate_metrics` for L lanes at once, lane innermost: ``acc`` (n, L) and
    ``mp`` (m, L) the lanes' accumulators and parameters (the window starts equal in
    every lane), x (nx, L), q and tau (4, L), Xd and qd the shared reference row;
    ``work`` = (lane model work, Jq (4, 3, L), q (4, L), e (7, L)); all C-contiguous.
    Every lane adds period k (a lane that has stopped keeps adding: its caller saved its
    accumulators when it stopped). The same sums as the scalar function, in the same
    order, without branches across lanes; the limb speeds come from the lane limb
    Jacobian, which agrees with the scalar one to rounding.

    A block of accumulator rows (the 7 sums of a window, ...) is one loop over its rows
    times the lanes, on flat views: a trip count of 7 L or 4 L, which LLVM runs in its
    vector body, where one loop per row of L = 8 lanes ran its short remainder loops
    (docs/performance.md)."""
    wide_vectors()
    disjoint_arrays()
    w, Jq, qw, e = work
    L = x.shape[1]
    for i in range(3):
        for l in range(L):
            e[i, l] = (Xd[i] - x[i, l]) * mp[_MP_SCALE + i, l]
    for i in range(4):
        for l in range(L):
            e[3 + i, l] = (qd[i] - q[i, l]) * mp[_MP_SCALE + 3 + i, l]
    a, ef, tf = flat_view(acc), flat_view(e), flat_view(tau)
    n7 = 7 * L
    nw = int(mp[0, 0])
    for win in range(nw):
        if k >= mp[_MP_START + win, 0]:
            b = win * _PER_WINDOW * L
            for m in range(n7):
                a[unsigned(b + m)] += ef[unsigned(m)]
            b += n7
            for m in range(n7):
                v = ef[unsigned(m)]
                a[unsigned(b + m)] += v * v
            b += n7
            for m in range(n7):
                a[unsigned(b + m)] = max(a[unsigned(b + m)], abs(ef[unsigned(m)]))
    t = nw * _PER_WINDOW
    n4 = 4 * L
    prev, peak = (t + _A_PREV) * L, (t + _A_PEAK) * L
    if k > 0:
        chat = (t + _A_CHAT) * L
        for m in range(n4):
            a[unsigned(chat + m)] += abs(tf[unsigned(m)] - a[unsigned(prev + m)])
    for m in range(n4):
        a[unsigned(prev + m)] = tf[unsigned(m)]
    for m in range(n4):
        a[unsigned(peak + m)] = max(a[unsigned(peak + m)], abs(tf[unsigned(m)]))
    for l in range(L):
        e[0, l] = 0.0  # 1.0 where a limb is at the force limit
    for i in range(4):
        for l in range(L):
            e[0, l] = max(e[0, l], 1.0 if abs(tau[i, l]) >= mp[_MP_FLIM, l] else 0.0)
    for l in range(L):
        acc[t + _A_AT, l] += e[0, l]
    on = False
    for l in range(L):
        on |= mp[_MP_VLIM, l] < math.inf
    if on:  # lanes without a speed limit add nothing (their speeds count as 0)
        lane_limb_jacobian(mp[_MP_GEOM : _MP_GEOM + 11], x[0:3], w, Jq, qw)
        for l in range(L):
            e[0, l] = 0.0  # 1.0 where a limb is over the speed limit
            e[1, l] = 1.0 if mp[_MP_VLIM, l] < math.inf else 0.0
        for i in range(4):
            for l in range(L):
                qd_i = Jq[i, 0, l] * x[3, l] + Jq[i, 1, l] * x[4, l] + Jq[i, 2, l] * x[5, l]
                v = e[1, l] * abs(qd_i)
                acc[t + _A_SPEED + i, l] = max(acc[t + _A_SPEED + i, l], v)
                e[0, l] = max(e[0, l], 1.0 if v > mp[_MP_VLIM, l] else 0.0)
        for l in range(L):
            acc[t + _A_OVER, l] += e[0, l]


def _run_loop(
    plant, x, pw, sensor, ss, sw, ctrl, cs, cw, act, ast, aw, n_z, Tc, substeps,
    k0, every, ref, qdes, dist_values, dist_index, rk, ast_s, vec, logs, log_c, log_s,
    acc, mp, mw,
):  # fmt: skip
    """The loop over periods k0 .. k0 + len(ref) - 1 on preallocated arrays; returns
    (status, k).

    x, ss, cs, ast are the parts' states, advanced in place; ``rk`` (5 + 5, n) holds the
    RK4 stages of the plant (rows 0-4) and of the actuator's continuous state (rows 5-9);
    ``vec`` (6, 6) the per-period vectors y, F, cmd, tau, q, J^T tau. ``ref`` (c, 9),
    ``qdes`` (c, 4) and ``dist_index`` (c,) are this chunk's reference, desired limb
    lengths and disturbance index, from period k0 on. ``logs`` the (rows, .) arrays X,
    Xdot, y, F, tau, q, disturbance of the whole run, row k // every for the periods
    k = 0, every, 2 every, ...; ``log_c`` the controller's log (rows, m), or (0, m) for
    none, ``log_s`` the sensor's likewise. ``acc`` the metrics' accumulators, ``mp`` their
    parameters (:func:`metric_params`), ``mw`` their scratch. Returns status 0 when all
    periods ran, else the code of :data:`STATUS` with k the first period whose state (or
    measurement: status 3) is invalid.
    """
    n = ref.shape[0]
    nx = x.shape[0]
    y, F, cmd, tau, q, Fa = vec[0], vec[1, 0:3], vec[2, 0:4], vec[3, 0:4], vec[4, 0:4], vec[5, 0:3]
    xs = rk[4, 0:nx]
    log_X, log_Xd, log_y, log_F, log_tau, log_q, log_dist = logs
    R, Jm, qm, ev = mw
    h = Tc / substeps
    log_c_on = log_c.shape[0] > 0
    log_s_on = log_s.shape[0] > 0
    row = (k0 + every - 1) // every  # the first row at or after k0, logged at k = nxt
    nxt = row * every
    for j in range(n):
        k = k0 + j
        status = pose_status(x)
        if status != 0:
            return status, k
        sensor_measure(sensor, ss, sw, x, y)
        for i in range(6):
            if not math.isfinite(y[i]):
                return 3, k
        logged = k == nxt
        if logged and log_s_on:
            sensor_log(sensor, ss, log_s[row])
        if logged and log_c_on:
            controller_log(ctrl, cs, log_c[row])  # the state used for F_k
        r = ref[j]
        controller_step(ctrl, cs, cw, y, r, F)
        actuator_command_after(act, ast, aw, y, F, ctrl, cw, cmd)
        dist = dist_values[dist_index[j]]
        if logged:
            for i in range(3):
                log_X[row, i] = x[i]
                log_Xd[row, i] = x[3 + i]
                log_dist[row, i] = dist[i]
            for i in range(6):
                log_y[row, i] = y[i]
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
                    if logged:
                        for i in range(4):
                            log_tau[row, i] = tau[i]
                            log_q[row, i] = q[i]
                        for i in range(3):
                            log_F[row, i] = Fa[i]
                    accumulate_metrics(acc, mp, k, r, x, qdes[j], q, tau, R, Jm, qm, ev)
            for i in range(nx):
                x[i] += h / 6.0 * (rk[0, i] + 2.0 * rk[1, i] + 2.0 * rk[2, i] + rk[3, i])
            for i in range(n_z):
                ast[i] += h / 6.0 * (rk[5, i] + 2.0 * rk[6, i] + 2.0 * rk[7, i] + rk[8, i])
            if pose_status(x) != 0:
                break
        if logged:
            row += 1
            nxt += every
    return 0, k0 + n


@dataclass(frozen=True, eq=False)
class Inputs:
    """What the loop reads every period, in chunks of ``chunk_size`` periods.

    ``chunk(k0, k1)`` gives, for periods k0 .. k1 - 1, the reference (k1 - k0, 9)
    [X_d, Xdot_d, Xddot_d], the desired limb lengths (k1 - k0, 4) (for the metrics) and the
    index (k1 - k0,) into ``dist_values`` (m, 3), the held disturbance. ``periods`` in the
    run; one logged row every ``every`` periods; ``metrics`` the metrics' parameters
    (:func:`metric_params`).
    """

    periods: int
    every: int
    chunk_size: int
    chunk: Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]
    dist_values: np.ndarray
    metrics: np.ndarray

    @property
    def rows(self) -> int:
        """Logged rows of the whole run."""
        return -(-self.periods // self.every)

    def chunks(self) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
        """(k0, reference, desired lengths, disturbance index) of each chunk in turn."""
        for k0 in range(0, self.periods, self.chunk_size):
            yield (k0, *self.chunk(k0, min(self.periods, k0 + self.chunk_size)))


@dataclass(frozen=True, eq=False)
class LoopOutput:
    """What :func:`run_parts` returns: status, periods run, logs (their rows), final
    states, and the metrics' raw accumulators (:func:`metric_values`)."""

    status: int
    steps: int
    logs: dict[str, np.ndarray]
    controller_log: np.ndarray | None
    sensor_log: np.ndarray | None
    final_state: dict[str, np.ndarray]
    kernel_seconds: float
    metrics: np.ndarray


_LOG_WIDTHS = (3, 3, 6, 3, 4, 4, 3)  # X, Xdot, y (what the sensor gave), F = J^T tau, tau, q, dist


class LogStack:
    """The logs of L runs in one block per log, (L, rows, ...) each: what a lane loop
    writes (pkmctl.sim.lanes), so that its compiled type does not depend on L."""

    def __init__(self, lanes: int, n: int, controller_log: int = 0, sensor_log: int = 0) -> None:
        self.arrays = tuple(np.empty((lanes, n, m)) for m in _LOG_WIDTHS)
        self.controller = np.empty((lanes, n if controller_log else 0, max(1, controller_log)))
        self.sensor = np.empty((lanes, n if sensor_log else 0, max(1, sensor_log)))

    def lanes(self, L: int) -> tuple[tuple, np.ndarray, np.ndarray]:
        """(logs, controller log, sensor log) of lanes 0 .. L - 1, as the lane loop takes them."""
        return tuple(a[:L] for a in self.arrays), self.controller[:L], self.sensor[:L]


class LogBuffers:
    """The arrays one run logs into, (rows, ...) each; reusable from run to run.

    :meth:`stacked` makes the buffers of L runs as the lanes of one :class:`LogStack`
    (``stack`` and ``lane`` say which); a lane loop given such buffers logs into them
    directly."""

    stack: LogStack | None = None
    lane: int = 0

    def __init__(self, n: int, controller_log: int = 0, sensor_log: int = 0) -> None:
        self.n = n
        self.arrays = tuple(np.empty((n, m)) for m in _LOG_WIDTHS)
        self.controller = np.empty((n if controller_log else 0, max(1, controller_log)))
        self.sensor = np.empty((n if sensor_log else 0, max(1, sensor_log)))

    @classmethod
    def stacked(
        cls, lanes: int, n: int, controller_log: int = 0, sensor_log: int = 0
    ) -> list[LogBuffers]:
        """The buffers of ``lanes`` runs, each a lane of one :class:`LogStack`."""
        stack = LogStack(lanes, n, controller_log, sensor_log)
        out = []
        for lane in range(lanes):
            b = cls.__new__(cls)
            b.n, b.stack, b.lane = n, stack, lane
            b.arrays = tuple(a[lane] for a in stack.arrays)
            b.controller, b.sensor = stack.controller[lane], stack.sensor[lane]
            out.append(b)
        return out


LOG_NAMES = ("X", "Xdot", "y", "F", "tau", "q", "disturbance")


def _describe(parts: dict[str, Part]) -> str:
    users = [p for p in parts.values() if not p.builtin] or list(parts.values())
    named = ", ".join(f"{p.kind} {p.name!r}" for p in users)
    return ("the part " if len(users) == 1 else "the parts ") + named


def _reason(exc: Exception) -> str:
    """The cause of a Numba error in one line (its report runs to 50 lines): the innermost
    error (a part's step is typed inside the loop's call to it, so the outer lines only
    say that no implementation of ``controller_step`` matched) and where in the part's
    own file, e.g. "Unknown attribute 'kq' of type Law(...) (law.py, line 15:
    F[i] = p.kq[i] * (ref[i] - y[i]))"."""
    import re

    text = re.sub(r"\x1b\[[0-9;]*m", "", str(exc))
    lines = [line.strip() for line in text.splitlines()]
    rejected = [i for i, line in enumerate(lines) if line.startswith("Rejected as the impl")]
    start = rejected[-1] + 1 if rejected else 0
    skip = ("During:", "File", "^", "raised from", "<source elided>", "Rejected as", ">>>",
            "There are", "- Of which", "Overload in function", "With argument")  # fmt: skip

    def informative(line: str) -> bool:
        return bool(line) and not line.startswith(skip) and "nopython mode pipeline" not in line

    at = next((i for i in range(start, len(lines)) if informative(lines[i])), None)
    cause = "" if at is None else lines[at]
    if cause.startswith("No implementation of function"):  # say which call: its signature
        sig = next((x for x in lines[at + 1 : at + 4] if x.startswith(">>>")), "")
        cause = f"no implementation of {sig[3:].strip()}" if sig else cause
    if not cause:
        cause = next((x for x in lines if x and not x.startswith(skip[:3])), "")
    if "returning of array" in cause or "NRT required" in cause:  # Numba's words for an
        # allocation without refcounts (NRT: array arithmetic such as ref[0:3] - y[0:3])
        cause += (" (a step must not allocate: no array arithmetic or copies, loop over the "
                  "elements; make its arrays in its work)")  # fmt: skip
    where = ""
    for i in range(start, len(lines)):
        m = re.match(r'File "([^"]+)", line (\d+):', lines[i])
        if m and "pkmctl" not in m.group(1) and "numba" not in m.group(1):
            source = next((lines[j - 1] for j in range(i + 1, min(i + 12, len(lines)))
                           if lines[j].startswith("^")), "")  # fmt: skip
            where = f" ({Path(m.group(1)).name}, line {m.group(2)}" + (
                f": {source})" if source else ")"
            )
            break
    return ((cause or type(exc).__name__)[:240] + where)[:400]


def _key(parts: dict[str, Part]) -> tuple[tuple, list[str], str]:
    key = tuple(parts[k].params for k in ("plant", "sensor", "controller", "actuator"))
    sources = [s for p in parts.values() if not p.builtin for s in p.sources]
    return key, sources, global_values(parts.values())


def loop_for(parts: dict[str, Part]):
    """The compiled loop for this combination of parts (one per process, cached on disk)."""
    key, sources, values = _key(parts)
    return specialise(_run_loop, key, sources, refcount=False, values=values)


_MARKER = "compiled"


def is_compiled(parts: dict[str, Part]) -> bool:
    """Whether this combination's loop has run on this machine with the current sources
    (a marker in its cache folder, written after its first successful run). For a
    stepped plant, the loop is :mod:`pkmctl.sim.stepped`'s compiled period."""
    if parts["plant"].stepper is not None:
        from pkmctl.sim.stepped import _period as compiled
    else:
        compiled = _run_loop
    key, sources, values = _key(parts)
    return (specialised_dir(compiled, key, sources, values) / _MARKER).exists()


def _mark_compiled(loop) -> None:
    # never called (a run that stopped before its first period), or not a cached
    # dispatcher (a test's stand-in)
    if not getattr(loop, "signatures", None) or getattr(loop, "_cache", None) is None:
        return
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
    every: int
    metrics: np.ndarray  # the accumulators
    metric_work: tuple  # their scratch: R (3, 3), Jq (4, 3), q (4,), e (7,)

    def bundle(self, kind: str) -> tuple:
        return self.bundles[kind]

    def output(self, status: int, m: int, dt: float) -> LoopOutput:
        """The LoopOutput of a run that stopped after m periods with ``status``."""
        logs = self.logs
        rows = -(-m // self.every)  # k = 0, every, ... < m
        return LoopOutput(
            status=int(status),
            steps=int(m),
            logs={name: a[:rows] for name, a in zip(LOG_NAMES, logs.arrays, strict=True)},
            controller_log=logs.controller[:rows] if self.n_log else None,
            sensor_log=logs.sensor[:rows] if self.n_slog else None,
            final_state={k: b[1] for k, b in self.bundles.items()},
            kernel_seconds=dt,
            metrics=self.metrics,
        )


def setup(
    parts: dict[str, Part], bundles: dict[str, tuple], inputs: Inputs, buffers: LogBuffers | None
) -> Setup:
    """Copy the bundles' states (the loop advances the copies), size the log buffers (one
    row per logged period) and zero the metrics' accumulators."""
    copied = {k: (p, s.copy(), w) for k, (p, s, w) in bundles.items()}
    n_log = int(parts["controller"].log_size(bundles["controller"][0]))
    n_slog = int(parts["sensor"].log_size(bundles["sensor"][0]))
    n = inputs.rows
    logs = LogBuffers(n, n_log, n_slog) if buffers is None else buffers
    if logs.n != n:
        raise ValueError(f"buffers: {logs.n} rows, the run logs {n}")
    if logs.sensor.shape != ((n, n_slog) if n_slog else (0, 1)):  # buffers of another sensor
        logs.sensor = np.empty((n if n_slog else 0, max(1, n_slog)))
    work = (np.empty((3, 3)), np.empty((4, 3)), np.empty(4), np.empty(7))
    return Setup(
        copied, logs, parts["actuator"].continuous, n_log, n_slog, int(inputs.every),
        _accumulators(inputs.metrics), work,
    )  # fmt: skip


def compile_error(parts: dict[str, Part], exc: Exception) -> PartError:
    """One line for a combination of parts that Numba cannot compile."""
    users = [p for p in parts.values() if not p.builtin] or list(parts.values())
    verb = "does" if len(users) == 1 else "do"
    return PartError(f"{_describe(parts)} {verb} not compile: {_reason(exc)}")


@contextlib.contextmanager
def blame(parts: dict[str, Part], k: int, period: float) -> Iterator[None]:
    """Around a call of the parts' compiled code (from period ``k`` on): a Numba error is
    a one-line compile error (:func:`compile_error`); another exception, with a user's
    part in the loop, a one-line PartError naming the part(s), the exception and the time
    (the user's ``raise ValueError("boom")`` read "error: boom"; a RuntimeError "an
    internal error"); with pkmctl's parts alone, the exception as it is."""
    try:
        yield
    except NumbaError as exc:
        raise compile_error(parts, exc) from exc
    except Exception as exc:
        if all(p.builtin for p in parts.values()):
            raise
        verb = "raises" if sum(not p.builtin for p in parts.values()) == 1 else "raise"
        raise PartError(
            f"{_describe(parts)} {verb} {type(exc).__name__}: {str(exc)[:300]} (in the "
            f"period starting at t = {k * period:.6g} s or later)"
        ) from exc


def run_parts(
    parts: dict[str, Part],
    bundles: dict[str, tuple],
    *,
    period: float,
    substeps: int,
    inputs: Inputs,
    buffers: LogBuffers | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LoopOutput:
    """Run the loop of ``parts`` (kind → :class:`~pkmctl.parts.Part`) from ``bundles``
    (kind → (params, initial state, work)) over ``inputs.periods`` periods, chunk by chunk
    (:class:`Inputs`). The states in ``bundles`` are copied, not changed. ``progress``
    is called as ``progress(periods done, periods)`` after each chunk.
    """
    run = setup(parts, bundles, inputs, buffers)
    (plant_p, x, pw), (sensor_p, ss, sw) = run.bundle("plant"), run.bundle("sensor")
    (ctrl_p, cs, cw), (act_p, ast, aw) = run.bundle("controller"), run.bundle("actuator")
    logs, n_z = run.logs, run.n_z
    rk = np.zeros((10, max(x.shape[0], n_z, 1)))
    vec = np.zeros((6, 6))
    ast_s = np.zeros(max(ast.shape[0], 1))[: ast.shape[0]]
    loop = loop_for(parts)
    head = (plant_p, x, pw, sensor_p, ss, sw, ctrl_p, cs, cw, act_p, ast, aw, n_z,
            float(period), int(substeps))  # fmt: skip
    tail = (rk, ast_s, vec, logs.arrays, logs.controller, logs.sensor, run.metrics,
            inputs.metrics, run.metric_work)  # fmt: skip
    status, k, dt = 0, inputs.periods, 0.0
    for k0, ref, qdes, dist_index in inputs.chunks():
        args = (*head, k0, run.every, ref, qdes, inputs.dist_values, dist_index, *tail)
        with blame(parts, k0, period):  # (only the compiled code: not progress's)
            if k0 == 0:  # compiling or loading the loop is not its time
                ready(loop, *args)
            t0 = time.perf_counter()
            status, k = loop(*args)
            dt += time.perf_counter() - t0
        if status:
            break
        if progress is not None:
            progress(k0 + ref.shape[0], inputs.periods)
    _mark_compiled(loop)
    return run.output(status, k if status else inputs.periods, dt)
