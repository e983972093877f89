"""Controllers: SMC, FSMC, AFSMC, the baselines PD and CTC, their parts and classes.

Importing this package registers the built-in controller parts (DESIGN.md §3, §6).
"""

from pkmctl.control import adaptive, baselines, sliding  # noqa: F401  (registers the parts)
from pkmctl.control.adaptive import adapt
from pkmctl.control.base import (
    AFSMC,
    CONTROLLERS,
    CTC,
    FSMC,
    PD,
    SMC,
    Controller,
    ControllerState,
    make_controller,
)
from pkmctl.control.gains import BASELINE_GAINS, TABLE3, Gains
from pkmctl.control.sliding import sliding_surface

__all__ = [
    "AFSMC",
    "BASELINE_GAINS",
    "CONTROLLERS",
    "CTC",
    "FSMC",
    "PD",
    "SMC",
    "TABLE3",
    "Controller",
    "ControllerState",
    "Gains",
    "adapt",
    "make_controller",
    "sliding_surface",
]
