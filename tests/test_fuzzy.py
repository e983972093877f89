"""Tests of pkmctl.fuzzy: membership functions, the Mamdani engine, its exact centroid, the
paper's FLC against scikit-fuzzy, and the compiled scalar path."""

import numba
import numpy as np
import pytest
import skfuzzy as fuzz
from hypothesis import given, settings
from hypothesis import strategies as st
from skfuzzy import control as ctrl

from pkmctl import fuzzy as fz

NAMES = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")
# Table 1 of the paper (DESIGN.md §3), typed again here so that a transcription error in
# pkmctl.fuzzy shows up: rows ṡ = NB..PB, columns s = NB..PB.
TABLE_1 = """
PB PB PM PM PS PS ZO
PB PM PM PS PS ZO NS
PM PM PS PS ZO NS NS
PM PS PS ZO NS NS NM
PS PS ZO NS NS NM NM
PS ZO NS NS NM NM NB
ZO NS NS NM NM NB NB
"""
RULES = [row.split() for row in TABLE_1.strip().splitlines()]


@pytest.fixture(scope="module")
def flc():
    return fz.FLC()


def sk_terms(x, lo, hi):
    """The seven terms of DESIGN.md §3 on the points x, with scikit-fuzzy: (7, len(x))."""
    c = np.linspace(lo, hi, 7)
    mfs = [fuzz.zmf(x, c[0], c[1])]
    mfs += [fuzz.trimf(x, [c[k - 1], c[k], c[k + 1]]) for k in range(1, 6)]
    mfs += [fuzz.smf(x, c[5], c[6])]
    return np.array(mfs)


def sk_flc(s, sdot, y):
    """The FLC with scikit-fuzzy's membership functions and centroid on the grid y (M,),
    for inputs s, sdot (N,): rule strengths min(μ_s, μ_ṡ), clip, max, fuzz.defuzz."""
    ms = sk_terms(np.clip(s, -1, 1), -1, 1)
    md = sk_terms(np.clip(sdot, -10, 10), -10, 10)
    levels = np.zeros((7, len(s)))  # max strength of the rules aimed at each output term
    for i in range(7):
        for j in range(7):
            k = NAMES.index(RULES[i][j])
            levels[k] = np.fmax(levels[k], np.fmin(ms[j], md[i]))
    out = sk_terms(y, -1, 1)
    agg = [np.max(np.fmin(levels[:, n, None], out), axis=0) for n in range(len(s))]
    return np.array([fuzz.defuzz(y, a, "centroid") for a in agg])


def random_inputs(rng, n):
    """Inputs over 1.5× the universes, so that some are clipped, plus the corners."""
    s = np.concatenate([rng.uniform(-1.5, 1.5, n), [-1, 1, 0, 2, -2]])
    sdot = np.concatenate([rng.uniform(-15, 15, n), [-10, 10, 0, -20, 20]])
    return s, sdot


# --- membership functions ------------------------------------------------------------


@pytest.mark.parametrize(
    ("ours", "theirs", "params"),
    [
        (fz.trimf, lambda x, p: fuzz.trimf(x, p), (-0.3, 0.2, 0.9)),
        (fz.trimf, lambda x, p: fuzz.trimf(x, p), (-0.3, -0.3, 0.5)),
        (fz.trimf, lambda x, p: fuzz.trimf(x, p), (-0.3, 0.5, 0.5)),
        (fz.trapmf, lambda x, p: fuzz.trapmf(x, p), (-0.8, -0.2, 0.1, 0.7)),
        (fz.trapmf, lambda x, p: fuzz.trapmf(x, p), (-0.8, -0.8, 0.1, 0.7)),
        (fz.gaussmf, lambda x, p: fuzz.gaussmf(x, *p), (0.2, 0.35)),
        (fz.zmf, lambda x, p: fuzz.zmf(x, *p), (-0.4, 0.6)),
        (fz.smf, lambda x, p: fuzz.smf(x, *p), (-0.4, 0.6)),
    ],
)
def test_membership_functions_match_skfuzzy(ours, theirs, params):
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.uniform(-1.2, 1.2, 2000), params, np.linspace(-1, 1, 201)])
    np.testing.assert_allclose(ours(x, *params), theirs(x, params), rtol=0, atol=1e-15)


def test_membership_functions_preserve_shape():
    x = np.linspace(-1, 1, 12).reshape(3, 4)
    for f, p in [(fz.trimf, (-1, 0, 1)), (fz.trapmf, (-1, 0, 0, 1)), (fz.gaussmf, (0, 1)),
                 (fz.zmf, (-1, 1)), (fz.smf, (-1, 1))]:  # fmt: skip
        assert f(x, *p).shape == (3, 4)
        assert f(x[:, ::2], *p).shape == (3, 2)  # non-contiguous input
        y = f(0.25, *p)
        assert isinstance(y, float) and np.ndim(y) == 0
        assert np.isnan(f(np.nan, *p))
    assert fz.smf(0.5, 0.5, 0.5) == 1.0 and fz.zmf(0.5, 0.5, 0.5) == 1.0  # MATLAB's steps


@pytest.mark.parametrize(
    ("f", "params"),
    [
        (fz.trimf, (0, -1, 1)),
        (fz.trapmf, (0, 1, 0.5, 2)),
        (fz.gaussmf, (0, 0)),
        (fz.zmf, (1, 0)),
        (fz.smf, (0, np.inf)),
    ],  # fmt: skip
)
def test_membership_functions_reject_bad_parameters(f, params):
    with pytest.raises(ValueError, match="must"):
        f(0.0, *params)


# --- the paper's FLC against scikit-fuzzy ---------------------------------------------


def test_flc_matches_skfuzzy_defuzz_on_600_random_inputs(flc):
    rng = np.random.default_rng(20240601)
    s, sdot = random_inputs(rng, 600)
    y = np.linspace(-1, 1, 6001)  # term centres k/3 lie on the grid
    ref = sk_flc(s, sdot, y)
    diff = np.max(np.abs(flc(s, sdot) - ref))
    assert diff <= 1e-3, f"max |FLC - skfuzzy| = {diff:.3e}"
    assert diff <= 1e-5, f"max |FLC - skfuzzy| = {diff:.3e} (expected ~1e-7 on this grid)"


def test_flc_matches_skfuzzy_control_system(flc):
    def add_terms(var, lo, hi):
        mfs = sk_terms(var.universe, lo, hi)
        for name, mf in zip(NAMES, mfs, strict=True):
            var[name] = mf

    # grids on which every term centre is a sample (skfuzzy interpolates memberships)
    s = ctrl.Antecedent(np.linspace(-1, 1, 6001), "s")
    sdot = ctrl.Antecedent(np.linspace(-10, 10, 6001), "sdot")
    u = ctrl.Consequent(np.linspace(-1, 1, 18001), "u", defuzzify_method="centroid")
    for var, lo, hi in ((s, -1, 1), (sdot, -10, 10), (u, -1, 1)):
        add_terms(var, lo, hi)
    rules = [
        ctrl.Rule(s[NAMES[j]] & sdot[NAMES[i]], u[RULES[i][j]]) for i in range(7) for j in range(7)
    ]
    sim = ctrl.ControlSystemSimulation(ctrl.ControlSystem(rules))
    rng = np.random.default_rng(7)
    a, b = random_inputs(rng, 40)
    ref = []
    for x1, x2 in zip(a, b, strict=True):
        sim.input["s"] = np.clip(x1, -1, 1)
        sim.input["sdot"] = np.clip(x2, -10, 10)
        sim.compute()
        ref.append(sim.output["u"])
    diff = np.max(np.abs(flc(a, b) - np.array(ref)))
    assert diff <= 1e-3, f"max |FLC - skfuzzy.control| = {diff:.3e}"


def test_flc_rule_table_is_table_1():
    assert [list(row) for row in fz.PAPER_RULE_TABLE] == RULES


# --- properties of the FLC -------------------------------------------------------------


def test_flc_odd_symmetry_zero_and_range(flc):
    rng = np.random.default_rng(3)
    s, sdot = random_inputs(rng, 20000)
    u = flc(s, sdot)
    np.testing.assert_allclose(flc(-s, -sdot), -u, rtol=0, atol=1e-12)
    assert flc(0.0, 0.0) == 0.0
    assert np.all(np.abs(u) <= 1.0)


def test_flc_monotone_in_s_at_zero_sdot(flc):
    s = np.linspace(-1.2, 1.2, 24001)
    u = flc(s, np.zeros_like(s))
    assert np.all(np.diff(u) <= 1e-12)
    assert u[0] > 0.5 > -0.5 > u[-1]  # maps positive s to negative output (Table 1)


def test_flc_shapes(flc):
    assert isinstance(flc(0.1, 2.0), float)
    assert flc(np.array(0.1), 2.0) == flc(0.1, 2.0)
    assert flc(np.zeros(5), 1.0).shape == (5,)
    assert flc(np.zeros(1), np.zeros(1)).shape == (1,)
    assert flc(np.zeros((4, 3)), np.ones((4, 3))).shape == (4, 3)
    assert flc(np.zeros((4, 1)), np.ones(3)).shape == (4, 3)
    assert flc(np.zeros(0), np.zeros(0)).shape == (0,)
    grid = flc(*np.meshgrid(np.linspace(-1, 1, 5), np.linspace(-10, 10, 7)))
    assert grid.shape == (7, 5)
    assert np.isnan(flc(np.nan, 0.0)) and np.isnan(flc(0.0, np.array([np.nan]))[0])
    assert flc(1e300, -np.inf) == flc(1.0, -10.0)  # clipped
    with pytest.raises(TypeError):
        flc(0.0)


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-1e3, 1e3, allow_nan=False),
    st.floats(-1e4, 1e4, allow_nan=False),
)
def test_flc_property_symmetry_range_and_compiled_path(s, sdot):
    flc = fz.FLC()
    u = flc(s, sdot)
    assert -1.0 <= u <= 1.0
    assert abs(flc(-s, -sdot) + u) <= 1e-12
    assert abs(fz.flc_eval(flc.compiled(), s, sdot) - u) <= 1e-12
    assert abs(flc.general(s, sdot) - u) <= 1e-12


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7))
def test_centroid_property_mirror_levels(levels):
    """The output terms are mirror images: reversing the clip levels mirrors the centroid."""
    flc = fz.FLC()
    lv = np.array(levels)
    if lv.max() == 0.0:
        assert flc.defuzzify(lv) == 0.0  # empty aggregate: midpoint of [-1, 1]
    else:
        assert abs(flc.defuzzify(lv) + flc.defuzzify(lv[::-1])) <= 1e-12


# --- compiled scalar path ------------------------------------------------------------


@numba.njit  # no cache=True: Numba's cache would not see an edit to flc_eval (DESIGN.md §6)
def _loop_flc_eval(tables, s, sdot, out):
    for n in range(s.shape[0]):
        out[n] = fz.flc_eval(tables, s[n], sdot[n])


def test_compiled_scalar_path_equals_vectorised(flc):
    rng = np.random.default_rng(11)
    s, sdot = random_inputs(rng, 5000)
    out = np.empty_like(s)
    _loop_flc_eval(flc.compiled(), s, sdot, out)
    np.testing.assert_allclose(out, flc(s, sdot), rtol=0, atol=1e-12)
    assert fz.flc_eval(flc.compiled(), 0.3, -2.0) == flc(0.3, -2.0)
    assert np.isnan(fz.flc_eval(flc.compiled(), np.nan, 0.0))
    assert fz.mamdani_eval(flc.compiled(), np.array([0.3, -2.0])) == flc(0.3, -2.0)


def test_compiled_tables_describe_the_system(flc):
    t = flc.compiled()
    assert isinstance(t, tuple) and all(isinstance(a, np.ndarray) for a in t)
    assert not any(a.flags.writeable for a in t)
    parts = t.unpack()
    assert parts["in_kind"].shape == (2, 7) and parts["rule_cons"].shape == (49,)
    assert t.ints[4] == 1  # the FLC runs on the fast kernel
    assert flc.compiled() is t  # compiled once


def random_grid_terms(rng, lo, hi, n, output):
    """n random terms on a uniform grid of [lo, hi]: term k vanishes outside (g_k-1, g_k+1).

    Output terms must also fall/rise monotonically across each cell, so an output
    trapezoid's plateau lies outside the universe (a shoulder).
    """
    g = np.linspace(lo, hi, n)
    h = g[1] - g[0]
    out = []
    for k in range(n):
        a = g[k] - h if k == 0 else g[k - 1] + rng.uniform(0, 0.3) * h
        d = g[k] + h if k == n - 1 else g[k + 1] - rng.uniform(0, 0.3) * h
        kind = rng.choice(["trimf", "trapmf", "zmf" if k == 0 else "smf"])
        if kind == "zmf" and k == 0:
            out.append(fz.Term(f"T{k}", "zmf", (g[0] - rng.uniform(0, 0.4) * h, d)))
        elif kind == "smf" and k == n - 1:
            out.append(fz.Term(f"T{k}", "smf", (a, g[k] + rng.uniform(0, 0.4) * h)))
        elif kind == "trapmf" and not output:
            b, c = np.sort(g[k] + rng.uniform(-0.3, 0.3, 2) * h)
            out.append(fz.Term(f"T{k}", "trapmf", (a, b, c, d)))
        elif kind == "trapmf" and k in (0, n - 1):
            sgn = -1 if k == 0 else 1
            b, c = np.sort([g[k], g[k] + sgn * rng.uniform(0.1, 1.0) * h])
            out.append(fz.Term(f"T{k}", "trapmf", (min(a, b), b, c, max(c, d))))
        else:
            out.append(fz.Term(f"T{k}", "trimf", (a, g[k], d)))
    return tuple(out)


def random_grid_system(rng, output_plateaus=False):
    """A random two-input system on uniform grids (fast-kernel eligible unless
    output_plateaus puts interior trapezoids among the output terms)."""
    n1, n2, K = rng.integers(2, 8, size=3)
    x1 = fz.Variable("x1", (-2.0, 3.0), random_grid_terms(rng, -2.0, 3.0, n1, False))
    x2 = fz.Variable("x2", (0.0, 1.0), random_grid_terms(rng, 0.0, 1.0, n2, False))
    y = fz.Variable("y", (-5.0, 5.0), random_grid_terms(rng, -5.0, 5.0, K, not output_plateaus))
    rules = [
        fz.Rule((i, j), int(rng.integers(K)), float(rng.choice([1.0, rng.uniform()])))
        for i in range(n1)
        for j in range(n2)
        if rng.uniform() < 0.9
    ]
    return fz.MamdaniSystem((x1, x2), y, rules or [fz.Rule((0, 0), 0)])


def test_fast_kernel_agrees_with_general_kernel_on_random_grid_systems():
    rng = np.random.default_rng(5)
    for _ in range(60):
        system = random_grid_system(rng)
        assert system.compiled().ints[4] == 1
        a, b = rng.uniform(-2.5, 3.5, 300), rng.uniform(-0.2, 1.2, 300)
        diff = np.max(np.abs(system(a, b) - system.general(a, b)))
        assert diff <= 1e-12, f"fast vs general kernel: {diff:.3e}"


def test_compiled_scalar_path_on_systems_outside_the_fast_kernel():
    rng = np.random.default_rng(8)
    n_general = 0
    for _ in range(10):
        system = random_grid_system(rng, output_plateaus=True)
        n_general += system.compiled().ints[4] == 0
        a, b = rng.uniform(-2.5, 3.5, 200), rng.uniform(-0.2, 1.2, 200)
        out = np.empty_like(a)
        _loop_flc_eval(system.compiled(), a, b, out)
        np.testing.assert_allclose(out, system(a, b), rtol=0, atol=1e-12)
    assert n_general > 0


def test_fast_kernel_agrees_with_general_kernel_on_flc(flc):
    rng = np.random.default_rng(6)
    s, sdot = random_inputs(rng, 20000)
    grid = np.meshgrid(np.linspace(-1, 1, 61), np.linspace(-10, 10, 61))  # on breakpoints
    for a, b in ((s, sdot), grid):
        np.testing.assert_allclose(flc(a, b), flc.general(a, b), rtol=0, atol=1e-12)


# --- exact centre of gravity -----------------------------------------------------------


def numeric_centroid(terms, lo, hi, levels, n=400001):
    y = np.linspace(lo, hi, n)
    agg = np.max([np.minimum(h, t(y)) for h, t in zip(levels, terms, strict=True)], axis=0)
    return np.trapezoid(y * agg, y) / np.trapezoid(agg, y)


def output_sets():
    rng = np.random.default_rng(9)
    yield "paper", fz.uniform_terms(-1.0, 1.0)
    # overlapping, unordered, non-grid piecewise-polynomial terms: the general kernel
    yield (
        "mixed",
        (
            fz.Term("a", "trapmf", (-1.2, -0.7, -0.4, 0.1)),
            fz.Term("b", "trimf", (-0.5, 0.0, 0.9)),
            fz.Term("c", "zmf", (-0.9, 0.3)),
            fz.Term("d", "smf", (-0.2, 0.6)),
            fz.Term("e", "trimf", tuple(np.sort(rng.uniform(-1, 1, 3)))),
            fz.Term("f", "trapmf", (0.5, 0.501, 0.799, 0.8)),  # steep edges
        ),
    )
    # Gaussian output terms: breakpoint-aware quadrature
    yield (
        "gauss",
        (
            fz.Term("g1", "gaussmf", (-0.5, 0.2)),
            fz.Term("g2", "gaussmf", (0.1, 0.05)),
            fz.Term("g3", "gaussmf", (0.6, 0.3)),
            fz.Term("t", "trimf", (-1.0, -0.2, 0.4)),
        ),
    )


@pytest.mark.parametrize(("label", "terms"), list(output_sets()))
def test_exact_centroid_matches_fine_numerical_integral(label, terms):
    y = fz.Variable("y", (-1.0, 1.0), terms)
    x = fz.Variable("x", (0.0, 1.0), (fz.Term("lo", "trimf", (0, 0, 1)),))
    system = fz.MamdaniSystem((x,), y, [fz.Rule((0,), 0)])
    rng = np.random.default_rng(sum(map(ord, label)))
    for trial in range(25):
        levels = rng.uniform(0, 1, len(terms)) * (rng.uniform(size=len(terms)) < 0.6)
        if trial == 0:
            levels = np.ones(len(terms))
        if not levels.any():
            continue
        exact = system.defuzzify(levels)
        ref = numeric_centroid(terms, -1.0, 1.0, levels)
        assert abs(exact - ref) <= 1e-6, f"{label}: exact {exact} vs numeric {ref}"


def test_centroid_of_vertical_edges_and_steps():
    y = fz.Variable("y", (0.0, 1.0), (
        fz.Term("box", "trapmf", (0.5, 0.5, 0.8, 0.8)),
        fz.Term("z", "zmf", (0.2, 0.2)), fz.Term("s", "smf", (0.9, 0.9))))  # fmt: skip
    x = fz.Variable("x", (0.0, 1.0), (fz.Term("lo", "trimf", (0, 0, 1)),))
    system = fz.MamdaniSystem((x,), y, [fz.Rule((0,), 0)])
    assert system.defuzzify([0.3, 0, 0]) == pytest.approx(0.65, abs=1e-15)
    assert system.defuzzify([0, 0.7, 0]) == pytest.approx(0.1, abs=1e-15)
    assert system.defuzzify([0, 0, 0.2]) == pytest.approx(0.95, abs=1e-15)
    # box on [0.5, 0.8] at 0.4 and the step on [0.9, 1] at 1: (0.12 * 0.65 + 0.1 * 0.95) / 0.22
    assert system.defuzzify([0.4, 0, 1.0]) == pytest.approx(0.173 / 0.22, abs=1e-15)


def test_defuzzify_shapes_and_empty_aggregate(flc):
    L = np.random.default_rng(2).uniform(0, 1, (4, 3, 7))
    assert flc.defuzzify(L).shape == (4, 3)
    assert flc.defuzzify(np.zeros(7)) == 0.0
    with pytest.raises(ValueError, match="levels"):
        flc.defuzzify(np.ones(6))
    with pytest.raises(ValueError, match="levels"):
        flc.defuzzify(np.full(7, 1.5))


# --- the general engine ----------------------------------------------------------------


def test_empty_aggregate_returns_output_midpoint():
    x = fz.Variable("x", (0.0, 1.0), (fz.Term("low", "trimf", (0.0, 0.0, 0.5)),))
    y = fz.Variable("y", (2.0, 6.0), (fz.Term("a", "trimf", (2.0, 3.0, 4.0)),))
    system = fz.MamdaniSystem((x,), y, [fz.Rule(("low",), "a")])
    assert system(0.9) == 4.0  # no rule fires
    assert system(0.0) == pytest.approx(3.0)
    zero_weight = fz.MamdaniSystem((x,), y, [fz.Rule(("low",), "a", 0.0)])
    assert zero_weight(0.0) == 4.0


def test_three_input_system_with_dont_care_and_weights_matches_reference():
    rng = np.random.default_rng(12)
    vars_ = [fz.Variable(f"x{i}", (-1.0, 1.0), fz.uniform_terms(-1.0, 1.0, NAMES[:5]))
             for i in range(3)]  # fmt: skip
    out = fz.Variable("y", (0.0, 10.0), (
        fz.Term("lo", "gaussmf", (2.0, 1.5)), fz.Term("mid", "trapmf", (2.0, 4.0, 6.0, 8.0)),
        fz.Term("hi", "smf", (5.0, 9.5))))  # fmt: skip
    rules = []
    for _ in range(40):
        ant = tuple(None if rng.uniform() < 0.3 else int(rng.integers(5)) for _ in range(3))
        rules.append(fz.Rule(ant, int(rng.integers(3)), float(rng.uniform(0.2, 1.0))))
    system = fz.MamdaniSystem(vars_, out, rules)
    assert system.compiled().ints[4] == 0  # general kernel
    X = rng.uniform(-1.3, 1.3, (30, 3))
    got = system(X[:, 0], X[:, 1], X[:, 2])
    y = np.linspace(0, 10, 200001)
    for n, x in enumerate(X):
        mu = [np.array([t(np.clip(x[i], -1, 1)) for t in vars_[i].terms]) for i in range(3)]
        levels = np.zeros(3)
        for r in rules:
            s = min([1.0] + [mu[i][a] for i, a in enumerate(r.antecedent) if a is not None])
            levels[r.consequent] = max(levels[r.consequent], r.weight * s)
        np.testing.assert_allclose(system.clip_levels(*x), levels, atol=1e-15)
        agg = np.max([np.minimum(h, t(y)) for h, t in zip(levels, out.terms, strict=True)], axis=0)
        ref = np.trapezoid(y * agg, y) / np.trapezoid(agg, y)
        assert abs(got[n] - ref) <= 1e-6


def test_mamdani_system_validation():
    x = fz.Variable("x", (0.0, 1.0), (fz.Term("a", "trimf", (0.0, 0.5, 1.0)),))
    with pytest.raises(ValueError, match="no term 'b'"):
        fz.MamdaniSystem((x,), x, [fz.Rule(("b",), "a")])
    with pytest.raises(ValueError, match="weight"):
        fz.MamdaniSystem((x,), x, [fz.Rule(("a",), "a", 1.5)])
    with pytest.raises(ValueError, match="antecedents"):
        fz.MamdaniSystem((x,), x, [fz.Rule(("a", "a"), "a")])
    with pytest.raises(ValueError, match="universe"):
        fz.Variable("x", (1.0, 0.0), x.terms)
    with pytest.raises(ValueError, match="unknown membership function 'custommf'"):
        fz.Term("p", "custommf", (0, 1, 2, 3))
    with pytest.raises(ValueError, match="MamdaniSystem takes trimf"):  # FuzzySystem does
        fz.MamdaniSystem((fz.Variable("p", (0, 3), (fz.Term("p", "pimf", (0, 1, 2, 3)),)),), x,
                         [((0,), 0)])  # fmt: skip
    with pytest.raises(ValueError, match="takes 3 or 4 parameters"):
        fz.Term("p", "trimf", (0, 1))
    system = fz.MamdaniSystem((x,), x, [(("a",), "a")])  # tuples are accepted as rules
    assert system.rules == (fz.Rule((0,), 0, 1.0),)


def test_a_term_index_must_be_an_integer():
    """Variable.index took int(1.9) = 1 and True as term 1 without a word, where
    FuzzySystem refuses both (a code reader)."""
    a, b = fz.Term("a", "trimf", (0.0, 0.5, 1.0)), fz.Term("b", "trimf", (0.5, 1.0, 1.5))
    x = fz.Variable("x", (0.0, 1.0), (a, b))
    for bad in (1.9, 1.0, True, "1", -1, 2):
        with pytest.raises(ValueError, match=r"term index|no term"):
            x.index(bad)
    with pytest.raises(ValueError, match=r"term index 1\.9 is not an integer in \[0, 1\]"):
        fz.MamdaniSystem((x,), x, [fz.Rule((1.9,), 1)])
    assert x.index(np.int64(1)) == 1 and x.index("b") == 1


@pytest.mark.parametrize(
    "kind, params",
    [("trimf", (0, 1, 2)), ("trimf", (0, 1, 2, 99)), ("trapmf", (0, 1, 2, 3)),
     ("pimf", (0, 1, 2, 3)), ("zmf", (1, 2)), ("linzmf", (1, 2)), ("smf", (1, 2)),
     ("linsmf", (1, 2)), ("gaussmf", (0, 20)), ("gbellmf", (1, 2, 0)),
     ("sigmf", (2, 0)), ("dsigmf", (0.5, -1, 0.5, 1)), ("psigmf", (0.5, -1, -0.5, 1)),
     ("gauss2mf", (20, -1, 20, 1))],
    # (the smooth kinds' slopes gentle enough that no membership underflows to 0 on the grid)
)  # fmt: skip
def test_a_terms_support_is_where_its_membership_is_positive(kind, params):
    """Term.support() against the membership itself on a grid: a trimf's ignored fourth
    parameter was its upper end, and pimf, linzmf and linsmf were unbounded (a code
    reader)."""
    term = fz.Term("t", kind, params)
    lo, hi = term.support()
    x = np.linspace(-50.0, 50.0, 1_000_001)  # 1e-4 apart
    positive = x[np.asarray(term(x)) > 0]
    assert (lo == -np.inf) == (positive[0] == x[0]) and (hi == np.inf) == (positive[-1] == x[-1])
    if lo > -np.inf:
        assert lo <= positive[0] <= lo + 2e-4
    if hi < np.inf:
        assert hi - 2e-4 <= positive[-1] <= hi


def test_a_grid_near_the_largest_doubles_is_finite_and_silent():
    """A .fis Range of [-1e308 1] printed numpy's overflow warnings three times (a
    fuzzer): the grid is scaled first there; elsewhere it is as before, exactly
    symmetric."""
    import warnings

    from pkmctl.fuzzy.engine import _grid_points

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = _grid_points(-1e308, 1.0, 3)
        assert np.all(np.isfinite(g)) and g[0] == -1e308 and g[-1] == 1.0
        assert np.array_equal(_grid_points(-1.0, 1.0, 5), [-1.0, -0.5, 0.0, 0.5, 1.0])
        assert np.array_equal(_grid_points(-1.7e308, 1.7e308, 3), [-1.7e308, 0.0, 1.7e308])
