"""The staging folder of a command's outputs (pkmctl.io.atomic.staged_folder) on Ctrl-C:
what the CLI's interrupt handler removes, and a Ctrl-C held during the renames."""

import os
import signal
import time
from pathlib import Path

import pytest

from pkmctl.io import atomic
from pkmctl.io.atomic import discard, published, staged_folder


def test_discard_removes_the_folders_the_run_made_above_its_output(tmp_path):
    """The CLI's Ctrl-C handler discards the stage and exits at once, so the context's own
    cleanup never runs: "nestC/x/y was not created" left nestC/x behind."""
    (tmp_path / "kept").mkdir()
    cm = staged_folder(tmp_path / "nest" / "x" / "y")
    stage = cm.__enter__()  # (never exited: the command exits the process from here)
    (stage / "pd.json").write_text("{}")
    assert (tmp_path / "nest" / "x").is_dir()
    discard(stage)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"]
    assert not published(stage)


def test_a_ctrl_c_held_during_the_renames_comes_after_the_set_is_in_place(tmp_path, monkeypatch):
    """The interrupt is raised once the new set replaced the old one; ``published`` then
    says so (the CLI says "the results are in DIR", not "nothing written"), and the old
    files' trash folder is gone, not left in the output folder."""
    dest = tmp_path / "out"
    dest.mkdir()
    (dest / "a.txt").write_text("old")
    merge = atomic._merge

    def merge_then_ctrl_c(*args):
        merge(*args)
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(atomic, "_merge", merge_then_ctrl_c)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt), staged_folder(dest) as stage:
            (stage / "a.txt").write_text("new")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert (dest / "a.txt").read_text() == "new"
    assert published(stage)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.txt", "out"]


def test_a_folder_named_on_the_way_by_dot_dot_is_not_left_behind(tmp_path):
    """--out x/../y: x was made on the way (as the path was written) and stayed after a
    failed run, which removed "x/.." (the non-empty folder above) and stopped there; and
    after a good one (a fuzzer)."""
    dest = tmp_path / "x" / ".." / "y"
    with pytest.raises(RuntimeError), staged_folder(dest) as stage:
        (stage / "a.txt").write_text("a")
        raise RuntimeError("the run failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    with staged_folder(dest) as stage:
        (stage / "a.txt").write_text("a")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["y"]
    assert (tmp_path / "y" / "a.txt").read_text() == "a"


def test_a_tilde_is_the_home_folder(tmp_path, monkeypatch):
    """--out=~/x (which the shell leaves as it is) and PKMCTL_CACHE_DIR=~/c (a .env file,
    a Dockerfile's ENV) made a folder named "~" in the current one (a tester)."""
    from pkmctl import _jit
    from pkmctl.io.atomic import check_output_file, check_output_folder

    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    assert check_output_folder("~/out") == tmp_path / "home" / "out"
    assert check_output_file("~/a.toml") == tmp_path / "home" / "a.toml"
    monkeypatch.setenv("PKMCTL_CACHE_DIR", "~/cache")
    assert _jit._cache_root() == tmp_path / "home" / "cache"
    assert not (tmp_path / "~").exists()


def test_a_ctrl_c_during_the_writability_probe_leaves_no_probe_folder(tmp_path, monkeypatch):
    """check_output_folder makes a folder and removes it at once to see that it can; a
    Ctrl-C between the two (a full run's interrupted reproduce, once) left an empty
    ``.pkmctl-probe-*`` in the user's output folder. The Ctrl-C still comes, after."""
    import tempfile

    from pkmctl.io.atomic import check_output_folder

    dest = tmp_path / "out"
    dest.mkdir()
    mkdtemp = tempfile.mkdtemp

    def mkdtemp_then_ctrl_c(*args, **kwargs):
        made = mkdtemp(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)
        return made

    monkeypatch.setattr(tempfile, "mkdtemp", mkdtemp_then_ctrl_c)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            check_output_folder(dest)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["out"]


def test_settle_waits_for_a_worker_threads_probe_and_lets_none_start(tmp_path, monkeypatch):
    """The CLI's Ctrl-C exits at once (os._exit) while a worker thread may be between
    making its probe folder and removing it: ``settle``, called before that exit, waits
    for the probe to be gone and lets no new one be made."""
    import tempfile
    import threading

    from pkmctl.io import atomic

    mkdtemp = tempfile.mkdtemp
    made, go_on = threading.Event(), threading.Event()

    def slow_mkdtemp(*args, **kwargs):
        folder = mkdtemp(*args, **kwargs)
        made.set()
        go_on.wait(10)
        return folder

    monkeypatch.setattr(tempfile, "mkdtemp", slow_mkdtemp)
    worker = threading.Thread(target=atomic.check_output_folder, args=(tmp_path,))
    worker.start()
    assert made.wait(10)
    assert [p.name for p in tmp_path.iterdir()][0].endswith(".tmp")  # the probe is there
    settled = threading.Thread(target=atomic.settle)
    settled.start()
    settled.join(0.3)
    assert settled.is_alive()  # waiting for the probe
    go_on.set()
    settled.join(10)
    worker.join(10)
    try:
        assert not settled.is_alive() and list(tmp_path.iterdir()) == []
        late = threading.Thread(target=atomic.check_output_folder, args=(tmp_path,), daemon=True)
        late.start()
        late.join(0.3)
        assert late.is_alive() and list(tmp_path.iterdir()) == []  # no probe after settle
    finally:
        atomic._PROBE_LOCK.release()
    late.join(10)
    assert not late.is_alive()


def test_an_interrupted_runs_thread_cannot_stage_in_its_removed_folder(tmp_path):
    """``reproduce`` stages its files inside the command's staging folder. A Ctrl-C
    removes that folder (``discard``) and exits while the run's thread goes on: that
    thread's own staging then found its folder gone and made its staging folder in the
    user's output folder instead, where it stayed (a tester's random SIGHUP)."""
    from pkmctl.errors import OutputError
    from pkmctl.io.atomic import discard

    dest = tmp_path / "out"
    dest.mkdir()
    (dest / "old.txt").write_text("old")
    with pytest.raises(KeyboardInterrupt), staged_folder(dest) as stage:
        discard(stage)  # the command's Ctrl-C, in the main thread
        with pytest.raises(OutputError, match="its run was stopped"):  # the run's thread
            with staged_folder(stage) as inner:
                (inner / "table4.csv").write_text("new")
        raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["old.txt", "out"]


def test_a_probe_folder_a_killed_process_left_is_swept_by_a_later_run(tmp_path, monkeypatch):
    """The probe is named as a staging folder so that a later run removes one a killed
    process left; named ".pkmctl-<pid>@<host>-probe-*.tmp", its host read as
    "<host>-probe", never this one, and it stayed (a reviewer)."""
    import subprocess
    import tempfile

    from pkmctl.io.atomic import check_output_folder

    dest = tmp_path / "out"
    dest.mkdir()
    names, mkdtemp = [], tempfile.mkdtemp

    def record(*args, **kwargs):
        names.append(Path(mkdtemp(*args, **kwargs)))
        return str(names[-1])

    monkeypatch.setattr(tempfile, "mkdtemp", record)
    check_output_folder(dest)
    monkeypatch.undo()
    (probe,) = names
    dead = subprocess.Popen(["true"])
    dead.wait()
    left = dest / probe.name.replace(f"-{os.getpid()}@", f"-{dead.pid}@", 1)
    left.mkdir()
    os.utime(left, (time.time() - 3600,) * 2)  # an hour ago: its process is gone
    with staged_folder(dest) as stage:
        (stage / "a.txt").write_text("a")
    assert sorted(p.name for p in dest.iterdir()) == ["a.txt"]


def test_a_stopped_campaign_folder_is_not_made_after_the_command_said_so(tmp_path):
    """An interrupted ``campaign run`` said "nothing written" and exited; its thread,
    which cannot be stopped, went on and made the campaign folder before the process
    ended (a tester's SIGTERM while the model kernels compiled). Once the command has
    stopped the folder, the store is not made; one made before is whole."""
    from pkmctl.campaign.spec import CampaignSpec
    from pkmctl.campaign.store import open_store

    (tmp_path / "spec.toml").write_text(
        'name = "stopped"\nscenario = "paper"\ncontrollers = ["pd"]\nseeds = 2\n'
        'duration = 0.01\nmetrics = ["rmse"]\n'
    )
    spec = CampaignSpec.from_toml(tmp_path / "spec.toml")
    made = tmp_path / "made"
    open_store(made, spec, resume=False)
    atomic.stop(made)  # after the store: it stays whole
    assert (made / "campaign.json").is_file() and (made / "runs").is_dir()
    out = tmp_path / "out"
    atomic.stop(out)  # the command's Ctrl-C, in the main thread
    with pytest.raises(FileNotFoundError, match="its run was stopped"):
        open_store(out, spec, resume=False)  # the run's thread, going on
    assert not out.exists()
