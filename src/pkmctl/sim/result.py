"""The result of one closed-loop run: the data and the parameters that produced it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pkmctl.sim.scenario import Scenario

__all__ = ["Result"]


@dataclass(frozen=True, eq=False)
class Result:
    """One closed-loop run, sampled at every control period (N samples).

    Carries its scenario and controller name. Arrays: ``t`` (N,); ``X``, ``Xdot``,
    ``X_desired``, ``Xdot_desired``, ``F`` (N, 3) (F: task-space force J^T tau applied
    by the actuators); ``q``, ``q_desired``, ``tau``, ``tau_desired`` (N, 4) (q the true
    limb lengths); ``disturbance`` (N, 3) the tau_d' acting over each period;
    ``X_measured``, ``Xdot_measured`` (N, 3) and ``q_measured`` (N, 4): what the sensor
    gave the controller; ``theta_hat`` (N, 36) for AFSMC, else None; ``logs`` any other
    per-period log of a part, by name. ``final_state`` maps each part kind ("plant",
    "sensor", "controller", "actuator") to its state array at the end; ``parts`` maps it
    to the part's name. ``success`` is False only for a partial result kept in a
    :class:`~pkmctl.SimulationDiverged`; ``message`` says why. ``info`` holds
    ``kernel_seconds`` (wall time of the compiled loop) and ``steps``.
    """

    scenario: Scenario
    controller: str
    t: np.ndarray
    X: np.ndarray
    Xdot: np.ndarray
    X_desired: np.ndarray
    Xdot_desired: np.ndarray
    q: np.ndarray
    q_desired: np.ndarray
    F: np.ndarray
    tau: np.ndarray
    tau_desired: np.ndarray
    disturbance: np.ndarray
    theta_hat: np.ndarray | None = None
    X_measured: np.ndarray | None = None
    Xdot_measured: np.ndarray | None = None
    q_measured: np.ndarray | None = None
    logs: dict = field(default_factory=dict)
    final_state: dict = field(default_factory=dict)
    parts: dict = field(default_factory=dict)
    success: bool = True
    message: str = "ok"
    info: dict = field(default_factory=dict)

    def rmse(self) -> dict[str, float]:
        """RMSE over all control samples (eq. 55-57): z in mm, angles in degrees, q in m."""
        from pkmctl.sim.metrics import rmse

        return rmse(self)

    def __repr__(self) -> str:
        return (
            f"Result(controller={self.controller!r}, scenario={self.scenario.name!r}, "
            f"N={self.t.size}, success={self.success})"
        )
