"""Campaigns of user parts (``pkmctl --plugin FILE.py campaign ...``, docs/parts.md)."""

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
from typer.testing import CliRunner

import pkmctl
from pkmctl.campaign import CampaignSpec
from pkmctl.campaign.execute import run_campaign
from pkmctl.campaign.spec import SpecError
from pkmctl.campaign.store import check_store, open_store, read_records
from pkmctl.cli import app
from pkmctl.plugins import ENV

runner = CliRunner()
SRC = Path(pkmctl.__file__).resolve().parents[1]

LAW = """
from typing import NamedTuple
import pkmctl

GAIN = 1.0e4

class P(NamedTuple):
    k: float

    @classmethod
    def from_context(cls, ctx):
        return cls(GAIN)

@pkmctl.register_controller("NAME", params=P)
def law(p, state, work, y, ref, F):
    for i in range(3):
        F[i] = p.k * (ref[i] - y[i])
"""

#: A step Numba cannot type (a dict of objects): fails in ~2 s, before any loop runs.
NO_COMPILE = LAW.replace(
    "    for i in range(3):", '    d = {"a": object()}\n    for i in range(3):'
)


def _plugin(tmp_path: Path, source: str) -> tuple[Path, str]:
    """A plugin file registering a controller of a fresh name, imported in this process
    as ``pkmctl --plugin`` imports it; (its path, the controller's name)."""
    module = "law_" + uuid.uuid4().hex[:10]
    name = module.replace("_", "-")
    path = tmp_path / f"{module}.py"
    path.write_text(source.replace("NAME", name))
    spec = importlib.util.spec_from_file_location(module, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[module] = mod
    spec.loader.exec_module(mod)
    return path, name


def _spec(tmp_path: Path, controllers: list[str], seeds: int = 2) -> Path:
    path = tmp_path / "spec.toml"
    path.write_text(f"scenario = \"paper\"\ncontrollers = {json.dumps(controllers)}\n"
                    f"seeds = {seeds}\nduration = 0.05\nmetrics = [\"rmse\"]\n")  # fmt: skip
    return path


def test_a_resume_with_an_edited_plugin_part_is_refused(tmp_path, monkeypatch):
    monkeypatch.setenv(ENV, "")  # --plugin adds to it: restored after the test
    plugin, name = _plugin(tmp_path, LAW)
    spec_file = _spec(tmp_path, ["pd", name])
    spec = CampaignSpec.from_toml(spec_file)
    out = tmp_path / "c"
    open_store(out, spec, resume=False)  # as a campaign interrupted before its first task
    stored = json.loads((out / "campaign.json").read_text())["user_parts"]
    assert list(stored) == [f"controller {name}"]
    assert stored[f"controller {name}"]["files"] == [str(plugin)]
    check_store(out, spec, resume=True)  # the same source: a resume goes on
    plugin.write_text(plugin.read_text().replace("GAIN = 1.0e4", "GAIN = 2.0e4"))  # edited
    expected = (
        f"--resume: controller {name!r}: its source, or a value its code reads, changed "
        f"since the campaign in {str(out)!r} started ({plugin.name}); its records would mix "
        f"two versions of it: restore them, or run the campaign into another --out"
    )
    with pytest.raises(SpecError) as err:
        run_campaign(spec, out, workers=1, resume=True)
    assert str(err.value) == expected
    res = runner.invoke(app, ["--plugin", str(plugin), "campaign", "run", str(spec_file),
                              "--out", str(out), "--resume"])  # fmt: skip
    assert res.exit_code == 2, res.output
    assert res.stderr.strip().splitlines()[-1] == f"error: {expected}"
    assert list((out / "runs").iterdir()) == []


def test_a_resume_after_a_value_imported_by_the_part_changed_is_refused(tmp_path, monkeypatch):
    """Gains imported from a helper module (``from gains import GAIN``) and read by the
    part's from_context: editing the helper changed no hashed source, and a resume mixed
    two versions of the controller in one campaign, exit 0 (a tester)."""
    monkeypatch.setenv(ENV, "")
    helper = "gains_" + uuid.uuid4().hex[:10]
    (tmp_path / f"{helper}.py").write_text("GAIN = 1.0e4\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    source = LAW.replace("GAIN = 1.0e4", f"from {helper} import GAIN")
    plugin, name = _plugin(tmp_path, source)
    spec = CampaignSpec.from_toml(_spec(tmp_path, ["pd", name]))
    out = tmp_path / "c"
    open_store(out, spec, resume=False)
    check_store(out, spec, resume=True)  # nothing changed: a resume goes on
    # a new process after the helper's edit: the plugin imports the new value
    monkeypatch.setattr(sys.modules[plugin.stem], "GAIN", 2.0e4)
    with pytest.raises(SpecError, match=f"controller {name!r}: its source, or a value its"):
        check_store(out, spec, resume=True)
    monkeypatch.setattr(sys.modules[plugin.stem], "GAIN", 1.0e4)
    check_store(out, spec, resume=True)  # restored: it goes on


_API_RUN = """
import importlib.util, sys
from pkmctl.campaign import CampaignSpec
from pkmctl.campaign.execute import run_campaign
from pkmctl.campaign.store import read_records

{script_law}

if __name__ == "__main__":
    import {module}  # registered here only, as a notebook's import does
    import {registrar}  # registers a step another module defines
    spec = importlib.util.spec_from_file_location("{by_path}", sys.argv[3])
    loaded = importlib.util.module_from_spec(spec)  # from a folder off sys.path
    sys.modules["{by_path}"] = loaded
    spec.loader.exec_module(loaded)
    done = run_campaign(CampaignSpec.from_toml(sys.argv[1]), sys.argv[2], workers=2)
    rows = read_records(sys.argv[2], timing=False).to_pylist()
    print(sorted({{(r["controller"], r["status"]) for r in rows}}))
"""


def test_from_python_local_workers_import_the_module_that_registered_the_part(
    tmp_path, monkeypatch
):
    """run_campaign(workers=2) from a script that imports its part's module (no
    --plugin): every run of the part was an error record, its hint naming --plugin. Also
    (a reviewer): a part registered by a module other than its step's, one loaded from a
    file off sys.path, and one registered at the script's top level (its values read as
    __main__'s here and __mp_main__'s in a worker: every run was a PluginMismatch)."""
    monkeypatch.delenv(ENV, raising=False)
    tag = uuid.uuid4().hex[:8]
    module, helper, registrar, by_path = (f"{w}_{tag}" for w in ("law", "steps", "reg", "far"))
    names = {m: m.replace("_", "-") for m in (module, registrar, by_path, "main")}
    names["main"] = f"main-{tag}"
    (tmp_path / f"{module}.py").write_text(LAW.replace("NAME", names[module]))
    unregistered = LAW.replace('@pkmctl.register_controller("NAME", params=P)\n', "")
    (tmp_path / f"{helper}.py").write_text(unregistered)
    (tmp_path / f"{registrar}.py").write_text(
        f"import pkmctl\nfrom {helper} import P, law\n"
        f"pkmctl.register_controller({names[registrar]!r}, params=P)(law)\n"
    )
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / f"{by_path}.py").write_text(LAW.replace("NAME", names[by_path]))
    script = tmp_path / "run.py"
    script.write_text(_API_RUN.format(module=module, registrar=registrar, by_path=by_path,
                                      script_law=LAW.replace("NAME", names["main"])))  # fmt: skip
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(SRC)]))
    env.pop(ENV, None)
    spec = _spec(tmp_path, ["pd", *names.values()], seeds=1)
    res = subprocess.run([sys.executable, str(script), str(spec), str(tmp_path / "c"),
                          str(tmp_path / "lib" / f"{by_path}.py")], env=env,
                         capture_output=True, text=True, timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stderr
    expected = sorted({(n, "ok") for n in [*names.values(), "pd"]})
    assert res.stdout.strip() == str(expected), res.stdout + res.stderr
    # defined at a prompt or in a notebook cell: no worker can import it, said up front
    code = LAW.replace("NAME", "typed-law") + (
        "\nfrom pkmctl.campaign import CampaignSpec\n"
        "from pkmctl.campaign.execute import run_campaign\n"
        f"run_campaign(CampaignSpec.from_toml({str(_spec(tmp_path, ['typed-law']))!r}), "
        f"{str(tmp_path / 'd')!r}, workers=2)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=600)  # fmt: skip
    assert res.returncode == 1
    assert res.stderr.strip().splitlines()[-1] == (
        "pkmctl.campaign.spec.SpecError: controller 'typed-law' is registered in a notebook "
        "or at a prompt, which worker processes cannot import: define it in a module and "
        "import that, or run with workers=1"
    ), res.stderr
    assert not (tmp_path / "d").exists()


def test_a_worker_that_cannot_import_a_parts_module_says_why():
    """The worker's import error was dropped, and each run's error then told the user to
    import the module, which they had done (a reviewer)."""
    code = ("import os; from pkmctl.sim import workers; "
            "workers._start(os.getppid(), ('no_such_module_here',))")  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(SRC))
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=120)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert res.stderr == (
        "warning: a worker could not import no_such_module_here: ModuleNotFoundError: No "
        "module named 'no_such_module_here'\n"
    )


def test_a_part_that_does_not_compile_stops_the_campaign_before_any_record(tmp_path, monkeypatch):
    monkeypatch.setenv(ENV, "")
    plugin, name = _plugin(tmp_path, NO_COMPILE)
    out = tmp_path / "c"
    res = runner.invoke(app, ["--plugin", str(plugin), "campaign", "run",
                              str(_spec(tmp_path, ["pd", name])), "--out", str(out),
                              "--workers", "2"])  # fmt: skip
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, res.stderr
    assert errors[0].startswith(f"error: the part controller {name!r} does not compile: ")
    assert errors[0].endswith("; nothing run"), errors[0]
    assert not out.exists()


def _pkmctl(*args: str, **kw) -> subprocess.Popen:
    env = dict(os.environ)
    src = str(Path(pkmctl.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([src, env.get("PYTHONPATH", "")])
    env.pop(ENV, None)
    return subprocess.Popen([sys.executable, "-c", "from pkmctl.cli import main; main()", *args],
                            env=env, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                            **kw)  # fmt: skip


def test_the_resume_hint_after_ctrl_c_repeats_the_plugins(tmp_path):
    import shlex

    (tmp_path / "my plugins").mkdir()
    plugin = tmp_path / "my plugins" / "noop_plugin.py"
    plugin.write_text("import pkmctl  # registers nothing: what matters is the hint\n")
    spec = _spec(tmp_path, ["smc"], seeds=64)
    spec.write_text(spec.read_text().replace("0.05", "0.5"))
    out = tmp_path / "out"
    proc = _pkmctl("--plugin", str(plugin), "campaign", "run", str(spec), "--out", str(out),
                   "--workers", "1")  # fmt: skip
    deadline = time.monotonic() + 120
    while not (out / "campaign.json").exists() and proc.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    hint = shlex.join(["pkmctl", "--plugin", str(plugin), "campaign", "run", str(spec), "--out",
                       str(out), "--workers", "1", "--resume"])  # fmt: skip
    assert f"{hint} completes it" in err, err


def test_a_campaign_of_a_plugin_part_read_without_it_says_to_pass_it(tmp_path, monkeypatch):
    plugin, name = _plugin(tmp_path, LAW)
    out = tmp_path / "c"
    open_store(out, CampaignSpec.from_toml(_spec(tmp_path, [name])), resume=False)
    proc = _pkmctl("campaign", "report", str(out))  # a new process: the plugin not imported
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    assert err.strip() == (
        f"error: {str(out)!r}: its runs use the controller {name!r}, which is not registered: "
        f"pass the plugin that registers it (it was read from {plugin}), pkmctl --plugin "
        f"FILE.py campaign ..."
    )
    with pytest.raises(
        SpecError,
        match=r"'no-such-law' is not a registered controller \(.*; "
        r"your own: pass the plugin that registers it, pkmctl --plugin FILE.py",
    ):
        CampaignSpec.from_toml(_spec(tmp_path, ["no-such-law"]))  # fmt: skip


#: A controller whose build refuses a payload: every run of a cell with one is an error.
NO_PAYLOAD = LAW.replace(
    "        return cls(GAIN)",
    "        if ctx.scenario.payload.mass > 0:\n"
    "            raise ValueError('no payload, please')\n"
    "        return cls(GAIN)",
)


def _with_payload(tmp_path: Path, source: str, workers: int):
    """``campaign run`` of a plugin controller over payload.mass 0 and 5, one seed: (the
    result, the campaign folder, the plugin file, the controller's name)."""
    plugin, name = _plugin(tmp_path, source)
    spec_file = _spec(tmp_path, [name], seeds=1)
    spec_file.write_text(spec_file.read_text() + '[factors."payload.mass"]\nvalues = [0.0, 5.0]\n')
    out = tmp_path / "c"
    res = runner.invoke(app, ["--plugin", str(plugin), "campaign", "run", str(spec_file),
                              "--out", str(out), "--workers", str(workers)])  # fmt: skip
    return res, out, plugin, name


def test_a_run_that_errs_says_why_in_the_command_and_the_report(tmp_path, monkeypatch):
    """A run that raises is a record with status "error": `campaign run` prints its message
    and exits 1 (an error is not a result), the report names it at its cell."""
    monkeypatch.setenv(ENV, "")
    res, out, plugin, name = _with_payload(tmp_path, NO_PAYLOAD, workers=1)
    assert res.exit_code == 1, res.output  # a run that failed with an error: not a result
    why = f"PartError: controller {name!r}: build failed: ValueError: no payload, please"
    # which run, so that it can be rerun alone (a tester queried the records for it)
    assert f"1 run failed (cell 1 {name} seed 0): {why}" in res.stderr, res.stderr
    assert [r["status"] for r in read_records(out).to_pylist()] == ["ok", "error"]
    res = runner.invoke(app, ["--plugin", str(plugin), "campaign", "report", str(out)])
    assert res.exit_code == 0, res.output
    md = (out / "report" / "report.md").read_text()
    assert f"at payload.mass = 5; 1 error (seed 0): {why}" in md, md


SEED_ZERO = LAW.replace(
    "        return cls(GAIN)",
    "        if ctx.scenario.disturbance.seed == 0:\n"
    "            raise ValueError('not seed 0')\n"
    "        return cls(GAIN)",
)


def test_a_build_that_refuses_one_seed_is_that_runs_error_alone(tmp_path, monkeypatch):
    """A task's first run whose build raised made every run of the task an error record
    with its message (a tester: 8 of 8 for a build refusing seed 0), and --resume failed
    them all again."""
    monkeypatch.setenv(ENV, "")
    plugin, name = _plugin(tmp_path, SEED_ZERO)
    spec_file = _spec(tmp_path, [name], seeds=4)  # seeds 0-3, one task
    out = tmp_path / "c"
    res = runner.invoke(app, ["--plugin", str(plugin), "campaign", "run", str(spec_file),
                              "--out", str(out), "--workers", "1"])  # fmt: skip
    assert res.exit_code == 1, res.output
    rows = sorted(read_records(out).to_pylist(), key=lambda r: r["seed"])
    assert [r["status"] for r in rows] == ["error", "ok", "ok", "ok"]
    assert "not seed 0" in rows[0]["message"]
    alone = pkmctl.simulate(CampaignSpec.from_toml(spec_file).scenario(0), name, seed=2)
    assert rows[2]["rmse_z_mm"] == pytest.approx(alone.rmse()["z_mm"], rel=1e-12)


EXITS = LAW.replace(
    "        return cls(GAIN)",
    "        if ctx.scenario.payload.mass > 0:\n"
    "            import os\n"
    "            os._exit(3)\n"
    "        return cls(GAIN)",
)


def test_a_worker_that_keeps_dying_names_its_task_and_the_resume(tmp_path, monkeypatch):
    """A run that ends its process (a plugin's os._exit) broke the pool four times and
    ended in 'RuntimeError: a worker process died 4 times; 1 tasks left (an internal
    error ...)', exit 1, naming no task and no way on."""
    monkeypatch.setenv(ENV, "")
    res, out, _, name = _with_payload(tmp_path, EXITS, workers=2)
    assert res.exit_code == 2, res.output
    (line,) = [ln for ln in res.stderr.splitlines() if ln.startswith("error: ")]
    assert line.startswith("error: a worker process died 4 times, running task 1 (cell 1: "
                           f"payload.mass = 5.0; controller {name}): a run there ends its "
                           "process"), line  # fmt: skip
    assert line.endswith("--workers 2 --resume completes the campaign"), line
    assert "(1 of 2 in " in line and "internal error" not in line
    assert [r["status"] for r in read_records(out).to_pylist()] == ["ok"]  # the one done


@pytest.mark.cluster
def test_a_task_that_ends_its_dask_workers_is_named(tmp_path):
    """On Dask, a run that ends its worker process read "KilledWorker: Attempted to run
    task ... (an internal error ...)", exit 1, no resume (a tester; or, with the default
    allowed-failures, that the scheduler had gone away). Now the task is named, as the
    local executor names it."""
    from tests.test_campaign import _cluster

    module = "law_" + uuid.uuid4().hex[:10]
    name = module.replace("_", "-")
    (tmp_path / f"{module}.py").write_text(EXITS.replace("NAME", name))
    spec_file = _spec(tmp_path, [name], seeds=1)
    spec_file.write_text(spec_file.read_text() + '[factors."payload.mass"]\nvalues = [0.0, 5.0]\n')
    out = tmp_path / "c"
    with _cluster(2, worker_args=("--preload", module), pythonpath=(str(tmp_path),),
                  allowed_failures=0) as (address, _):  # fmt: skip
        proc = _pkmctl("--plugin", str(tmp_path / f"{module}.py"), "campaign", "run",
                       str(spec_file), "--out", str(out), "--scheduler", address)  # fmt: skip
        _, err = proc.communicate(timeout=170)
    assert proc.returncode == 2, err
    (line,) = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert line.startswith(
        f"error: task 1 (cell 1: payload.mass = 5.0; controller {name}) ended each worker "
        "process it ran on, 1 of them (the scheduler's allowed-failures): a run there ends "
        "its process"
    ), line
    assert "--resume completes the campaign" in line and "internal error" not in line, line


def _mismatch(name: str, ran: str, recorded: str) -> str:
    return (
        f"PluginMismatch: controller {name!r}: the worker ran another version of it (source "
        f"hash {ran}; the campaign's is {recorded}): make the workers import the plugin this "
        "campaign was started with, then --resume"
    )


def _recorded(out: Path, name: str) -> str:
    return json.loads((out / "campaign.json").read_text())["user_parts"][f"controller {name}"][
        "sha256"
    ]


def test_runs_of_another_version_of_a_part_than_the_recorded_one_are_error_records(
    tmp_path, monkeypatch
):
    """A process runs the part it imported; its file edited since (not imported again),
    campaign.json recorded the edited file's hash while the records came from the code
    imported before. Each task now says which version its runs ran."""
    monkeypatch.setenv(ENV, "")
    plugin, name = _plugin(tmp_path, LAW)
    spec = CampaignSpec.from_toml(_spec(tmp_path, ["pd", name]))
    first = run_campaign(spec, tmp_path / "a", workers=1)  # the imported version, recorded
    assert first.complete and first.errors == 0
    before = _recorded(tmp_path / "a", name)
    plugin.write_text(plugin.read_text().replace("GAIN = 1.0e4", "GAIN = 2.0e4"))
    out = tmp_path / "b"
    done = run_campaign(spec, out, workers=1)
    after = _recorded(out, name)
    assert after != before
    rows = read_records(out).to_pylist()
    assert {r["status"] for r in rows if r["controller"] == "pd"} == {"ok"}
    mine = [r for r in rows if r["controller"] == name]
    assert len(mine) == 2 and done.errors == 2
    assert {r["message"] for r in mine} == {_mismatch(name, before, after)}
    assert all(r["rmse_z_mm"] is None and r["status"] == "error" for r in mine)


def test_runs_a_worker_made_with_another_pkmctl_are_error_records(tmp_path, monkeypatch):
    """A tester's Dask worker ran a copy of pkmctl with one line changed: 8 records differed
    from an undisturbed run, with exit 0 and "0 failed". Each task's worker now sends the
    hash of pkmctl's modules as it imported them; a task made by other code is error
    records saying so (run here: the worker's hash stands for another machine's)."""
    from pkmctl import _jit
    from pkmctl.campaign import execute

    spec = CampaignSpec.from_toml(_spec(tmp_path, ["pd", "smc"]))
    real = execute._task_result
    other = "f" * 20
    assert _jit.package_stamp() != other

    def elsewhere(spec, task):
        table, ran, code = real(spec, task)
        assert code == _jit.package_stamp()  # (what a worker sends: its own)
        return table, ran, other if task.index == 0 else code

    monkeypatch.setattr(execute, "_task_result", elsewhere)
    done = run_campaign(spec, tmp_path / "c", workers=1)
    rows = read_records(tmp_path / "c").to_pylist()
    first = {(r.controller, r.seed) for r in spec.tasks()[0].runs}
    bad = [r for r in rows if (r["controller"], r["seed"]) in first]
    assert bad and done.errors == len(bad) == len(first)
    assert {r["message"] for r in bad} == {
        f"CodeMismatch: the worker ran another pkmctl (its modules' hash {other}; this "
        f"campaign's {_jit.package_stamp()}): run the same pkmctl on every worker (restart a "
        "worker started before pkmctl changed), then --resume"
    }
    assert all(r["status"] == "error" and r["rmse_z_mm"] is None for r in bad)
    assert all(r["status"] == "ok" for r in rows if r not in bad)
    session = json.loads((tmp_path / "c" / "campaign.json").read_text())["sessions"][-1]
    assert session["pkmctl_sources"] == _jit.package_stamp()
    # --resume with the workers on the campaign's code runs them again
    monkeypatch.setattr(execute, "_task_result", real)
    again = run_campaign(spec, tmp_path / "c", workers=1, resume=True)
    statuses = {r["status"] for r in read_records(tmp_path / "c").to_pylist()}
    assert again.errors == 0 and statuses == {"ok"}


@pytest.mark.cluster
def test_dask_workers_running_another_version_of_a_plugin_make_error_records(tmp_path):
    """The workers preload their own copy of the plugin (another GAIN); the client's copy,
    whose hash campaign.json records, is not what made their records: those runs are
    error records naming the mismatch, and the command exits 1."""
    from tests.test_campaign import _cluster

    module = "law_" + uuid.uuid4().hex[:10]
    name = module.replace("_", "-")
    theirs, mine = tmp_path / "workers", tmp_path / "client"
    theirs.mkdir()
    mine.mkdir()
    (theirs / f"{module}.py").write_text(LAW.replace("NAME", name).replace("1.0e4", "3.0e4"))
    (mine / f"{module}.py").write_text(LAW.replace("NAME", name))
    spec_file = _spec(tmp_path, ["pd", name])
    out = tmp_path / "c"
    with _cluster(1, worker_args=("--preload", module), pythonpath=(str(theirs),)) as (
        address, _
    ):  # fmt: skip
        proc = _pkmctl("--plugin", str(mine / f"{module}.py"), "campaign", "run",
                       str(spec_file), "--out", str(out), "--scheduler", address)  # fmt: skip
        _, err = proc.communicate(timeout=170)
    assert proc.returncode == 1, err
    _plugin_at(mine / f"{module}.py", module)  # to read the records here
    recorded = _recorded(out, name)
    rows = read_records(out).to_pylist()
    assert {r["status"] for r in rows if r["controller"] == "pd"} == {"ok"}
    messages = {r["message"] for r in rows if r["controller"] == name}
    assert len(messages) == 1, messages
    (message,) = messages
    assert message.startswith(f"PluginMismatch: controller {name!r}: the worker ran another ")
    assert f"the campaign's is {recorded})" in message
    ran = message.split("(source hash ", 1)[1].split(";", 1)[0]
    assert ran != recorded
    assert f"2 runs failed (cell 0 {name} seed 0, cell 0 {name} seed 1): {message}" in err, err


@pytest.mark.cluster
def test_dask_workers_preloading_the_plugin_file_run_its_part(tmp_path):
    """``dask worker --preload my_law.py`` (docs/parts.md) imports the file, then reloads
    it: the second registration of the same part from the same text killed the worker."""
    from tests.test_campaign import _cluster

    module = "law_" + uuid.uuid4().hex[:10]
    name = module.replace("_", "-")
    plugin = tmp_path / f"{module}.py"
    plugin.write_text(LAW.replace("NAME", name))
    spec_file = _spec(tmp_path, ["pd", name])
    out = tmp_path / "c"
    with _cluster(1, worker_args=("--preload", str(plugin))) as (address, workers):
        proc = _pkmctl("--plugin", str(plugin), "campaign", "run", str(spec_file), "--out",
                       str(out), "--scheduler", address)  # fmt: skip
        _, err = proc.communicate(timeout=170)
        assert workers[0].poll() is None  # alive
    assert proc.returncode == 0, err
    _plugin_at(plugin, module)
    rows = read_records(out).to_pylist()
    assert len(rows) == 4 and {r["status"] for r in rows} == {"ok"}


def _plugin_at(path: Path, module: str) -> None:
    """Import the plugin file ``path`` as ``module`` in this process (to read records)."""
    loader = importlib.util.spec_from_file_location(module, path)
    sys.modules[module] = importlib.util.module_from_spec(loader)
    loader.loader.exec_module(sys.modules[module])
