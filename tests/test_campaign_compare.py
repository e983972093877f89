"""A ``[[compare]]`` question's numbers against the records they come from (report items
5 and 6 of the campaign test report): made-up records, no run."""

import math

import numpy as np
import pyarrow as pa
import pytest

from pkmctl.campaign import CampaignSpec, stats
from pkmctl.campaign.store import schema

SPEC = """
name = "compare"
scenario = "paper"
controllers = ["pd", "smc"]
seeds = 8
duration = 0.05
metrics = ["rmse"]

[factors."payload.mass"]
values = [0.0, 5.0]

[[compare]]
name = "smc-vs-pd"
controller = "smc"
baseline = "pd"
"""

METRIC = "rmse_z_mm"


def _records(spec: CampaignSpec, value, status=lambda cell, ctrl, seed: "ok") -> pa.Table:
    """A record per run: ``value(cell, controller, seed)`` for every metric column, the
    status ``status(...)`` (no metrics unless "ok")."""
    sch = schema(spec)
    metric_cols = [n for n in sch.names if n.startswith("rmse_")]
    rows = []
    for cell in range(len(spec.cells)):
        for ctrl in spec.controllers:
            for seed in spec.seeds:
                st = status(cell, ctrl, seed)
                v = value(cell, ctrl, seed) if st == "ok" else None
                rows.append({"spec_hash": spec.digest, "cell": cell, "controller": ctrl,
                             "seed": seed, "task": 0, "f.payload.mass": spec.cells[cell][
                                 "payload.mass"], "status": st, "diverged_at": None,
                             "message": "" if st == "ok" else "ValueError: no",
                             **dict.fromkeys(metric_cols, v), "wall_s": 0.0, "kernel_s": 0.0,
                             "worker": "w"})  # fmt: skip
    return pa.Table.from_pylist(rows, schema=sch)


def _values(seed: int):
    rng = np.random.default_rng(seed)
    table = {}

    def value(cell, ctrl, s):
        key = (cell, ctrl, s)
        if key not in table:
            table[key] = float(rng.lognormal(-1.0 + cell + 0.1 * (ctrl == "smc"), 0.4))
        return table[key]

    return value


@pytest.mark.parametrize("order", [["pd", "smc"], ["smc", "pd"]])
def test_paired_and_comparison_give_the_same_interval_to_the_same_difference(order):
    """paired.csv (a - b, a before b in ``controllers``) and comparison.csv (baseline -
    controller) seeded their bootstraps differently when the question named its two in the
    other order: two intervals for one difference, and verdicts that could disagree."""
    text = SPEC.replace('controllers = ["pd", "smc"]', f"controllers = {order!r}".replace("'", '"'))
    spec = CampaignSpec.from_toml(text)
    table = _records(spec, _values(3))
    paired = {r["cell"]: r for r in stats.paired_differences(spec, table, [METRIC])}
    rows = stats.comparison(spec, table, "smc", "pd", [METRIC])
    assert len(rows) == len(spec.cells) + 1
    for r in rows:
        p = paired[r["cell"]]
        assert (p["a"], p["b"]) == tuple(order)
        # the gain is pd - smc; paired.csv has a - b
        flip = 1.0 if p["a"] == "pd" else -1.0
        assert r["gain"] == flip * p["mean"]
        lo, hi = (p["lo"], p["hi"]) if flip > 0 else (-p["hi"], -p["lo"])
        assert (r["lo"], r["hi"]) == (lo, hi), (order, r["cell"])
        verdict = {"a": "pd", "b": "smc", "unclear": "unclear"}[p["better"]]
        assert {"controller": "smc", "baseline": "pd", "unclear": "unclear"}[r["better"]] == (
            verdict if p["a"] == "pd" else {"pd": "smc", "smc": "pd"}.get(verdict, verdict)
        )  # the winner named by the same difference
        assert r["pairs"] == p["pairs"] == (8 if r["cell"] >= 0 else 16)


def test_a_comparison_says_each_mean_over_what_when_one_side_failed():
    """smc failed every run at payload.mass = 5: the pooled row's means are over the
    pairs (cell 0 only), and the means over all of each one's runs are apart, equal to
    the records' own means (pd's over both cells)."""
    spec = CampaignSpec.from_toml(SPEC)
    value = _values(5)
    table = _records(spec, value, lambda cell, ctrl, s: "error" if (cell, ctrl) == (1, "smc")
                     else "ok")  # fmt: skip
    rows = {r["cell"]: r for r in stats.comparison(spec, table, "smc", "pd", [METRIC])}
    pooled = rows[-1]
    pd0 = [value(0, "pd", s) for s in spec.seeds]
    pd_all = pd0 + [value(1, "pd", s) for s in spec.seeds]
    smc0 = [value(0, "smc", s) for s in spec.seeds]
    assert pooled["pairs"] == 8 and pooled["controller_failed"] == 8
    assert pooled["baseline_mean"] == pytest.approx(np.mean(pd0), rel=1e-15)
    assert pooled["controller_mean"] == pytest.approx(np.mean(smc0), rel=1e-15)
    assert pooled["baseline_mean_all"] == pytest.approx(np.mean(pd_all), rel=1e-15)
    assert pooled["baseline_runs_all"] == 16
    assert pooled["controller_mean_all"] == pytest.approx(np.mean(smc0), rel=1e-15)
    assert pooled["controller_runs_all"] == 8
    assert pooled["baseline_mean_all"] > 1.5 * pooled["baseline_mean"]  # the gap of the report
    # per cell, the means over all runs are summary.csv's
    summary = {(r["cell"], r["controller"]): r for r in stats.cell_stats(spec, table, [METRIC])}
    for cell in (0, 1):
        r = rows[cell]
        assert r["baseline_mean_all"] == pytest.approx(summary[(cell, "pd")]["mean"], rel=1e-15)
        smc = summary[(cell, "smc")]["mean"]
        assert (math.isnan(r["controller_mean_all"]) and math.isnan(smc)) or (
            r["controller_mean_all"] == pytest.approx(smc, rel=1e-15)
        )
    assert rows[1]["pairs"] == 0 and rows[1]["controller_runs_all"] == 0


def test_the_short_answer_says_what_each_mean_is_over_when_one_side_failed():
    """answer.md said "At all cells: flaky 0.413, pd 0.413" where pd's mean over all its
    runs was 0.884: the pooled means were the pairs' (cell 0 only), unsaid."""
    from pkmctl.report.campaign import short_answer

    spec = CampaignSpec.from_toml(SPEC)
    value = _values(5)
    failing = _records(spec, value, lambda cell, ctrl, s: "error" if (cell, ctrl) == (1, "smc")
                       else "ok")  # fmt: skip
    q = spec.compare[0]
    rows = stats.comparison(spec, failing, "smc", "pd", [METRIC])
    line = short_answer(spec, rows, q, [METRIC])[1]  # (then the runs that failed)
    pd_all = np.mean([value(c, "pd", s) for c in (0, 1) for s in spec.seeds])
    smc0 = np.mean([value(0, "smc", s) for s in spec.seeds])
    pd0 = np.mean([value(0, "pd", s) for s in spec.seeds])
    assert (
        f"Over all cells, in the 8 pairs where both ended ok: smc {smc0:.4g}, pd {pd0:.4g} "
        f"(over all their runs that ended ok: smc {smc0:.4g} over 8 runs; pd {pd_all:.4g} "
        "over 16 runs); ratio "
    ) in line, line
    # a grid's reference is the pooled row: named once ("At all cells: …; over all cells …"
    # said it twice)
    assert "At all cells" not in line and line.count("all cells") == 1, line
    # no run failed: the line is as before, the means the pairs' (which are every run)
    rows = stats.comparison(spec, _records(spec, value), "smc", "pd", [METRIC])
    (line,) = short_answer(spec, rows, q, [METRIC])[1:]
    assert "pairs" not in line and f", pd {pd_all:.4g}; ratio " in line, line
    assert "Over all cells: smc " in line and line.count("all cells") == 1, line


def test_drawn_values_are_named_in_the_fewest_digits_that_tell_them_apart():
    """Cell names printed a draw in 16 digits (theta_scale = 0.6582751372901796; a tester),
    where the docs promise as many as tell it from the others."""
    from pkmctl.report.campaign import _cell_name

    head = 'scenario = "paper"\ncontrollers = ["smc"]\nseeds = 1\nduration = 0.05\n'
    drawn = CampaignSpec.from_toml(
        head + '[factors."controller_model.theta_scale"]\ndistribution = "uniform"\n'
        "low = 0.4\nhigh = 1.0\nsamples = 3\nseed = 2\n"
    )
    names = [_cell_name(drawn, i) for i in range(3)]
    values = [c["controller_model.theta_scale"] for c in drawn.cells]
    assert names == [f"controller_model.theta_scale = {v:.3g}" for v in values], names
    close = CampaignSpec.from_toml(
        head + '[factors."controller_model.theta_scale"]\nvalues = [0.1234567891, 0.1234567899]\n'
    )
    # 9 digits tell these two apart (0.1234567899 reads 0.12345679)
    assert [_cell_name(close, i).split(" = ")[1] for i in range(2)] == [
        "0.123456789",
        "0.12345679",
    ]
    # a value %g holds is written so, whatever the others need
    mixed = CampaignSpec.from_toml(
        head + '[factors."payload.mass"]\nvalues = [0.5, 2.0000000001, 2.0000000002]\n'
    )
    assert [_cell_name(mixed, i).split(" = ")[1] for i in range(3)] == [
        "0.5",
        "2.0000000001",
        "2.0000000002",
    ]


def test_the_interval_of_a_mean_stays_where_the_metric_can_be():
    """Two seeds far apart: the widened interval of an RMSE's mean went to -0.004 mm in a
    tester's summary.csv, a bar off the bottom of a log axis. Every campaign metric is
    >= 0, so the interval of a mean is cut at 0 (in summary.csv and the figures); a paired
    difference, which may be negative, keeps its own."""
    spec = CampaignSpec.from_toml(SPEC.replace("seeds = 8", "seeds = 2"))
    table = _records(spec, lambda cell, ctrl, seed: [0.001, 0.03][seed])
    x = np.array([0.001, 0.03])
    lo, hi = stats.bootstrap_interval(x, seed=1)
    assert lo < 0 < hi  # what the cut is for
    for r in stats.cell_stats(spec, table, [METRIC]):
        assert r["lo"] == 0.0 and r["hi"] > x.mean(), r
    for r in stats.by_factor(spec, table, METRIC, "payload.mass"):
        assert r["lo"] == 0.0 and r["hi"] > x.mean(), r
    d = stats.comparison(spec, _records(spec, lambda c, ctrl, s: [0.001, 0.03][s ^ (ctrl == "pd")]),
                         "smc", "pd", [METRIC])  # fmt: skip
    assert min(r["lo"] for r in d) < 0  # differences are not cut


def test_campaign_figures_draw_each_controller_in_its_reproduce_colour(tmp_path):
    """A campaign's figure took matplotlib's colour cycle in the spec's order: with
    controllers ["afsmc", "smc"], AFSMC was orange (FSMC's colour in reproduce's figures)
    and SMC green (AFSMC's) in the next campaign."""
    import matplotlib.image

    from pkmctl.report.campaign import _plot, _tick
    from pkmctl.report.figures import _color, controller_colors

    assert controller_colors(["afsmc", "mine", "smc", "yours"]) == {
        "afsmc": _color("afsmc"), "smc": _color("smc"), "mine": "C5", "yours": "C6"
    }  # fmt: skip
    spec = CampaignSpec.from_toml(
        SPEC.replace('["pd", "smc"]', '["afsmc", "smc"]').replace('"pd"', '"afsmc"')
    )
    table = _records(spec, lambda cell, ctrl, seed: 0.1 + 0.2 * (ctrl == "afsmc") + 0.01 * seed)
    _plot(spec, table, METRIC, "payload.mass", tmp_path / "f.png")
    rgb = (matplotlib.image.imread(tmp_path / "f.png")[..., :3] * 255).round()

    def pixels(color):
        return int((np.abs(rgb - np.array(color)).sum(-1) < 30).sum())

    tab10 = {"smc": (31, 119, 180), "fsmc": (255, 127, 14), "afsmc": (44, 160, 44)}
    assert pixels(tab10["afsmc"]) > 100 and pixels(tab10["smc"]) > 100
    assert pixels(tab10["fsmc"]) == 0
    assert _tick([10.0, 10.0, 10.0]) == "[10, 10, 10]"  # was "[10.0, 10.0, 10.0]", overlapping


def test_a_log_axis_only_when_every_interval_is_above_zero():
    """An interval cut at 0 is a bar to the bottom of a log axis, drawn as if it went on
    (a review of the cut): the axis stays linear then."""
    from pkmctl.report.campaign import _log_y

    row = {"mean": 1.0, "lo": 0.5, "hi": 2.0}
    far = {"mean": 100.0, "lo": 50.0, "hi": 200.0}
    assert _log_y([row, far])
    assert not _log_y([{**row, "lo": 0.0}, far])
    assert not _log_y([row, {**far, "mean": 10.0}])  # 10x apart: linear
    assert _log_y([{**row, "lo": math.nan}, far])  # no interval (1 run): no say
