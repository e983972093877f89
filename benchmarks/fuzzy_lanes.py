"""The fuzzy term in lanes against lane by lane, on a closed loop's own inputs.

    PYTHONPATH=. python benchmarks/fuzzy_lanes.py [--seconds S] [--lanes L] [--repeats N]

Runs FSMC on ``paper`` for seeds 1..L (single runs), rebuilds the FLC's inputs of every
period and axis from the logged measurements as the controller computes them
(s* = K_s s, sdot* = K_sdot times the filtered sdot), groups them as a lane loop sees
them (the L runs' inputs of one period and axis together), and times, best of N, the
lane kernel (``grid_eval_lanes``, one call per group) against the scalar kernel on the
same points one at a time; checks that they agree bit for bit. Also: random points
over the universes and 8 jittered copies of random points. Never a pass/fail test.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit


def _compiled():
    from pkmctl.fuzzy.kernels import _grid_eval2
    from pkmctl.fuzzy.lanes import grid_eval_lanes

    @njit(fastmath=False)
    def lanes(ints, reals, X1, X2, out):
        for b in range(X1.shape[0]):
            grid_eval_lanes(ints, reals, X1[b], X2[b], out[b])

    @njit(fastmath=False)
    def scalar(ints, reals, X1, X2, out):
        for b in range(X1.shape[0]):
            for l in range(X1.shape[1]):
                out[b, l] = _grid_eval2(ints, reals, X1[b, l], X2[b, l])

    return lanes, scalar


def closed_loop_inputs(seconds: float, lanes: int) -> tuple[np.ndarray, np.ndarray]:
    """(x1, x2) of shape (periods * 3, lanes): the FLC inputs of FSMC's runs."""
    from pkmctl.control.gains import Gains
    from pkmctl.sim.simulate import simulate_many

    res = simulate_many("paper", "fsmc", seeds=list(range(1, lanes + 1)), duration=seconds,
                        lanes=1, workers=1)  # fmt: skip
    g = Gains()
    Tc = float(res[0].t[1] - res[0].t[0])
    alpha = 1.0 / g.filter_periods
    x1, x2 = [], []
    for r in res:
        s = (r.Xdot_desired - r.Xdot_measured) + g.lam * (r.X_desired - r.X_measured)
        sd = np.zeros_like(s)
        f = np.zeros(3)
        for k in range(len(s)):  # pkmctl.control.sliding.filter_sdot
            raw = (s[k] - s[k - 1]) / Tc if k > 0 else np.zeros(3)
            f = f + alpha * (raw - f)
            sd[k] = f
        x1.append(g.Ks * s)
        x2.append(g.Ksd * sd)
    return (np.stack(x1, -1).reshape(-1, lanes), np.stack(x2, -1).reshape(-1, lanes))


def _time(fn, args, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args)
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv: list[str] | None = None) -> int:
    from pkmctl.fuzzy import FLC

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=0.5)
    ap.add_argument("--lanes", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args(argv)
    ints, reals = FLC().compiled()
    lanes, scalar = _compiled()
    rng = np.random.default_rng(0)
    n = 200_000 // a.lanes
    near = np.repeat(rng.uniform([-1, -10], [1, 10], (n, 1, 2)), a.lanes, axis=1)
    near += rng.normal(0.0, 1e-3, near.shape) * [2.0, 20.0]
    wide = rng.uniform([-1.2, -12], [1.2, 12], (n, a.lanes, 2))
    cases = {
        "closed loop (FSMC)": closed_loop_inputs(a.seconds, a.lanes),
        "random points": (wide[..., 0].copy(), wide[..., 1].copy()),
        "8 jittered copies": (near[..., 0].copy(), near[..., 1].copy()),
    }
    print(f"{'inputs':<20} {'lanes ns/point':>15} {'scalar ns/point':>16} {'ratio':>6}  same")
    for name, (X1, X2) in cases.items():
        X1, X2 = np.ascontiguousarray(X1), np.ascontiguousarray(X2)
        o1, o2 = np.empty_like(X1), np.empty_like(X1)
        lanes(ints, reals, X1, X2, o1)
        scalar(ints, reals, X1, X2, o2)
        same = bool(np.array_equal(o1.view(np.int64), o2.view(np.int64)))
        tl = _time(lanes, (ints, reals, X1, X2, o1), a.repeats) / X1.size * 1e9
        ts = _time(scalar, (ints, reals, X1, X2, o2), a.repeats) / X1.size * 1e9
        print(f"{name:<20} {tl:>15.1f} {ts:>16.1f} {ts / tl:>6.2f}  {same}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
