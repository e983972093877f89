"""What a first lane run costs: compiling from an empty cache, per lane count.

    PYTHONPATH=. python benchmarks/lanes_compile.py [--controller afsmc] [--scenario paper]
        [--lanes 8] [--rest 3]

In a fresh interpreter with an empty cache folder (``PKMCTL_CACHE_DIR`` set to a new
temporary folder, removed afterwards): ``simulate_many`` of ``lanes`` seeds in one lane
loop (the loop and every kernel it calls compile), then of ``lanes + rest`` seeds, i.e.
a full batch and a remainder batch of ``rest`` lanes (compiles nothing more if no
argument's type depends on the lane count), then the same again in a second fresh
interpreter on the now full cache (loads only). Runs of 0.05 s, one thread. Prints the
wall seconds of each call and the machine. Never a pass/fail test.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

_CHILD = """
import json, sys, time
t0 = time.perf_counter()
from pkmctl.sim.simulate import simulate_many
t1 = time.perf_counter()
c, sc, L, rest = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
simulate_many(sc, c, seeds=range(L), duration=0.05, lanes=L, workers=1)
t2 = time.perf_counter()
simulate_many(sc, c, seeds=range(L + rest), duration=0.05, lanes=L, workers=1)
t3 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "full_batch_s": t2 - t1, "with_remainder_s": t3 - t2}))
"""


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text(errors="replace").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="afsmc")
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--lanes", type=int, default=8)
    ap.add_argument("--rest", type=int, default=3, help="lanes of the remainder batch")
    a = ap.parse_args()
    args = [a.controller, a.scenario, str(a.lanes), str(a.rest)]
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, PKMCTL_CACHE_DIR=cache)
        for name in ("empty cache", "full cache"):
            run = subprocess.run([sys.executable, "-c", _CHILD, *args], env=env,
                                 capture_output=True, text=True, check=True)  # fmt: skip
            out[name] = json.loads(run.stdout.strip().splitlines()[-1])
    print(f"machine: {_cpu()}, {os.cpu_count()} cores; {a.controller} on {a.scenario}, "
          f"{a.lanes} lanes then {a.lanes} + {a.rest}")  # fmt: skip
    print(f"{'':12} {'import':>8} {'full batch':>11} {'+ remainder':>12}")
    for name, r in out.items():
        print(f"{name:12} {r['import_s']:7.1f}s {r['full_batch_s']:10.1f}s "
              f"{r['with_remainder_s']:11.1f}s")  # fmt: skip


if __name__ == "__main__":
    main()
