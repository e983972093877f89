"""Run a loop under Linux ``perf`` with the compiled kernels named in its report.

    perf record -F 5000 -o lanes.data python benchmarks/perf_map.py --controller afsmc
    perf report -i lanes.data --no-children --sort sym

Runs ``simulate_many`` (8 seeds of ``--seconds`` on ``paper``, ``--lanes`` at once, or 1
for the single loop; ``--metrics-only``: as a campaign runs them, logging only t = 0)
``--repeats`` times, then writes ``/tmp/perf-<pid>.map``, the file
``perf report`` reads to name code that no ELF file describes: the address of every
function in Numba's execution engine (read from its private attributes, so a Numba
upgrade may need this script changed), each taken to run to the next one's address.
Functions that LLVM inlined are part of their callers. ``--dump`` also writes the lane
or single loop's machine code to a file, for ``objdump -D -b binary -m i386:x86-64
--adjust-vma=<its address>`` (the address is printed), to read the hottest
instructions of ``perf script -F ip``.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import sys


def _symbols() -> list[tuple[int, str]]:
    from numba.core.registry import cpu_target

    engine = cpu_target.target_context.codegen()._engine
    out = []
    for name in engine._defined_symbols:
        address = engine._ee.get_function_address(name)
        if address:
            out.append((address, name))
    return sorted(out)


def write_map() -> list[tuple[int, int, str]]:
    """Write /tmp/perf-<pid>.map; returns its (address, size, name) rows."""
    syms = _symbols()
    rows = []
    for i, (address, name) in enumerate(syms):
        end = syms[i + 1][0] if i + 1 < len(syms) else address + 4096
        rows.append((address, min(end - address, 1 << 20), name))
    with open(f"/tmp/perf-{os.getpid()}.map", "w", encoding="ascii") as fh:
        fh.writelines(f"{a:x} {s:x} {n}\n" for a, s, n in rows)
    return rows


def main(argv: list[str] | None = None) -> int:
    from pkmctl.sim.simulate import simulate_many

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="afsmc")
    ap.add_argument("--lanes", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=0.5)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--dump", default=None, help="write the loop's machine code here")
    ap.add_argument(
        "--metrics-only",
        action="store_true",
        help="runs as campaigns make them: keep='metrics', a log of t = 0",
    )
    a = ap.parse_args(argv)
    for _ in range(a.repeats):
        res = simulate_many("paper", a.controller, seeds=list(range(1, 9)),
                            duration=a.seconds, lanes=a.lanes, workers=1,
                            keep="metrics" if a.metrics_only else "results")  # fmt: skip
        if not a.metrics_only:  # (metrics-only runs return their metrics alone)
            print(f"{a.controller}: {sum(r.info['kernel_seconds'] for r in res):.4f} s of loops",
                  file=sys.stderr)  # fmt: skip
    rows = write_map()
    print(f"wrote /tmp/perf-{os.getpid()}.map: {len(rows)} functions", file=sys.stderr)
    if a.dump:
        loop = "_run_lanes" if a.lanes > 1 else "_run_loop"
        for address, size, name in rows:
            if name.startswith("_ZN6pkmctl3sim") and f"{len(loop)}{loop}B" in name:
                with open(a.dump, "wb") as fh:
                    fh.write(ctypes.string_at(address, size))
                print(f"{loop}: {size} bytes at 0x{address:x} -> {a.dump}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
