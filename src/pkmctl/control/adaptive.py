"""AFSMC (DESIGN.md §3; the paper's eq. 46 and 50-51 corrected).

    F = Y(X, Xdot, Xr_dot, Xr_ddot) Theta^ + K s + u_f,
    dTheta^/dt = Gamma Y^T s, projected onto [theta_min, theta_max]

with u_f as for FSMC. Gamma = gamma diag(Theta_0^2): every parameter adapts at the same
relative rate for the same share of the force (DESIGN.md §4 asks for a per-parameter
scaling). State: the sliding state (7,) then Theta^ (36,). Logs Theta^ (``theta_hat``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pkmctl._jit import kernel
from pkmctl.control.sliding import (
    FUZZY_WORK,
    MODEL_JACOBIAN,
    SLIDING_STATE,
    filter_sdot,
    fuzzy_surface_gain,
    fuzzy_term,
    fuzzy_work,
    machine_force,
    machine_model,
    sliding_surface,
)
from pkmctl.fuzzy import FISTables, SystemTables
from pkmctl.model.dynamics import regressor_kernel
from pkmctl.model.machine import N_THETA_EXT, extended_regressor_kernel
from pkmctl.model.simd import stack_block
from pkmctl.parts import PartContext, builtin_part

__all__ = ["AFSMCExtParams", "AFSMCParams", "adapt"]

#: The largest parameter vector adapt() updates through its stack block (Theta_ext).
_MAX_THETA = N_THETA_EXT


class AFSMCParams(NamedTuple):
    """AFSMC: as FSMC, plus Theta_0 (n,), Gamma's diagonal and the projection bounds (n,)."""

    geom: np.ndarray
    theta0: np.ndarray
    lam: np.ndarray
    K: np.ndarray
    Ks: np.ndarray
    Ksd: np.ndarray
    Ku: np.ndarray
    Tc: float
    alpha_f: float
    flc: FISTables | SystemTables
    gamma_vec: np.ndarray
    theta_min: np.ndarray
    theta_max: np.ndarray
    mach: np.ndarray
    mach_on: float

    @classmethod
    def from_context(cls, ctx: PartContext) -> AFSMCParams:
        g, th0 = ctx.gains, ctx.model.theta
        lo, hi = g.theta_bounds
        return cls(ctx.model.geometry, th0, g.lam, g.K, g.Ks, g.Ksd, g.Ku, float(ctx.period),
                   1.0 / g.filter_periods, ctx.flc.compiled(), g.gamma * th0**2, lo * th0,
                   hi * th0, *machine_model(ctx))  # fmt: skip


@kernel(inline="always", refcount=False)
def adapt(theta_hat, Y, s, Tc, gamma_vec, th_min, th_max):
    """One period of dTheta^/dt = Gamma Y^T s (explicit Euler), projected onto the bounds.

    The paper's eq. 50-51 have the sign and the derivative wrong (DESIGN.md §3). Y^T s
    goes to a stack block first: a loop that reads Y and s and writes Theta^ needs LLVM's
    run-time overlap checks, and with them ran 5x slower (61 against 12 ns for 36
    parameters, docs/performance.md); the stack block overlaps nothing.
    """
    W = stack_block(_MAX_THETA)
    n = theta_hat.shape[0]
    s0, s1, s2 = s[0], s[1], s[2]
    if n > _MAX_THETA:  # never for Theta (36) or Theta_ext (48): the block's bound
        for k in range(n):
            v = theta_hat[k] + Tc * gamma_vec[k] * (Y[0, k] * s0 + Y[1, k] * s1 + Y[2, k] * s2)
            theta_hat[k] = min(th_max[k], max(th_min[k], v))
        return
    for k in range(n):
        W[k] = Y[0, k] * s0 + Y[1, k] * s1 + Y[2, k] * s2
    for k in range(n):
        v = theta_hat[k] + Tc * gamma_vec[k] * W[k]
        theta_hat[k] = min(th_max[k], max(th_min[k], v))


@kernel(refcount=False)
def afsmc_step(p, state, work, y, ref, F):
    """One period of eq. 46 and the projected adaptive law."""
    n = p.theta0.shape[0]
    X, Xd = y[0:3], y[3:6]
    theta_hat = state[SLIDING_STATE : SLIDING_STATE + n]
    w, Y, s, xr_d, xr_dd = work[0], work[5], work[6], work[7], work[8]
    sliding_surface(p.lam, X, Xd, ref[0:3], ref[3:6], ref[6:9], s, xr_d, xr_dd)
    filter_sdot(state, s, p.Tc, p.alpha_f)
    regressor_kernel(p.geom, X, Xd, xr_d, xr_dd, w, Y)
    for i in range(3):
        acc = 0.0
        for k in range(n):
            acc += Y[i, k] * theta_hat[k]
        F[i] = acc
    machine_force(p, X, Xd, xr_d, xr_dd, work, F)  # fixed, not adapted
    for i in range(3):
        F[i] += p.K[i] * s[i]
    fuzzy_term(p.flc, work[FUZZY_WORK], p.Ks, p.Ksd, p.Ku, s, state[3:6], F)
    adapt(theta_hat, Y, s, p.Tc, p.gamma_vec, p.theta_min, p.theta_max)


@kernel(refcount=False)
def afsmc_log(p, state, row):
    """The estimate Theta^ used for this period's F (logged before the update)."""
    for k in range(row.shape[0]):
        row[k] = state[SLIDING_STATE + k]


def _initial(p: AFSMCParams) -> np.ndarray:
    return np.concatenate([np.zeros(SLIDING_STATE), p.theta0])


builtin_part("controller", "afsmc", {"step": afsmc_step, "log": afsmc_log}, params=AFSMCParams,
         build=None, state_size=lambda p: SLIDING_STATE + p.theta0.shape[0],
         work=lambda p: fuzzy_work(p, p.theta0.shape[0]), initial_state=_initial,
         limb_jacobian=MODEL_JACOBIAN,
         log_size=lambda p: p.theta0.shape[0], log_name="theta_hat",
         description="adaptive fuzzy sliding mode control (eq. 46, 50-51 corrected)",
             label="AFSMC", surface_gain=fuzzy_surface_gain, adaptive=True)  # fmt: skip


# ------------------------------------------------------------------ over Theta_ext
#: Scales of Gamma for the 12 machine parameters when the controllers' model has none (its
#: estimate is 0): typical magnitudes of a servo on a ball screw, not the plant's values.
EXT_SCALE = np.array([1.0] * 4 + [10.0] * 4 + [100.0] * 4)  # kg, N, N s/m


class AFSMCExtParams(NamedTuple):
    """AFSMC over Theta_ext (48,) = [Theta, m_r, F_c, F_v] (DESIGN.md §7): as
    :class:`AFSMCParams`, with the smooth sign's v_s. Theta_0 is the controllers' model
    (``controller_model``: theta_scale Theta and its rotor inertia and friction, 0 if it has
    none); Gamma = gamma diag(scale^2), scale = Theta_0 (Theta) and max(Theta_0,
    :data:`EXT_SCALE`) (the machine); bounds [lo, hi] Theta_0 (Theta) and [0, hi scale]
    (the machine: rotor inertia and friction stay >= 0)."""

    geom: np.ndarray
    theta0: np.ndarray
    lam: np.ndarray
    K: np.ndarray
    Ks: np.ndarray
    Ksd: np.ndarray
    Ku: np.ndarray
    Tc: float
    alpha_f: float
    flc: FISTables | SystemTables
    gamma_vec: np.ndarray
    theta_min: np.ndarray
    theta_max: np.ndarray
    v_s: float

    @classmethod
    def from_context(cls, ctx: PartContext) -> AFSMCExtParams:
        g = ctx.gains
        lo, hi = g.theta_bounds
        mm, _ = machine_model(ctx)
        th = ctx.model.theta
        theta0 = np.concatenate([th, mm[:12]])
        scale = np.concatenate([th, np.maximum(mm[:12], EXT_SCALE)])
        tmin = np.concatenate([lo * th, np.zeros(12)])
        return cls(ctx.model.geometry, theta0, g.lam, g.K, g.Ks, g.Ksd, g.Ku, float(ctx.period),
                   1.0 / g.filter_periods, ctx.flc.compiled(), g.gamma * scale**2, tmin,
                   hi * scale, float(mm[12]))  # fmt: skip


@kernel(refcount=False)
def afsmc_ext_step(p, state, work, y, ref, F):
    """One period of eq. 46 with Y_ext Theta_ext^ and the projected adaptive law over 48."""
    n = p.theta0.shape[0]
    X, Xd = y[0:3], y[3:6]
    theta_hat = state[SLIDING_STATE : SLIDING_STATE + n]
    w, Y, s, xr_d, xr_dd = work[0], work[5], work[6], work[7], work[8]
    sliding_surface(p.lam, X, Xd, ref[0:3], ref[3:6], ref[6:9], s, xr_d, xr_dd)
    filter_sdot(state, s, p.Tc, p.alpha_f)
    extended_regressor_kernel(p.geom, X, Xd, xr_d, xr_dd, p.v_s, w, Y)
    for i in range(3):
        acc = 0.0
        for k in range(n):
            acc += Y[i, k] * theta_hat[k]
        F[i] = acc
    for i in range(3):
        F[i] += p.K[i] * s[i]
    fuzzy_term(p.flc, work[FUZZY_WORK], p.Ks, p.Ksd, p.Ku, s, state[3:6], F)
    adapt(theta_hat, Y, s, p.Tc, p.gamma_vec, p.theta_min, p.theta_max)


builtin_part("controller", "afsmc-ext", {"step": afsmc_ext_step, "log": afsmc_log},
             params=AFSMCExtParams, build=None,
             state_size=lambda p: SLIDING_STATE + p.theta0.shape[0],
             work=lambda p: fuzzy_work(p, p.theta0.shape[0]), initial_state=_initial,
             limb_jacobian=MODEL_JACOBIAN,
             log_size=lambda p: p.theta0.shape[0], log_name="theta_hat",
             description="AFSMC adapting over Theta_ext = [Theta, m_r, F_c, F_v] (docs/machine.md)",
             label="AFSMC-ext", surface_gain=fuzzy_surface_gain, adaptive=True)  # fmt: skip
