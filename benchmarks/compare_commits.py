"""First-run compile time and loop speed of two commits, side by side on this machine.

    python -m benchmarks.compare_commits [--base COMMIT] [--head COMMIT] [--repeats N]

Each commit is exported (``git archive``) into a temporary folder and installed
(non-editable, ``--no-deps``) into a fresh virtual environment that sees this
machine's installed NumPy, Numba and the rest (``--system-site-packages``), so both
use the same libraries and neither finds compiled code from earlier runs: the old
layout caches beside its sources (fresh), the new one in ``$PKMCTL_CACHE_DIR``
(pointed at a fresh folder). Then, for each commit:

1. ``pkmctl reproduce`` twice into temporary folders: the first run compiles, the
   second finds everything cached; compile time = first - second, in wall time and in
   CPU time (user + system, the worker processes included: the new layout compiles in
   parallel processes, and CPU time is what a loaded machine disturbs least). The new
   layout runs five controllers where the old ran three: not in its favour.
2. The closed loop's speed: 10 s of the ``paper`` scenario per controller, best of
   ``--repeats`` runs, in steps per second, both commits alternating so that the
   machine's drift hits both.
3. The FLC's time per evaluation from compiled code (the ``pkmctl bench`` number).

Prints a table and writes ``compare_commits.json`` beside the current directory.
Nothing here is a pass/fail test.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_SPEED = r"""
import json, sys, time
import pkmctl
names = sys.argv[1].split(",")
out = {}
for c in names:
    pkmctl.simulate("paper", controller=c, duration=0.01)
    r = pkmctl.simulate("paper", controller=c, duration=10.0)
    out[c] = r.t.size / r.info["kernel_seconds"]
print(json.dumps(out))
"""

_FLC = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
try:
    from benchmarks.fuzzy_bench import run
except ImportError:
    from pkmctl.fuzzy_bench import run
print(json.dumps({"flc_us": run(quick=False)["compiled_us"]}))
"""


def _sh(cmd: list[str], *, text: bool = True, **kw) -> subprocess.CompletedProcess:
    done = subprocess.run(cmd, capture_output=True, text=text, **kw)
    if done.returncode != 0:
        err = done.stderr if text else done.stderr.decode(errors="replace")
        sys.exit(f"failed: {' '.join(cmd)}\n{err[-2000:]}")
    return done


class Checkout:
    """One commit, exported and installed into its own virtual environment."""

    def __init__(self, commit: str, where: Path) -> None:
        self.commit = _sh(["git", "-C", str(ROOT), "rev-parse", "--short", commit]).stdout.strip()
        self.src = where / f"src-{self.commit}"
        self.src.mkdir()
        archive = _sh(["git", "-C", str(ROOT), "archive", "--format=tar", commit], text=False)
        subprocess.run(["tar", "-x", "-C", str(self.src)], input=archive.stdout, check=True)
        self.venv = where / f"venv-{self.commit}"
        _sh([sys.executable, "-m", "venv", "--system-site-packages", str(self.venv)])
        self.python = str(self.venv / "bin" / "python")
        _sh([self.python, "-m", "pip", "install", "-q", "--no-deps", str(self.src)])
        self.cache = where / f"cache-{self.commit}"
        self.env = os.environ | {"PKMCTL_CACHE_DIR": str(self.cache)}
        self.env.pop("PYTHONPATH", None)

    def run(self, code: str, *args: str) -> dict:
        done = _sh([self.python, "-c", code, *args], env=self.env, cwd=self.venv)
        return json.loads(done.stdout.strip().splitlines()[-1])

    def reproduce(self) -> tuple[float, float]:
        """(wall, CPU) seconds of one ``pkmctl reproduce`` (CPU: user + system of the
        process and the workers it waited for; less sensitive to a loaded machine)."""
        with tempfile.TemporaryDirectory() as out:
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            _sh([self.python, "-m", "pkmctl", "reproduce", "--out", out], env=self.env)
            wall = time.perf_counter() - t0
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            return wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="HEAD~1", help="the commit before the change")
    parser.add_argument("--head", default="HEAD", help="the commit with the change")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="pkmctl-compare-") as tmp:
        base, head = Checkout(args.base, Path(tmp)), Checkout(args.head, Path(tmp))
        res: dict = {
            "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
            f"Python {platform.python_version()}",
        }
        for c in (base, head):
            (first, first_cpu), (warm, warm_cpu) = c.reproduce(), c.reproduce()
            res[c.commit] = {
                "reproduce_first_s": first, "reproduce_warm_s": warm, "compile_s": first - warm,
                "reproduce_first_cpu_s": first_cpu, "reproduce_warm_cpu_s": warm_cpu,
                "compile_cpu_s": first_cpu - warm_cpu,
            }  # fmt: skip
            print(f"{c.commit}: reproduce first {first:.1f} s ({first_cpu:.1f} s CPU), "
                  f"warm {warm:.1f} s ({warm_cpu:.1f} s CPU)", flush=True)  # fmt: skip
        names = "smc,fsmc,afsmc"
        speeds: dict[str, dict[str, float]] = {base.commit: {}, head.commit: {}}
        for _ in range(args.repeats):
            for c in (base, head):  # alternate, so drift hits both
                for k, v in c.run(_SPEED, names).items():
                    speeds[c.commit][k] = max(speeds[c.commit].get(k, 0.0), v)
        for c in (base, head):
            res[c.commit]["loop_steps_per_s"] = speeds[c.commit]
            res[c.commit] |= c.run(_FLC, str(c.src))
    b, h = res[base.commit], res[head.commit]
    print(f"\n{res['machine']}")
    print(f"{'':34}{base.commit:>12}{head.commit:>12}{'ratio':>8}")
    rows = [
        ("first reproduce (s)", b["reproduce_first_s"], h["reproduce_first_s"]),
        ("warm reproduce (s)", b["reproduce_warm_s"], h["reproduce_warm_s"]),
        ("compile time = first - warm (s)", b["compile_s"], h["compile_s"]),
        ("compile CPU = first - warm (s)", b["compile_cpu_s"], h["compile_cpu_s"]),
        *((f"loop {k} (steps/s)", b["loop_steps_per_s"][k], h["loop_steps_per_s"][k])
          for k in names.split(",")),
        ("FLC in compiled code (us)", b["flc_us"], h["flc_us"]),
    ]  # fmt: skip
    for label, x, y in rows:
        print(f"{label:34}{x:12,.3f}{y:12,.3f}{y / x:8.2f}")
    Path("compare_commits.json").write_text(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
