"""Actuators: from the task-space command to the limb forces (DESIGN.md §6). Built in: ``ideal``.

See :mod:`pkmctl.parts` for the contract.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pkmctl._jit import kernel
from pkmctl.model.dynamics import actuator_forces_kernel
from pkmctl.model.kinematics import limb_jacobian
from pkmctl.parts import PartContext, builtin_part

__all__ = ["IdealActuator"]


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
def ideal_command(p, state, work, y, F, cmd):
    """cmd = J (J^T J)^-1 F at the measured pose y[:3] (eq. 22), clipped to the limit."""
    R, Jq, q = work
    limb_jacobian(p.geom, y[0:3], R, Jq, q)
    actuator_forces_kernel(Jq, F, cmd)
    if p.force_limit > 0.0:
        for i in range(4):
            cmd[i] = min(p.force_limit, max(-p.force_limit, cmd[i]))


@kernel(refcount=False)
def ideal_force(p, state, cmd, tau):
    """The command reaches the plant unchanged (zero-order hold)."""
    for i in range(4):
        tau[i] = cmd[i]


builtin_part(
    "actuator",
    "ideal",
    {"command": ideal_command, "force": ideal_force},
    params=IdealActuator,
    build=None,
    state_size=0,
    work=lambda p: (np.empty((3, 3)), np.empty((4, 3)), np.empty(4)),
    description="minimum-norm split at the measured pose, optional force limit",
)
