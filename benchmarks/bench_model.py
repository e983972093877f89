"""Time the compiled model kernels from compiled code (issue 2, point 6).

    python benchmarks/bench_model.py

Prints microseconds per evaluation of M, C and G together, and of the regressor,
each called in an njit loop (as the closed loop calls them).
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit

import pkmctl
from pkmctl.dynamics import dynamics_kernel, make_work, regressor_kernel


@njit(cache=True)
def _loop_mcg(geom, theta, X, Xd, n):
    work = make_work()
    M, C, G = np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    acc = 0.0
    for k in range(n):
        X[2] = 0.3 * np.sin(1e-4 * k)  # vary the pose so nothing is hoisted
        dynamics_kernel(geom, theta, X, Xd, work, M, C, G)
        acc += M[0, 0] + C[1, 1] + G[0]
    return acc


@njit(cache=True)
def _loop_regressor(geom, X, Xd, Xr, Xrr, n):
    work = make_work()
    Y = np.empty((3, 36))
    acc = 0.0
    for k in range(n):
        X[2] = 0.3 * np.sin(1e-4 * k)
        regressor_kernel(geom, X, Xd, Xr, Xrr, work, Y)
        acc += Y[0, 0]
    return acc


def _best_of(fn, args, n, repeats=5):
    fn(*args[:-1], 10)  # compile / warm
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args[:-1], n)
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def run(quick: bool = False) -> dict[str, float]:
    robot = pkmctl.Mechanism.paper()
    n = 20_000 if quick else 200_000
    X = np.array([0.71, 0.2, -0.1])
    Xd = np.array([0.02, 0.5, -0.4])
    g, th = robot.geometry.copy(), robot.theta.copy()
    mcg = _best_of(_loop_mcg, (g, th, X.copy(), Xd, n), n)
    reg = _best_of(_loop_regressor, (g, X.copy(), Xd, Xd * 0.9, Xd * 3, n), n)
    return {"mcg_us": mcg, "regressor_us": reg}


if __name__ == "__main__":
    r = run()
    print(f"M, C, G together : {r['mcg_us']:.3f} us per evaluation (budget 3 us)")
    print(f"regressor Y      : {r['regressor_us']:.3f} us per evaluation (budget 5 us)")
