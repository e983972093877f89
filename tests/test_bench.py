"""`pkmctl bench --quick` runs once as a smoke test. Timing is never asserted here."""

import json
import shutil
import tempfile
from pathlib import Path

from typer.testing import CliRunner

from benchmarks.bench import render, rows, user_law_file
from benchmarks.flops import count
from pkmctl.cli import app


def test_bench_quick_smoke(tmp_path):
    out = tmp_path / "bench.json"
    before = set(Path(tempfile.gettempdir()).glob("pkmctl-bench-*"))
    res = CliRunner().invoke(app, ["bench", "--quick", "--json", str(out)])
    assert res.exit_code == 0, res.output
    # the user's my_law.py is kept in the cache folder: a run left a folder in /tmp
    assert not set(Path(tempfile.gettempdir()).glob("pkmctl-bench-*")) - before
    data = json.loads(out.read_text())
    assert set(data["steps"]) == {"smc", "fsmc", "afsmc", "pd", "ctc", "my-law"}
    assert data["mujoco"]["steps_per_s"] > 0  # the test command installs MuJoCo
    labels = [r[0] for r in rows(data)]
    for label in (
        "MuJoCo RK4 (same step), open loop",
        "MuJoCo Euler (same step), open loop",
        "MuJoCo RK4 + AFSMC from Python",
        "AFSMC loop, plant.kind = mujoco",
    ):
        assert label in labels
    # each ratio is a median of rounds in which both sides are timed alternately (they
    # were timed a minute apart: a tester)
    assert labels.count("  closed-form AFSMC loop / this") == 4  # (--quick: one round)
    assert data["mujoco"]["rounds"] == 1 and data["mujoco"]["ratio_steps_per_s"] > 0
    assert data["flops"]["rounds"] == 1
    judged = [r[2] for r in rows(data) if r[0] == "  closed-form AFSMC loop / this"]
    assert judged == ["≥ 20 x", "", "≥ 20 x", ""]  # RK4 and AFSMC from Python: issue 16.2
    many = dict(data, mujoco=dict(data["mujoco"], rounds=3))
    assert "  closed-form AFSMC loop / this, median of 3 rounds" in [r[0] for r in rows(many)]
    targets = {r[0]: r[2] for r in rows(data)}
    assert targets["  share of scalar peak (>100 %: 4-wide limbs)"] == "≥ 75 %"
    assert targets["  afsmc step, time/flop ÷ plant's"] == "≤ 1.5 x"
    assert targets["  ÷ its 5 runs' loops, summed"] == "≤ 1.5 x"
    assert data["machine"]["cpu"] not in ("", "x86_64")  # the processor's name
    assert "[14/14]" in res.output  # progress: each section counted, with the time so far
    assert "  user's my-law / built-in pd" in labels
    pr = data["prototype"]  # issue 10: the prototype loop beside the ideal one
    assert pr["ideal_substeps_per_s"] > 0 and pr["prototype_substeps_per_s"] > 0
    assert pr["ratio"] == pr["prototype_substeps_per_s"] / pr["ideal_substeps_per_s"]
    for label in (
        "PD loop 1 kHz, ideal machine",
        "PD loop 1 kHz, prototype",
        "  prototype / ideal",
    ):
        assert label in labels
    assert {r[0]: r[2] for r in rows(data)}["  prototype / ideal"] == "≥ 0.5 x"
    enc = data["encoder"]  # issue 10: the encoder's measure from compiled code, warm
    assert enc["measure_us"] > 0 and enc["samples"] > 0
    assert {r[0]: r[2] for r in rows(data)}["encoder measure, compiled, warm"] == "≤ 1.0 us"
    assert data["flc"]["compiled_us"] > 0 and data["batch"]["workers"] >= 1
    assert data["flc"]["term_us"] > 0 and data["flc"]["term_general_us"] > 0  # issue 15
    assert "FLC as FSMC's fuzzy term (term_eval)" in labels
    assert data["flops"]["flops_per_step"] > data["flops"]["plant_eval_flops"] * 4
    assert data["reproduce"]["warm_s"] > 0
    fc = data["fis_corpus"]  # issue 15.4: the corpus's 81-rule file beside its peers
    assert "skipped" in fc or fc["pkmctl_exact_us"] > 0  # timed, never judged here
    assert "skipped" in fc or max(fc["skfuzzy_max_diff"], fc["fuzzylite_max_diff"]) < 1e-6
    assert data["identify"]["seconds"] > 0 and data["identify"]["used"] > 0
    camp = data["campaign"]  # issue 11: campaign speed, side by side in one run
    assert camp["one_worker"]["wall_s"] > 0 and camp["two_workers"]["work_s"] > 0
    assert camp["dask"]["wall_s"] > 0 and 0 < camp["overhead"]["overhead_fraction"] < 1
    assert camp["ceiling"]["ratio"] > 0
    targets = {r[0]: r[2] for r in rows(data)}
    assert targets["  2 workers / 1, start excluded"] == "≥ 1.8 x"
    assert targets["  Dask / local, start excluded"] == "≥ 0.9 x"
    assert targets["campaign: cost outside the loop"] == "< 10 %"
    assert "≥ 200,000 steps/s" in res.output  # the table, with its targets
    # the targets are judged only in full mode: a slow loop is flagged, a fast one passes
    slow = dict(data, quick=False)
    slow["steps"] = {k: dict(v, loop_steps_per_s=150_000.0) for k, v in data["steps"].items()}
    fast = dict(
        slow, steps={k: dict(v, loop_steps_per_s=250_000.0) for k, v in slow["steps"].items()}
    )
    held = {r[0]: r[3] for r in rows(slow)}
    assert held["closed loop afsmc, one core"] == "NO"
    assert {r[0]: r[3] for r in rows(fast)}["closed loop afsmc, one core"] == "yes"
    assert {r[0]: r[3] for r in rows(data)}["closed loop afsmc, one core"] == "-"
    assert render(slow).splitlines()[1].split() == ["measurement", "result", "target", "held"]


def test_bench_runs_only_this_pkmctls_benchmarks(tmp_path, monkeypatch):
    """`pkmctl bench` ran any benchmarks/bench.py of the current folder (another project's,
    an older checkout's) before its own (a tester)."""
    import sys

    import benchmarks
    from pkmctl import cli

    fake = tmp_path / "benchmarks"
    fake.mkdir()
    (fake / "__init__.py").write_text("")
    (fake / "bench.py").write_text("raise SystemExit('the foreign bench ran')\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [str(tmp_path), *sys.path])
    ours = Path(benchmarks.__file__).resolve().parent
    cli._import_benchmarks()
    import benchmarks.bench as found

    assert Path(found.__file__).resolve().parent == ours


def test_user_law_file_kept_by_its_text(tmp_path, monkeypatch):
    # one file per text of docs/parts.md's block, in the cache root, written once (a
    # temporary folder per run was never removed: 65 piled up in /tmp)
    monkeypatch.setenv("PKMCTL_CACHE_DIR", str(tmp_path / "cache"))
    file = user_law_file()
    assert file.name == "my_law.py" and file.parent.parent == tmp_path / "cache" / "bench"
    code = file.read_text(encoding="utf-8")
    assert code.startswith("# my_law.py") and "register_controller" in code
    written = file.stat().st_mtime_ns
    assert user_law_file() == file and file.stat().st_mtime_ns == written
    file.write_text("# damaged", encoding="utf-8")
    assert user_law_file().read_text(encoding="utf-8") == code
    # a cache root that cannot be written: a temporary folder (removed at exit)
    (tmp_path / "a-file").write_text("")
    monkeypatch.setenv("PKMCTL_CACHE_DIR", str(tmp_path / "a-file" / "cache"))
    other = user_law_file()
    assert other.read_text(encoding="utf-8") == code
    shutil.rmtree(other.parent)


def test_flop_counter_counts_what_it_should():
    # The 3x3 L D L^T solve counted by hand, statement by statement (a conditional
    # expression counts its costlier branch, its comparison nothing):
    n = count("cholesky_solve3")
    # r0 /, l10 *, l20 *, d1 (*, -), r1 /, t21 (*, -), l21 *, d2 (*, *, -, -), r2 /,
    # z1 (*, -), z2 (*, *, -, -), x2 *, x1 (*, *, -), x0 (*, *, *, -, -)
    assert n == 1 + 1 + 1 + 2 + 1 + 2 + 1 + 4 + 1 + 2 + 4 + 1 + 3 + 5


def test_every_script_and_benchmark_answers_help_without_running():
    """Four documented scripts ran their whole measurement, minutes of it, when given
    --help (a tester). Each of scripts/ and benchmarks/ run as a program answers --help
    with its usage; one interpreter runs them all (its imports once), a minute at most."""
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    files = sorted(str(f) for d in ("scripts", "benchmarks") for f in (root / d).glob("*.py")
                   if "__main__" in f.read_text(encoding="utf-8"))  # fmt: skip
    assert len(files) >= 15
    code = (
        "import contextlib, io, runpy, sys\n"
        "for path in sys.argv[1:]:\n"
        "    sys.argv, out = [path, '--help'], io.StringIO()\n"
        "    with contextlib.redirect_stdout(out):\n"
        "        try:\n"
        "            runpy.run_path(path, run_name='__main__')\n"
        "        except SystemExit as exc:\n"
        "            assert exc.code in (0, None), (path, exc.code)\n"
        "    assert out.getvalue().startswith('usage: '), (path, out.getvalue()[:300])\n"
        "print('ok', len(sys.argv))\n"
    )
    env = dict(os.environ, PYTHONPATH=str(root))
    res = subprocess.run([sys.executable, "-c", code, *files], capture_output=True, text=True,
                         cwd=root, env=env, timeout=120)  # fmt: skip
    assert res.returncode == 0 and res.stdout.startswith("ok"), res.stderr[-2000:]
