"""The campaign report says what cost a comparison its pairs: runs that did not end ok
(a PD diverging in every run of a cell read as "fewer than the 5 pairs a verdict takes",
as if too few seeds had been asked for) or a metric not finite in runs that did ("no pair
of runs where both ended ok" where every run had). Records are made up, not run."""

from __future__ import annotations

from pkmctl.report.campaign import write_report
from tests.test_campaign import _fake_campaign

SPEC = (
    'scenario = "paper"\ncontrollers = ["pd", "smc"]\nseeds = 6\nduration = 0.05\n'
    'metrics = ["rmse"]\n[factors."payload.mass"]\nvalues = [0.0, 5.0]\n'
)


def test_cells_without_pairs_say_the_runs_that_did_not_end_ok_took_them(tmp_path):
    out = tmp_path / "c"
    # PD diverges in every run of the second cell
    _fake_campaign(out, SPEC, status=lambda r: "diverged" if (r.cell, r.controller) == (1, "pd")
                   else "ok")  # fmt: skip
    write_report(out)
    md = (out / "report" / "report.md").read_text()
    assert ("(all with fewer than the 5 pairs a verdict takes; in 1 of them, runs that did "
            "not end ok took pairs away, listed below)") in md  # fmt: skip


def test_a_metric_undefined_in_every_run_is_said_not_blamed_on_the_runs(tmp_path):
    out = tmp_path / "c"
    nan = float("nan")
    _fake_campaign(out, SPEC, metric=lambda r, m: nan)  # every run ok, no finite metric
    write_report(out)
    md = (out / "report" / "report.md").read_text()
    assert "no pair of runs where both ended ok" not in md
    assert ("- pd vs smc: no pair to compare: in 12 pairs that ended ok the metric is not "
            "finite") in md  # fmt: skip


def test_runs_not_run_yet_are_not_called_runs_that_did_not_end_ok(tmp_path):
    """An interrupted campaign's missing runs were counted as runs that did not end ok
    ("listed below", and nothing was)."""
    out = tmp_path / "c"
    _fake_campaign(out, SPEC)
    sorted((out / "runs").glob("task-*.parquet"))[-1].unlink()  # as if interrupted
    write_report(out)
    md = (out / "report" / "report.md").read_text()
    assert "runs that did not end ok took pairs away" not in md
    assert "runs not run yet (the campaign is not complete)" in md
