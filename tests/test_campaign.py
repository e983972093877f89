"""Campaigns (issue 11): specs, local and Dask execution, the store, resume, report."""

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from conftest import CORPUS
from typer.testing import CliRunner

import pkmctl
from pkmctl.campaign import CampaignSpec
from pkmctl.campaign.execute import run_campaign
from pkmctl.campaign.store import query, read_records, read_spec
from pkmctl.cli import app

runner = CliRunner()

SMALL = """
name = "small"
scenario = "paper"
controllers = ["fsmc", "afsmc"]
seeds = [3, 8]
duration = 0.05
metrics = ["rmse", "max_error"]

[factors."payload.mass"]
values = [0.0, 8.0]

[factors."controller_model.theta_scale"]
distribution = "uniform"
low = 0.4
high = 1.0
samples = 2
seed = 5
"""


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("spec") / "small.toml"
    path.write_text(SMALL)
    return path


@pytest.fixture(scope="module")
def reference(spec_file, tmp_path_factory):
    """The uninterrupted campaign, in this process (one worker)."""
    out = tmp_path_factory.mktemp("ref") / "camp"
    done = run_campaign(CampaignSpec.from_toml(spec_file), out, workers=1)
    assert done.complete and done.done_now == 16
    return out, read_records(out, timing=False)


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (
            '[factors."payload.mas"]\nvalues = [1.0]\n',
            "payload.mas: unknown field (payload: mass, offset)",
        ),
        ('[factors."payload.mass"]\nvalues = [-1.0]\n', "payload.mass = -1.0: must be"),
        ('[factors."timing.control_period"]\nvalues = []\n', "must be a non-empty list"),
        ("seeds = 0\n", "seeds = 0: must be >= 1 (zero runs)"),
        ('controllers = ["smc", "nope"]\n', "'nope' is not a registered controller"),
        ('[factors."disturbance.amplitude"]\nvalues = [[1.0, 2.0]]\n', "disturbance.amplitude"),
        (
            '[factors."payload.mass"]\ndistribution = "uniform"\nlow = 1.0\nhigh = 2.0\n',
            "samples = None: must be an integer >= 1",
        ),
        # not "(zero runs)", which 2.5 seeds are not (a tester)
        ("seeds = 2.5\n", "seeds = 2.5: must be a count >= 1 or a non-empty list of integers"),
        # a draw out of range names the factor that drew it (it read "payload.mass = -0.80")
        (
            '[factors."payload.mass"]\ndistribution = "normal"\nmean = 0.5\nstd = 1.0\n'
            "samples = 20\nseed = 1\n",
            "factors.'payload.mass': a draw of its normal distribution (seed 1) is outside the "
            "field's range: payload.mass = -0.80",
        ),
        # over an integer or a vector: "outside the field's range ... narrow the
        # distribution", which no narrowing mends (a tester)
        (
            '[factors."sensor.counts_per_rev"]\ndistribution = "uniform"\nlow = 1000.0\n'
            "high = 2000.0\nsamples = 2\n",
            "factors.'sensor.counts_per_rev': a distribution draws one real number a cell, "
            "and this field takes an integer (now 160000): give its values instead",
        ),
        (
            '[factors."disturbance.amplitude"]\ndistribution = "uniform"\nlow = 0.0\n'
            "high = 1.0\nsamples = 3\n",
            "this field takes a list of 3 numbers (now [2.0, 2.0, 2.0])",
        ),
    ],
)
def test_bad_specs_fail_in_one_line_before_anything_runs(tmp_path, change, expected):
    spec = tmp_path / "bad.toml"
    spec.write_text('scenario = "paper"\nduration = 0.05\n' + change)
    out = tmp_path / "out"
    res = runner.invoke(app, ["campaign", "run", str(spec), "--out", str(out)])
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and expected in lines[0], lines
    assert not out.exists()


@pytest.mark.parametrize(
    ("duration", "why"),
    [("-1.0", "must be a finite number in (0, 3600] (s)"),
     ("1e-9", "must be >= control_period (5e-05)")],
)  # fmt: skip
def test_a_bad_duration_is_named_as_the_spec_writes_it(tmp_path, duration, why):
    """It read "timing.duration = -1.0", a key the spec never has (a code reader)."""
    spec = tmp_path / "bad.toml"
    spec.write_text(f'scenario = "paper"\nduration = {duration}\n')
    res = runner.invoke(app, ["campaign", "show", str(spec)])
    assert res.exit_code == 2, res.output
    want = f"error: duration = {float(duration)!r} (timing.duration): {why}"
    assert res.stderr.strip() == want, res.stderr


def test_spec_expands_to_paired_cells_and_deterministic_tasks(spec_file):
    spec = CampaignSpec.from_toml(spec_file)
    assert spec.n_runs == 16 and len(spec.cells) == 4
    masses = [c["payload.mass"] for c in spec.cells]
    assert masses == [0.0, 0.0, 8.0, 8.0]
    draws = {c["controller_model.theta_scale"] for c in spec.cells}
    assert len(draws) == 2 and all(0.4 <= d < 1.0 for d in draws)
    again = CampaignSpec.from_toml(spec_file)
    assert again.digest == spec.digest and again.tasks() == spec.tasks()
    runs = [(r.cell, r.controller, r.seed) for t in spec.tasks() for r in t.runs]
    assert len(runs) == len(set(runs)) == 16
    other = CampaignSpec.from_toml(SMALL.replace("seed = 5", "seed = 6"))
    assert other.digest != spec.digest


def test_records_match_a_plain_simulate(spec_file, reference):
    out, table = reference
    spec = CampaignSpec.from_toml(spec_file)
    rows = table.to_pylist()
    assert [(r["cell"], r["controller"], r["seed"]) for r in rows] == [
        (c, k, s) for c in range(4) for k in ("fsmc", "afsmc") for s in (3, 8)
    ]
    assert {r["status"] for r in rows} == {"ok"} and {r["spec_hash"] for r in rows} == {spec.digest}
    r = rows[15]  # cell 3, afsmc, seed 8
    sc = spec.base.replace(**spec.cells[3])
    assert r["f.payload.mass"] == 8.0
    assert r["f.controller_model.theta_scale"] == spec.cells[3]["controller_model.theta_scale"]
    ref = pkmctl.simulate(sc, controller="afsmc", seed=8).rmse()
    # the campaign ran it in SIMD lanes: equal to the single run within 1e-12 relative
    assert r["rmse_z_mm"] == pytest.approx(ref["z_mm"], rel=1e-12, abs=0)
    assert r["rmse_beta_deg"] == pytest.approx(ref["beta_deg"], rel=1e-12, abs=0)
    assert r["max_error_q4_m"] > 0
    counts = query(out, "SELECT controller, count(*) AS n FROM runs GROUP BY 1 ORDER BY 1")
    assert counts.to_pylist() == [{"controller": "afsmc", "n": 8}, {"controller": "fsmc", "n": 8}]
    files = sorted((out / "runs").iterdir())
    assert len(files) == len(spec.tasks()) and all(f.suffix == ".parquet" for f in files)
    full = read_records(out)
    assert all(w > 0 for w in full.column("wall_s").to_pylist())


def test_interrupted_then_resumed_equals_uninterrupted(spec_file, reference, tmp_path):
    _, expected = reference
    spec = CampaignSpec.from_toml(spec_file)
    out = tmp_path / "camp"
    first = run_campaign(spec, out, workers=1, stop_after=3)
    assert not first.complete and first.tasks_now == 3
    (out / "runs" / ".task-00005.parquet.abc.tmp").write_bytes(b"half a file")  # a crash
    # resuming with another spec is refused; without --resume, so is the folder
    other = spec_file.parent / "other.toml"
    other.write_text(SMALL.replace("seeds = [3, 8]", "seeds = [3, 9]"))
    res = runner.invoke(app, ["campaign", "run", str(other), "--out", str(out), "--resume"])
    assert res.exit_code == 2 and "a different spec" in res.stderr, res.output
    res = runner.invoke(app, ["campaign", "run", str(spec_file), "--out", str(out)])
    assert res.exit_code == 2 and "--resume" in res.stderr, res.output
    res = runner.invoke(
        app, ["campaign", "run", str(spec_file), "--out", str(out), "--resume", "--workers", "2"]
    )
    assert res.exit_code == 0, res.output
    assert "16 runs" in res.stderr and "runs in" in res.stdout
    # the estimate is of the runs left (it was of all 16, as if none were stored)
    left = spec.n_runs - sum(len(t.runs) for t in spec.tasks()[:3])
    assert f"; {left} runs left, estimated " in res.stderr, res.stderr
    table = read_records(out, timing=False)
    assert table.equals(expected)  # bit for bit, every column but the timing ones
    import json

    from pkmctl._jit import source_stamp

    sessions = json.loads((out / "campaign.json").read_text())["sessions"]
    assert [s["where"] for s in sessions] == ["1 local worker", "2 local workers"]
    assert all(s["kernel_sources"] == source_stamp() for s in sessions)  # how, recorded
    tasks = [pq.read_table(f).column("task")[0].as_py() for f in (out / "runs").glob("t*")]
    assert sorted(tasks) == list(range(len(spec.tasks())))


@contextlib.contextmanager
def _cluster(n_workers: int, *, deadline_s: float = 180.0, dashboard: bool = False,
             worker_args: tuple[str, ...] = (), pythonpath: tuple[str, ...] = (),
             allowed_failures: int = 3):  # fmt: skip
    """A real dask.distributed cluster on 127.0.0.1: a scheduler and ``n_workers`` worker
    processes of one thread, without nannies (so a worker's pid is the process we started
    and can kill), each started with ``worker_args`` too (``--preload``) and
    ``pythonpath`` first on its path. Yields (address, worker processes). A watchdog stops
    every process after ``deadline_s``, so a hung campaign fails the test instead of
    hanging it.

    The scheduler binds ports it chooses itself (port 0) and says its address in a
    scheduler file. A port chosen here and closed before the scheduler bound it could be
    taken meanwhile by another test's cluster (its dashboards take random ports): the
    scheduler then died and the client, talking to an HTTP server, saw "Stream is closed"
    for a minute (once, on an empty cache, when imports were slow)."""
    pytest.importorskip("distributed")
    from distributed import Client

    env = dict(os.environ)
    src = str(Path(pkmctl.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([*pythonpath, src, env.get("PYTHONPATH", "")])
    # a task outlives 3 lost workers
    env["DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES"] = str(allowed_failures)
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env}
    folder = tempfile.TemporaryDirectory(prefix="pkmctl-cluster-")
    scheduler_file = Path(folder.name) / "scheduler.json"
    # loopback only: --no-dashboard alone still serves HTTP on 0.0.0.0:8787 (scheduler)
    # and 0.0.0.0 at a random port (each worker)
    scheduler = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
         "--port", "0", "--dashboard-address", "127.0.0.1:0",
         "--scheduler-file", str(scheduler_file), *([] if dashboard else ["--no-dashboard"])],
        **quiet,
    )  # fmt: skip
    workers = []
    procs = [scheduler]

    def stop():
        for p in reversed(procs):
            if p.poll() is None:
                p.kill()

    watchdog = threading.Timer(deadline_s, stop)
    watchdog.start()
    try:
        deadline = time.monotonic() + 60
        address = None
        while address is None:
            if scheduler.poll() is not None:
                raise RuntimeError(f"the test's dask scheduler exited ({scheduler.returncode})")
            if time.monotonic() > deadline:
                raise TimeoutError("the test's dask scheduler wrote no address in 60 s")
            try:
                address = json.loads(scheduler_file.read_text())["address"]
            except (OSError, ValueError, KeyError):  # not yet written, or half
                time.sleep(0.2)
        for _ in range(n_workers):
            workers.append(
                subprocess.Popen(
                    [
                        sys.executable,
                        "-m",
                        "distributed.cli.dask_worker",
                        address,
                        "--nthreads",
                        "1",
                        "--no-nanny",
                        "--no-dashboard",
                        "--dashboard-address",
                        "127.0.0.1:0",
                        "--host",
                        "127.0.0.1",
                        *worker_args,
                    ],
                    **quiet,
                )  # fmt: skip
            )
            procs.append(workers[-1])
        deadline = time.monotonic() + 60
        while True:
            try:
                with Client(address, timeout="2s") as c:
                    c.wait_for_workers(n_workers, timeout=max(1, deadline - time.monotonic()))
                break
            except (OSError, TimeoutError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        yield address, workers
    finally:
        watchdog.cancel()
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
        folder.cleanup()


@pytest.mark.cluster
def test_dask_cluster_of_worker_processes_gives_the_same_records(spec_file, reference, tmp_path):
    _, expected = reference
    with _cluster(2, dashboard=True) as (address, _):
        out = tmp_path / "camp"
        res = runner.invoke(
            app, ["campaign", "run", str(spec_file), "--out", str(out), "--scheduler", address]
        )
        assert res.exit_code == 0, res.output
        table = read_records(out, timing=False)
        assert table.equals(expected)
        workers = set(read_records(out).column("worker").to_pylist())
        assert len(workers) >= 1 and all(":" in w for w in workers)
        assert "dashboard: http://127.0.0.1:" in res.stderr, res.output


@pytest.mark.cluster
def test_a_scheduler_without_a_dashboard_gets_no_link():
    """``dask scheduler --no-dashboard`` still serves HTTP at the dashboard's port (8787 by
    default) and lists it among its services; the link printed was a 404."""
    from distributed import Client

    from pkmctl.campaign.execute import dashboard_link

    with _cluster(1) as (address, _), Client(address, timeout="10s") as client:
        assert "dashboard" in client.scheduler_info()["services"]  # listed all the same
        assert dashboard_link(client) is None


#: Many short tasks (16 of 2 runs), so that when the first result is back the worker we
#: kill still holds tasks (queued or running) that the scheduler must run elsewhere.
KILL = """
name = "kill"
scenario = "paper"
controllers = ["fsmc", "afsmc"]
seeds = [0, 1]
duration = 0.2
metrics = ["rmse", "rmse_after_1s"]

[factors."payload.mass"]
values = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
"""


@pytest.mark.cluster
def test_killing_a_worker_mid_campaign_loses_and_duplicates_nothing(tmp_path):
    spec = CampaignSpec.from_toml(KILL)
    tasks = spec.tasks()
    assert len(tasks) == 16 and spec.n_runs == 32
    run_campaign(spec, tmp_path / "local", workers=1)
    expected = read_records(tmp_path / "local", timing=False)
    with _cluster(2) as (address, workers):
        pids = {str(w.pid): w for w in workers}
        out = tmp_path / "camp"
        killed, clients = {}, []

        def progress(done, failures, total, rate):
            if done == 0 or killed:
                return
            # the first result is on disk: kill the worker that computed it, mid-campaign
            first = next((out / "runs").glob("task-*.parquet"))
            pid = pq.read_table(first).column("worker")[0].as_py().rsplit(":", 1)[1]
            addr = next(a for a, p in clients[0].run(os.getpid).items() if str(p) == pid)
            busy = clients[0].processing(workers=[addr])[addr]  # its tasks, lost with it
            victim = pids[pid]
            victim.kill()
            victim.wait(10)
            killed.update(pid=pid, done=done, code=victim.returncode, lost=len(busy))

        done = run_campaign(
            spec, out, scheduler=address, progress=progress, on_client=clients.append
        )
    assert killed and killed["code"] == -signal.SIGKILL, killed
    assert killed["lost"] >= 1, killed  # it held a task: the scheduler had to run it again
    assert killed["done"] < spec.n_runs  # killed mid-campaign, not after it
    assert done.complete and done.done_now == spec.n_runs and done.tasks_now == len(tasks)
    table = read_records(out, timing=False)
    keys = list(zip(*(table.column(k).to_pylist() for k in ("cell", "controller", "seed")),
                    strict=True))  # fmt: skip
    assert len(keys) == len(set(keys)) == spec.n_runs  # none lost, none duplicated
    assert table.equals(expected)  # bit for bit, as the local run
    by = read_records(out).column("worker").to_pylist()
    survivor = next(p for p in pids if p != killed["pid"])
    assert any(w.endswith(":" + survivor) for w in by)
    # the killed worker's records are of tasks it finished before it died
    assert sum(w.endswith(":" + killed["pid"]) for w in by) <= killed["done"]


@pytest.mark.cluster
def test_a_cluster_that_loses_every_worker_stops_in_one_line_and_resumes(tmp_path):
    """Every worker lost at once takes the campaign's scattered spec with it: the client
    raised 'FutureCancelledError: ... already forgotten. (an internal error ...)', exit 1,
    with no word of --resume. Now a WorkStopped (one line, exit 2 with the resume command
    in the CLI); a resume on a new cluster completes the campaign, as an uninterrupted
    run would have."""
    from pkmctl.campaign.execute import WorkStopped

    spec = CampaignSpec.from_toml(KILL)
    out = tmp_path / "camp"
    with _cluster(2) as (address, workers):
        killed = []

        def progress(done, failures, total, rate):
            if done and not killed:  # the first result is on disk: lose every worker
                for w in workers:
                    w.kill()
                for w in workers:
                    w.wait(10)
                killed.append(done)

        with pytest.raises(WorkStopped) as info:
            run_campaign(spec, out, scheduler=address, progress=progress)
    assert killed and killed[0] < spec.n_runs
    msg = str(info.value)
    assert msg.startswith("the Dask cluster stopped the campaign's work (") and "\n" not in msg
    assert msg.endswith(
        "every worker holding the campaign's spec did (a run that ends its worker process "
        "takes the spec with each worker it runs on: if --resume stops the same way, local "
        "workers, without --scheduler, name its task); the runs done are kept"
    )
    done = run_campaign(spec, out, workers=1, resume=True)
    assert done.complete and done.done_before >= killed[0]
    run_campaign(spec, tmp_path / "local", workers=1)
    assert read_records(out, timing=False).equals(read_records(tmp_path / "local", timing=False))


def test_report_states_in_words_what_the_numbers_say(reference, tmp_path):
    import shutil

    from pkmctl.campaign import stats

    src, table = reference
    out = tmp_path / "camp"
    shutil.copytree(src, out)
    res = runner.invoke(app, ["campaign", "report", str(out)])
    assert res.exit_code == 0, res.output
    md = (out / "report" / "report.md").read_text()
    spec = CampaignSpec.from_toml(out / "spec.toml")
    paired = stats.paired_differences(spec, table, ["rmse_z_mm"])
    pooled = next(r for r in paired if r["cell"] == -1)
    assert pooled["pairs"] == 8 and pooled["lo"] <= pooled["mean"] <= pooled["hi"]
    # the words follow the interval: 8 pooled pairs name a winner only if 0 is outside
    said = {
        "a": ": fsmc is better.",
        "b": ": afsmc is better.",
        "unclear": "cannot tell them apart",
    }
    assert said[pooled["better"]] in md
    assert (pooled["better"] == "unclear") == (pooled["lo"] <= 0 <= pooled["hi"])
    # 2 pairs per cell are too few to name a winner in any cell
    assert all(r["better"] == "unclear" for r in paired if r["cell"] >= 0)
    assert "cannot tell in 4 of 4 cells (all with fewer than the 5 pairs a verdict takes)" in md
    assert "No run diverged" in md
    figs = sorted(p.name for p in (out / "report" / "figures").iterdir())
    assert len(figs) == 3 * 2 and "rmse_z_mm_vs_payload.mass.png" in figs
    assert all((out / "report" / "figures" / f).read_bytes()[:4] == b"\x89PNG" for f in figs)
    rows = (out / "report" / "summary.csv").read_text().splitlines()
    assert len(rows) == 1 + 4 * 2 * 3
    res = runner.invoke(app, ["campaign", "report", str(tmp_path / "nothing")])
    assert res.exit_code == 2 and "not a campaign folder" in res.stderr


def test_bootstrap_interval_covers_the_mean_and_shrinks():
    import numpy as np

    from pkmctl.campaign.stats import bootstrap_interval

    rng = np.random.default_rng(0)
    small = rng.normal(1.0, 1.0, 20)
    big = rng.normal(1.0, 1.0, 2000)
    lo, hi = bootstrap_interval(small, seed=1)
    assert lo < small.mean() < hi
    lo2, hi2 = bootstrap_interval(big, seed=1)
    assert lo2 < 1.0 < hi2 and (hi2 - lo2) < (hi - lo) / 5
    assert bootstrap_interval(small, seed=1) == (lo, hi)


def test_a_diverged_run_is_a_record_with_its_time(tmp_path):
    spec = CampaignSpec.from_toml(
        'scenario = "paper"\ncontrollers = ["fsmc"]\nseeds = [1]\nduration = 0.02\n'
        '[factors."disturbance.amplitude"]\nvalues = [[2.0, 2.0, 2.0], [1e6, 1e6, 1e6]]\n'
    )
    run_campaign(spec, tmp_path / "c", workers=1)
    rows = read_records(tmp_path / "c").to_pylist()
    assert [r["status"] for r in rows] == ["ok", "diverged"]
    assert rows[0]["diverged_at"] is None and 0 < rows[1]["diverged_at"] < 0.02
    assert rows[1]["rmse_z_mm"] is None and rows[0]["rmse_z_mm"] > 0
    assert rows[1]["f.disturbance.amplitude"] == "[1000000.0, 1000000.0, 1000000.0]"
    res = runner.invoke(app, ["campaign", "report", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    md = (tmp_path / "c" / "report" / "report.md").read_text()
    said = "fsmc: 1 of 1 runs did not end ok (1 diverged) at disturbance.amplitude = [1000000.0,"
    assert said in md and md.count("did not end ok") == 1


def test_a_cell_the_plant_cannot_model_is_refused_before_any_run(tmp_path):
    """Coulomb friction on the MuJoCo plant: refused when the spec is read, naming the field
    and the cell's value, with nothing written (it had run as error records, exit 1). A run
    that errs is a record (tests/test_campaign_plugins.py)."""
    pytest.importorskip("mujoco", reason="MuJoCo is not installed (pkmctl[mujoco])")
    base = pkmctl.Scenario.builtin("paper").replace(**{"plant.kind": "mujoco"})
    (tmp_path / "mj.toml").write_text(base.to_toml())
    (tmp_path / "spec.toml").write_text(
        'scenario = "mj.toml"\ncontrollers = ["pd"]\nseeds = [1]\nduration = 0.01\n'
        '[factors."plant.friction_coulomb"]\nvalues = [0.0, 5.0]\n'
    )
    out = tmp_path / "c"
    res = runner.invoke(app, ["campaign", "run", str(tmp_path / "spec.toml"), "--out", str(out),
                              "--workers", "1"])  # fmt: skip
    assert res.exit_code == 2, res.output
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert "plant.friction_coulomb = 5.0: plant.kind = 'mujoco' cannot model it" in res.stderr
    assert not out.exists()


def test_a_logged_campaign_says_the_time_left(spec_file, tmp_path):
    """Progress lines (a log, not a terminal) give the time left at the rate so far."""
    out = tmp_path / "c"
    res = runner.invoke(app, ["campaign", "run", str(spec_file), "--out", str(out),
                              "--workers", "1"])  # fmt: skip
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.stderr.splitlines() if re.match(r"\d+/16 runs, ", ln)]
    assert lines and lines[-1].startswith("16/16 runs, 0 not ok, "), res.stderr
    assert not lines[-1].endswith(" left")  # done: nothing left to say
    before = [ln for ln in lines if not ln.startswith("16/16")]
    # (while loops compile, the line says so: the next test; the line of the task that
    # ended the compiles has no rate yet to give)
    compiled = [i for i, ln in enumerate(before) if ln.endswith(" compiled")]
    after = before[compiled[-1] + 2 :] if compiled else before
    assert before and all(
        re.fullmatch(r"\d+/16 runs, 0 not ok, [\d.]+ runs/s, about [\d.]+ (s|min) left", ln)
        for ln in after
    ), before


def test_no_time_left_is_guessed_while_the_workers_compile(spec_file, tmp_path, monkeypatch):
    """A rate over the workers' first compiles read "about 3.9 h left" for 6 minutes of
    work (a tester). Until a task of each combination that was not compiled has ended, the
    line says the time left comes once they are; after, no rate from before is used."""
    from pkmctl.campaign import execute, store

    spec = CampaignSpec.from_toml(spec_file)
    combos = {store.loop_key(p) for p in store.cell_parts(spec).values()}
    assert len(combos) == 2  # two controllers on one machine
    seen = []
    monkeypatch.setattr(execute, "uncompiled_combinations", lambda s: set(combos))
    run_campaign(spec, tmp_path / "api", workers=1,
                 progress=lambda compiling, **kw: seen.append((kw["done"], compiling)))  # fmt: skip
    assert seen[0] == (0, 2) and seen[-1] == (16, 0), seen
    assert [c for _, c in seen] == sorted((c for _, c in seen), reverse=True)
    # an old callback without ``compiling`` is called as before
    run_campaign(spec, tmp_path / "old", workers=1, progress=lambda done, failures, total, rate: 0)
    res = runner.invoke(app, ["campaign", "run", str(spec_file), "--out", str(tmp_path / "c"),
                              "--workers", "1"])  # fmt: skip
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.stderr.splitlines() if re.match(r"\d+/16 runs, ", ln)]
    compiling = [ln for ln in lines if ln.endswith("compiled")]
    assert compiling and compiling[0].endswith(", the time left once 1 loop compiled"), lines
    assert not any("about" in ln for ln in lines[: lines.index(compiling[-1])]), lines


def test_cells_that_differ_in_a_value_alone_compile_one_loop(tmp_path, monkeypatch):
    """Cells that differ in ``actuators.force_limit`` alone run one loop, but were counted
    as two to compile, and the progress line said "the time left once 1 loop compiled"
    until a task of the second cell ended: ten minutes of paper-claims (a tester)."""
    from pkmctl.campaign import execute, store

    spec = CampaignSpec.from_toml(
        HEAD.replace("seeds = 1", "seeds = 2")
        + '[factors."actuators.force_limit"]\nvalues = ["none", 2000.0]\n'
    )
    assert len({store.machine_key(cell) for cell in spec.cells}) == 2
    with monkeypatch.context() as m:
        m.setenv("PKMCTL_CACHE_DIR", str(tmp_path / "empty"))
        todo = store.uncompiled_combinations(spec)
    assert len(todo) == 1 and store.uncompiled_loops(spec) in (0, 1)
    monkeypatch.setattr(execute, "uncompiled_combinations", lambda s: set(todo))
    seen = []
    run_campaign(spec, tmp_path / "c", workers=1,
                 progress=lambda compiling, **kw: seen.append((kw["done"], compiling)))  # fmt: skip
    assert seen == [(0, 1), (2, 0), (4, 0)], seen  # the first task ran the loop


def test_a_folder_whose_spec_is_refused_now_says_so_and_where_its_records_are(tmp_path):
    """A folder made before a check was added (a MuJoCo cell with Coulomb friction ran as
    error records) was refused by report and --resume with the bare scenario error."""
    from pkmctl.campaign.store import open_store

    (tmp_path / "spec.toml").write_text(
        'scenario = "paper"\ncontrollers = ["pd"]\nseeds = [1]\nduration = 0.01\n'
    )
    out = tmp_path / "c"
    open_store(out, CampaignSpec.from_toml(tmp_path / "spec.toml"), resume=False)
    stored = (out / "scenario.toml").read_text()  # as such a folder holds it
    stored = stored.replace('[plant]\nkind = "rigid"', '[plant]\nkind = "mujoco"')
    (out / "scenario.toml").write_text(stored.replace("friction_coulomb = 0.0",
                                                      "friction_coulomb = 5.0"))  # fmt: skip
    assert 'kind = "mujoco"' in (out / "scenario.toml").read_text()
    res = runner.invoke(app, ["campaign", "report", str(out)])
    assert res.exit_code == 2, res.output
    line = res.stderr.strip()
    assert line.startswith(f"error: {str(out)!r}: its spec is refused as read now ("), line
    assert "plant.friction_coulomb = 5.0: plant.kind = 'mujoco' cannot model it" in line
    assert line.endswith("its records are the Parquet files in its runs/ folder, which "
                         "DuckDB or pyarrow read as they are"), line  # fmt: skip


def test_a_scheduler_that_cannot_be_reached_leaves_nothing(spec_file, tmp_path):
    out = tmp_path / "c"
    args = ["campaign", "run", str(spec_file), "--out", str(out), "--scheduler", "nonsense"]
    res = runner.invoke(app, args)
    assert res.exit_code == 2, res.output
    said = "error: --scheduler 'nonsense': cannot connect (missing port number in address"
    assert said in res.stderr and res.stderr.rstrip().endswith("nothing written"), res.stderr
    assert not out.exists()  # a campaign folder would need --resume to be used again


def test_a_report_of_no_runs_is_refused(spec_file, tmp_path):
    from pkmctl.campaign.store import open_store

    out = tmp_path / "c"
    open_store(out, CampaignSpec.from_toml(spec_file), resume=False)  # started, nothing run
    res = runner.invoke(app, ["campaign", "report", str(out)])
    assert res.exit_code == 2, res.output
    assert "no run recorded yet (0 of 16)" in res.stderr, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not (out / "report").exists()


def test_the_docs_spec_is_valid():
    import re

    text = (Path(__file__).resolve().parents[1] / "docs" / "campaigns.md").read_text()
    toml = re.findall(r"```toml\n(.*?)```", text, flags=re.S)[0]
    spec = CampaignSpec.from_toml(toml)
    assert len(spec.cells) == 18 and spec.n_runs == 360  # as the docs say
    assert spec.cells[1]["actuators.force_limit"] == 2000.0
    assert spec.cells[0]["actuators.force_limit"] is None


def test_a_spec_naming_a_scenario_file_reports_from_the_stored_copy(tmp_path):
    specs = tmp_path / "specs"
    specs.mkdir()
    base = pkmctl.Scenario.builtin("paper-1khz").replace(**{"payload.mass": 1.0})
    (specs / "base.toml").write_text(base.to_toml())
    (specs / "c.toml").write_text(
        'scenario = "base.toml"\ncontrollers = ["fsmc", "afsmc"]\nseeds = 1\nduration = 0.05\n'
    )
    out = tmp_path / "out"
    res = runner.invoke(app, ["campaign", "run", str(specs / "c.toml"), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "1/2 runs" in res.stderr or "2/2 runs" in res.stderr  # lines in a log
    (specs / "base.toml").unlink()  # the folder carries its own copy
    res = runner.invoke(app, ["campaign", "report", str(out)])
    assert res.exit_code == 0, res.output
    rows = read_records(out).to_pylist()
    assert [r["controller"] for r in rows] == ["fsmc", "afsmc"]
    assert (
        rows[0]["rmse_z_mm"] == pkmctl.simulate(base, "fsmc", duration=0.05, seed=0).rmse()["z_mm"]
    )


OFAT = """
name = "ofat"
scenario = "paper"
design = "one-at-a-time"
controllers = ["smc", "afsmc"]
seeds = 2
duration = 0.05

[factors."payload.mass"]
values = [0.0, 4.0]

[factors."timing.control_period"]
values = [5e-5, 1e-3]
with = { "timing.substeps" = [1, 20] }

[[compare]]
name = "adaptation"
controller = "afsmc"
baseline = "smc"
"""


def test_one_at_a_time_design_varies_each_factor_around_the_base():
    spec = CampaignSpec.from_toml(OFAT)
    assert spec.design == "one-at-a-time"
    assert spec.center == {"payload.mass": 0.0, "timing.control_period": 5e-5}
    assert spec.cells == (
        {"payload.mass": 0.0, "timing.control_period": 5e-5},  # the centre: the base
        {"payload.mass": 4.0, "timing.control_period": 5e-5},
        {"payload.mass": 0.0, "timing.control_period": 1e-3, "timing.substeps": 20},
    )
    assert spec.scenario(2).timing.substeps == 20 and spec.scenario(1).timing.substeps == 1
    assert spec.axis("payload.mass") == [0, 1] and spec.axis("timing.control_period") == [0, 2]
    assert spec.n_runs == 3 * 2 * 2
    assert [(q.name, q.controller, q.baseline) for q in spec.compare] == [
        ("adaptation", "afsmc", "smc")
    ]
    # the questions shape the report, not the records: the hash ignores them
    no_q = OFAT[: OFAT.index("[[compare]]")]
    assert CampaignSpec.from_toml(no_q).digest == spec.digest
    grid = CampaignSpec.from_toml(no_q.replace('design = "one-at-a-time"\n', ""))
    assert len(grid.cells) == 4 and grid.cells[3]["timing.substeps"] == 20
    assert grid.axis("payload.mass") == [0, 1, 2, 3]


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (('design = "one-at-a-time"', 'design = "latin"'), "design = 'latin': must be one of"),
        (("[1, 20]", "[1]"), "must be a list of 2 values"),
        (('controller = "afsmc"', 'controller = "pd"'), "compare[0].controller = 'pd': not one"),
        (("[1, 20]", "[1, 0]"), "timing.substeps"),
    ],
)
def test_bad_designs_links_and_questions_fail_in_one_line(tmp_path, change, expected):
    spec = tmp_path / "bad.toml"
    spec.write_text(OFAT.replace(*change))
    res = runner.invoke(app, ["campaign", "run", str(spec), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], lines


def test_paper_claims_is_a_builtin_campaign_of_the_issue_s_factors(tmp_path):
    spec = CampaignSpec.from_toml("paper-claims")
    assert spec is not None and spec.name == "paper-claims"
    assert CampaignSpec.builtin("paper-claims").digest == spec.digest
    assert set(spec.controllers) == {"smc", "fsmc", "afsmc", "pd", "ctc"}
    assert len(spec.seeds) >= 10 and spec.duration > 1.0  # a metric after the first second
    values = {p: [c[p] for c in spec.cells] for p in spec.factors}
    theta = values["controller_model.theta_scale"]
    assert max(theta) == 1.0 and min(theta) == 0.3
    assert min(values["payload.mass"]) == 0.0 and max(values["payload.mass"]) == 10.0
    amp = [a[0] for a in values["disturbance.amplitude"]]
    assert min(amp) == 2.0 and max(amp) == 50.0
    assert set(values["timing.control_period"]) == {5e-5, 1e-3}
    assert set(values["actuators.force_limit"]) == {None, 2160.0}
    at_1khz = next(c for c in spec.cells if c["timing.control_period"] == 1e-3)
    assert spec.scenario(spec.cells.index(at_1khz)).timing == pkmctl.Scenario.builtin(
        "paper-1khz"
    ).timing.model_copy(update={"duration": spec.duration})
    assert {(q.controller, q.baseline) for q in spec.compare} == {
        ("afsmc", "fsmc"),
        ("fsmc", "smc"),
    }
    res = runner.invoke(app, ["campaign", "show", "paper-claims"])
    assert res.exit_code == 0, res.output
    assert res.stdout.startswith("# The built-in campaign `paper-claims`")
    assert CampaignSpec.from_toml(res.stdout).digest == spec.digest  # a copy to edit
    assert f"{spec.n_runs} runs = {len(spec.cells)} cells (one-at-a-time)" in res.stderr
    res = runner.invoke(app, ["campaign", "show", "paper-claim"])  # a typo: the names offered
    said = "'paper-claim': no such file, nor a built-in campaign (choose from paper-claims)"
    assert res.exit_code == 2 and said in res.stderr, res.stderr
    assert len(res.stderr.splitlines()) == 1, res.stderr
    # `campaign run paper-claims` finds it too (refused here before running anything: the
    # folder holds another campaign), in one line: the campaign's header, what it would
    # run, is said only once it starts (it was printed above the refusal)
    out = tmp_path / "taken"
    out.mkdir()
    (out / "campaign.json").write_text('{"spec_hash": "0"}')
    res = runner.invoke(app, ["campaign", "run", "paper-claims", "--out", str(out)])
    assert res.exit_code == 2 and "holds a campaign already" in res.stderr, res.output
    assert len(res.stderr.splitlines()) == 1, res.stderr


def test_a_verdict_held_back_for_too_few_pairs_says_so():
    from pkmctl.campaign.stats import MIN_PAIRS
    from pkmctl.report.campaign import _words

    row = {"metric": "m", "cell": -1, "a": "x", "b": "y", "mean": -1.0, "lo": -1.2, "hi": -0.8,
           "win_rate_a": 1.0, "better": "unclear"}  # fmt: skip
    short = _words(None, [{**row, "pairs": MIN_PAIRS - 1}], "m")[0]
    assert short.endswith(f"too few pairs to tell (a verdict takes at least {MIN_PAIRS}).")
    enough = _words(None, [{**row, "pairs": MIN_PAIRS, "lo": -1.0, "hi": 0.5}], "m")[0]
    assert enough.endswith("the data cannot tell them apart.")


def test_a_question_is_answered_with_ratios_and_intervals(reference, tmp_path):
    import shutil

    from pkmctl.campaign import stats

    src, table = reference
    out = tmp_path / "camp"
    shutil.copytree(src, out)
    text = (out / "spec.toml").read_text()
    text += '\n[[compare]]\nname = "adaptation"\ncontroller = "afsmc"\nbaseline = "fsmc"\n'
    (out / "spec.toml").write_text(text)  # a question does not change the hash
    res = runner.invoke(app, ["campaign", "report", str(out)])
    assert res.exit_code == 0, res.output
    spec = CampaignSpec.from_toml(out / "spec.toml")
    rows = stats.comparison(spec, table, "afsmc", "fsmc", ["rmse_z_mm"])
    pooled = next(r for r in rows if r["cell"] == -1)
    assert pooled["pairs"] == 8
    assert pooled["ratio"] == pytest.approx(pooled["controller_mean"] / pooled["baseline_mean"])
    assert pooled["ratio_lo"] <= pooled["ratio"] <= pooled["ratio_hi"]
    assert pooled["gain"] == pytest.approx(pooled["baseline_mean"] - pooled["controller_mean"])
    # the same verdict as the paired differences (fsmc - afsmc = the gain)
    paired = stats.paired_differences(spec, table, ["rmse_z_mm"])
    same = next(r for r in paired if r["cell"] == -1)
    assert pooled["gain"] == pytest.approx(same["mean"])
    assert {"a": "baseline", "b": "controller", "unclear": "unclear"}[same["better"]] == (
        pooled["better"]
    )
    answer = (out / "report" / "answer.md").read_text()
    assert "**adaptation** (afsmc against fsmc)" in answer
    from pkmctl.report.campaign import _ratio

    assert f"Over all cells: afsmc {pooled['controller_mean']:.4g}" in answer
    assert f"; ratio {_ratio(pooled)}." in answer
    # 2 pairs per cell: every cell is "cannot tell", and the answer says why
    assert "cannot tell in 4 (all with fewer than the 5 pairs a verdict takes)" in answer
    # and each cell of the table says why, not "cannot tell" beside a tight interval
    table = answer.split("| condition |", 1)[1]
    assert "no verdict (2 pairs < 5)" in table and "cannot tell" not in table
    assert answer.split("\n\n", 1)[1] in (out / "report" / "report.md").read_text()
    assert (out / "report" / "comparison.csv").read_text().startswith("question,controller")


def test_figure_labels_say_the_quantity_and_unit():
    from pkmctl.report.campaign import _metric_label

    assert _metric_label("rmse_after_1s_alpha_deg") == "RMSE after 1 s, α (°)"
    assert _metric_label("max_error_q3_m") == "largest |error|, q3 (m)"
    assert _metric_label("chattering_N_per_s_2") == "chattering index, limb 2 (N/s)"
    assert _metric_label("peak_force_N_4") == "peak force, limb 4 (N)"


def test_a_resume_groups_the_runs_as_the_folder_was_started(tmp_path):
    import json

    from pkmctl.campaign.spec import LEGACY_TASK_MULTIPLE, LEGACY_TASK_SECONDS, TASK_SECONDS
    from pkmctl.campaign.store import open_store, task_grouping, task_seconds

    spec = CampaignSpec.from_toml(
        'scenario = "paper"\ncontrollers = ["fsmc"]\nseeds = 10\nduration = 0.2\n'
        'metrics = ["rmse"]\n'
    )
    old, new = spec.tasks(LEGACY_TASK_SECONDS, LEGACY_TASK_MULTIPLE), spec.tasks()
    assert [len(t.runs) for t in old] == [7, 3] and [len(t.runs) for t in new] == [10]
    fresh = tmp_path / "fresh"
    run_campaign(spec, fresh, workers=1)
    assert task_seconds(fresh) == TASK_SECONDS
    legacy = tmp_path / "legacy"  # a folder made before the task size was recorded
    open_store(legacy, spec, resume=False)
    manifest = json.loads((legacy / "campaign.json").read_text())
    del manifest["task_seconds"], manifest["task_multiple"]
    (legacy / "campaign.json").write_text(json.dumps(manifest))
    assert task_grouping(legacy) == (LEGACY_TASK_SECONDS, LEGACY_TASK_MULTIPLE)
    run_campaign(spec, legacy, workers=1, resume=True)
    assert len(list((legacy / "runs").iterdir())) == 2  # its own two tasks, not one
    a = read_records(legacy, timing=False).drop_columns(["task"])
    b = read_records(fresh, timing=False).drop_columns(["task"])
    assert a.equals(b)


def test_tasks_hold_whole_batches_of_lanes():
    """Seeds per task round up to TASK_MULTIPLE (whole SIMD batches), as far as a cell has
    seeds; a folder records the multiple, and one without it groups as before (by 1)."""
    from pkmctl.campaign.spec import TASK_MULTIPLE
    from pkmctl.campaign.store import _manifest

    spec = CampaignSpec.from_toml(
        'scenario = "paper"\ncontrollers = ["afsmc"]\nseeds = 20\nduration = 4.2\n'
        'metrics = ["rmse"]\n'
    )
    assert TASK_MULTIPLE == 8
    assert [len(t.runs) for t in spec.tasks()] == [8, 8, 4]
    assert [len(t.runs) for t in spec.tasks(multiple=1)] == [3] * 6 + [2]
    assert _manifest(spec)["task_multiple"] == TASK_MULTIPLE
    assert _manifest(spec)["tasks"] == 3


def test_a_cells_tasks_share_one_prepared_scenario_per_process():
    from pkmctl.campaign.execute import _prepared

    text = 'scenario = "paper"\ncontrollers = ["smc", "pd"]\nseeds = 3\nduration = 0.05\n'
    text += 'metrics = ["rmse"]\n\n[factors."payload.mass"]\nvalues = [0.0, 4.0]\n'
    spec = CampaignSpec.from_toml(text)
    other = CampaignSpec.from_toml(text.replace("0.05", "0.06"))
    assert _prepared(spec, 1) is _prepared(spec, 1)
    assert _prepared(spec, 0) is not _prepared(spec, 1)
    assert _prepared(other, 1) is not _prepared(spec, 1)  # another digest
    assert _prepared(other, 1).periods != _prepared(spec, 1).periods


# --------------------------------------------------------------------------------------
# Found by testing (factors set twice, duplicated levels, the .fis, stale or foreign files,
# digits, strings, the scheduler's handshake, Ctrl-C). Most use a campaign folder of
# made-up records (_fake_campaign): no run, so they take well under a second each.


def _fake_campaign(out: Path, text: str, metric=None, status=None) -> CampaignSpec:
    """A campaign folder of ``text`` whose records are made up, not run: ``metric(run,
    column)`` gives each metric (default: by cell and controller), ``status(run)`` each
    status (default "ok")."""
    import pyarrow as pa

    from pkmctl.campaign.store import (
        factor_column,
        factor_value,
        metric_columns,
        open_store,
        schema,
        write_task,
    )

    spec = CampaignSpec.from_toml(text)
    runs = open_store(out, spec, resume=False)
    for t in spec.tasks():
        rows = []
        for r in t.runs:
            st = status(r) if status else "ok"
            row = {"spec_hash": spec.digest, "cell": r.cell, "controller": r.controller,
                   "seed": r.seed, "task": t.index}  # fmt: skip
            row.update({factor_column(p): factor_value(spec, p, spec.cells[r.cell][p])
                        for p in spec.factors})  # fmt: skip
            row.update(status=st, diverged_at=0.01 if st == "diverged" else None, message="")
            for m in metric_columns(spec.metrics):
                if st != "ok":
                    row[m] = None
                elif metric is not None:
                    row[m] = metric(r, m)
                else:
                    row[m] = 1.0 + r.cell + spec.controllers.index(r.controller) + 1e-3 * r.seed
            row.update(wall_s=0.0, kernel_s=0.0, worker="test:0")
            rows.append(row)
        write_task(runs, t.index, pa.Table.from_pylist(rows, schema=schema(spec)))
    return spec


def test_a_report_compares_the_kept_actuator_metrics_too(tmp_path):
    """smc tracks better but chatters 100 times as much on limb 2: the report said
    "smc is better" on the RMSEs alone (a tester)."""
    from pkmctl.campaign.store import read_records
    from pkmctl.report.campaign import write_report

    text = (HEAD.replace('["smc"]', '["smc", "pd"]').replace("seeds = 1", "seeds = 6")
            + 'metrics = ["rmse", "chattering_N_per_s"]\n')  # fmt: skip

    def metric(run, column):
        smc = run.controller == "smc"
        if column == "chattering_N_per_s_2":
            return (100.0 if smc else 1.0) * (1 + 0.01 * run.seed)
        return (0.5 if smc else 1.0) * (1 + 0.01 * run.seed)

    out = tmp_path / "c"
    _fake_campaign(out, text, metric=metric)
    write_report(out)
    report = (out / "report" / "report.md").read_text()
    at = report.index("### The actuators")
    assert "**smc vs pd**" in report[:at] and "smc is better." in report[:at]
    limb2 = report[report.index("#### chattering_N_per_s_2") :]
    assert limb2.split("####")[1].count("pd is better.") == 1, limb2
    import csv

    with (out / "report" / "paired.csv").open() as f:
        rows = {(r["cell"], r["metric"]): r for r in csv.DictReader(f)}
    assert rows[("-1", "chattering_N_per_s_2")]["better"] == "b"  # pd
    assert rows[("-1", "chattering_N_per_s_1")]["better"] == "a"  # smc
    with (out / "report" / "summary.csv").open() as f:
        assert {"chattering_N_per_s_2", "rmse_z_mm"} <= {r["metric"] for r in csv.DictReader(f)}
    assert "peak_force_N" not in report  # not kept: not compared
    assert "Each limb's chattering index (N/s), kept" in report
    assert read_records(out).num_rows == 12
    # with only actuator metrics kept they are the headline, said once (every row and
    # verdict came twice; a reviewer)
    only = tmp_path / "only"
    _fake_campaign(only, text.replace('"rmse", "chattering_N_per_s"', '"chattering_N_per_s"'),
                   metric=metric)  # fmt: skip
    write_report(only)
    lines = (only / "report" / "summary.csv").read_text().splitlines()
    assert len(lines) == len(set(lines)) == 1 + 4 * 2  # 4 limbs x 2 controllers, 1 cell
    assert "### The actuators" not in (only / "report" / "report.md").read_text()


def _refused(tmp_path, text: str, command: str = "run") -> str:
    """The one line `campaign run` (or `show`) refuses ``text`` with (exit 2, no folder)."""
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    out = tmp_path / "o"
    args = ["--out", str(out)] if command == "run" else []
    res = runner.invoke(app, ["campaign", command, str(spec), *args])
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert not out.exists()
    return lines[0]


HEAD = 'scenario = "paper"\ncontrollers = ["smc"]\nseeds = 1\nduration = 0.05\n'


@pytest.mark.parametrize(
    ("factors", "expected"),
    [
        (  # substeps 2 and 3 would never run: the other factor's with set it
            '[factors."timing.substeps"]\nvalues = [2, 3]\n'
            '[factors."timing.control_period"]\nvalues = [5e-5, 1e-3]\n'
            'with = { "timing.substeps" = [1, 20] }\n',
            "factors.'timing.control_period'.with.'timing.substeps': timing.substeps is set "
            "twice, as a factor and in this with",
        ),
        (
            '[factors."payload.mass"]\nvalues = [0.0, 1.0]\nwith = { "timing.substeps" = [1, 2] }\n'
            '[factors."timing.control_period"]\nvalues = [5e-5, 1e-3]\n'
            'with = { "timing.substeps" = [1, 20] }\n',
            "timing.substeps is set twice, also in factors.'payload.mass'.with",
        ),
        (  # each run's seed overwrote it: every cell the same
            '[factors."disturbance.seed"]\nvalues = [0, 1, 2]\n',
            "factors.'disturbance.seed': a campaign cannot vary it (each run's seed sets it",
        ),
        (
            '[factors."payload.mass"]\nvalues = [0.0, 1.0]\n'
            'with = { "disturbance.seed" = [1, 2] }\n',
            "factors.'payload.mass'.with.'disturbance.seed': a campaign cannot set it",
        ),
    ],
)
def test_a_field_set_twice_or_by_each_run_is_refused(tmp_path, factors, expected):
    assert expected in _refused(tmp_path, HEAD + factors)


@pytest.mark.parametrize(
    ("design", "factors", "expected"),
    [
        ("grid", "values = [5.0, 5.0, 5.0]", "values = [5.0, 5.0, 5.0]: a value named twice"),
        ("grid", "values = [5, 5.0]", "values = [5, 5.0]: a value named twice (5.0)"),
        ("one-at-a-time", "values = [0.0, 5.0, 5.0]", "a value named twice (5.0)"),
    ],
)
def test_a_level_named_twice_is_refused(tmp_path, design, factors, expected):
    """Identical cells would count as independent pairs in the pooled statistics."""
    text = HEAD + f'design = "{design}"\n[factors."payload.mass"]\n{factors}\n'
    assert expected in _refused(tmp_path, text)


def test_a_metric_named_twice_is_refused(tmp_path):
    line = _refused(tmp_path, HEAD + 'metrics = ["rmse", "rmse"]\n')
    assert "metrics = ['rmse', 'rmse']: a metric named twice" in line


def test_more_runs_than_a_campaign_holds_are_refused_at_once(tmp_path):
    limit = 1_000_000  # pkmctl.campaign.spec.MAX_RUNS
    t0 = time.perf_counter()
    line = _refused(tmp_path, HEAD.replace("seeds = 1", "seeds = 600000").replace(
        '["smc"]', '["smc", "pd"]'), "show")  # fmt: skip
    assert "seeds = 600000: 1200000 runs (cells x controllers x seeds), more than the " \
           f"{limit} a campaign holds" in line  # fmt: skip
    big = HEAD + '[factors."payload.mass"]\nvalues = [0.0, 1.0]\n'
    line = _refused(tmp_path, big.replace("seeds = 1", f"seeds = {limit}"), "show")
    assert f"2 cells x 1 controller x {limit} seeds: {2 * limit} runs" in line
    assert time.perf_counter() - t0 < 10


def test_out_of_memory_in_a_campaign_command_gives_no_single_run_advice(monkeypatch):
    def boom(*a, **k):
        raise MemoryError

    monkeypatch.setattr(CampaignSpec, "from_toml", boom)
    res = runner.invoke(app, ["campaign", "show", "paper-claims"])
    assert res.exit_code == 2, res.output
    assert res.stderr.strip() == "error: out of memory reading the spec", res.stderr


def _paper_fis(tmp_path: Path, sdot: str = "10") -> Path:
    from importlib import resources

    text = (resources.files("pkmctl") / "fuzzy" / "data" / "paper_flc.fis").read_text()
    if sdot != "10":
        text = text.replace("Range=[-10 10]", f"Range=[-{sdot} {sdot}]", 1)
    path = tmp_path / "flc.fis"
    path.write_text(text)
    return path


def test_a_fis_file_counts_by_its_content_and_the_folder_keeps_a_copy(tmp_path):
    from pkmctl.campaign.spec import SpecError

    src = tmp_path / "src"
    src.mkdir()
    fis = _paper_fis(src)
    import tomllib

    import tomli_w

    scen = tomllib.loads(pkmctl.Scenario.builtin("paper").to_toml())
    scen["fuzzy"]["fis"] = "flc.fis"  # relative to the scenario file
    (src / "scen.toml").write_text(tomli_w.dumps(scen))
    (src / "spec.toml").write_text(
        'scenario = "scen.toml"\ncontrollers = ["fsmc"]\nseeds = 1\nduration = 0.02\n'
        'metrics = ["rmse"]\n'
    )
    spec = CampaignSpec.from_toml(src / "spec.toml")
    original = fis.read_bytes()
    _paper_fis(src, sdot="8")  # another fuzzy system, in the same file: another campaign
    edited = CampaignSpec.from_toml(src / "spec.toml")
    assert edited.digest != spec.digest
    fis.write_bytes(original)
    out = tmp_path / "camp"
    run_campaign(spec, out, workers=1)
    assert (out / "fuzzy.fis").read_bytes() == original
    assert 'fis = "fuzzy.fis"' in (out / "scenario.toml").read_text()  # relative: movable
    _paper_fis(src, sdot="8")  # edited again: a resume is refused
    with pytest.raises(SpecError, match="a different spec"):
        run_campaign(edited, out, workers=1, resume=True)
    # the folder is complete without the .fis it was made from, wherever it is
    fis.unlink()
    moved = tmp_path / "moved"
    out.rename(moved)
    res = runner.invoke(app, ["campaign", "report", str(moved)])
    assert res.exit_code == 0, res.output
    assert read_records(moved).column("status").to_pylist() == ["ok"]


def test_one_at_a_time_centre_takes_the_with_of_its_value():
    spec = CampaignSpec.from_toml(
        HEAD.replace('["smc"]', '["smc", "pd"]') + 'design = "one-at-a-time"\n'
        '[factors."timing.control_period"]\nvalues = [5e-5, 1e-3]\n'
        'with = { "timing.substeps" = [4, 20] }\n'
        '[factors."payload.mass"]\nvalues = [0.0, 2.0]\n'
    )
    assert [c.get("timing.substeps") for c in spec.cells] == [4, 20, 4]
    assert [spec.scenario(i).timing.substeps for i in range(3)] == [4, 20, 4]
    assert spec.axis("payload.mass") == [0, 2]
    # a with value equal to the base's changes no cell (nor the built-in's hash)
    same = CampaignSpec.from_toml(OFAT)
    assert same.cells[0] == {"payload.mass": 0.0, "timing.control_period": 5e-5}


def test_figures_draw_a_numeric_factor_in_the_order_of_its_values(tmp_path, monkeypatch):
    from matplotlib.axes import Axes

    from pkmctl.report.campaign import write_report

    drawn = []
    real = Axes.errorbar

    def spy(self, x, y, *a, **k):
        drawn.append(list(x))
        return real(self, x, y, *a, **k)

    monkeypatch.setattr(Axes, "errorbar", spy)
    text = HEAD.replace('["smc"]', '["smc", "pd"]') + 'design = "one-at-a-time"\n'
    text += 'metrics = ["rmse"]\n[factors."controller_model.theta_scale"]\n'
    _fake_campaign(tmp_path / "c", text + "values = [1.0, 0.85, 0.5]\n")
    write_report(tmp_path / "c")
    assert drawn and all(xs == [0.5, 0.85, 1.0] for xs in drawn), drawn  # not 0.85, 1, 0.5


def test_a_host_that_answers_but_is_not_dask_fails_in_seconds(spec_file, tmp_path, monkeypatch):
    import http.server

    from pkmctl.campaign import execute

    class Quiet(http.server.BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    monkeypatch.setattr(execute, "CONNECT_SECONDS", 2.0, raising=False)
    out = tmp_path / "c"
    address = f"tcp://127.0.0.1:{server.server_address[1]}"
    box = {}
    args = ["campaign", "run", str(spec_file), "--out", str(out), "--scheduler", address]
    worker = threading.Thread(target=lambda: box.update(res=runner.invoke(app, args)), daemon=True)
    try:
        worker.start()
        worker.join(30)
        assert not worker.is_alive(), "hangs on a server that is not Dask"
    finally:
        server.shutdown()
    res = box["res"]
    assert res.exit_code == 2, res.output
    said = f"error: --scheduler '{address}': cannot connect (no Dask handshake within 2 s"
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error: ")]
    assert len(errors) == 1 and errors[0].startswith(said), res.stderr
    assert not out.exists()


def _pkmctl(*args: str, **kw) -> subprocess.Popen:
    env = dict(os.environ)
    src = str(Path(pkmctl.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([src, env.get("PYTHONPATH", "")])
    # Ctrl-C as a terminal gives it: a test run started in the background inherits SIGINT
    # ignored, and Python then never raises KeyboardInterrupt (as tests/test_failures.py)
    return subprocess.Popen([sys.executable, "-c", "from pkmctl.cli import main; main()", *args],
                            env=env, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                            **kw)  # fmt: skip


def test_an_interrupted_report_leaves_no_staging_folder(tmp_path):
    out = tmp_path / "c"
    text = HEAD.replace('["smc"]', '["smc", "pd"]') + 'metrics = ["rmse", "max_error"]\n'
    text += '[factors."payload.mass"]\nvalues = [0.0, 1.0, 2.0]\n'
    _fake_campaign(out, text + '[factors."controller_model.theta_scale"]\nvalues = [0.5, 1.0]\n')
    (out / "report").mkdir()
    proc = _pkmctl("campaign", "report", str(out))
    deadline = time.monotonic() + 60
    while not list((out / "report").glob(".pkmctl-*")) and proc.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.005)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("the report was done before the interrupt")
    assert proc.returncode == 130, err
    assert "nothing written" in err
    assert list((out / "report").iterdir()) == []  # no .pkmctl-*.tmp left


def test_the_resume_hint_after_ctrl_c_is_a_command_to_paste(tmp_path):
    import shlex

    spec = tmp_path / "s p.toml"
    spec.write_text(HEAD.replace("seeds = 1", "seeds = 64").replace("0.05", "0.5"))
    out = tmp_path / "out dir"
    proc = _pkmctl("campaign", "run", str(spec), "--out", str(out), "--workers", "1")
    deadline = time.monotonic() + 120
    while not (out / "campaign.json").exists() and proc.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    hint = shlex.join(["pkmctl", "campaign", "run", str(spec), "--out", str(out), "--workers",
                       "1", "--resume"])  # fmt: skip
    assert f"{hint} completes it" in err, err


def test_ctrl_c_after_the_last_run_is_stored_says_the_campaign_is_complete(tmp_path):
    """It said "60 of 60 runs kept ...; ... --resume completes it" (a tester)."""
    spec = tmp_path / "s.toml"
    spec.write_text(HEAD.replace("seeds = 1", "seeds = 2"))
    out = tmp_path / "c"
    code = (
        "import os, signal, sys, time\n"
        "import pkmctl.campaign.execute as ex\n"
        "real = ex.run_campaign\n"
        "def run_then_ctrl_c(*args, **kwargs):\n"
        "    done = real(*args, **kwargs)\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(30)\n"
        "    return done\n"
        "ex.run_campaign = run_then_ctrl_c\n"
        "from pkmctl.cli import main\n"
        "main()\n"
    )
    env = dict(os.environ, PYTHONPATH=str(Path(pkmctl.__file__).resolve().parents[1]))
    proc = subprocess.run(
        [sys.executable, "-c", code, "campaign", "run", str(spec), "--out", str(out),
         "--workers", "1"],
        env=env, capture_output=True, text=True, timeout=300,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    assert proc.returncode == 130, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.endswith(f": all 2 runs are kept in {out}: the campaign is complete "
                         f"(pkmctl campaign report {out} reports it)"), last  # fmt: skip
    assert len(read_records(out, timing=False)) == 2
    # some of them error records: not complete, a resume reruns them (a reviewer)
    plugin = tmp_path / "raising_law.py"
    plugin.write_text(
        "from typing import NamedTuple\nimport pkmctl\n\n"
        "class P(NamedTuple):\n    k: float\n\n"
        "    @classmethod\n    def from_context(cls, ctx):\n"
        "        raise ValueError('no gains for this machine')\n\n"
        "@pkmctl.register_controller('raising-law', params=P)\n"
        "def law(p, state, work, y, ref, F):\n    F[:] = 0.0\n"
    )
    spec.write_text(HEAD.replace('["smc"]', '["smc", "raising-law"]'))
    proc = subprocess.run(
        [sys.executable, "-c", code, "--plugin", str(plugin), "campaign", "run", str(spec),
         "--out", str(tmp_path / "e"), "--workers", "1"],
        env=env, capture_output=True, text=True, timeout=300,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    assert proc.returncode == 130, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert ": all 2 runs are kept in " in last and ", 1 run failed with an error: " in last
    assert last.endswith(" --resume runs their tasks again"), last


def test_a_report_removes_the_files_it_no_longer_writes(tmp_path):
    from pkmctl.report.campaign import write_report

    out = tmp_path / "c"
    text = HEAD.replace('["smc"]', '["smc", "afsmc"]')
    question = '\n[[compare]]\nname = "adaptation"\ncontroller = "afsmc"\nbaseline = "smc"\n'
    _fake_campaign(out, text + question)
    write_report(out)
    assert (out / "report" / "answer.md").exists() and (out / "report" / "comparison.csv").exists()
    (out / "report" / "mine.txt").write_text("a file of the user's")
    (out / "spec.toml").write_text(text)  # the question removed: same hash
    write_report(out)
    left = sorted(p.name for p in (out / "report").iterdir())
    assert left == ["divergence.csv", "figures", "mine.txt", "paired.csv", "report.md",
                    "summary.csv"]  # fmt: skip


def test_a_task_file_of_another_campaign_is_refused(tmp_path):
    import shutil

    from pkmctl.campaign.spec import SpecError

    text = HEAD.replace('["smc"]', '["smc", "pd"]')
    spec = _fake_campaign(tmp_path / "a", text)
    other = _fake_campaign(tmp_path / "b", text.replace("0.05", "0.06"))
    shutil.copy(tmp_path / "b" / "runs" / "task-00001.parquet",
                tmp_path / "a" / "runs" / "task-00001.parquet")  # fmt: skip
    said = f"task-00001.parquet: records of campaign {other.digest!r}, not of this folder's"
    with pytest.raises(SpecError, match=said):
        read_records(tmp_path / "a")
    with pytest.raises(SpecError, match=said):  # not counted as done
        run_campaign(spec, tmp_path / "a", workers=1, resume=True)
    res = runner.invoke(app, ["campaign", "report", str(tmp_path / "a")])
    assert res.exit_code == 2 and said in res.stderr, res.output
    # a new campaign in a folder whose runs/ holds files but no campaign.json
    (tmp_path / "b" / "campaign.json").unlink()
    with pytest.raises(SpecError, match="runs/ holds 2 task files"):
        run_campaign(spec, tmp_path / "b", workers=1)


def test_levels_and_csv_numbers_keep_every_digit(tmp_path):
    import csv

    from pkmctl.report.campaign import write_report

    out = tmp_path / "c"
    _fake_campaign(out, HEAD.replace('["smc"]', '["smc", "pd"]') + 'metrics = ["rmse"]\n'
                   '[factors."payload.mass"]\nvalues = [1.00001, 1.00004, 10.0]\n',
                   metric=lambda r, m: 8.923456789e-05 * (1 + r.cell))  # fmt: skip
    write_report(out)
    md = (out / "report" / "report.md").read_text()
    assert "payload.mass = 1.00001 |" in md and "payload.mass = 1.00004 |" in md
    assert "payload.mass = 10 |" in md  # as few digits as tell it
    rows = list(csv.DictReader((out / "report" / "summary.csv").open()))
    assert {r["f.payload.mass"] for r in rows} == {"1.00001", "1.00004", "10.0"}
    means = {float(r["mean"]) for r in rows if r["metric"] == "rmse_z_mm"}
    assert means == {8.923456789e-05 * k for k in (1, 2, 3)}  # read back exactly


def test_string_factor_values_are_stored_as_the_text(tmp_path):
    from pkmctl.report.campaign import write_report

    out = tmp_path / "c"
    _fake_campaign(out, HEAD + 'metrics = ["rmse"]\n[factors."sensor.kind"]\n'
                   'values = ["ideal", "encoder"]\n')  # fmt: skip
    n = query(out, """SELECT count(*) AS n FROM runs WHERE "f.sensor.kind" = 'ideal'""")
    assert n.to_pylist() == [{"n": 1}]
    assert read_records(out).column("f.sensor.kind").to_pylist() == ["ideal", "encoder"]
    write_report(out)
    assert "sensor.kind = encoder" in (out / "report" / "report.md").read_text()


def test_report_of_one_controller_failed_points_and_durations_by_cell(tmp_path):
    from pkmctl.report.campaign import write_report

    out = tmp_path / "c"
    _fake_campaign(out, HEAD.replace("seeds = 1", "seeds = 2") + 'metrics = ["rmse"]\n'
                   '[factors."timing.duration"]\nvalues = [0.05, 0.1]\n',
                   status=lambda r: "diverged" if (r.cell, r.seed) == (1, 0) else "ok")  # fmt: skip
    write_report(out)
    md = (out / "report" / "report.md").read_text()
    assert "4 runs recorded: 2 cells x 1 controllers (smc) x 2 seeds, 0.05-0.1 s each" in md
    assert "One controller (smc): no pair to compare" in md
    assert "### rmse_z_mm\n\n## " not in md  # no empty section
    assert 'a point marked "k failed" leaves out k runs that diverged or failed' in md


def test_the_docs_name_every_built_in_scenario():
    from pkmctl.sim.scenario import BUILTINS

    text = (Path(__file__).resolve().parents[1] / "docs" / "campaigns.md").read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith('scenario = "paper"'))
    assert all(name in line or name in text.split(line)[1][:200] for name in BUILTINS), line


def test_a_stray_copy_of_a_task_file_is_not_counted_and_a_run_twice_is_refused(tmp_path):
    import shutil

    from pkmctl.campaign.spec import SpecError
    from pkmctl.campaign.store import completed_tasks

    text = HEAD.replace('["smc"]', '["smc", "pd"]').replace("seeds = 1", "seeds = 3")
    spec = _fake_campaign(tmp_path / "a", text)
    runs = tmp_path / "a" / "runs"
    # what a file manager makes of a copy: not a file of the campaign's
    shutil.copy(runs / "task-00001.parquet", runs / "task-00001 (copy).parquet")
    shutil.copy(runs / "task-00001.parquet", runs / "task-1.parquet")
    assert read_records(tmp_path / "a").num_rows == spec.n_runs == 6
    assert query(tmp_path / "a", "SELECT count(*) AS n FROM runs").column("n").to_pylist() == [6]
    assert completed_tasks(runs) == {0, 1}
    # a campaign's own file name, another task's records: each of its runs twice
    shutil.copy(runs / "task-00001.parquet", runs / "task-00000.parquet")
    said = (
        f"{runs / 'task-00001.parquet'}: run (cell 0, pd, seed 0) is also in "
        f"{runs / 'task-00000.parquet'}: a run recorded twice"
    )
    with pytest.raises(SpecError) as err:
        read_records(tmp_path / "a")
    assert str(err.value).startswith(said)
    res = runner.invoke(app, ["campaign", "report", str(tmp_path / "a")])
    assert res.exit_code == 2 and res.stderr.strip() == f"error: {err.value}", res.output


def test_seeds_above_2_to_the_53_stay_apart_in_the_statistics(tmp_path):
    from pkmctl.campaign import stats

    seeds = [2**62 + k for k in range(6)]  # one float for all six
    text = HEAD.replace('["smc"]', '["smc", "pd"]').replace("seeds = 1", f"seeds = {seeds}")

    def metric(run, column):
        return (2.0 if run.controller == "pd" else 1.0) + (run.seed - 2**62) ** 2

    spec = _fake_campaign(tmp_path / "a", text, metric=metric)
    table = read_records(tmp_path / "a")
    row = next(r for r in stats.paired_differences(spec, table, ["rmse_z_mm"]) if r["cell"] == -1)
    assert row["pairs"] == 6 and row["mean"] == -1.0 and row["better"] == "a"
    comp = stats.comparison(spec, table, "pd", "smc", ["rmse_z_mm"])
    assert [r["pairs"] for r in comp] == [6, 6]


def test_fis_files_of_a_factor_count_by_content_and_are_copied(tmp_path):
    import shutil

    from pkmctl.campaign.spec import SpecError

    src = tmp_path / "src"
    src.mkdir()
    a = _paper_fis(src).rename(src / "a.fis")
    b = _paper_fis(src, sdot="8").rename(src / "b.fis")
    spec_toml = src / "spec.toml"
    spec_toml.write_text(  # relative to the spec's folder, not to the working directory
        HEAD.replace('["smc"]', '["fsmc"]')
        + 'metrics = ["rmse"]\n[factors."fuzzy.fis"]\nvalues = ["a.fis", "b.fis", "none"]\n'
    )
    spec = CampaignSpec.from_toml(spec_toml)
    assert [c["fuzzy.fis"] for c in spec.cells] == ["a.fis", "b.fis", None]
    out = tmp_path / "camp"
    _fake_campaign(out, spec_toml)
    original = b.read_bytes()
    b.write_text(b.read_text().replace("Range=[-8 8]", "Range=[-9 9]", 1))
    edited = CampaignSpec.from_toml(spec_toml)
    assert edited.digest != spec.digest  # another fuzzy system in cell 1: another campaign
    with pytest.raises(SpecError, match="a different spec"):
        run_campaign(edited, out, workers=1, resume=True)
    # the folder holds what its records were made with: it reads without the originals
    copies = sorted(p.read_bytes() for p in (out / "fis").iterdir())
    assert copies == sorted([a.read_bytes(), original])
    shutil.rmtree(src)
    moved = tmp_path / "moved"
    out.rename(moved)
    assert read_records(moved).num_rows == 3
    res = runner.invoke(app, ["campaign", "report", str(moved)])
    assert res.exit_code == 0, res.output


def test_two_fis_files_of_the_same_content_are_a_value_named_twice(tmp_path):
    a = _paper_fis(tmp_path).rename(tmp_path / "a.fis")
    (tmp_path / "b.fis").write_bytes(a.read_bytes())
    spec = tmp_path / "bad.toml"
    text = HEAD + '[factors."fuzzy.fis"]\nvalues = ["a.fis", "b.fis"]\n'
    spec.write_text(text)
    res = runner.invoke(app, ["campaign", "show", str(spec)])
    assert res.exit_code == 2, res.output
    assert res.stderr.strip() == (
        "error: factors.'fuzzy.fis'.values = ['a.fis', 'b.fis']: a value named twice "
        "('b.fis' holds the same fuzzy system as 'a.fis', byte for byte)"
    )


def test_runs_of_1_s_or_less_have_their_headline_over_the_whole_run(tmp_path):
    from pkmctl.campaign import stats

    line = _refused(tmp_path, HEAD + 'metrics = ["rmse_after_1s"]\n')
    assert line == (
        "error: metrics = ['rmse_after_1s'] with duration = 0.05: rmse_after_1s needs runs "
        "longer than 1 s (a control sample at t >= 1 s); keep rmse too (the whole run) or "
        "make the runs longer"
    )
    line = _refused(tmp_path, HEAD + 'metrics = ["rmse_after_1s"]\n'
                    '[factors."timing.duration"]\nvalues = [1.5, 1.0]\n')  # fmt: skip
    assert "with timing.duration = 1.0 (cell 1): rmse_after_1s needs runs longer than" in line
    # a cell of 0.6 s beside one of 1.5 s: every cell compared over the whole run
    text = HEAD.replace('["smc"]', '["smc", "pd"]').replace("seeds = 1", "seeds = 6") + (
        'metrics = ["rmse", "rmse_after_1s"]\n[factors."timing.duration"]\nvalues = [0.6, 1.5]\n'
    )

    def metric(run, column):  # as the runs record it: no rmse_after_1s in 0.6 s
        if column.startswith("rmse_after_1s") and run.cell == 0:
            return None
        return (1.0 if run.controller == "smc" else 2.0) + run.seed / 10

    spec = _fake_campaign(tmp_path / "a", text, metric=metric)
    table = read_records(tmp_path / "a")
    assert spec.past_1s() == [False, True]
    assert stats.headline_metrics(spec, table) == ["rmse_z_mm", "rmse_alpha_deg", "rmse_beta_deg"]
    res = runner.invoke(app, ["campaign", "report", str(tmp_path / "a")])
    assert res.exit_code == 0, res.output
    md = (tmp_path / "a" / "report" / "report.md").read_text()
    assert "smc better in 2 of 2 cells" in md and "fewer than" not in md


def test_ties_missing_values_and_typos_are_said(tmp_path):
    import math

    from pkmctl.campaign import stats

    text = HEAD.replace('["smc"]', '["smc", "pd"]').replace("seeds = 1", "seeds = 5")

    def metric(run, column):  # equal controllers, and one ok run without a value
        return math.nan if (run.controller, run.seed) == ("pd", 0) else 1.0 + run.seed

    spec = _fake_campaign(tmp_path / "a", text, metric=metric)
    table = read_records(tmp_path / "a")
    row = next(r for r in stats.paired_differences(spec, table, ["rmse_z_mm"]) if r["cell"] < 0)
    assert row["pairs"] == 4 and row["ties"] == 4 and row["win_rate_a"] == 0.0
    assert [r["ties"] for r in stats.comparison(spec, table, "smc", "pd", ["rmse_z_mm"])] == [4, 4]
    pd = [r for r in stats.cell_stats(spec, table, ["rmse_z_mm"]) if r["controller"] == "pd"]
    assert (pd[0]["ok"], pd[0]["missing"], pd[0]["mean"]) == (5, 1, 3.5)
    # and report.md says both: ties are not losses, a missing value is not silent
    res = runner.invoke(app, ["campaign", "report", str(tmp_path / "a")])
    assert res.exit_code == 0, res.output
    md = (tmp_path / "a" / "report" / "report.md").read_text()
    assert "smc lower in 0 % of pairs, equal in 100 %" in md
    assert "- pd, rmse_z_mm: 1 of 5 at" in md
    line = _refused(tmp_path, HEAD + '[factors."payload.mass"]\nvalue = [0.0, 1.0]\n')
    assert line.startswith("error: factors.'payload.mass': unknown key 'value' (give values")
    q = '[[compare]]\nname = "x"\ncontroller = "smc"\nbaseline = "pd"\n'
    two = HEAD.replace('["smc"]', '["smc", "pd"]') + q + q.replace('"x"', '"y"')
    line = _refused(tmp_path, two)
    assert "compare[1] = " in line and "the same controller and baseline as compare[0]" in line


# ------------------------------------------------------------------ fixes of the 2026-12 review


@pytest.mark.parametrize(
    ("factors", "expected"),
    [
        (
            '[factors."logging.every"]\nvalues = [1, 10]\n',
            "factors.'logging.every': it changes no record (the records' metrics are computed "
            "in the loop over every period, whatever is logged): its cells would be identical "
            "runs counted as independent pairs; remove the factor",
        ),
        (
            '[factors."payload.mass"]\nvalues = [0.0, 1.0]\nwith = { "logging.every" = [1, 2] }\n',
            "factors.'payload.mass'.with.'logging.every': it changes no record",
        ),
        ('[factors."name"]\nvalues = ["a", "b"]\n', "factors.'name': it changes no record"),
    ],
)
def test_a_factor_over_a_field_that_changes_no_record_is_refused(tmp_path, factors, expected):
    assert expected in _refused(tmp_path, HEAD + factors)


def test_samples_are_bounded_before_they_are_drawn(tmp_path):
    t0 = time.perf_counter()
    body = 'distribution = "uniform"\nlow = 0.0\nhigh = 1.0\nsamples = 100000000\n'
    line = _refused(tmp_path, HEAD + f'[factors."payload.mass"]\n{body}', "show")
    assert (
        "factors.'payload.mass'.samples = 100000000: 100000000 runs (cells x controllers x "
        "seeds), more than the 1000000 a campaign holds" in line
    )
    body = body.replace("100000000", "100000000000")
    assert "samples = 100000000000: " in _refused(tmp_path, HEAD + f'[factors."m"]\n{body}', "show")
    assert time.perf_counter() - t0 < 3  # drawing 10^8 samples took 6 s and 800 MB


def test_a_folders_own_spec_resumes_with_its_stored_scenario(tmp_path):
    """The folder is complete on its own: its spec.toml names a scenario file that is not
    there, and reads as the campaign it holds (its stored scenario.toml)."""
    specs = tmp_path / "specs"
    specs.mkdir()
    base = pkmctl.Scenario.builtin("paper").replace(**{"payload.mass": 1.0})
    (specs / "mysc.toml").write_text(base.to_toml())
    (specs / "c.toml").write_text(
        'scenario = "mysc.toml"\ncontrollers = ["pd"]\nseeds = 1\nduration = 0.05\n'
        'metrics = ["rmse"]\n[factors."payload.offset"]\nvalues = [[0.0, 0.0, 0.0], '
        "[0.0, 0.0, 0.01]]\n"
    )
    out = tmp_path / "out"
    args = ["--out", str(out), "--workers", "1"]
    res = runner.invoke(app, ["campaign", "run", str(specs / "c.toml"), *args])
    assert res.exit_code == 0, res.output
    first = read_records(out, timing=False)
    (out / "runs" / "task-00001.parquet").unlink()
    res = runner.invoke(app, ["campaign", "run", str(out / "spec.toml"), *args, "--resume"])
    assert res.exit_code == 0, res.output
    assert "(1 done before)" in res.stdout
    assert read_records(out, timing=False).equals(first)
    res = runner.invoke(app, ["campaign", "show", str(out / "spec.toml")])
    assert res.exit_code == 0, res.output
    # edited, it is no longer the campaign's: read as written, not with the stored copy
    own = (out / "spec.toml").read_text()
    (out / "spec.toml").write_text(own.replace('scenario = "mysc.toml"', 'scenario = "prototype"'))
    assert CampaignSpec.from_toml(out / "spec.toml").base.name == "prototype"
    (out / "spec.toml").write_text(own.replace("seeds = 1", "seeds = 2"))
    with pytest.raises(pkmctl.ScenarioError, match="mysc.toml': No such file"):  # not there
        CampaignSpec.from_toml(out / "spec.toml")


def _erring(monkeypatch, cells: set):
    """Make the runs of ``cells`` records of status "error" (a failure of the machine, say)."""
    import pyarrow as pa

    from pkmctl.campaign import execute

    real = execute.run_task

    def run_task(spec, task, lanes=None):
        rows = real(spec, task, lanes).to_pylist()
        for r in rows:
            if r["cell"] in cells:
                r.update(status="error", message="RuntimeError: flaky")
                r.update({k: None for k in r if k.startswith("rmse")})
        return pa.Table.from_pylist(rows, schema=execute.schema(spec))

    monkeypatch.setattr(execute, "run_task", run_task)


def test_error_records_fail_the_command_and_a_resume_runs_their_tasks_again(tmp_path, monkeypatch):
    spec = tmp_path / "s.toml"
    spec.write_text(HEAD + 'metrics = ["rmse"]\n[factors."payload.mass"]\nvalues = [0.0, 1.0]\n')
    out = tmp_path / "c"
    args = ["campaign", "run", str(spec), "--out", str(out), "--workers", "1"]
    with monkeypatch.context() as m:
        _erring(m, {1})
        res = runner.invoke(app, args)
        assert res.exit_code == 1, res.output
        assert "of the 2 runs stored: 0 diverged, 1 failed with an error" in res.stdout
        assert "1 run failed (cell 1 smc seed 0): RuntimeError: flaky" in res.stderr
        hint = f"{' '.join(['pkmctl', *args[:5]])} --workers 1 --resume runs their tasks again"
        assert hint in res.stderr, res.stderr
        # an interrupted resume: the error records of the earlier session still count
        (out / "runs" / "task-00000.parquet").unlink()
        done = run_campaign(CampaignSpec.from_toml(spec), out, workers=1, resume=True,
                            stop_after=1)  # fmt: skip
        assert (done.done_before, done.done_now, done.errors, done.rerun) == (0, 1, 1, 1)
        # the same error again: still a failure (exit 1), and said so
        res = runner.invoke(app, [*args, "--resume"])
        assert res.exit_code == 1, res.output
        assert "1 run in " in res.stdout
        assert "(1 done before), 1 of them again after an error;" in res.stdout
    res = runner.invoke(app, [*args, "--resume"])  # the cause gone: the task runs again
    assert res.exit_code == 0, res.output
    assert "1 of them again after an error; of the 2 runs stored: 0 diverged, 0 failed" in (
        res.stdout
    )
    assert [r["status"] for r in read_records(out).to_pylist()] == ["ok", "ok"]


def test_campaign_messages_count_in_the_singular_and_say_none(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text(HEAD + '[factors."actuators.force_limit"]\nvalues = ["none", 2000.0]\n')
    res = runner.invoke(app, ["campaign", "show", str(spec)])
    assert res.exit_code == 0, res.output
    assert "2 runs = 2 cells (grid) x 1 controller x 1 seed," in res.stderr
    assert 'cell 0: actuators.force_limit = "none"' in res.stderr
    out = tmp_path / "c"
    res = runner.invoke(app, ["campaign", "run", str(spec), "--out", str(out), "--workers", "1"])
    assert res.exit_code == 0, res.output
    assert "in 2 tasks on 1 local worker; estimated" in res.stderr
    assert "start the workers" not in res.stderr
    (tmp_path / "bad.toml").write_text("a = [\n")
    line = _refused(tmp_path, "a = [\n", "show")
    assert line.startswith(f"error: campaign spec {str(tmp_path / 'bad.toml')!r}: "), line


def test_run_says_what_it_will_do_with_its_workers_and_a_resume_of_nothing(tmp_path):
    """--workers was silently ignored beside --scheduler; "on 6 local workers" was said
    where one task starts one; a mistyped --out with --resume started the campaign again
    without a word."""
    spec = tmp_path / "s.toml"
    spec.write_text(HEAD)
    out = tmp_path / "o"
    res = runner.invoke(app, ["campaign", "run", str(spec), "--out", str(out), "--workers", "2",
                              "--scheduler", "tcp://127.0.0.1:1"])  # fmt: skip
    assert res.exit_code == 2 and "--workers = 2: not with --scheduler" in res.output
    assert not out.exists()
    args = ["campaign", "run", str(spec), "--out", str(out), "--workers", "6", "--resume"]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert f"--resume: {str(out)!r} holds no campaign yet: starting it there" in res.output
    assert "in 1 task on 1 local worker;" in res.output


def test_a_damaged_task_file_is_named_with_what_to_do(tmp_path):
    """A truncated task file gave pyarrow's "Parquet magic bytes not found in footer"."""
    out = tmp_path / "c"
    _fake_campaign(out, HEAD.replace('["smc"]', '["smc", "pd"]'))
    task = sorted((out / "runs").glob("task-*.parquet"))[0]
    task.write_bytes(task.read_bytes()[:100])
    resume = ["campaign", "run", str(out / "spec.toml"), "--out", str(out), "--resume"]
    for args in (["campaign", "report", str(out)], resume):
        res = runner.invoke(app, args)
        assert res.exit_code == 2, res.output
        line = res.output.strip().splitlines()[-1]  # (run says what it will run first)
        assert line.startswith(f"error: {task}: not a readable task file (Parquet magic")
        assert line.endswith("; delete it, and --resume runs its task again")


def test_a_resume_refuses_a_task_file_holding_another_tasks_runs(tmp_path):
    """A copy of task 0's file under task 1's name counted task 1 as done: --resume said
    the campaign was complete, its runs were never run, and the report then refused the
    folder (a run recorded twice)."""
    import shutil

    out = tmp_path / "c"
    spec = _fake_campaign(out, HEAD.replace('["smc"]', '["smc", "pd"]'))
    t0, t1 = spec.tasks()[:2]
    assert {(r.controller, r.seed) for r in t0.runs} != {(r.controller, r.seed) for r in t1.runs}
    runs = out / "runs"
    first, second = runs / "task-00000.parquet", runs / "task-00001.parquet"
    second.unlink()
    shutil.copyfile(first, second)
    resume = ["campaign", "run", str(out / "spec.toml"), "--out", str(out), "--resume",
              "--workers", "1"]  # fmt: skip
    res = runner.invoke(app, resume)
    assert res.exit_code == 2, res.output
    r = t0.runs[0]
    assert res.stderr.strip().splitlines()[-1] == (
        f"error: {second}: not this task's records (it holds run (cell {r.cell}, "
        f"{r.controller}, seed {r.seed}), not one of task 1's: another task's file copied "
        "to its name?); delete it, and --resume runs its task again"
    )
    assert sorted(p.name for p in runs.iterdir()) == ["task-00000.parquet", "task-00001.parquet"]
    second.unlink()  # as the line says: the task runs again, the campaign is whole
    res = runner.invoke(app, resume)
    assert res.exit_code == 0, res.output
    assert len(read_records(out)) == spec.n_runs


def test_a_fis_factor_off_zero_at_rest_gets_one_note_if_a_fuzzy_controller_runs(tmp_path):
    corpus = CORPUS / "matlab_tipper.fis"
    if not corpus.is_file():
        pytest.skip("no .fis corpus")
    (tmp_path / "tip.fis").write_bytes(corpus.read_bytes())
    _paper_fis(tmp_path).rename(tmp_path / "flc.fis")
    factor = '[factors."fuzzy.fis"]\nvalues = ["tip.fis", "flc.fis", "none"]\n'
    for controllers, count in (('["fsmc", "smc"]', 1), ('["afsmc-ext"]', 1), ('["smc", "pd"]', 0)):
        spec = tmp_path / "spec.toml"
        spec.write_text(HEAD.replace('["smc"]', controllers) + factor)
        notes = CampaignSpec.from_toml(spec).fuzzy_offset_notes()
        assert len(notes) == count and all("tip.fis" in n for n in notes), notes


def test_the_campaign_report_repeats_the_fis_offset_warning(tmp_path):
    """docs/fuzzy.md says the report repeats the warning `campaign run` prints; the
    campaign's report.md did not (a tester)."""
    corpus = CORPUS / "matlab_tipper.fis"
    if not corpus.is_file():
        pytest.skip("no .fis corpus")
    (tmp_path / "tip.fis").write_bytes(corpus.read_bytes())
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(
        HEAD.replace('["smc"]', '["fsmc"]').replace("0.05", "0.01")
        + 'metrics = ["rmse"]\n[factors."fuzzy.fis"]\nvalues = ["tip.fis", "none"]\n'
    )
    spec = CampaignSpec.from_toml(spec_file)
    (note,) = spec.fuzzy_offset_notes()
    out = tmp_path / "camp"
    run_campaign(spec, out, workers=1)
    res = runner.invoke(app, ["campaign", "report", str(out)])
    assert res.exit_code == 0, res.output
    report = (out / "report" / "report.md").read_text()
    # the note names the file as the campaign folder keeps it
    (kept,) = read_spec(out).fuzzy_offset_notes()
    assert f"**Warning**: {kept}." in report and "FLC(0, 0) = 5.077" in kept, report[:2000]
    assert kept.split(": ", 1)[1] == note.split(": ", 1)[1]


def test_the_time_estimate_counts_each_runs_loop():
    """The estimate took the task size's 5 us a period for every run: paper-claims read
    5.0 min on 2 workers and took 55 s. Now a run in lanes, alone, or on a plant stepped
    from Python (MuJoCo's) costs what ESTIMATE_PERIOD says for its loop."""
    from pkmctl.campaign.store import ESTIMATE_PERIOD, ESTIMATE_RUN, estimate_seconds
    from pkmctl.sim.lanes import lane_count

    kinds = '[factors."plant.kind"]\nvalues = ["rigid", "mujoco"]\n'
    spec = CampaignSpec.from_toml(HEAD.replace('["smc"]', '["pd"]') + kinds)
    periods = round(0.05 / spec.base.timing.control_period)
    lanes = ESTIMATE_PERIOD["lanes"] * 8 / min(8, lane_count())
    # a run in lanes costs next to nothing outside its loop (the spec's 10 ms a run made
    # 1600 runs of 0.2 s "20 s", which took 2.8 s)
    assert ESTIMATE_RUN["lanes"] < 1e-3
    assert estimate_seconds(spec, [(0, "pd")]) == pytest.approx(
        periods * lanes + ESTIMATE_RUN["lanes"]
    )
    stepped = periods * ESTIMATE_PERIOD["stepped"] + ESTIMATE_RUN["stepped"]
    assert estimate_seconds(spec, [(1, "pd")] * 3) == pytest.approx(3 * stepped)
    assert estimate_seconds(spec) == pytest.approx(estimate_seconds(spec, [(0, "pd"), (1, "pd")]))
    # each RK4 sub-step and the machine's parts cost their share: 1000 sub-steps read
    # "estimated 0.0 s" and took 9.8 s (a tester)
    from pkmctl.sim import cost

    subs = '[factors."timing.substeps"]\nvalues = [1, 1000]\n'
    spec = CampaignSpec.from_toml(HEAD.replace('["smc"]', '["pd"]') + subs)
    one, many = (estimate_seconds(spec, [(i, "pd")]) - cost.RUN["lanes"] for i in (0, 1))
    assert many / one == pytest.approx(1 + 999 * cost.SUBSTEP["lanes"] / cost.PERIOD["lanes"])
    proto = CampaignSpec.from_toml(HEAD.replace('["smc"]', '["pd"]').replace("paper", "prototype"))
    built = cost.PERIOD["lanes"] + 9 * cost.SUBSTEP["lanes"] * cost.DRIVE + cost.ENCODER["lanes"]
    assert estimate_seconds(proto, [(0, "pd")]) == pytest.approx(
        50 * built * 8 / min(8, lane_count()) + cost.RUN["lanes"]
    )


def test_a_resume_while_the_campaign_runs_is_refused(tmp_path):
    """A `campaign run --resume` started while the campaign ran reran every task not yet
    written (a tester: 72 runs twice). The running one holds the folder (an flock on
    runs/); the other is refused in one line, and resumes once it is free."""
    from pkmctl.campaign.execute import _folder_lock
    from pkmctl.errors import OutputError

    out = tmp_path / "c"
    spec = _fake_campaign(out, HEAD)
    (tmp_path / "spec.toml").write_text(HEAD)
    with _folder_lock(out, out / "runs"):  # as the running campaign holds it
        with pytest.raises(OutputError, match="another pkmctl campaign run is running into"):
            run_campaign(spec, out, workers=1, resume=True)
        # the command: one line (the campaign's header came first, as if it ran)
        res = runner.invoke(app, ["campaign", "run", str(tmp_path / "spec.toml"), "--out",
                                  str(out), "--workers", "1", "--resume"])  # fmt: skip
        assert res.exit_code == 2, res.output
        assert len(res.stderr.splitlines()) == 1, res.stderr
        assert "another pkmctl campaign run is running into" in res.stderr, res.stderr
    assert run_campaign(spec, out, workers=1, resume=True).done_now == 0


def test_workers_that_cannot_take_the_spec_are_one_line():
    """A Dask worker started before pkmctl changed could not unpickle the spec: the
    command said "Exception: ImportError(...) (an internal error ...)", exit 1."""
    from pkmctl.campaign.execute import WorkStopped, _dask_stream

    class Workers:  # a client whose workers fail to load what it sends
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def scatter(self, data, broadcast=False):
            raise Exception(  # noqa: TRY002 - what distributed raised, as it raised it
                "ImportError(\"cannot import name 'FUZZY_CONTROLLERS' from 'pkmctl.sim.scenario'\")"
            )

    spec = CampaignSpec.from_toml(HEAD)
    with pytest.raises(WorkStopped) as info:
        list(_dask_stream(spec, spec.tasks(), Workers(), None, None))
    msg = str(info.value)
    assert msg.startswith("the Dask workers could not take the campaign's spec (Exception: "
                          "ImportError(\"cannot import name 'FUZZY_CONTROLLERS'"), msg  # fmt: skip
    assert msg.endswith("Restart them; no run was made") and "\n" not in msg


def test_a_factor_over_a_gain_no_controller_reads_is_refused():
    """gains.gamma (AFSMC's adaptation gain) over smc and pd made cells of identical runs,
    which the statistics counted as independent pairs (a tester). Refused in one line; a
    controller that reads it makes the factor valid."""
    from pkmctl.campaign.spec import SpecError

    def spec(controllers: str, factor: str) -> CampaignSpec:
        return CampaignSpec.from_toml(HEAD.replace('["smc"]', controllers) + factor)

    gamma = '[factors."gains.gamma"]\nvalues = [0.5, 0.9]\n'
    with pytest.raises(SpecError) as info:
        spec('["smc", "pd"]', gamma)
    assert str(info.value) == (
        "factors.'gains.gamma': none of the controllers (smc, pd) reads it: its cells would "
        "be identical runs counted as independent pairs; remove the factor, or add a "
        "controller that reads it"
    )
    assert spec('["smc", "afsmc"]', gamma).n_runs == 4
    # each read by the one named and by none of the other two
    for factor, reader, others in (
        ('[factors."gains.eps"]\nvalues = [0.1, 0.2]\n', "smc", '["pd", "ctc"]'),
        ('[factors."gains.pd_kp"]\nvalues = [[1.0, 2.0, 3.0], [2.0, 2.0, 3.0]]\n', "pd",
         '["smc", "ctc"]'),
        ('[factors."gains.ctc_kd"]\nvalues = [[1.0, 2.0, 3.0], [2.0, 2.0, 3.0]]\n', "ctc",
         '["smc", "pd"]'),
    ):  # fmt: skip
        with pytest.raises(SpecError, match="none of the controllers"):
            spec(others, factor)
        assert spec(f'["{reader}"]', factor).n_runs == 2


def test_the_estimate_says_when_the_workers_compile_first(tmp_path, monkeypatch):
    """A campaign estimated at 1.1 s took 250 s on an empty cache, and nothing said the
    workers were compiling (a tester). The loops not run on this machine are counted."""
    from pkmctl.campaign import store

    spec = CampaignSpec.from_toml(HEAD.replace('["smc"]', '["smc", "pd"]'))
    pkmctl.simulate(spec.scenario(0), "smc", duration=0.01)  # this cache: smc's has run
    pkmctl.simulate(spec.scenario(0), "pd", duration=0.01)
    assert store.uncompiled_loops(spec) == 0
    with monkeypatch.context() as m:
        m.setenv("PKMCTL_CACHE_DIR", str(tmp_path / "empty"))
        assert store.uncompiled_loops(spec) == 2
    # several seeds run in lanes: their lane loop is the one asked for, marked as it runs
    # (the single loop's marker said "not run yet" after every campaign of lanes)
    lanes = CampaignSpec.from_toml(HEAD.replace('["smc"]', '["smc", "pd"]')
                                   .replace("seeds = 1", "seeds = 3"))  # fmt: skip
    pkmctl.simulate_many(lanes.scenario(0), "smc", seeds=[0, 1], duration=0.01, lanes=2)
    pkmctl.simulate_many(lanes.scenario(0), "pd", seeds=[0, 1], duration=0.01, lanes=2)
    assert store.uncompiled_loops(lanes) == 0
    with monkeypatch.context() as m:
        m.setenv("PKMCTL_CACHE_DIR", str(tmp_path / "empty"))
        assert store.uncompiled_loops(lanes) == 2
    monkeypatch.setattr(store, "uncompiled_loops", lambda spec: 1)  # (the run: compiled)
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(HEAD)
    res = runner.invoke(app, ["campaign", "run", str(spec_file), "--out", str(tmp_path / "c"),
                              "--workers", "1"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert (", plus compiling: 1 combination of parts and controller has not run on this "
            "machine with this pkmctl yet") in " ".join(res.stderr.split()), res.stderr  # fmt: skip


def test_a_campaigns_log_gets_a_line_a_minute_as_well(tmp_path, monkeypatch):
    """In a log (not a terminal) progress came every 10 % only: an 85 min campaign was
    silent for 8.5 min. A line also comes once LOG_EVERY_S has passed since the last."""
    from pkmctl import cli

    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(
        HEAD + '[factors."payload.mass"]\n'
        "values = [" + ", ".join(f"{0.1 * k:.1f}" for k in range(24)) + "]\n"
    )
    lines = {}
    for every in (60.0, 0.0):
        monkeypatch.setattr(cli, "LOG_EVERY_S", every)
        res = runner.invoke(app, ["campaign", "run", str(spec_file), "--out",
                                  str(tmp_path / f"c{every}"), "--workers", "1"])  # fmt: skip
        assert res.exit_code == 0, res.output
        lines[every] = [ln for ln in res.stderr.splitlines() if " runs, 0 not ok, " in ln]
    assert len(lines[0.0]) > len(lines[60.0]) >= 1, lines


def test_a_campaigns_log_gets_a_line_a_minute_while_no_task_ends(tmp_path, monkeypatch):
    """The lines came only as tasks ended: 2 workers compiling 9 loops left a log silent
    for 11.5 min, where the docs promise a line at least every minute (a tester). Tasks
    of 0.6 s, LOG_EVERY_S 0.2 s: lines between them, saying what is awaited."""
    from pkmctl import cli
    from pkmctl.campaign import execute

    real = execute._task_result

    def slow(spec, task):
        time.sleep(0.6)
        return real(spec, task)

    monkeypatch.setattr(execute, "_task_result", slow)
    monkeypatch.setattr(cli, "LOG_EVERY_S", 0.2)
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(HEAD + '[factors."payload.mass"]\nvalues = [0.0, 1.0]\n')
    said = {}
    for compiling in (set(), {"a loop"}):
        monkeypatch.setattr(execute, "uncompiled_combinations", lambda s, c=compiling: set(c))
        out = tmp_path / f"c{len(compiling)}"
        res = runner.invoke(app, ["campaign", "run", str(spec_file), "--out", str(out),
                                  "--workers", "1"])  # fmt: skip
        assert res.exit_code == 0, res.output
        said[len(compiling)] = [ln for ln in res.stderr.splitlines() if "since the start)" in ln]
    idle = r"0/2 runs, 0 not ok, no task has ended yet \([\d.]+ s since the start\)"
    assert said[0] and re.fullmatch(idle, said[0][0]), said
    # between the tasks: when the last one ended (it said "no task has ended since the
    # last line" of a task that had: a reviewer)
    later = r"1/2 runs, 0 not ok, the last task ended [\d.]+ s ago \([\d.]+ s since the start\)"
    assert any(re.fullmatch(later, line) for line in said[0]), said
    first = r"0/2 runs, 0 not ok, the workers compile 1 loop first \([\d.]+ s since the start\)"
    assert said[1] and re.fullmatch(first, said[1][0]), said


def test_a_full_disk_names_the_file_the_runs_kept_and_the_resume(tmp_path, monkeypatch):
    """ "error: No space left on device", and nothing more (a tester's 200 kB tmpfs): no
    file, no runs kept, no resume command."""
    import contextlib
    import errno

    import pyarrow as pa

    from pkmctl.campaign import execute, store

    @contextlib.contextmanager
    def full(path, mode="w"):
        class Disk:
            def write(self, data):
                raise OSError(errno.ENOSPC, "No space left on device")

        yield Disk()

    real = store.atomic_write
    monkeypatch.setattr(store, "atomic_write", full)
    with pytest.raises(OSError) as info:
        store.write_task(tmp_path, 3, pa.table({"a": [1]}))
    assert info.value.filename == str(tmp_path / "task-00003.parquet")
    monkeypatch.setattr(store, "atomic_write", real)
    calls = []

    def second_fails(runs, index, table):
        calls.append(index)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device", str(runs / "task-x.parquet"))
        return store.write_task(runs, index, table)

    monkeypatch.setattr(execute, "write_task", second_fails)
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(HEAD + '[factors."payload.mass"]\nvalues = [0.0, 1.0, 2.0]\n')
    out = tmp_path / "c"
    res = runner.invoke(app, ["campaign", "run", str(spec_file), "--out", str(out),
                              "--workers", "1"])  # fmt: skip
    assert res.exit_code == 2, res.output
    line = " ".join(res.stderr.split())
    said = (
        f"error: {out / 'runs' / 'task-x.parquet'}: No space left on device; the runs done are "
        f"kept (1 of 3 in {out}); once it can be written, pkmctl campaign run {spec_file} "
        f"--out {out} --workers 1 --resume completes the campaign"
    )
    assert said in line, line


def test_an_empty_or_binary_spec_is_refused_in_one_line(tmp_path):
    """An empty spec ran a campaign of every key's default (3 runs of 10 s), where an
    empty scenario file is refused; a binary one gave Python's "'utf-8' codec can't
    decode byte 0x84 in position 3" (a fuzzer)."""
    (tmp_path / "empty.toml").write_text(" \n# nothing\n")
    (tmp_path / "binary.toml").write_bytes(b"a =\x84\x00\xff")
    for name, said in (
        ("empty.toml", "empty (no key set; `pkmctl campaign show paper-claims` prints a full one)"),
        ("binary.toml", "not UTF-8 text (byte 0x84 at offset 3)"),
    ):
        res = runner.invoke(app, ["campaign", "run", str(tmp_path / name), "--out",
                                  str(tmp_path / "c")])  # fmt: skip
        assert res.exit_code == 2, res.output
        assert len(res.stderr.strip().splitlines()) == 1 and said in res.stderr, res.stderr
        assert not (tmp_path / "c").exists()


def test_an_empty_name_is_no_folder(tmp_path):
    """`simulate ""` and `campaign run ""` said "'.': Is a directory" (a fuzzer)."""
    for args, said in (
        (["simulate", "", "--out", str(tmp_path / "o")], "scenario = '': must name a built-in"),
        (["campaign", "run", "", "--out", str(tmp_path / "o")],
         "campaign spec = '': must name a file or a built-in campaign (paper-claims)"),
        (["campaign", "show", ""], "campaign spec = '': must name a file"),
    ):  # fmt: skip
        res = runner.invoke(app, args)
        assert res.exit_code == 2 and said in res.stderr, res.stderr
        assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


@pytest.mark.parametrize("seeds", [1, 3, 9])
def test_a_campaign_that_ran_has_nothing_left_to_compile(tmp_path, monkeypatch, seeds):
    """With 2-4 seeds the header said "plus compiling ... a minute or more each" on every
    run, and the progress "the time left once 1 loop compiled": it asked for the lane
    loop, which a rest of half a batch or less never builds (a tester). The loops asked
    for are those the tasks run."""
    from pkmctl.campaign.store import uncompiled_loops
    from pkmctl.sim import lanes

    spec = CampaignSpec.from_toml(
        f'scenario = "paper"\ncontrollers = ["pd"]\nseeds = {seeds}\nduration = 0.01\n'
    )
    run_campaign(spec, tmp_path / "c", workers=1)
    assert uncompiled_loops(spec) == 0
    # a resume with nothing left runs no session (one was recorded each time: a tester)
    assert run_campaign(spec, tmp_path / "c", workers=1, resume=True).done_now == 0
    sessions = json.loads((tmp_path / "c" / "campaign.json").read_text())["sessions"]
    assert len(sessions) == 1
    # as if no lane loop were compiled: only a campaign whose tasks run one asks for it
    monkeypatch.setattr(lanes, "lanes_compiled", lambda parts: False)
    batches = lanes.lane_batches(seeds, lanes.lane_count())
    assert uncompiled_loops(spec) == (1 if max(batches) > 1 else 0), batches


def test_a_campaign_resumed_by_other_pkmctl_code_says_so(spec_file, tmp_path):
    """A resume after an upgrade completed the campaign with another version's code, and
    nothing but campaign.json's sessions said so (a tester). The command and report.md
    say it now."""
    out = tmp_path / "c"
    run_campaign(CampaignSpec.from_toml(spec_file), out, workers=1, stop_after=1)
    manifest = json.loads((out / "campaign.json").read_text())
    manifest["sessions"][0]["pkmctl_sources"] = "0123456789abcdef0123"  # as an older one
    (out / "campaign.json").write_text(json.dumps(manifest))
    res = runner.invoke(app, ["campaign", "run", str(spec_file), "--out", str(out),
                              "--workers", "1", "--resume"])  # fmt: skip
    assert res.exit_code == 0, res.output
    said = "note: its records were made by 2 versions of pkmctl's code: "
    assert said in res.stderr and "0123456789abcdef0123" in res.stderr, res.stderr
    res = runner.invoke(app, ["campaign", "report", str(out)])
    assert res.exit_code == 0, res.output
    report = " ".join((out / "report" / "report.md").read_text().split())
    assert "**Note**: its records were made by 2 versions of pkmctl's code" in report
    fresh = tmp_path / "f"
    run_campaign(CampaignSpec.from_toml(spec_file), fresh, workers=1)
    from pkmctl.campaign.store import mixed_versions

    assert mixed_versions(fresh) == ""
