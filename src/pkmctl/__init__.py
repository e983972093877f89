"""pkmctl: model, control and simulate the 2RPU-2SPR redundantly actuated parallel manipulator.

The public interface of DESIGN.md §5 and §11::

    robot = pkmctl.Mechanism.paper()
    scenario = pkmctl.Scenario.builtin("paper")
    result = pkmctl.simulate(scenario, controller="afsmc")   # or smc, fsmc, pd, ctc, yours
    flc = pkmctl.fuzzy.FLC()

Parts of the loop (controllers, sensors, actuators, plants) are added with
:func:`register_controller` and its siblings (docs/parts.md).
"""

from pkmctl import (
    _start,  # noqa: F401  (first: a quiet Ctrl-C while importing)
    fuzzy,
)
from pkmctl.control import (
    AFSMC,
    CONTROLLERS,
    CTC,
    FSMC,
    PD,
    SMC,
    Controller,
    Gains,
    make_controller,
)
from pkmctl.control import lanes as _control_lanes  # noqa: F401, I001
from pkmctl.errors import ConvergenceError, InvalidPoseError, PkmctlError, SimulationDiverged
from pkmctl.io.results import load_result, save_result
from pkmctl.model.mechanism import Body, Mechanism
from pkmctl.parts import (
    PartContext,
    PartError,
    register_actuator,
    register_controller,
    register_plant,
    register_sensor,
)
from pkmctl.sim import (  # noqa: F401  (registers parts)
    actuators,
    lane_parts,  # their lane forms (pkmctl.sim.lanes)
    metrics,
    plants,
    sensors,
)
from pkmctl.sim.result import Result
from pkmctl.sim.scenario import Scenario, ScenarioError
from pkmctl.sim.simulate import simulate, simulate_many

__all__ = [
    "AFSMC",
    "CONTROLLERS",
    "CTC",
    "FSMC",
    "PD",
    "SMC",
    "Body",
    "Controller",
    "ConvergenceError",
    "Gains",
    "InvalidPoseError",
    "Mechanism",
    "PartContext",
    "PartError",
    "PkmctlError",
    "Result",
    "Scenario",
    "ScenarioError",
    "SimulationDiverged",
    "fuzzy",
    "load_result",
    "make_controller",
    "metrics",
    "register_actuator",
    "register_controller",
    "register_plant",
    "register_sensor",
    "save_result",
    "simulate",
    "simulate_many",
]
__version__ = "0.2.2"
