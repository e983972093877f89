"""Actuators: from the task-space command to the limb forces (DESIGN.md §6). Built in:
``ideal`` and ``drive`` (the servo drives on ball screws of §7).

See :mod:`pkmctl.parts` for the contract.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pkmctl._jit import kernel
from pkmctl.model.dynamics import actuator_forces_kernel
from pkmctl.model.kinematics import limb_jacobian
from pkmctl.parts import PartContext, builtin_part

__all__ = ["DriveActuator", "IdealActuator", "drive_actuator"]


class IdealActuator(NamedTuple):
    """Minimum-norm split at the measured pose, held over the period, optionally clipped.

    ``geom`` (11,) the controllers' geometry; ``force_limit`` (N) per limb, <= 0: none.
    """

    geom: np.ndarray
    force_limit: float

    @classmethod
    def from_context(cls, ctx: PartContext) -> IdealActuator:
        limit = None if ctx.scenario is None else ctx.scenario.actuators.force_limit
        return cls(ctx.model.geometry, -1.0 if limit is None else float(limit))


@kernel(refcount=False)
def ideal_command_at(p, state, work, y, F, Jq, cmd):
    """cmd = J (J^T J)^-1 F with J = Jq, the limb Jacobian at the measured pose y[:3]
    (eq. 22), clipped to the limit."""
    actuator_forces_kernel(Jq, F, cmd)
    if p.force_limit > 0.0:
        for i in range(4):
            cmd[i] = min(p.force_limit, max(-p.force_limit, cmd[i]))


@kernel(refcount=False)
def ideal_command(p, state, work, y, F, cmd):
    """:func:`ideal_command_at` with the limb Jacobian computed here."""
    R, Jq, q = work
    limb_jacobian(p.geom, y[0:3], R, Jq, q)
    ideal_command_at(p, state, work, y, F, Jq, cmd)


@kernel(refcount=False)
def ideal_force(p, state, cmd, tau):
    """The command reaches the plant unchanged (zero-order hold)."""
    for i in range(4):
        tau[i] = cmd[i]


builtin_part(
    "actuator",
    "ideal",
    {"command": ideal_command, "command_at": ideal_command_at, "force": ideal_force},
    params=IdealActuator,
    build=None,
    state_size=0,
    work=lambda p: (np.empty((3, 3)), np.empty((4, 3)), np.empty(4)),
    limits=lambda p: (p.force_limit if p.force_limit > 0 else math.inf, math.inf),
    description="minimum-norm split at the measured pose, optional force limit",
)


# ------------------------------------------------------------------ the drive (DESIGN.md §7)
#: Drive state: the torque reaching the screw T (4, the continuous state, N m), the command
#: held for the delay (4), periods with a measured limb speed over the limit, the largest
#: measured limb speed (m/s).
DRIVE_STATE = 10


class DriveActuator(NamedTuple):
    """A servo drive in torque mode on a ball screw, one per limb (DESIGN.md §7).

    ``geom`` (11,) the controllers' geometry (the split is at the measured pose);
    ``gain`` = 2 pi eta / l (N per N m), f = gain T; ``peak_torque`` (N m, inf: none);
    ``lag`` tau_d (s) of the first-order torque lag, 0: none; ``max_speed`` (m/s at the
    limb: rpm / 60 * l), counted, not enforced; ``delay`` 1.0: the command computed from
    the sample at t_k acts from t_k+1 (a computation delay of one period), else 0.0.
    """

    geom: np.ndarray
    gain: float
    peak_torque: float
    lag: float
    max_speed: float
    delay: float

    @classmethod
    def from_context(cls, ctx: PartContext) -> DriveActuator:
        sc = ctx.scenario
        if sc is None:
            from pkmctl.sim.scenario import ActuatorSpec, PlantSpec

            act, lead = ActuatorSpec(), PlantSpec().screw_lead
        else:
            act, lead = sc.actuators, sc.plant_spec.screw_lead
        return drive_actuator(
            ctx.model,
            screw_lead=lead,
            efficiency=act.efficiency,
            peak_torque=act.peak_torque,
            lag=act.lag,
            max_speed_rpm=act.max_speed,
            delay_periods=act.delay_periods,
        )


def drive_actuator(
    model,
    *,
    screw_lead: float = 0.01,
    efficiency: float = 0.9,
    peak_torque: float = 3.82,
    lag: float = 2e-4,
    max_speed_rpm: float = 5000.0,
    delay_periods: int = 0,
) -> DriveActuator:
    """The ``drive`` bundle from the controllers' :class:`~pkmctl.Mechanism` and the drive's
    numbers (m, -, N m, s, rpm, periods); ``peak_torque=math.inf`` removes the clipping."""
    return DriveActuator(
        model.geometry,
        2.0 * math.pi * float(efficiency) / float(screw_lead),
        float(peak_torque),
        float(lag),
        float(max_speed_rpm) / 60.0 * float(screw_lead),
        1.0 if delay_periods else 0.0,
    )


@kernel(refcount=False)
def drive_command(p, state, work, y, F, cmd):
    """:func:`drive_command_at` with the limb Jacobian computed here."""
    R, Jq, q, _ = work
    limb_jacobian(p.geom, y[0:3], R, Jq, q)
    drive_command_at(p, state, work, y, F, Jq, cmd)


@kernel(refcount=False)
def drive_command_at(p, state, work, y, F, Jq, cmd):
    """Torque commands cmd (4,) N m: the split J (J^T J)^-1 F at the measured pose (eq. 22)
    with J = Jq, T = f / gain clipped at the peak torque, held one period if delayed;
    counts the periods whose measured limb speed |J Xdot^| exceeds the limit."""
    f = work[3]
    actuator_forces_kernel(Jq, F, f)
    over = 0.0
    for i in range(4):
        qd = abs(Jq[i, 0] * y[3] + Jq[i, 1] * y[4] + Jq[i, 2] * y[5])
        if qd > p.max_speed:
            over = 1.0
        state[9] = max(state[9], qd)
    state[8] += over
    for i in range(4):
        T = min(p.peak_torque, max(-p.peak_torque, f[i] / p.gain))
        if p.delay > 0.0:
            cmd[i] = state[4 + i]
            state[4 + i] = T
        else:
            cmd[i] = T


@kernel(refcount=False)
def drive_force(p, state, cmd, tau):
    """Limb forces tau = 2 pi eta T / l (4,), T the lagged torque (or the command if no lag)."""
    for i in range(4):
        tau[i] = p.gain * (state[i] if p.lag > 0.0 else cmd[i])


@kernel(refcount=False)
def drive_derivative(p, state, cmd, dstate):
    """dT/dt = (T_cmd - T) / tau_d: the first-order torque lag, integrated with the plant."""
    for i in range(4):
        dstate[i] = (cmd[i] - state[i]) / p.lag if p.lag > 0.0 else 0.0


def _drive_report(p: DriveActuator, state: np.ndarray) -> dict:
    return {
        "speed_violations": int(state[8]),
        "peak_measured_limb_speed": float(state[9]),
        "speed_limit": p.max_speed,
    }


builtin_part(
    "actuator",
    "drive",
    {
        "command": drive_command,
        "command_at": drive_command_at,
        "force": drive_force,
        "derivative": drive_derivative,
    },
    params=DriveActuator,
    build=None,
    state_size=DRIVE_STATE,
    continuous=4,
    work=lambda p: (np.empty((3, 3)), np.empty((4, 3)), np.empty(4), np.empty(4)),
    report=_drive_report,
    limits=lambda p: (p.gain * p.peak_torque, p.max_speed),  # peak force, maximum limb speed
    description="servo drives on ball screws: split, f = 2 pi eta T / l, peak torque, lag",
)
