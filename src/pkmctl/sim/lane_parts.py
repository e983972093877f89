"""The built-in plant, sensor and actuator in lane form (:mod:`pkmctl.sim.lanes`): the
``rigid`` plant (all options of DESIGN.md §7), the ``ideal`` sensor and the ``ideal``
actuator for L runs at once, every array with a trailing lane dimension. Lane l computes
what the scalar function computes on lane l's numbers (tests/test_lanes.py). The
``encoder`` sensor and the ``drive`` actuator have no lane form: in a lane loop they run
lane by lane.
"""

from __future__ import annotations

import numpy as np

from pkmctl._jit import kernel
from pkmctl.model.lanes import (
    LANE_JQ,
    LANE_Q,
    LaneRigidPlant,
    lane_actuator_forces,
    lane_limb_jacobian,
    lane_rigid_derivative,
    make_lane_work,
)
from pkmctl.model.simd import flat_view
from pkmctl.parts import attach_lanes
from pkmctl.sim import actuators, plants, sensors  # noqa: F401  (the parts extended here)

__all__: list[str] = []


@kernel(refcount=False)
def lane_rigid_observe(p, x, tau, work, q, F):
    """q and J^T tau per lane from the kinematics the last derivative left in ``work``
    (:func:`pkmctl.sim.plants.rigid_observe`)."""
    Jq, qw = work[LANE_JQ], work[LANE_Q]
    L = x.shape[1]
    qf, qwf = flat_view(q), flat_view(qw)  # rows x lanes as one flat loop
    for m in range(qf.shape[0]):
        qf[m] = qwf[m]
    for i in range(3):
        for l in range(L):
            F[i, l] = (
                Jq[0, i, l] * tau[0, l]
                + Jq[1, i, l] * tau[1, l]
                + Jq[2, i, l] * tau[2, l]
                + (Jq[3, i, l] * tau[3, l])
            )


@kernel(refcount=False)
def lane_ideal_measure(p, state, work, x, y):
    """y = [X, Xdot] per lane."""
    yf, xf = flat_view(y), flat_view(x)  # rows 0-5 of x: the first 6 L elements
    for m in range(yf.shape[0]):
        yf[m] = xf[m]


@kernel(refcount=False)
def lane_ideal_command_at(p, state, work, y, F, Jq, cmd):
    """cmd = J (J^T J)^-1 F per lane, clipped to the lane's limit (if > 0)."""
    lane_actuator_forces(Jq, F, cmd)
    L = cmd.shape[1]
    for i in range(4):
        for l in range(L):
            lim = p.force_limit[l]
            c = cmd[i, l]
            cmd[i, l] = min(lim, max(-lim, c)) if lim > 0.0 else c


@kernel(refcount=False)
def lane_ideal_command(p, state, work, y, F, cmd):
    """:func:`lane_ideal_command_at` with the limb Jacobian computed here."""
    Jq, q = work[LANE_JQ], work[LANE_Q]
    lane_limb_jacobian(p.geom, y[0:3], work, Jq, q)
    lane_ideal_command_at(p, state, work, y, F, Jq, cmd)


@kernel(refcount=False)
def lane_ideal_force(p, state, cmd, tau):
    """The command reaches the plant unchanged, per lane."""
    tf, cf = flat_view(tau), flat_view(cmd)
    for m in range(tf.shape[0]):
        tf[m] = cf[m]


attach_lanes(
    "plant", "rigid", {"derivative": lane_rigid_derivative, "observe": lane_rigid_observe},
    lane_work=lambda p, L: make_lane_work(L), lane_params=LaneRigidPlant,
)  # fmt: skip
attach_lanes("sensor", "ideal", {"measure": lane_ideal_measure},
             lane_work=lambda p, L: (np.zeros(1),))  # fmt: skip
attach_lanes(
    "actuator", "ideal",
    {"command": lane_ideal_command, "command_at": lane_ideal_command_at,
     "force": lane_ideal_force},
    lane_work=lambda p, L: make_lane_work(L),
)  # fmt: skip
