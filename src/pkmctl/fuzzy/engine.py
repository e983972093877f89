"""Membership functions, a compiled Mamdani engine with exact centroid, and the paper's FLC.

The fuzzy logic controller of DESIGN.md §3 (the paper's section 3.2 and Table 1) is
``FLC()``; it is one instance of the general :class:`MamdaniSystem`:

- AND = min, implication = min (clipping), aggregation = max;
- defuzzification = centre of gravity of the aggregated set over the output universe,
  computed in closed form for piecewise-polynomial output terms (trimf, trapmf, zmf, smf)
  and by breakpoint-aware Gauss-Legendre quadrature for Gaussian output terms;
- inputs outside their universe are clipped to it; a NaN input gives NaN;
- when no rule fires (empty aggregate) the result is the midpoint of the output universe,
  as in MATLAB's Fuzzy Logic Toolbox.

The rule base is compiled once into arrays (:class:`FISTables`). Evaluation runs in Numba
kernels; :func:`flc_eval` is the scalar entry point for other ``@numba.njit`` code.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Sequence
from dataclasses import KW_ONLY, dataclass, field
from typing import NamedTuple, overload

import numpy as np
from numpy.typing import ArrayLike

from pkmctl.fuzzy.kernels import (
    FAST_SLOT,
    HEADER,
    INT_SECTIONS,
    O_NT,
    O_RIN,
    REAL_SECTIONS,
    centroid_batch,
    eval_batch,
    flc_eval,
    grid_eval_batch,
    levels_batch,
    mamdani_eval,
)
from pkmctl.fuzzy.mf import MF_TYPES, check_mf, mf_fill

__all__ = [
    "MF_KINDS",
    "FISTables",
    "FLC",
    "FuzzyWarning",
    "MamdaniSystem",
    "PAPER_RULE_TABLE",
    "Rule",
    "TERM_NAMES",
    "Term",
    "Variable",
    "flc_eval",
    "gaussmf",
    "mamdani_eval",
    "smf",
    "trapmf",
    "trimf",
    "uniform_terms",
    "zmf",
]

# The membership function kinds the exact Mamdani kernels integrate in closed form:
# MATLAB name -> (kernel code, number of parameters). Parameters follow the public
# functions below: gaussmf is (mean, sigma). Terms may use every kind of
# pkmctl.fuzzy.mf.MF_TYPES; systems with the others are pkmctl.fuzzy.system.FuzzySystem.
MF_KINDS: dict[str, tuple[int, int]] = {
    "trimf": (0, 3),
    "trapmf": (1, 4),
    "gaussmf": (2, 2),
    "zmf": (3, 2),
    "smf": (4, 2),
}


def _check_mf(kind: str, params: Sequence[float]) -> tuple[float, ...]:
    """Validated parameters of a membership function of any toolbox kind (MF_TYPES)."""
    return check_mf(kind, params)


def _membership(kind: str, params: Sequence[float], x: ArrayLike) -> np.ndarray:
    return _membership_checked(kind, _check_mf(kind, params), x)


def _membership_checked(kind: str, params: tuple[float, ...], x: ArrayLike) -> np.ndarray:
    """:func:`_membership` of parameters already validated (a Term's)."""
    p = (params + (0.0,) * 4)[:4]
    xa = np.asarray(x, dtype=np.float64)
    flat = np.ascontiguousarray(xa).reshape(-1)
    out = np.empty(flat.shape)
    mf_fill(MF_TYPES[kind][0], p[0], p[1], p[2], p[3], flat, out)
    return out.reshape(xa.shape)[()]


def trimf(x: ArrayLike, a: float, b: float, c: float) -> np.ndarray:
    """Triangular membership function, feet a and c, peak b (a <= b <= c), as MATLAB's.

    Parameters
    ----------
    x : array_like, any shape
    a, b, c : float

    Returns
    -------
    ndarray, shape of x (a NumPy float for scalar x)
    """
    return _membership("trimf", (a, b, c), x)


def trapmf(x: ArrayLike, a: float, b: float, c: float, d: float) -> np.ndarray:
    """Trapezoidal membership function: 0 at a, 1 on [b, c], 0 at d (a <= b <= c <= d).

    Parameters and shapes as :func:`trimf`.
    """
    return _membership("trapmf", (a, b, c, d), x)


def gaussmf(x: ArrayLike, mean: float, sigma: float) -> np.ndarray:
    """Gaussian membership function exp(-(x - mean)² / (2 sigma²)), sigma > 0.

    Parameters and shapes as :func:`trimf`. (MATLAB's parameter order is [sigma mean].)
    """
    return _membership("gaussmf", (mean, sigma), x)


def zmf(x: ArrayLike, a: float, b: float) -> np.ndarray:
    """Z-shaped quadratic spline: 1 up to a, 1/2 at (a + b)/2, 0 from b (a <= b).

    1 - 2((x - a)/(b - a))² on [a, (a + b)/2], 2((x - b)/(b - a))² on [(a + b)/2, b];
    a == b is a step (1 for x <= a). Parameters and shapes as :func:`trimf`.
    """
    return _membership("zmf", (a, b), x)


def smf(x: ArrayLike, a: float, b: float) -> np.ndarray:
    """S-shaped quadratic spline: 0 up to a, 1/2 at (a + b)/2, 1 from b (a <= b).

    The mirror image of :func:`zmf`: smf(x, a, b) = 1 - zmf(x, a, b) except at a step.
    Parameters and shapes as :func:`trimf`.
    """
    return _membership("smf", (a, b), x)


# ---------------------------------------------------------------------------------------
# The Mamdani system
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Term:
    """A linguistic term: a name and a membership function ``kind`` (a key of
    :data:`pkmctl.fuzzy.mf.MF_TYPES`) with ``params`` in MATLAB's order, except gaussmf:
    (mean, sigma). MamdaniSystem takes the kinds of MF_KINDS; FuzzySystem all."""

    name: str
    kind: str
    params: tuple[float, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", _check_mf(self.kind, self.params))

    def __call__(self, x: ArrayLike) -> np.ndarray:
        """Membership of x, shape of x."""
        return _membership_checked(self.kind, self.params, x)  # checked in __post_init__

    def support(self) -> tuple[float, float]:
        """Closure of the set where the membership is positive (may be infinite)."""
        p = self.params
        # (trimf's p[2], not p[-1]: MATLAB ignores a fourth parameter, which made the
        # support of (0, 1, 2, 99) reach 99; pimf, linzmf and linsmf were unbounded: a
        # code reader)
        bounds = {
            "trimf": lambda: (p[0], p[2]),
            "trapmf": lambda: (p[0], p[3]),
            "pimf": lambda: (p[0], max(p[0], p[3])),  # smf(a, b) . zmf(c, d)
            "zmf": lambda: (-np.inf, p[1]),
            "linzmf": lambda: (-np.inf, p[1]),
            "smf": lambda: (p[0], np.inf),
            "linsmf": lambda: (p[0], np.inf),
        }
        return bounds[self.kind]() if self.kind in bounds else (-np.inf, np.inf)


@dataclass(frozen=True)
class Variable:
    """A linguistic variable: a name, a universe [lo, hi] (lo < hi) and its terms."""

    name: str
    universe: tuple[float, float]
    terms: tuple[Term, ...]

    def __post_init__(self) -> None:
        lo, hi = (float(v) for v in self.universe)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(
                f"variable {self.name!r}: universe must be finite with lo < hi, got {self.universe}"
            )
        terms = tuple(self.terms)
        if not terms or len({t.name for t in terms}) != len(terms):
            raise ValueError(f"variable {self.name!r}: needs >= 1 term with unique names")
        object.__setattr__(self, "universe", (lo, hi))
        object.__setattr__(self, "terms", terms)

    @property
    def term_names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.terms)

    def index(self, term: int | str) -> int:
        """0-based index of a term given by name or index; ValueError if absent."""
        if isinstance(term, str):
            if term not in self.term_names:
                raise ValueError(
                    f"variable {self.name!r} has no term {term!r} "
                    f"(terms: {', '.join(self.term_names)})"
                )
            return self.term_names.index(term)
        # (an integer only: int(1.9) made a rule on term 1 without a word, and True was
        # term 1, where FuzzySystem refuses both: a code reader)
        if (
            isinstance(term, bool)
            or not isinstance(term, numbers.Integral)
            or not 0 <= int(term) < len(self.terms)
        ):
            raise ValueError(
                f"variable {self.name!r}: term index {term!r} is not an integer in "
                f"[0, {len(self.terms) - 1}]"
            )
        return int(term)


@dataclass(frozen=True)
class Rule:
    """IF input_1 IS antecedent[0] AND ... THEN output IS consequent, with a weight.

    Terms are given by name or 0-based index; None in the antecedent means "don't care".
    The firing strength is weight · min over the inputs (weight in [0, 1]).
    """

    antecedent: tuple[int | str | None, ...]
    consequent: int | str
    weight: float = 1.0


class FISTables(NamedTuple):
    """A compiled Mamdani system: two flat read-only arrays that fully describe it.

    ``ints`` (int64) starts with a header ``[n_in, K, R, T, fast]`` (inputs, output terms,
    rules, largest number of terms of an input, fast-kernel flag) and the offsets of the
    int sections ``in_nterms (n_in,)``, ``in_kind (n_in, T)``, ``out_kind (K,)``,
    ``rule_ant (R, n_in)`` (0-based term index, -1 = don't care), ``rule_cons (R,)``,
    ``grid_cons (G, G)``, then of the float64 sections of ``reals``: ``in_range (n_in, 2)``,
    ``grid_inv_step (n_in,)``, ``in_params (n_in, T, 4)``, ``out_range (2,)``,
    ``out_params (K, 4)``, ``rule_weight (R,)``, ``grid_weight (G, G)``, ``cells (C, 12)``.
    Kinds are the codes of MF_KINDS (-1 pads), parameters are zero-padded to 4.

    The fast kernel (``fast == 1``, G = T, C = K - 1; else G = C = 0) needs two inputs
    whose terms sit on uniform grids (term k vanishes outside (g_k-1, g_k+1)), one AND rule
    per pair of input terms (``grid_cons``/``grid_weight``, -1 = no rule) and output terms
    on a uniform grid that fall (term m) and rise (term m + 1) monotonically across each
    cell [g_m, g_m+1]; ``cells[m]`` = [g_m, g_m+1, shape, end, width of the falling ramp,
    shape, start, width of the rising one, their crossing point and value, and the
    reciprocals of the two widths] (shape 0: linear, 1: quadratic spline; the reciprocals
    are what the kernels multiply by, so that they divide by no table constant). Two
    arrays, not one per section: Numba reference-counts every array passed to a call,
    atomically, and that cost dominated with fifteen arrays.
    """

    ints: np.ndarray
    reals: np.ndarray

    def __reduce__(self):
        # Copies (pickle, copy.deepcopy) stay read-only: a writable copy is another type
        # to Numba, and every kernel that takes the tables would compile once more for it.
        return (_frozen_tables, (self.ints, self.reals))

    def unpack(self) -> dict[str, np.ndarray]:
        """Named views of the sections, with the shapes above."""
        n_in, K, R, T, fast = (int(v) for v in self.ints[:5])
        G, C = (T, K - 1) if fast else (0, 0)
        shapes = dict(
            in_nterms=(n_in,),
            in_kind=(n_in, T),
            out_kind=(K,),
            rule_ant=(R, n_in),
            rule_cons=(R,),
            grid_cons=(G, G),
            in_range=(n_in, 2),
            grid_inv_step=(n_in,),
            in_params=(n_in, T, 4),
            out_range=(2,),
            out_params=(K, 4),
            rule_weight=(R,),
            grid_weight=(G, G),
            cells=(C, 12),
        )
        out = {}
        for arr, names, first in (
            (self.ints, INT_SECTIONS, O_NT),
            (self.reals, REAL_SECTIONS, O_RIN),
        ):
            for n, name in enumerate(names):
                o = int(self.ints[first + n])
                out[name] = arr[o : o + math.prod(shapes[name])].reshape(shapes[name])
        return out


def _grid_points(lo: float, hi: float, n: int) -> np.ndarray:
    """n evenly spaced points from lo to hi, exactly symmetric if lo = -hi."""
    k = np.arange(n)
    with np.errstate(over="ignore", invalid="ignore"):  # (a .fis Range of [-1e308 1]
        g = (lo * (n - 1 - k) + hi * k) / (n - 1)  # printed numpy's overflow warnings)
    if not np.all(np.isfinite(g)):  # near the largest doubles: scaled first
        g = lo / (n - 1) * (n - 1 - k) + hi / (n - 1) * k
    return g


def _grid(var: Variable) -> np.ndarray | None:
    """The uniform grid g (K,) on the universe that the terms of var sit on, or None."""
    lo, hi = var.universe
    n = len(var.terms)
    if n < 2:
        return None
    g = _grid_points(lo, hi, n)
    tol = 8.0 * np.finfo(float).eps * (hi - lo)
    for k, term in enumerate(var.terms):
        s_lo, s_hi = term.support()
        if k > 0 and (s_lo < g[k - 1] - tol or term(g[k - 1]) != 0.0):
            return None
        if k < n - 1 and (s_hi > g[k + 1] + tol or term(g[k + 1]) != 0.0):
            return None
    return g


def _ramp(term: Term, rising: bool, g0: float, g1: float) -> tuple[int, float, float] | None:
    """(shape, foot, width) of the term as a monotone unit ramp on [g0, g1], or None.

    The foot is where the ramp is 0: its start if rising, its end if falling.
    """
    p = term.params
    tol = 8.0 * np.finfo(float).eps * (abs(g0) + abs(g1))  # grid points may differ by ulps
    if term.kind in ("trimf", "trapmf"):
        top = p[1] if rising else p[-2]  # first or last point where μ = 1
        peak_ok = top >= g1 - tol if rising else top <= g0 + tol
        ramp = (0, p[0], p[1] - p[0]) if rising else (0, p[-1], p[-1] - p[-2])
    else:
        peak_ok = term.kind == ("smf" if rising else "zmf")
        ramp = (1, p[0] if rising else p[1], p[1] - p[0])
    return ramp if peak_ok and ramp[2] > 0.0 else None


def _cells(var: Variable, g: np.ndarray) -> np.ndarray | None:
    """Per-cell data of the fast kernel (see FISTables), or None if not applicable."""
    cells = np.zeros((len(g) - 1, 12))
    for m in range(len(g) - 1):
        A, B = var.terms[m], var.terms[m + 1]
        ra, rb = _ramp(A, False, g[m], g[m + 1]), _ramp(B, True, g[m], g[m + 1])
        if ra is None or rb is None:
            return None
        lo, hi = g[m], g[m + 1]  # A - B is non-increasing: bisect for its zero
        while True:
            mid = 0.5 * (lo + hi)
            if not lo < mid < hi:
                break
            lo, hi = (mid, hi) if A(mid) > B(mid) else (lo, mid)
        cells[m] = (g[m], g[m + 1], *ra, *rb, hi, max(A(hi), B(hi)), 1.0 / ra[2], 1.0 / rb[2])
    return cells


def _compile(inputs: tuple[Variable, ...], output: Variable, rules: tuple[Rule, ...]) -> FISTables:
    n_in, K, R = len(inputs), len(output.terms), len(rules)
    T = max(len(v.terms) for v in inputs)
    in_kind = np.full((n_in, T), -1, dtype=np.int64)
    in_params = np.zeros((n_in, T, 4))
    for i, v in enumerate(inputs):
        for j, term in enumerate(v.terms):
            in_kind[i, j] = MF_KINDS[term.kind][0]
            in_params[i, j, : len(term.params)] = term.params
    out_params = np.zeros((K, 4))
    for k, term in enumerate(output.terms):
        out_params[k, : len(term.params)] = term.params
    ant = np.array([[-1 if a is None else a for a in r.antecedent] for r in rules], np.int64)
    grids = [_grid(v) for v in inputs]
    out_grid = _grid(output)
    cells = None if out_grid is None else _cells(output, out_grid)
    fast = (
        n_in == 2
        and all(g is not None for g in grids)
        and cells is not None
        and bool(np.all(ant >= 0))
        and len({tuple(a) for a in ant}) == R
    )
    G = T if fast else 0
    grid_cons = np.full((G, G), -1, dtype=np.int64)
    grid_weight = np.zeros((G, G))
    if fast:
        for a, rule in zip(ant, rules, strict=True):
            grid_cons[a[0], a[1]] = rule.consequent
            grid_weight[a[0], a[1]] = rule.weight
    int_sections = dict(
        in_nterms=[len(v.terms) for v in inputs],
        in_kind=in_kind,
        out_kind=[MF_KINDS[t.kind][0] for t in output.terms],
        rule_ant=ant,
        rule_cons=[r.consequent for r in rules],
        grid_cons=grid_cons,
    )
    real_sections = dict(
        in_range=[v.universe for v in inputs],
        grid_inv_step=[0.0 if g is None else 1.0 / (g[1] - g[0]) for g in grids],
        in_params=in_params,
        out_range=output.universe,
        out_params=out_params,
        rule_weight=[r.weight for r in rules],
        grid_weight=grid_weight,
        cells=cells if fast else np.zeros((0, 12)),
    )
    ints = [np.array([n_in, K, R, T, int(fast)] + [0] * (HEADER - 5), dtype=np.int64)]
    reals: list[np.ndarray] = []
    for parts, sections, first, dtype in (
        (ints, int_sections, O_NT, np.int64),
        (reals, real_sections, O_RIN, np.float64),
    ):
        for n, name in enumerate(INT_SECTIONS if dtype is np.int64 else REAL_SECTIONS):
            ints[0][first + n] = sum(p.size for p in parts)
            parts.append(np.asarray(sections[name], dtype=dtype).reshape(-1))
    return _frozen_tables(np.concatenate(ints), np.concatenate(reals))


def _frozen_tables(ints: np.ndarray, reals: np.ndarray) -> FISTables:
    """FISTables over the two arrays, made read-only (contiguous copies if they are not)."""
    ints, reals = np.ascontiguousarray(ints), np.ascontiguousarray(reals)
    ints.setflags(write=False)
    reals.setflags(write=False)
    return FISTables(ints, reals)


class FuzzyWarning(UserWarning):
    """An evaluation took a fallback (zero-area aggregate with firing rules)."""


def _warn_zero_area(name: str, count: int) -> None:
    if count:
        warnings.warn(
            f"{name}: {count} evaluation(s) had a zero-area aggregate although rules fired "
            "(singleton output terms): output = centroid of the point masses",
            FuzzyWarning,
            stacklevel=3,
        )


@dataclass(frozen=True)
class MamdaniSystem:
    """A Mamdani fuzzy system with one or more inputs and one output.

    Contract:

    1. AND = min (times the rule weight), implication = min, aggregation = max, centre
       of gravity over the output universe: exact for trimf/trapmf/zmf/smf output terms,
       breakpoint-aware quadrature (error << 1e-6) with Gaussian output terms.
    2. Inputs are clipped to their universes; a NaN input gives NaN.
    3. If no rule fires, the output is the midpoint of the output universe (as MATLAB);
       if rules fire but the aggregate has zero area (singleton terms, trimf [c c c]),
       the centroid of the point masses, with a :class:`FuzzyWarning`.
    4. The rule base is compiled once into :class:`FISTables` (``compiled()``);
       evaluation never loops over rules in Python.
    """

    inputs: tuple[Variable, ...]
    output: Variable
    rules: tuple[Rule, ...]
    _: KW_ONLY
    name: str = "mamdani"
    _tables: FISTables = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        inputs = tuple(self.inputs)
        if not inputs:
            raise ValueError("a Mamdani system needs at least one input")
        rules = []
        for n, r in enumerate(self.rules):
            r = r if isinstance(r, Rule) else Rule(*r)
            if len(r.antecedent) != len(inputs):
                raise ValueError(
                    f"rule {n}: {len(r.antecedent)} antecedents for {len(inputs)} inputs"
                )
            w = float(r.weight)
            if not 0.0 <= w <= 1.0:
                raise ValueError(f"rule {n}: weight must be in [0, 1], got {w}")
            ant = tuple(
                None if a is None else v.index(a) for a, v in zip(r.antecedent, inputs, strict=True)
            )
            rules.append(Rule(ant, self.output.index(r.consequent), w))
        if not rules:
            raise ValueError("a Mamdani system needs at least one rule")
        for v in (*inputs, self.output):
            for t in v.terms:
                if t.kind not in MF_KINDS or len(t.params) != MF_KINDS[t.kind][1]:
                    raise ValueError(
                        f"MamdaniSystem takes {', '.join(MF_KINDS)} terms; {v.name!r} has "
                        f"{t.kind} {t.params} (use pkmctl.fuzzy.system.FuzzySystem)"
                    )
        object.__setattr__(self, "inputs", inputs)
        object.__setattr__(self, "rules", tuple(rules))
        object.__setattr__(self, "_tables", _compile(inputs, self.output, tuple(rules)))

    def compiled(self) -> FISTables:
        """The compiled system, for :func:`flc_eval` / :func:`mamdani_eval` in njit code."""
        return self._tables

    def _stack(self, x: tuple) -> tuple[np.ndarray, tuple[int, ...]]:
        if len(x) != len(self.inputs):
            raise TypeError(f"{self.name} takes {len(self.inputs)} inputs, got {len(x)}")
        arrs = [np.asarray(v, dtype=np.float64) for v in x]
        if all(a.ndim == 0 for a in arrs):
            return np.array([arrs], dtype=np.float64).reshape(1, -1), ()
        arrs = np.broadcast_arrays(*arrs)
        return np.stack([a.reshape(-1) for a in arrs], axis=1), arrs[0].shape

    @overload
    def __call__(self, *x: float) -> float: ...
    @overload
    def __call__(self, *x: ArrayLike) -> float | np.ndarray: ...
    def __call__(self, *x: ArrayLike) -> float | np.ndarray:
        """Crisp output for inputs of any broadcastable shapes.

        Returns
        -------
        float if all inputs are scalars, else ndarray of the broadcast shape.
        """
        X, shape = self._stack(x)
        out = np.empty(X.shape[0])
        if self._tables[0][FAST_SLOT] == 1 and X.shape[1] == 2:
            grid_eval_batch(*self._tables, X, out)  # never a zero-area aggregate
        else:
            _warn_zero_area(self.name, eval_batch(*self._tables, X, out, True))
        return float(out[0]) if shape == () else out.reshape(shape)

    def general(self, *x: ArrayLike) -> float | np.ndarray:
        """As ``__call__`` but always with the general kernel (to check the fast one)."""
        X, shape = self._stack(x)
        out = np.empty(X.shape[0])
        _warn_zero_area(self.name, eval_batch(*self._tables, X, out, False))
        return float(out[0]) if shape == () else out.reshape(shape)

    def clip_levels(self, *x: ArrayLike) -> np.ndarray:
        """Clip level of each output term, shape (*broadcast shape, K)."""
        X, shape = self._stack(x)
        out = np.empty((X.shape[0], len(self.output.terms)))
        levels_batch(*self._tables, X, out)
        return out.reshape(shape + (out.shape[1],))

    def defuzzify(self, levels: ArrayLike) -> np.ndarray:
        """Centre of gravity of max_k min(levels[k], μ_k) over the output universe.

        Parameters
        ----------
        levels : array_like, shape (..., K), values in [0, 1]

        Returns
        -------
        ndarray, shape (...)
        """
        L = np.asarray(levels, dtype=np.float64)
        if (
            L.ndim == 0
            or L.shape[-1] != len(self.output.terms)
            or np.any(~(np.abs(L - 0.5) <= 0.5))
        ):
            raise ValueError(
                f"levels must have shape (..., {len(self.output.terms)}) and "
                f"values in [0, 1], got shape {L.shape}"
            )
        flat = np.ascontiguousarray(L.reshape(-1, L.shape[-1]))
        out = np.empty(flat.shape[0])
        t = self._tables.unpack()
        centroid_batch(t["out_kind"], t["out_params"], *self.output.universe, flat, out)
        return out.reshape(L.shape[:-1])[()]


# ---------------------------------------------------------------------------------------
# The paper's fuzzy logic controller (DESIGN.md §3)
# ---------------------------------------------------------------------------------------

TERM_NAMES = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")

# Table 1 of the paper: rows ṡ* = NB..PB, columns s* = NB..PB, entries the output term.
PAPER_RULE_TABLE = (
    ("PB", "PB", "PM", "PM", "PS", "PS", "ZO"),  # ṡ* = NB
    ("PB", "PM", "PM", "PS", "PS", "ZO", "NS"),  # ṡ* = NM
    ("PM", "PM", "PS", "PS", "ZO", "NS", "NS"),  # ṡ* = NS
    ("PM", "PS", "PS", "ZO", "NS", "NS", "NM"),  # ṡ* = ZO
    ("PS", "PS", "ZO", "NS", "NS", "NM", "NM"),  # ṡ* = PS
    ("PS", "ZO", "NS", "NS", "NM", "NM", "NB"),  # ṡ* = PM
    ("ZO", "NS", "NS", "NM", "NM", "NB", "NB"),  # ṡ* = PB
)


def uniform_terms(lo: float, hi: float, names: Sequence[str] = TERM_NAMES) -> tuple[Term, ...]:
    """Terms centred on len(names) evenly spaced points c_0 = lo ... c_n-1 = hi.

    Interior terms are triangles with feet at the neighbouring centres; the first is
    zmf(c_0, c_1), the last smf(c_n-2, c_n-1) (DESIGN.md §3).
    """
    n = len(names)
    if n < 2:
        raise ValueError(f"uniform_terms needs >= 2 names, got {n}")
    c = _grid_points(lo, hi, n)
    return (
        (Term(names[0], "zmf", (c[0], c[1])),)
        + tuple(Term(names[k], "trimf", (c[k - 1], c[k], c[k + 1])) for k in range(1, n - 1))
        + (Term(names[-1], "smf", (c[-2], c[-1])),)
    )


def FLC() -> MamdaniSystem:
    """The paper's fuzzy logic controller u = FLC(s*, ṡ*) (DESIGN.md §3, Table 1).

    s* ∈ [-1, 1], ṡ* ∈ [-10, 10], u ∈ [-1, 1], seven terms NB..PB each
    (:func:`uniform_terms`). ``FLC()(s, sdot)`` takes scalars or arrays;
    ``flc_eval(FLC().compiled(), s, sdot)`` is the same from njit code.
    """
    s = Variable("s", (-1.0, 1.0), uniform_terms(-1.0, 1.0))
    sdot = Variable("sdot", (-10.0, 10.0), uniform_terms(-10.0, 10.0))
    u = Variable("u", (-1.0, 1.0), uniform_terms(-1.0, 1.0))
    rules = tuple(
        Rule((s_term, sdot_term), PAPER_RULE_TABLE[i][j])
        for i, sdot_term in enumerate(TERM_NAMES)
        for j, s_term in enumerate(TERM_NAMES)
    )
    return MamdaniSystem((s, sdot), u, rules, name="paper_flc")
