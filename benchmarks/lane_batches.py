"""Many runs as users and campaigns make them: ``simulate_many`` of n seeds and a task of
the ``paper-claims`` campaign, wall time, one thread.

    PYTHONPATH=. python benchmarks/lane_batches.py [--seeds 3,6,10,16] [--seconds 1]
        [--controllers smc,fsmc,afsmc,pd,ctc] [--rounds 3] [--json FILE]

Per controller: ``simulate_many("paper", c, seeds=1..n, keep="metrics", workers=1)`` for
each n, in lanes as pkmctl batches them (``lane_batches``: full batches, a rest of more
than half a batch padded to full width, a smaller rest one at a time) and one at a time
(``lanes=1``), alternating, best of ``rounds``; then ``run_task`` of the campaign's first
task of that controller (its 4.2 s runs), best of ``rounds``. To compare two commits, run
it with ``PYTHONPATH=<checkout>/src`` of each, one after the other (each loads its own
compiled cache). Timing is never a pass/fail test.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from benchmarks.lanes_speed import _cpu
from benchmarks.timing import best_time


def measure(controller: str, seeds: list[int], seconds: float, rounds: int) -> dict:
    """Best wall seconds of simulate_many in lanes and one at a time, per n, and of a task."""
    import pkmctl
    from pkmctl.campaign import CampaignSpec
    from pkmctl.campaign.execute import run_task
    from pkmctl.sim.simulate import simulate_many

    def many(n: int, lanes: int | None) -> None:
        simulate_many("paper", controller, seeds=list(range(1, n + 1)), duration=seconds,
                      keep="metrics", workers=1, lanes=lanes)  # fmt: skip

    out: dict = {}
    for n in seeds:
        many(n, None), many(n, 1)  # compile or load both loops
        lanes = best_time(lambda n=n: many(n, None), rounds)
        one = best_time(lambda n=n: many(n, 1), rounds)
        out[f"{n} seeds"] = {"lanes_s": lanes, "single_s": one, "ratio": one / lanes}
    spec_file = Path(pkmctl.__file__).parent / "campaign" / "specs" / "paper-claims.toml"
    spec = CampaignSpec.from_toml(spec_file.read_text(encoding="utf-8"))
    task = next(t for t in spec.tasks() if t.runs[0].controller == controller)
    run_task(spec, task)
    out["task"] = {"runs": len(task.runs), "s": best_time(lambda: run_task(spec, task), rounds)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="3,6,10,16")
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--controllers", default="smc,fsmc,afsmc,pd,ctc")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    seeds = [int(s) for s in a.seeds.split(",")]
    print(f"machine: {_cpu()}; paper, {a.seconds:g} s runs, metrics only, one thread")
    print(f"{'controller':<10} {'seeds':>5} {'lanes s':>8} {'one by one s':>13} {'ratio':>6}")
    res = {"machine": _cpu(), "seconds": a.seconds, "cases": {}}
    for c in a.controllers.split(","):
        m = measure(c, seeds, a.seconds, a.rounds)
        res["cases"][c] = m
        for n in seeds:
            r = m[f"{n} seeds"]
            print(f"{c:<10} {n:>5} {r['lanes_s']:>8.3f} {r['single_s']:>13.3f} {r['ratio']:>6.2f}")
        print(f"{c:<10} a paper-claims task of {m['task']['runs']} runs: {m['task']['s']:.3f} s")
        sys.stdout.flush()
    if a.json:
        with open(a.json, "w", encoding="utf-8") as fh:
            json.dump(res, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
