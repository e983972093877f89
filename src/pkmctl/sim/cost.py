"""What a run costs, estimated before it runs: a campaign's "estimated ..." and the
warning `pkmctl simulate` gives before a long run.

A control period costs :data:`PERIOD` of its loop (in SIMD lanes, one run alone, or a
plant stepped from Python), each RK4 sub-step of the plant beyond the first
:data:`SUBSTEP` (:data:`DRIVE` times that with drives, whose lag is a state the sub-steps
integrate), and the encoder's pose by forward kinematics :data:`ENCODER`; a run costs
:data:`RUN` outside its loop. The period's cost at one sub-step was measured on the
shared 2-core Zen 4 development machine (2026-12-07, `paper`): in lanes (8 there)
0.38-0.59 µs by controller, alone PD 1.2, SMC 1.3, AFSMC 1.7 µs, MuJoCo's plant stepped
from Python 64-73 µs. The rest on the 2-vCPU Xeon (2026-12-07, PD and AFSMC, 1-100
sub-steps): a sub-step 0.24 µs in lanes and 0.49 µs alone on `paper`, 0.34 and 0.6 µs on
`prototype` (drives, friction); the encoder 0.6 µs a period in lanes, about 6 µs alone;
MuJoCo's RK4 step 26 µs. The campaign estimate ignored the sub-steps and the machine's
parts: a spec of 1000 sub-steps read "0.0 s" and took 9.8 s (a tester).
"""

from __future__ import annotations

from typing import Any

__all__ = ["DRIVE", "ENCODER", "PERIOD", "RUN", "SUBSTEP", "period_seconds", "run_seconds"]

#: A control period at one RK4 sub-step (s), by loop.
PERIOD = {"lanes": 0.6e-6, "single": 2e-6, "stepped": 70e-6}
#: Each further RK4 sub-step of the plant (s), by loop.
SUBSTEP = {"lanes": 0.25e-6, "single": 0.5e-6, "stepped": 26e-6}
#: A sub-step's cost with drives (``actuators.kind = "drive"``), as a multiple.
DRIVE = 1.4
#: The encoder's pose by forward kinematics (``sensor.kind = "encoder"``), a period (s).
ENCODER = {"lanes": 0.6e-6, "single": 6e-6, "stepped": 6e-6}
#: A run outside its loop (prepare, build, metrics; s): in lanes next to nothing (1600
#: runs of 0.2 s in 8 lanes took 2.8 s on one worker, 1.75 ms a run with the loop),
#: alone 3-5 ms (docs/campaigns.md, "cost outside the loop").
RUN = {"lanes": 2e-4, "single": 4e-3, "stepped": 4e-3}


def period_seconds(parts: dict[str, Any], substeps: int, loop: str) -> float:
    """Estimated seconds of one control period of one run of ``parts`` (the resolved
    parts by kind) at ``substeps`` RK4 sub-steps, in ``loop`` ("lanes", "single" or
    "stepped"); lanes at 8 a batch (fewer cost more, 8 / L times: the caller's)."""
    drive = DRIVE if parts["actuator"].name == "drive" else 1.0
    encoder = ENCODER[loop] if parts["sensor"].name == "encoder" else 0.0
    return PERIOD[loop] + (int(substeps) - 1) * SUBSTEP[loop] * drive + encoder


def run_seconds(scenario: Any, parts: dict[str, Any], loop: str = "single") -> float:
    """Estimated seconds of one run of ``scenario`` with ``parts``, compiled already."""
    t = scenario.timing
    periods = round(t.duration / t.control_period)
    return periods * period_seconds(parts, t.substeps, loop) + RUN[loop]
