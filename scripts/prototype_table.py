"""The five controllers on the prototype scenarios (docs/machine.md): RMSE over the whole run
and after 1 s, peak limb force against the drives' 2160 N, share of periods at it, peak
true limb speed against 0.833 m/s and the time above it, chattering of tau_1..4 (N/s).

    PYTHONPATH=src python scripts/prototype_table.py [scenario ...] [--duration 10]
"""

from __future__ import annotations

import argparse
import math

import pkmctl
from pkmctl.sim.metrics import (
    chattering_index,
    limb_speed,
    peak_forces,
    rmse,
    time_at_force_limit,
    time_over_speed_limit,
)

CONTROLLERS = ("smc", "fsmc", "afsmc", "pd", "ctc")


def measure(scenario: pkmctl.Scenario, controller: str) -> dict:
    """The table's columns, from :mod:`pkmctl.sim.metrics` (over every control period,
    whatever ``logging.every`` the scenario has)."""
    r = pkmctl.simulate(scenario, controller=controller)
    lm = r.loop_metrics
    duration = lm.periods * lm.period
    speed = limb_speed(r)
    return {
        "rmse": rmse(r),
        "rmse1": rmse(r, t_from=1.0),
        "peak": float(peak_forces(r).max()),
        "limit": lm.force_limit,
        "at_limit": (time_at_force_limit(r) or 0.0) / duration,
        "speed": math.nan if speed is None else float(speed.max()),
        "vmax": lm.speed_limit,
        "over": time_over_speed_limit(r) or 0.0,
        "chat": chattering_index(r),
    }


def row(name: str, m: dict) -> str:
    e, e1 = m["rmse"], m["rmse1"]
    c = m["chat"]
    return (
        f"| {name} | {e['z_mm']:.3g} ({e1['z_mm']:.3g}) "
        f"| {e['alpha_deg']:.3g} ({e1['alpha_deg']:.3g}) "
        f"| {e['beta_deg']:.3g} ({e1['beta_deg']:.3g}) "
        f"| {m['peak']:.0f} | {100 * m['at_limit']:.2g} % | {m['speed']:.2f}, {m['over']:.3f} s "
        f"| {' / '.join(f'{x:.3g}' for x in c)} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenarios", nargs="*", default=["prototype"])
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--controllers", default=",".join(CONTROLLERS))
    args = ap.parse_args()
    if not args.duration > 1.0:  # the table's errors are after 1 s (a traceback before)
        ap.error(f"--duration = {args.duration:g}: must be > 1 s (the errors after 1 s)")
    for name in args.scenarios:
        sc = pkmctl.Scenario.builtin(name).replace(**{"timing.duration": args.duration})
        print(f"\n{name}, {args.duration:g} s\n")
        print("| controller | z (mm) | α (deg) | β (deg) | peak force (N) | at limit "
              "| peak speed (m/s), time over | chattering (N/s) |")  # fmt: skip
        print("|---|---|---|---|---|---|---|---|")
        for c in args.controllers.split(","):
            try:
                print(row(c.upper(), measure(sc, c)), flush=True)
            except pkmctl.SimulationDiverged as exc:
                print(f"| {c.upper()} | diverged: {exc} |", flush=True)


if __name__ == "__main__":
    main()
