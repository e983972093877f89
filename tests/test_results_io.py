"""A result on disk is one pair: its table and its JSON are written both or neither, and
a table beside the JSON of another save is refused on reading (issue: a seed-9 table
read back as seed 0 after a Ctrl-C between the two writes)."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import pkmctl
from pkmctl.io.results import load_result, save_result


@pytest.fixture(scope="module")
def runs() -> dict[str, pkmctl.Result]:
    """Three pd runs: seed 0 and seed 9 of 0.01 s (200 rows each), seed 9 of 0.02 s."""
    paper = pkmctl.Scenario.builtin("paper")
    nine = paper.replace(**{"disturbance.seed": 9})
    return {
        "seed0": pkmctl.simulate(paper, "pd", duration=0.01),
        "seed9": pkmctl.simulate(nine, "pd", duration=0.01),
        "seed9long": pkmctl.simulate(nine, "pd", duration=0.02),
    }


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _same(back: pkmctl.Result, r: pkmctl.Result) -> None:
    for name in ("t", "X", "q", "tau", "disturbance"):
        np.testing.assert_array_equal(getattr(back, name), getattr(r, name), err_msg=name)
    assert back.scenario == r.scenario


def _interrupt_json_write(monkeypatch, json_path: Path, where: str) -> None:
    """Ctrl-C as the JSON is written (``json.dump``) or renamed into place (the table
    already renamed: the last moment the pair can still be split)."""
    if where == "json.dump":

        def dump(*args, **kwargs):
            raise KeyboardInterrupt

        monkeypatch.setattr(json, "dump", dump)
        return
    replace = os.replace

    def replace_but_the_json(src, dst, *args, **kwargs):
        if Path(dst) == json_path:
            raise KeyboardInterrupt
        return replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace_but_the_json)


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
@pytest.mark.parametrize("where", ["json.dump", "os.replace"])
def test_ctrl_c_between_the_two_writes_keeps_the_old_pair(runs, tmp_path, monkeypatch, fmt, where):
    out = tmp_path / "sr"
    save_result(runs["seed0"], out, fmt=fmt)
    before = _files(out)
    _interrupt_json_write(monkeypatch, out / "pd.json", where)
    with pytest.raises(KeyboardInterrupt):
        save_result(runs["seed9long"], out, fmt=fmt)
    monkeypatch.undo()
    assert _files(out) == before  # no new table beside the old JSON, no temporary file
    _same(load_result(out / "pd.json"), runs["seed0"])


@pytest.mark.parametrize("where", ["json.dump", "os.replace"])
def test_ctrl_c_in_a_first_save_leaves_no_file(runs, tmp_path, monkeypatch, where):
    out = tmp_path / "sr"
    out.mkdir()
    _interrupt_json_write(monkeypatch, out / "pd.json", where)
    with pytest.raises(KeyboardInterrupt):
        save_result(runs["seed0"], out)
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("folder", ["pd.json", "pd.parquet"])
def test_a_folder_in_place_of_a_file_fails_before_anything_is_written(runs, tmp_path, folder):
    out = tmp_path / "sr"
    (out / folder).mkdir(parents=True)
    with pytest.raises(OSError) as err:
        save_result(runs["seed0"], out)
    assert [p.name for p in out.iterdir()] == [folder] and not any((out / folder).iterdir())
    assert f"{folder}': is a folder" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
@pytest.mark.parametrize("other", ["seed9", "seed9long"])
def test_a_table_of_another_save_is_refused(runs, tmp_path, fmt, other):
    """Of the same row count (seed 9 beside seed 0's JSON) too: the JSON holds the
    table's SHA-256."""
    mine, theirs = tmp_path / "mine", tmp_path / "theirs"
    save_result(runs["seed0"], mine, fmt=fmt)
    save_result(runs[other], theirs, fmt=fmt)
    shutil.copyfile(theirs / f"pd.{fmt}", mine / f"pd.{fmt}")
    with pytest.raises(ValueError, match=rf"pd\.{fmt} does not match .*pd\.json") as err:
        load_result(mine / "pd.json")
    assert "\n" not in str(err.value) and str(mine) in str(err.value)


def _without_digest(json_path: Path) -> None:
    """The JSON as written before it recorded the table's SHA-256."""
    meta = json.loads(json_path.read_text())
    meta.pop("table_sha256", None)
    json_path.write_text(json.dumps(meta, indent=2))


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_a_json_without_the_digest_loads_and_its_row_count_is_checked(runs, tmp_path, fmt):
    old, longer = tmp_path / "old", tmp_path / "longer"
    save_result(runs["seed0"], old, fmt=fmt)
    _without_digest(old / "pd.json")
    _same(load_result(old / "pd.json"), runs["seed0"])
    save_result(runs["seed9long"], longer, fmt=fmt)
    shutil.copyfile(longer / f"pd.{fmt}", old / f"pd.{fmt}")
    with pytest.raises(ValueError, match="400 rows, the JSON's samples = 200"):
        load_result(old / "pd.json")


def test_a_save_over_a_pair_replaces_both_and_follows_the_umask(runs, tmp_path):
    out = tmp_path / "sr"
    save_result(runs["seed0"], out)
    mask = os.umask(0o027)
    try:
        table, meta = save_result(runs["seed9long"], out)
    finally:
        os.umask(mask)
    assert sorted(p.name for p in out.iterdir()) == ["pd.json", "pd.parquet"]  # no .tmp
    assert {p.stat().st_mode & 0o777 for p in (table, meta)} == {0o640}
    _same(load_result(meta), runs["seed9long"])


def test_a_pair_whose_names_just_fit_can_be_saved_again(runs, tmp_path):
    """A 233-character stem was saved once and then never again: the name the old file
    is kept by while the new one is renamed in was 4 bytes over the limit (a tester)."""
    from pkmctl.io.atomic import TEMP_EXTRA, _name_max

    stem = "x" * (_name_max(tmp_path) - TEMP_EXTRA - len(".parquet"))
    save_result(runs["seed0"], tmp_path, stem)
    table, meta = save_result(runs["seed9long"], tmp_path, stem)
    _same(load_result(meta), runs["seed9long"])
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{stem}.json", f"{stem}.parquet"]


def test_a_ctrl_c_held_while_the_pair_is_renamed_goes_to_the_handler_that_was_there(
    runs, tmp_path, monkeypatch
):
    """Held off while the files are renamed, a Ctrl-C then raised KeyboardInterrupt
    whatever the handler was: a library user's own handler was never called, and a
    process that ignores SIGINT got the exception."""
    import signal

    from pkmctl.io import atomic

    real = atomic._replace_together

    def interrupted(tmps, targets):
        os.kill(os.getpid(), signal.SIGINT)  # arrives while the renames are held
        real(tmps, targets)

    monkeypatch.setattr(atomic, "_replace_together", interrupted)
    heard = []
    previous = signal.signal(signal.SIGINT, lambda *a: heard.append(a[0]))
    try:
        save_result(runs["seed0"], tmp_path / "own")  # the user's handler hears it
        assert heard == [signal.SIGINT]
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        save_result(runs["seed0"], tmp_path / "ignored")  # ignored: no exception
        signal.signal(signal.SIGINT, signal.default_int_handler)
        with pytest.raises(KeyboardInterrupt):  # Python's own: the pair is written first
            save_result(runs["seed0"], tmp_path / "default")
    finally:
        signal.signal(signal.SIGINT, previous)
    for name in ("own", "ignored", "default"):
        _same(load_result(tmp_path / name / "pd.json"), runs["seed0"])


def test_a_csv_loads_in_about_its_own_size_of_memory(runs, tmp_path):
    """A StringIO of the decoded text held 4 bytes a character (1.9 GB for a 335 MB CSV)."""
    import tracemalloc

    _, meta = save_result(runs["seed9long"], tmp_path, fmt="csv")
    size = (tmp_path / "pd.csv").stat().st_size
    tracemalloc.start()
    try:
        load_result(meta)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 3 * size, (peak, size)


def test_a_wrong_file_or_stem_is_one_line_naming_it(runs, tmp_path):
    """The table's path in place of the JSON's was a UnicodeDecodeError; a stem with a
    folder wrote outside the folder given; an object not a Result an AttributeError."""
    r = next(iter(runs.values()))
    table, meta = save_result(r, tmp_path)
    with pytest.raises(ValueError) as err:
        load_result(table)
    assert str(err.value) == (
        f"{table}: not the JSON file save_result writes beside a result's table: give "
        f"{meta}, written beside it"
    )
    for stem in ("../escaped", "sub/x", ".."):
        with pytest.raises(ValueError, match=f"^stem = {stem!r}: must be a file name"):
            save_result(r, tmp_path / "in", stem)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([table.name, meta.name])
    with pytest.raises(TypeError, match="^result = 'pd': must be a pkmctl Result"):
        save_result("pd", tmp_path)


def test_a_result_of_a_part_not_imported_names_its_file_and_the_import(runs, tmp_path):
    """In a new process that has not imported the module of a part the run used, the
    error named neither the file nor what to do from Python."""
    from pkmctl.sim.scenario import ScenarioError

    r = next(iter(runs.values()))
    _, meta = save_result(r, tmp_path)
    data = json.loads(meta.read_text())
    data["scenario_toml"] = data["scenario_toml"].replace(
        '[sensor]\nkind = "ideal"', '[sensor]\nkind = "x-not-imported"', 1
    )
    assert "x-not-imported" in data["scenario_toml"]
    meta.write_text(json.dumps(data))
    with pytest.raises(ScenarioError) as err:
        load_result(meta)
    msg = str(err.value)
    assert msg.startswith(f"{meta}: its scenario: sensor.kind") and "in Python, import it" in msg


def test_an_empty_stem_is_refused(runs, tmp_path):
    """stem="" fell back to the controller's name without a word (a tester)."""
    with pytest.raises(ValueError, match="stem = '': must be a file name, or None"):
        save_result(runs["seed0"], tmp_path, stem="")
    assert not any(tmp_path.iterdir())


def test_a_csv_reads_as_float64_in_other_readers_with_the_signs_of_zeros(tmp_path):
    """ "%.17g" wrote 0.0 as "0" and -0.0 as "-0": pyarrow, pandas, polars and DuckDB read a
    column of whole numbers (t logged once a second, a zero disturbance) as int64, and
    -0.0 came back as +0 (a tester). Every column now reads as float64, bit for bit."""
    import pyarrow.csv as pv
    import pyarrow.parquet as pq

    sc = pkmctl.Scenario.builtin("paper").replace(**{"disturbance.amplitude": [0.0, 0.0, 0.0]})
    runs = {
        "seconds": pkmctl.simulate(sc.replace(**{"logging.every": 20_000}), "pd", duration=3.0),
        "zeros": pkmctl.simulate(sc, "pd", duration=0.01),
    }
    assert runs["seconds"].t.tolist() == [0.0, 1.0, 2.0]
    assert np.signbit(runs["zeros"].disturbance).any()
    for name, r in runs.items():
        csv, _ = save_result(r, tmp_path / name, fmt="csv")
        parquet, _ = save_result(r, tmp_path / f"{name}-p")
        back, want = pv.read_csv(csv), pq.read_table(parquet)
        assert back.column_names == want.column_names
        assert {str(t) for t in back.schema.types} == {"double"}, name
        for col in want.column_names:
            a, b = want.column(col).to_numpy(), back.column(col).to_numpy()
            assert np.array_equal(a, b) and np.array_equal(np.signbit(a), np.signbit(b)), col
        mine = load_result(tmp_path / name / "pd.json")  # pkmctl's own reader, as before
        assert np.array_equal(np.signbit(mine.disturbance), np.signbit(r.disturbance))
        _same(mine, r)


def test_a_save_in_the_other_format_removes_the_earlier_table(runs, tmp_path):
    """save_result(fmt="csv") over a parquet save left pd.parquet beside a pd.json that
    describes pd.csv; `identify pd.parquet` then labelled it with the csv run's scenario,
    or refused it, blaming the data (a tester). The command removed it; now the library
    does too."""
    save_result(runs["seed0"], tmp_path)
    save_result(runs["seed9"], tmp_path, fmt="csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pd.csv", "pd.json"]
    save_result(runs["seed0"], tmp_path, stem="other")  # another stem's files are not touched
    save_result(runs["seed0"], tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "other.json", "other.parquet", "pd.json", "pd.parquet"
    ]  # fmt: skip


def test_a_resaved_result_keeps_the_software_that_made_it(runs, tmp_path):
    """load_result dropped the JSON's "software", and save_result wrote the pkmctl saving
    it: a re-saved result was labelled as made by it (a tester). A loaded result keeps its
    own; one made before it was recorded saves null."""
    from pkmctl.io.results import provenance

    _, meta = save_result(runs["seed0"], tmp_path / "a")
    made = json.loads(meta.read_text())
    assert made["software"] == provenance() and "software" not in made["info"]
    old = dict(made, software={"pkmctl": "0.0.1", "kernel_sources": "older"})
    meta.write_text(json.dumps(old))
    back = load_result(meta)
    assert back.info["software"] == {"pkmctl": "0.0.1", "kernel_sources": "older"}
    _, meta2 = save_result(back, tmp_path / "b", fmt="csv")
    again = json.loads(meta2.read_text())
    assert again["software"] == {"pkmctl": "0.0.1", "kernel_sources": "older"}
    assert "software" not in again["info"]
    del old["software"]  # made before it was recorded
    meta.write_text(json.dumps(old))
    _, meta3 = save_result(load_result(meta), tmp_path / "c")
    assert json.loads(meta3.read_text())["software"] is None


def test_reading_the_tables_leaves_an_interpreter_that_exits(runs, tmp_path):
    """pyarrow given a Python file object (to read a path that is not UTF-8 under
    LANG=C) aborted the interpreter at exit: "terminate called without an active
    exception", in 2 of 8 runs here (apache/arrow#34314, #50482). It gets its own file on
    the path's bytes now. Ten processes, each reading a run's table and a campaign task
    file as pkmctl does, must all exit 0."""
    import subprocess
    import sys

    import pyarrow as pa
    import pyarrow.parquet as pq

    table, _ = save_result(runs["seed0"], tmp_path)
    pq.write_table(pa.table({"a": np.arange(100_000.0)}), tmp_path / "task.parquet")
    code = (
        "import sys\nfrom pathlib import Path\n"
        "from pkmctl.campaign.store import _read\nfrom pkmctl.ident.identify import _read_table\n"
        "_read(Path(sys.argv[2]))\n_read_table(Path(sys.argv[1]))\n"
    )
    for _ in range(10):
        r = subprocess.run([sys.executable, "-c", code, str(table), str(tmp_path / "task.parquet")],
                           capture_output=True, text=True, timeout=60)  # fmt: skip
        assert r.returncode == 0, r.stderr


def test_to_arrow_is_the_table_save_result_writes(tmp_path):
    """A notebook had to write Parquet and read it back to get a Result into pandas or
    polars (a tester): ``to_arrow`` gives the same table without the file."""
    import pyarrow.parquet as pq

    import pkmctl

    r = pkmctl.simulate("prototype", "afsmc", duration=0.01)  # measured columns, theta_hat
    table, _ = pkmctl.save_result(r, tmp_path)
    assert r.to_arrow().equals(pq.read_table(table))
    assert "q1_m" in r.to_arrow().column_names and "theta_hat0" in r.to_arrow().column_names
