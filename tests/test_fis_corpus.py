"""The .fis corpus (../shared/fis-corpus): every readable file agrees with an independent
engine and round-trips exactly.

The oracle is pyfuzzylite, its engine built from the parsed file (its own membership
functions, norms, activation and aggregation over rules). Its aggregated fuzzy set is
sampled on a uniform grid plus every point where the set may bend: the output terms'
breakpoints, the points where a term meets its activation degree (min implication) and
where the highest implied set changes (max aggregation), the last two found by bisection
on fuzzylite's memberships. Between those points the set is smooth, so the
piecewise-linear interpolant of the samples, defuzzified with scikit-fuzzy's formulas
(``defuzz`` centroid and bisector, vectorised here and checked against it), has an error
c h^2 + O(h^4), and one Richardson step over nested grids of spacing h and h/2 removes
the h^2 term. It is exact for piecewise-linear sets. Maximum-based methods (mom, som,
lom) are compared in MATLAB's sampled form (same grid on both sides), since they are
defined on samples. Sugeno outputs come from pyfuzzylite's WeightedAverage /
WeightedSum directly.

``PKMCTL_FULL=1`` samples the oracle on a grid five times finer (100 001 points instead
of 20 001); both forms check 200 points per file.
"""

import logging
import os
import warnings
import zlib

import numpy as np
import pytest
from conftest import CORPUS

from pkmctl.fuzzy import fis
from pkmctl.fuzzy.system import FuzzySystem, FuzzyWarning

FILES = sorted(CORPUS.glob("*.fis")) if CORPUS.is_dir() else []
pytestmark = pytest.mark.skipif(not FILES, reason="no .fis corpus next to the repository")
FULL = os.environ.get("PKMCTL_FULL") == "1"
N_POINTS = 200
GRID = 100001 if FULL else 20001  # the oracle's finer grid
RICHARDSON = (GRID // 2 + 1, GRID)  # nested grids, h and h / 2
REFUSED = {"frss_malformed.fis"}  # hand-edited: [system] and OrMethod="max'


def _import_fuzzylite():
    """pyfuzzylite, without what its import does to the whole process: numpy's floating
    point errors set to "ignore", and a handler on the root logger (through which every
    library's INFO records then print, Dask's in ``pkmctl bench`` included)."""
    root = logging.getLogger()
    handlers = list(root.handlers)
    with np.errstate():  # restores numpy's error handling on leaving
        module = pytest.importorskip("fuzzylite")
    root.handlers[:] = handlers
    return module


fl = _import_fuzzylite()


@pytest.fixture(autouse=True)
def _fuzzylite_numpy_errors():
    """pyfuzzylite divides by zero on purpose (its terms' edges): numpy's warnings of it
    off for this module's tests, as its import would have set them for the process."""
    with np.errstate(divide="ignore", invalid="ignore"):
        yield


fuzz = pytest.importorskip("skfuzzy")


def _fl_term(t, engine):
    p = t.params
    kind = t.kind
    if kind == "trimf":
        return fl.Triangle(t.name, p[0], p[1], p[2])
    if kind == "trapmf":
        return fl.Trapezoid(t.name, *p)
    if kind == "gaussmf":
        return fl.Gaussian(t.name, p[0], p[1])  # pkmctl keeps (mean, sigma)
    if kind == "gauss2mf":
        return fl.GaussianProduct(t.name, p[1], p[0], p[3], p[2])
    if kind == "gbellmf":
        return fl.Bell(t.name, p[2], p[0], p[1])
    if kind == "sigmf":
        return fl.Sigmoid(t.name, p[1], p[0])
    if kind == "dsigmf":
        return fl.SigmoidDifference(t.name, p[1], p[0], p[2], p[3])
    if kind == "psigmf":
        return fl.SigmoidProduct(t.name, p[1], p[0], p[2], p[3])
    if kind == "pimf":
        return fl.PiShape(t.name, *p)
    if kind == "zmf":
        return fl.ZShape(t.name, p[0], p[1])
    if kind == "smf":
        return fl.SShape(t.name, p[0], p[1])
    if kind == "linzmf":
        return fl.Ramp(t.name, p[1], p[0])
    if kind == "linsmf":
        return fl.Ramp(t.name, p[0], p[1])
    if kind == "constant":
        return fl.Constant(t.name, p[0])
    return fl.Linear(t.name, list(p), engine)


def fuzzylite_engine(system: FuzzySystem) -> "fl.Engine":
    """A pyfuzzylite engine of the parsed system, with clipped inputs (lock_range)."""
    eng = fl.Engine(name="oracle")
    names = [f"in{i}" for i in range(len(system.inputs))]
    outs = [f"out{i}" for i in range(len(system.outputs))]
    for n, v in zip(names, system.inputs, strict=True):
        eng.input_variables.append(
            fl.InputVariable(n, minimum=v.universe[0], maximum=v.universe[1], lock_range=True)
        )
        eng.input_variables[-1].terms = [_fl_term(t, eng) for t in v.terms]
    sugeno = system.kind == "sugeno"
    agg = {"max": fl.Maximum(), "sum": fl.UnboundedSum(), "probor": fl.AlgebraicSum()}
    for n, v in zip(outs, system.outputs, strict=True):
        defuzz = (
            (fl.WeightedAverage() if system.defuzz_method == "wtaver" else fl.WeightedSum())
            if sugeno
            else fl.Centroid(100)
        )
        eng.output_variables.append(
            fl.OutputVariable(n, minimum=v.universe[0], maximum=v.universe[1],
                              aggregation=None if sugeno else agg[system.agg_method],
                              defuzzifier=defuzz)
        )  # fmt: skip
    for v, ov in zip(system.outputs, eng.output_variables, strict=True):
        ov.terms = [_fl_term(t, eng) for t in v.terms]
    tnorm = {"min": fl.Minimum(), "prod": fl.AlgebraicProduct()}
    block = fl.RuleBlock(
        conjunction=tnorm[system.and_method],
        disjunction={"max": fl.Maximum(), "probor": fl.AlgebraicSum()}[system.or_method],
        implication=tnorm[system.imp_method],
        activation=fl.General(),
    )
    for r in system.rules:
        conn = " and " if r.connective == "and" else " or "
        ants = [
            f"{names[i]} is {'not ' if a < 0 else ''}{system.inputs[i].terms[abs(a) - 1].name}"
            for i, a in enumerate(r.antecedent)
            if a != 0
        ]
        cons = [
            f"{outs[o]} is {'not ' if c < 0 else ''}{system.outputs[o].terms[abs(c) - 1].name}"
            for o, c in enumerate(r.consequent)
            if c != 0
        ]
        if not ants or not cons:
            continue
        text = f"if {conn.join(ants)} then {' and '.join(cons)} with {r.weight!r}"
        block.rules.append(fl.Rule.create(text, eng))
    eng.rule_blocks.append(block)
    return eng


def _safe_names(system: FuzzySystem) -> FuzzySystem:
    """Term names fuzzylite's rule parser accepts (t0, t1, ...), same system otherwise."""
    import dataclasses

    def rename(v):
        terms = tuple(dataclasses.replace(t, name=f"t{k}") for k, t in enumerate(v.terms))
        return dataclasses.replace(v, terms=terms)

    return system.replace(
        inputs=tuple(rename(v) for v in system.inputs),
        outputs=tuple(rename(v) for v in system.outputs),
    )


def oracle(system: FuzzySystem, X: np.ndarray, samples: int | None) -> np.ndarray:
    """Outputs (N, n_out) of the independent engine (module docstring)."""
    eng = fuzzylite_engine(_safe_names(system))
    out = np.empty((X.shape[0], len(system.outputs)))
    grids, singletons = [], []
    for v in system.outputs:
        lo, hi = v.universe
        if samples:
            grids.append((np.linspace(lo, hi, samples),) * 2)
        else:
            pts = [p for t in v.terms for p in _breakpoints(t) if lo <= p <= hi]
            grids.append(
                tuple(np.unique(np.concatenate([np.linspace(lo, hi, n), pts])) for n in RICHARDSON)
            )
        # every term seen on the grid is a single point (trimf [c c c]): zero area
        singletons.append(
            all(
                min(t.params) == max(t.params)
                for t in v.terms
                if np.any(np.asarray(_fl_term(t, eng).membership(grids[-1][1])) > 0)
            )
        )
    for n, x in enumerate(X):
        for iv, value in zip(eng.input_variables, x, strict=True):
            iv.value = value
        eng.process()
        for o, ov in enumerate(eng.output_variables):
            lo, hi = system.outputs[o].universe
            if system.kind == "sugeno":
                value = float(np.asarray(ov.value, dtype=float).reshape(-1)[0])
                out[n, o] = 0.5 * (lo + hi) if np.isnan(value) else value
                continue
            # the rules that fired (fuzzylite keeps one activation per rule, most at 0)
            ov.fuzzy.terms[:] = [a for a in ov.fuzzy.terms if a.degree > 0]
            coarse, fine = grids[o]
            if not ov.fuzzy.terms:
                out[n, o] = 0.5 * (lo + hi)  # no rule fired
            elif samples or singletons[o]:
                y = fine
                mfx = np.asarray(ov.fuzzy.membership(y), dtype=float).reshape(-1)
                if not np.any(mfx > 0):
                    out[n, o] = 0.5 * (lo + hi)
                elif singletons[o] or system.defuzz_method == "centroid":
                    out[n, o] = np.sum(y * mfx) / np.sum(mfx)  # MATLAB's sampled centroid
                else:  # scaled: skfuzzy's methods fail on sets of height ~1e-40
                    out[n, o] = fuzz.defuzz(y, mfx / mfx.max(), system.defuzz_method)
            else:
                kinks = _kinks(ov.fuzzy.terms, fine, system.imp_method == "min",
                               system.agg_method == "max")  # fmt: skip
                values = []
                for y in (coarse, fine):
                    y = np.unique(np.concatenate([y, kinks]))
                    mfx = np.asarray(ov.fuzzy.membership(y), dtype=float).reshape(-1)
                    values.append(_DEFUZZ[system.defuzz_method](y, mfx / mfx.max()))
                # Richardson: the interpolant's error is c h^2 + O(h^4) between kinks
                out[n, o] = values[1] + (values[1] - values[0]) / 3.0
    return out


def _breakpoints(term) -> list[float]:
    """A term's parameters and the midpoints between them (the splines of zmf, smf and
    pimf change polynomial there): where it may not be smooth."""
    p = sorted(term.params)
    return p + [0.5 * (a + b) for a, b in zip(p, p[1:], strict=False)]


def _bisect(f, a: float, b: float) -> list[float]:
    """Both ends of the last bracket of a sign change of f in [a, b]."""
    below = f(a) < 0.0
    for _ in range(200):
        m = 0.5 * (a + b)
        if not a < m < b:
            break
        if (f(m) < 0.0) == below:
            a = m
        else:
            b = m
    return [a, b]


def _kinks(activated, y: np.ndarray, clip: bool, top: bool) -> list[float]:
    """Where the aggregate of the fired rules bends besides the terms' breakpoints, found
    by bisection on fuzzylite's own membership functions between the grid points ``y``
    that bracket them:

    - ``clip`` (min implication): where a term meets its activation degree h. Missing,
      such a kink costs the piecewise-linear interpolant of the samples much more than
      its h^2 error where the rule fires weakly (h below ~1e-4): the clipped triangle has
      near-vertical sides (h times the foot-to-peak distance wide) that the interpolant
      spreads over a whole grid cell, moving the centroid by about cell / range / 2
      (2.5e-6 of the range on a 100 001-point grid at activity_mamdani0).
    - ``top`` (max aggregation): where the highest implied set changes.
    """
    pts: list[float] = []
    if clip:
        for act in activated:
            h = float(act.degree)
            if not 0.0 < h < 1.0:
                continue
            g = np.asarray(act.term.membership(y), dtype=float) - h
            f = lambda m, t=act.term, h=h: float(t.membership(m)) - h  # noqa: E731
            for i in np.nonzero(np.sign(g[:-1]) != np.sign(g[1:]))[0]:
                pts += _bisect(f, y[i], y[i + 1])
    if top and len(activated) > 1:
        sets = np.array([np.asarray(a.membership(y), dtype=float).reshape(-1) for a in activated])
        best = np.argmax(sets, axis=0)
        for i in np.nonzero((best[:-1] != best[1:]) & (sets.max(axis=0)[1:] > 0))[0]:
            p, q = activated[best[i]], activated[best[i + 1]]
            pts += _bisect(lambda m, p=p, q=q: float(p.membership(m)) - float(q.membership(m)),
                           y[i], y[i + 1])  # fmt: skip
    return pts


def _pl_centroid(y: np.ndarray, mu: np.ndarray) -> float:
    """Centroid of the piecewise-linear interpolant of (y, mu): skfuzzy's
    ``defuzz(y, mu, "centroid")``, vectorised."""
    dy = np.diff(y)
    area = 0.5 * dy * (mu[:-1] + mu[1:])
    moment = dy * (y[:-1] * (2.0 * mu[:-1] + mu[1:]) + y[1:] * (mu[:-1] + 2.0 * mu[1:])) / 6.0
    return float(np.sum(moment) / np.sum(area))


def _pl_bisector(y: np.ndarray, mu: np.ndarray) -> float:
    """Bisector of the piecewise-linear interpolant: skfuzzy's ``defuzz(y, mu,
    "bisector")``, vectorised."""
    dy = np.diff(y)
    cum = np.cumsum(0.5 * dy * (mu[:-1] + mu[1:]))
    half = 0.5 * cum[-1]
    i = int(np.searchsorted(cum, half))
    rest = half - (cum[i - 1] if i else 0.0)
    if rest <= 0.0:
        return float(y[i])
    m1, slope = mu[i], (mu[i + 1] - mu[i]) / dy[i]
    # solve m1 u + slope u^2 / 2 = rest for u in [0, dy]
    return float(y[i] + 2.0 * rest / (m1 + np.sqrt(m1 * m1 + 2.0 * slope * rest)))


_DEFUZZ = {"centroid": _pl_centroid, "bisector": _pl_bisector}


def _points(system, rng, n):
    lo = np.array([v.universe[0] for v in system.inputs])
    hi = np.array([v.universe[1] for v in system.inputs])
    pad = 0.05 * (hi - lo)
    return rng.uniform(lo - pad, hi + pad, (n, len(lo)))


def _max_strength(system, X):
    """Largest rule strength at each point (N,) (AND = min; only selects the points)."""
    lo = np.array([v.universe[0] for v in system.inputs])
    hi = np.array([v.universe[1] for v in system.inputs])
    Xc = np.clip(X, lo, hi)
    best = np.zeros(X.shape[0])
    for r in system.rules:
        mus = [
            np.asarray(system.inputs[i].terms[abs(a) - 1](Xc[:, i]))
            for i, a in enumerate(r.antecedent)
            if a != 0
        ]
        if mus:
            best = np.maximum(best, np.max(mus, axis=0) if r.connective == "or" else np.min(mus, 0))
    return best


def _readable():
    return [f for f in FILES if f.name not in REFUSED]


def test_corpus_reads_all_but_the_malformed_file():
    assert len(FILES) == 30
    for f in FILES:
        if f.name in REFUSED:
            with pytest.raises(fis.FISError) as info:
                fis.read_fis(f)
            lines = str(info.value).splitlines()
            assert lines[0].startswith(f"{f}:1: section names are case-sensitive")
            assert lines[1].startswith(f"{f}:9: OrMethod must be a quoted string")
        else:
            fis.read_fis(f)


@pytest.mark.parametrize("path", _readable(), ids=lambda p: p.stem)
def test_corpus_file_agrees_with_pyfuzzylite_and_round_trips(path):
    system = fis.read_fis(path, general=True)
    rng = np.random.default_rng(zlib.crc32(path.name.encode()))
    X = _points(system, rng, N_POINTS)
    sampled = system.defuzz_method in ("mom", "som", "lom")
    ours_sys = system.replace(samples=1001) if sampled else system
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FuzzyWarning)
        ours = ours_sys.evaluate(X)
    ref = oracle(system, X, 1001 if sampled else None)
    # A rule firing at a subnormal strength (~1e-320) gives an aggregate whose area
    # underflows to 0 in double precision (in MATLAB too): no engine defines a value there.
    levels = _max_strength(system, X)
    ours, ref = ours[levels > 1e-300], ref[levels > 1e-300]
    span = np.array([v.universe[1] - v.universe[0] for v in system.outputs])
    err = np.max(np.abs(ours - ref) / span)
    assert err <= 1e-6, f"{path.name}: max error {err:.2e} of the output range"
    # round trip: the text read back is the same system, evaluated bit for bit the same
    text = fis.to_fis_text(system)
    back = fis.read_fis(text, general=True)
    assert back == system
    assert fis.to_fis_text(back) == text
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FuzzyWarning)
        np.testing.assert_array_equal(back.evaluate(X), system.evaluate(X))


def test_oracle_defuzzifiers_are_skfuzzys():
    """The vectorised centroid and bisector of the oracle are scikit-fuzzy's, except where
    skfuzzy's bisector is wrong: when the cell before the one holding the bisector has zero
    area, skfuzzy's running area restarts from 0 there (its ``accum_area`` is only set for
    cells of positive area)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        y = np.unique(rng.uniform(-2.0, 3.0, 400))
        mu = np.clip(rng.normal(0.3, 0.4, y.size), 1e-3, 1.0)
        mu[rng.integers(0, 7) :: 7] = 0.0  # single zeros: no cell of zero area
        for method, ours in _DEFUZZ.items():
            assert ours(y, mu) == pytest.approx(fuzz.defuzz(y, mu, method), abs=1e-12)
    # triangle (area 1), a gap, a ramp and a plateau (area 1.5): half = 1.25 is reached
    # 1/sqrt(2) into the ramp [3, 4]; skfuzzy gives 4.58, outside that cell
    y, mu = np.arange(6.0), np.array([0.0, 1.0, 0.0, 0.0, 1.0, 1.0])
    assert _pl_bisector(y, mu) == pytest.approx(3.0 + 0.5**0.5, abs=1e-15)
