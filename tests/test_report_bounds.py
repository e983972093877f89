"""Bounds of what the reports print and write: the paper's Table 4 numbers, each cell's
digits, the edge of "RMSE after the first second", the label of a controller that is no
part, the files reproduce checks before its runs, and the campaign report's numbers."""

from __future__ import annotations

import math
from pathlib import PurePosixPath

import pytest

import pkmctl
from pkmctl.errors import OutputError
from pkmctl.report.tables import (
    PAPER_TABLE4,
    _fmt,
    controller_label,
    rmse_after,
    table4_markdown,
)
from pkmctl.sim.metrics import RMSE_KEYS, chattering_index, last_time, peak_forces

#: Table 4 of the paper, as printed there (z mm, alpha and beta deg, q1..q4 m).
PAPER = {
    "smc": (0.545968, 0.918397, 6.12032, 0.0120748, 0.0266254, 0.00977163, 0.0173405),
    "fsmc": (0.218587, 0.825874, 4.73001, 0.00969521, 0.0193492, 0.00668029, 0.0140356),
    "afsmc": (0.377072, 0.184167, 2.66612, 0.00153664, 0.0094806, 0.00061928, 0.0075560),
}


@pytest.fixture(scope="module")
def smc() -> pkmctl.Result:
    return pkmctl.simulate("paper", "smc", duration=0.02)


def _cell(x: float, digits: int) -> str:
    """``x`` to ``digits`` significant digits, trailing zeros kept, no lone "."."""
    text = f"{x:#.{digits}g}"
    return text[:-1] if text.endswith(".") else text


def _rows(md: str, label: str, source: str | None = None) -> list[list[str]]:
    rows = []
    for line in md.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if cells[0] == label and (source is None or cells[1] == source):
            rows.append(cells)
    return rows


def test_the_papers_table4_is_every_number_of_the_paper():
    """Only two of the 21 numbers were checked: any other, mistyped, went into every
    report's "paper" row and every "ours / paper" ratio unseen."""
    assert {c: tuple(row[k] for k in RMSE_KEYS) for c, row in PAPER_TABLE4.items()} == PAPER


def test_the_ratio_row_has_two_significant_digits(smc):
    ours = smc.rmse()
    [row] = _rows(table4_markdown({"smc": smc}), "SMC", "ours / paper")
    assert row[2:] == [_cell(ours[k] / PAPER_TABLE4["smc"][k], 2) for k in RMSE_KEYS]


def test_the_force_row_has_four_digits_of_peaks_and_three_of_chattering(smc):
    md = table4_markdown({"smc": smc})
    force_row = _rows(md.split("peak |τ_i|")[1], "SMC")  # the last table's
    assert len(force_row) == 1
    peaks = [_cell(float(v), 4) for v in peak_forces(smc)]
    chat = [_cell(float(v), 3) for v in chattering_index(smc)]
    assert force_row[0][1:] == peaks + chat


@pytest.mark.parametrize(
    ("x", "spec", "text"),
    [
        (0.7, ".4g", "0.7000"),  # trailing zeros kept
        (5222.0, ".4g", "5222"),  # not "5222."
        (0.0012345, ".2g", "0.0012"),
        (16757.01, ".3g", "1.68e+04"),
        (None, ".4g", "—"),
        (math.nan, ".4g", "—"),
        (math.inf, ".2g", "—"),
    ],
)
def test_a_cell_is_its_significant_digits(x, spec, text):
    assert _fmt(x, spec) == text


def test_rmse_after_a_time_the_run_reaches_at_its_last_period(smc):
    """A run that ends exactly at ``t_from`` has an RMSE from there (its last sample);
    one that ends before it has none."""
    end = last_time(smc)
    after = rmse_after(smc, end)
    assert after is not None and set(after) == set(RMSE_KEYS)
    assert rmse_after(smc, end + 1e-9) is None


def test_a_controller_that_is_no_part_is_labelled_by_its_own_name():
    assert controller_label("my-Law") == "my-Law"
    assert controller_label("afsmc") == "AFSMC"


@pytest.mark.parametrize(
    "name",
    [
        "table4.csv",
        "table4.md",
        "report.md",
        "timeseries/afsmc.parquet",
        "timeseries/ctc.json",
        "figures/fig10.png",
        "figures/fig26.png",
        "figures/machine_end.png",
    ],
)
def test_reproduce_refuses_a_folder_where_it_writes_a_file_before_any_run(tmp_path, name):
    """Each file ``reproduce`` writes is checked before the five runs: a folder in its
    place was refused only at the end, all the work lost."""
    from pkmctl.experiment import reproduce

    (tmp_path / name).mkdir(parents=True)
    with pytest.raises(OutputError) as err:
        reproduce(pkmctl.Scenario.builtin("paper", 0.01), tmp_path)
    assert str(err.value) == (
        f"output folder: {str(tmp_path / name)!r} is a folder, where pkmctl puts a file of "
        "that name: move it away or choose another output folder"
    )
    left = {p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")}
    assert left == {name, *(p.as_posix() for p in PurePosixPath(name).parents)} - {"."}


# ---------------------------------------------------------------- the campaign report
@pytest.mark.parametrize(
    ("ratio", "lo", "hi", "text"),
    [
        (0.93, 0.92, 0.94, "0.930× [0.920, 0.940]"),  # within (0.9, 1.1): three decimals
        (1.09, 1.08, 1.095, "1.090× [1.080, 1.095]"),
        (0.9, 0.85, 0.95, "0.9× [0.85, 0.95]"),  # the bounds themselves: 2 digits
        (0.95, math.nan, math.nan, "0.950×"),  # no interval (one pair)
        # an interval below 1 in the fifth digit: as many decimals as show it
        (0.99995, 0.9999, 0.99996, "0.99995× [0.99990, 0.99996]"),
        # outside (0.9, 1.1) too: an interval off 1 read "[1, 1.4]", as one holding 1 does
        # (a mutation tester); two significant digits otherwise
        (1.2, 1.0004, 1.4, "1.2× [1.0004, 1.4]"),
        (1.15, 0.996, 1.3, "1.1× [1, 1.3]"),
        (0.8, 0.6, 0.9996, "0.8× [0.6, 0.9996]"),
        (1.4, 1.38, 1.42, "1.4× [1.4, 1.4]"),
    ],
)
def test_a_campaign_ratio_is_printed_in_the_digits_its_range_gets(ratio, lo, hi, text):
    from pkmctl.report.campaign import _ratio

    assert _ratio({"ratio": ratio, "ratio_lo": lo, "ratio_hi": hi}) == text


def test_a_factor_level_keeps_every_digit_that_tells_it_apart():
    """%g's six digits made 1.000001 read "1", the same as a level of 1."""
    from pkmctl.report.campaign import _level

    assert [_level(x) for x in (1.000001, 0.001, 1e-7, 2.0, 10)] == [
        "1.000001",
        "0.001",
        "1e-07",
        "2",
        "10",
    ]


def test_a_csv_number_that_is_not_finite_is_an_empty_field():
    """A reader types the column as numbers only when no field is text ("nan")."""
    from pkmctl.report.campaign import _full

    assert [_full(x) for x in (math.nan, math.inf, -math.inf, None, 0.1, 3)] == [
        "",
        "",
        "",
        "",
        "0.1",
        "3",
    ]


@pytest.mark.parametrize(
    ("failed", "diverged", "text"),
    [
        (3, 1, "3 pd runs did not end ok (1 diverged, 2 failed with an error)"),
        (2, 2, "2 pd runs diverged"),
        (1, 0, "1 pd run failed with an error"),
        (0, 0, "every pd run ended ok"),
    ],
)
def test_runs_not_ok_are_counted_by_how_they_ended(failed, diverged, text):
    from pkmctl.report.campaign import _not_ok

    assert (
        _not_ok({"baseline_failed": failed, "baseline_diverged": diverged}, "baseline", "pd")
        == text
    )


def test_a_campaign_figure_is_logarithmic_from_means_20_times_apart():
    from pkmctl.report.campaign import _log_y

    low = {"mean": 1.0, "lo": 0.5}
    assert _log_y([low, {"mean": 20.0, "lo": 19.0}])
    assert not _log_y([low, {"mean": 19.99, "lo": 19.0}])
