"""The general engine's continuous defuzzification is exact where the aggregate bends or
peaks inside a breakpoint interval: interior maxima (mom/som/lom), two crossings of implied
sets in one interval, and non-monotone pimf/gauss2mf/dsigmf terms. Oracle: the aggregate
written out here, integrated by scipy's adaptive quad; maxima by a dense grid refined by a
bounded scalar search."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pkmctl.fuzzy.fis import read_fis

scipy = pytest.importorskip("scipy")
from scipy import integrate, optimize  # noqa: E402

# an oracle that could not reach its tolerance (a kink inside a panel) is no oracle
pytestmark = pytest.mark.filterwarnings("error::scipy.integrate.IntegrationWarning")

HEAD = """[System]
Name='t'
Type='mamdani'
NumInputs=1
NumOutputs=1
NumRules={nr}
AndMethod='min'
OrMethod='max'
ImpMethod='{imp}'
AggMethod='{agg}'
DefuzzMethod='{defuzz}'

[Input1]
Name='x'
Range=[0 1]
NumMFs=1
MF1='any':'trimf',[-1 0.5 2]

[Output1]
Name='y'
Range=[{lo} {hi}]
NumMFs={nt}
{mfs}

[Rules]
{rules}
"""


def _smf(a, b, y):
    if y <= a:
        return 0.0
    if y >= b:
        return 1.0
    m = 0.5 * (a + b)
    return 2 * ((y - a) / (b - a)) ** 2 if y <= m else 1 - 2 * ((b - y) / (b - a)) ** 2


def _sig(a, c, y):
    z = -a * (y - c)
    return 1 / (1 + math.exp(z)) if z < 700 else 0.0


def _mf(kind, p, y):
    if kind == "trimf":
        a, b, c = p[:3]
        return max(
            0.0, min((y - a) / (b - a) if b > a else 1.0, (c - y) / (c - b) if c > b else 1.0)
        )
    if kind == "smf":
        return _smf(p[0], p[1], y)
    if kind == "zmf":
        return 1 - _smf(p[0], p[1], y)
    if kind == "pimf":
        return _smf(p[0], p[1], y) * (1 - _smf(p[2], p[3], y))
    if kind == "gauss2mf":
        s1, c1, s2, c2 = p
        v = math.exp(-((y - c1) ** 2) / (2 * s1 * s1)) if y <= c1 else 1.0
        return v * (math.exp(-((y - c2) ** 2) / (2 * s2 * s2)) if y >= c2 else 1.0)
    if kind == "dsigmf":
        return abs(_sig(p[0], p[1], y) - _sig(p[2], p[3], y))
    if kind == "psigmf":
        return _sig(p[0], p[1], y) * _sig(p[2], p[3], y)
    if kind == "sigmf":
        return _sig(p[0], p[1], y)
    if kind == "gaussmf":  # MATLAB's [sigma mean]
        return math.exp(-((y - p[1]) ** 2) / (2 * p[0] * p[0]))
    if kind == "gbellmf":
        return 1 / (1 + abs((y - p[2]) / p[0]) ** (2 * p[1]))
    raise AssertionError(kind)


def _case(terms, weights, imp="min", agg="max", lo=0.0, hi=10.0):
    """(.fis text builder, aggregate function) of one input fully firing rules k -> term k
    with the given weights."""
    mfs = "\n".join(
        f"MF{k + 1}='t{k}':'{kind}',[{' '.join(repr(v) for v in p)}]"
        for k, (kind, p) in enumerate(terms)
    )
    rules = "\n".join(f"1, {k + 1} ({w!r}) : 1" for k, w in enumerate(weights))

    def text(defuzz):
        return HEAD.format(nr=len(weights), imp=imp, agg=agg, defuzz=defuzz, lo=lo, hi=hi,
                           nt=len(terms), mfs=mfs, rules=rules)  # fmt: skip

    def aggregate(y):
        zs = [min(w, _mf(k, p, y)) if imp == "min" else w * _mf(k, p, y)
              for (k, p), w in zip(terms[: len(weights)], weights, strict=True)]  # fmt: skip
        if agg == "max":
            return max(zs)
        if agg == "sum":
            return sum(zs)
        v = 0.0
        for z in zs:
            v = v + z - v * z
        return v

    return text, aggregate, (lo, hi)


def _engine(text, defuzz):
    return float(read_fis(text(defuzz), general=True)(0.5))


def _pts(lo, hi):
    return list(np.linspace(lo, hi, 41)[1:-1])


def _kinks(terms, weights, imp="min", agg="max", lo=0.0, hi=10.0):
    """Where the aggregate of these rules has a kink, for quad's break points (a kink
    inside a panel costs quad its precision): the terms' parameters (and the joints of
    the s-curves' halves), where a term crosses its clip level (min), and where two rules'
    outputs cross (max) or two sigmoids of a dsigmf do. Found as sign changes on a grid
    with 1e-5 spacing near each parameter, then bisected."""
    params = sorted({v for _, p in terms for v in p if lo < v < hi})
    for kind, p in terms:
        if kind in ("smf", "zmf", "pimf"):
            params += [0.5 * (p[0] + p[1])] + ([0.5 * (p[2] + p[3])] if kind == "pimf" else [])
    ys = np.union1d(
        np.linspace(lo, hi, 20_001),
        np.concatenate([np.linspace(c - 0.05, c + 0.05, 10_001) for c in params]),
    )
    ys = ys[(ys >= lo) & (ys <= hi)]
    rules = list(zip(terms[: len(weights)], weights, strict=True))

    def out(k, p, w):
        return (lambda y: min(w, _mf(k, p, y))) if imp == "min" else lambda y: w * _mf(k, p, y)

    diffs = []
    for k, p in terms:
        if k == "dsigmf":
            diffs.append(lambda y, p=p: _sig(p[0], p[1], y) - _sig(p[2], p[3], y))
    if imp == "min":
        diffs += [lambda y, k=k, p=p, w=w: _mf(k, p, y) - w for (k, p), w in rules]
    if agg == "max":
        outs = [out(k, p, w) for (k, p), w in rules]
        diffs += [
            lambda y, a=a, b=b: a(y) - b(y) for i, a in enumerate(outs) for b in outs[i + 1 :]
        ]
    found = list(params)
    for d in diffs:
        v = np.array([d(y) for y in ys])
        for j in np.flatnonzero(np.sign(v[:-1]) * np.sign(v[1:]) < 0):
            found.append(optimize.brentq(d, ys[j], ys[j + 1], xtol=1e-15))
    return sorted({float(y) for y in found if lo < y < hi})


def _centroid(f, lo, hi, kinks=()):
    pts = sorted({*_pts(lo, hi), *kinks})
    kw = dict(points=pts, limit=1000, epsabs=1e-14, epsrel=1e-13)
    m0 = integrate.quad(f, lo, hi, **kw)[0]
    m1 = integrate.quad(lambda y: y * f(y), lo, hi, **kw)[0]
    return m1 / m0, m0


def _bisector(f, lo, hi, kinks=()):
    _, m0 = _centroid(f, lo, hi, kinks)
    kw = dict(limit=1000, epsabs=1e-14, epsrel=1e-13)

    def g(z):
        pts = [p for p in sorted({*_pts(lo, hi), *kinks}) if p < z]
        return integrate.quad(f, lo, z, points=pts or None, **kw)[0] - 0.5 * m0

    return optimize.brentq(g, lo, hi, xtol=1e-14)


def _argmax(f, lo, hi):
    ys = np.linspace(lo, hi, 200_001)
    v = np.array([f(y) for y in ys])
    k = int(np.argmax(v))
    h = ys[1] - ys[0]
    r = optimize.minimize_scalar(lambda y: -f(y), bounds=(max(lo, ys[k] - h), min(hi, ys[k] + h)),
                                 method="bounded", options={"xatol": 1e-12})  # fmt: skip
    return r.x if -r.fun >= v[k] else ys[k]


SUM_POLY = dict(terms=[("zmf", [0, 10]), ("trimf", [0, 10, 20])], weights=[1.0, 0.4])
CROSS_MIN = dict(terms=[("smf", [0, 1]), ("trimf", [0.075, 0.9083333333333333, 2])],
                 weights=[1.0, 1.0], lo=0.0, hi=0.9)  # fmt: skip
CROSS2 = dict(terms=[("smf", [0, 1]), ("trimf", [-0.02, 1.18, 2])], weights=[0.5, 0.6],
              imp="prod", lo=0.0, hi=1.0)  # fmt: skip
PIMF = dict(terms=[("pimf", [0, 6, 3, 10]), ("trimf", [0, 1, 2])], weights=[0.7])
G2 = dict(terms=[("gauss2mf", [1, 6, 1.5, 3]), ("trimf", [0, 1, 2])], weights=[0.7])
G2_CLIP = dict(terms=[("gauss2mf", [1, 6, 1.5, 3]), ("trimf", [0, 1, 2])], weights=[0.2])
DSIG = dict(terms=[("dsigmf", [2.4781, 2.144, -618.0329, 2.214])], weights=[0.028],
            lo=2.11, hi=2.25)  # fmt: skip


@pytest.mark.parametrize(
    ("case", "imp", "agg", "truth"),
    [(SUM_POLY, "prod", "sum", 1.0), (SUM_POLY, "min", "sum", 2.5),
     (SUM_POLY, "prod", "probor", None), (PIMF, "min", "max", None),
     (PIMF, "prod", "max", None)],
)  # fmt: skip
@pytest.mark.parametrize("defuzz", ["mom", "som", "lom"])
def test_interior_maximum(case, imp, agg, truth, defuzz):
    c = {**case, "imp": imp, "agg": agg}
    text, f, (lo, hi) = _case(**c)
    got = _engine(text, defuzz)
    if imp == "min" and case is PIMF:  # a plateau at the clip level
        ys = np.linspace(lo, hi, 400_001)
        v = np.array([f(y) for y in ys])
        top = ys[v >= v.max() * (1 - 1e-12)]
        want = {"mom": 0.5 * (top[0] + top[-1]), "som": top[0], "lom": top[-1]}[defuzz]
        assert got == pytest.approx(want, abs=2 * (hi - lo) / 400_000)
        return
    want = _argmax(f, lo, hi) if truth is None else truth
    assert got == pytest.approx(want, abs=1e-6 * (hi - lo))


@pytest.mark.parametrize(
    "case", [CROSS_MIN, CROSS2, PIMF, {**PIMF, "imp": "prod"}, G2_CLIP, DSIG,
             {**SUM_POLY, "agg": "sum"}],
)  # fmt: skip
@pytest.mark.parametrize("defuzz", ["centroid", "bisector"])
def test_centroid_bisector(case, defuzz):
    text, f, (lo, hi) = _case(**case)
    got = _engine(text, defuzz)
    kinks = _kinks(**case)
    want = _centroid(f, lo, hi, kinks)[0] if defuzz == "centroid" else _bisector(f, lo, hi, kinks)
    assert got == pytest.approx(want, abs=1e-8 * (hi - lo))


# Terms narrower than the general engine's quadrature panels (range/256 = 0.039 here):
# before the resolution nodes, sigma = 0.003 was off by 1e-3 of the range, sigma = 0.01
# by 2.5e-6. Each case: its terms (two rules of unequal weights) and where the oracle's
# quad must look (the terms' centres).
NARROW = {
    "gaussmf": ([("gaussmf", [0.003, 3.001]), ("gaussmf", [0.004, 7.3])], [3.001, 7.3]),
    "gauss2mf": ([("gauss2mf", [0.003, 3.0, 0.004, 3.01]), ("gaussmf", [0.002, 7.3])],
                 [3.0, 3.01, 7.3]),
    "gbellmf": ([("gbellmf", [0.004, 2, 3.001]), ("gbellmf", [0.006, 1.5, 7.3])], [3.001, 7.3]),
    "sigmf": ([("sigmf", [500, 3.001]), ("sigmf", [-400, 7.3])], [3.001, 7.3]),
    "dsigmf": ([("dsigmf", [500, 3.0, 500, 3.02]), ("gaussmf", [0.005, 7.3])], [3.0, 3.02, 7.3]),
    "psigmf": ([("psigmf", [500, 3.0, -500, 3.02]), ("gaussmf", [0.005, 7.3])], [3.0, 3.02, 7.3]),
}  # fmt: skip


def _narrow_oracle(f, centres, lo=0.0, hi=10.0, kinks=()):
    """Centroid and bisector of f by quad, with break points every 0.0005 around each
    centre (out to 0.2, where every narrow term here is flat to 1e-14) and at ``kinks``."""
    near = {round(c + 0.0005 * k, 10) for c in centres for k in range(-400, 401)}
    pts = sorted(p for p in near | set(kinks) if lo < p < hi)
    kw = dict(limit=20_000, epsabs=1e-15, epsrel=1e-13)

    def integral(g, z):
        return integrate.quad(g, lo, z, points=[p for p in pts if p < z] or None, **kw)[0]

    m0 = integral(f, hi)
    centroid = integral(lambda y: y * f(y), hi) / m0
    bisector = optimize.brentq(lambda z: integral(f, z) - 0.5 * m0, lo, hi, xtol=1e-13)
    return centroid, bisector


@pytest.mark.parametrize("kind", list(NARROW))
@pytest.mark.parametrize(("imp", "agg"), [("min", "max"), ("prod", "max"), ("prod", "sum"),
                                          ("min", "probor")])  # fmt: skip
def test_terms_narrower_than_a_panel(kind, imp, agg):
    terms, centres = NARROW[kind]
    text, f, (lo, hi) = _case(terms, [0.7, 0.35], imp=imp, agg=agg)
    centroid, bisector = _narrow_oracle(f, centres, kinks=_kinks(terms, [0.7, 0.35], imp, agg))
    assert _engine(text, "centroid") == pytest.approx(centroid, abs=1e-10 * (hi - lo))
    assert _engine(text, "bisector") == pytest.approx(bisector, abs=1e-9 * (hi - lo))


@pytest.mark.parametrize("sigma", [0.01, 0.003, 0.001])
def test_narrow_gaussians_in_the_mamdani_engine(sigma):
    """The Mamdani engine (min, max, centroid) integrates Gaussians on panels of
    range/512 and gets the same resolution nodes."""
    from pkmctl.fuzzy import MamdaniSystem

    terms = [("gaussmf", [sigma, 3.001]), ("gaussmf", [sigma, 7.3])]
    text, f, (lo, hi) = _case(terms, [0.7, 0.35])
    system = read_fis(text("centroid"))
    assert isinstance(system, MamdaniSystem)
    centroid, _ = _narrow_oracle(f, [3.001, 7.3], kinks=_kinks(terms, [0.7, 0.35]))
    assert float(system(0.5)) == pytest.approx(centroid, abs=1e-10 * (hi - lo))


SMOOTH_PEAKS = [
    dict(terms=[("gaussmf", [1.5, 4]), ("gaussmf", [1.5, 6.1])], weights=[0.63, 0.37],
         imp="prod", agg="sum"),
    dict(terms=[("gaussmf", [1.0, 4]), ("gbellmf", [1.2, 2, 5.5])], weights=[0.6, 0.5],
         imp="prod", agg="probor"),
    dict(terms=[("sigmf", [3, 4]), ("gaussmf", [0.8, 5.0])], weights=[0.5, 0.7],
         imp="prod", agg="sum"),
]  # fmt: skip


@pytest.mark.parametrize("case", range(len(SMOOTH_PEAKS)))
@pytest.mark.parametrize("defuzz", ["mom", "som", "lom"])
def test_smooth_interior_maximum(case, defuzz):
    """A maximum of a sum or probor of smooth terms lies between the panels' samples: it
    used to be reported at the nearest sample (8e-4 of the range off, the first case)."""
    text, f, (lo, hi) = _case(**SMOOTH_PEAKS[case])
    assert _engine(text, defuzz) == pytest.approx(_argmax(f, lo, hi), abs=1e-7 * (hi - lo))
