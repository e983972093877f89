"""Bounds of what is read and written: save_result/load_result (the formats allowed, what
a JSON must be, a table whose columns are not the JSON's, a non-finite final state, a stale
table that is a link, a .fis file changed since the run), plugin files, atomic writes."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

import pkmctl
from pkmctl.io.results import load_result, save_result


@pytest.fixture(scope="module")
def run() -> pkmctl.Result:
    return pkmctl.simulate("paper", "pd", duration=0.01)


def test_a_format_not_known_is_refused_in_one_line_and_nothing_is_written(run, tmp_path):
    """Without the check, fmt="xlsx" wrote a Parquet table named pd.xlsx."""
    with pytest.raises(ValueError) as err:
        save_result(run, tmp_path, fmt="xlsx")
    assert str(err.value) == "fmt = 'xlsx': must be one of parquet, csv"
    assert not any(tmp_path.iterdir())


def test_a_json_of_another_format_version_is_refused(run, tmp_path):
    _, meta = save_result(run, tmp_path)
    data = json.loads(meta.read_text())
    data["format_version"] = 2
    meta.write_text(json.dumps(data))
    with pytest.raises(ValueError) as err:
        load_result(meta)
    assert str(err.value) == f"{meta}: unsupported format_version 2"


@pytest.mark.parametrize("text", ["[1, 2]", '"pd"', "3"])
def test_a_json_that_is_not_an_object_is_the_one_line_refusal(tmp_path, text):
    """A JSON list or number was an AttributeError/TypeError, not the one-line refusal."""
    path = tmp_path / "x.json"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        load_result(path)
    assert str(err.value) == f"{path}: not the JSON file save_result writes beside a result's table"


def test_a_file_with_no_json_beside_it_gets_no_hint(tmp_path):
    """The hint "give x.json, written beside it" names a file only where there is one."""
    path = tmp_path / "notes.txt"
    path.write_bytes(b"\xff\xfe not json")
    with pytest.raises(ValueError) as err:
        load_result(path)
    assert str(err.value) == (
        f"{path}: not the JSON file save_result writes beside a result's table"
    )


def test_a_table_with_other_columns_than_the_json_is_refused(run, tmp_path):
    """A JSON written before the table's digest, beside a CSV of one column more: the
    column count is what catches it (the rows and the order of the columns shifted)."""
    table, meta = save_result(run, tmp_path, fmt="csv")
    data = json.loads(meta.read_text())
    data.pop("table_sha256")
    meta.write_text(json.dumps(data))
    lines = table.read_text().splitlines()
    table.write_text("\n".join([lines[0] + ",extra"] + [ln + ",1.0" for ln in lines[1:]]) + "\n")
    with pytest.raises(ValueError) as err:
        load_result(meta)
    assert str(err.value) == f"{table}: expected {len(data['columns'])} columns"


def test_a_final_state_that_is_not_finite_reads_back_as_nan(run, tmp_path):
    """Written as null (standard JSON), it must read back as NaN, not as a number."""
    odd = dataclasses.replace(run, final_state={"controller": np.array([1.5, math.nan, -math.inf])})
    _, meta = save_result(odd, tmp_path)
    assert json.loads(meta.read_text())["final_state"] == {"controller": [1.5, None, None]}
    back = load_result(meta).final_state["controller"]
    assert back[0] == 1.5 and np.isnan(back[1:]).all()


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_a_stale_table_that_is_a_dangling_link_is_removed(run, tmp_path, fmt):
    """An earlier table of the other format is removed, also a link to a file gone."""
    other = "csv" if fmt == "parquet" else "parquet"
    stale = tmp_path / f"pd.{other}"
    stale.symlink_to(tmp_path / "gone")
    save_result(run, tmp_path, fmt=fmt)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f"pd.{fmt}", "pd.json"])


@pytest.mark.parametrize("stem", ["a\\b", "..\\up", "x\\"])
def test_a_stem_with_a_backslash_is_refused(run, tmp_path, stem):
    """A backslash is a folder separator on Windows: "..\\up" wrote outside the folder."""
    with pytest.raises(ValueError) as err:
        save_result(run, tmp_path, stem)
    assert str(err.value) == f"stem = {stem!r}: must be a file name, without a folder"
    assert not any(tmp_path.iterdir())
