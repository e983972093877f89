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

from pkmctl._jit import kernel
from pkmctl.fuzzy.kernels import mf_piece

__all__ = ["MF_TYPES", "POLYNOMIAL_MFS", "check_mf", "mf_value"]

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
    if kind == _LINZ:
        if x <= a:
            return 1.0
        if x >= b:
            return 0.0
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


def breakpoints(kind: str, params: Sequence[float]) -> list[float]:
    """Points where the function is not smooth or changes monotony (its extrema).

    Between two consecutive ones the function is monotone and, for the polynomial
    kinds, one polynomial.
    """
    p = list(params)
    if kind in ("trimf", "trapmf"):
        return p[: 3 if kind == "trimf" else 4]
    if kind in ("zmf", "smf"):
        return [p[0], 0.5 * (p[0] + p[1]), p[1]]
    if kind == "pimf":
        return [p[0], 0.5 * (p[0] + p[1]), p[1], p[2], 0.5 * (p[2] + p[3]), p[3]]
    if kind in ("linzmf", "linsmf"):
        return p[:2]
    if kind == "gaussmf":
        return [p[0]]
    if kind == "gauss2mf":
        return [p[1], p[3]]
    if kind == "gbellmf":
        return [p[2]]
    if kind == "sigmf":
        return [p[1]]
    # dsigmf, psigmf: the centres and the extremum between them (golden section)
    lo, hi = min(p[1], p[3]), max(p[1], p[3])
    s1 = lambda x: 1.0 / (1.0 + math.exp(-p[0] * (x - p[1])))  # noqa: E731
    s2 = lambda x: 1.0 / (1.0 + math.exp(-p[2] * (x - p[3])))  # noqa: E731

    def f(x: float) -> float:
        return -abs(s1(x) - s2(x)) if kind == "dsigmf" else -s1(x) * s2(x)

    g = (math.sqrt(5) - 1) / 2
    a, b = lo - (hi - lo + 1.0), hi + (hi - lo + 1.0)
    for _ in range(200):
        x1, x2 = b - g * (b - a), a + g * (b - a)
        a, b = (a, x2) if f(x1) < f(x2) else (x1, b)
    return [p[1], p[3], 0.5 * (a + b)]
