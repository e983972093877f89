"""pkmctl: model, control and simulate the 2RPU-2SPR redundantly actuated parallel manipulator."""

from .errors import ConvergenceError, InvalidPoseError, PkmctlError, SimulationDiverged
from .mechanism import Body, Mechanism

__all__ = [
    "Body",
    "ConvergenceError",
    "InvalidPoseError",
    "Mechanism",
    "PkmctlError",
    "SimulationDiverged",
]
__version__ = "0.1.0"
