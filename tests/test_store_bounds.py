"""The results store at its bounds: which files count as a task's, what counts as done,
the task grouping of an old folder, the records' order (a tester's mutation round)."""

import json
import shutil

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pkmctl.campaign.spec import SpecError
from pkmctl.campaign.store import (
    completed_tasks,
    mixed_versions,
    read_records,
    stored_statuses,
    task_grouping,
    write_task,
)
from tests.test_campaign import HEAD, _fake_campaign

THREE = HEAD.replace('["smc"]', '["smc", "pd"]').replace("seeds = 1", "seeds = 3")


@pytest.fixture
def folder(tmp_path):
    out = tmp_path / "c"
    spec = _fake_campaign(out, THREE)
    return out, spec


def test_a_file_numbered_past_the_last_task_is_not_the_campaigns(folder):
    out, spec = folder
    runs, n = out / "runs", len(spec.tasks())
    shutil.copy(runs / "task-00000.parquet", runs / f"task-{n:05d}.parquet")
    assert sorted(stored_statuses(runs, n)) == list(range(n))
    table = read_records(out)  # the copy is not read: no run counted twice
    assert table.num_rows == spec.n_runs == 6


def test_a_task_file_not_named_with_five_digits_does_not_count_as_done(folder):
    out, spec = folder
    runs, n = out / "runs", len(spec.tasks())
    shutil.copy(runs / "task-00000.parquet", runs / "task-9.parquet")
    shutil.copy(runs / "task-00000.parquet", runs / "task-00000 (copy).parquet")
    assert completed_tasks(runs) == set(range(n))
    assert sorted(stored_statuses(runs)) == list(range(n))


def test_a_task_file_mixing_in_another_campaigns_records_is_refused(folder):
    out, spec = folder
    runs = out / "runs"
    t = pq.read_table(runs / "task-00000.parquet")
    hashes = t.column("spec_hash").to_pylist()
    hashes[-1] = "0" * 16
    t = t.set_column(t.schema.get_field_index("spec_hash"), "spec_hash", pa.array(hashes))
    write_task(runs, 0, t)
    with pytest.raises(SpecError) as exc:
        completed_tasks(runs, spec.digest)
    assert str(exc.value) == (
        f"{runs / 'task-00000.parquet'}: records of campaign {'0' * 16!r}, not of this "
        f"folder's {spec.digest!r} (a file of another campaign: move it out of runs/)"
    )


def test_a_task_file_holding_one_of_its_runs_twice_is_refused(folder):
    out, spec = folder
    runs = out / "runs"
    task = spec.tasks()[0]
    t = pq.read_table(runs / "task-00000.parquet")
    write_task(runs, 0, pa.concat_tables([t, t.slice(0, 1)]))
    with pytest.raises(SpecError) as exc:
        completed_tasks(runs, spec.digest, spec.tasks())
    assert str(exc.value) == (
        f"{runs / 'task-00000.parquet'}: not this task's records (it holds "
        f"{len(task.runs) + 1} records of the {len(task.runs)} runs of task 0); delete it, "
        "and --resume runs its task again"
    )


def test_a_folder_made_before_the_grouping_was_recorded_groups_as_it_did_then(folder):
    out, _ = folder
    assert task_grouping(out) == (1.0, 8)
    manifest = json.loads((out / "campaign.json").read_text())
    del manifest["task_seconds"], manifest["task_multiple"]
    (out / "campaign.json").write_text(json.dumps(manifest))
    assert task_grouping(out) == (0.2, 1)


def test_two_versions_of_pkmctl_in_one_campaign_are_said(folder):
    out, _ = folder
    manifest = json.loads((out / "campaign.json").read_text())
    manifest["sessions"] = [{"pkmctl": "0.2.3", "pkmctl_sources": "aaa"}]
    (out / "campaign.json").write_text(json.dumps(manifest))
    assert mixed_versions(out) == ""
    manifest["sessions"].append({"pkmctl": "0.2.4", "pkmctl_sources": "bbb"})
    (out / "campaign.json").write_text(json.dumps(manifest))
    assert mixed_versions(out) == (
        "its records were made by 2 versions of pkmctl's code: 0.2.3 (sources aaa), 0.2.4 "
        "(sources bbb), in the order of their sessions in campaign.json; run into another "
        "folder to keep them apart"
    )


def test_records_are_sorted_by_cell_controller_in_the_specs_order_and_seed(folder):
    out, spec = folder
    t = read_records(out)
    keys = list(zip(t.column("cell").to_pylist(), t.column("controller").to_pylist(),
                    t.column("seed").to_pylist(), strict=True))  # fmt: skip
    seeds = sorted(spec.seeds)
    assert keys == [(0, c, s) for c in ("smc", "pd") for s in seeds]
    assert seeds[0] < seeds[-1]
