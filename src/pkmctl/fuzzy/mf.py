"""The membership functions of MATLAB's Fuzzy Logic Toolbox, as one Numba kernel.

:data:`MF_TYPES` maps each toolbox name to its kernel code and parameter count. The
parameters are in MATLAB's order, except gaussmf, which pkmctl keeps as (mean, sigma)
(MATLAB writes [sigma mean]; :mod:`pkmctl.fuzzy.fis` converts). Codes 0-4 are the kinds the
exact Mamdani kernels of :mod:`pkmctl.fuzzy.kernels` integrate in closed form;
:func:`mf_value` evaluates them with the same formula (``mf_piece``), so both engines give
identical memberships.

MATLAB's definitions (``x`` the input; sig(a, c) = 1 / (1 + exp(-a (x - c)))):

- gauss2mf [s1 c1 s2 c2]: exp(-(x-c1)²/2s1²) left of c1, 1 between, exp(-(x-c2)²/2s2²) right of c2
- gbellmf [a b c]: 1 / (1 + ((x - c)/a)^(2b))
- sigmf [a c]: sig(a, c); dsigmf [a1 c1 a2 c2]: |sig(a1, c1) - sig(a2, c2)|;
  psigmf [a1 c1 a2 c2]: sig(a1, c1) · sig(a2, c2)
- pimf [a b c d]: smf(x, a, b) · zmf(x, c, d)
- linzmf [a b]: 1 up to a, linear to 0 at b; linsmf [a b]: 0 up to a, linear to 1 at b
- trimf takes a fourth parameter, which MATLAB ignores (old files have one).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pkmctl._jit import kernel
from pkmctl.fuzzy.kernels import mf_piece

__all__ = ["MF_TYPES", "POLYNOMIAL_MFS", "check_mf", "mf_value", "resolution_nodes"]

_jit = kernel(fastmath=False)

#: name -> (kernel code, fewest parameters, most parameters)
MF_TYPES: dict[str, tuple[int, int, int]] = {
    "trimf": (0, 3, 4),
    "trapmf": (1, 4, 4),
    "gaussmf": (2, 2, 2),
    "zmf": (3, 2, 2),
    "smf": (4, 2, 2),
    "gauss2mf": (5, 4, 4),
    "gbellmf": (6, 3, 3),
    "sigmf": (7, 2, 2),
    "dsigmf": (8, 4, 4),
    "psigmf": (9, 4, 4),
    "pimf": (10, 4, 4),
    "linzmf": (11, 2, 2),
    "linsmf": (12, 2, 2),
}
#: Kernel codes of the piecewise-polynomial kinds (degree <= 4), integrated exactly by
#: Gauss-Legendre quadrature between breakpoints.
POLYNOMIAL_MFS = frozenset({0, 1, 3, 4, 10, 11, 12})
_GAUSS2, _GBELL, _SIG, _DSIG, _PSIG, _PI, _LINZ, _LINS = range(5, 13)
_ORDERED = {"trimf": 3, "trapmf": 4, "zmf": 2, "smf": 2, "linzmf": 2, "linsmf": 2}


def check_mf(kind: str, params: Sequence[float]) -> tuple[float, ...]:
    """Validated parameters of a membership function (ValueError naming the problem)."""
    if kind not in MF_TYPES:
        raise ValueError(f"unknown membership function {kind!r} (supported: {', '.join(MF_TYPES)})")
    p = tuple(float(v) for v in params)
    _, lo, hi = MF_TYPES[kind]
    if not lo <= len(p) <= hi:
        n = str(lo) if lo == hi else f"{lo} or {hi}"
        raise ValueError(f"{kind} takes {n} parameters, got {len(p)}: {p}")
    if not all(math.isfinite(v) for v in p):
        raise ValueError(f"{kind} parameters must be finite, got {p}")
    if kind in _ORDERED:
        q = p[: _ORDERED[kind]]
        if any(u > v for u, v in zip(q, q[1:], strict=False)):
            raise ValueError(f"{kind} parameters must be non-decreasing, got {p}")
    elif kind == "pimf" and (p[0] > p[1] or p[2] > p[3]):
        raise ValueError(f"pimf parameters must have a <= b and c <= d, got {p}")
    elif kind == "gaussmf" and p[1] <= 0.0:
        raise ValueError(f"gaussmf sigma must be > 0, got {p[1]}")
    elif kind == "gauss2mf" and (p[0] <= 0.0 or p[2] <= 0.0):
        raise ValueError(f"gauss2mf sigmas must be > 0, got {p}")
    elif kind == "gbellmf" and p[0] == 0.0:
        raise ValueError(f"gbellmf width a must be non-zero, got {p}")
    return p


@_jit
def _sig(a, c, x):
    return 1.0 / (1.0 + math.exp(-a * (x - c)))


@_jit
def mf_value(kind, a, b, c, d, x):
    """Membership of x in the function of code ``kind`` with parameters a, b, c, d."""
    if kind <= 4:
        return mf_piece(kind, a, b, c, d, x)[0]
    if kind == _GAUSS2:
        y = 1.0
        if x <= b:
            y = math.exp(-((x - b) ** 2) / (2.0 * a * a))
        if x >= d:
            y *= math.exp(-((x - d) ** 2) / (2.0 * c * c))
        return y
    if kind == _GBELL:
        t = ((x - c) / a) ** 2
        return 1.0 / (1.0 + t**b)
    if kind == _SIG:
        return _sig(a, b, x)
    if kind == _DSIG:
        return abs(_sig(a, b, x) - _sig(c, d, x))
    if kind == _PSIG:
        return _sig(a, b, x) * _sig(c, d, x)
    if kind == _PI:
        return mf_piece(4, a, b, 0.0, 0.0, x)[0] * mf_piece(3, c, d, 0.0, 0.0, x)[0]
    if kind == _LINZ:  # 0 from b on first: [a a] is 0 at a (MATLAB: 1 below a, 0 from a)
        if x >= b:
            return 0.0
        if x <= a:
            return 1.0
        return (b - x) / (b - a)
    # _LINS
    if x >= b:
        return 1.0
    if x <= a:
        return 0.0
    return (x - a) / (b - a)


@_jit
def mf_fill(kind, a, b, c, d, x, out):
    """out[n] = mf_value(kind, a, b, c, d, x[n]) (NaN for NaN)."""
    for n in range(x.shape[0]):
        out[n] = mf_value(kind, a, b, c, d, x[n]) if x[n] == x[n] else math.nan


#: Steps, in units of a smooth term's scale, of the nodes that resolve it: a Gaussian to
#: 8 sigma (beyond, below e^-32 of its peak); a sigmoid to 32/|a| (within e^-32 of 1 or 0).
_GAUSS_STEPS = tuple(0.5 * k for k in range(1, 17))
_SIG_STEPS = (*_GAUSS_STEPS, 10.0, 12.0, 16.0, 20.0, 24.0, 32.0)


def resolution_nodes(kind: str, params: Sequence[float], h: float, width: float) -> list[float]:
    """Nodes that resolve a smooth term narrower than the quadrature panels (width h).

    Gauss-Legendre on panels of width h integrates a Gaussian of sigma >= h to rounding
    (measured: sigma = 1.3 h, 6e-13 of the range), one of sigma = h/4 only to 1e-6 and one
    of sigma = h/40 to 2e-2. Where a term's scale (sigma, 1/|a| of a sigmoid, a bell's
    |a|/max(1, |b|)) is below 2 h this gives the points at half-scale steps around its
    centre (a bell: its core, then geometric steps of sqrt(2) over its heavy tails up to
    ``width``, the universe's); otherwise none, and the panels alone do (the same
    numbers as before these nodes existed). gaussmf as (mean, sigma).
    """
    p = list(params)
    out: list[float] = []

    def around(c: float, scale: float, steps: Sequence[float]) -> None:
        if scale < 2.0 * h:
            out.extend(c + sign * scale * t for t in steps for sign in (-1.0, 1.0))

    if kind == "gaussmf":
        around(p[0], p[1], _GAUSS_STEPS)
    elif kind == "gauss2mf":
        around(p[1], p[0], _GAUSS_STEPS)
        around(p[3], p[2], _GAUSS_STEPS)
    elif kind == "sigmf":
        around(p[1], 1.0 / abs(p[0]) if p[0] else math.inf, _SIG_STEPS)
    elif kind in ("dsigmf", "psigmf"):
        for a, c in ((p[0], p[1]), (p[2], p[3])):
            around(c, 1.0 / abs(a) if a else math.inf, _SIG_STEPS)
    elif kind == "gbellmf":
        a, b, c = abs(p[0]), min(max(abs(p[1]), 1.0), 16.0), p[2]
        if a / b < 2.0 * h:
            core = [k / (4.0 * b) for k in range(1, int(8.0 * b) + 1)]  # to 2 |a|
            tail = [2.0 * math.sqrt(2.0) ** k for k in range(1, 200)]
            tail = [t for t in tail if a * t <= 2.0 * width]
            out.extend(c + sign * a * t for t in (*core, *tail) for sign in (-1.0, 1.0))
    return out


def _extrema_scan(df, lo: float, hi: float, n: int = 4000) -> list[float]:
    """Where df changes sign on [lo, hi]: a grid of n cells, then bisection."""
    out = []
    xs = [lo + (hi - lo) * k / n for k in range(n + 1)]
    gs = [df(x) for x in xs]
    for k in range(n):
        a, b, ga = xs[k], xs[k + 1], gs[k]
        if ga == 0.0 and 0 < k and gs[k - 1] * gs[k + 1] < 0.0:
            out.append(a)
        elif ga * gs[k + 1] < 0.0:
            for _ in range(100):
                m = 0.5 * (a + b)
                if not a < m < b:
                    break
                gm = df(m)
                if (gm < 0.0) == (ga < 0.0):
                    a = m
                else:
                    b = m
            out.append(0.5 * (a + b))
    return out


def _pimf_extrema(p: Sequence[float]) -> list[float]:
    """Interior extrema of smf(a, b) · zmf(c, d) where both factors vary (b > c): on each
    interval between the factors' breakpoints the product is one polynomial of degree
    <= 4 (fitted on 5 points in local coordinates, roots of its derivative, polished by
    bisection on the sign of the derivative)."""
    a, b, c, d = p
    lo, hi = max(a, c), min(b, d)
    if not lo < hi:
        return []
    knots = sorted({lo, hi, *[v for v in (0.5 * (a + b), 0.5 * (c + d)) if lo < v < hi]})
    out = []
    for u, w in zip(knots, knots[1:], strict=False):
        mid, rad = 0.5 * (u + w), 0.5 * (w - u)
        t = np.cos((2 * np.arange(5) + 1) * np.pi / 10)
        v = [mf_value(10, a, b, c, d, mid + rad * tk) for tk in t]
        cf = np.polynomial.polynomial.polyfit(t, v, 4)
        dcf = np.polynomial.polynomial.polyder(cf)

        def df(x: float, dcf=dcf, mid=mid, rad=rad) -> float:
            return float(np.polynomial.polynomial.polyval((x - mid) / rad, dcf))

        out += [x for x in _extrema_scan(df, u, w, 64) if u < x < w]
    return out


def breakpoints(kind: str, params: Sequence[float]) -> list[float]:
    """Points where the function is not smooth or changes monotony (its extrema).

    Between two consecutive ones the function is monotone and, for the polynomial
    kinds, one polynomial. Also where the factors of pimf (b > c) and gauss2mf (c1 > c2)
    overlap (the product's maximum) and where dsigmf's two sigmoids cross.
    """
    p = list(params)
    if kind in ("trimf", "trapmf"):
        return p[: 3 if kind == "trimf" else 4]
    if kind in ("zmf", "smf"):
        return [p[0], 0.5 * (p[0] + p[1]), p[1]]
    if kind == "pimf":
        pts = [p[0], 0.5 * (p[0] + p[1]), p[1], p[2], 0.5 * (p[2] + p[3]), p[3]]
        return pts + _pimf_extrema(p)
    if kind in ("linzmf", "linsmf"):
        return p[:2]
    if kind == "gaussmf":
        return [p[0]]
    if kind == "gauss2mf":
        s1, c1, s2, c2 = p
        if c1 > c2:  # overlapping tails: the product peaks between the centres
            return [c1, c2, (c1 * s2 * s2 + c2 * s1 * s1) / (s1 * s1 + s2 * s2)]
        return [c1, c2]
    if kind == "gbellmf":
        return [p[2]]
    if kind == "sigmf":
        return [p[1]]
    # dsigmf, psigmf: the centres, the crossing of the two sigmoids (dsigmf's zero) and
    # every extremum (sign changes of the derivative on a grid over where both vary)
    a1, c1, a2, c2 = p
    pts = [c1, c2]
    if kind == "dsigmf" and a1 != a2:
        pts.append((a1 * c1 - a2 * c2) / (a1 - a2))
    ends = [c + s * 40.0 / abs(a) for a, c in ((a1, c1), (a2, c2)) if a != 0.0 for s in (-1, 1)]
    if not ends:
        return pts

    def s(a: float, c: float, x: float) -> float:
        z = -a * (x - c)
        return 1.0 / (1.0 + math.exp(z)) if z < 700.0 else 0.0

    def df(x: float) -> float:
        u, v = s(a1, c1, x), s(a2, c2, x)
        if kind == "dsigmf":
            return a1 * u * (1.0 - u) - a2 * v * (1.0 - v)
        return a1 * (1.0 - u) + a2 * (1.0 - v)

    return pts + _extrema_scan(df, min(ends), max(ends))
