"""Sensors: what the controller sees of the plant (DESIGN.md §6). Built in: ``ideal``.

See :mod:`pkmctl.parts` for the contract.
"""

from __future__ import annotations

from pkmctl._jit import kernel
from pkmctl.parts import NoParams, builtin_part

__all__ = ["IdealSensor"]


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
