"""Campaign specs at their bounds (seeds, distributions, the rmse_after_1s duration) and
the report's statistics at theirs (equal controllers, the summary's median)."""

import csv
import math

import pytest
from typer.testing import CliRunner

from pkmctl.campaign import CampaignSpec
from pkmctl.campaign.store import read_records
from pkmctl.cli import app
from tests.test_campaign import HEAD, _fake_campaign, _refused

runner = CliRunner()

TWO = HEAD.replace('["smc"]', '["smc", "pd"]').replace("seeds = 1", "seeds = 6")


def test_equal_controllers_are_never_named_better(tmp_path):
    """Both controllers give the same value on every seed (as two peak forces at the same
    force limit do): every difference is 0, its interval [0, 0]. Enough pairs for a
    verdict (6 >= MIN_PAIRS), and the verdict is that the data cannot tell them apart,
    never "smc is better"."""
    from pkmctl.campaign import stats

    spec = _fake_campaign(tmp_path / "a", TWO, metric=lambda run, column: 1.0 + run.seed)
    table = read_records(tmp_path / "a")
    rows = stats.paired_differences(spec, table, ["rmse_z_mm"])
    assert rows and all(r["pairs"] == 6 >= stats.MIN_PAIRS for r in rows)
    assert [(r["cell"], r["mean"], r["better"]) for r in rows] == [
        (r["cell"], 0.0, "unclear") for r in rows
    ]
    cmp = stats.comparison(spec, table, "smc", "pd", ["rmse_z_mm"])
    assert cmp and [r["better"] for r in cmp] == ["unclear"] * len(cmp)
    res = runner.invoke(app, ["campaign", "report", str(tmp_path / "a")])
    assert res.exit_code == 0, res.output
    md = (tmp_path / "a" / "report" / "report.md").read_text()
    assert "smc lower in 0 % of pairs, equal in 100 %: the data cannot tell them apart." in md
    assert "smc is better" not in md and "smc better in" not in md


def test_a_seed_above_2_63_minus_1_is_refused_before_anything_is_written(tmp_path):
    """A run's seed is a C long: 2^63 was accepted, then `campaign run` failed with an
    internal OverflowError and left its folder behind."""
    top = HEAD.replace("seeds = 1", "seeds = [9223372036854775807]")
    assert CampaignSpec.from_toml(top).seeds == (2**63 - 1,)
    line = _refused(tmp_path, HEAD.replace("seeds = 1", "seeds = [9223372036854775808]"))
    assert line == "error: seeds: 9223372036854775808 must be an integer in [0, 2^63 - 1]"


@pytest.mark.parametrize(
    ("factor", "expected"),
    [
        (  # log(0): was "error: math domain error", which names no field
            '[factors."controller_model.theta_scale"]\ndistribution = "loguniform"\n'
            "low = 0.0\nhigh = 1.0\nsamples = 3\n",
            "error: factors.'controller_model.theta_scale': need 0 < low < high, got 0.0, 1.0",
        ),
        (  # std = 0 or low = high: three identical cells counted as independent pairs
            '[factors."payload.mass"]\ndistribution = "normal"\nmean = 1.0\nstd = 0.0\n'
            "samples = 3\n",
            "error: factors.'payload.mass'.std = 0.0: must be > 0",
        ),
        (
            '[factors."payload.mass"]\ndistribution = "uniform"\nlow = 2.0\nhigh = 2.0\n'
            "samples = 3\n",
            "error: factors.'payload.mass': low = 2.0 must be < high = 2.0",
        ),
    ],
    ids=["loguniform-low-0", "normal-std-0", "uniform-low-eq-high"],
)
def test_a_distribution_at_its_bound_is_refused_in_one_line(tmp_path, factor, expected):
    assert _refused(tmp_path, HEAD + factor, "show") == expected


def test_rmse_after_1s_takes_runs_whose_last_sample_is_at_1_s(tmp_path):
    """docs/campaigns.md: rmse_after_1s needs a control sample at t >= 1 s. On paper's
    50 us period, 1.00005 s has its last sample at t = 1 s (accepted), 1.0 s at
    0.99995 s (refused in one line)."""
    text = 'scenario = "paper"\ncontrollers = ["smc"]\nseeds = 1\nmetrics = ["rmse_after_1s"]\n'
    spec = CampaignSpec.from_toml(text + "duration = 1.00005\n")
    assert spec.duration == 1.00005 and spec.metrics == ("rmse_after_1s",)
    line = _refused(tmp_path, text + "duration = 1.0\n", "show")
    assert line == (
        "error: metrics = ['rmse_after_1s'] with duration = 1.0: rmse_after_1s needs runs "
        "longer than 1 s (a control sample at t >= 1 s); keep rmse too (the whole run) or "
        "make the runs longer"
    )


def test_the_summary_median_is_the_median(tmp_path):
    """pd's values over its 6 seeds are 0, 1, 4, 9, 16, 25: median 6.5, mean 9.1667;
    cell_stats and summary.csv give each in its column."""
    from pkmctl.campaign import stats

    spec = _fake_campaign(tmp_path / "a", TWO, metric=lambda run, column: float(run.seed**2))
    table = read_records(tmp_path / "a")
    pd = [r for r in stats.cell_stats(spec, table, ["rmse_z_mm"]) if r["controller"] == "pd"]
    assert [(r["median"], r["mean"]) for r in pd] == [(6.5, pytest.approx(55 / 6))]
    res = runner.invoke(app, ["campaign", "report", str(tmp_path / "a")])
    assert res.exit_code == 0, res.output
    with open(tmp_path / "a" / "report" / "summary.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["controller"] == "pd"]
    row = next(r for r in rows if r["metric"] == "rmse_z_mm")
    assert math.isclose(float(row["median"]), 6.5) and math.isclose(float(row["mean"]), 55 / 6)
