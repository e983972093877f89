"""Sensors: what the controller sees of the plant (DESIGN.md §6). Built in: ``ideal`` and
``encoder`` (the motor encoders and forward kinematics of §7).

See :mod:`pkmctl.parts` for the contract.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pkmctl._jit import kernel
from pkmctl.model.dynamics import cholesky_solve3
from pkmctl.model.kinematics import limb_jacobian
from pkmctl.parts import NoParams, PartContext, builtin_part

__all__ = ["EncoderSensor", "IdealSensor", "encoder_sensor", "fk_batch"]


class IdealSensor(NoParams):
    """The exact pose and rate at the sample time (the paper's assumption)."""


@kernel(refcount=False)
def ideal_measure(p, state, work, x, y):
    """y = [X, Xdot]: the plant's own state."""
    for i in range(6):
        y[i] = x[i]


builtin_part(
    "sensor",
    "ideal",
    {"measure": ideal_measure},
    params=IdealSensor,
    build=lambda ctx: IdealSensor(),
    state_size=0,
    description="exact X and Xdot at the sample time",
)


# ------------------------------------------------------------------ encoders (DESIGN.md §7)
# state: X^ (3), q^ of the previous sample (4), filtered qdot^ (4), started, sample index,
# y of the previous sample (6, for the delay), q^ given now (4), q^ of the previous sample
# (4), the most Gauss-Newton iterations any sample took.
_XH, _QP, _VF, _ST, _K, _YP, _QO, _QOP, _IT = 0, 3, 7, 11, 12, 13, 19, 23, 27
ENCODER_STATE = 28


class EncoderSensor(NamedTuple):
    """Quantised limb lengths, forward kinematics and J^+ rates (DESIGN.md §7).

    ``geom_plant`` (11,): the machine whose lengths the encoders read; ``geom_model``
    (11,): the geometry the forward kinematics assumes; ``resolution`` (m per count,
    l / counts_per_rev); ``noise`` (n, 4) m, Gaussian samples added to q before
    quantising (drawn once per run, seeded; (1, 4) zeros when off) and ``noise_on``;
    ``alpha`` = T_c / (tau_f + T_c), the filter of the backward difference; ``Tc`` (s);
    ``delay`` 1.0: the controller gets the previous sample; ``X0`` (3,) the pose the
    first forward kinematics starts from (the machine is homed); ``step_tol`` (m, rad)
    and ``grad_tol`` (m^2) stop Gauss-Newton; ``max_iter``.
    """

    geom_plant: np.ndarray
    geom_model: np.ndarray
    resolution: float
    noise: np.ndarray
    noise_on: float
    alpha: float
    Tc: float
    delay: float
    X0: np.ndarray
    step_tol: float
    grad_tol: float
    max_iter: int

    @classmethod
    def from_context(cls, ctx: PartContext) -> EncoderSensor:
        sc = ctx.scenario
        if sc is None:
            return encoder_sensor(ctx.plant, ctx.model, period=ctx.period)
        se = sc.sensor
        n = int(round(sc.timing.duration / sc.timing.control_period)) + 1
        return encoder_sensor(
            ctx.plant,
            ctx.model,
            period=ctx.period,
            screw_lead=sc.plant_spec.screw_lead,
            counts_per_rev=se.counts_per_rev,
            noise=se.noise,
            velocity_filter=se.velocity_filter,
            delay_periods=se.delay_periods,
            X0=np.array(sc.initial.X, dtype=float),
            samples=n,
            seed=(se.seed, sc.disturbance.seed),
        )


def encoder_sensor(
    plant,
    model,
    *,
    period: float,
    screw_lead: float = 0.01,
    counts_per_rev: int = 160_000,
    noise: float = 0.0,
    velocity_filter: float = 0.0,
    delay_periods: int = 0,
    X0=(0.7, 0.0, 0.0),
    samples: int = 1,
    seed=0,
) -> EncoderSensor:
    """The ``encoder`` bundle: the machine's and the model's :class:`~pkmctl.Mechanism`, the
    period (s), the screw lead (m), counts per revolution, noise sigma (m), filter time
    constant (s), delay (0 or 1 periods), the start pose (3,), and for noise the number of
    samples and the seed of :func:`numpy.random.default_rng`."""
    if noise > 0:
        draws = np.random.default_rng(seed).normal(0.0, float(noise), size=(samples, 4))
    else:
        draws = np.zeros((1, 4))
    return EncoderSensor(
        plant.geometry,
        model.geometry,
        float(screw_lead) / int(counts_per_rev),
        draws,
        1.0 if noise > 0 else 0.0,
        float(period) / (float(velocity_filter) + float(period)),
        float(period),
        1.0 if delay_periods else 0.0,
        np.array(X0, dtype=float),
        1e-12,
        1e-15,
        20,
    )


@kernel(inline="always", refcount=False)
def _normal_equations(Jq, r):
    """Upper triangle of J^T J and J^T r, for r (4,)."""
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    g0 = g1 = g2 = 0.0
    for i in range(4):
        j0, j1, j2 = Jq[i, 0], Jq[i, 1], Jq[i, 2]
        a00 += j0 * j0
        a01 += j0 * j1
        a02 += j0 * j2
        a11 += j1 * j1
        a12 += j1 * j2
        a22 += j2 * j2
        g0 += j0 * r[i]
        g1 += j1 * r[i]
        g2 += j2 * r[i]
    return a00, a01, a02, a11, a12, a22, g0, g1, g2


#: The predicted stop of :func:`fk_gauss_newton` needs the last step below this many
#: step tolerances: J, from the last iterate, is then within 1e-11 (m, rad) of X.
_JACOBIAN_STEPS = 10.0


@kernel(refcount=False)
def fk_gauss_newton(geom, qh, X, R, Jq, q, r, step_tol, grad_tol, max_iter):
    """Least-squares forward kinematics: X (3,) minimising |q(X) - qh|^2, from X in place.

    Gauss-Newton steps dX = -(J^T J)^-1 J^T r (four rounded lengths fit no pose exactly:
    the residual never reaches zero). Stops when the gradient J^T r is below
    ``grad_tol``, when the step is below ``step_tol``, or when the steps contract so fast
    (ratio rho = |d_j| / |d_j-1| < 1/2) that the error left, at most |d_j| rho / (1 - rho),
    is below ``step_tol`` and the step below 10 ``step_tol``: from a warm start that is
    two iterations where waiting for a step under ``step_tol`` took three and a fourth
    evaluation of J. Returns the iterations taken, or -1 if it did not converge, became
    non-finite or left the chart (z > 0, |angles| < pi/2). Leaves in ``Jq`` the J (4, 3)
    of the last iterate: within the last step (below 1e-11 with the defaults) of the
    returned X. Allocates nothing.
    """
    prev = math.inf
    for it in range(1, max_iter + 1):
        limb_jacobian(geom, X, R, Jq, q)
        for i in range(4):
            r[i] = q[i] - qh[i]
        a00, a01, a02, a11, a12, a22, g0, g1, g2 = _normal_equations(Jq, r)
        if max(abs(g0), abs(g1), abs(g2)) <= grad_tol:
            return it
        d0, d1, d2 = cholesky_solve3(a00, a01, a02, a11, a12, a22, -g0, -g1, -g2)
        X[0] += d0
        X[1] += d1
        X[2] += d2
        if not (math.isfinite(X[0]) and math.isfinite(X[1]) and math.isfinite(X[2])):
            return -1
        if X[0] <= 0.0 or abs(X[1]) >= 0.5 * math.pi or abs(X[2]) >= 0.5 * math.pi:
            return -1
        step = max(abs(d0), abs(d1), abs(d2))
        if step <= step_tol:
            return it
        rho = step / prev  # prev = inf at the first iteration: rho = 0, but no stop (below)
        if it > 1 and rho < 0.5 and step <= _JACOBIAN_STEPS * step_tol:
            if step * rho / (1.0 - rho) <= step_tol:
                return it
        prev = step
    return -1


@kernel
def fk_batch(geom, qh, X0, step_tol, grad_tol, max_iter, out):
    """:func:`fk_gauss_newton` for every row of ``qh`` (n, 4), each warm-started at the
    previous pose (``X0`` (3,) for the first, with four times the iterations); poses into
    ``out`` (n, 3). Returns (the first row that failed, or -1; the largest |q(X) - qh| m)."""
    R, Jq, q, r = np.empty((3, 3)), np.empty((4, 3)), np.empty(4), np.empty(4)
    X = X0.copy()
    worst = 0.0
    for k in range(qh.shape[0]):
        it = fk_gauss_newton(
            geom, qh[k], X, R, Jq, q, r, step_tol, grad_tol, max_iter if k else 4 * max_iter
        )
        if it < 0:
            return k, worst
        for i in range(4):
            worst = max(worst, abs(q[i] - qh[k, i]))
        for i in range(3):
            out[k, i] = X[i]
    return -1, worst


@kernel(refcount=False)
def encoder_measure(p, state, work, x, y):
    """y = [X^, Xdot^] from the quantised limb lengths of the plant at the sample time.

    q^ = res round((q + noise) / res); X^ by :func:`fk_gauss_newton` from the previous X^
    extrapolated by its rate over one period;
    Xdot^ = J^+(X^) qdot^, qdot^ the backward difference of q^ through a first-order
    filter (0 at the first sample: the machine starts at rest). With the delay, y is the
    previous sample's. NaN in y if forward kinematics fails (the loop stops there).
    """
    R, Jq, q, qh, r, Xn = work
    limb_jacobian(p.geom_plant, x[0:3], R, Jq, q)  # what the encoders turn with
    k = int(state[_K])
    for i in range(4):
        qn = q[i] + (p.noise[k, i] if p.noise_on > 0.0 else 0.0)
        qh[i] = p.resolution * math.floor(qn / p.resolution + 0.5)
    started = state[_ST] > 0.0
    # warm start: the previous X^ moved on by its rate over one period (a pose error of
    # ~T_c^2 Xddot instead of ~T_c Xdot: one Gauss-Newton iteration fewer), or the
    # previous X^ itself if that leaves the chart
    for i in range(3):
        Xn[i] = state[_XH + i] + p.Tc * state[_YP + 3 + i] if started else p.X0[i]
    if started and (Xn[0] <= 0.0 or abs(Xn[1]) >= 0.5 * math.pi or abs(Xn[2]) >= 0.5 * math.pi):
        for i in range(3):
            Xn[i] = state[_XH + i]
    it = fk_gauss_newton(p.geom_model, qh, Xn, R, Jq, q, r, p.step_tol, p.grad_tol, p.max_iter)
    if it < 0:
        for i in range(6):
            y[i] = math.nan
        return
    state[_IT] = max(state[_IT], float(it))
    for i in range(4):
        d = (qh[i] - state[_QP + i]) / p.Tc if started else 0.0
        state[_VF + i] = state[_VF + i] + p.alpha * (d - state[_VF + i]) if started else 0.0
        state[_QP + i] = qh[i]
    a00, a01, a02, a11, a12, a22, g0, g1, g2 = _normal_equations(Jq, state[_VF : _VF + 4])
    v0, v1, v2 = cholesky_solve3(a00, a01, a02, a11, a12, a22, g0, g1, g2)
    delayed = p.delay > 0.0 and started
    for i in range(3):
        state[_XH + i] = Xn[i]
    new0, new1, new2, new3, new4, new5 = Xn[0], Xn[1], Xn[2], v0, v1, v2
    if delayed:
        for i in range(6):
            y[i] = state[_YP + i]
        for i in range(4):
            state[_QO + i] = state[_QOP + i]
    else:
        y[0], y[1], y[2], y[3], y[4], y[5] = new0, new1, new2, new3, new4, new5
        for i in range(4):
            state[_QO + i] = qh[i]
    state[_YP], state[_YP + 1], state[_YP + 2] = new0, new1, new2
    state[_YP + 3], state[_YP + 4], state[_YP + 5] = new3, new4, new5
    for i in range(4):
        state[_QOP + i] = qh[i]
    state[_ST] = 1.0
    state[_K] = k + 1.0


@kernel(refcount=False)
def encoder_log(p, state, row):
    """The quantised lengths q^ (4,) behind this period's measurement (``q_measured``)."""
    for i in range(4):
        row[i] = state[_QO + i]


def _encoder_report(p: EncoderSensor, state: np.ndarray) -> dict:
    return {"fk_max_iterations": int(state[_IT]), "encoder_resolution": p.resolution}


builtin_part(
    "sensor",
    "encoder",
    {"measure": encoder_measure, "log": encoder_log},
    params=EncoderSensor,
    build=None,
    state_size=ENCODER_STATE,
    work=lambda p: (
        np.empty((3, 3)),
        np.empty((4, 3)),
        *(np.empty(4) for _ in range(3)),
        np.empty(3),
    ),  # fmt: skip
    log_size=4,
    log_name="q_measured",
    report=_encoder_report,
    memory=lambda sc: 4 if sc.sensor.noise > 0 else 0,  # the noise, drawn up front (n, 4)
    description="quantised limb lengths, forward kinematics, J^+ rates (docs/machine.md)",
)
