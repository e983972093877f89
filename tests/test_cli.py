"""End to end through the ``pkmctl`` entry point."""

import csv
import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

import pkmctl
from pkmctl.cli import app
from pkmctl.io.results import load_result
from pkmctl.sim.metrics import RMSE_KEYS

runner = CliRunner()


def test_reproduce_end_to_end(tmp_path):
    out = tmp_path / "out"
    res = runner.invoke(app, ["reproduce", "--out", str(out), "--duration", "0.2", "--seed", "5"])
    assert res.exit_code == 0, res.output
    with open(out / "table4.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["controller"] for r in rows] == ["smc", "fsmc", "afsmc", "pd", "ctc"]
    assert list(rows[0]) == ["controller", *RMSE_KEYS]
    assert all(float(r[k]) > 0 for r in rows for k in RMSE_KEYS)
    md = (out / "table4.md").read_text()
    assert "6.12032" in md  # the paper's SMC beta RMSE beside ours
    assert "| PD | ours |" in md and "| PD | paper |" not in md  # ours gain two rows
    report = (out / "report.md").read_text()
    figs = sorted(p.name for p in (out / "figures").iterdir())
    machine = ["machine_end.png", "machine_home.png", "machine_largest-tilt.png"]
    if "## The machine" in report and "No images of the machine" in report:
        machine = []  # no MuJoCo or no offscreen GL here: said in one line instead
    assert figs == [f"fig{n}.png" for n in range(10, 27)] + machine
    for name in figs:
        assert f"figures/{name}" in report
        assert (out / "figures" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    series = load_result(out / "timeseries" / "afsmc.json")
    assert series.t.size == 4000 and series.scenario.disturbance.seed == 5
    assert np.isclose(float(rows[2]["beta_deg"]), series.rmse()["beta_deg"], rtol=1e-12)
    meta = json.loads((out / "timeseries" / "smc.json").read_text())
    assert meta["controller"] == "smc" and "rmse" in meta["metrics"]
    # which pkmctl made them (only campaign.json said: a tester)
    from pkmctl import __version__, _jit

    assert meta["software"]["pkmctl"] == __version__
    assert meta["software"]["kernel_sources"] == _jit.source_stamp()
    assert meta["software"]["pkmctl_sources"] == _jit.package_stamp()
    assert f"Made by pkmctl {__version__} (sources {_jit.package_stamp()}, kernels " in report
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
    said = [line for line in res.output.splitlines() if line.startswith("wrote ")]
    assert len(said) == 1, res.output  # where the time went (issue 16.4), on one line
    assert re.search(r"in [\d.]+ s: [\d.]+ s before the runs, [\d.]+ s of runs \(their "
                     r"compiled loops [\d.]+ s, summed\), [\d.]+ s more for the figures, "
                     r"[\d.]+ s for the report$", said[0]), said  # fmt: skip


def test_reproduce_says_why_the_machine_has_no_pictures(tmp_path, monkeypatch):
    """Without MuJoCo (or an offscreen GL), reproduce said "rendering the machine" and
    nothing more: only report.md told why it had no pictures (a tester)."""
    from pkmctl import experiment

    why = "No images of the machine: pkmctl.plants.mujoco needs MuJoCo: pip install x."
    monkeypatch.setattr(experiment, "_machine_images", lambda results, folder: ([], why))
    out = tmp_path / "out"
    res = runner.invoke(app, ["reproduce", "--out", str(out), "--duration", "0.01"])
    assert res.exit_code == 0, res.output
    assert f"note: {why}" in res.stderr.splitlines(), res.stderr
    assert why in (out / "report.md").read_text()


def test_reproduce_phases_add_up(tmp_path):
    from pkmctl.experiment import reproduce

    seen: list[tuple[int, int]] = []
    out = reproduce(pkmctl.Scenario.builtin("paper"), tmp_path / "o", duration=0.1,
                    run_progress=lambda *a: seen.append(a))  # fmt: skip
    # the five runs' periods together, as they compute: all of them by the end
    assert seen[-1] == (5 * 2000, 5 * 2000) and all(t == 10000 for _, t in seen)
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)
    ph = out.phases
    assert set(ph) == {"before", "runs", "loops", "figures", "report"}
    assert all(v >= 0 for v in ph.values()) and ph["loops"] > 0
    spent = ph["before"] + ph["runs"] + ph["figures"] + ph["report"]
    assert spent == pytest.approx(out.wall_time_s, rel=1e-6, abs=1e-3)
    kernels = sum(r.info["kernel_seconds"] for r in out.results.values())
    assert ph["loops"] == kernels


def test_scenario_and_simulate_commands(tmp_path):
    res = runner.invoke(app, ["scenario", "paper-1khz"])
    assert res.exit_code == 0
    sc = pkmctl.Scenario.from_toml(res.stdout)
    assert sc == pkmctl.Scenario.builtin("paper-1khz")
    path = tmp_path / "s.toml"
    path.write_text(sc.replace(**{"timing.duration": 0.05}).to_toml())
    res = runner.invoke(
        app, ["simulate", str(path), "--controller", "fsmc", "--out", str(tmp_path)]
    )
    assert res.exit_code == 0, res.output
    assert load_result(tmp_path / "fsmc.json").t.size == 50
    # the same run as CSV replaces the Parquet table its new fsmc.json no longer names
    args = ["simulate", str(path), "--controller", "fsmc", "--out", str(tmp_path)]
    res = runner.invoke(app, [*args, "--format", "csv"])
    assert res.exit_code == 0, res.output
    assert "removed fsmc.parquet of an earlier run" in res.output
    assert not (tmp_path / "fsmc.parquet").exists()
    assert load_result(tmp_path / "fsmc.json").t.size == 50


def test_simulate_shows_how_far_the_run_is_on_a_terminal(tmp_path, monkeypatch):
    import io

    from rich.console import Console

    from pkmctl import cli
    from pkmctl.sim import simulate as sim

    screen = io.StringIO()
    monkeypatch.setattr(cli, "err_console", Console(file=screen, force_terminal=True, width=100))
    monkeypatch.setattr(sim, "CHUNK_PERIODS", 500)  # 2000 periods: four steps of the bar
    args = ["simulate", "paper", "--controller", "pd", "--duration", "0.1"]
    res = runner.invoke(app, [*args, "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    frames = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", screen.getvalue())
    assert "simulating pd on 'paper'" in frames and "100%" in frames, frames


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["reproduce", "--scenario", "nope"], "unknown built-in"),
        (["reproduce", "--duration", "-1"], "--duration = -1.0 (timing.duration): "),
        (["reproduce", "--seed", "-3"], "--seed = -3 (disturbance.seed): "),
        (["simulate", "paper", "--seed", "-3"], "--seed = -3 (disturbance.seed): "),
        (["scenario", "nope"], "unknown built-in"),
        (["simulate", "missing.toml"], "No such file"),
        (["simulate", "paper", "--controller", "pid"], "--controller = 'pid'"),
    ],
)
def test_bad_input_exits_2_with_one_line(args, match):
    res = runner.invoke(app, args)
    assert res.exit_code == 2
    assert match in res.output
    lines = [ln for ln in res.output.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, res.output


def test_diverging_simulation_exits_1(tmp_path):
    bad = pkmctl.Scenario.builtin("paper").replace(
        **{"gains.K": [1e9, 1e9, 1e9], "timing.duration": 0.2}
    )
    path = tmp_path / "bad.toml"
    path.write_text(bad.to_toml())
    res = runner.invoke(app, ["simulate", str(path), "--controller", "smc"])
    assert res.exit_code == 1
    assert "diverged at t = " in res.output


def test_console_script_installed():
    # the installed entry point, as a user runs it
    res = subprocess.run(
        [sys.executable, "-m", "pkmctl", "scenario", "paper"], capture_output=True, text=True
    )
    assert res.returncode == 0 and 'name = "paper"' in res.stdout


def test_no_color_means_no_escape_codes_at_all():
    """NO_COLOR (no-color.org) dropped rich's colours but still sent bold: "error:" came
    as ESC[1m. FORCE_COLOR makes rich style a pipe as it would a terminal."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "NO_COLOR"} | {"FORCE_COLOR": "1"}

    def stderr(env: dict) -> str:
        args = [sys.executable, "-m", "pkmctl", "simulate", "no-such"]
        return subprocess.run(args, capture_output=True, text=True, timeout=120, env=env).stderr

    assert "\x1b[" in stderr(env)  # styled without it
    plain = stderr(env | {"NO_COLOR": "1"})
    assert plain.startswith("error: ") and "\x1b" not in plain, repr(plain)


@pytest.mark.parametrize("args", [["scenario", "paper"], ["campaign", "show", "paper-claims"]])
def test_printing_to_a_closed_or_full_stdout_is_one_line(args):
    """stdout closed (``>&-``) was an internal AttributeError, and for ``campaign show`` a
    traceback; ``> /dev/full`` did not say it was stdout."""
    import os

    what = "the scenario" if args[0] == "scenario" else "the spec"
    closed = subprocess.run([sys.executable, "-m", "pkmctl", *args], stdout=None,
                            stderr=subprocess.PIPE, text=True, preexec_fn=lambda: os.close(1),
                            timeout=120)  # fmt: skip
    assert closed.returncode == 2, closed.stderr
    assert closed.stderr.strip() == f"error: stdout is closed: nowhere to print {what} " \
        "(redirect it to a file)"  # fmt: skip
    with open("/dev/full", "w") as full:
        res = subprocess.run([sys.executable, "-m", "pkmctl", *args], stdout=full,
                             stderr=subprocess.PIPE, text=True, timeout=120)  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip() == (
        f"error: printing {what} to stdout failed: No space left on device"
    )


def test_a_full_stdout_after_the_files_are_written_is_one_line(tmp_path):
    """`pkmctl simulate ... > /dev/full` printed a 40-line traceback, exit 1, after its
    files were written (a tester): one line on stderr now, the files whole."""
    with open("/dev/full", "w") as full:
        res = subprocess.run([sys.executable, "-m", "pkmctl", "simulate", "paper", "--duration",
                              "0.01", "--out", str(tmp_path / "o")], stdout=full,
                             stderr=subprocess.PIPE, text=True, timeout=300)  # fmt: skip
    assert res.returncode == 1, res.stderr
    assert res.stderr.strip().splitlines()[-1] == (
        "error: stdout: No space left on device; the files written are whole"
    ), res.stderr
    assert "Traceback" not in res.stderr
    back = pkmctl.load_result(tmp_path / "o" / "afsmc.json")
    assert back.t.size == 200


@pytest.mark.parametrize(
    ("command", "text"),
    [(["identify"], "scenario [controller_model] block"),
     (["mujoco-model"], "viscous friction ([plant]) become"), ([], "(Parquet by default, or CSV)")],
)  # fmt: skip
def test_help_shows_its_text_verbatim(command, text):
    """Help is Markdown, not rich markup (which took "[plant]" for a style and dropped
    it); the command list joins a docstring's lines."""
    res = runner.invoke(app, [*command, "--help"], terminal_width=200)
    assert res.exit_code == 0
    assert any(text in re.sub(r"[ │]+", " ", line) for line in res.output.splitlines())


@pytest.mark.parametrize(
    ("command", "flag"),
    [([], "--version"), ([], "--debug"), (["bench"], "--quick"),
     (["identify"], "--physical"), (["campaign", "run"], "--resume")],
)  # fmt: skip
def test_help_shows_flags_without_a_value(command, flag):
    """A flag takes no value: its help row shows no "<bool>" (Typer's default display),
    which read as if ``--debug true`` were the way to set it."""
    res = runner.invoke(app, [*command, "--help"], terminal_width=200)
    assert res.exit_code == 0
    rows = [re.sub(r"[ │]+", " ", line).strip() for line in res.output.splitlines()]
    row = next(r for r in rows if r.startswith(flag + " "))
    assert "<bool>" not in row


def test_console_entry_freezes_the_objects_for_a_quick_exit(monkeypatch, capsys):
    """``pkmctl`` (pyproject's script and ``python -m pkmctl``) is ``cli.main``: the app,
    its exit status, then ``gc.freeze()``, so that the interpreter's shutdown does not
    collect every object again (docs/performance.md)."""
    import gc
    import tomllib
    from pathlib import Path

    from pkmctl import cli

    root = Path(__file__).resolve().parents[1]
    scripts = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts == {"pkmctl": "pkmctl.cli:main"}
    assert "main()" in (root / "src" / "pkmctl" / "__main__.py").read_text()
    import signal

    monkeypatch.setattr(sys, "argv", ["pkmctl", "--version"])
    signals = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    before = {sig: signal.getsignal(sig) for sig in signals}
    gc.unfreeze()
    try:
        with pytest.raises(SystemExit) as exit_:
            cli.main()
        frozen = gc.get_freeze_count()
        after = {sig: signal.getsignal(sig) for sig in signals}
    finally:
        gc.unfreeze()
        for sig, handler in before.items():
            signal.signal(sig, handler)
    assert exit_.value.code in (0, None)
    from pkmctl import _jit

    assert capsys.readouterr().out.strip() == (
        f"pkmctl {pkmctl.__version__} (sources {_jit.package_stamp()}, kernels "
        f"{_jit.source_stamp()})"
    )
    assert frozen > 10_000  # every object the imports made
    # its work done and said: a signal in the shutdown was a silent exit 130, or a
    # traceback of the atexit functions with exit 0 (a tester)
    assert set(after.values()) == {signal.SIG_IGN}


def test_scenario_help_describes_every_built_in():
    from pkmctl.cli import scenario
    from pkmctl.sim.scenario import BUILTINS

    described = scenario.__doc__.split("Built-in scenarios:", 1)[1]
    assert all(f"**{name}**" in described for name in BUILTINS), described


_PLUGIN = """
from typing import NamedTuple

import numpy as np

import pkmctl


class HalfPD(NamedTuple):
    kp: np.ndarray
    kd: np.ndarray

    @classmethod
    def from_context(cls, ctx):
        return cls(0.5 * ctx.gains.pd_kp, ctx.gains.pd_kd)


@pkmctl.register_controller("plugin-half-pd", params=HalfPD)
def half_pd(p, state, work, y, ref, F):
    for i in range(3):
        F[i] = p.kp[i] * (ref[i] - y[i]) + p.kd[i] * (ref[3 + i] - y[3 + i])
"""


def _names_in_worker() -> list[str]:
    from pkmctl.parts import names

    return list(names("controller"))


def test_plugin_registers_a_users_part_for_the_command_and_its_workers(tmp_path, monkeypatch):
    """`pkmctl --plugin FILE.py` imports the user's file first: its controller runs from the
    command line (it could not: parts.md's "import the module first" had no CLI form),
    and the worker processes pkmctl starts import it too."""
    (tmp_path / "half_pd.py").write_text(_PLUGIN)
    done = subprocess.run(
        [sys.executable, "-m", "pkmctl", "--plugin", str(tmp_path / "half_pd.py"), "simulate",
         "paper", "--controller", "plugin-half-pd", "--duration", "0.01", "--out",
         str(tmp_path / "out")],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    back = load_result(tmp_path / "out" / "plugin-half-pd.json")
    assert back.controller == "plugin-half-pd" and back.t.size == 200
    # a worker of this machine imports what PKMCTL_PLUGINS lists
    from pkmctl.plugins import ENV
    from pkmctl.sim.workers import spawn_pool

    monkeypatch.setenv(ENV, str(tmp_path / "half_pd.py"))
    with spawn_pool(1) as pool:
        assert "plugin-half-pd" in pool.submit(_names_in_worker).result(timeout=300)


def test_a_worker_that_cannot_import_a_plugin_says_so_and_lives(tmp_path, monkeypatch, capfd):
    """A plugin that failed in a worker broke the pool: tracebacks, then "a worker process
    died 4 times" (a code reader). The worker says why in one line; its runs then find
    no such part."""
    from pkmctl.plugins import ENV
    from pkmctl.sim.workers import spawn_pool

    (tmp_path / "gone_bad.py").write_text("raise RuntimeError('edited since')\n")
    monkeypatch.setenv(ENV, json.dumps([str(tmp_path / "gone_bad.py")]))
    with spawn_pool(1) as pool:
        assert "plugin-half-pd" not in pool.submit(_names_in_worker).result(timeout=300)
    err = capfd.readouterr().err
    assert (
        f"warning: a worker could not import a plugin: --plugin {tmp_path / 'gone_bad.py'}: "
        "RuntimeError: edited since (gone_bad.py, line 1: raise RuntimeError('edited since'))"
    ) in err.splitlines()
    assert "Traceback" not in err


def _refusal_in_worker(name: str) -> str:
    from pkmctl.campaign.execute import _imported
    from pkmctl.parts import PartError, get_part

    try:
        _imported({"controller": get_part("controller", name)})
    except PartError as exc:
        return str(exc)
    return "ran"


def test_a_part_whose_module_failed_in_the_worker_is_refused_with_that_reason(
    tmp_path, monkeypatch, capfd
):
    """A plugin that registered its part, then raised in the worker (a licence server
    the workers cannot reach): its runs said the part "raises RuntimeError ... (in the
    period starting at t = 0 s)", and each worker warned twice (a review)."""
    from pkmctl.plugins import ENV
    from pkmctl.sim.workers import spawn_pool

    name = "half_" + tmp_path.name.replace("-", "_")
    plugin = tmp_path / f"{name}.py"
    plugin.write_text(_PLUGIN.replace("plugin-half-pd", "plugin-half-in-worker")
                      + "import multiprocessing\nif multiprocessing.parent_process():\n"
                      "    raise RuntimeError('no licence server')\n")  # fmt: skip
    monkeypatch.setenv(ENV, json.dumps([str(plugin)]))
    with spawn_pool(1, (name,)) as pool:
        said = pool.submit(_refusal_in_worker, "plugin-half-in-worker").result(timeout=300)
    assert said.startswith(
        f"controller 'plugin-half-in-worker': this worker could not import its module {name}: "
        f"--plugin {plugin}: RuntimeError: no licence server ("
    ), said
    warned = [ln for ln in capfd.readouterr().err.splitlines() if ln.startswith("warning:")]
    assert len(warned) == 1, warned


def test_a_plugin_in_a_folder_whose_name_holds_a_path_separator_reaches_the_workers(
    tmp_path, monkeypatch
):
    """The plugins were recorded joined by os.pathsep: a folder named "col:on" split into
    two paths no worker could import, and a campaign ended in 16 tracebacks and "a worker
    process died 4 times" (a code reader)."""
    from pkmctl.plugins import ENV, load_plugins
    from pkmctl.sim.workers import spawn_pool

    folder = tmp_path / f"col{os.pathsep}on"
    folder.mkdir()
    name = "colon_" + tmp_path.name.replace("-", "_")
    (folder / f"{name}.py").write_text(_PLUGIN.replace("plugin-half-pd", "plugin-colon-pd"))
    monkeypatch.setenv(ENV, "")
    monkeypatch.setattr(sys, "path", list(sys.path))
    assert load_plugins([str(folder / f"{name}.py")]) == [str((folder / f"{name}.py").resolve())]
    with spawn_pool(1) as pool:
        assert "plugin-colon-pd" in pool.submit(_names_in_worker).result(timeout=300)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "--plugin {path}: no such file"),
        (
            "raise RuntimeError('boom')",
            "--plugin {path}: RuntimeError: boom (bad_plugin.py, line 1: raise "
            "RuntimeError('boom'))",
        ),
        # the place was lost with a message of several lines (a code reader)
        (
            "raise ValueError('first line\\nsecond line')",
            "--plugin {path}: ValueError: first line [...] (bad_plugin.py, line 1: raise "
            "ValueError('first line\\nsecond line'))",
        ),
        # pkmctl exited 0 having done nothing, or printed the plugin's argparse usage as
        # its own (a code reader)
        (
            "import sys\nsys.exit(0)",
            "--plugin {path}: the module called sys.exit(0) while it was imported (a "
            "script's argparse or main code at its top level? put it under if __name__ == "
            '"__main__":)',
        ),
        (
            "import argparse\nargparse.ArgumentParser().parse_args(['--foo'])",
            "--plugin {path}: the module called sys.exit(2) while it was imported (a "
            "script's argparse or main code at its top level? put it under if __name__ == "
            '"__main__":)',
        ),
    ],
)
def test_a_plugin_that_fails_is_one_line(tmp_path, content, message):
    path = tmp_path / "bad_plugin.py"
    if content is not None:
        path.write_text(content)
    res = runner.invoke(app, ["--plugin", str(path), "simulate", "paper"])
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    if "argparse" in (content or ""):  # its own usage lines first, then what they were
        assert lines[0].startswith("usage: ") and len(lines) == 3, lines
        lines = lines[-1:]
    assert lines == ["error: " + message.format(path=path)]


def test_a_plugin_module_in_the_current_folder_says_how_to_import_it(tmp_path, monkeypatch):
    """`pkmctl --plugin myparts` beside myparts.py: "No module named 'myparts'", as the
    command's import path does not hold the current folder (a tester)."""
    name = "parts_" + tmp_path.name.replace("-", "_")
    (tmp_path / f"{name}.py").write_text("x = 1\n")
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["--plugin", name, "scenario", "paper"])
    assert res.exit_code == 2, res.output
    assert res.output.strip() == (
        f"error: --plugin {name}: no module {name!r} on the import path, which does not hold "
        f"the current folder; give the file (--plugin ./{name}.py) or PYTHONPATH=."
    )


def test_a_file_named_as_a_built_in_scenario_is_not_passed_over(tmp_path, monkeypatch):
    """`pkmctl scenario paper > paper`, edited, then `pkmctl simulate paper` ran the
    built-in without a word (a tester). The two are told apart in one line."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "paper").write_text(pkmctl.Scenario.builtin("paper").to_toml())
    res = runner.invoke(app, ["simulate", "paper", "--duration", "0.01", "--out", "o"])
    assert res.exit_code == 2, res.output
    assert res.output.strip() == (
        "error: 'paper' names both a built-in scenario and a file here: give ./paper for the "
        "file (or rename it to .toml)"
    )
    assert not (tmp_path / "o").exists()
    res = runner.invoke(app, ["simulate", "./paper", "--duration", "0.01", "--out", "o"])
    assert res.exit_code == 0, res.output


def test_simulate_in_a_log_says_how_far_it_is(tmp_path):
    """An hour's run at 20 kHz was silent for 81 s when its stderr was a log (a tester);
    a log gets a line every 10 % (or minute), and one when the files are written."""
    res = subprocess.run(
        [sys.executable, "-m", "pkmctl", "simulate", "paper", "--controller", "pd",
         "--duration", "1", "--out", str(tmp_path / "o")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("simulating pd on 'paper': ")]
    assert len(lines) >= 5 and " of 20,000 periods (10 %)" in lines[0], res.stderr
    assert "writing pd.parquet" in res.stderr
    # the rate and the time left, once the loop has run a while (a 27-day run said
    # "(0 %)" and nothing more: a tester)
    assert re.search(r"\(\d+ %\), [\d,]+ periods/s, about [\d.]+ s left$", lines[-1]), lines


def test_a_long_run_is_estimated_before_it_starts(tmp_path, monkeypatch):
    from pkmctl import cli
    from pkmctl.sim import cost

    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["simulate", "paper", "--duration", "0.01", "--out", "o"])
    assert res.exit_code == 0 and "estimated" not in res.stderr, res.stderr
    monkeypatch.setattr(cli, "LONG_RUN_S", 0.0)
    res = runner.invoke(app, ["simulate", "prototype", "--duration", "0.01", "--out", "o"])
    assert res.exit_code == 0, res.stderr
    est = cost.PERIOD["single"] + 9 * cost.SUBSTEP["single"] * cost.DRIVE + cost.ENCODER["single"]
    line = next(ln for ln in res.stderr.splitlines() if "estimated" in ln)
    assert line == (
        "simulating afsmc on 'prototype': 10 periods of 10 RK4 sub-steps, estimated "
        f"{10 * est + cost.RUN['single']:.1f} s on a machine like ours (Ctrl-C stops it; "
        "timing.duration, .control_period and .substeps set its length)"
    )


def test_a_write_error_names_the_file_by_its_final_name():
    """reproduce on a full disk named a file two staging folders deep (its own and the
    library's, inside it: a tester); the line names the file as it would have been."""
    from pathlib import Path

    from pkmctl.cli import _final_path

    stage, out = Path("/d/.pkmctl-7@h-x1.tmp"), Path("/d/r")
    inner = f"{stage}/.pkmctl-7@h-y2.tmp/timeseries/smc.parquet"
    assert _final_path(inner, stage, out) == "/d/r/timeseries/smc.parquet"
    assert _final_path(f"{stage}/pd.json", stage, out) == "/d/r/pd.json"
    assert _final_path("/elsewhere/x", stage, out) == "/elsewhere/x"


def test_a_terminal_that_is_not_utf8_gets_the_results_and_no_traceback(tmp_path):
    """Under LANG=C (or PYTHONIOENCODING=ascii) the "°" of the RMSE table's header was a
    UnicodeEncodeError traceback, exit 1, after the files were written; and pyarrow,
    which takes a path as UTF-8, could neither write nor read a table in a folder named
    in another script ("s é": the log called "binary data" by identify)."""
    import os

    env = {k: v for k, v in os.environ.items() if not k.startswith("LC_")}
    env.update(LANG="C", LC_ALL="C", PYTHONUTF8="0", PYTHONCOERCECLOCALE="0",
               PYTHONIOENCODING="ascii")  # fmt: skip

    def run(*args):
        return subprocess.run([sys.executable, "-m", "pkmctl", *args], capture_output=True,
                              text=True, cwd=tmp_path, env=env, encoding="utf-8",
                              errors="surrogateescape")  # fmt: skip

    r = run("simulate", "prototype", "--controller", "pd", "--duration", "0.05", "--out", "s é")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "alpha deg" in r.stdout and "wrote s \\udcc3\\udca9/pd.parquet" in r.stdout, r.stdout
    folder = tmp_path / "s é"
    assert sorted(p.name for p in folder.iterdir()) == ["pd.json", "pd.parquet"]
    assert load_result(folder / "pd.json").t.size == 50  # 1 kHz
    r = run("identify", "s é/pd.parquet", "--out", "id")  # read: it is too short
    assert r.returncode == 2 and "too short for --cutoff" in r.stderr, r.stderr


@pytest.mark.parametrize(("term", "live"), [("xterm-256color", True), ("dumb", False)])
def test_a_dumb_terminal_gets_the_plain_progress_lines(term, live):
    """TERM=dumb on a terminal showed no progress at all (rich draws no live bar there)
    and hid the compile lines: it gets the plain lines a log gets (a tester)."""
    import os
    import pty

    leader, follower = pty.openpty()
    try:
        r = subprocess.run(
            [sys.executable, "-c", "from pkmctl.cli import err_console as e; print(e.is_terminal)"],
            stdout=subprocess.PIPE, stderr=follower, text=True, check=True,
            env={**os.environ, "TERM": term},
        )  # fmt: skip
    finally:
        os.close(leader)
        os.close(follower)
    assert r.stdout.strip() == str(live)


def test_a_home_matplotlib_cannot_write_in_is_no_warning(tmp_path):
    """A HOME that cannot be written: matplotlib printed a warning of two lines (with the
    advice to set MPLCONFIGDIR) beside pkmctl's own one-line warning (a tester). The
    command gives it a temporary folder, removed at exit. (~/.config is a file here, which
    no user can make a folder in, root included.)"""
    import os

    home = tmp_path / "home"
    home.mkdir()
    (home / ".config").write_text("a file")
    code = (
        "import os\nfrom pkmctl.cli import _quiet_matplotlib_home\n_quiet_matplotlib_home()\n"
        "import matplotlib, matplotlib.font_manager\nprint(os.environ['MPLCONFIGDIR'])\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MPLCONFIGDIR", "XDG_CONFIG_HOME",
                                                            "XDG_CACHE_HOME")}  # fmt: skip
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                       env={**env, "HOME": str(home)})  # fmt: skip
    assert r.stderr == "", r.stderr
    assert "pkmctl-matplotlib-" in r.stdout and not os.path.exists(r.stdout.strip())


def test_simulate_says_when_the_drives_spent_time_at_their_limits(tmp_path):
    """Drives without torque (peak_torque = 1e-300) sank the platform 38 mm, and simulate
    showed only the error table: the time at the force limit was in the JSON alone (a
    fuzzer). A line says it beside the table when it passes 1 % of the run."""
    res = runner.invoke(app, ["simulate", "prototype", "--controller", "pd", "--duration",
                              "0.2", "--out", str(tmp_path / "p")])  # fmt: skip
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "p" / "pd.json").read_text())["metrics"]
    force, speed = meta["time_at_force_limit_s"], meta["time_over_speed_limit_s"]
    assert force > 0.002 and speed > 0.002  # the transient, on the prototype's drives
    out = " ".join(res.stdout.split())
    assert (
        f"note: the drives were at their force limit for {force:.3g} s of the 0.2 s run "
        f"({100 * force / 0.2:.0f} %; time_at_force_limit_s in the JSON's metrics)"
    ) in out
    assert f"over their speed limit for {speed:.3g} s of the 0.2 s run" in out
    res = runner.invoke(app, ["simulate", "paper", "--controller", "pd", "--duration", "0.2",
                              "--out", str(tmp_path / "q")])  # fmt: skip
    assert res.exit_code == 0 and "note:" not in res.stdout, res.stdout
    # ideal actuators with a force limit have no drives (a code reader)
    sc = tmp_path / "fl.toml"
    sc.write_text(pkmctl.Scenario.builtin("paper").replace(**{"actuators.force_limit": 100.0})
                  .to_toml())  # fmt: skip
    res = runner.invoke(app, ["simulate", str(sc), "--controller", "pd", "--duration", "0.2",
                              "--out", str(tmp_path / "r")])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "note: the actuators were at their force limit for " in " ".join(res.stdout.split())


def test_help_in_a_narrow_terminal_cuts_nothing():
    """At 40 columns the help cut option names and defaults with "…" (`--max-residu…`,
    `[default: pkmctl-o…`: 106 cut lines over the help pages, a tester)."""
    import os

    env = {**os.environ, "COLUMNS": "40"}
    for command in (["identify"], ["simulate"], ["campaign", "run"], ["excite"], ["bench"]):
        r = subprocess.run([sys.executable, "-m", "pkmctl", *command, "--help"], env=env,
                           capture_output=True, text=True, check=True)  # fmt: skip
        assert "…" not in r.stdout, (command, r.stdout)


def test_reproduce_removes_a_table_in_the_other_format_of_its_runs(tmp_path):
    """reproduce into a folder holding timeseries/pd.csv (an earlier run's, saved as CSV)
    left it beside the new pd.json, which describes pd.parquet (a tester); simulate
    removed it. Other files there stay."""
    from pkmctl.experiment import reproduce

    ts = tmp_path / "out" / "timeseries"
    ts.mkdir(parents=True)
    (ts / "pd.csv").write_text("t\n0.0\n")
    (ts / "mine.csv").write_text("kept\n")
    reproduce(pkmctl.Scenario.builtin("paper", 0.05), tmp_path / "out")
    assert not (ts / "pd.csv").exists() and (ts / "mine.csv").read_text() == "kept\n"
    assert (ts / "pd.parquet").is_file() and (ts / "pd.json").is_file()
