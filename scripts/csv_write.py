"""The CSV time series' write time, old format against new, side by side in one process.

``%.17g`` (what pkmctl wrote before 0.2.0: 0.0 as "0", which other readers take for an
integer) against each double's ``repr`` (what ``save_result`` writes now), on a 2 s AFSMC
run of the paper, alternating, medians of 3 rounds (docs/performance.md, fifteenth
session). Run: ``python scripts/csv_write.py``.
"""

import argparse
import os
import tempfile
import time

import numpy as np

import pkmctl
from pkmctl.io.results import _columns, _write_table


def main() -> None:
    r = pkmctl.simulate("paper", "afsmc", duration=2.0)
    names, cols = _columns(r)

    def old(path: str) -> None:
        with open(path, "w", encoding="utf-8", newline="\n") as fh:
            np.savetxt(fh, np.column_stack(cols), delimiter=",", header=",".join(names),
                       comments="", fmt="%.17g")  # fmt: skip

    def new(path: str) -> None:
        _write_table(path, names, cols, "csv")

    times: dict[str, list[float]] = {"old": [], "new": []}
    sizes = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(3):
            for name, write in (("old", old), ("new", new)):
                path = os.path.join(tmp, f"{name}.csv")
                t0 = time.perf_counter()
                write(path)
                times[name].append(time.perf_counter() - t0)
                sizes[name] = os.path.getsize(path)
    print(f"{r.t.size} rows x {len(names)} columns")
    for name, t in times.items():
        print(f"{name}: median {np.median(t):.2f} s, {sizes[name] / 1e6:.1f} MB")
    print(f"new / old: {np.median(times['new']) / np.median(times['old']):.2f}")


if __name__ == "__main__":
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()  # --help says what it measures; no option
    main()
