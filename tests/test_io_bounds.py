"""Bounds of what is read and written: save_result/load_result (the formats allowed, what
a JSON must be, a table whose columns are not the JSON's, a non-finite final state, a stale
table that is a link, a .fis file changed since the run), plugin files, atomic writes."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

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


# ---------------------------------------------------------------- plugin files read in
@pytest.fixture
def plugin_env(monkeypatch):
    """PKMCTL_PLUGINS and sys.path as they were after the test; its modules forgotten."""
    import sys

    from pkmctl.plugins import ENV

    monkeypatch.setenv(ENV, "")
    monkeypatch.setattr(sys, "path", list(sys.path))
    before = set(sys.modules)
    yield ENV
    for name in set(sys.modules) - before:
        if name.startswith("plug_") or name.startswith("helper_"):
            del sys.modules[name]


def _unique(tmp_path) -> str:
    return tmp_path.name.replace("-", "_").lower()


def test_a_plugin_file_not_named_as_a_module_is_refused(tmp_path, plugin_env):
    import sys

    from pkmctl.plugins import PluginError, load_plugins

    path = tmp_path / "my-law.py"
    path.write_text("VALUE = 1\n")
    with pytest.raises(PluginError) as err:
        load_plugins([str(path)])
    assert str(err.value) == f"--plugin {path}: 'my-law' is not a Python module name"
    assert "my-law" not in sys.modules


def test_a_plugin_imports_a_module_beside_it(tmp_path, plugin_env):
    from pkmctl.plugins import load_plugins

    u = _unique(tmp_path)
    (tmp_path / f"helper_{u}.py").write_text("VALUE = 7\n")
    path = tmp_path / f"plug_{u}.py"
    path.write_text(f"from helper_{u} import VALUE\nassert VALUE == 7\n")
    assert load_plugins([str(path)]) == [str(path.resolve())]


def test_a_plugin_that_failed_can_be_loaded_once_fixed(tmp_path, plugin_env):
    """A failed import left its half module in sys.modules: the fixed file was then
    taken for the file "imported already", the fixed one never run."""
    import sys

    from pkmctl.plugins import PluginError, load_plugins

    path = tmp_path / f"plug_{_unique(tmp_path)}.py"
    path.write_text("raise RuntimeError('boom')\n")
    with pytest.raises(PluginError, match="RuntimeError: boom"):
        load_plugins([str(path)])
    path.write_text("VALUE = 1\n")
    assert load_plugins([str(path)]) == [str(path.resolve())]
    assert sys.modules[path.stem].VALUE == 1  # the fixed file ran, not the half module kept


def test_the_environment_lists_every_plugin_loaded_once(tmp_path, plugin_env):
    """Workers import what PKMCTL_PLUGINS lists: a second --plugin must not drop the first."""
    import os

    from pkmctl.plugins import listed, load_plugins

    u = _unique(tmp_path)
    a, b = tmp_path / f"plug_{u}_a.py", tmp_path / f"plug_{u}_b.py"
    for p in (a, b):
        p.write_text("VALUE = 1\n")
    load_plugins([str(a)])
    load_plugins([str(b), str(a)])
    assert json.loads(os.environ[plugin_env]) == [str(a.resolve()), str(b.resolve())]
    assert listed() == [str(a.resolve()), str(b.resolve())]


@pytest.mark.parametrize(
    ("value", "names"),
    [('["a", "", "b"]', ["a", "b"]), ("a" + ":" * 2 + "b:", ["a", "b"]), ("", [])],
)
def test_the_environments_empty_names_are_no_plugins(monkeypatch, value, names):
    import os

    from pkmctl.plugins import ENV, listed

    monkeypatch.setenv(ENV, value.replace(":", os.pathsep))
    assert listed() == names


# ---------------------------------------------------------------- atomic writes
def test_an_output_file_name_of_the_longest_length_is_allowed_and_written(tmp_path):
    """The longest name is the file system's less the temporary name's extra bytes: that
    name is checked, and written; one byte more is refused in one line, before any work."""
    from pkmctl.errors import OutputError
    from pkmctl.io.atomic import TEMP_EXTRA, _name_max, atomic_write, check_output_file

    longest = _name_max(tmp_path) - TEMP_EXTRA
    path = tmp_path / ("x" * longest)
    assert check_output_file(path) == path
    with atomic_write(path) as fh:
        fh.write("ok")
    assert path.read_text() == "ok"
    with pytest.raises(OutputError) as err:
        check_output_file(tmp_path / ("y" * (longest + 1)))
    assert str(err.value).endswith(
        f"...: the name is too long (at most {longest} bytes: the file is written under a "
        f"temporary name {TEMP_EXTRA} bytes longer first)"
    )


@pytest.mark.parametrize("mode", ["a", "r+", "x", "w+"])
def test_atomic_write_refuses_a_mode_that_is_not_a_new_file(tmp_path, mode):
    """ "a" appended to the empty temporary file, then replaced the file: its text lost."""
    from pkmctl.io.atomic import atomic_write

    (tmp_path / "f").write_text("kept")
    with pytest.raises(ValueError) as err, atomic_write(tmp_path / "f", mode):
        pass
    assert str(err.value) == f"mode = {mode!r}: must be 'w' or 'wb'"
    assert [p.name for p in tmp_path.iterdir()] == ["f"] and (tmp_path / "f").read_text() == "kept"


@pytest.mark.parametrize("blank", ["", "   ", "\t"])
def test_a_blank_output_folder_is_an_empty_path(blank):
    from pkmctl.errors import OutputError
    from pkmctl.io.atomic import check_output_folder

    with pytest.raises(OutputError) as err:
        check_output_folder(blank)
    assert (
        str(err.value) == f"output folder = {blank!r}: empty path (name a folder, e.g. pkmctl-out)"
    )


def test_an_output_file_that_cannot_be_written_is_refused(tmp_path, monkeypatch):
    """(as root every file is writable: os.access is made to say no for this one)"""
    import os

    from pkmctl.errors import OutputError
    from pkmctl.io.atomic import check_output_file

    path = tmp_path / "out.json"
    path.write_text("{}")
    access = os.access
    monkeypatch.setattr(os, "access", lambda p, m: False if p == path else access(p, m))
    with pytest.raises(OutputError) as err:
        check_output_file(path)
    assert str(err.value) == f"output file {str(path)!r}: not writable"


# ---------------------------------------------------------------- a scenario's .fis file
@pytest.mark.parametrize("then", ["edited", "removed"])
def test_a_result_reads_back_with_the_fis_text_its_run_used(tmp_path, monkeypatch, then):
    """The JSON carries the .fis file's text: edited or removed since the run, the result
    reads back with a copy of the text the run used (in the cache), not the file now."""
    from pkmctl import fuzzy
    from pkmctl.fuzzy import fis

    path = tmp_path / "mine.fis"
    text = fis.to_fis_text(fuzzy.FLC())
    path.write_text(text, encoding="utf-8")
    sc = pkmctl.Scenario.builtin("paper").replace(**{"fuzzy.fis": str(path)})
    _, meta = save_result(pkmctl.simulate(sc, "pd", duration=0.01), tmp_path / "out")
    if then == "edited":
        path.write_text(text.replace("Name='", "Name='edited-", 1), encoding="utf-8")
    else:
        path.unlink()
    monkeypatch.setenv("PKMCTL_CACHE_DIR", str(tmp_path / "cache"))  # (after the run)
    used = Path(load_result(meta).scenario.fuzzy.fis)
    assert used != path and used.parent == tmp_path / "cache" / "fis"
    assert used.name.endswith("-mine.fis") and used.read_text(encoding="utf-8") == text
