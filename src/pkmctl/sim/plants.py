"""Plants: what the loop integrates (DESIGN.md §6). Built in: ``rigid``, the closed form of §2.

A plant's state starts with [X (3), Xdot (3)] (the task-space pose and its rate);
the sensor reads it there. See :mod:`pkmctl.parts` for the contract.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pkmctl._jit import kernel
from pkmctl.model.dynamics import (
    JQ,
    Q,
    dynamics_kernel,
    forward_dynamics,
    make_work,
    task_force,
)
from pkmctl.parts import PartContext, builtin_part

__all__ = ["RigidPlant"]


def _rigid_work(p) -> tuple:
    """(the dynamics workspace, M (3, 3), C Xdot, G, f (3,))."""
    return make_work(), np.empty((3, 3)), np.empty(3), np.empty(3), np.empty(3)


class RigidPlant(NamedTuple):
    """The rigid closed-form machine: geometry (11,) and Theta (36,) of the true plant."""

    geom: np.ndarray
    theta: np.ndarray

    @classmethod
    def from_context(cls, ctx: PartContext) -> RigidPlant:
        return cls(ctx.plant.geometry, ctx.plant.theta)


@kernel(refcount=False)
def rigid_derivative(p, x, tau, dist, work, dx):
    """dx = [Xdot, M^-1 (J^T tau + tau_d' - C Xdot - G)] (eq. 24)."""
    w, M, C, G, f = work
    X, Xd = x[0:3], x[3:6]
    dynamics_kernel(p.geom, p.theta, X, Xd, Xd, w, M, C, G)  # C holds C Xdot
    Jq = w[JQ]
    for i in range(3):
        f[i] = Jq[0, i] * tau[0] + Jq[1, i] * tau[1] + Jq[2, i] * tau[2] + Jq[3, i] * tau[3]
        f[i] += dist[i]
        dx[i] = Xd[i]
    forward_dynamics(M, C, G, f, dx[3:6])


@kernel(refcount=False)
def rigid_observe(p, x, tau, work, q, F):
    """q and J^T tau from the kinematics the last derivative left in ``work``."""
    w = work[0]
    for i in range(4):
        q[i] = w[Q][i]
    task_force(w[JQ], tau, F)


builtin_part(
    "plant",
    "rigid",
    {"derivative": rigid_derivative, "observe": rigid_observe},
    params=RigidPlant,
    build=None,
    state_size=6,
    work=_rigid_work,
    description="the closed-form rigid machine of DESIGN.md §2",
)
