"""Baselines every comparison needs (DESIGN.md §6): PD plus gravity, and computed torque.

- ``pd``:  F = K_p e + K_d edot + G^(X) (+ J^T f^(J Xdot), the model's friction)
- ``ctc``: F = M^(X) a + C^(X, Xdot) Xdot + G^(X), a = Xddot_d + K_d edot + K_p e
  (+ J^T diag(m_r^) (J a + Jdot Xdot) + J^T f^(J Xdot), the model's rotors and friction)

with e = X_d - X at the measured (X, Xdot) and the controllers' model (Theta^). Default
gains: :data:`pkmctl.control.gains.BASELINE_GAINS` (and why). Stateless.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pkmctl._jit import kernel
from pkmctl.control.sliding import MODEL_JACOBIAN, controller_work, machine_force, machine_model
from pkmctl.model.dynamics import dynamics_kernel, gravity_kernel, inverse_dynamics
from pkmctl.parts import PartContext, builtin_part

__all__ = ["CTCParams", "PDParams"]


class PDParams(NamedTuple):
    """PD: the model's geometry (11,) and Theta^ (36,), K_p and K_d (3,)."""

    geom: np.ndarray
    theta: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    mach: np.ndarray
    mach_on: float

    @classmethod
    def from_context(cls, ctx: PartContext) -> PDParams:
        g = ctx.gains
        return cls(ctx.model.geometry, ctx.model.theta, g.pd_kp, g.pd_kd, *machine_model(ctx))


@kernel(refcount=False)
def pd_step(p, state, work, y, ref, F):
    """F = K_p e + K_d edot + G^(X)."""
    X = y[0:3]
    w, G = work[0], work[3]
    gravity_kernel(p.geom, p.theta, X, w, G)
    for i in range(3):
        F[i] = p.kp[i] * (ref[i] - X[i]) + p.kd[i] * (ref[3 + i] - y[3 + i]) + G[i]
    zero = work[13]
    machine_force(p, X, y[3:6], zero, zero, work, F)  # the friction only (zero v, a)


class CTCParams(NamedTuple):
    """Computed torque: the model's geometry (11,) and Theta^ (36,), K_p and K_d (3,)."""

    geom: np.ndarray
    theta: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    mach: np.ndarray
    mach_on: float

    @classmethod
    def from_context(cls, ctx: PartContext) -> CTCParams:
        g = ctx.gains
        return cls(ctx.model.geometry, ctx.model.theta, g.ctc_kp, g.ctc_kd, *machine_model(ctx))


@kernel(refcount=False)
def ctc_step(p, state, work, y, ref, F):
    """F = M^ (Xddot_d + K_d edot + K_p e) + C^ Xdot + G^."""
    X, Xd = y[0:3], y[3:6]
    w, M, Cv, G, a = work[0], work[1], work[2], work[3], work[8]
    dynamics_kernel(p.geom, p.theta, X, Xd, Xd, w, M, Cv, G)
    for i in range(3):
        a[i] = ref[6 + i] + p.kd[i] * (ref[3 + i] - Xd[i]) + p.kp[i] * (ref[i] - X[i])
    inverse_dynamics(M, Cv, G, a, F)
    machine_force(p, X, Xd, Xd, a, work, F)


builtin_part("controller", "pd", {"step": pd_step}, params=PDParams, build=None, state_size=0,
         work=lambda p: controller_work(), limb_jacobian=MODEL_JACOBIAN,
         description="PD in task space plus the model's gravity", label="PD",
         surface_gain=lambda g, flc: g.pd_kp / g.lam)  # fmt: skip
builtin_part("controller", "ctc", {"step": ctc_step}, params=CTCParams, build=None, state_size=0,
         work=lambda p: controller_work(), description="computed torque", label="CTC",
         limb_jacobian=MODEL_JACOBIAN)  # fmt: skip
