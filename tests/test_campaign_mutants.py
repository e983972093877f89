"""Mutation-guided checks of the campaign statistics (stats.py) and the campaign spec
(spec.py): each test pins a behaviour that docs/campaigns.md, DESIGN.md §8 or the
modules' own docstrings state, recomputed by hand from made-up records (no run)."""

import functools
import math

import numpy as np
import pyarrow as pa
import pytest
from scipy import stats as sps

from pkmctl.campaign import CampaignSpec, SpecError, stats
from pkmctl.campaign.spec import MAX_RUNS
from pkmctl.campaign.store import factor_column, factor_value, metric_columns, schema

HEAD = 'scenario = "paper"\nduration = 0.05\n'


@functools.cache
def _spec(text: str) -> CampaignSpec:
    return CampaignSpec.from_toml(text)


def _table(spec, value, status=None, present=None, message=None) -> pa.Table:
    """Made-up records: ``value(cell, controller, seed, column)`` for each metric column
    of an ok run, ``status(cell, controller, seed)`` (default "ok"), only the runs where
    ``present(...)`` (default all), ``message(...)`` for a run not ok."""
    sch = schema(spec)
    cols = metric_columns(spec.metrics)
    rows = []
    for cell in range(len(spec.cells)):
        for ctrl in spec.controllers:
            for seed in spec.seeds:
                key = (cell, ctrl, seed)
                if present is not None and not present(*key):
                    continue
                st = status(*key) if status else "ok"
                msg = "" if st == "ok" else (message(*key) if message else "ValueError: no")
                row = {"spec_hash": spec.digest, "cell": cell, "controller": ctrl,
                       "seed": seed, "task": 0, "status": st, "diverged_at": None,
                       "message": msg, "wall_s": 0.0, "kernel_s": 0.0, "worker": "w"}  # fmt: skip
                for p in spec.factors:
                    row[factor_column(p)] = factor_value(spec, p, spec.cells[cell][p])
                for c in cols:
                    row[c] = value(*key, c) if st == "ok" else None
                rows.append(row)
    return pa.Table.from_pylist(rows, schema=sch)


# ---------------------------------------------------------------- the intervals


def _hesterberg(n: int) -> float:
    return math.sqrt(n / (n - 1)) * sps.t.ppf(0.975, n - 1) / sps.norm.ppf(0.975)


def test_expansion_is_hesterbergs_factor():
    """docs/campaigns.md: sqrt(n/(n-1)) t_{n-1,0.975} / z_0.975: 1.58 at n = 5, 1.29 at
    8, 1.22 at 10, 1.10 at 20; 1.0 where there is no interval (n < 2)."""
    for n in (2, 3, 5, 8, 10, 20, 200):
        assert stats.expansion(n) == pytest.approx(_hesterberg(n), rel=1e-12), n
    assert [round(stats.expansion(n), 2) for n in (5, 8, 10, 20)] == [1.58, 1.29, 1.22, 1.10]
    assert stats.expansion(1) == 1.0 and stats.expansion(0) == 1.0


def _interval_by_hand(x: np.ndarray, seed: int) -> tuple[float, float]:
    """docs/campaigns.md: the 2.5 and 97.5 % percentiles of 2000 seeded resampled means,
    widened about the sample mean by Hesterberg's factor, and further where that is
    narrower than Student's t interval of the same values (ddof 1)."""
    n = x.size
    idx = np.random.default_rng(seed).integers(0, n, size=(2000, n))
    plo, phi = np.percentile(x[idx].mean(axis=1), [2.5, 97.5])
    m = x.mean()
    t_width = 2 * sps.t.ppf(0.975, n - 1) * sps.sem(x)
    k = max(_hesterberg(n), t_width / (phi - plo))
    return m + k * (plo - m), m + k * (phi - m)


@pytest.mark.parametrize(
    "x",
    [
        np.random.default_rng(1).normal(3.0, 1.0, 12),  # the widening decides
        np.array([0.0] * 11 + [50.0]),  # heavy-tailed: Student's t floor decides
        np.random.default_rng(2).lognormal(0.0, 1.2, 7),  # skewed: asymmetric
    ],
    ids=["normal", "heavy-tail", "skewed"],
)
def test_the_interval_of_a_mean_is_recomputed_by_hand(x):
    lo, hi = stats.bootstrap_interval(x, seed=17)
    want = _interval_by_hand(x, 17)
    assert (lo, hi) == pytest.approx(want, rel=1e-9, abs=1e-12)
    # never narrower than Student's t interval (the floor); it holds the sample mean
    t_lo, t_hi = sps.t.interval(0.95, x.size - 1, loc=x.mean(), scale=sps.sem(x))
    assert hi - lo >= (t_hi - t_lo) * (1 - 1e-12)
    assert lo < x.mean() < hi
    # each row of bootstrap_intervals is bootstrap_interval of that row
    rows = np.vstack([x, x[::-1] * 2.0])
    los, his = stats.bootstrap_intervals(rows, seed=17)
    assert (los[0], his[0]) == (lo, hi)
    assert (los[1], his[1]) == stats.bootstrap_interval(rows[1], seed=17)


def test_one_value_a_row_has_no_interval():
    """bootstrap_intervals: NaN if n < 2 (one value has no spread to resample)."""
    lo, hi = stats.bootstrap_intervals(np.array([[1.0], [2.0]]), seed=0)
    assert np.isnan(lo).all() and np.isnan(hi).all()
    assert all(math.isnan(v) for v in stats.bootstrap_interval(np.array([1.0]), seed=0))


def _ratio_by_hand(num, den, seed):
    """The pairs resampled together; widened about mean(num)/mean(den) as a mean, with
    the delta method's standard error; on the log scale when every resampled ratio is
    positive."""
    n = num.size
    idx = np.random.default_rng(seed).integers(0, n, size=(2000, n))
    ratios = num[idx].mean(axis=1) / den[idx].mean(axis=1)
    plo, phi = np.percentile(ratios, [2.5, 97.5])
    c = num.mean() / den.mean()
    se = np.std((num - c * den) / den.mean(), ddof=1) / math.sqrt(n)
    t = sps.t.ppf(0.975, n - 1)
    if c > 0 and plo > 0:
        lc, ll, lh = math.log(c), math.log(plo), math.log(phi)
        k = max(_hesterberg(n), 2 * t * (se / c) / (lh - ll))
        return math.exp(lc + k * (ll - lc)), math.exp(lc + k * (lh - lc))
    k = max(_hesterberg(n), 2 * t * se / (phi - plo))
    return c + k * (plo - c), c + k * (phi - c)


def test_the_ratio_interval_is_recomputed_by_hand():
    rng = np.random.default_rng(5)
    den = rng.lognormal(0.0, 0.5, 9) * np.array([1, 1, 2, 2, 5, 5, 10, 10, 50])
    num = 0.7 * den * rng.lognormal(0.0, 0.4, 9)
    got = stats.bootstrap_ratio_interval(num, den, seed=3)
    assert got == pytest.approx(_ratio_by_hand(num, den, 3), rel=1e-9)
    assert 0 < got[0] < num.mean() / den.mean() < got[1]
    # a numerator of both signs: some resampled ratios are negative, widened linearly
    num2 = np.array([3.0, -2.0, 1.0, -1.0, 2.0, 0.5])
    den2 = np.ones(6)
    lo, hi = stats.bootstrap_ratio_interval(num2, den2, seed=4)
    assert math.isfinite(lo) and lo < 0 < num2.mean() < hi
    assert (lo, hi) == pytest.approx(_ratio_by_hand(num2, den2, 4), rel=1e-9)
    # heavy-tailed: the floor (the delta method's standard error) decides, on the log
    # scale (every resampled ratio positive) and linearly (some negative)
    for top in (np.array([1.0] * 11 + [20.0]), np.array([-1.0] * 11 + [30.0])):
        got = stats.bootstrap_ratio_interval(top, np.ones(12), seed=4)
        assert got == pytest.approx(_ratio_by_hand(top, np.ones(12), 4), rel=1e-9)


# ---------------------------------------------------------------- which metrics


def test_headline_is_over_the_whole_run_unless_every_cell_passes_1_s():
    """docs/campaigns.md: the RMSE after 1 s only when the runs of every cell last longer
    than 1 s; a timing.duration factor of 0.6 and 1.5 s compares both over the whole run."""
    text = (HEAD + 'controllers = ["smc", "pd"]\nmetrics = ["rmse", "rmse_after_1s"]\n'
            '[factors."timing.duration"]\nvalues = [0.6, 1.5]\n')  # fmt: skip
    spec = _spec(text)
    table = _table(spec, lambda cell, c, s, col: None if "after" in col and cell == 0 else 1.0)
    assert stats.headline_metrics(spec, table) == ["rmse_z_mm", "rmse_alpha_deg", "rmse_beta_deg"]
    long = _spec(text.replace("[0.6, 1.5]", "[1.2, 1.5]"))
    table = _table(long, lambda *k: 1.0)
    assert stats.headline_metrics(long, table) == [
        "rmse_after_1s_z_mm",
        "rmse_after_1s_alpha_deg",
        "rmse_after_1s_beta_deg",
    ]


def test_without_an_error_metric_the_headline_is_the_first_kept_group():
    spec = _spec(HEAD + 'controllers = ["smc"]\nmetrics = ["chattering_N_per_s", "peak_force_N"]\n')
    table = _table(spec, lambda *k: 1.0)
    assert stats.headline_metrics(spec, table) == [f"chattering_N_per_s_{k}" for k in range(1, 5)]


def test_actuator_metrics_are_every_limb_with_a_value():
    """Each of the four limbs, chattering then peak force; a column with some values (a
    run failed) is kept, one with none is not."""
    text = HEAD + 'controllers = ["smc", "pd"]\nseeds = 3\n'
    spec = _spec(text + 'metrics = ["rmse", "chattering_N_per_s", "peak_force_N"]\n')
    table = _table(
        spec,
        lambda cell, c, s, col: None if col == "peak_force_N_3" else 1.0,
        status=lambda cell, c, s: "diverged" if (c, s) == ("pd", 0) else "ok",
    )
    assert stats.actuator_metrics(spec, table) == [
        *(f"chattering_N_per_s_{k}" for k in range(1, 5)),
        "peak_force_N_1",
        "peak_force_N_2",
        "peak_force_N_4",
    ]


# ---------------------------------------------------------------- per cell


def test_cell_stats_count_runs_failures_and_missing_values_by_hand():
    """summary.csv: runs, runs ok, divergences (not errors), missing (ok without a finite
    value), mean and median over the ok runs with a value; the interval cut at 0."""
    spec = _spec(HEAD + 'controllers = ["smc", "pd"]\nseeds = 6\nmetrics = ["rmse"]\n')
    vals = {("pd", s): float(s + 1) for s in range(6)} | {("smc", s): 0.0 for s in range(6)}
    vals["smc", 0] = 1e-3
    vals["smc", 5] = math.nan  # ok, but no value

    def status(cell, c, s):
        return {("pd", 0): "diverged", ("pd", 1): "error"}.get((c, s), "ok")

    table = _table(spec, lambda cell, c, s, col: vals[c, s], status=status)
    rows = {r["controller"]: r for r in stats.cell_stats(spec, table, ["rmse_z_mm"])}
    pd, smc = rows["pd"], rows["smc"]
    assert (pd["n"], pd["ok"], pd["diverged"], pd["missing"]) == (6, 4, 1, 0)
    assert pd["mean"] == pytest.approx(np.mean([3, 4, 5, 6]))
    assert pd["median"] == pytest.approx(4.5)
    assert pd["lo"] < pd["mean"] < pd["hi"]
    assert (smc["n"], smc["ok"], smc["diverged"], smc["missing"]) == (6, 6, 0, 1)
    assert smc["mean"] == pytest.approx(1e-3 / 5) and smc["median"] == 0.0
    # the percentile interval's low end is 0 (no 1e-3 drawn in a third of the
    # resamples), widened about the mean it falls below 0: cut at 0
    assert smc["lo"] == 0.0 < smc["mean"] < smc["hi"]


# ---------------------------------------------------------------- pairs


def _pairs_text(seeds: int) -> str:
    return (HEAD + f'controllers = ["smc", "pd"]\nseeds = {seeds}\nmetrics = ["rmse"]\n'
            '[factors."payload.mass"]\nvalues = [0.0, 5.0]\n')  # fmt: skip


def _bookkeeping():
    """Two cells alike: seed 0 smc lower, 1 a tie, 2 pd's value NaN, 3 pd diverged, 4
    smc erred, 5 smc not run yet."""
    spec = _spec(_pairs_text(6))
    vals = {"smc": [1.0, 2.0, 1.5, 1.0, 1.0, 1.0], "pd": [3.0, 2.0, math.nan, 1.0, 5.0, 7.0]}
    status = {("pd", 3): "diverged", ("smc", 4): "error"}
    table = _table(
        spec,
        lambda cell, c, s, col: vals[c][s] + 10 * cell,
        status=lambda cell, c, s: status.get((c, s), "ok"),
        present=lambda cell, c, s: (c, s) != ("smc", 5),
    )
    return spec, table


def test_paired_differences_bookkeeping_by_hand():
    """paired.csv's columns (docs/campaigns.md): a - b over the pairs, the win rate of a
    (ties win for neither), ties, a_failed / b_failed (recorded not ok), undefined,
    not_run (no record yet); one row per pair of controllers, a before b."""
    spec, table = _bookkeeping()
    rows = stats.paired_differences(spec, table, ["rmse_z_mm"])
    assert {(r["a"], r["b"]) for r in rows} == {("smc", "pd")}
    assert [r["cell"] for r in rows] == [0, 1, -1]
    for r in rows:
        k = 2 if r["cell"] == -1 else 1
        assert r["pairs"] == 2 * k and r["ties"] == k
        assert r["mean"] == pytest.approx((1.0 - 3.0) / 2)
        assert r["win_rate_a"] == 0.5
        assert (r["a_failed"], r["b_failed"], r["undefined"], r["not_run"]) == (k, k, k, k)
        assert r["better"] == "unclear"  # 2 or 4 pairs < 5


def test_comparison_bookkeeping_by_hand():
    """comparison.csv (docs/campaigns.md): pd against smc (the controller second in the
    spec): means over the pairs, gain = baseline - controller, the win rate of the
    controller (a tie is no win), failures and of them divergences, undefined,
    not_run, and each one's mean over all its ok runs with a finite value."""
    spec, table = _bookkeeping()
    rows = stats.comparison(spec, table, "pd", "smc", ["rmse_z_mm"])
    assert [r["cell"] for r in rows] == [0, 1, -1]
    for r in rows:
        cells = [0, 1] if r["cell"] == -1 else [r["cell"]]
        k = len(cells)
        smc_pairs = [v + 10 * c for c in cells for v in (1.0, 2.0)]
        pd_pairs = [v + 10 * c for c in cells for v in (3.0, 2.0)]
        assert r["pairs"] == 2 * k and r["ties"] == k
        assert r["baseline_mean"] == pytest.approx(np.mean(smc_pairs))
        assert r["controller_mean"] == pytest.approx(np.mean(pd_pairs))
        assert r["gain"] == pytest.approx(np.mean(smc_pairs) - np.mean(pd_pairs))
        assert r["ratio"] == pytest.approx(np.mean(pd_pairs) / np.mean(smc_pairs))
        assert r["win_rate"] == 0.0
        assert (r["controller_failed"], r["controller_diverged"]) == (k, k)
        assert (r["baseline_failed"], r["baseline_diverged"]) == (k, 0)
        assert (r["undefined"], r["not_run"]) == (k, k)
        pd_all = [v + 10 * c for c in cells for v in (3.0, 2.0, 5.0, 7.0)]
        smc_all = [v + 10 * c for c in cells for v in (1.0, 2.0, 1.5, 1.0)]
        assert (r["controller_runs_all"], r["baseline_runs_all"]) == (4 * k, 4 * k)
        assert r["controller_mean_all"] == pytest.approx(np.mean(pd_all))
        assert r["baseline_mean_all"] == pytest.approx(np.mean(smc_all))


def test_five_pairs_are_enough_for_a_verdict_four_are_not():
    """docs/campaigns.md: better when the interval excludes 0 over at least 5 pairs."""
    spec = _spec(_pairs_text(5))
    lower = {"smc": 1.0, "pd": 2.0}  # smc lower by 1 +- 0.01 on every seed

    def value(cell, c, s, col):
        return lower[c] + (0.01 * s if c == "smc" else 0.0)

    rows = stats.paired_differences(spec, _table(spec, value), ["rmse_z_mm"])
    assert [(r["cell"], r["pairs"], r["better"]) for r in rows] == [
        (0, 5, "a"),
        (1, 5, "a"),
        (-1, 10, "a"),
    ]
    for controller, baseline, want in (("smc", "pd", "controller"), ("pd", "smc", "baseline")):
        rows = stats.comparison(spec, _table(spec, value), controller, baseline, ["rmse_z_mm"])
        assert [r["better"] for r in rows] == [want] * 3
    table = _table(spec, value, present=lambda cell, c, s: not (cell == 0 and s == 4))
    rows = stats.paired_differences(spec, table, ["rmse_z_mm"])
    assert [(r["cell"], r["pairs"], r["better"]) for r in rows] == [
        (0, 4, "unclear"),
        (1, 5, "a"),
        (-1, 9, "a"),
    ]


def test_seeds_above_2_53_are_paired_as_themselves():
    """Seeds are integers up to 2^63 - 1: 2^60 and 2^60 + 1 are two seeds (as floats
    they would be one), so each cell has two pairs and nothing is "not run"."""
    seeds = f"[{2**60}, {2**60 + 1}]"
    spec = _spec(HEAD + f'controllers = ["smc", "pd"]\nseeds = {seeds}\nmetrics = ["rmse"]\n')
    table = _table(spec, lambda cell, c, s, col: float(s - 2**60) + (c == "pd"))
    (row, pooled) = stats.paired_differences(spec, table, ["rmse_z_mm"])
    assert (row["pairs"], row["not_run"], row["mean"]) == (2, 0, -1.0)
    rows = stats.comparison(spec, table, "smc", "pd", ["rmse_z_mm"])
    assert [(r["pairs"], r["not_run"]) for r in rows] == [(2, 0), (2, 0)]


# ---------------------------------------------------------------- by factor, errors


def test_by_factor_of_a_one_at_a_time_design_keeps_to_the_factors_axis():
    """by_factor: one-at-a-time, the cells of the factor's axis only (the others at the
    centre); ``failed`` the runs of that controller at that value that did not end ok."""
    text = (HEAD + 'controllers = ["smc", "pd"]\nseeds = 3\nmetrics = ["rmse"]\n'
            'design = "one-at-a-time"\n[factors."payload.mass"]\nvalues = [0.0, 5.0]\n'
            '[factors."actuators.force_limit"]\nvalues = ["none", 2000.0]\n')  # fmt: skip
    spec = _spec(text)
    assert spec.axis("payload.mass") == [0, 1] and spec.cells[2]["payload.mass"] == 0.0
    base = {0: 1.0, 1: 2.0, 2: 100.0}  # cell 2: force limit 2000, off payload's axis
    table = _table(
        spec,
        lambda cell, c, s, col: base[cell] + s,
        status=lambda cell, c, s: "diverged" if (c == "pd" and cell == 1 and s > 0) else "ok",
    )
    rows = {(r["controller"], r["value"]): r for r in stats.by_factor(spec, table, "rmse_z_mm",
                                                                     "payload.mass")}  # fmt: skip
    assert rows["smc", 0.0]["mean"] == pytest.approx(2.0) and rows["smc", 0.0]["n"] == 3
    assert (rows["smc", 5.0]["failed"], rows["smc", 5.0]["n"]) == (0, 3)
    assert (rows["pd", 5.0]["failed"], rows["pd", 5.0]["n"]) == (2, 1)
    assert rows["pd", 5.0]["mean"] == pytest.approx(2.0)


def test_error_messages_most_frequent_first():
    spec = _spec(HEAD + 'controllers = ["smc"]\nseeds = 4\nmetrics = ["rmse"]\n')
    table = _table(spec, lambda *k: 1.0, status=lambda *k: "error",
                   message=lambda cell, c, s: "rare" if s == 0 else "common")  # fmt: skip
    assert stats.error_messages(table) == [("common", 3), ("rare", 1)]
    runs = stats.error_runs(table, "common")
    assert runs == [(0, "smc", 1), (0, "smc", 2), (0, "smc", 3)]


def test_seeds_named_says_more_only_when_there_are_more():
    runs = [(0, "pd", s) for s in range(5)]
    assert stats.seeds_named(runs, cells=False) == "seeds 0, 1, 2, 3, 4"
    assert stats.seeds_named([*runs, (1, "pd", 9)], cells=False) == (
        "seeds 0, 1, 2, 3, 4 and 1 more"
    )


# ---------------------------------------------------------------- the spec


def _refused(text: str) -> str:
    """The one-line error a spec is refused with (a SpecError or a ScenarioError, both
    pkmctl's own: never a bare ValueError or a traceback of numpy's)."""
    from pkmctl.sim.scenario import ScenarioError

    with pytest.raises((SpecError, ScenarioError)) as info:
        CampaignSpec.from_toml(text)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


ONE = HEAD + 'controllers = ["smc"]\n'


def test_defaults_are_the_documented_ones():
    """docs/campaigns.md: controllers = ["smc", "fsmc", "afsmc"], seeds = 1 (seed 0),
    metrics = ["rmse", "rmse_after_1s"], name "campaign", design "grid", one cell."""
    spec = CampaignSpec.from_toml('scenario = "paper"\n')
    assert spec.controllers == ("smc", "fsmc", "afsmc")
    assert spec.seeds == (0,) and spec.metrics == ("rmse", "rmse_after_1s")
    assert (spec.name, spec.design, spec.cells) == ("campaign", "grid", ({},))
    assert _spec(ONE + "seeds = 3\n").seeds == (0, 1, 2)


@pytest.mark.parametrize(
    ("body", "names"),
    [
        ("seeds = [1, 1]\n", "seeds"),
        ("seeds = [true]\n", "seeds"),
        ("duration = true\n", "duration = True"),
        ('metrics = ["rmse", "rmse"]\n', "metrics"),
    ],
    ids=["seed-twice", "seed-bool", "duration-bool", "metric-twice"],
)
def test_a_bad_top_level_value_is_refused(body, names):
    top = 'scenario = "paper"\ncontrollers = ["smc"]\n'
    assert _refused(top + ("" if "duration" in body else "duration = 0.05\n") + body).startswith(
        names
    )


def test_a_controller_named_twice_is_refused():
    assert _refused(HEAD + 'controllers = ["smc", "smc"]\n').startswith("controllers")


@pytest.mark.parametrize(
    ("factor", "names"),
    [
        ('values = [0.0, 5.0, 5]\n', "a value named twice"),  # 5 and 5.0: one cell
        ('values = [1.0, 2.0]\nseed = 3\n', "unknown key 'seed'"),
        ('distribution = "uniform"\nlow = 0.0\nhigh = 1.0\nsamples = 0\n', ".samples = 0"),
        ('distribution = "uniform"\nlow = 0.0\nhigh = 1.0\nsamples = 2\nseed = -1\n',
         ".seed = -1"),
        ('distribution = "uniform"\nlow = 0.0\nhigh = inf\nsamples = 2\n', ".high = inf"),
        ('distribution = "normal"\nmean = nan\nstd = 1.0\nsamples = 2\n', ".mean = nan"),
        ('values = [0.0, 5.0]\nwith = { "actuators.force_limit" = [1.0, 2.0, 3.0] }\n',
         "must be a list of 2 values"),
        ('values = [0.0, 5.0]\nwith = { "logging.every" = [1, 2] }\n', "changes no record"),
    ],
    ids=["twice", "extra-key", "samples-0", "seed-negative", "inf", "nan", "with-length",
         "with-logging"],
)  # fmt: skip
def test_a_bad_factor_is_refused_naming_the_field(factor, names):
    msg = _refused(ONE + '[factors."payload.mass"]\n' + factor)
    assert msg.startswith("factors.'payload.mass'") and names in msg, msg


@pytest.mark.parametrize(
    "factor", ['"disturbance.seed"]\nvalues = [1, 2]\n', '"logging.every"]\nvalues = [1, 2]\n']
)
def test_a_factor_a_run_overrides_or_no_record_shows_is_refused(factor):
    assert _refused(ONE + "[factors." + factor).startswith("factors.")


def test_list_values_of_different_lengths_are_two_values_not_a_crash():
    """_same: lists of different lengths are different values; the scenario then refuses
    the short one in one line (a zip of unequal lists must not end in a ValueError)."""
    msg = _refused(
        ONE + '[factors."disturbance.amplitude"]\nvalues = [[1.0, 2.0, 3.0], [1.0, 2.0]]\n'
    )
    assert msg.startswith("disturbance.amplitude = [1.0, 2.0]")


def test_none_in_a_with_is_no_value():
    """docs/campaigns.md: "none" as a value means no value, in values and in with."""
    spec = _spec(ONE + '[factors."payload.mass"]\nvalues = [0.0, 5.0]\n'
                 'with = { "actuators.force_limit" = ["none", 2000.0] }\n')  # fmt: skip
    assert [c["actuators.force_limit"] for c in spec.cells] == [None, 2000.0]
    assert spec.scenario(0).actuators.force_limit is None


def _drawn(body: str, seed=None) -> CampaignSpec:
    text = ONE + '[factors."payload.mass"]\n' + body + (f"seed = {seed}\n" if seed else "")
    return CampaignSpec.from_toml(text)


def test_draws_are_seeded():
    """The same spec draws the same cells (and hash) every time; another seed others."""
    body = 'distribution = "uniform"\nlow = 1.0\nhigh = 2.0\nsamples = 4\n'
    a, b, c = _drawn(body, 7), _drawn(body, 7), _drawn(body, 8)
    assert a.cells == b.cells and a.digest == b.digest
    assert a.cells != c.cells and a.digest != c.digest
    assert all(1.0 <= cell["payload.mass"] < 2.0 for cell in a.cells)


def test_loguniform_and_normal_draw_their_distributions():
    """loguniform(1e-3, 1): uniform in log, so about half the draws below
    sqrt(1e-3 * 1) (a uniform would put 3 % there); normal(mean 5, std 0.1): all within
    5 std of 5, their sample mean and std near 5 and 0.1."""
    log = _drawn('distribution = "loguniform"\nlow = 1e-3\nhigh = 1.0\nsamples = 200\n', 1)
    x = np.array([c["payload.mass"] for c in log.cells])
    assert ((1e-3 <= x) & (x <= 1.0)).all()
    assert 0.38 <= np.mean(x < math.sqrt(1e-3)) <= 0.62
    norm = _drawn('distribution = "normal"\nmean = 5.0\nstd = 0.1\nsamples = 100\n', 1)
    y = np.array([c["payload.mass"] for c in norm.cells])
    assert (np.abs(y - 5.0) < 0.5).all()
    assert abs(y.mean() - 5.0) < 0.05 and 0.07 < y.std(ddof=1) < 0.13


def test_exactly_max_runs_is_accepted_one_more_is_refused():
    """docs/campaigns.md: more than 1,000,000 runs (cells x controllers x seeds) is
    refused; 1,000,000 is not more."""
    two = HEAD + 'controllers = ["smc", "pd"]\nmetrics = ["rmse"]\n'
    spec = CampaignSpec.from_toml(two + f"seeds = {MAX_RUNS // 2}\n")
    assert spec.n_runs == MAX_RUNS
    assert "more than the 1000000" in _refused(two + f"seeds = {MAX_RUNS // 2 + 1}\n")


def test_a_distribution_of_exactly_max_runs_is_accepted():
    """samples x controllers x seeds = 1,000,000 is not more than 1,000,000."""
    text = (
        ONE + f'metrics = ["rmse"]\nseeds = {MAX_RUNS // 10}\n[factors."payload.mass"]\n'
        'distribution = "uniform"\nlow = 0.0\nhigh = 1.0\nsamples = 10\n'
    )
    assert CampaignSpec.from_toml(text).n_runs == MAX_RUNS
    assert "more than the 1000000" in _refused(text.replace("samples = 10", "samples = 11"))


def test_the_run_count_before_building_multiplies_the_factors():
    """A grid has prod(values) cells (2 x 2 x 2 = 8); one-at-a-time 1 + sum(values - 1)
    (the centre and one other value = 2): each over 1,000,000 runs with these seeds."""
    grid = ('[factors."payload.mass"]\nvalues = [0.0, 5.0]\n'
            '[factors."actuators.force_limit"]\nvalues = ["none", 2000.0]\n'
            '[factors."controller_model.theta_scale"]\nvalues = [0.85, 0.5]\n')  # fmt: skip
    seeds = MAX_RUNS // 8 + 1  # 8 cells: over; 6 (a sum) would not be
    msg = _refused(ONE + f'metrics = ["rmse"]\nseeds = {seeds}\n' + grid)
    assert msg.startswith("8 cells x 1 controller x 125001 seeds: 1000008 runs"), msg
    oat = 'design = "one-at-a-time"\n[factors."payload.mass"]\nvalues = [0.0, 5.0]\n'
    msg = _refused(ONE + f'metrics = ["rmse"]\nseeds = {MAX_RUNS // 2 + 1}\n' + oat)
    assert msg.startswith("2 cells x 1 controller x 500001 seeds: 1000002 runs"), msg


def test_a_distributions_samples_are_bounded_with_every_controller_counted():
    """samples x controllers x seeds over 1,000,000 names the samples, before drawing."""
    text = (HEAD + 'controllers = ["smc", "pd"]\nseeds = 1000\nmetrics = ["rmse"]\n'
            '[factors."payload.mass"]\ndistribution = "uniform"\nlow = 0.0\nhigh = 1.0\n'
            "samples = 600\n")  # fmt: skip
    assert _refused(text).startswith("factors.'payload.mass'.samples = 600: 1200000 runs")


def test_one_at_a_time_cells_and_axes():
    """docs/campaigns.md: the centre (cell 0), then each factor's other values; a value
    equal to the base's is the centre, not a cell. A factor's axis: the cells where every
    other factor is at the centre."""
    text = (ONE + 'metrics = ["rmse"]\ndesign = "one-at-a-time"\n'
            '[factors."payload.mass"]\nvalues = [0.0, 5.0]\n'
            '[factors."actuators.force_limit"]\nvalues = ["none", 2000.0]\n'
            '[factors."controller_model.theta_scale"]\nvalues = [0.85, 0.5]\n')  # fmt: skip
    spec = _spec(text)
    centre = {"payload.mass": 0.0, "actuators.force_limit": None,
              "controller_model.theta_scale": 0.85}  # fmt: skip
    assert spec.cells == (
        centre,
        {**centre, "payload.mass": 5.0},
        {**centre, "actuators.force_limit": 2000.0},
        {**centre, "controller_model.theta_scale": 0.5},
    )
    assert spec.axis("payload.mass") == [0, 1]
    assert spec.axis("actuators.force_limit") == [0, 2]
    assert spec.axis("controller_model.theta_scale") == [0, 3]


def test_tasks_hold_every_run_once_in_multiples_of_seeds():
    """tasks: one cell and controller a task, its seeds in chunks of about task_seconds
    of work rounded up to a multiple of ``multiple``; every run exactly once."""
    spec = _spec(HEAD + 'controllers = ["smc", "pd"]\nseeds = 20\nmetrics = ["rmse"]\n'
                 '[factors."payload.mass"]\nvalues = [0.0, 5.0]\n')  # fmt: skip
    one = spec.run_seconds()
    assert one > 0
    tasks = spec.tasks(task_seconds=3 * one, multiple=8)  # 3 runs of work: 8 seeds
    assert [len(t.runs) for t in tasks] == [8, 8, 4] * 4
    assert [t.index for t in tasks] == list(range(len(tasks)))
    runs = [r for t in tasks for r in t.runs]
    assert sorted((r.cell, r.controller, r.seed) for r in runs) == sorted(
        (cell, c, s) for cell in range(2) for c in ("smc", "pd") for s in range(20)
    )
    assert all(len({(r.cell, r.controller) for r in t.runs}) == 1 for t in tasks)


@pytest.mark.parametrize(
    "compare",
    [
        'name = "q"\ncontroller = "smc"\nbaseline = "smc"\n',
        'name = "q"\ncontroller = "afsmc"\nbaseline = "smc"\n',
        'name = "q"\ncontroller = "pd"\nbaseline = "smc"\n[[compare]]\nname = "r"\n'
        'controller = "pd"\nbaseline = "smc"\n',
    ],
    ids=["self", "not-a-controller", "asked-twice"],
)
def test_a_bad_comparison_is_refused(compare):
    text = HEAD + 'controllers = ["smc", "pd"]\n[[compare]]\n' + compare
    assert _refused(text).startswith("compare[")


def test_rmse_after_1s_with_rmse_takes_short_runs():
    """docs/campaigns.md: with rmse kept too, rmse_after_1s is allowed on short runs (the
    report compares over the whole run)."""
    spec = _spec(ONE.replace("0.05", "0.6") + 'metrics = ["rmse", "rmse_after_1s"]\n')
    assert spec.metrics == ("rmse", "rmse_after_1s") and spec.past_1s() == [False]


def test_the_hash_holds_the_metrics_and_the_durations_are_per_cell():
    """docs/campaigns.md: the spec hash is of what determines the records (metrics kept
    among them); a timing.duration factor sets each cell's run length."""
    a = _spec(ONE + 'metrics = ["rmse"]\n')
    b = _spec(ONE + 'metrics = ["rmse", "max_error"]\n')
    assert a.digest != b.digest
    spec = _spec(ONE + 'metrics = ["rmse"]\n[factors."timing.duration"]\nvalues = [0.6, 1.5]\n')
    assert spec.durations() == [0.6, 1.5] and spec.past_1s() == [False, True]


# ---------------------------------------------------------------- bugs it found, fixed


def test_a_distribution_that_is_a_list_is_refused_naming_the_field():
    """docs/campaigns.md: the spec is checked whole before anything runs; a bad value
    ends in one line (SpecError: the field, the value, what is allowed). A distribution
    given as a list ended in "TypeError: unhashable type: 'list'", naming no field."""
    msg = _refused(ONE + '[factors."payload.mass"]\ndistribution = ["uniform"]\n')
    assert msg.startswith("factors.'payload.mass'.distribution")


def test_a_uniform_range_too_wide_to_draw_is_refused_in_one_line():
    """Finite low and high whose difference overflows (-1e308..1e308) passed the "finite
    number" check; NumPy then raised OverflowError, an internal error, exit 1."""
    body = 'distribution = "uniform"\nlow = -1e308\nhigh = 1e308\nsamples = 2\n'
    msg = _refused(ONE + '[factors."payload.mass"]\n' + body)
    assert msg.startswith("factors.'payload.mass'")
