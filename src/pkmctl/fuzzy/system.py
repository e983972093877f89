"""General fuzzy systems: the Mamdani and Sugeno systems of MATLAB's Fuzzy Logic Toolbox.

:class:`FuzzySystem` is what :func:`pkmctl.fuzzy.fis.read_fis` returns for files outside the
subset of :class:`pkmctl.fuzzy.MamdaniSystem`. It is compiled once into two flat arrays
(:class:`SystemTables`) and evaluated by the Numba kernels of
:mod:`pkmctl.fuzzy.general`, which never loop over rules in Python;
``fis_eval(system.compiled(), x, out)`` is the entry point for compiled code.

Semantics (MATLAB's unless said; the selectable ones are fields):

1. A rule's strength is weight · AND (min or prod) or OR (max or probor) over its
   antecedents; a negated antecedent (NOT, a negative index) uses 1 - μ; don't-care
   antecedents (0) are left out.
2. Mamdani: each rule implies (min or prod) its strength on its consequent term of each
   output (1 - μ if negated); the implied sets of all rules are aggregated (max, sum or
   probor) and defuzzified (centroid, bisector, mom, som, lom).
3. Sugeno: each rule's output is its constant or linear term at the inputs; wtaver is
   Σ w z / Σ w, wtsum Σ w z.
4. ``input_range``: ``"clip"`` (default; as the paper's FLC) clips inputs to their
   ranges before anything else, ``"raw"`` uses them as given (MATLAB).
5. ``samples``: ``None`` (default) defuzzifies the continuous aggregate (exact to
   rounding for polynomial terms, see :mod:`pkmctl.fuzzy.general`); an integer n
   samples it at ``linspace(lo, hi, n)`` as MATLAB does (n = 101 there).
6. No rule fired for an output: the middle of its range (as MATLAB).
7. Rules fire but the aggregate has zero area (singleton terms such as trimf [c c c]):
   the centroid of the point masses, Σ y μ(y) / Σ μ(y) over the singletons (the limit
   of MATLAB's sampled centroid when the singletons are samples), the bisector their
   weighted median, and a :class:`FuzzyWarning`.
8. som and lom are the smallest and largest point of the maximum set (current MATLAB and
   fuzzylite; MATLAB before R2019 took the smallest/largest *absolute* value).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import KW_ONLY, dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from pkmctl.fuzzy.engine import FuzzyWarning, MamdaniSystem, Term, Variable
from pkmctl.fuzzy.general import (
    AGG_CODES,
    AND_CODES,
    CONSTANT,
    DEFUZZ_CODES,
    HEADER,
    IMP_CODES,
    LINEAR,
    OR_CODES,
    PANELS,
    eval_batch,
    fis_eval,
)
from pkmctl.fuzzy.mf import MF_TYPES, POLYNOMIAL_MFS, breakpoints, resolution_nodes

__all__ = [
    "FuzzyRule",
    "FuzzySystem",
    "FuzzyWarning",
    "SugenoTerm",
    "SystemTables",
    "fis_eval",
]

INPUT_RANGES = ("clip", "raw")


@dataclass(frozen=True)
class SugenoTerm:
    """A Sugeno output term: ``constant`` (params (c,)) or ``linear`` (params
    (p_1, ..., p_n, c), z = Σ p_i x_i + c over the n inputs)."""

    name: str
    kind: str
    params: tuple[float, ...]

    def __post_init__(self) -> None:
        if self.kind not in ("constant", "linear"):
            raise ValueError(f"Sugeno term {self.name!r}: kind must be constant or linear")
        p = tuple(float(v) for v in self.params)
        if not p or not all(math.isfinite(v) for v in p):
            raise ValueError(f"Sugeno term {self.name!r}: needs finite parameters, got {p}")
        if self.kind == "constant" and len(p) != 1:
            raise ValueError(f"constant term {self.name!r} takes 1 parameter, got {len(p)}")
        object.__setattr__(self, "params", p)


@dataclass(frozen=True)
class FuzzyRule:
    """A rule in MATLAB's coding: one signed 1-based term index per input and per
    output (0 = don't care / no consequent, negative = NOT), a weight in [0, 1] and the
    connective ``"and"`` or ``"or"``."""

    antecedent: tuple[int, ...]
    consequent: tuple[int, ...]
    weight: float = 1.0
    connective: str = "and"


class SystemTables(NamedTuple):
    """A compiled :class:`FuzzySystem`: two flat read-only arrays (layout in
    :mod:`pkmctl.fuzzy.general`: header slots, then the sections at the offsets the
    header gives)."""

    ints: np.ndarray
    reals: np.ndarray

    def __reduce__(self):
        return (_frozen, (self.ints, self.reals))


def _frozen(ints: np.ndarray, reals: np.ndarray) -> SystemTables:
    ints, reals = np.ascontiguousarray(ints), np.ascontiguousarray(reals)
    ints.setflags(write=False)
    reals.setflags(write=False)
    return SystemTables(ints, reals)


def _choice(name: str, value: str, allowed: dict | tuple) -> None:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(allowed)}, got {value!r}")


@dataclass(frozen=True)
class FuzzySystem:
    """A Mamdani or Sugeno system with any number of inputs and outputs (module docstring).

    Parameters
    ----------
    inputs : sequence of Variable
    outputs : sequence of Variable
        Mamdani: terms are :class:`~pkmctl.fuzzy.Term`; Sugeno: :class:`SugenoTerm`.
    rules : sequence of FuzzyRule
    kind : "mamdani" or "sugeno"
    and_method, or_method, imp_method, agg_method, defuzz_method : str
        The toolbox's names (min/prod, max/probor, min/prod, max/sum/probor,
        centroid/bisector/mom/som/lom for Mamdani, wtaver/wtsum for Sugeno).
    input_range : "clip" or "raw"
    samples : None or int >= 3
    """

    inputs: tuple[Variable, ...]
    outputs: tuple[Variable, ...]
    rules: tuple[FuzzyRule, ...]
    _: KW_ONLY
    kind: str = "mamdani"
    name: str = "fis"
    and_method: str = "min"
    or_method: str = "max"
    imp_method: str = "min"
    agg_method: str = "max"
    defuzz_method: str = "centroid"
    input_range: str = "clip"
    samples: int | None = None
    _tables: SystemTables = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        inputs, outputs = tuple(self.inputs), tuple(self.outputs)
        rules = tuple(r if isinstance(r, FuzzyRule) else FuzzyRule(*r) for r in self.rules)
        _choice("kind", self.kind, ("mamdani", "sugeno"))
        _choice("and_method", self.and_method, AND_CODES)
        _choice("or_method", self.or_method, OR_CODES)
        _choice("imp_method", self.imp_method, IMP_CODES)
        _choice("agg_method", self.agg_method, AGG_CODES)
        sugeno = self.kind == "sugeno"
        _choice(
            "defuzz_method",
            self.defuzz_method,
            ("wtaver", "wtsum") if sugeno else tuple(DEFUZZ_CODES)[:5],
        )
        _choice("input_range", self.input_range, INPUT_RANGES)
        if self.samples is not None and (int(self.samples) != self.samples or self.samples < 3):
            raise ValueError(f"samples must be None or an integer >= 3, got {self.samples!r}")
        if not inputs or not outputs:
            raise ValueError("a fuzzy system needs at least one input and one output")
        for v in outputs:
            for t in v.terms:
                if isinstance(t, SugenoTerm) != sugeno:
                    raise ValueError(
                        f"output {v.name!r}: term {t.name!r} is not a "
                        f"{'Sugeno' if sugeno else 'membership function'} term"
                    )
                if sugeno and t.kind == "linear" and len(t.params) != len(inputs) + 1:
                    raise ValueError(
                        f"linear term {t.name!r} needs {len(inputs) + 1} parameters "
                        f"(one per input and a constant), got {len(t.params)}"
                    )
        for n, r in enumerate(rules):
            if len(r.antecedent) != len(inputs) or len(r.consequent) != len(outputs):
                raise ValueError(
                    f"rule {n + 1}: needs {len(inputs)} antecedents and {len(outputs)} consequents"
                )
            if not 0.0 <= float(r.weight) <= 1.0:
                raise ValueError(f"rule {n + 1}: weight must be in [0, 1], got {r.weight}")
            _choice(f"rule {n + 1} connective", r.connective, ("and", "or"))
            for idx, v in zip(r.antecedent + r.consequent, inputs + outputs, strict=True):
                if abs(int(idx)) > len(v.terms) or int(idx) != idx:
                    raise ValueError(f"rule {n + 1}: term index {idx} out of range for {v.name!r}")
            if sugeno and any(c < 0 for c in r.consequent):
                raise ValueError(f"rule {n + 1}: a Sugeno consequent cannot be negated")
        object.__setattr__(self, "inputs", inputs)
        object.__setattr__(self, "outputs", outputs)
        object.__setattr__(self, "rules", rules)
        object.__setattr__(self, "_tables", _compile(self))

    @classmethod
    def from_mamdani(cls, system: MamdaniSystem, **options) -> FuzzySystem:
        """The same system for the general engine (options: input_range, samples, name)."""
        rules = tuple(
            FuzzyRule(tuple(0 if a is None else a + 1 for a in r.antecedent),
                      (r.consequent + 1,), r.weight)
            for r in system.rules
        )  # fmt: skip
        options.setdefault("name", system.name)
        return cls(system.inputs, (system.output,), rules, **options)

    def replace(self, **changes) -> FuzzySystem:
        """A copy with some fields changed, e.g. ``replace(samples=101, input_range="raw")``."""
        return dataclasses.replace(self, **changes)

    def compiled(self) -> SystemTables:
        """The compiled system, for :func:`fis_eval` in njit code."""
        return self._tables

    def evaluate(self, X: ArrayLike) -> np.ndarray:
        """Crisp outputs at the rows of X.

        Parameters
        ----------
        X : array_like, shape (N, n_inputs)

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """
        return self._evaluate(X, stacklevel=3)

    def _evaluate(self, X: ArrayLike, stacklevel: int) -> np.ndarray:
        Xa = np.ascontiguousarray(X, dtype=np.float64)
        if Xa.ndim != 2 or Xa.shape[1] != len(self.inputs):
            raise ValueError(f"X must have shape (N, {len(self.inputs)}), got {Xa.shape}")
        out = np.empty((Xa.shape[0], len(self.outputs)))
        flags = eval_batch(*self._tables, Xa, out)
        if flags:
            warnings.warn(
                f"{self.name}: {flags} evaluation(s) had a zero-area aggregate although rules "
                "fired (singleton output terms): output = centroid of the point masses",
                FuzzyWarning,
                stacklevel=stacklevel,
            )
        return out

    def __call__(self, *x: ArrayLike) -> float | np.ndarray:
        """Outputs for inputs of any broadcastable shapes: a float (scalar inputs) or an
        array of the broadcast shape for one output; shape (*broadcast, n_outputs) for
        several."""
        if len(x) != len(self.inputs):
            raise TypeError(f"{self.name} takes {len(self.inputs)} inputs, got {len(x)}")
        arrs = np.broadcast_arrays(*[np.asarray(v, dtype=np.float64) for v in x])
        shape = arrs[0].shape
        X = np.stack([a.reshape(-1) for a in arrs], axis=1)
        out = self._evaluate(X, stacklevel=3)
        if len(self.outputs) == 1:
            return float(out[0, 0]) if shape == () else out[:, 0].reshape(shape)
        return out.reshape(shape + (len(self.outputs),))


def _mf_code(term) -> int:
    if isinstance(term, SugenoTerm):
        return CONSTANT if term.kind == "constant" else LINEAR
    return MF_TYPES[term.kind][0]


def _params4(term: Term) -> list[float]:
    return (list(term.params) + [0.0] * 4)[:4]


def _compile(system: FuzzySystem) -> SystemTables:
    inputs, outputs, rules = system.inputs, system.outputs, system.rules
    n_in, n_out, R = len(inputs), len(outputs), len(rules)
    T = max(len(v.terms) for v in inputs)
    KO = max(len(v.terms) for v in outputs)
    P = max(4, n_in + 1)
    sugeno = system.kind == "sugeno"
    in_kind = np.zeros((n_in, T), np.int64)
    in_par = np.zeros((n_in, T, 4))
    for i, v in enumerate(inputs):
        for j, t in enumerate(v.terms):
            in_kind[i, j] = _mf_code(t)
            in_par[i, j] = _params4(t)
    out_kind = np.zeros((n_out, KO), np.int64)
    out_par = np.zeros((n_out, KO, P))
    bps: list[list[float]] = []
    poly = []
    most = 0  # the most breakpoints of one term: bounds its clip points (new_work)
    for o, v in enumerate(outputs):
        pts: list[float] = []
        lo, hi = v.universe
        for k, t in enumerate(v.terms):
            out_kind[o, k] = _mf_code(t)
            out_par[o, k, : len(t.params)] = t.params
            if not sugeno:
                p = list(t.params)
                if t.kind == "gaussmf":
                    p = [p[0], p[1]]
                own = breakpoints(t.kind, p)
                most = max(most, len(own))
                pts += own
                pts += [y for y in resolution_nodes(t.kind, p, (hi - lo) / PANELS, hi - lo)
                        if lo < y < hi]  # fmt: skip
        bps.append(sorted(set(pts)))
        poly.append(int(not sugeno and all(_mf_code(t) in POLYNOMIAL_MFS for t in v.terms)))
    B = max(1, max(len(b) for b in bps))
    bp = np.zeros((n_out, B))
    for o, b in enumerate(bps):
        bp[o, : len(b)] = b
    ints_sec = [
        [len(v.terms) for v in inputs],
        in_kind,
        [len(v.terms) for v in outputs],
        out_kind,
        np.array([r.antecedent for r in rules], np.int64).reshape(R, n_in),
        np.array([r.consequent for r in rules], np.int64).reshape(R, n_out),
        [int(r.connective == "or") for r in rules],
        [len(b) for b in bps],
        poly,
    ]
    reals_sec = [
        [v.universe for v in inputs],
        in_par,
        [v.universe for v in outputs],
        out_par,
        [float(r.weight) for r in rules],
        bp,
    ]
    header = np.zeros(HEADER, np.int64)
    header[:15] = [
        n_in, n_out, R, T, KO, P, B, int(sugeno),
        AND_CODES[system.and_method], OR_CODES[system.or_method], IMP_CODES[system.imp_method],
        AGG_CODES[system.agg_method], DEFUZZ_CODES[system.defuzz_method],
        int(system.input_range == "clip"), 0 if system.samples is None else int(system.samples),
    ]  # fmt: skip
    header[HEADER - 1] = most
    int_parts = [np.asarray(s, np.int64).reshape(-1) for s in ints_sec]
    real_parts = [np.asarray(s, np.float64).reshape(-1) for s in reals_sec]
    pos = HEADER
    for n, part in enumerate(int_parts):
        header[15 + n] = pos
        pos += part.size
    pos = 0
    for n, part in enumerate(real_parts):
        header[15 + len(int_parts) + n] = pos
        pos += part.size
    return _frozen(np.concatenate([header, *int_parts]), np.concatenate(real_parts))


def as_general(system: MamdaniSystem | FuzzySystem, **options) -> FuzzySystem:
    """A :class:`FuzzySystem` for either kind of system (options as FuzzySystem fields)."""
    if isinstance(system, FuzzySystem):
        return system.replace(**options) if options else system
    return FuzzySystem.from_mamdani(system, **options)
