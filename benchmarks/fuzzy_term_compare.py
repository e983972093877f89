"""The paper's FLC from compiled code and the FSMC/AFSMC loops, two commits side by side.

    python -m benchmarks.fuzzy_term_compare [--base COMMIT] [--head PATH] [--rounds N]

``--base`` (default HEAD~1) is exported with ``git archive`` into a temporary folder;
``--head`` is a source tree (default: this checkout, as it is on disk). Each round runs
both, alternating, each in its own interpreter with ``PYTHONPATH`` at its ``src``
(compiled code goes to the usual cache, one folder per source hash, so neither sees the
other's): the FLC over 10^6 random inputs from an njit loop (``flc_eval``; and
``term_eval``, what FSMC and AFSMC call, where the tree has it), best of 5, and 10 s of
the ``paper`` scenario per loop, best of 3. Prints every round and the range per tree.
Nothing here is a pass/fail test.
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

_RUN = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import numpy as np
import pkmctl
from benchmarks.fuzzy_bench import _loop
from benchmarks.timing import best_time
from pkmctl.fuzzy import FLC

flc = FLC()
tables = flc.compiled()
n = 10**6
rng = np.random.default_rng(0)  # the inputs of fuzzy_bench.run and fuzzy_bench.term_us
s, sdot = rng.uniform(-1.2, 1.2, n), rng.uniform(-12.0, 12.0, n)
_loop(tables, s[:10], sdot[:10])
out = {"flc_eval_us": best_time(lambda: _loop(tables, s, sdot), 5) / n * 1e6}
try:
    from benchmarks.fuzzy_bench import term_us
except ImportError:  # before the fuzzy term had its own entry point
    pass
else:
    out["term_eval_us"] = term_us(flc, n, repeats=5)[0]
for c in ("fsmc", "afsmc"):
    pkmctl.simulate("paper", controller=c, duration=0.01)  # compile, or load the cache
    best = min(pkmctl.simulate("paper", controller=c, duration=10.0).info["kernel_seconds"]
               for _ in range(3))
    out[f"{c}_steps_per_s"] = 200_000 / best
print(json.dumps(out))
"""


def _measure(tree: Path) -> dict:
    env = os.environ | {"PYTHONPATH": str(tree / "src")}
    done = subprocess.run(
        [sys.executable, "-c", _RUN, str(tree)], capture_output=True, text=True, env=env, cwd=tree
    )
    if done.returncode:
        sys.exit(f"{tree}: failed\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="HEAD~1", help="the commit before the change")
    parser.add_argument("--head", default=str(ROOT), help="the source tree with the change")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="pkmctl-fuzzy-term-") as tmp:
        base = Path(tmp) / "base"
        base.mkdir()
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", "--format=tar", args.base],
            capture_output=True,
            check=True,
        )
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive.stdout, check=True)
        trees = {f"base {args.base}": base, "head": Path(args.head)}
        rows: dict[str, list[dict]] = {name: [] for name in trees}
        for r in range(args.rounds):
            for name, tree in trees.items():  # alternate, so drift hits both
                rows[name].append(_measure(tree))
                print(r, name, json.dumps(rows[name][-1]), flush=True)
    for name, got in rows.items():
        ranges = {k: (min(g[k] for g in got), max(g[k] for g in got)) for k in got[0]}
        print(name, ", ".join(f"{k} {lo:.4g}-{hi:.4g}" for k, (lo, hi) in ranges.items()))


if __name__ == "__main__":
    main()
