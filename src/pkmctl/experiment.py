"""The paper's experiment end to end: three controllers, Table 4, Figures 10-26, report.

:func:`reproduce` is what ``pkmctl reproduce`` calls; it writes into ``out``:

- ``table4.csv`` and ``table4.md`` (ours beside the paper's Table 4),
- ``figures/fig10.png`` ... ``fig26.png``,
- ``report.md`` (the table, the figures and a discussion computed from the numbers),
- ``timeseries/<controller>.parquet`` and ``.json`` (every control sample, scenario,
  metrics; see :mod:`pkmctl.io.results`).

The files are written into a staging folder and moved into ``out`` when all are
complete (:func:`pkmctl.io.atomic.staged_folder`): a failed or interrupted run leaves
the previous results untouched and no partial set. ``out`` is checked, and the memory
the five runs need, before anything is computed.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pkmctl import _jit  # (so spelled: this module holds no compiled code)
from pkmctl.io.atomic import atomic_write, check_output_folder, staged_folder
from pkmctl.io.results import remove_other_formats, save_result
from pkmctl.sim.loop import is_compiled
from pkmctl.sim.result import Result
from pkmctl.sim.scenario import Scenario, ScenarioError
from pkmctl.sim.simulate import (
    check_memory,
    disturbance_count,
    memory_needed,
    part_memory,
    precompile,
    prepare,
    resolve_parts,
    run_prepared,
)

__all__ = ["CONTROLLER_ORDER", "ReproduceOutput", "reproduce"]

#: The controllers ``pkmctl reproduce`` runs: the paper's three and the two baselines.
CONTROLLER_ORDER = ("smc", "fsmc", "afsmc", "pd", "ctc")
#: Columns of the largest controller log among them (AFSMC's Theta^).
_MAX_CONTROLLER_LOG = 36


@dataclass(frozen=True)
class ReproduceOutput:
    """What :func:`reproduce` produced: the results and the files written."""

    results: dict[str, Result]
    files: list[Path]
    wall_time_s: float
    #: Where the wall time went (s): ``"before"`` the runs (checks, compiling or loading
    #: the loops), ``"runs"`` (the five runs, two or more at a time, each one's time
    #: series written as it ends), ``"loops"`` (the sum of the runs' compiled-loop
    #: times, on however many cores), ``"figures"`` (from the end of the runs until the
    #: figures and the machine's images are written), ``"report"`` (the rest).
    phases: dict[str, float] = field(default_factory=dict)
    #: What the user should hear of beside the results: why the machine has no pictures
    #: (MuJoCo, or an offscreen GL backend, missing; report.md says it too).
    notes: list[str] = field(default_factory=list)


#: The poses :func:`_machine_images` renders, by name (figures/machine_<name>.png).
MACHINE_POSES = ("home", "largest-tilt", "end")


def reproduce_writes() -> list[str]:
    """Every path, relative to the output folder, that :func:`reproduce` writes (a
    folder's ending in "/"): checked before any work (a file named ``timeseries`` there
    was refused only after all the runs and figures)."""
    from pkmctl.report.figures import FIGURES

    return [
        "timeseries/",
        "figures/",
        "table4.csv",
        "table4.md",
        "report.md",
        *(f"timeseries/{c}.{ext}" for c in CONTROLLER_ORDER for ext in ("parquet", "json")),
        *(f"figures/{spec.filename}" for spec in FIGURES),
        *(f"figures/machine_{name}.png" for name in MACHINE_POSES),
    ]


def check_samples(scenario: Scenario) -> None:
    """Refuse a scenario whose runs log fewer than 2 rows: the figures draw each run over
    time (a 1-sample run failed only after all five runs, in the figures)."""
    t, every = scenario.timing, scenario.logging.every
    n = t.periods
    rows = -(-n // every)
    if rows >= 2:
        return
    fix = f"timing.duration >= {(every + 1) * t.control_period:.6g} s"
    if every > 1:
        fix += f", or logging.every <= {max(1, n - 1)}"
    raise ScenarioError(
        f"timing.duration = {t.duration!r}: reproduce draws each run over time and needs 2 "
        f"logged samples at least, this logs {rows} ({n} control period"
        f"{'s' * (n != 1)} of {t.control_period:g} s"
        f"{f', one row every {every}' if every > 1 else ''}); allowed: {fix}"
    )


def reproduce(
    scenario: Scenario,
    out: Path,
    *,
    seed: int | None = None,
    duration: float | None = None,
    progress: Callable[[str], None] | None = None,
    run_progress: Callable[[int, int], None] | None = None,
) -> ReproduceOutput:
    """Run SMC, FSMC, AFSMC and the baselines PD and CTC on ``scenario``; write the tables,
    figures and report. ``progress(message)`` is called at each step;
    ``run_progress(periods done, periods)`` of the five runs together as they compute (from
    their threads)."""
    from pkmctl.report import figures, tables

    from .report.document import render_report

    say = progress or (lambda _msg: None)
    t0 = time.perf_counter()
    out = check_output_folder(out, writes=reproduce_writes())
    if not isinstance(scenario, Scenario):
        raise TypeError(f"scenario: expected a pkmctl.Scenario, got {scenario!r}")
    if duration is not None:
        scenario = scenario.replace(**{"timing.duration": float(duration)})
    check_samples(scenario)
    n = scenario.timing.periods
    # All five runs' results are kept for the tables and figures: they must fit together.
    runs = len(CONTROLLER_ORDER)
    every = scenario.logging.every

    def need(e: int) -> int:
        return memory_needed(n, _MAX_CONTROLLER_LOG, runs=runs, every=e, sensor_log=4,
                             part_values=part_memory(scenario),
                             disturbance_values=disturbance_count(scenario),
                             saved=True)  # fmt: skip

    check_memory(need(every), f"reproduce ({runs} runs of {scenario.timing.duration:g} s)",
                 decimated=need, every=every, periods=n)  # fmt: skip

    def compiling(todo: list[str], n: int) -> None:
        say(f"compiling {len(todo)} control loops in {n} processes (once per machine)…")

    if not precompile(scenario, CONTROLLER_ORDER, on_start=compiling):
        # (precompile leaves a single missing loop to its run: "found in the cache" then
        # compiled it unsaid, a minute on a cold one)
        missing = [c for c in CONTROLLER_ORDER if not is_compiled(resolve_parts(scenario, c))]
        if not _jit.cache_writable():
            say("no compile cache: each run compiles its loop")
        elif missing:
            say(f"compiling the control loop of {', '.join(missing)} as it runs (once per "
                "machine)…")  # fmt: skip
        else:
            say("compiled loops found in the cache")
    with staged_folder(out) as stage:
        names: list[Path] = []

        def keep(res: Result) -> None:  # written while the other runs compute
            names.extend(save_result(res, stage / "timeseries"))

        t_runs = time.perf_counter()
        results = _run_all(scenario, seed, say, keep, run_progress)
        t_figures = time.perf_counter()
        say("drawing figures 10-26")
        job = figures.start_figures(results, stage / "figures")  # in other processes
        try:
            say("writing Table 4")
            for fname, text in (
                ("table4.csv", tables.table4_csv(results)),
                ("table4.md", tables.table4_markdown(results)),
            ):
                with atomic_write(stage / fname) as fh:
                    fh.write(text)
                names.append(stage / fname)
            say("rendering the machine")
            images, note = _machine_images(results, stage / "figures")
            names += [p[0] for p in images]
            figs = job.wait()
        except BaseException:
            job.cancel()
            raise
        names += figs
        t_report = time.perf_counter()
        say("writing report")
        wall = time.perf_counter() - t0
        report = render_report(
            results,
            figures=[f.relative_to(stage) for f in figs],
            scenario_name=next(iter(results.values())).scenario.name,
            wall_time_s=wall,
        )
        report += _machine_section(images, note, stage)
        with atomic_write(stage / "report.md") as fh:
            fh.write(report)
        names.append(stage / "report.md")
        files = [out / p.relative_to(stage) for p in names]
    for c in CONTROLLER_ORDER:  # an earlier run's table in the other format, beside the
        remove_other_formats(out / "timeseries", c, "parquet")  # json of this one
    t_end = time.perf_counter()
    phases = {
        "before": t_runs - t0,
        "runs": t_figures - t_runs,
        "loops": sum(float(r.info.get("kernel_seconds", 0.0)) for r in results.values()),
        "figures": t_report - t_figures,
        "report": t_end - t_report,
    }
    return ReproduceOutput(results=results, files=files, wall_time_s=t_end - t0, phases=phases,
                           notes=[] if images else [note])  # fmt: skip


def _run_all(
    scenario: Scenario, seed: int | None, say: Callable[[str], None],
    done: Callable[[Result], None], run_progress: Callable[[int, int], None] | None = None,
) -> dict:  # fmt: skip
    """The runs, two or more at a time; ``done`` is called on each (in order) while the
    later ones compute; ``run_progress`` with the periods done of all of them."""
    # The compiled loop releases the GIL: the runs share the machine's cores.
    workers = min(len(CONTROLLER_ORDER), os.cpu_count() or 1)
    prep = prepare(scenario, None)  # the desired trajectory, once for the five runs
    parts = {name: resolve_parts(prep.scenario, name) for name in CONTROLLER_ORDER}
    periods, lock = dict.fromkeys(CONTROLLER_ORDER, 0), threading.Lock()

    def reporter(name: str) -> Callable[[int, int], None] | None:
        if run_progress is None:
            return None

        def report(done: int, total: int) -> None:
            with lock:  # (two runs' reports in order: the sum never goes back)
                periods[name] = done
                run_progress(sum(periods.values()), total * len(periods))

        return report

    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = {
            name: pool.submit(run_prepared, prep, parts[name], seed, progress=reporter(name))
            for name in CONTROLLER_ORDER
        }
        try:
            results: dict[str, Result] = {}
            for name in CONTROLLER_ORDER:
                say(f"simulating {name}")
                results[name] = futures[name].result()
                done(results[name])
        except BaseException:
            for f in futures.values():  # a failed run: start no more of them
                f.cancel()
            raise
    return results


def _machine_images(results: dict[str, Result], folder: Path) -> tuple[list[Path], str]:
    """MuJoCo images of the AFSMC run at home (t = 0), at its largest tilt and at the end;
    ([], the one-line reason) where MuJoCo or an offscreen GL backend is missing."""
    try:
        from pkmctl.plants.mujoco import render_poses
    except ImportError as exc:
        return [], f"No images of the machine: {exc}."
    res = results.get("afsmc") or next(iter(results.values()))
    # the platform normal's angle from vertical: R = Rx(alpha) Ry(beta) takes e_z to
    # (sin b, -sin a cos b, cos a cos b) (|a| + |b| picked 29.6 deg over 30.0 here)
    tilt = np.arccos(np.clip(np.cos(res.X[:, 1]) * np.cos(res.X[:, 2]), -1.0, 1.0))
    picks = dict(zip(MACHINE_POSES, (0, int(np.argmax(tilt)), res.t.size - 1), strict=True))
    try:
        images = render_poses(res.scenario.plant(), res.X[list(picks.values())])
    except RuntimeError as exc:
        return [], f"No images of the machine: {exc}."
    import matplotlib.image

    paths = []
    for (name, k), im in zip(picks.items(), images, strict=True):
        path = folder / f"machine_{name}.png"
        with atomic_write(path, "wb") as fh:
            matplotlib.image.imsave(fh, im, format="png")
        paths.append((path, name, float(res.t[k]), res.X[k]))
    return paths, f"{res.controller.upper()} run, drawn by MuJoCo (pkmctl.plants.mujoco)."


def _machine_section(images, note: str, out: Path) -> str:
    lines = ["", "## The machine", "", note, ""]
    for path, name, t, X in images:
        a, b = (round(float(v), 1) + 0.0 for v in np.degrees(X[1:3]))  # + 0.0: no "-0.0"
        x = f"z = {X[0]:.3f} m, alpha = {a:.1f} deg, beta = {b:.1f} deg"
        lines.append(f"![{name}]({path.relative_to(out).as_posix()}) {name}, t = {t:.3f} s: {x}")
        lines.append("")
    return "\n".join(lines)
