"""Throughput per core of the lane loop against the single-run loop, side by side.

    PYTHONPATH=. python benchmarks/lanes_speed.py [--seconds S] [--lanes L] [--rounds N]
        [--controllers smc,fsmc,afsmc,pd,ctc] [--scenario paper] [--metrics-only] [--json FILE]

Per controller on the scenario (default ``paper``): L runs (seeds 1..L) one after another in the
single loop (``simulate_many(lanes=1, workers=1)``), then the same L runs in one lane
loop (``lanes=L, workers=1``), alternating, ``rounds`` times; each side's time is the sum
of its runs' compiled-loop times (``kernel_seconds``), best over the rounds. One thread:
the ratio is throughput per core. On a machine whose speed drifts between rounds, the
median of the rounds' own ratios (each round's lane loop against the single runs just
before and just after it) is the steadier number; both are printed. Also checks that
the two sides agree (max relative difference of X and tau over the runs). Never a
pass/fail test: prints a table. A lane loop computes a multiple of the machine's SIMD
width (``padded_lanes``), so ``--lanes 4`` on an AVX-512 machine times 4 runs in a loop
of 8 lanes, as ``simulate_many`` would run a batch of 4 with ``lanes=4``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys

import numpy as np


def _cpu() -> str:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


def measure(
    controller: str, seconds: float, lanes: int, rounds: int, scenario: str, only: bool = False
) -> dict:
    """Best kernel seconds of L single runs and of one lane loop of L, and their gap;
    ``only``: runs that log t = 0 alone (``metrics_only``, as campaign tasks), compared by
    their final states and accumulated squared errors instead of their logs."""
    from pkmctl.sim.scenario import Scenario
    from pkmctl.sim.simulate import metrics_only, simulate_many

    seeds = list(range(1, lanes + 1))
    sc = Scenario.builtin(scenario, seconds)
    sc = metrics_only(sc) if only else sc

    def side(n: int):
        res = simulate_many(sc, controller, seeds=seeds, lanes=n, workers=1)
        return sum(r.info["kernel_seconds"] for r in res), res

    def rel(a, b) -> float:
        if only:
            sa, sb = a.loop_metrics.sum_squared_error, b.loop_metrics.sum_squared_error
            return max(_rel(a.final_state["plant"], b.final_state["plant"]), _rel(sa, sb))
        return max(_rel(a.X, b.X), _rel(a.tau, b.tau))

    side(1), side(lanes)  # compile or load both loops
    gap = 0.0
    t1, r1 = side(1)
    singles, lane_loops, ratios = [t1], [], []
    for _ in range(rounds):
        tL, rL = side(lanes)
        t1, r1 = side(1)
        lane_loops.append(tL)
        ratios.append(0.5 * (singles[-1] + t1) / tL)
        singles.append(t1)
        for a, b in zip(rL, r1, strict=True):
            gap = max(gap, rel(a, b))
    best1, bestL = min(singles), min(lane_loops)
    return {"single_s": best1, "lanes_s": bestL, "ratio": best1 / bestL,
            "median_ratio": float(np.median(ratios)), "max_rel_diff": gap}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    from pkmctl.sim.lanes import lane_count

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--lanes", type=int, default=lane_count())
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--controllers", default="smc,fsmc,afsmc,pd,ctc")
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--metrics-only", action="store_true",
                    help="runs that log t = 0 alone, as campaign tasks")  # fmt: skip
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    out = {"machine": _cpu(), "lanes": a.lanes, "seconds": a.seconds, "scenario": a.scenario,
           "metrics_only": a.metrics_only, "cases": {}}  # fmt: skip
    what = ", metrics only (a log of t = 0)" if a.metrics_only else ""
    print(f"machine: {out['machine']}; {a.lanes} lanes; {a.scenario}, {a.seconds:g} s runs{what}")
    print(f"{'controller':<10} {'L single runs s':>16} {'one lane loop s':>16} {'ratio':>7} "
          f"{'median':>7} {'max rel diff':>13}")  # fmt: skip
    for c in a.controllers.split(","):
        m = measure(c, a.seconds, a.lanes, a.rounds, a.scenario, a.metrics_only)
        out["cases"][c] = m
        print(f"{c:<10} {m['single_s']:>16.3f} {m['lanes_s']:>16.3f} {m['ratio']:>7.2f} "
              f"{m['median_ratio']:>7.2f} {m['max_rel_diff']:>13.2e}")  # fmt: skip
        sys.stdout.flush()
    if a.json:
        with open(a.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
