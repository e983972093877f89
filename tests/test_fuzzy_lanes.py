"""The fuzzy term in SIMD lanes (issue 16, point 3): :func:`grid_eval_lanes` is the scalar
fast kernel bit for bit, lane by lane, whatever the other lanes hold; the general engine's
lane path is its scalar path."""

import numpy as np
import pytest
from conftest import CORPUS

from pkmctl._jit import kernel
from pkmctl.fuzzy import FLC, MamdaniSystem
from pkmctl.fuzzy.engine import Rule, Term, Variable, uniform_terms
from pkmctl.fuzzy.fis import read_fis
from pkmctl.fuzzy.general import new_work
from pkmctl.fuzzy.kernels import grid_eval_batch
from pkmctl.fuzzy.lanes import MAX_TERMS, grid_eval_lanes
from pkmctl.fuzzy.term import term_eval, term_eval_lanes


def _names(n: int) -> tuple[str, ...]:
    return tuple(f"t{k}" for k in range(n))


def _grid_system(n1: int, n2: int, k: int, trapezoids: bool = False) -> MamdaniSystem:
    """Inputs of n1 and n2 terms on uniform grids (trapezoid inputs if asked), an output
    of k terms, rules (j1, j2) -> (j1 + 2 j2) mod k with weights in (0, 1]: fast kernel."""
    in1 = uniform_terms(-2.0, 3.0, _names(n1))
    if trapezoids:  # trapmf(g[j-1], g[j-1] + h/4, g[j] + h/4, g[j+1]) between the ends
        g = np.linspace(-2.0, 3.0, n1)
        h = g[1] - g[0]
        mid = tuple(
            Term(f"t{j}", "trapmf", (g[j - 1], g[j - 1] + h / 4, g[j] + h / 4, g[j + 1]))
            for j in range(1, n1 - 1)
        )
        in1 = (in1[0], *mid, in1[-1])
    v1 = Variable("a", (-2.0, 3.0), in1)
    v2 = Variable("b", (-0.5, 0.7), uniform_terms(-0.5, 0.7, _names(n2)))
    out = Variable("u", (-4.0, 1.0), uniform_terms(-4.0, 1.0, _names(k)))
    rules = tuple(
        Rule((f"t{a}", f"t{b}"), f"t{(a + 2 * b) % k}", 1.0 - 0.05 * ((a + b) % 7))
        for a in range(n1)
        for b in range(n2)
    )
    return MamdaniSystem((v1, v2), out, rules)


def _systems() -> dict[str, MamdaniSystem]:
    systems = {
        "paper": FLC(),
        "5x3 trapezoids, 9 out": _grid_system(5, 3, 9, trapezoids=True),
        "2x7, 3 out": _grid_system(2, 7, 3),
        f"{MAX_TERMS + 1} terms (lane by lane)": _grid_system(MAX_TERMS + 1, 3, 5),
    }
    path = CORPUS / "dcdc_converter.fis"
    if path.is_file():
        systems["dcdc_converter.fis"] = read_fis(path)
    return systems


def _points(system: MamdaniSystem, n: int, seed: int) -> np.ndarray:
    """Grid points and their neighbouring floats, random points inside and beyond the
    universes, NaN and infinities: (N, 2)."""
    cols = []
    for v in system.inputs:
        lo, hi = v.universe
        g = np.linspace(lo, hi, len(v.terms))
        cols.append(np.concatenate([g, np.nextafter(g, -np.inf), np.nextafter(g, np.inf)]))
    grid = np.array(np.meshgrid(*cols)).reshape(2, -1).T
    rng = np.random.default_rng(seed)
    (lo1, hi1), (lo2, hi2) = (v.universe for v in system.inputs)
    w1, w2 = hi1 - lo1, hi2 - lo2
    wide = rng.uniform([lo1 - w1, lo2 - w2], [hi1 + w1, hi2 + w2], (n, 2))
    # lanes near each other (as a campaign's runs): 8 jittered copies of each point
    near = np.repeat(rng.uniform([lo1, lo2], [hi1, hi2], (n // 8, 2)), 8, axis=0)
    near += rng.normal(0.0, 1e-3, near.shape) * [hi1 - lo1, hi2 - lo2]
    odd = np.array([[np.nan, 0.0], [0.0, np.nan], [np.inf, -np.inf], [-np.inf, np.inf],
                    [np.nan, np.nan]])  # fmt: skip
    X = np.concatenate([grid, wide, near, odd])
    return X[rng.permutation(len(X))] if seed % 2 else X


@pytest.mark.parametrize("name", list(_systems()))
def test_lanes_are_the_scalar_kernel_bit_for_bit(name):
    system = _systems()[name]
    ints, reals = system.compiled()
    assert ints[4] == 1  # on the fast kernel
    for seed in (1, 2):
        X = _points(system, 4000, seed)
        want = np.empty(len(X))
        grid_eval_batch(ints, reals, X, want)
        for L in (8, 3, 11, len(X)):  # whole blocks, a partial one, blocks and a remainder
            n = len(X) - len(X) % L
            got = np.empty(n)
            for s in range(0, n, L):  # lanes s .. s + L - 1 at once
                grid_eval_lanes(ints, reals, X[s : s + L, 0].copy(), X[s : s + L, 1].copy(),
                                got[s : s + L])  # fmt: skip
            np.testing.assert_array_equal(got.view(np.int64), want[:n].view(np.int64))


@kernel(refcount=False)
def _both(tables, work, x1, x2, one, lanes):
    """term_eval point by point into ``one``, term_eval_lanes on all points into ``lanes``."""
    for n in range(x1.shape[0]):
        one[n] = term_eval(tables, work, x1[n], x2[n])
    term_eval_lanes(tables, work, x1, x2, lanes)


@pytest.mark.parametrize("general", [False, True])
def test_term_eval_lanes_is_term_eval_on_either_engine(general):
    system = FLC()
    tables = system.compiled()
    work = (np.zeros(1),)
    if general:
        from pkmctl.fuzzy.system import as_general

        tables = as_general(system).compiled()
        work = new_work(tables.ints)
    X = _points(system, 300, 3)
    one, lanes = np.empty(len(X)), np.empty(len(X))
    _both(tables, work, X[:, 0].copy(), X[:, 1].copy(), one, lanes)
    np.testing.assert_array_equal(lanes, one)
