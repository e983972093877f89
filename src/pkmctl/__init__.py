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
    plants,  # the plants of other engines (pkmctl.plants.mujoco imports MuJoCo)
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

# These register the built-in parts. Under their own names, sim's plants hid the package
# pkmctl.plants, whose pkmctl.plants.mujoco_max_timestep was then missing (a tester).
from pkmctl.sim import actuators as _actuators  # noqa: F401
from pkmctl.sim import lane_parts as _lane_parts  # noqa: F401  (the lane forms)
from pkmctl.sim import metrics
from pkmctl.sim import plants as _sim_plants  # noqa: F401
from pkmctl.sim import sensors as _sensors  # noqa: F401
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
    "plants",
    "register_actuator",
    "register_controller",
    "register_plant",
    "register_sensor",
    "save_result",
    "simulate",
    "simulate_many",
]
__version__ = "0.2.4"
