"""The .fis corpus (../shared/fis-corpus): every readable file agrees with an independent
engine and round-trips exactly.

The oracle is pyfuzzylite, its engine built from the parsed file (its own membership
functions, norms, activation and aggregation over rules); its aggregated fuzzy set is
sampled and defuzzified by scikit-fuzzy (``defuzz``: exact for the piecewise-linear
interpolant of the samples) on a grid of 20 001 points plus the output terms'
breakpoints. Maximum-based methods (mom, som, lom) are compared in MATLAB's sampled form
(same grid on both sides), since they are defined on samples. Sugeno outputs come from
pyfuzzylite's WeightedAverage / WeightedSum directly.
"""

import os
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest

from pkmctl.fuzzy import fis
from pkmctl.fuzzy.system import FuzzySystem, FuzzyWarning

CORPUS = Path(__file__).resolve().parents[2] / "shared" / "fis-corpus"
if not CORPUS.is_dir():
    CORPUS = Path("/work/shared/fis-corpus")
FILES = sorted(CORPUS.glob("*.fis")) if CORPUS.is_dir() else []
pytestmark = pytest.mark.skipif(not FILES, reason="no .fis corpus next to the repository")
FULL = os.environ.get("PKMCTL_FULL") == "1"
N_POINTS = 200
GRID = 100001 if FULL else 20001  # oracle grid; 200 points need the finer one
REFUSED = {"frss_malformed.fis"}  # hand-edited: [system] and OrMethod="max'

fl = pytest.importorskip("fuzzylite")
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
    grids = []
    fl_terms = [
        {t.name: _fl_term(t, eng) for t in v.terms} for v in system.outputs
    ]  # by the original names, to tell singleton terms
    for v in system.outputs:
        lo, hi = v.universe
        if samples:
            grids.append(np.linspace(lo, hi, samples))
            continue
        pts = [p for t in v.terms for p in t.params if lo <= p <= hi]
        grids.append(np.unique(np.concatenate([np.linspace(lo, hi, GRID), pts])))
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
            y = grids[o]
            mfx = np.asarray(ov.fuzzy.membership(y), dtype=float).reshape(-1)
            singletons = all(
                min(t.params) == max(t.params)
                for t in system.outputs[o].terms
                if np.any(np.asarray(fl_terms[o][t.name].membership(y)) > 0)
            )
            if not np.any(mfx > 0):
                out[n, o] = 0.5 * (lo + hi)  # no rule fired (or no sample positive)
            elif singletons or samples and system.defuzz_method == "centroid":
                out[n, o] = np.sum(y * mfx) / np.sum(mfx)  # MATLAB's sampled centroid
            else:  # scaled: skfuzzy's centroid fails on sets of height ~1e-40
                out[n, o] = fuzz.defuzz(y, mfx / mfx.max(), system.defuzz_method)
    return out


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
    X = _points(system, rng, N_POINTS if FULL or system.kind == "sugeno" else 60)
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
