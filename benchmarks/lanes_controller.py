"""Each controller's lane step against its scalar step, per lane, side by side in one run.

    PYTHONPATH=. python benchmarks/lanes_controller.py [--controllers afsmc,fsmc,smc,ctc,pd]
        [--lanes 8] [--rounds 5] [--n 100000]

For each controller on the ``paper`` scenario: ``controller_step`` of the scalar form in
a compiled loop (one run's controller), and of the lane form on L runs at once (seeds
1..L), whose time is divided by L. The measured pose moves a little every call, so
nothing is hoisted out of the loop. Rounds alternate the controllers and both forms;
each round's time is the best of 3 repeats. Prints the best times and the median of the
rounds' ratios (scalar time ÷ lane time per lane): the part of point 3's throughput that
the controller contributes (`benchmarks/lanes_speed.py` times the whole loop). Timing is
never a pass/fail test. The loops are compiled at every start (plain ``njit``, not the
project's cache, which is keyed on pkmctl's sources only): about a minute.
"""

from __future__ import annotations

import argparse
import statistics

import numba
import numpy as np

import pkmctl.sim.lanes  # noqa: F401  (registers the lane forms)
from benchmarks.lanes_model import machine
from benchmarks.timing import best_time
from pkmctl._jit import JIT_OPTIONS, NO_REFCOUNT
from pkmctl.parts import controller_step, stack_lanes
from pkmctl.sim.simulate import _set_up, prepare, resolve_parts

_jit = numba.njit(**(JIT_OPTIONS | NO_REFCOUNT))


@_jit
def _scalar(ctrl, state, work, y, ref, F, n):
    acc = 0.0
    z = y[0]
    for k in range(n):
        y[0] = z + 1e-9 * k
        controller_step(ctrl, state, work, y, ref, F)
        acc += F[0]
    y[0] = z
    return acc


@_jit
def _lanes(ctrl, state, work, y, ref, F, n):
    acc = 0.0
    L = y.shape[1]
    z = y[0, 0]
    for k in range(n):
        for l in range(L):
            y[0, l] = z + 1e-9 * (k + l)
        controller_step(ctrl, state, work, y, ref, F)
        acc += F[0, 0]
    for l in range(L):
        y[0, l] = z
    return acc


def _setup(prep, controller: str, lanes: int) -> tuple:
    """The scalar controller of seed 1 and the lane controller of seeds 1..L, with the
    measured state and the reference at t = 0 (plus 0.1 mm, so that the errors are not 0)."""
    parts = resolve_parts(prep.scenario, controller)
    bundles = [_set_up(prep, parts, s, True).bundles["controller"] for s in range(1, lanes + 1)]
    ref = np.ascontiguousarray(prep.chunk(0, 1)[0][0], dtype=float)
    y = ref[:6] + 1e-4
    p, state, work = bundles[0]
    one = (p, state.copy(), work, y.copy(), ref.copy(), np.zeros(3))
    lp, ls, lw = stack_lanes(parts["controller"], [(b[0], b[1].copy(), b[2]) for b in bundles])
    rep = lambda a: np.ascontiguousarray(np.repeat(a[:, None], lanes, axis=1))  # noqa: E731
    many = (lp, ls, lw, rep(y), rep(ref), np.zeros((3, lanes)))
    return one, many


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controllers", default="afsmc,fsmc,smc,ctc,pd")
    ap.add_argument("--lanes", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--n", type=int, default=100_000, help="scalar steps per repeat")
    a = ap.parse_args(argv)
    L, n = a.lanes, a.n
    prep = prepare("paper", 0.5)
    setups = {}
    for c in a.controllers.split(","):
        one, many = _setup(prep, c, L)
        _scalar(*one, 10)  # compile
        _lanes(*many, 10)
        setups[c] = (one, many)
    times: dict[str, list[tuple[float, float]]] = {c: [] for c in setups}
    for _ in range(a.rounds):
        for c, (one, many) in setups.items():
            t1 = best_time(lambda one=one: _scalar(*one, n), 3) / n
            tl = best_time(lambda many=many: _lanes(*many, n // L), 3) / (n // L) / L
            times[c].append((t1, tl))
    print(f"machine: {machine()}; {L} lanes, best of 3, {a.rounds} rounds")
    print(f"{'controller':10s} {'scalar µs':>10s} {'lane µs/lane':>13s} {'median ×':>9s}  rounds")
    for c, v in times.items():
        ratios = [t1 / tl for t1, tl in v]
        print(
            f"{c:10s} {min(t for t, _ in v) * 1e6:10.3f} {min(t for _, t in v) * 1e6:13.3f} "
            f"{statistics.median(ratios):9.2f}  {' '.join(f'{r:.2f}' for r in ratios)}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
