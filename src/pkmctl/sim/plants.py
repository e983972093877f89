"""Plants: what the loop integrates (DESIGN.md §6). Built in: ``rigid``, the closed form of §2,
and ``mujoco``, the same machine stepped in MuJoCo (§10, :mod:`pkmctl.sim.stepped`).

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
from pkmctl.parts import PartContext, PartError, builtin_part

__all__ = ["MujocoPlant", "RigidPlant"]


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


class MujocoPlant(NamedTuple):
    """The machine stepped in MuJoCo (DESIGN.md §10); geometry (11,) and Theta (36,) of the
    true plant, for ``observe``'s log of J(X)^T tau (the MuJoCo model is built from the
    same Mechanism, :mod:`pkmctl.plants.mujoco`)."""

    geom: np.ndarray
    theta: np.ndarray

    @classmethod
    def from_context(cls, ctx: PartContext) -> MujocoPlant:
        return cls(ctx.plant.geometry, ctx.plant.theta)


@kernel(refcount=False)
def mujoco_observe(p, x, tau, work, q, F):
    """q and J^T tau at X from the closed-form kinematics (the loop overwrites q with the
    lengths MuJoCo's slides give, which agree to 1e-15 m)."""
    w, M, C, G, f = work
    dynamics_kernel(p.geom, p.theta, x[0:3], x[3:6], x[3:6], w, M, C, G)
    for i in range(4):
        q[i] = w[Q][i]
    task_force(w[JQ], tau, F)


def _mujoco_stepper(p: MujocoPlant, ctx: PartContext, h: float):
    """A :class:`pkmctl.plants.mujoco.MujocoMachine` of the true plant at RK4 step h (s)."""
    try:
        from pkmctl.plants.mujoco import MujocoMachine
    except ImportError as exc:
        raise PartError(f"plant 'mujoco': {exc}") from None
    return MujocoMachine(ctx.plant, timestep=h)


builtin_part(
    "plant",
    "mujoco",
    {"observe": mujoco_observe},
    params=MujocoPlant,
    build=None,
    state_size=6,
    work=_rigid_work,
    stepper=_mujoco_stepper,
    description="the same machine in MuJoCo, RK4 at the loop's sub-step (DESIGN.md §10)",
)
