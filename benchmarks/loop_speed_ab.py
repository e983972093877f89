"""The compiled loop's steps per second at two commits, alternating, in one run.

    python benchmarks/loop_speed_ab.py [--base COMMIT] [--head COMMIT] [--rounds N]

Both commits are exported (``git archive``) into a temporary folder and imported from
there (``PYTHONPATH``) by fresh interpreters, alternately, so that the machine's load hits
both alike; their loops compile into the usual cache (one folder per source hash) on the
first round, which is not timed. Per round and commit: each case's ``kernel_seconds``,
best of 3 runs in that process. Prints steps per second per case (best over rounds) and
the ratio head / base. Lighter than ``compare_commits.py`` (no install, no
``reproduce``); like it, never a pass/fail test.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: (scenario, controller, seconds): the paper's 20 kHz loop, and the prototype's 1 kHz one.
CASES = (("paper", "smc", 2.0), ("paper", "afsmc", 2.0), ("paper", "pd", 2.0),
         ("prototype", "pd", 10.0))  # fmt: skip

_TIMER = r"""
import json, sys
import pkmctl
out = {}
for name, controller, seconds in json.loads(sys.argv[1]):
    pkmctl.simulate(name, controller=controller, duration=0.01)  # compile or load
    best = min(pkmctl.simulate(name, controller=controller, duration=seconds)
               .info["kernel_seconds"] for _ in range(3))
    sc = pkmctl.Scenario.builtin(name)
    out[f"{name}/{controller}"] = round(seconds / sc.timing.control_period) / best
print(json.dumps(out))
"""


def _export(commit: str, where: Path) -> Path:
    folder = where / commit.replace("/", "_")
    folder.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", commit],
                             capture_output=True, check=True)  # fmt: skip
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive.stdout, check=True)
    return folder / "src"


def _time(src: Path, cases=CASES) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(src))
    done = subprocess.run([sys.executable, "-c", _TIMER, json.dumps(cases)], capture_output=True,
                          text=True, env=env)  # fmt: skip
    if done.returncode != 0:
        sys.exit(f"timing {src} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="HEAD~1")
    ap.add_argument("--head", default="HEAD")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--cases", help="scenario:controller:seconds,... (default: CASES; a commit "
                    "older than the prototype scenario needs e.g. paper:afsmc:2)")  # fmt: skip
    args = ap.parse_args()
    cases = CASES
    if args.cases:
        cases = [(n, c, float(t)) for n, c, t in (x.split(":") for x in args.cases.split(","))]
    with tempfile.TemporaryDirectory(prefix="pkmctl-ab-") as tmp:
        trees = {c: _export(c, Path(tmp)) for c in (args.base, args.head)}
        for src in trees.values():
            _time(src, cases)  # compile (or load the cache): not timed
        best: dict[str, dict[str, float]] = {c: {} for c in trees}
        for _ in range(args.rounds):
            for c, src in trees.items():
                for case, rate in _time(src, cases).items():
                    best[c][case] = max(best[c].get(case, 0.0), rate)
    print(f"{'case':<18} {args.base:>14} {args.head:>14}  ratio (steps/s, best of {args.rounds})")
    for case in best[args.base]:
        a, b = best[args.base][case], best[args.head][case]
        print(f"{case:<18} {a:>14,.0f} {b:>14,.0f}  {b / a:.3f}")


if __name__ == "__main__":
    main()
