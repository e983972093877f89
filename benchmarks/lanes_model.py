"""The lane kernels against the scalar ones, per evaluation, side by side in one run.

    python -m benchmarks.lanes_model [--lanes 8] [--repeats 7] [--n 200000] [--peaks]

Times, from compiled loops, the rigid plant's RK4 stage derivative (the paper's rigid
machine, and with every option of DESIGN.md §7 on) and the regressor Y: the scalar
kernel once per evaluation, and the lane kernel on L lanes at once, whose time is
divided by L. Best of ``repeats``; prints µs per evaluation, the throughput ratio
(scalar time ÷ lane time per lane) and the machine. Timing is never a pass/fail test.
"""

from __future__ import annotations

import argparse
import platform
import subprocess

import numba
import numpy as np

from benchmarks.timing import best_time
from pkmctl._jit import JIT_OPTIONS, NO_REFCOUNT
from pkmctl.model.dynamics import make_work, regressor_kernel
from pkmctl.model.lanes import (
    lane_regressor,
    lane_rigid_derivative,
    lane_rigid_plant,
    make_lane_work,
)
from pkmctl.sim.plants import _rigid_work, rigid_derivative, rigid_plant

# Plain njit, not @kernel: the project's cache is keyed on pkmctl's sources only, so a
# cached benchmark loop would not notice an edit to this file.
_jit = numba.njit(**(JIT_OPTIONS | NO_REFCOUNT))


# The pose moves a little every call (nothing is hoisted out of the loop), by an add,
# not a sin: a libm call per evaluation would be a tenth of the scalar derivative's time.
@_jit
def _scalar_plant(p, x, tau, dist, work, dx, n):
    acc = 0.0
    z = x[2]
    for k in range(n):
        x[2] = z + 1e-9 * k
        rigid_derivative(p, x, tau, dist, work, dx)
        acc += dx[3]
    x[2] = z
    return acc


@_jit
def _lane_plant(p, x, tau, dist, work, dx, n):
    acc = 0.0
    L = x.shape[1]
    z = x[2, 0]
    for k in range(n):
        for l in range(L):
            x[2, l] = z + 1e-9 * (k + l)
        lane_rigid_derivative(p, x, tau, dist, work, dx)
        acc += dx[3, 0]
    for l in range(L):
        x[2, l] = z
    return acc


@_jit
def _scalar_regressor(geom, X, Xd, Xr, Xrr, work, Y, n):
    acc = 0.0
    z = X[2]
    for k in range(n):
        X[2] = z + 1e-9 * k
        regressor_kernel(geom, X, Xd, Xr, Xrr, work, Y)
        acc += Y[0, 0]
    X[2] = z
    return acc


@_jit
def _lane_regressor(geom, X, Xd, Xr, Xrr, work, Y, n):
    acc = 0.0
    L = X.shape[1]
    z = X[2, 0]
    for k in range(n):
        for l in range(L):
            X[2, l] = z + 1e-9 * (k + l)
        lane_regressor(geom, X, Xd, Xr, Xrr, work, Y)
        acc += Y[0, 0, 0]
    for l in range(L):
        X[2, l] = z
    return acc


def machine() -> str:
    """The processor's model name (``lscpu``), core count and SIMD width."""
    name = platform.processor() or platform.machine()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        name = next(
            line.split(":", 1)[1].strip() for line in out.splitlines() if "Model name" in line
        )
    except (OSError, subprocess.CalledProcessError, StopIteration):
        pass
    with open("/proc/cpuinfo", encoding="utf-8") as f:
        flags = next((line for line in f if line.startswith("flags")), "").split()
    simd = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    return f"{name}, {numba.config.NUMBA_NUM_THREADS} cores, {simd}, Numba {numba.__version__}"


def _states(L: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    X = np.stack([rng.uniform(0.6, 0.8, L), rng.uniform(-0.4, 0.4, L), rng.uniform(-0.4, 0.4, L)])
    Xd = rng.normal(scale=0.3, size=(3, L))
    return X, Xd, rng


def _per_call(fn, args: tuple, n: int, repeats: int) -> float:
    """Seconds per kernel call of the loop ``fn(*args, n)``, best of ``repeats``."""
    fn(*args, 10)  # compile (or load), and warm up
    return best_time(lambda: fn(*args, n), repeats) / n


def run(lanes: int = 8, repeats: int = 7, n: int = 200_000) -> dict[str, dict[str, float]]:
    """µs per evaluation, scalar and per lane, and their ratio, for each case."""
    import pkmctl

    robot = pkmctl.Mechanism.paper()
    X, Xd, rng = _states(lanes)
    tau = rng.normal(scale=50.0, size=(4, lanes))
    dist = np.zeros((3, lanes))
    x = np.ascontiguousarray(np.vstack([X, Xd]))
    m = max(1, n // lanes)  # lane calls per repeat: as many evaluations as the scalar loop's
    options = dict(
        rotor_inertia=2.77e-5,
        friction_coulomb=30.0,
        friction_viscous=300.0,
        payload_mass=2.0,
        payload_offset=(0.05, 0.02, 0.03),
    )
    cases = {}
    for case, kw in (("rigid derivative", {}), ("derivative, §7 options on", options)):
        p = rigid_plant(robot, **kw)
        one = (p, x[:, 0].copy(), tau[:, 0].copy(), dist[:, 0].copy(), _rigid_work(p), np.empty(6))
        lane = (
            lane_rigid_plant([p] * lanes),
            x,
            tau,
            dist,
            make_lane_work(lanes),
            np.empty((6, lanes)),
        )
        cases[case] = (_scalar_plant, one, _lane_plant, lane)
    Xr, Xrr = 0.9 * Xd, rng.normal(size=(3, lanes))
    one = (robot.geometry.copy(), *(np.ascontiguousarray(a[:, 0]) for a in (X, Xd, Xr, Xrr)))
    geom = np.ascontiguousarray(np.repeat(robot.geometry[:, None], lanes, 1))
    cases["regressor Y"] = (
        _scalar_regressor,
        (*one, make_work(), np.empty((3, 36))),
        _lane_regressor,
        (geom, X, Xd, Xr, Xrr, make_lane_work(lanes), np.empty((3, 36, lanes))),
    )
    out = {}
    for case, (fs, args_s, fl, args_l) in cases.items():
        ts = _per_call(fs, args_s, n, repeats)
        tl = _per_call(fl, args_l, m, repeats) / lanes
        out[case] = {"scalar_us": ts * 1e6, "lane_us": tl * 1e6, "ratio": ts / tl}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lanes", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--n", type=int, default=200_000, help="scalar evaluations per repeat")
    ap.add_argument("--peaks", action="store_true", help="flop rates against both FMA peaks")
    a = ap.parse_args()
    print(f"machine: {machine()}")
    print(f"L = {a.lanes} lanes, best of {a.repeats}, {a.n} evaluations per repeat")
    print(f"{'kernel':28s} {'scalar µs':>10s} {'lane µs/lane':>13s} {'throughput ×':>13s}")
    res = run(a.lanes, a.repeats, a.n)
    for case, r in res.items():
        print(f"{case:28s} {r['scalar_us']:10.3f} {r['lane_us']:13.3f} {r['ratio']:13.2f}")
    if a.peaks:
        peaks(res["rigid derivative"])


def peaks(r: dict[str, float]) -> None:
    """The rigid stage's flop rate in both forms against the measured FMA peaks: how far
    either is from what the machine can do. The lane form is counted with the scalar
    kernel's flops per lane (its selects' arms included: an upper bound of its own)."""
    from benchmarks.flops import plant_stage_flops
    from benchmarks.peak import scalar_fma_peak, vector_fma_peak

    flops = plant_stage_flops()
    scalar, vector = scalar_fma_peak(), vector_fma_peak()
    g1, gl = flops / r["scalar_us"] / 1e3, flops / r["lane_us"] / 1e3
    print(f"rigid stage {flops:,.0f} flops (counted): scalar kernel {g1:.1f} GFLOP/s, "
          f"lane kernel {gl:.1f} GFLOP/s per core")  # fmt: skip
    print(f"FMA peaks (measured): scalar {scalar:.1f} GFLOP/s, vector {vector:.1f} GFLOP/s; "
          f"the lane kernel at {100 * gl / vector:.0f} % of the vector peak, which allows "
          f"at most {vector / g1:.2f}x the scalar kernel")  # fmt: skip


if __name__ == "__main__":
    main()
