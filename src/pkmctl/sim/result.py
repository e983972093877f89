"""The result of one closed-loop run: the data and the parameters that produced it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from pkmctl.sim.metrics import LoopMetrics
from pkmctl.sim.scenario import Scenario

if TYPE_CHECKING:
    import pyarrow as pa
    from matplotlib.figure import Figure

__all__ = ["Result"]


@dataclass(frozen=True, eq=False)
class Result:
    """One closed-loop run, sampled every ``logging.every`` control periods (N samples:
    t = 0, every T_c, 2 every T_c, ...; every period by default).

    Carries its scenario and controller name. Arrays: ``t`` (N,); ``X``, ``Xdot``,
    ``X_desired``, ``Xdot_desired``, ``F`` (N, 3) (F: task-space force J^T tau applied
    by the actuators); ``q``, ``q_desired``, ``tau``, ``tau_desired`` (N, 4) (q the true
    limb lengths); ``disturbance`` (N, 3) the tau_d' acting over each period;
    ``X_measured``, ``Xdot_measured`` (N, 3) and ``q_measured`` (N, 4): what the sensor
    gave the controller (the true arrays where none are given); ``theta_hat`` (N, 36)
    for AFSMC, (N, 48) for afsmc-ext, else None; ``logs`` any other per-period log of a
    part, by name. ``final_state`` maps each part kind ("plant",
    "sensor", "controller", "actuator") to its state array at the end; ``parts`` maps it
    to the part's name. ``success`` is False only for a partial result kept in a
    :class:`~pkmctl.SimulationDiverged`; ``message`` says why. ``info`` holds
    ``kernel_seconds`` (wall time of the compiled loop), ``steps`` (control periods
    run) and ``software`` (:func:`pkmctl.io.results.provenance` of the pkmctl that ran
    it; a loaded result's is what its JSON says, None before 0.2.0). ``loop_metrics``:
    the metrics the loop accumulated over every period
    (:class:`pkmctl.sim.metrics.LoopMetrics`; what :mod:`pkmctl.sim.metrics` reports when
    the log is decimated).
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
    # arrays always (DESIGN.md §11): None given means the truth (__post_init__), as
    # load_result reads a file that did not save them
    X_measured: np.ndarray = None  # type: ignore[assignment]
    Xdot_measured: np.ndarray = None  # type: ignore[assignment]
    q_measured: np.ndarray = None  # type: ignore[assignment]
    logs: dict[str, np.ndarray] = field(default_factory=dict)
    final_state: dict[str, np.ndarray] = field(default_factory=dict)
    parts: dict[str, str] = field(default_factory=dict)
    success: bool = True
    message: str = "ok"
    info: dict[str, Any] = field(default_factory=dict)
    loop_metrics: LoopMetrics | None = None

    def __post_init__(self) -> None:
        for name in ("X_measured", "Xdot_measured", "q_measured"):
            if getattr(self, name) is None:  # a sensor that saw the truth
                object.__setattr__(self, name, getattr(self, name.removesuffix("_measured")))
        if "software" not in self.info:  # what made the run (a loaded result has its own)
            from pkmctl.io.results import provenance

            self.info["software"] = provenance()

    @property
    def every(self) -> int:
        """Control periods per logged sample (the scenario's ``logging.every``)."""
        return int(self.scenario.logging.every)

    def to_arrow(self) -> pa.Table:
        """The time series as a pyarrow Table, the columns ``save_result`` writes (their
        names and meaning: docs/architecture.md), without a file:
        ``result.to_arrow().to_pandas()``, ``polars.from_arrow(result.to_arrow())``. A
        notebook had to write Parquet and read it back (a tester)."""
        import pyarrow as pa

        from pkmctl.io.results import _columns

        names, columns = _columns(self)
        return pa.table(columns, names=names)

    def rmse(self) -> dict[str, float]:
        """RMSE over all control samples (eq. 55-57): z in mm, angles in degrees, q in m."""
        from pkmctl.sim.metrics import rmse

        return rmse(self)

    def plot(self, figure: int | str = "z", *, dpi: float = 110) -> Figure:
        """One of the paper's figures 10-26 for this run, as ``pkmctl reproduce`` draws
        it (:func:`pkmctl.report.draw_figure`, which also puts several runs in one).

        Parameters
        ----------
        figure : int or str
            The figure's number (10-26) or its name: "z", "alpha", "beta", "q1"-"q4"
            (tracking), "z error", ... (errors), "z box", ... (box plots), "tau1"-"tau4"
            (forces); :func:`pkmctl.report.figure_names` lists them.
        dpi : float, keyword-only
            The figure's resolution (``reproduce``'s, 110, by default).

        Returns
        -------
        matplotlib.figure.Figure
            Not through pyplot (no global state): ``fig.savefig(path)`` writes it.
        """
        from pkmctl.report.figures import draw_figure

        return draw_figure(self, figure, dpi=dpi)

    def __repr__(self) -> str:
        every = f", every={self.every}" if self.every > 1 else ""
        return (
            f"Result(controller={self.controller!r}, scenario={self.scenario.name!r}, "
            f"N={self.t.size}{every}, success={self.success})"
        )
