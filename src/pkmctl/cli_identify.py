"""``pkmctl excite`` and ``pkmctl identify`` (DESIGN.md §9), registered on the app of
:mod:`pkmctl.cli` (imported there), with its one-line errors and Ctrl-C handling.

    pkmctl excite [--scenario NAME|FILE] [--out FILE] [--harmonics H] [--base-frequency F]
    pkmctl identify LOG [--out DIR] [--scenario NAME|FILE] [--validate LOG2] [--cutoff HZ]
                    [--force-lead auto|SECONDS] [--physical/--no-physical]
                    [--max-residual PERCENT]
"""

from __future__ import annotations

import json
import math
import shlex
import warnings
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table
from rich.text import Text

from pkmctl.cli import (
    _KEPT,
    _SCENARIO_NAMES,
    _Compiles,
    _debug,
    _fail,
    _fraction_bar,
    _handle,
    _interruptible,
    _kept,
    _load_scenario,
    _say,
    _untouched,
    app,
    console,
    err_console,
)


def _table_of(log: Path) -> Path:
    """The table a pkmctl .json names (``read_log`` follows it), else ``log``: the .json
    beside ``RUN/pd.json`` is itself, which names pd.parquet, so the run's scenario and its
    force-lead default were taken for another table's and dropped (a code reader)."""
    if log.suffix.lower() != ".json" or not log.is_file():
        return log
    try:
        return log.with_name(json.loads(log.read_text(encoding="utf-8"))["table"])
    except (OSError, ValueError, KeyError, TypeError):
        return log  # (read_log says what it is not)


def _beside(log: Path) -> str:
    """The text of the .json beside ``log``; OSError if it is not a regular file (a FIFO
    named LOG.json blocked the read for ever: a code reader)."""
    meta = log.with_suffix(".json")
    if not meta.is_file():
        raise FileNotFoundError(meta)
    return meta.read_text(encoding="utf-8")


def _metadata_scenario(log: Path) -> str | None:
    """The scenario (TOML text) of pkmctl's metadata beside ``log`` (its .json); None if
    there is none, or the .json is not pkmctl's. The text ends with a line break, so that
    ``Scenario.from_toml`` reads it as text (one line of it was read as a file's name)."""
    try:
        meta = json.loads(_beside(log))
        text = meta["scenario_toml"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if _other_table(log) is not None:  # another table's metadata: not this log's machine
        return None
    return text + "\n" if isinstance(text, str) else None


def _other_table(log: Path) -> str | None:
    """The table pkmctl's .json beside ``log`` describes, when that is not ``log`` (a
    pd.csv saved after pd.parquet: the json is the csv's run, which may be another
    machine's, and it labelled the parquet's run or refused it, blaming the data)."""
    try:
        table = json.loads(_beside(log))["table"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return table if isinstance(table, str) and table != log.name else None


def _other_machine(log: Path, assumed) -> str:
    """Why a pkmctl log (its .json) is of another machine than the scenario ``assumed``
    (its mechanism, plant or payload differ), or "" (the same, or no pkmctl .json)."""
    from pkmctl.sim.scenario import Scenario

    text = _metadata_scenario(log)
    try:
        sc = Scenario.from_toml(text) if text is not None else None
    except Exception:  # (its own error would be the log's, not the validation's)
        return ""
    sections = ("mechanism", "plant_spec", "payload")
    differ = [n for n in sections if sc is not None and getattr(sc, n) != getattr(assumed, n)]
    if not differ:
        return ""
    names = ", ".join("plant" if n == "plant_spec" else n for n in differ)
    return (
        f"its .json is of scenario {sc.name!r}, whose {names} "
        f"{'differ' if len(differ) > 1 else 'differs'} from the scenario "
        f"assumed ({assumed.name!r}): the validation error compares two machines"
    )


def _scenario_for(ctx: typer.Context, spec: str | None, log: Path | None):
    """The named scenario; else the one beside a pkmctl log (its .json); else prototype;
    and a label saying which and where it came from (for errors and the report). A .json
    beside the log that is pkmctl's metadata but whose scenario cannot be read is refused
    (the log is another machine's than the default: guessing it would give a wrong model);
    one that is not pkmctl's metadata is said so in the label."""
    why_not = "no pkmctl .json beside the log"
    if spec is None and log is not None:
        meta = log.with_suffix(".json")
        if meta.is_file():
            from pkmctl.sim.scenario import Scenario

            text = _metadata_scenario(log)
            if (other := _other_table(log)) is not None:
                why_not = f"{str(meta)!r} beside the log describes {other!r}, not this log"
            elif text is None:  # not pkmctl's metadata: fall back to the default
                why_not = f"{str(meta)!r} beside the log is not pkmctl's metadata"
            else:
                try:
                    sc = Scenario.from_toml(text)
                except Exception as exc:  # ScenarioError, a TOML error: one line
                    first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                    _fail(
                        f"log {str(log)!r}: the pkmctl metadata beside it, {str(meta)!r}, holds "
                        f"a scenario that cannot be read ({first}); give the machine's "
                        "--scenario"
                    )
                return sc, f"scenario {sc.name!r} (from {str(meta)!r}, beside the log)"
    try:
        sc = _interruptible(lambda: _load_scenario(spec or "prototype"), lambda: "nothing done")
    except Exception as exc:
        _handle(ctx, exc)
    if spec is None:
        return sc, f"scenario {sc.name!r} (the default: no --scenario and {why_not})"
    return sc, f"scenario {sc.name!r} (--scenario {spec})"


def _as_options(message: str) -> str:
    """The library's keywords (``cutoff``, ``force_lead``, ``max_residual``) as the
    command's options."""
    message = message.replace("force_lead = auto", "--force-lead auto")
    for word, option in (("cutoff", "--cutoff"), ("force_lead", "--force-lead"),
                         ("max_residual", "--max-residual")):  # fmt: skip
        message = message.replace(f"{word} = ", f"{option} = ")
        message = message.replace(f"raise the {word}", f"raise {option}")
        message = message.replace(f"raise {word}", f"raise {option}")
    return message


@app.command()
def excite(
    ctx: typer.Context,
    scenario: Annotated[
        str, typer.Option(help=f"The machine: a built-in ({_SCENARIO_NAMES}) or a TOML file.")
    ] = "prototype",
    out: Annotated[
        str, typer.Option(help="The scenario file to write (TOML), with the trajectory.")
    ] = "excite.toml",
    harmonics: Annotated[int, typer.Option(help="Harmonics per coordinate (3-20).")] = 5,
    base_frequency: Annotated[
        float, typer.Option(help="Base frequency (Hz); the trajectory repeats at 1/F s.")
    ] = 0.2,
    periods: Annotated[int, typer.Option(help="Periods of the trajectory in the run.")] = 2,
    seed: Annotated[int, typer.Option(help="Seed of the optimiser's random starts.")] = 0,
) -> None:
    """Design an exciting trajectory for identification: a Fourier series per coordinate
    minimising the condition number of the base observation matrix inside the workspace
    and the drives' limits, at rest at both ends. Writes SCENARIO on it as OUT."""
    from pkmctl.ident.identify import ceil_g
    from pkmctl.io.atomic import atomic_write, check_output_file

    if not 3 <= harmonics <= 20:
        _fail(f"--harmonics = {harmonics}: must be in [3, 20]")
    if not 0 < base_frequency <= 10:
        _fail(f"--base-frequency = {base_frequency}: must be in (0, 10] Hz")
    if not 1 <= periods <= 100:
        _fail(f"--periods = {periods}: must be in [1, 100]")
    if periods / base_frequency > 3600.0:  # (1e-100 Hz: "Singular matrix"; 1e-3 Hz: "try
        # another --seed", for a run of 2000 s)
        _fail(
            f"--base-frequency = {base_frequency:g}: a run of --periods = {periods} would last "
            f"{periods / base_frequency:.4g} s, over timing.duration's 3600 s: must be >= "
            f"{ceil_g(periods / 3600.0):g} Hz"  # (rounded up: ">= 0.001944" refused it)
        )
    if seed < 0:
        _fail(f"--seed = {seed}: must be >= 0")
    if not scenario.strip():  # ('' was the prototype, unsaid)
        _fail(f"--scenario = {scenario!r}: must name a built-in ({_SCENARIO_NAMES}) or a file")
    try:
        out = check_output_file(out, what="--out")
    except Exception as exc:
        _handle(ctx, exc)
    base, _ = _scenario_for(ctx, scenario, None)
    from pkmctl.ident.excite import FORCE_MARGIN, SPEED_MARGIN, design_excitation, design_software
    from pkmctl.ident.identify import (
        DEFAULT_CUTOFF,
        MIN_HARMONIC_GAIN,
        cutoff_for,
        floor_g,
        highest_harmonic,
        max_cutoff,
        minimum_duration,
        sample_rate,
    )

    # the top harmonic must pass identify's parallel filter (at most fs/50 of the log); fs
    # as identify reads it from the log (333.333 Hz, not 333.3333...: a code reader)
    fs = sample_rate(base.timing.control_period * base.logging.every)
    top = harmonics * base_frequency
    cut = cutoff_for(top, fs)
    if cut is None:
        _fail(
            f"--base-frequency x --harmonics = {top:g} Hz: pkmctl identify would filter the top "
            f"harmonic away (a {fs:g} Hz log allows --cutoff <= {floor_g(max_cutoff(fs)):g} "
            f"Hz, which keeps {100 * MIN_HARMONIC_GAIN:g} % of a harmonic up to "
            f"{highest_harmonic(fs):g} Hz); allowed: base frequency x harmonics <= "
            f"{highest_harmonic(fs):g} Hz"
        )

    doing = f"designing an exciting trajectory for {base.name!r}"
    try:
        with (
            _fraction_bar() as bar,
            (compiles := _Compiles(bar, task := bar.add_task(doing, total=None))).listen(),
        ):

            def progress(done: int, total: int) -> None:
                text = f"{doing} ({done} of {total} random starts done)"
                bar.update(task, completed=done, total=total, description=text)
                if not err_console.is_terminal:  # a log: a line a start (20-30 s unsaid)
                    _say(text)

            def work():
                with warnings.catch_warnings():  # SLSQP's finite differences at a bad start
                    warnings.simplefilter("ignore", RuntimeWarning)
                    return design_excitation(
                        base,
                        harmonics=harmonics,
                        base_frequency=base_frequency,
                        periods=periods,
                        seed=seed,
                        progress=progress,
                    )

            exc_ = _interruptible(work, lambda: f"nothing written{compiles.kept()}")
            sc = exc_.scenario(base)
    except Exception as exc:
        _handle(ctx, exc)
    try:  # (a write that failed after the design printed a 50-line traceback)
        with atomic_write(out) as fh:
            fh.write(
                f"# pkmctl excite --scenario {scenario} --harmonics {harmonics} "
                f"--base-frequency {base_frequency:g} --periods {periods} --seed {seed}\n"
                f"# designed with {design_software()}: SLSQP's path, and so the design, "
                "changes with them (docs/identification.md)\n"
            )
            fh.write(sc.to_toml())
    except OSError as exc:
        _handle(ctx, exc, suffix=f"; {out} not written")
    _KEPT["note"] = f"{out} is written"
    from pkmctl.ident.excite import assumed_limits

    if note := assumed_limits(base):
        _say(f"note: {note}")
    t = Table(title=f"Exciting trajectory for {base.name!r} ({exc_.seconds:.1f} s to design)")
    t.add_column("")
    t.add_column("this trajectory", justify="right")
    t.add_column("limit / eq. 54", justify="right")
    t.add_row("cond(W_b) over the run", f"{exc_.cond:.4g}", f"{exc_.cond_paper:.4g} (eq. 54)")
    t.add_row("base parameters", str(exc_.base.count), "of 48")
    t.add_row(
        Text("peak limb force [N]"),
        f"{exc_.peak_force:.4g}",
        f"{FORCE_MARGIN * exc_.force_limit:.4g} ({100 * FORCE_MARGIN:g} % of "
        f"{exc_.force_limit:.4g})",
    )
    t.add_row(
        Text("peak limb speed [m/s]"),
        f"{exc_.peak_speed:.3g}",
        f"{SPEED_MARGIN * exc_.speed_limit:.3g} ({100 * SPEED_MARGIN:g} % of "
        f"{exc_.speed_limit:.3g})",
    )
    t.add_row("max cond(J)", f"{exc_.max_cond_j:.3g}", "50")
    t.add_row(Text("z range [m]"), f"{exc_.z_range[0]:.3f}-{exc_.z_range[1]:.3f}", "0.62-0.78")
    t.add_row(Text("max |alpha|, |beta| [rad]"), f"{exc_.max_angle:.3f}", "0.5")
    console.print(t)
    raise_cutoff = f" --cutoff {cut:g}" if cut != DEFAULT_CUTOFF else ""
    console.print(
        Text(
            f"wrote {out}: {exc_.duration:g} s; run it with "
            f"pkmctl simulate {shlex.quote(str(out))} --controller pd --out DIR, then pkmctl "
            f"identify DIR/pd.parquet{raise_cutoff}"  # (quoted: a path with a space ran
        )  # "simulate sc" when pasted)
    )
    # a run of D s logs t = 0 .. D - 1/fs at most: one interval less than D (a run of
    # 6.72631 s, said long enough for 6.726 s, logged 6.725 s: a code reader)
    need = minimum_duration(cut, exc_.base.count, fs) + 1.0 / fs
    if exc_.duration < need * (1.0 - 1e-9):
        at = f"--cutoff {cut:g} Hz" if raise_cutoff else f"its default --cutoff {cut:g} Hz"
        _say(
            f"warning: {exc_.duration:g} s is too short for pkmctl identify at {at}, which "
            f"needs >= {need:.4g} s of run (the log's span and one interval): use --periods "
            f">= {math.ceil(need * base_frequency - 1e-9)}"
        )


@app.command()
def identify(
    ctx: typer.Context,
    log: Annotated[
        Path,
        typer.Argument(
            metavar="LOG",
            help="A run's time series: pkmctl's Parquet/CSV, or a CSV with columns t (s), "
            "q1..q4 (m), tau1..tau4 (N, limb forces).",
        ),
    ],
    out: Annotated[
        str, typer.Option(help="Output folder: report.md, figures, the estimate.")
    ] = "pkmctl-identify",
    scenario: Annotated[
        str | None,
        typer.Option(
            help="The machine's geometry and the prior (a built-in or a TOML file; default: "
            "the scenario beside a pkmctl log, else prototype)."
        ),
    ] = None,
    validate: Annotated[
        Path | None, typer.Option(help="A second log: predict its J^T tau and report the error.")
    ] = None,
    cutoff: Annotated[
        float,
        typer.Option(help="Parallel filter cutoff (Hz): in (0, fs/50], fs the log's sample rate."),
    ] = 10.0,
    force_lead: Annotated[
        str | None,
        typer.Option(
            help="Force timing: the force at t is the logged one at t - LEAD (s); 'auto' "
            "estimates it (e.g. forces held over a control period: +T/2). Default: auto "
            "for a pkmctl log (its .json beside it), else 0 (instantaneous readings).",
            show_default=False,
        ),
    ] = None,
    physical: Annotated[
        bool,
        typer.Option(
            help="Also a physically consistent estimate (controller_model.toml).", metavar=""
        ),
    ] = True,
    max_residual: Annotated[
        float,
        typer.Option(
            help="Refuse a log whose physically consistent fit (WLS with --no-physical) leaves "
            "more than this % of J^T tau unexplained (genuine logs: < 0.2 %; bad signs, units "
            "or swapped columns: > 12 %). Raise it for a machine with unmodelled effects.",
            metavar="PERCENT",
        ),
    ] = 5.0,  # pkmctl.ident.identify.MAX_RELATIVE_RESIDUAL (not imported: numpy, scipy)
) -> None:
    """Identify the base parameters and the joint friction from a logged run (OLS, WLS,
    jackknife standard deviations), optionally validate on a second log; write a report
    and the estimate as a scenario [controller_model] block."""
    import numpy as np

    from pkmctl.ident.identify import (
        IdentificationError,
        check_log_file,
        predict,
        read_log,
    )
    from pkmctl.ident.identify import identify as run_identify
    from pkmctl.ident.report import OUTPUT_NAMES, remove_stale, write_identification
    from pkmctl.io.atomic import check_output_folder, discard, staged_folder

    log = _table_of(log)
    validate = _table_of(validate) if validate is not None else None
    how = "auto"
    if force_lead is None:  # a pkmctl log's forces are commands held over a period
        force_lead = "auto" if _metadata_scenario(log) is not None else "0"
        how = "auto, the default for a pkmctl log"
    if force_lead == "auto":
        lead = None
    else:
        try:
            lead = float(force_lead)
        except ValueError:
            _fail(f"--force-lead = {force_lead!r}: must be 'auto' or a number of seconds")
        if not abs(lead) < 1.0:
            _fail(f"--force-lead = {force_lead}: must be 'auto' or a time in (-1, 1) s")
    if not (math.isfinite(cutoff) and cutoff > 0):
        _fail(f"--cutoff = {cutoff:g}: must be > 0 Hz (at most a fiftieth of the sample rate)")
    if not 0 < max_residual <= 100:  # NaN too
        _fail(f"--max-residual = {max_residual:g}: must be in (0, 100] %")
    try:  # before the long work (the output first, as every command does)
        out = check_output_folder(out, what="--out", writes=OUTPUT_NAMES)
        check_log_file(log)
        if validate is not None:
            check_log_file(validate, what="--validate")
    except Exception as exc:
        _handle(ctx, exc)
    existed = out.is_dir()
    _KEPT["note"] = _untouched(out, existed)
    sc, origin = _scenario_for(ctx, scenario, log)
    compiles = _Compiles()
    stage = None
    try:
        with (
            staged_folder(out) as stage,
            console.status(Text(f"identifying from {log}")),
            compiles.listen(),
        ):

            def work():
                # refused logs are refused in one line; no numerical warnings on the way
                with warnings.catch_warnings(), np.errstate(all="ignore"):
                    warnings.simplefilter("ignore", RuntimeWarning)
                    idn = run_identify(read_log(log), sc, cutoff=cutoff, force_lead=lead,
                                       physical=physical, scenario_label=origin,
                                       max_residual=max_residual / 100)  # fmt: skip
                    val = None
                    if validate is not None:
                        val = predict(idn, read_log(validate, what="--validate"), sc)
                        val["source"] = str(validate)
                    return idn, val, write_identification(idn, stage, source=str(log),
                                                          validation=val)  # fmt: skip

            def interrupted() -> str:
                discard(stage)
                return _untouched(out, existed) + compiles.kept()

            idn, val, paths = _interruptible(work, interrupted)
    except KeyboardInterrupt:
        _KEPT["note"] = _kept(out, existed, stage)
        raise
    except MemoryError:
        _fail(
            f"out of memory identifying from {log} (about 2.3 kB per sample): cut the log, or "
            f"resample it to a lower rate (>= 50 x --cutoff); {_untouched(out, existed)}"
        )
    except Exception as exc:
        if isinstance(exc, IdentificationError) and not _debug(ctx):
            exc = IdentificationError(_as_options(str(exc)))
        _handle(ctx, exc, suffix="; " + _untouched(out, existed))
    _KEPT["note"] = _kept(out, existed, stage)
    stale = remove_stale(out, paths)
    obs = idn.observation
    used = obs.t.size
    _say(
        f"{obs.samples_in} samples: {used} used; "
        + "; ".join(f"{k} discarded ({why})" for why, k in obs.discarded.items())
    )
    _say(
        f"length noise <= {1e6 * obs.length_noise:.3g} um rms (what the {obs.diff_cutoff:g} Hz "
        f"pose filter removes); the Coulomb columns' limb rates filtered at "
        f"{obs.rate_cutoff:.4g} Hz"
    )
    if lead is None:
        _say(f"force lead ({how}): {1e3 * obs.force_lead:+.4g} ms")
    for note in idn.notes:  # (the report's notes: a tester found them only there)
        _say(f"warning: {note}")
    t = Table(title=f"{idn.base.count} base parameters (cond {idn.cond:.4g}), WLS")
    for c, j in (("#", "right"), ("base parameter", "left"), ("unit", "left"),
                 ("estimate", "right"), ("std %", "right")):  # fmt: skip
        t.add_column(c, justify=j, overflow="fold")
    for k in range(idn.base.count):
        t.add_row(
            str(k + 1),
            Text(idn.base.expressions[k]),
            idn.base.units[k],
            f"{idn.wls.beta[k]:.5g}",
            f"{idn.wls.std_percent[k]:.3g}",
        )
    console.print(t)
    msg = (
        f"residual RMS (WLS) z {idn.wls.rms[0]:.3g} N, alpha {idn.wls.rms[1]:.3g} N m, "
        f"beta {idn.wls.rms[2]:.3g} N m; relative error {100 * idn.wls.relative_error:.3g} %"
    )
    if val is not None:
        msg += f"; validation on {validate}: {100 * val['relative_error']:.3g} %"
    console.print(Text(msg))
    console.print(Text(f"machine: {idn.scenario}"))
    if validate is not None and (other := _other_machine(validate, sc)):
        _say(f"warning: --validate {str(validate)!r}: {other}")
    if val is not None and not val["relative_error"] <= max_residual / 100:
        # (a log in kN read 9.99e+04 %, negated forces 200 %, without a word)
        _say(
            f"warning: --validate {str(validate)!r}: the estimate leaves "
            f"{100 * val['relative_error']:.3g} % of its J^T tau unexplained, more than "
            f"--max-residual = {max_residual:g} % allows the identification's log: forces of "
            "the other sign or in other units, swapped columns, or another machine"
        )
    wrote = f"wrote {out / 'report.md'} and {len(paths) - 1} more files"
    if stale:
        wrote += f"; removed {', '.join(p.name for p in stale)} of an earlier run"
    console.print(Text(wrote))
