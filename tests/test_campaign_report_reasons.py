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


COMPARE = '[[compare]]\nname = "q"\ncontroller = "pd"\nbaseline = "smc"\n'


def test_a_side_that_diverged_in_every_run_is_said_to_have_diverged(tmp_path):
    """A cell where PD diverged in every run and SMC in none read "cannot tell", and its
    runs "did not end ok" (which also covers errors, that are not a result), and the
    table's "failed 6/0" read as 6 of 0 (a tester's findings). The CSV left numbers out
    as "n/a", which made DuckDB read the column as text."""
    import csv

    out = tmp_path / "c"
    _fake_campaign(out, SPEC + COMPARE, status=lambda r: "diverged"
                   if (r.cell, r.controller) == (1, "pd") else "ok")  # fmt: skip
    write_report(out)
    answer = (out / "report" / "answer.md").read_text()
    assert "in 1 of them, runs that diverged took pairs away, listed below" in answer
    assert "- at payload.mass = 5: 6 pd runs diverged; every smc run ended ok" in answer
    assert "no verdict (0 pairs < 5); runs not ok: pd 6, smc 0" in answer
    with open(out / "report" / "comparison.csv") as fh:
        rows = [r for r in csv.DictReader(fh) if r["cell"] == "1"]
    assert rows and all(r["ratio"] == "" and r["controller_diverged"] == "6" for r in rows)


def test_a_partial_campaigns_answer_says_its_runs_are_not_run_yet(tmp_path):
    """answer.md gave "fewer than the 5 pairs" alone where report.md said why."""
    out = tmp_path / "c"
    _fake_campaign(out, SPEC + COMPARE)
    sorted((out / "runs").glob("task-*.parquet"))[-1].unlink()  # as if interrupted
    write_report(out)
    answer = (out / "report" / "answer.md").read_text()
    assert "runs not run yet (the campaign is not complete)" in answer


def test_a_ratio_interval_off_1_is_printed_in_the_digits_that_show_it():
    """ "1.000x [1.000, 1.000] worse": the interval excluded 1 in the fifth digit."""
    from pkmctl.report.campaign import _ratio

    r = {"ratio": 1.0002682, "ratio_lo": 1.0000054, "ratio_hi": 1.0005302}
    assert _ratio(r) == "1.00027× [1.00001, 1.00053]"
    r = {"ratio": 0.997, "ratio_lo": 0.994, "ratio_hi": 1.0004}  # holds 1: as before
    assert _ratio(r) == "0.997× [0.994, 1.000]"
    r = {"ratio": 0.99, "ratio_lo": 0.985, "ratio_hi": 0.9951}
    assert _ratio(r) == "0.990× [0.985, 0.995]"
