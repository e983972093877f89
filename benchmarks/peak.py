"""The machine's double-precision FMA peaks, scalar and vector, measured rather than taken
from a data sheet.

    python -m benchmarks.peak

A compiled loop runs 16 independent chains of ``a = a * b + c`` (contracted to fused
multiply-adds, 2 flops each; 16 chains cover 2 FMA pipes x 4 cycles of latency with room
to spare) in a child interpreter with Numba's loop and SLP vectorizers off
(``NUMBA_LOOP_VECTORIZE=0``, ``NUMBA_SLP_VECTORIZE=0``, read when Numba is imported). It
gives what scalar code can reach at the clock the machine really runs at, turbo included,
which the nominal MHz of ``/proc/cpuinfo`` does not say (on the 2-core Xeon of
docs/performance.md: 14.7 GFLOP/s measured against 10.4 from 2.6 GHz x 4).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

_CHILD = r"""
import json, sys, time
from numba import njit

@njit(fastmath={"contract"}, cache=False)
def chains(n, b, c):
    a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = 1.0
    a8 = a9 = a10 = a11 = a12 = a13 = a14 = a15 = 1.5
    for _ in range(n):
        a0 = a0 * b + c; a1 = a1 * b + c; a2 = a2 * b + c; a3 = a3 * b + c
        a4 = a4 * b + c; a5 = a5 * b + c; a6 = a6 * b + c; a7 = a7 * b + c
        a8 = a8 * b + c; a9 = a9 * b + c; a10 = a10 * b + c; a11 = a11 * b + c
        a12 = a12 * b + c; a13 = a13 * b + c; a14 = a14 * b + c; a15 = a15 * b + c
    return (a0 + a1 + a2 + a3 + a4 + a5 + a6 + a7 + a8 + a9 + a10 + a11 + a12 + a13
            + a14 + a15)

n = int(sys.argv[1])
chains(10, 0.999999, 1e-6)
best = 1e9
for _ in range(5):
    t0 = time.perf_counter()
    chains(n, 0.999999, 1e-6)
    best = min(best, time.perf_counter() - t0)
print(json.dumps({"gflops": 16 * 2 * n / best / 1e9}))
"""


# The vector peak: 8 independent chains, each a row of 8 doubles (one 512-bit register
# with AVX-512, two 256-bit ones with AVX2), written so that LLVM keeps them in registers
# (a constant 64-element block, fully unrolled and packed by the SLP vectoriser) with
# 512-bit vectors preferred (pkmctl's wide_vectors(), as the lane kernels).
_VECTOR_CHILD = r"""
import json, sys, time
import numpy as np
from numba import njit
from pkmctl.model.simd import wide_vectors

@njit(fastmath={"contract"}, cache=False)
def chains(n, a, b, c):
    wide_vectors()
    for _ in range(n):
        for i in range(64):
            a[i] = a[i] * b + c
    return a.sum()

n = int(sys.argv[1])
a = np.ones(64)
chains(10, a, 0.999999, 1e-6)
best = 1e9
for _ in range(5):
    t0 = time.perf_counter()
    chains(n, a, 0.999999, 1e-6)
    best = min(best, time.perf_counter() - t0)
print(json.dumps({"gflops": 64 * 2 * n / best / 1e9}))
"""


def vector_fma_peak(n: int = 5_000_000) -> float:
    """GFLOP/s of 64 independent FMA chains in SIMD registers (8 x 512 bits with AVX-512),
    best of 5, in a child interpreter: what the lane kernels could reach at most."""
    out = subprocess.run([sys.executable, "-c", _VECTOR_CHILD, str(n)], capture_output=True,
                         text=True, check=True)  # fmt: skip
    return float(json.loads(out.stdout.strip().splitlines()[-1])["gflops"])


def scalar_fma_peak(n: int = 20_000_000) -> float:
    """GFLOP/s of 16 independent scalar FMA chains, best of 5, in a child interpreter."""
    env = dict(os.environ, NUMBA_LOOP_VECTORIZE="0", NUMBA_SLP_VECTORIZE="0")
    out = subprocess.run([sys.executable, "-c", _CHILD, str(n)], env=env, capture_output=True,
                         text=True, check=True)  # fmt: skip
    return float(json.loads(out.stdout.strip().splitlines()[-1])["gflops"])


if __name__ == "__main__":
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()  # --help says what it measures; no option
    print(f"scalar FMA peak {scalar_fma_peak():.2f} GFLOP/s")
    print(f"vector FMA peak {vector_fma_peak():.2f} GFLOP/s")
