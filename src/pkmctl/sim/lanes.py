"""L runs at once in SIMD lanes (DESIGN.md §6, §8): the loop of :mod:`pkmctl.sim.loop`
with a lane dimension innermost in every state and per-period array.

The runs of one lane loop share their part *types*, timing and reference trajectory;
they may differ in every number (seeds and so the disturbance, gains, Theta^, payload,
...). Each part runs in lane form: a part with lane functions (``lanes=`` at
registration) gets its L bundles stacked into one (:func:`pkmctl.parts.stack_lanes`)
and runs all lanes in one call, which LLVM vectorises across the lanes; any other part
runs its scalar functions lane by lane, with the same arithmetic.

Every lane is checked as the single loop checks its run: a lane whose pose leaves the
valid set, whose state becomes non-finite or whose sensor fails stops there (its status,
period and final states are kept, its logs and metrics end), and the other lanes go on;
the stopped lane's states are reset to their initial values so that it computes benign
numbers until the loop ends. Within a period, a lane whose pose becomes invalid after a
sub-step keeps that sub-step's state, as the single loop does when it stops integrating.

:func:`run_lanes` gives one :class:`~pkmctl.sim.loop.LoopOutput` per lane, equal within
1e-12 relative to what :func:`~pkmctl.sim.loop.run_parts` gives for that run alone
(tests/test_lanes.py); not bit for bit, since the lane model kernels have their own order
of sums and their own cos and sin (docs/performance.md). A sensor that quantises (the
prototype's encoder) turns such a last-bit difference into a count sooner or later, and
the runs then part as two seeds' noise would: over 10 s of ``prototype`` 7 runs of 8
parted after 6.5-9 s, a limb force then differing by up to 100 N (docs/campaigns.md).
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np

from pkmctl._jit import kernel, ready, specialise, specialised_dir
from pkmctl.model.lanes import make_lane_work, wide_vectors
from pkmctl.model.simd import flat_view
from pkmctl.parts import (
    EachLane,
    LaneMismatch,
    Part,
    actuator_command_after,
    actuator_derivative,
    actuator_force,
    controller_log,
    controller_step,
    global_values,
    lane_class,
    plant_derivative,
    plant_observe,
    sensor_log,
    sensor_measure,
    stack_lanes,
)
from pkmctl.sim.loop import (
    _MARKER,
    Inputs,
    LogBuffers,
    LoopOutput,
    _mark_compiled,
    accumulate_metrics_lanes,
    blame,
    metric_windows,
    pose_status,
)

__all__ = [
    "LaneMismatch",
    "in_batches",
    "lane_batches",
    "lane_count",
    "lanes_supported",
    "padded_lanes",
    "run_lanes",
]


@functools.cache
def lane_count() -> int:
    """Lanes a batch holds by default: the machine's double-precision SIMD width (8 with
    AVX-512, 4 with AVX2, else 2), read from /proc/cpuinfo (Linux), 4 elsewhere."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return 8 if "avx512f" in flags else 4 if "avx2" in flags else 2
    except OSError:
        pass
    return 4


def padded_lanes(n: int) -> int:
    """The lanes a lane loop of n runs computes: n rounded up to a multiple of
    :func:`lane_count`. The lane kernels' loops over the lanes are vectorised for that
    width; fewer lanes run their scalar remainder code, which is slower than the padded
    loop (measured: 2 lanes took 1.1x and 4 lanes 1.8x the time of 8, for PD and AFSMC;
    docs/performance.md), so the extra lanes are copies of the first run."""
    w = lane_count()
    return -(-n // w) * w


def lane_batches(n: int, lanes: int) -> list[int]:
    """The sizes of the batches that n runs go in, at most ``lanes`` at once: full batches,
    then the rest as one batch if it fills more than half of one, else one run at a time.
    A batch costs a full one (:func:`padded_lanes`), and a lane loop does L runs in the
    time of L / r single runs with r = 1.5-1.9 (docs/performance.md), so a rest of m runs
    is faster alone for m below L / r, 4.2-5.5 of 8: "more than half" sits at that line."""
    if lanes <= 1:
        return [1] * n
    full, rest = divmod(n, lanes)
    return [lanes] * full + ([rest] if 2 * rest > lanes else [1] * rest)


def in_batches(items: list, lanes: int) -> list[list]:
    """``items`` (runs, seeds) cut into the batches of :func:`lane_batches`, in order."""
    out, i = [], 0
    for size in lane_batches(len(items), lanes):
        out.append(items[i : i + size])
        i += size
    return out


def lanes_supported(parts: dict[str, Part]) -> bool:
    """Whether a lane loop speeds these parts up: the plant and the controller have lane
    functions (the costly part of every period), and no part is stepped outside compiled
    code. Any combination of compiled parts *runs* in lanes; this says when it pays."""
    if parts["plant"].stepper is not None:
        return False
    return bool(parts["plant"].lanes) and bool(parts["controller"].lanes)


@kernel(inline="always", refcount=False)
def _save(src, dst, l):
    for i in range(src.shape[0]):
        dst[i, l] = src[i, l]


@kernel(inline="always", refcount=False)
def _all_valid(x, L, pose):
    """Whether rows 0-5 of every lane of x (6+, L) are finite and, with ``pose`` (a
    constant), a valid pose (pose_status 0): one branch-free pass over the lanes, so that
    the loop looks lane by lane only when a lane needs it (a stopped lane holds its
    initial state, which is valid)."""
    bad = 0
    h = 0.5 * math.pi
    for l in range(L):
        ok = (abs(x[0, l]) < math.inf) & (abs(x[1, l]) < math.inf) & (abs(x[2, l]) < math.inf)
        ok &= (abs(x[3, l]) < math.inf) & (abs(x[4, l]) < math.inf) & (abs(x[5, l]) < math.inf)
        if pose:
            ok &= (x[0, l] > 0.0) & (abs(x[1, l]) < h) & (abs(x[2, l]) < h)
        bad += not ok
    return bad == 0


@kernel(inline="always", refcount=False)
def _stop(l, st, k, status, kstop, alive, x, ss, cs, ast, fin, init, acc, accL):
    """Lane l stops at period k with status st: keep its states and metrics' accumulators,
    reset its states to the initial ones (benign numbers until the loop ends)."""
    status[l] = st
    kstop[l] = k
    alive[l] = 0
    for i in range(accL.shape[0]):
        acc[l, i] = accL[i, l]
    states = (x, ss, cs, ast)
    for n in range(4):
        _save(states[n], fin[n], l)
        for i in range(states[n].shape[0]):
            states[n][i, l] = init[n][i, l]


def _run_lanes(
    plant, x, pw, sensor, ss, sw, ctrl, cs, cw, act, ast, aw, n_z, Tc, substeps,
    k0, every, ref, qdes, dist_values, dist_index, kx, kz, xs, zs, vec, logs, log_c, log_s,
    row_c, row_s, acc, accL, mpL, mwL, alive, status, kstop, fin, init, frz,
):  # fmt: skip
    """Periods k0 .. k0 + len(ref) - 1 of L lanes on preallocated arrays.

    States x (nx, L), ss, cs, ast (n, L); ``kx`` and ``kz`` the four RK4 stages (n, L) of
    the plant and of the actuator's continuous state, ``xs``, ``zs`` the stage states;
    ``vec`` = (y (6, L), F (3, L), cmd, tau, q (4, L), Fa (3, L), r (9, L), dist (3, L));
    ``ref`` (c, 9), ``qdes`` (c, 4), ``dist_index`` (c,) shared by the lanes,
    ``dist_values`` (L, m, 3) each lane's; ``logs`` the single loop's log arrays with a
    leading lane axis (L, rows, .), ``log_c``, ``log_s`` likewise (L, rows or 0, m) and
    their lane-form rows ``row_c``, ``row_s`` (m, L) (no argument's type depends on L:
    one compiled loop serves every lane count);
    ``accL`` (., L) and ``mpL`` (., L) the metrics' accumulators and parameters, lane
    innermost, ``mwL`` their scratch (:func:`~pkmctl.sim.loop.accumulate_metrics_lanes`);
    ``acc`` (L, .) receives a lane's accumulators when it stops.
    ``alive``, ``status``, ``kstop`` (L,) per lane; ``fin`` the states of stopped lanes,
    ``init`` the initial states, ``frz`` = (x, ast, flags) of lanes whose pose became
    invalid within the period. Returns the number of lanes still running.
    """
    wide_vectors()
    n = ref.shape[0]
    L = x.shape[1]
    nx = x.shape[0]
    y, F, cmd, tau, q, Fa, r, dist = vec
    # the RK4 arithmetic on (rows, L) C-contiguous arrays as one loop over rows x lanes:
    # a trip count of 6 L rather than six loops of L, which ran LLVM's remainder code
    x_f, xs_f, ast_f, zs_f = flat_view(x), flat_view(xs), flat_view(ast), flat_view(zs)
    nxL, nzL = nx * L, n_z * L
    fx, fz, frozen = frz
    h = Tc / substeps
    log_c_on = log_c.shape[1] > 0
    log_s_on = log_s.shape[1] > 0
    log_X, log_Xd, log_y, log_F, log_tau, log_q, log_dist = logs
    row = (k0 + every - 1) // every
    nxt = row * every
    running = 0
    for l in range(L):
        running += alive[l]
    for j in range(n):
        if running == 0:
            return 0
        k = k0 + j
        if not _all_valid(x, L, True):
            for l in range(L):
                if alive[l]:
                    st = pose_status(x[:, l])
                    if st != 0:
                        _stop(l, st, k, status, kstop, alive, x, ss, cs, ast, fin, init, acc,
                              accL)  # fmt: skip
                        running -= 1
        if running == 0:
            return 0
        sensor_measure(sensor, ss, sw, x, y)
        if not _all_valid(y, L, False):
            for l in range(L):
                if alive[l]:
                    for i in range(6):
                        if not math.isfinite(y[i, l]):
                            _stop(l, 3, k, status, kstop, alive, x, ss, cs, ast, fin, init,
                                  acc, accL)  # fmt: skip
                            running -= 1
                            break
        logged = k == nxt
        if logged and log_s_on:
            sensor_log(sensor, ss, row_s)
            for l in range(L):
                for i in range(row_s.shape[0]):
                    log_s[l, row, i] = row_s[i, l]
        if logged and log_c_on:
            controller_log(ctrl, cs, row_c)
            for l in range(L):
                for i in range(row_c.shape[0]):
                    log_c[l, row, i] = row_c[i, l]
        for i in range(9):
            v = ref[j, i]
            for l in range(L):
                r[i, l] = v
        d = dist_index[j]
        for l in range(L):
            for i in range(3):
                dist[i, l] = dist_values[l, d, i]
        controller_step(ctrl, cs, cw, y, r, F)
        actuator_command_after(act, ast, aw, y, F, ctrl, cw, cmd)
        if logged:
            for l in range(L):
                for i in range(3):
                    log_X[l, row, i] = x[i, l]
                    log_Xd[l, row, i] = x[3 + i, l]
                    log_dist[l, row, i] = dist[i, l]
                for i in range(6):
                    log_y[l, row, i] = y[i, l]
        for l in range(L):
            frozen[l] = 0
        for sub in range(substeps):
            for st in range(4):  # one call site per part function, as in the single loop
                k_x, k_z = kx[st], kz[st]
                if st == 0:
                    for m in range(nxL):
                        xs_f[m] = x_f[m]
                    for m in range(ast_f.shape[0]):  # all of it, as the single loop
                        zs_f[m] = ast_f[m]
                else:
                    a = h if st == 3 else 0.5 * h
                    p_x, p_z = flat_view(kx[st - 1]), flat_view(kz[st - 1])
                    for m in range(nxL):
                        xs_f[m] = x_f[m] + a * p_x[m]
                    for m in range(nzL):
                        zs_f[m] = ast_f[m] + a * p_z[m]
                actuator_force(act, zs, cmd, tau)
                plant_derivative(plant, xs, tau, dist, pw, k_x)
                actuator_derivative(act, zs, cmd, k_z)
                if sub == 0 and st == 0:
                    plant_observe(plant, xs, tau, pw, q, Fa)
                    if logged:
                        for l in range(L):
                            if alive[l]:
                                for i in range(4):
                                    log_tau[l, row, i] = tau[i, l]
                                    log_q[l, row, i] = q[i, l]
                                for i in range(3):
                                    log_F[l, row, i] = Fa[i, l]
                    accumulate_metrics_lanes(accL, mpL, k, ref[j], x, qdes[j], q, tau, mwL)
            k1, k2, k3, k4 = (flat_view(kx[0]), flat_view(kx[1]), flat_view(kx[2]),
                              flat_view(kx[3]))  # fmt: skip
            for m in range(nxL):
                x_f[m] += h / 6.0 * (k1[m] + 2.0 * k2[m] + 2.0 * k3[m] + k4[m])
            z1, z2, z3, z4 = (flat_view(kz[0]), flat_view(kz[1]), flat_view(kz[2]),
                              flat_view(kz[3]))  # fmt: skip
            for m in range(nzL):
                ast_f[m] += h / 6.0 * (z1[m] + 2.0 * z2[m] + 2.0 * z3[m] + z4[m])
            if not _all_valid(
                x, L, True
            ):  # the single loop stops integrating here: keep this state
                for l in range(L):
                    if alive[l] and not frozen[l] and pose_status(x[:, l]) != 0:
                        frozen[l] = 1
                        _save(x, fx, l)
                        _save(ast, fz, l)
        for l in range(L):
            if frozen[l]:
                _save(fx, x, l)
                _save(fz, ast, l)
        if logged:
            row += 1
            nxt += every
    return running


def lane_loop_for(parts: dict[str, Part], bundles: dict[str, tuple]):
    """The compiled lane loop for these parts (one per combination of lane-form types)."""
    key = tuple(type(bundles[k][0]) for k in ("plant", "sensor", "controller", "actuator"))
    fn, key, sources, values = _lane_key(parts, key)
    return specialise(fn, key, sources, refcount=False, values=values)


def _lane_key(parts: dict[str, Part], lane_types: tuple) -> tuple:
    """(function, key, sources, values) of the lane loop whose bundles have ``lane_types``."""
    key = lane_types + tuple(parts[k].params for k in ("plant", "sensor", "controller", "actuator"))
    sources = [s for p in parts.values() if not p.builtin for s in p.sources]
    return _run_lanes, ("lanes", *key), sources, global_values(parts.values())


def lanes_compiled(parts: dict[str, Part]) -> bool:
    """Whether this combination's lane loop has run on this machine with these sources (a
    marker in its cache folder, as :func:`pkmctl.sim.loop.is_compiled` for the single
    loop; a part whose ``lane_ok`` refuses a run's bundle runs lane by lane, another loop,
    which this does not ask)."""
    types = tuple(lane_class(parts[k].params) if parts[k].lanes else EachLane
                  for k in ("plant", "sensor", "controller", "actuator"))  # fmt: skip
    fn, key, sources, values = _lane_key(parts, types)
    return (specialised_dir(fn, key, sources, values) / _MARKER).exists()


def _is_stack(buffers: list | None, L: int, rows: int, n_log: int, n_slog: int) -> bool:
    """Whether ``buffers`` are lanes 0 .. L - 1 of one LogStack sized for these runs."""
    if buffers is None or len(buffers) < L or buffers[0].stack is None:
        return False
    stack = buffers[0].stack
    return (
        all(b.stack is stack and b.lane == i for i, b in enumerate(buffers[:L]))
        and stack.arrays[0].shape[1] == rows
        and stack.controller.shape[1:] == ((rows, n_log) if n_log else (0, 1))
        and stack.sensor.shape[1:] == ((rows, n_slog) if n_slog else (0, 1))
    )


def _shared_inputs(inputs: list[Inputs]) -> Inputs:
    first = inputs[0]
    for other in inputs[1:]:
        if (other.periods, other.every, other.chunk_size) != (
            first.periods,
            first.every,
            first.chunk_size,
        ) or other.chunk != first.chunk:
            raise LaneMismatch("the runs differ in their timing or reference trajectory")
        if other.dist_values.shape != first.dist_values.shape:
            raise LaneMismatch("the runs differ in their number of disturbance values")
        if other.metrics.shape != first.metrics.shape:
            raise LaneMismatch("the runs differ in their metric windows")
    return first


def run_lanes(
    parts: dict[str, Part],
    bundles: list[dict[str, tuple]],
    *,
    period: float,
    substeps: int,
    inputs: list[Inputs],
    buffers: list | None = None,
) -> list[LoopOutput]:
    """Run len(bundles) runs of ``parts`` at once, in L = :func:`padded_lanes` lanes;
    one LoopOutput per run, as :func:`pkmctl.sim.loop.run_parts` gives it for that run
    alone. The runs must share their timing and reference (one
    :class:`~pkmctl.sim.loop.Inputs` chunking each, but their own disturbance values and
    metric parameters); else :class:`LaneMismatch`.
    ``buffers``: the runs log into them when they are lanes 0 .. L - 1 of one stack
    (:meth:`~pkmctl.sim.loop.LogBuffers.stacked`), else into new ones."""
    from pkmctl.sim.loop import setup

    if not bundles or len(bundles) != len(inputs):
        raise ValueError(f"bundles: {len(bundles)} runs, inputs: {len(inputs)}")
    shared = _shared_inputs(inputs)
    n_runs = len(bundles)
    L = padded_lanes(n_runs)  # lanes past n_runs: copies of run 0, their results dropped
    bundles = list(bundles) + [bundles[0]] * (L - n_runs)
    inputs = list(inputs) + [inputs[0]] * (L - n_runs)
    n_log = int(parts["controller"].log_size(bundles[0]["controller"][0]))
    n_slog = int(parts["sensor"].log_size(bundles[0]["sensor"][0]))
    if not _is_stack(buffers, L, shared.rows, n_log, n_slog):  # none, or not lanes of a stack
        buffers = LogBuffers.stacked(L, shared.rows, n_log, n_slog)
    runs = [
        setup(parts, b, inp, buffers[i])
        for i, (b, inp) in enumerate(zip(bundles, inputs, strict=True))
    ]
    lane = {
        kind: stack_lanes(parts[kind], [run.bundle(kind) for run in runs])
        for kind in ("plant", "sensor", "controller", "actuator")
    }
    (plant_p, x, pw), (sensor_p, ss, sw) = lane["plant"], lane["sensor"]
    (ctrl_p, cs, cw), (act_p, ast, aw) = lane["controller"], lane["actuator"]
    nx, n_z = x.shape[0], runs[0].n_z
    e = np.zeros
    kx = tuple(e((nx, L)) for _ in range(4))
    kz = tuple(e((max(n_z, 0), L)) for _ in range(4))
    xs, zs = e((nx, L)), e(ast.shape)
    vec = tuple(e((m, L)) for m in (6, 3, 4, 4, 4, 3, 9, 3))
    logs, log_c, log_s = buffers[0].stack.lanes(L)  # each run's own logs, as lanes
    n_log, n_slog = runs[0].n_log, runs[0].n_slog
    row_c, row_s = e((max(1, n_log), L)), e((max(1, n_slog), L))
    acc = np.stack([run.metrics for run in runs])
    accL = np.ascontiguousarray(acc.T)
    mp = np.stack([inp.metrics for inp in inputs])
    if np.any(metric_windows(mp) != metric_windows(mp[0])):
        raise LaneMismatch("the runs differ in their metric windows")
    mpL = np.ascontiguousarray(mp.T)
    mwL = (make_lane_work(L), e((4, 3, L)), e((4, L)), e((7, L)))
    dist_values = np.ascontiguousarray(np.stack([inp.dist_values for inp in inputs]))
    alive = np.ones(L, dtype=np.int64)
    status = np.zeros(L, dtype=np.int64)
    kstop = np.full(L, shared.periods, dtype=np.int64)
    states = (x, ss, cs, ast)
    init = tuple(s.copy() for s in states)
    fin = tuple(s.copy() for s in states)
    frz = (e(x.shape), e(ast.shape), np.zeros(L, dtype=np.int64))
    loop = lane_loop_for(parts, lane)
    head = (plant_p, x, pw, sensor_p, ss, sw, ctrl_p, cs, cw, act_p, ast, aw, n_z,
            float(period), int(substeps))  # fmt: skip
    tail = (kx, kz, xs, zs, vec, logs, log_c, log_s, row_c, row_s, acc, accL, mpL, mwL,
            alive, status, kstop, fin, init, frz)  # fmt: skip
    dt = 0.0
    for k0, ref, qdes, dist_index in shared.chunks():
        args = (*head, k0, shared.every, ref, qdes, dist_values, dist_index, *tail)
        with blame(parts, k0, period):
            if k0 == 0:  # compiling or loading the loop is not its time
                ready(loop, *args)
            t0 = time.perf_counter()
            left = loop(*args)
            dt += time.perf_counter() - t0
        if left == 0:
            break
    _mark_compiled(loop)  # (lanes_compiled asks for it)
    runs = runs[:n_runs]
    for kind, s, f in zip(("plant", "sensor", "controller", "actuator"), states, fin, strict=True):
        for i, run in enumerate(runs):
            run.bundles[kind][1][:] = f[:, i] if status[i] else s[:, i]
    out = []
    for i, run in enumerate(runs):
        m = int(kstop[i]) if status[i] else shared.periods
        run.metrics[:] = acc[i] if status[i] else accL[:, i]
        out.append(run.output(int(status[i]), m, dt / n_runs))
    return out
