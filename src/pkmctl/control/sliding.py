"""SMC and FSMC (DESIGN.md §3; the paper's eq. 25-26), and what AFSMC shares with them.

Notation: e = X_d - X, s = edot + lambda e (the sliding surface), Xr_dot = Xdot_d + lambda e,
Xr_ddot = Xddot_d + lambda edot.

- SMC  (eq. 25): F = M^ Xr_ddot + C^ Xr_dot + G^(X_d) + K s + Lambda sat(s / eps)
- FSMC (eq. 26): F = M^ Xr_ddot + C^ Xr_dot + G^(X_d) + K s + u_f

with u_f,i = -K_u,i FLC(K_s,i s_i, K_sdot,i sdot_i). The minus makes the paper's rule
table (positive s -> negative output) stabilising: s^T u_f >= 0. FLC is the scenario's
fuzzy system (``[fuzzy]``: the paper's by default, or a ``.fis`` file), compiled as
:mod:`pkmctl.fuzzy.term` says; its work arrays are the last item of the work tuple.

sdot is the backward difference of s over one period, low-pass filtered with time
constant tau_f = ``filter_periods`` T_c; on the first step there is no previous s and
the difference is taken as 0. State (7,): [s_prev (3), sdot (3), started].
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pkmctl._jit import kernel
from pkmctl.fuzzy import FISTables, SystemTables
from pkmctl.fuzzy.term import term_eval, term_work
from pkmctl.model.dynamics import (
    JQ,
    dynamics_kernel,
    gravity_kernel,
    inverse_dynamics,
    make_work,
)
from pkmctl.model.machine import N_MACHINE_MODEL, add_machine_model
from pkmctl.parts import PartContext, builtin_part

__all__ = [
    "FSMCParams",
    "FUZZY_WORK",
    "SLIDING_STATE",
    "SMCParams",
    "controller_work",
    "fuzzy_surface_gain",
    "fuzzy_work",
    "smc_surface_gain",
    "filter_sdot",
    "fuzzy_term",
    "machine_force",
    "machine_model",
    "sliding_surface",
]

#: Size of the sliding-surface state: s_prev (3), filtered sdot (3), started flag.
SLIDING_STATE = 7


#: Where the work of :func:`controller_work` holds the limb Jacobian at y[:3] after a
#: step (the model's kinematics at the measured pose, last evaluated there by every
#: built-in controller): the parts' ``limb_jacobian``, which the actuator then reuses.
MODEL_JACOBIAN = (0, JQ)


def controller_work(n_theta: int = 0) -> tuple:
    """Work of a model-based controller: (a dynamics workspace, M (3, 3), C v, G, G(X_d),
    Y (3, n_theta), s, Xr_dot, Xr_ddot (3,), and the machine model's scratch R (3, 3),
    Jq (4, 3), q (4,), Jdv (4,), zero (3,))."""
    e = np.empty
    return (make_work(), e((3, 3)), e(3), e(3), e(3), e((3, n_theta)), e(3), e(3), e(3),
            e((3, 3)), e((4, 3)), e(4), e(4), np.zeros(3))  # fmt: skip


def machine_model(ctx: PartContext) -> tuple[np.ndarray, float]:
    """The controllers' model of the machine (DESIGN.md §7) from the scenario's
    ``controller_model``: ([m_r (4), F_c (4), F_v (4), v_s] (13,), 1.0 if any is on else
    0.0). Nothing (zeros, 0.0) without a scenario: the paper's design."""
    mm = np.zeros(N_MACHINE_MODEL)
    mm[12] = 1e-3
    sc = getattr(ctx, "scenario", None)
    if sc is None:
        return mm, 0.0
    cm = sc.controller_model
    mm[0:4], mm[4:8], mm[8:12] = cm.machine_terms(sc.plant_spec.screw_lead)
    mm[12] = cm.friction_velocity
    return mm, 1.0 if np.any(mm[0:12] > 0) else 0.0


@kernel(inline="always", refcount=False)
def machine_force(p, X, Xd, v, a, work, F):
    """F += the machine model's rotor and friction terms, if the bundle ``p`` has them on."""
    if p.mach_on > 0.0:
        add_machine_model(p.geom, p.mach, X, Xd, v, a, work[9], work[10], work[11], work[12], F)


@kernel(inline="always", refcount=False)
def sliding_surface(lam, X, Xd, Xdes, Xddes, Xdddes, s, xr_d, xr_dd):
    """Fill s = edot + lam e, Xr_dot = Xdot_d + lam e, Xr_ddot = Xddot_d + lam edot (3,)."""
    for i in range(3):
        e = Xdes[i] - X[i]
        ed = Xddes[i] - Xd[i]
        s[i] = ed + lam[i] * e
        xr_d[i] = Xddes[i] + lam[i] * e
        xr_dd[i] = Xdddes[i] + lam[i] * ed


@kernel(inline="always", refcount=False)
def filter_sdot(state, s, Tc, alpha_f):
    """Advance the sdot estimate state[3:6] with the new s; state[0:3] <- s."""
    for i in range(3):
        raw = (s[i] - state[i]) / Tc if state[6] > 0.0 else 0.0
        state[3 + i] += alpha_f * (raw - state[3 + i])
        state[i] = s[i]
    state[6] = 1.0


def fuzzy_work(p, n_theta: int = 0) -> tuple:
    """Work of a fuzzy sliding-mode controller: :func:`controller_work` and, last (index
    :data:`FUZZY_WORK`), the work arrays of its fuzzy system ``p.flc``."""
    return controller_work(n_theta) + (term_work(p.flc),)


#: Index of the fuzzy system's work arrays in :func:`fuzzy_work`.
FUZZY_WORK = 14


@kernel(inline="always", refcount=False)
def fuzzy_term(flc, fwork, Ks, Ksd, Ku, s, sdot, F):
    """F -= K_u FLC(K_s s, K_sdot sdot), component by component (eq. 26); ``fwork`` is
    the fuzzy system's work (:func:`pkmctl.fuzzy.term.term_work`)."""
    for i in range(3):
        F[i] -= Ku[i] * term_eval(flc, fwork, Ks[i] * s[i], Ksd[i] * sdot[i])


@kernel(inline="always", refcount=False)
def _model_force(geom, theta, X, Xd, Xdes, work, F):
    """s, Xr and F = M^ Xr_ddot + C^ Xr_dot + G^(X_d) (eq. 25-26 write G at X_d)."""
    w, M, Cv, G, Gd, xr_d, xr_dd = work[0], work[1], work[2], work[3], work[4], work[7], work[8]
    gravity_kernel(geom, theta, Xdes, w, Gd)
    dynamics_kernel(geom, theta, X, Xd, xr_d, w, M, Cv, G)  # Cv holds C^ Xr_dot
    inverse_dynamics(M, Cv, Gd, xr_dd, F)


class SMCParams(NamedTuple):
    """SMC: the model's geometry (11,) and Theta^ (36,), Table 3's lam, K, Lam (3,), eps,
    T_c and the sdot filter's alpha = 1 / filter_periods."""

    geom: np.ndarray
    theta: np.ndarray
    lam: np.ndarray
    K: np.ndarray
    Lam: np.ndarray
    eps: float
    Tc: float
    alpha_f: float
    mach: np.ndarray
    mach_on: float

    @classmethod
    def from_context(cls, ctx: PartContext) -> SMCParams:
        g = ctx.gains
        return cls(ctx.model.geometry, ctx.model.theta, g.lam, g.K, g.Lam, float(g.eps),
                   float(ctx.period), 1.0 / g.filter_periods, *machine_model(ctx))  # fmt: skip


@kernel(refcount=False)
def smc_step(p, state, work, y, ref, F):
    """One period of eq. 25."""
    X, Xd = y[0:3], y[3:6]
    s, xr_d, xr_dd = work[6], work[7], work[8]
    sliding_surface(p.lam, X, Xd, ref[0:3], ref[3:6], ref[6:9], s, xr_d, xr_dd)
    filter_sdot(state, s, p.Tc, p.alpha_f)
    _model_force(p.geom, p.theta, X, Xd, ref[0:3], work, F)
    machine_force(p, X, Xd, xr_d, xr_dd, work, F)
    for i in range(3):
        F[i] += p.K[i] * s[i]
        F[i] += p.Lam[i] * min(1.0, max(-1.0, s[i] / p.eps))


class FSMCParams(NamedTuple):
    """FSMC: as :class:`SMCParams` with the FLC's scalings Ks, Ksd, Ku (3,) and its tables
    (``FISTables`` on the fast kernel, ``SystemTables`` on the general engine)."""

    geom: np.ndarray
    theta: np.ndarray
    lam: np.ndarray
    K: np.ndarray
    Ks: np.ndarray
    Ksd: np.ndarray
    Ku: np.ndarray
    Tc: float
    alpha_f: float
    flc: FISTables | SystemTables
    mach: np.ndarray
    mach_on: float

    @classmethod
    def from_context(cls, ctx: PartContext) -> FSMCParams:
        g = ctx.gains
        return cls(ctx.model.geometry, ctx.model.theta, g.lam, g.K, g.Ks, g.Ksd, g.Ku,
                   float(ctx.period), 1.0 / g.filter_periods, ctx.flc.compiled(),
                   *machine_model(ctx))  # fmt: skip


@kernel(refcount=False)
def fsmc_step(p, state, work, y, ref, F):
    """One period of eq. 26."""
    X, Xd = y[0:3], y[3:6]
    s, xr_d, xr_dd = work[6], work[7], work[8]
    sliding_surface(p.lam, X, Xd, ref[0:3], ref[3:6], ref[6:9], s, xr_d, xr_dd)
    filter_sdot(state, s, p.Tc, p.alpha_f)
    _model_force(p.geom, p.theta, X, Xd, ref[0:3], work, F)
    machine_force(p, X, Xd, xr_d, xr_dd, work, F)
    for i in range(3):
        F[i] += p.K[i] * s[i]
    fuzzy_term(p.flc, work[FUZZY_WORK], p.Ks, p.Ksd, p.Ku, s, state[3:6], F)


def smc_surface_gain(g, flc) -> np.ndarray:
    """Gain from s to F near s = 0 inside the boundary layer: K + Lambda / eps (3,)."""
    return g.K + g.Lam / g.eps


def fuzzy_surface_gain(g, flc) -> np.ndarray:
    """Gain from s to F near s = 0: K + K_u K_s |dFLC/ds*(0, 0)| (central difference) (3,)."""
    h = 1e-4
    slope = abs(flc(h, 0.0) - flc(-h, 0.0)) / (2 * h)
    return g.K + g.Ku * g.Ks * slope


builtin_part("controller", "smc", {"step": smc_step}, params=SMCParams, build=None,
             state_size=SLIDING_STATE, work=lambda p: controller_work(), label="SMC",
             limb_jacobian=MODEL_JACOBIAN,
             description="sliding mode control with a boundary layer (eq. 25)",
             surface_gain=smc_surface_gain)  # fmt: skip
builtin_part("controller", "fsmc", {"step": fsmc_step}, params=FSMCParams, build=None,
             state_size=SLIDING_STATE, work=fuzzy_work, label="FSMC",
             limb_jacobian=MODEL_JACOBIAN,
             description="fuzzy sliding mode control (eq. 26)",
             surface_gain=fuzzy_surface_gain)  # fmt: skip
