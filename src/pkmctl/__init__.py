"""pkmctl: model, control and simulate the 2RPU-2SPR redundantly actuated parallel manipulator.

The public interface of DESIGN.md §5::

    robot = pkmctl.Mechanism.paper()
    scenario = pkmctl.Scenario.builtin("paper")
    result = pkmctl.simulate(scenario, controller="afsmc")
    flc = pkmctl.fuzzy.FLC()
"""

from . import fuzzy, metrics
from .controllers import AFSMC, CONTROLLERS, FSMC, SMC, Controller, Gains, make_controller
from .errors import ConvergenceError, InvalidPoseError, PkmctlError, SimulationDiverged
from .mechanism import Body, Mechanism
from .scenario import Scenario, ScenarioError
from .simulation import Result, simulate

__all__ = [
    "AFSMC",
    "CONTROLLERS",
    "FSMC",
    "SMC",
    "Body",
    "Controller",
    "ConvergenceError",
    "Gains",
    "InvalidPoseError",
    "Mechanism",
    "PkmctlError",
    "Result",
    "Scenario",
    "ScenarioError",
    "SimulationDiverged",
    "fuzzy",
    "make_controller",
    "metrics",
    "simulate",
]
__version__ = "0.1.0"
