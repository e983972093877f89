"""Speed of the paper's FLC: pkmctl's compiled and batched paths against scikit-fuzzy and simpful.

Run ``python -m benchmarks.bench_fuzzy [--quick]`` or ``pkmctl bench``; both call :func:`run`.
All engines evaluate the same rule base (DESIGN.md §3, Table 1) on the same inputs; the
maximum difference to pkmctl's exact centroid is reported beside each time.
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.timing import best_time
from pkmctl._jit import kernel
from pkmctl.fuzzy import FLC, PAPER_RULE_TABLE, TERM_NAMES, flc_eval
from pkmctl.fuzzy.term import term_eval, term_system, term_work


@kernel
def _loop(tables, s, sdot):
    acc = 0.0
    for n in range(s.shape[0]):
        acc += flc_eval(tables, s[n], sdot[n])
    return acc


@kernel(refcount=False)
def _term_loop(tables, work, s, sdot):
    """The fuzzy term's call (FSMC/AFSMC, pkmctl.fuzzy.term) as the control loop makes it:
    compiled without reference counting, the work made once."""
    acc = 0.0
    for n in range(s.shape[0]):
        acc += term_eval(tables, work, s[n], sdot[n])
    return acc


def term_us(system, n: int, *, repeats: int = 3, seed: int = 0) -> tuple[float, float]:
    """(random, smooth): microseconds per evaluation of ``system`` as the fuzzy term of
    FSMC/AFSMC runs it (:func:`pkmctl.fuzzy.term.term_system`), from compiled code, on n
    random inputs over 1.2 times its input ranges and on a smooth trajectory over them."""
    run = term_system(system)
    tables = run.compiled()
    work = term_work(tables)
    (a0, a1), (b0, b1) = (v.universe for v in run.inputs)
    ca, ra, cb, rb = 0.5 * (a0 + a1), 0.6 * (a1 - a0), 0.5 * (b0 + b1), 0.6 * (b1 - b0)
    rng = np.random.default_rng(seed)
    x1, x2 = ca + rng.uniform(-ra, ra, n), cb + rng.uniform(-rb, rb, n)
    t = np.arange(n) * 50e-6  # 20 kHz
    y1, y2 = ca + 0.8 * ra * np.sin(2 * t), cb + 0.8 * rb * np.cos(3 * t)
    _term_loop(tables, work, x1[:10], x2[:10])  # compile
    return tuple(
        best_time(lambda u=u, v=v: _term_loop(tables, work, u, v), repeats) / n * 1e6
        for u, v in ((x1, x2), (y1, y2))
    )


def _skfuzzy_flc():
    """The FLC as a scikit-fuzzy ControlSystemSimulation on fine universes."""
    import skfuzzy as fuzz
    from skfuzzy import control as ctrl

    def add_terms(var, lo, hi):
        c = np.linspace(lo, hi, 7)
        var["NB"] = fuzz.zmf(var.universe, c[0], c[1])
        for k in range(1, 6):
            var[TERM_NAMES[k]] = fuzz.trimf(var.universe, [c[k - 1], c[k], c[k + 1]])
        var["PB"] = fuzz.smf(var.universe, c[5], c[6])

    s = ctrl.Antecedent(np.linspace(-1, 1, 6001), "s")
    sdot = ctrl.Antecedent(np.linspace(-10, 10, 6001), "sdot")
    u = ctrl.Consequent(np.linspace(-1, 1, 18001), "u", defuzzify_method="centroid")
    for var, lo, hi in ((s, -1, 1), (sdot, -10, 10), (u, -1, 1)):
        add_terms(var, lo, hi)
    rules = [
        ctrl.Rule(s[TERM_NAMES[j]] & sdot[TERM_NAMES[i]], u[PAPER_RULE_TABLE[i][j]])
        for i in range(7)
        for j in range(7)
    ]
    sim = ctrl.ControlSystemSimulation(ctrl.ControlSystem(rules))

    def evaluate(a: float, b: float) -> float:
        sim.input["s"] = float(np.clip(a, -1, 1))
        sim.input["sdot"] = float(np.clip(b, -10, 10))
        sim.compute()
        return float(sim.output["u"])

    return evaluate


def _simpful_flc():
    """The FLC in simpful: zmf/smf exactly (as custom membership functions); simpful's
    Mamdani centroid is a discrete sum over 1000 points of the output universe."""
    import simpful as sf

    class _Spline(sf.MF_object):
        def __init__(self, a: float, b: float, rising: bool) -> None:
            self.a, self.b, self.rising = a, b, rising

        def _execute(self, x: float) -> float:
            t = min(max((x - self.a) / (self.b - self.a), 0.0), 1.0)
            up = 2 * t * t if t <= 0.5 else 1 - 2 * (1 - t) ** 2
            return up if self.rising else 1.0 - up

    def variable(lo: float, hi: float) -> sf.LinguisticVariable:
        c = np.linspace(lo, hi, 7)
        sets = [sf.FuzzySet(function=_Spline(c[0], c[1], False), term="NB")]
        sets += [
            sf.FuzzySet(function=sf.Triangular_MF(c[k - 1], c[k], c[k + 1]), term=TERM_NAMES[k])
            for k in range(1, 6)
        ]
        sets += [sf.FuzzySet(function=_Spline(c[5], c[6], True), term="PB")]
        return sf.LinguisticVariable(sets, universe_of_discourse=[lo, hi])

    fs = sf.FuzzySystem(show_banner=False, verbose=False)
    fs.add_linguistic_variable("s", variable(-1, 1))
    fs.add_linguistic_variable("sdot", variable(-10, 10))
    fs.add_linguistic_variable("u", variable(-1, 1))
    rules = [
        f"IF (s IS {TERM_NAMES[j]}) AND (sdot IS {TERM_NAMES[i]}) THEN (u IS {row[j]})"
        for i, row in enumerate(PAPER_RULE_TABLE)
        for j in range(7)
    ]
    fs.add_rules(rules, verbose=False)

    def evaluate(a: float, b: float) -> float:
        fs.set_variable("s", float(np.clip(a, -1, 1)), verbose=False)
        fs.set_variable("sdot", float(np.clip(b, -10, 10)), verbose=False)
        return float(fs.Mamdani_inference(["u"], ignore_warnings=True)["u"])

    return evaluate


def run(quick: bool = False, *, echo: bool = False) -> dict:
    """Measure (and print if ``echo``); return the numbers (times in microseconds per evaluation).

    Returns
    -------
    dict
        ``compiled_us``: one ``flc_eval`` call from an njit loop over 10^6 random inputs
        (10^5 if quick); ``compiled_smooth_us``: the same on a smooth trajectory, as in the
        control loop; ``term_us``, ``term_smooth_us``: the same through the fuzzy term's
        entry point (``term_eval``, what FSMC/AFSMC call), ``term_general_us``,
        ``term_general_smooth_us``: the paper's FLC on the general engine there (what a
        ``.fis`` system outside the fast kernel costs; 10^5 inputs, 10^4 if quick);
        ``batched_us``: per point of ``flc(s, sdot)`` on 10^5 points;
        ``python_scalar_us``: one ``flc(s, sdot)`` call from Python; ``skfuzzy_us`` and
        ``simpful_us`` (if installed) with ``skfuzzy_max_diff``/``simpful_max_diff`` to
        pkmctl, and the ratios ``ratio_<peer>_over_compiled``, ``ratio_<peer>_over_batched``.
    """
    flc = FLC()
    tables = flc.compiled()
    rng = np.random.default_rng(0)
    n_loop = 10**5 if quick else 10**6
    s = rng.uniform(-1.2, 1.2, n_loop)
    sdot = rng.uniform(-12.0, 12.0, n_loop)
    t = np.arange(n_loop) * 50e-6  # 20 kHz
    s_smooth, sdot_smooth = 0.8 * np.sin(2 * t), 8.0 * np.cos(3 * t)
    _loop(tables, s[:10], sdot[:10])  # compile
    out: dict = {}
    out["compiled_us"] = best_time(lambda: _loop(tables, s, sdot), 3) / n_loop * 1e6
    out["compiled_smooth_us"] = (
        best_time(lambda: _loop(tables, s_smooth, sdot_smooth), 3) / n_loop * 1e6
    )
    out["term_us"], out["term_smooth_us"] = term_us(flc, n_loop)
    general = term_system(flc, engine="general")
    out["term_general_us"], out["term_general_smooth_us"] = term_us(general, n_loop // 10)
    nb = 10**5
    flc(s[:nb], sdot[:nb])
    out["batched_us"] = best_time(lambda: flc(s[:nb], sdot[:nb]), 3) / nb * 1e6
    pairs = list(zip(s[:1000].tolist(), sdot[:1000].tolist(), strict=True))
    out["python_scalar_us"] = best_time(lambda: [flc(a, b) for a, b in pairs], 3) * 1e3

    n_ref = 10 if quick else 40
    ours = flc(s[:n_ref], sdot[:n_ref])
    for name, make in (("skfuzzy", _skfuzzy_flc), ("simpful", _simpful_flc)):
        try:
            evaluate = make()
        except ImportError as exc:  # optional dependencies (the "bench" extra)
            out[f"{name}_error"] = f"not available ({exc})"
            continue
        evaluate(0.1, 0.2)
        t0 = time.perf_counter()
        ref = np.array([evaluate(a, b) for a, b in zip(s[:n_ref], sdot[:n_ref], strict=True)])
        out[f"{name}_us"] = (time.perf_counter() - t0) / n_ref * 1e6
        out[f"{name}_max_diff"] = float(np.max(np.abs(ref - ours)))
        out[f"ratio_{name}_over_compiled"] = out[f"{name}_us"] / out["compiled_us"]
        out[f"ratio_{name}_over_batched"] = out[f"{name}_us"] / out["batched_us"]

    lines = [
        "pkmctl FLC (paper, DESIGN.md §3), exact centroid, per evaluation:",
        f"  compiled flc_eval in an njit loop : {out['compiled_us'] * 1e3:8.1f} ns (random inputs)",
        f"                                      {out['compiled_smooth_us'] * 1e3:8.1f} ns (smooth)",
        f"  as FSMC's fuzzy term (term_eval)  : {out['term_us'] * 1e3:8.1f} ns (random inputs)",
        f"                                      {out['term_smooth_us'] * 1e3:8.1f} ns (smooth)",
        f"  the same on the general engine    : {out['term_general_us']:8.2f} us (random inputs)",
        f"                                      {out['term_general_smooth_us']:8.2f} us (smooth)",
        f"  batched flc(s, sdot), 1e5 points  : {out['batched_us'] * 1e3:8.1f} ns",
        f"  flc(s, sdot) from Python, scalar  : {out['python_scalar_us']:8.2f} us",
    ]
    for name, what in (
        ("skfuzzy", "scikit-fuzzy ControlSystemSimulation (universes of 6001/6001/18001 points)"),
        ("simpful", "simpful Mamdani (zmf/smf exact, as custom functions; its centroid is a "
         "discrete sum over 1000 points of the output universe, hence the larger difference)"),
    ):  # fmt: skip
        if f"{name}_us" in out:
            lines += [
                f"  {what}:",
                f"    {out[f'{name}_us'] / 1e3:.2f} ms, max |diff| {out[f'{name}_max_diff']:.1e}, "
                f"{out[f'ratio_{name}_over_compiled']:,.0f}x compiled, "
                f"{out[f'ratio_{name}_over_batched']:,.0f}x batched",
            ]
    if echo:
        print("\n".join(lines))
    return out


CORPUS_FILE = "bank_choice4.fis"  # 4 inputs, 81 rules, trapmf/trimf, centroid


def run_corpus(path, n: int = 200, *, echo: bool = False) -> dict:
    """Time a 4-input, 81-rule corpus file with pkmctl, scikit-fuzzy and pyfuzzylite.

    Returns microseconds per evaluation: ``pkmctl_exact_us`` (MamdaniSystem, closed-form
    centroid), ``pkmctl_general_us`` (FuzzySystem kernels), ``skfuzzy_us``,
    ``fuzzylite_us``, and each peer's ``*_max_diff`` to pkmctl.
    """
    import logging

    root = logging.getLogger()
    handlers = list(root.handlers)
    import fuzzylite as fl  # the oracle of tests/test_fis_corpus.py

    root.handlers[:] = handlers  # its import adds one: Dask's INFO records would print
    import skfuzzy as fuzz
    from skfuzzy import control as ctrl

    from pkmctl.fuzzy.fis import read_fis

    general = read_fis(path, general=True)
    exact = read_fis(path)
    rng = np.random.default_rng(0)
    lo = np.array([v.universe[0] for v in general.inputs])
    hi = np.array([v.universe[1] for v in general.inputs])
    X = rng.uniform(lo, hi, (n, len(lo)))
    out: dict = {}
    general.evaluate(X[:2])
    out["pkmctl_general_us"] = best_time(lambda: general.evaluate(X), 3) / n * 1e6
    ref = general.evaluate(X)[:, 0]
    cols = [X[:, i] for i in range(X.shape[1])]
    exact(*cols)
    out["pkmctl_exact_us"] = best_time(lambda: exact(*cols), 3) / n * 1e6
    out["pkmctl_exact_max_diff"] = float(np.max(np.abs(exact(*cols) - ref)))

    ants = []
    for i, v in enumerate(general.inputs):
        a = ctrl.Antecedent(np.linspace(*v.universe, 2001), f"in{i}")
        for k, t in enumerate(v.terms):
            a[f"t{k}"] = getattr(fuzz, t.kind)(a.universe, list(t.params))
        ants.append(a)
    ov = general.outputs[0]
    cons = ctrl.Consequent(np.linspace(*ov.universe, 20001), "out")
    for k, t in enumerate(ov.terms):
        cons[f"t{k}"] = getattr(fuzz, t.kind)(cons.universe, list(t.params))
    rules = []
    for r in general.rules:
        terms = [ants[i][f"t{a - 1}"] for i, a in enumerate(r.antecedent) if a > 0]
        ante = terms[0]
        for t in terms[1:]:
            ante = ante & t
        rules.append(ctrl.Rule(ante, cons[f"t{r.consequent[0] - 1}"]))
    sim = ctrl.ControlSystemSimulation(ctrl.ControlSystem(rules))
    m = min(n, 50)

    def sk_all():
        res = []
        for x in X[:m]:
            for i, v in enumerate(x):
                sim.input[f"in{i}"] = v
            sim.compute()
            res.append(sim.output["out"])
        return np.array(res)

    t0 = time.perf_counter()
    sk = sk_all()
    out["skfuzzy_us"] = (time.perf_counter() - t0) / m * 1e6
    out["skfuzzy_max_diff"] = float(np.max(np.abs(sk - ref[:m])))

    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_fis_corpus import _safe_names, fuzzylite_engine

    eng = fuzzylite_engine(_safe_names(general))
    eng.output_variables[0].defuzzifier = fl.Centroid(20000)

    def fl_all():
        res = []
        with np.errstate(divide="ignore", invalid="ignore"):  # pyfuzzylite's own setting
            for x in X[:m]:
                for iv, v in zip(eng.input_variables, x, strict=True):
                    iv.value = v
                eng.process()
                res.append(float(np.asarray(eng.output_variables[0].value).reshape(-1)[0]))
        return np.array(res)

    t0 = time.perf_counter()
    fz = fl_all()
    out["fuzzylite_us"] = (time.perf_counter() - t0) / m * 1e6
    out["fuzzylite_max_diff"] = float(np.max(np.abs(fz - ref[:m])))
    if echo:
        print(f"{Path(path).name}: 4 inputs, {len(general.rules)} rules, per evaluation:")
        print(f"  pkmctl MamdaniSystem (closed-form centroid): {out['pkmctl_exact_us']:9.2f} us")
        print(f"  pkmctl FuzzySystem (general kernels)       : {out['pkmctl_general_us']:9.2f} us")
        print(f"  scikit-fuzzy (output grid 20001)           : {out['skfuzzy_us']:9.1f} us, "
              f"max |diff| {out['skfuzzy_max_diff']:.1e}")  # fmt: skip
        print(f"  pyfuzzylite (Centroid resolution 20000)    : {out['fuzzylite_us']:9.1f} us, "
              f"max |diff| {out['fuzzylite_max_diff']:.1e}")  # fmt: skip
    return out
