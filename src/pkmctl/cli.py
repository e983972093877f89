"""The ``pkmctl`` command (DESIGN.md §5): a thin layer over the library.

    pkmctl [--version] [--debug] COMMAND ...
    pkmctl reproduce [--scenario NAME|FILE] [--out DIR] [--seed N] [--duration S]
    pkmctl simulate SCENARIO [--controller NAME] [--out DIR] [--format parquet|csv]
                    [--seed N] [--duration S]
    pkmctl scenario [NAME]
    pkmctl bench [--quick] [--json PATH]
    pkmctl mujoco-model --out FILE.xml [--scenario NAME|FILE] [--rotor-inertia J] ...
    pkmctl campaign run SPEC.toml|NAME [--out DIR] [--workers N] [--scheduler ADDRESS] [--resume]
    pkmctl campaign show SPEC.toml|NAME
    pkmctl campaign report DIR
    pkmctl excite [--scenario NAME|FILE] [--out FILE] [--harmonics H] [--base-frequency F]
    pkmctl identify LOG [--out DIR] [--scenario NAME|FILE] [--validate LOG2] [--cutoff HZ]

Every error a user can cause ends in one line on stderr naming the cause (the value,
the field or the path) and exit status 2 for bad input or environment (output
location, disk, memory, a missing dependency), 1 for a run that failed (diverged), 130
for Ctrl-C; ``--debug`` shows the traceback instead. Output locations are checked
before any computation, and a run's files appear all at once (io/atomic.py).

Ctrl-C: the work runs in a worker thread the main thread waits on, so an interrupt is
answered within a fraction of a second even while Numba compiles (the worker is then
abandoned: the process exits at once, after removing its staging folder).
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, NoReturn, TypeVar

import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    Progress,
    SpinnerColumn,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Table
from rich.text import Text
from typer.core import TyperGroup

try:  # Typer >= 0.2x carries its own copy of Click; older ones use Click itself
    from typer._click.exceptions import ClickException
except ImportError:  # pragma: no cover - depends on the installed Typer
    from click import ClickException

from pkmctl.parts import names as _part_names
from pkmctl.sim.scenario import BUILTINS as _SCENARIOS
from pkmctl.sim.scenario import FUZZY_CONTROLLERS

T = TypeVar("T")

_CONTROLLERS = ", ".join(_part_names("controller"))
_SCENARIO_NAMES = ", ".join(_SCENARIOS)


# What an interrupt between a command's steps keeps (the command sets the note), and
# the signal that stopped it: Ctrl-C, or SIGTERM (`kill`, a job scheduler), handled alike
# but said and ended as itself (exit 128 + the signal: 130 or 143, as a shell reports it)
# (t0: when the command began: main() sets it, in-process calls at their own start)
_KEPT: dict = {"t0": time.perf_counter(), "note": "", "signal": 2, "in_main": False, "mains": 0}


def _terminated(signum, frame) -> None:
    _KEPT["signal"] = signum
    raise KeyboardInterrupt


def _stopped(after: float, kept: str) -> None:
    """Say how the command was stopped and what it kept, and exit 128 + the signal."""
    word = {15: "terminated (SIGTERM)", 1: "hung up (SIGHUP)"}.get(_KEPT["signal"], "interrupted")
    _say(f"{word} after {after:.1f} s{kept}")
    _hard_exit(128 + _KEPT["signal"])


class _OneLineGroup(TyperGroup):
    """Usage errors (a bad option, a missing argument) in one line, not a panel."""

    def main(self, *args, **kwargs):  # noqa: D102
        kwargs["standalone_mode"] = False
        try:
            code = super().main(*args, **kwargs)
        except ClickException as exc:
            if type(exc).__name__ == "NoArgsIsHelpError":  # Click >= 8.2: plain `pkmctl`
                exc.show()
                sys.exit(exc.exit_code)
            name = exc.ctx.command_path if getattr(exc, "ctx", None) else "pkmctl"
            _print_error(f"{exc.format_message()} (see {name} --help)")
            sys.exit(exc.exit_code)
        except typer.Abort:  # Ctrl-C between a command's interruptible steps
            code = 130
        except Exception as exc:
            if not _interrupted(exc):
                raise
            code = 130
        if code == 130:  # (Typer >= 0.29 returns Exit(130) for a KeyboardInterrupt: silent)
            # os._exit, not sys.exit: an interpreter shutdown would wait for worker
            # processes still compiling (concurrent.futures joins them at exit)
            kept = f": {_KEPT['note']}" if _KEPT["note"] else ""
            _stopped(time.perf_counter() - _KEPT["t0"], kept)
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(
    cls=_OneLineGroup,
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    # Help as Markdown: rich markup would eat "[plant]" in a help text, and Typer's
    # command list keeps a docstring's line breaks in that mode.
    rich_markup_mode="markdown",
    help="Model, control and simulate the 2RPU-2SPR parallel manipulator "
    "(SMC, FSMC, AFSMC, PD, CTC). The first run compiles the numerical kernels "
    "(minutes; cached on disk for later runs).",
)
# Tables need ~100 columns; a pipe or a CI log would otherwise get rich's 80. Lines of
# text are not wrapped (soft_wrap): a command to copy or a line to grep stays whole.
# NO_COLOR (no-color.org): rich drops the colours but keeps bold and underline; no
# escape codes at all is what a user who sets it wants.
_PLAIN = {"color_system": None} if os.environ.get("NO_COLOR") else {}
# A dumb terminal (TERM=dumb: Emacs' shells, some CI pseudo-terminals) draws no live
# progress bar: it gets the plain lines a log gets (it showed no progress at all)
_DUMB = {"force_terminal": False} if os.environ.get("TERM", "") in ("dumb", "unknown") else {}
console = Console(width=max(Console().width, 110), soft_wrap=True, **_PLAIN)
# Help at 80 columns at least: narrower, Typer cut option names and defaults with "…"
# (`--max-residu…`, `[default: pkmctl-o…`: 106 cut lines at 40 columns, a tester)
try:
    import typer.rich_utils as _typer_rich

    if getattr(_typer_rich, "MAX_WIDTH", 0) is None:
        _typer_rich.MAX_WIDTH = max(Console().width, 80)
except ImportError:  # pragma: no cover - a Typer without rich help
    pass
err_console = Console(stderr=True, **_PLAIN, **_DUMB)


def _can_print(text: str) -> bool:
    """Whether stdout's encoding can write ``text`` (not under LANG=C or
    PYTHONIOENCODING=ascii: a "°" in the RMSE table's header was a UnicodeEncodeError
    traceback, exit 1, after the files were written)."""
    try:
        text.encode(getattr(sys.stdout, "encoding", None) or "utf-8")
    except (UnicodeEncodeError, LookupError):
        return False
    return True


_DEGREE = "°" if _can_print("°") else "deg"


def _print_error(message: str) -> None:
    # A Text, not markup: "[0.7, 2.0]" or a file named "[abc].toml" must show verbatim.
    err_console.print(Text.assemble(("error: ", "bold red"), message), soft_wrap=True)


def _say(message: str) -> None:
    for compiles in _LISTENING:  # a compile that ended is said before what follows it
        compiles.flush()  # ("compiled the control loop" came after the run's progress)
    err_console.print(Text(message), soft_wrap=True, highlight=False)


def _debug(ctx: typer.Context) -> bool:
    obj = ctx.find_root().obj
    return bool(obj and obj.get("debug"))


def _fail(message: str, code: int = 2) -> NoReturn:
    _print_error(message)
    raise typer.Exit(code)


def _exit_status(exc: BaseException) -> int:
    """1 for a run that failed; 2 for bad input or environment."""
    from pkmctl.errors import ConvergenceError, SimulationDiverged

    return 1 if isinstance(exc, SimulationDiverged | ConvergenceError) else 2


def _describe(exc: BaseException) -> str:
    """One line for an exception a user can cause."""
    from pkmctl.errors import PkmctlError

    if isinstance(exc, PkmctlError | ValueError | TypeError):
        return str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if isinstance(exc, ModuleNotFoundError):
        return f"missing dependency {exc.name!r}: install it (python -m pip install {exc.name})"
    if isinstance(exc, MemoryError):
        return "out of memory: shorten timing.duration or lengthen timing.control_period"
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        return f"{where}{exc.strerror or exc}"
    return f"{type(exc).__name__}: {exc} (an internal error; pkmctl --debug shows the traceback)"


def _interrupted(exc: BaseException | None) -> bool:
    """Whether ``exc`` came of a Ctrl-C (or SIGTERM, SIGHUP): an interrupt while a compiled
    module initialises surfaces as the ImportError it caused ("initialization failed", a
    50-line traceback and exit 1 where a lazy import of SciPy was hit: a tester)."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _handle(ctx: typer.Context, exc: BaseException, *, suffix: str = "") -> NoReturn:
    """End the command with one line (or re-raise under --debug); an error an interrupt
    caused ends it as the interrupt."""
    if _interrupted(exc):
        raise KeyboardInterrupt from exc
    if _debug(ctx):
        raise exc
    if isinstance(exc, ModuleNotFoundError | MemoryError | OSError | ValueError | TypeError):
        code = _exit_status(exc)
    else:
        from pkmctl.errors import PkmctlError

        code = _exit_status(exc) if isinstance(exc, PkmctlError) else 1
    _fail(_describe(exc) + suffix, code)


def _to_stdout(text: str, what: str) -> None:
    """Write ``what`` (e.g. "the scenario") to stdout, or fail in one line saying it was
    stdout that could not take it: closed (``>&-``: sys.stdout is None, an
    AttributeError before) or failing (``> /dev/full``: "No space left on device")."""
    if sys.stdout is None:
        raise OSError(f"stdout is closed: nowhere to print {what} (redirect it to a file)")
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except OSError as exc:
        raise OSError(f"printing {what} to stdout failed: {exc.strerror or exc}") from None


def _hard_exit(code: int) -> NoReturn:
    """Exit now, abandoning worker threads (a compiling thread cannot be stopped), once
    no compiled code is being written to the cache (no half-written file left there), no
    folder probed for writing is there (io/atomic.py) and no worker is being launched;
    its workers are sent the SIGTERM they would get when it ends (sim/workers.py)."""
    from pkmctl import _jit
    from pkmctl.io import atomic
    from pkmctl.sim import workers

    _jit.settle()
    atomic.settle()
    workers.settle()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def _interruptible(work: Callable[[], T], on_interrupt: Callable[[], str]) -> T:
    """Run ``work`` in a worker thread; on Ctrl-C call ``on_interrupt`` (clean up, return
    what was kept), say so and exit 130 (143 for a SIGTERM) at once, whatever the worker
    is doing.

    The main thread only waits, in short slices, so Python runs its SIGINT handler
    within milliseconds: Numba's compiler releases the GIL in its LLVM calls and every
    few ms of its Python code.
    """
    box: dict = {}

    def target() -> None:
        try:
            box["value"] = work()
        except BaseException as exc:  # handed to the main thread
            box["error"] = exc

    worker = threading.Thread(target=target, name="pkmctl-work", daemon=True)
    try:
        worker.start()
        while worker.is_alive():
            worker.join(0.05)
    except KeyboardInterrupt:
        kept = on_interrupt()
        _stopped(time.perf_counter() - _KEPT["t0"], f": {kept}")  # since the command began
    if "error" in box:
        raise box["error"]
    return box["value"]


def _version(value: bool) -> None:
    if value:
        import pkmctl
        from pkmctl import _jit

        # the hashes outputs record ("Made by pkmctl 0.2.0 (sources ..., kernels ...)"):
        # one version number covers many states of the code (a tester)
        typer.echo(
            f"pkmctl {pkmctl.__version__} (sources {_jit.package_stamp()}, kernels "
            f"{_jit.source_stamp()})"
        )
        raise typer.Exit()


@app.callback()
def _main(
    ctx: typer.Context,
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version, is_eager=True, help="Print the version.", metavar=""
        ),
    ] = False,
    debug: Annotated[
        bool,
        typer.Option(
            "--debug", help="Show the traceback of an error (before COMMAND).", metavar=""
        ),
    ] = False,
    plugin: Annotated[
        list[str] | None,
        typer.Option(
            "--plugin",
            help="A Python file or module that registers your own parts (docs/parts.md), "
            "imported first; repeat for several (before COMMAND).",
            metavar="FILE",
        ),
    ] = None,
) -> None:
    import signal

    if threading.current_thread() is threading.main_thread():  # the start-up's quiet handler
        if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # (ignored: stays so)
            signal.signal(signal.SIGINT, signal.default_int_handler)  # off (_start.py)
        # SIGTERM (kill, a job scheduler) as Ctrl-C: the same clean-up, where it left the
        # staging folder with all written so far and the figure processes behind
        # SIGHUP (the terminal closed, ssh dropped) too: it left a half-written staging
        # folder of 34 MB in OUT (a tester). Each unless ignored (nohup; an ignored
        # SIGTERM was ignored only while the command started: a reviewer)
        for sig in (signal.SIGTERM, signal.SIGHUP):
            if signal.getsignal(sig) is not signal.SIG_IGN:
                signal.signal(sig, _terminated)
    ctx.obj = {"debug": debug}
    # what an interrupt keeps until the command says otherwise (it said nothing: "after
    # 0.7 s" alone, in every interrupted excite: a tester); a command that writes more
    # than one thing sets its own as it goes
    _KEPT["note"] = "nothing written"
    if not _KEPT["in_main"]:  # (called in-process, as tests do: from this call)
        _KEPT["t0"] = time.perf_counter()
    if plugin:
        from pkmctl.plugins import load_plugins

        try:
            load_plugins(plugin)
        except Exception as exc:
            _handle(ctx, exc)


def _load_scenario(spec: str, changes: dict | None = None):
    """The scenario ``spec`` names, with ``changes`` made before it is validated (a
    file's trajectory is checked over the duration that will run, not the file's)."""
    from pkmctl.sim.scenario import BUILTINS, Scenario, ScenarioError

    if not spec.strip():  # (Path("") is ".": "'.': Is a directory")
        raise ScenarioError(
            f"scenario = {spec!r}: must name a built-in ({', '.join(BUILTINS)}) or a TOML file"
        )
    if spec in BUILTINS:
        if Path(spec).is_file():  # (`pkmctl scenario paper > paper`, edited, ran the built-in)
            raise ScenarioError(
                f"{spec!r} names both a built-in scenario and a file here: give ./{spec} for "
                "the file (or rename it to .toml)"
            )
        return Scenario.builtin(spec, changes=changes)
    path = Path(spec)
    if path.suffix.lower() == ".toml" or path.exists():
        return Scenario.from_toml(path, changes)
    return Scenario.builtin(spec)  # raises: unknown built-in, with the list


def _overrides(seed: int | None, duration: float | None) -> dict:
    changes = {}
    if duration is not None:
        changes["timing.duration"] = duration
    if seed is not None:
        changes["disturbance.seed"] = seed
    return changes


def _scenario(ctx: typer.Context, spec: str, seed, duration, kept: str, *, fuzzy: bool):
    """The scenario, validated; interruptible, since validating the trajectory calls the
    kinematics kernels, which a first run compiles. ``fuzzy``: a run of FSMC or AFSMC
    follows, so a ``.fis`` file off 0 at rest is worth a warning."""
    compiles = _Compiles()
    try:
        with compiles.listen():
            sc = _interruptible(
                lambda: _load_scenario(spec, _overrides(seed, duration)),
                lambda: kept + compiles.kept(),
            )
    except Exception as exc:
        _handle(ctx, _as_typed(exc, seed, duration))
    if fuzzy and (note := sc.fuzzy_offset_note()):
        _say(f"warning: {note}")
    return sc


def _as_typed(exc: Exception, seed, duration) -> Exception:
    """``exc`` with a value given as an option named as the option the user typed."""
    text = str(exc)
    for option, field, given in (("--seed", "disturbance.seed", seed),
                                 ("--duration", "timing.duration", duration)):  # fmt: skip
        if given is not None and text.startswith(f"{field} = ") and ": " in text:
            why = text.split(": ", 1)[1]
            exc = type(exc)(f"{option} = {given!r} ({field}): {why}")
    return exc


#: whether this process said that the compile cache cannot be written (said once)
_CACHE_WARNED: list[bool] = []
#: the groups of kernels this process has said it compiled: a group compiled again later
#: (a kernel first called by a later step) is "more of" it, not a second first compile
_COMPILED: set[str] = set()


def _more(what: str) -> str:
    # (a second control loop is another loop, not more of the first)
    return f"more of {what}" if what in _COMPILED and what.endswith("kernels") else what


#: the :class:`_Compiles` listening now
_LISTENING: list = []


class _Compiles:
    """Say what compiles while it compiles: in the progress bar on a terminal (its
    elapsed-time column runs), as plain lines otherwise (a log, CI). Counts what was
    compiled, for the message after an interrupt."""

    def __init__(self, bar: Progress | None = None, task=None) -> None:
        self.bar, self.task, self.done = bar, task, 0
        # the group compiled last and its seconds so far, said when another group starts
        # or listening ends: one pair of lines per group, not one per kernel of it
        self.pending: tuple[str, float] | None = None
        self.lock = threading.Lock()

    def __call__(self, event: str, what: str, seconds: float) -> None:
        if event == "failed":  # its error follows in one line
            return
        from pkmctl import _jit

        kept = _jit.cache_writable()
        with self.lock:
            if event == "start":
                if self.pending is not None and self.pending[0] == what:
                    return  # the same group goes on
                self._flush(kept)
                if not kept and not _CACHE_WARNED:
                    _CACHE_WARNED.append(True)
                    held = (
                        "what it holds for these sources loads, what it lacks"
                        if _jit.cache_dir().is_dir()
                        else "compiled code is kept in memory only, and every run"
                    )
                    _say(
                        f"warning: the compile cache {str(_jit.cache_root())!r} cannot be "
                        f"written: {held} compiles again (set PKMCTL_CACHE_DIR to a "
                        "writable folder)"
                    )
                self._show(f"compiling {_more(what)} ({_jit.compile_note('start', kept)})…")
            else:
                self.done += 1
                before = self.pending[1] if self.pending and self.pending[0] == what else 0.0
                self.pending = (what, before + seconds)

    def _show(self, msg: str) -> None:
        if self.bar is not None and err_console.is_terminal:
            self.bar.update(self.task, description=msg)
        else:
            _say(msg)

    def flush(self) -> None:
        """Say the compile that ended, if any (not from inside this object's own calls)."""
        if self.pending is None or not self.lock.acquire(blocking=False):
            return
        try:
            from pkmctl import _jit

            self._flush(_jit.cache_writable())
        finally:
            self.lock.release()

    def _flush(self, kept: bool) -> None:
        if self.pending is not None:
            what, seconds = self.pending
            self.pending = None
            from pkmctl import _jit

            where = _jit.compile_note("end", kept)
            self._show(f"compiled {_more(what)} in {seconds:.1f} s ({where})")
            _COMPILED.add(what)

    @contextlib.contextmanager
    def listen(self):
        # (imported as a module: the text "pkmctl" "._jit" would put cli.py into the
        # kernels' source hash, and every edit of the CLI would recompile them all)
        from pkmctl import _jit

        _LISTENING.append(self)
        try:
            with _jit.announce(self):
                yield
        finally:
            _LISTENING.remove(self)
            with self.lock:
                self._flush(_jit.cache_writable())

    def kept(self) -> str:
        return "; kernels compiled so far stay cached" if self.done else ""


def _final_path(path: str, stage: Path, out: Path) -> str:
    """A file being written in the staging folder ``stage`` (and any staging folder inside
    it), by the name it would have had in ``out``: reproduce on a full disk named
    ".../.pkmctl-1@a.tmp/.pkmctl-1@b.tmp/timeseries/smc.parquet" (a tester)."""
    if not path.startswith(str(stage)):
        return path
    rest = Path(path[len(str(stage)) :].lstrip(os.sep))
    parts = [p for p in rest.parts if not (p.startswith(".pkmctl-") and p.endswith(".tmp"))]
    return str(out.joinpath(*parts))


def _fraction_bar() -> Progress:
    """A bar with the fraction done, on stderr and only on a terminal (a log gets no
    bar), gone when the work ends; its task's description says what compiles meanwhile
    (:class:`_Compiles`)."""
    return Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TaskProgressColumn(),  # (none while compiling: no total yet)
        TimeElapsedColumn(),
        console=err_console,
        transient=True,
        disable=not err_console.is_terminal,
    )


def _untouched(out: Path, existed: bool) -> str:
    return (
        f"nothing written; {out} keeps its previous results"
        if existed
        else f"nothing written; {out} was not created"
    )


def _kept(out: Path, existed: bool, stage: Path | None) -> str:
    """What an interrupt after a command's work keeps: its results once its staging
    folder is published (a Ctrl-C held during the renames comes after them)."""
    from pkmctl.io.atomic import published

    return f"the results are in {out}" if published(stage) else _untouched(out, existed)


def _rmse_table(results: dict, title: str) -> Table:
    from pkmctl.sim.metrics import RMSE_KEYS

    table = Table(title=title)
    table.add_column("RMSE", no_wrap=True)
    for k in RMSE_KEYS:
        table.add_column(
            k.replace("_deg", f" {_DEGREE}").replace("_mm", " mm").replace("_m", " m"),
            justify="right",
            no_wrap=True,
        )
    for name, res in results.items():
        r = res.rmse()
        table.add_row(name, *(f"{r[k]:.4g}" for k in RMSE_KEYS))
    return table


@app.command()
def reproduce(
    ctx: typer.Context,
    scenario: Annotated[
        str,
        typer.Option(help=f"Built-in scenario ({_SCENARIO_NAMES}) or a TOML file."),
    ] = "paper",
    out: Annotated[
        str, typer.Option(help="Output folder (created; same-named files replaced).")
    ] = "pkmctl-out",
    seed: Annotated[int | None, typer.Option(help="Disturbance seed (overrides).")] = None,
    duration: Annotated[float | None, typer.Option(help="Duration in s (overrides).")] = None,
) -> None:
    """Run SMC, FSMC, AFSMC, PD and CTC; write Table 4 (CSV, Markdown), Figures 10-26
    (PNG), report.md and the time series (Parquet + JSON).

    The files appear all at once when the run is complete; a failed or interrupted run
    leaves OUT as it was.
    """
    from pkmctl.experiment import CONTROLLER_ORDER, check_samples, reproduce_writes
    from pkmctl.experiment import reproduce as run
    from pkmctl.io.atomic import check_output_folder, staged_folder

    try:  # (a str, not a Path: Path("") is ".", and --out '' must be refused)
        out = check_output_folder(out, what="--out", writes=reproduce_writes())
    except Exception as exc:
        _handle(ctx, exc)
    existed = out.is_dir()
    _KEPT["note"] = _untouched(out, existed)
    sc = _scenario(ctx, scenario, seed, duration, _untouched(out, existed), fuzzy=True)
    try:
        check_samples(sc)  # before the compile and the runs, not in the figures after them
    except Exception as exc:
        _handle(ctx, _as_typed(exc, seed, duration))
    steps = ["compile", *CONTROLLER_ORDER, "series", "table", "figures", "report", "machine"]
    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        console=err_console,
        transient=False,
        disable=not err_console.is_terminal,  # a log gets plain lines instead
    ) as bar:
        task = bar.add_task("starting", total=len(steps))
        count = {"n": -1}
        compiles = _Compiles(bar, task)

        def progress(msg: str) -> None:
            count["n"] += 1
            shown["msg"] = msg
            bar.update(task, completed=count["n"], description=msg)
            if not err_console.is_terminal:
                _say(msg)

        shown = {"msg": "starting"}

        def run_progress(done: int, total: int) -> None:  # the five runs together
            if shown["msg"].startswith("simulating"):
                bar.update(
                    task, description=f"{shown['msg']} (runs {100 * done / total:.0f} % done)"
                )

        stage = None
        try:
            with staged_folder(out) as stage:

                def interrupted() -> str:
                    from pkmctl.io.atomic import discard
                    from pkmctl.report.figures import stop_drawing

                    stop_drawing()  # before the folder they draw into goes
                    discard(stage)
                    bar.stop()
                    return _untouched(out, existed) + compiles.kept()

                with compiles.listen():
                    output = _interruptible(
                        lambda: run(sc, stage, progress=progress, run_progress=run_progress),
                        interrupted,
                    )
        except KeyboardInterrupt:
            _KEPT["note"] = _kept(out, existed, stage)
            raise
        except Exception as exc:
            bar.stop()
            if isinstance(exc, OSError) and stage is not None and exc.filename:
                exc.filename = _final_path(str(exc.filename), stage, out)
            _handle(ctx, exc, suffix="; " + _untouched(out, existed))
        _KEPT["note"] = _kept(out, existed, stage)
        bar.update(task, completed=len(steps), description="done")
    console.print(_rmse_table(output.results, f"RMSE, scenario {sc.name!r}"))
    ph = output.phases
    from pkmctl.parts import get_part

    # a plant stepped outside compiled code (MuJoCo) is stepped from Python each period
    stepped = any(get_part("plant", r.scenario.plant_spec.kind).stepper is not None
                  for r in output.results.values())  # fmt: skip
    loops = "loops, stepped from Python," if stepped else "compiled loops"
    console.print(Text(
        f"wrote {len(output.files)} files to {out}/ in {output.wall_time_s:.1f} s: "
        f"{ph['before']:.1f} s before the runs, {ph['runs']:.1f} s of runs (their "
        f"{loops} {ph['loops']:.1f} s, summed), {ph['figures']:.1f} s more for the figures, "
        f"{ph['report']:.1f} s for the report"
    ))  # fmt: skip
    console.print(Text(f"report: {out / 'report.md'}"))
    for note in output.notes:  # (README: "without it they say so in one line")
        _say(f"note: {note}")


@app.command()
def simulate(
    ctx: typer.Context,
    scenario_file: Annotated[
        str,
        typer.Argument(
            metavar="SCENARIO", help=f"Scenario TOML file or built-in name ({_SCENARIO_NAMES})."
        ),
    ],
    controller: Annotated[
        str, typer.Option(help=f"A registered controller (built in: {_CONTROLLERS}).")
    ] = "afsmc",
    out: Annotated[
        str,
        typer.Option(
            help="Output folder for the time series (created; this controller's files "
            "replaced, its table in the other format removed)."
        ),
    ] = (
        "pkmctl-out"  # a str: typer would make --out '' the Path '.', the current folder
    ),
    fmt: Annotated[
        str,
        typer.Option("--format", help="Time-series format: parquet (the default) or csv."),
    ] = "parquet",
    seed: Annotated[int | None, typer.Option(help="Disturbance seed (overrides).")] = None,
    duration: Annotated[float | None, typer.Option(help="Duration in s (overrides).")] = None,
) -> None:
    """Run one controller on a scenario; write its time series (Parquet by default, or
    CSV) and its metadata (JSON) into OUT, both at once."""
    from pkmctl.io.atomic import check_output_folder, discard, staged_folder
    from pkmctl.io.results import FORMATS, remove_other_formats, save_result
    from pkmctl.sim.simulate import simulate as run

    if fmt not in FORMATS:
        _fail(f"--format = {fmt!r}: must be one of {', '.join(FORMATS)}")
    if controller not in _part_names("controller"):
        _fail(
            f"--controller = {controller!r}: must be one of {', '.join(_part_names('controller'))}"
            " (your own: pkmctl --plugin FILE.py simulate ...)"
        )
    try:
        writes = (f"{controller}.{fmt}", f"{controller}.json")
        out = check_output_folder(out, what="--out", writes=writes)
    except Exception as exc:
        _handle(ctx, exc)
    existed = out.is_dir()
    _KEPT["note"] = _untouched(out, existed)
    fuzzy = controller in FUZZY_CONTROLLERS
    sc = _scenario(ctx, scenario_file, seed, duration, _untouched(out, existed), fuzzy=fuzzy)
    doing = f"simulating {controller} on {sc.name!r}"
    stage = None
    try:
        from pkmctl.sim.simulate import check_saved_memory

        # (before the estimate: a 3600 s run said "estimated 2.4 min", then that it
        # needs 81.62 GiB: a code reader)
        check_saved_memory(sc, controller)  # (the save's copy too)
        with (
            staged_folder(out) as stage,
            _fraction_bar() as bar,
            (compiles := _Compiles(bar, task := bar.add_task(doing, total=None))).listen(),
        ):
            said = {"at": time.monotonic(), "tenth": 0, "first": None}
            _say_long_run(sc, controller, doing)

            def progress(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total, description=doing)
                now = time.monotonic()
                if said["first"] is None:  # the loop's first report: compiled by now
                    said["first"] = (now, done)
                if err_console.is_terminal or not total or done >= total:
                    return
                # a log gets a line every 10 % or minute (an hour's run at 20 kHz was
                # silent for 81 s: a tester), with the rate and the time left once the
                # loop has run a while (a 27-day run said "(0 %)" and nothing more)
                tenth = 10 * done // total
                if tenth > said["tenth"] or now - said["at"] >= LOG_EVERY_S:
                    t0, d0 = said["first"]
                    rate = (done - d0) / (now - t0) if done > d0 and now > t0 else 0.0
                    pace = (f", {rate:,.0f} periods/s, about {_seconds((total - done) / rate)} "
                            "left") if rate > 0 else ""  # fmt: skip
                    _say(f"{doing}: {done:,} of {total:,} periods "
                         f"({100 * done / total:.0f} %){pace}")  # fmt: skip
                    said.update(at=now, tenth=tenth)

            def work():
                result = run(sc, controller=controller, progress=progress)
                bar.update(task, description=f"writing {controller}.{fmt}")
                if not err_console.is_terminal:
                    _say(f"writing {controller}.{fmt}")
                return result, save_result(result, stage, fmt=fmt)

            def interrupted() -> str:
                discard(stage)
                bar.stop()
                return _untouched(out, existed) + compiles.kept()

            result, paths = _interruptible(work, interrupted)
    except KeyboardInterrupt:
        _KEPT["note"] = _kept(out, existed, stage)
        raise
    except Exception as exc:
        if isinstance(exc, OSError) and stage is not None and exc.filename:
            exc.filename = _final_path(str(exc.filename), stage, out)
        _handle(ctx, exc, suffix="; " + _untouched(out, existed))
    _KEPT["note"] = _kept(out, existed, stage)
    # the run's time series in the other format, of an earlier run, would now disagree
    # with the metadata beside it
    stale = remove_other_formats(out, controller, fmt)
    console.print(_rmse_table({controller: result}, f"RMSE, scenario {sc.name!r}"))
    for line in _limit_notes(result):
        console.print(Text(line))
    console.print(
        Text(
            f"wrote {out / paths[0].name} and {out / paths[1].name}"
            + "".join(f"; removed {p.name} of an earlier run" for p in stale)
        )
    )


def _limit_notes(result) -> list[str]:
    """A line for each of the actuators' limits the run spent more than 1 % of its time at
    (force) or over (speed): the errors above are then a saturated machine's, which only
    the JSON said (a fuzzer's drives without torque sank 38 mm, unsaid)."""
    from pkmctl.sim.metrics import summary

    # ("the drives" of ideal actuators with a force_limit, which have none: a code reader)
    who = "the drives" if result.parts.get("actuator") == "drive" else "the actuators"

    m = summary(result)
    span = result.t[-1] - result.t[0] if result.t.size > 1 else 0.0
    span = result.scenario.timing.duration if result.loop_metrics is not None else span
    out = []
    for key, what in (("time_at_force_limit_s", "at their force limit"),
                      ("time_over_speed_limit_s", "over their speed limit")):  # fmt: skip
        t = m.get(key)
        if t is not None and span > 0 and t > 0.01 * span:
            out.append(f"note: {who} were {what} for {t:.3g} s of the {span:g} s run "
                       f"({100 * t / span:.0f} %; {key} in the JSON's metrics)")  # fmt: skip
    return out


@app.command()
def scenario(
    ctx: typer.Context,
    name: Annotated[
        str, typer.Argument(metavar="NAME", help=f"Built-in scenario name ({_SCENARIO_NAMES}).")
    ] = "paper",
) -> None:
    """Print a built-in scenario as TOML (edit it and pass it to reproduce or simulate).

    Built-in scenarios: **paper** (the paper's experiment at T_c = 50 us), **paper-1khz**
    (the same at 1 ms), **prototype** (the machine as built: 1 kHz, servo drives, rotor
    inertia, friction, encoders), **prototype-model** (its controllers also know the
    rotors and the friction), **prototype-tuned** (that, with beta gains for 1 kHz and a
    start on the trajectory). Each file's description says more.
    """
    from pkmctl.sim.scenario import Scenario

    try:
        _to_stdout(Scenario.builtin(name).to_toml(), "the scenario")
    except Exception as exc:
        _handle(ctx, exc)


@app.command()
def bench(
    ctx: typer.Context,
    quick: Annotated[bool, typer.Option(help="Short runs (a smoke test).", metavar="")] = False,
    json_out: Annotated[
        str | None, typer.Option("--json", help="Also write the results to this JSON file.")
    ] = None,
) -> None:
    """Measure speed on this machine: steps/s, FLC, latency, batch, and peers in one run.

    About 2 minutes on 2 cores (--quick: about 1): it starts worker processes and a local
    Dask cluster (on loopback), and runs pkmctl reproduce twice in a child process. Each
    ratio to a peer is measured in alternating rounds. The measuring code is not
    installed with pkmctl: it lives in the ``benchmarks/`` folder of this pkmctl's source
    checkout (beside an editable install, or the current folder if it is a checkout of
    the same files).
    """
    from pkmctl.io.atomic import check_output_file

    if json_out is not None:
        try:
            json_out = check_output_file(json_out, what="--json")
        except Exception as exc:
            _handle(ctx, exc)
    _import_benchmarks()
    from benchmarks.bench import machine_line, remove_temporary, rows, run_all

    def say(m: str) -> None:
        err_console.print(Text(m, style="dim"), soft_wrap=True)

    def interrupted() -> str:
        remove_temporary()
        return "nothing written"

    try:
        results = _interruptible(lambda: run_all(quick=quick, progress=say), interrupted)
    except Exception as exc:
        _handle(ctx, exc)
    table = Table(title=machine_line(results), title_justify="left")
    # measurements and results wrap in a narrow terminal; targets and verdicts never (they
    # were cut to "he…" at 100 columns: a tester)
    table.add_column("measurement", justify="left", ratio=3)
    table.add_column("result", justify="right", ratio=2)
    table.add_column("target", justify="right", no_wrap=True, min_width=6)
    table.add_column("held", justify="center", no_wrap=True, min_width=4)
    for label, text, target, held in rows(results):
        table.add_row(label, text, target, Text(held, style="red") if held == "NO" else held)
    console.print(table)
    if json_out is not None:
        import json

        from pkmctl.io.atomic import atomic_write

        try:
            with atomic_write(json_out) as fh:
                json.dump(results, fh, indent=2)
        except Exception as exc:
            _handle(ctx, exc)
        _KEPT["note"] = f"{json_out} is written"
        console.print(Text(f"wrote {json_out}"))


@app.command("mujoco-model")
def mujoco_model(
    out: Annotated[str, typer.Option(help="The MJCF file to write (FILE.xml).")],
    scenario: Annotated[
        str, typer.Option(help="Built-in scenario name or TOML file: its true plant.")
    ] = "paper",
    rotor_inertia: Annotated[
        float | None,
        typer.Option(help="Rotor inertia per motor, kg m^2 (slide armature); default: plant's."),
    ] = None,
    screw_lead: Annotated[
        float | None, typer.Option(help="Ball-screw lead, m; default: the scenario's.")
    ] = None,
    friction_viscous: Annotated[
        float | None,
        typer.Option(help="Viscous friction, N s/m (slide damping); default: the scenario's."),
    ] = None,
    friction_coulomb: Annotated[
        float | None,
        typer.Option(help="Coulomb friction, N: refused unless 0; default: the scenario's."),
    ] = None,
) -> None:
    """Write the scenario's machine as a MuJoCo model (MJCF), e.g. for MuJoCo's viewer.

    The scenario's rotor inertia and viscous friction ([plant]) become MuJoCo's armature
    and damping, its payload the platform's mass and inertia, its RK4 sub-step (control
    period / sub-steps) the model's timestep; an option given here overrides the
    scenario's. Coulomb friction must be 0: MuJoCo's is a constraint, not
    the tanh law, so a scenario or option with it is refused.
    """
    from pkmctl.errors import PkmctlError
    from pkmctl.io.atomic import atomic_write, check_output_file

    try:
        from pkmctl.plants.mujoco import build_mjcf, scenario_error, scenario_options
    except ImportError as exc:
        if _interrupted(exc):
            raise KeyboardInterrupt from exc
        _fail(str(exc))
    try:  # (a name over 255 bytes raises here: check_output_file says so below)
        folder = Path(out).is_dir() and out.strip()
    except OSError:
        folder = False
    if folder:
        _fail(f"--out {out}: is a folder, give a file name (FILE.xml)")
    given = {
        k: v
        for k, v in (("rotor_inertia", rotor_inertia), ("screw_lead", screw_lead),
                     ("friction_viscous", friction_viscous),
                     ("friction_coulomb", friction_coulomb))
        if v is not None
    }  # fmt: skip
    try:
        out = check_output_file(out, what="--out")
        # the options as scenario fields, so the scenario's ranges check them too
        sc = _load_scenario(scenario, {f"plant.{k}": v for k, v in given.items()})
        step = sc.timing.control_period / sc.timing.substeps  # the loop's RK4 sub-step
        text = build_mjcf(sc.plant(), timestep=step, **scenario_options(sc))
    except (PkmctlError, ValueError) as exc:
        flags = {k: "--" + k.replace("_", "-") for k in given}
        msg = scenario_error(str(exc), flags)
        for k, flag in flags.items():
            if msg.startswith(f"plant.{k} = "):
                msg = flag + msg[len(f"plant.{k}") :]
        if msg.startswith("plant.friction_coulomb"):
            msg += " (--friction-coulomb 0 writes the model without it)"
        _fail(msg)
    try:
        with atomic_write(out) as fh:
            fh.write(text)
    except OSError as exc:
        _fail(f"--out {out}: cannot write: {exc.strerror or exc}")
    _KEPT["note"] = f"{out} is written"
    console.print(f"wrote {out}")


campaign_app = typer.Typer(
    cls=TyperGroup,
    no_args_is_help=True,
    rich_markup_mode="markdown",
    help="Robustness campaigns: many paired runs over factors of a scenario (docs/campaigns.md).",
)
app.add_typer(campaign_app, name="campaign")


def _seconds(s: float) -> str:
    if s < 10:
        return f"{s:.1f} s"
    if s >= 2 * 86400:
        return f"{s / 86400:.1f} days"
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min" if s < 7200 else f"{s / 3600:.1f} h"


#: A run estimated to take longer than this (s) is said before it starts.
LONG_RUN_S = 60.0


def _say_long_run(sc, controller: str, doing: str) -> None:
    """Say a run's estimated time before it starts, if over :data:`LONG_RUN_S`: a valid
    scenario of 3.6e9 periods of 1000 sub-steps (about 27 days) started without a word
    (a tester). Compiling is not in it."""
    from pkmctl.sim import cost
    from pkmctl.sim.simulate import resolve_parts

    parts = resolve_parts(sc, controller)
    loop = "stepped" if parts["plant"].stepper is not None else "single"
    est = cost.run_seconds(sc, parts, loop)
    if est > LONG_RUN_S:
        t = sc.timing
        _say(f"{doing}: {round(t.duration / t.control_period):,} periods of {t.substeps} "
             f"RK4 sub-step{'s' * (t.substeps > 1)}, estimated {_seconds(est)} on a machine "
             "like ours (Ctrl-C stops it; timing.duration, .control_period and .substeps "
             "set its length)")  # fmt: skip


def _campaign_handle(ctx: typer.Context, exc: BaseException, doing: str) -> NoReturn:
    """:func:`_handle` for the campaign commands; running out of memory says what the
    command was doing (``doing``), not the single-run advice about timing.duration."""
    if isinstance(exc, MemoryError) and not _debug(ctx):
        _fail(f"out of memory {doing}")
    _handle(ctx, exc)


def _runs_left(spec, out: Path) -> list[tuple[int, str]]:
    """The runs (cell, controller) a ``--resume`` of the campaign in ``out`` will run (for
    the estimate only: a folder the run refuses counts every run here; the run says why)."""
    from pkmctl.campaign.execute import task_states

    try:
        tasks, done, erred = task_states(spec, out)
    except Exception:  # noqa: BLE001 - the run says what is wrong, in its own words
        tasks, done, erred = spec.tasks(), set(), set()
    return [(r.cell, r.controller) for t in tasks if t.index not in done or t.index in erred
            for r in t.runs]  # fmt: skip


#: A campaign's progress in a log (not a terminal): a line at least this often (s).
LOG_EVERY_S = 60.0


def _n(count: int, noun: str) -> str:
    """``1 cell``, ``2 cells``."""
    return f"{count} {noun}" + "s" * (count != 1)


def _plugin_args(ctx: typer.Context) -> list[str]:
    """The ``--plugin`` options the command was given (to repeat in a command it prints)."""
    plugins = ctx.find_root().params.get("plugin") or []
    return [a for p in plugins for a in ("--plugin", p)]


def _each(spec) -> str:
    """How long each run of a campaign is (a range when ``timing.duration`` is a factor)."""
    durations = spec.durations()
    lo, hi = min(durations), max(durations)
    return f"{lo:g} s each" if lo == hi else f"{lo:g}-{hi:g} s each (by cell)"


@campaign_app.command("run")
def campaign_run(
    ctx: typer.Context,
    spec_file: Annotated[
        str,
        typer.Argument(
            metavar="SPEC", help="The campaign spec (TOML), or a built-in's name: paper-claims."
        ),
    ],
    out: Annotated[
        str, typer.Option(help="Campaign folder: the spec and one Parquet file per task.")
    ] = "pkmctl-campaign",
    workers: Annotated[
        int | None, typer.Option(help="Local worker processes (default: every core).")
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(help="Run on the Dask cluster of this scheduler (tcp://host:8786)."),
    ] = None,
    resume: Annotated[
        bool,
        typer.Option(help="Complete the interrupted campaign in OUT (the same spec).", metavar=""),
    ] = False,
) -> None:
    """Run a campaign: every cell x controller x seed of SPEC.

    Records go to OUT/runs as tasks finish, so an interrupted campaign keeps what it did
    and --resume completes it.
    """
    from pkmctl.campaign.execute import WorkStopped, run_campaign
    from pkmctl.campaign.spec import CampaignSpec
    from pkmctl.io.atomic import check_output_folder

    if workers is not None and workers < 1:
        _fail(f"--workers = {workers}: must be >= 1")
    if workers is not None and scheduler:  # (it was ignored, silently)
        _fail(f"--workers = {workers}: not with --scheduler (the cluster's workers run the tasks)")
    try:
        out = check_output_folder(out, what="--out")
    except Exception as exc:
        _handle(ctx, exc)
    compiles = _Compiles()
    try:
        with compiles.listen():
            spec = _interruptible(
                lambda: CampaignSpec.from_toml(Path(spec_file) if spec_file.strip() else spec_file),
                lambda: "nothing run",
            )
    except Exception as exc:
        _campaign_handle(ctx, exc, "reading the spec: nothing run")
    for note in spec.fuzzy_offset_notes():
        _say(f"warning: {note}")
    existed = (out / "campaign.json").exists()
    if resume and not existed:  # a mistyped --out would start the whole campaign again
        _say(f"--resume: {str(out)!r} holds no campaign yet: starting it there")
    n_workers = workers or (os.cpu_count() or 1)
    tasks = spec.tasks()
    n_workers = min(n_workers, max(1, len(tasks)))  # no more processes than tasks start
    where = (
        f"the cluster at {scheduler}"
        if scheduler
        else f"{n_workers} local worker" + "s" * (n_workers > 1)
    )
    from pkmctl.campaign.store import estimate_seconds, uncompiled_loops

    runs = _runs_left(spec, out) if resume and existed else None
    left = spec.n_runs if runs is None else len(runs)
    work = estimate_seconds(spec, runs)
    estimate = (
        f"{_seconds(work)} of runs on one core (divide by the cluster's cores)"
        if scheduler
        else f"{_seconds(work / n_workers)}"
        + (" (plus a few s to start the workers)" if min(n_workers, len(tasks)) > 1 else "")
    )
    if new := uncompiled_loops(spec):
        estimate += (
            f", plus compiling: {_n(new, 'combination')} of parts and controller "
            f"{'has' if new == 1 else 'have'} not run on this machine with this pkmctl yet, "
            "and the workers compile their loops first (a minute or more each, once)"
        )
    # said once the campaign starts (run_campaign's on_start): above a refusal (a folder
    # another campaign run holds, a plant that cannot be built) it read as if it ran
    header = (
        f"campaign {spec.name!r} ({spec.digest}): {_n(spec.n_runs, 'run')} = "
        f"{_n(len(spec.cells), 'cell')} x {_n(len(spec.controllers), 'controller')} x "
        f"{_n(len(spec.seeds), 'seed')}, in {_n(len(tasks), 'task')} on {where}; "
        + (f"{_n(left, 'run')} left, " if left != spec.n_runs else "")
        + f"estimated {estimate}"
    )
    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} runs"),
        TextColumn("{task.fields[failures]} not ok"),
        TextColumn("{task.fields[rate]:.1f} runs/s"),
        TimeElapsedColumn(),
        TextColumn("{task.fields[left]}"),
        console=err_console,
        disable=not err_console.is_terminal,
    ) as bar:
        task = bar.add_task("running", total=spec.n_runs, failures=0, rate=0.0, left="")
        state = {"done": 0, "said": time.monotonic(), "compiled": False, "since": None,
                 "failures": 0, "compiling": 0, "started": None, "ended": None}  # fmt: skip
        talk = threading.Lock()  # (the lines of the two threads below, one at a time)
        quiet = threading.Event()  # set: the campaign has ended

        seen: list[tuple[float, int]] = []  # (time, runs done) of the last half minute

        def progress(done, failures, total, rate, compiling=0):
            # the time left at the rate of the last 30 s once there are 10 s of it (the
            # session's rate, first compile included, read "about 3.9 h left" for 4.4 min
            # of work: a tester); before that, the session's rate so far. None while the
            # workers compile loops (a rate over compiles read "3.9 h" for 6 min), and the
            # rate's window starts when they are done.
            now = time.monotonic()
            if compiling:
                seen.clear()
                state["since"] = None
            elif state["compiled"] and state["since"] is None:
                state["since"] = (now, done)  # the compiles ended with this task
            seen.append((now, done))
            while len(seen) > 2 and now - seen[1][0] >= 30.0:
                seen.pop(0)
            t0, d0 = seen[0]
            state["compiled"] = state["compiled"] or bool(compiling)
            ts, ds = state["since"] or (now, done)
            if now - t0 >= 10.0 and done > d0:
                rate_left = (done - d0) / (now - t0)
            elif not state["compiled"]:
                rate_left = rate
            else:  # the rate since the compiles ended (the session's counts them)
                rate_left = (done - ds) / (now - ts) if done > ds and now > ts else 0.0
            left = (
                f"about {_seconds((total - done) / rate_left)} left"
                if rate_left > 0 and done < total
                else ""
            )
            if compiling and done < total:
                left = f"the time left once {_n(compiling, 'loop')} compiled"
            step = max(1, total // 10)  # a log (not a terminal) gets a line every 10 %, or
            # a minute (an 85 min campaign was silent 8.5 min); not before a run of this
            # session (a resume's start said "0.0 runs/s")
            due = done // step > state["done"] // step or now - state["said"] >= LOG_EVERY_S
            with talk:
                if not err_console.is_terminal and rate > 0 and due:
                    _say(f"{done}/{total} runs, {failures} not ok, {rate:.1f} runs/s"
                         + (f", {left}" if left else ""))  # fmt: skip
                    state["said"] = now
                if done > state["done"]:
                    state["ended"] = now  # (a task ended: the heartbeat's "last task")
                state.update(done=done, failures=failures, compiling=compiling)
            bar.update(task, completed=done, failures=failures, rate=rate, left=left)

        def heartbeat() -> None:
            # A log's line a minute while no task ends: lines came only as tasks ended, so
            # 2 workers compiling 9 loops left a log silent for 11.5 min (a tester).
            while not quiet.wait(max(0.05, min(5.0, LOG_EVERY_S))):
                with talk:
                    now = time.monotonic()
                    if quiet.is_set() or now - state["said"] < LOG_EVERY_S:
                        continue  # (ended while this waited for the lock: said nothing)
                    c, since = state["compiling"], _seconds(now - state["started"])
                    ended = state["ended"]
                    doing = (
                        f"the workers compile {_n(c, 'loop')} first" if c
                        else "no task has ended yet" if ended is None
                        else f"the last task ended {_seconds(now - ended)} ago"
                    )  # fmt: skip
                    _say(f"{state['done']}/{spec.n_runs} runs, {state['failures']} not ok, "
                         f"{doing} ({since} since the start)")  # fmt: skip
                    state["said"] = now

        def started() -> None:
            _say(header)
            state["said"] = state["started"] = time.monotonic()
            if not err_console.is_terminal:  # (a terminal has its bar's clock)
                threading.Thread(target=heartbeat, name="pkmctl-log-lines", daemon=True).start()

        def on_client(client):
            from pkmctl.campaign.execute import dashboard_link

            link = dashboard_link(client)
            _say(f"dashboard: {link}" if link else "the cluster's scheduler runs no dashboard")

        def resume_command() -> str:
            import shlex

            args = ["pkmctl", *_plugin_args(ctx), "campaign", "run", spec_file, "--out", str(out)]
            if scheduler:
                args += ["--scheduler", scheduler]
            elif workers is not None:
                args += ["--workers", str(workers)]
            return shlex.join([*args, "--resume"])

        def hush() -> None:
            quiet.set()
            with talk:  # (a line being said is said whole, before what follows)
                pass

        def interrupted() -> str:
            from pkmctl.io.atomic import stop

            hush()
            bar.stop()
            stop(out)  # the campaign folder is made whole before this, or not at all
            if not (out / "campaign.json").exists():  # stopped before the folder was made
                return "nothing written"
            if state["done"] >= spec.n_runs:  # (it said "--resume completes it"; a tester)
                from pkmctl.campaign.store import read_records

                statuses = read_records(out, timing=False).column("status").to_pylist()
                if errors := statuses.count("error"):  # (a reviewer)
                    return (f"all {spec.n_runs} runs are kept in {out}, {_n(errors, 'run')} "
                            f"failed with an error: once the cause is fixed, "
                            f"{resume_command()} runs their tasks again")  # fmt: skip
                return (f"all {spec.n_runs} runs are kept in {out}: the campaign is complete "
                        f"(pkmctl campaign report {out} reports it)")  # fmt: skip
            kept = f"{state['done']} of {spec.n_runs} runs kept in {out}"
            if not existed and state["done"] == 0:
                kept = f"no run done yet; the campaign folder {out} is made"
            return f"{kept}; {resume_command()} completes it"

        try:
            with compiles.listen():
                try:
                    done = _interruptible(
                        lambda: run_campaign(
                            spec,
                            out,
                            workers=n_workers,
                            scheduler=scheduler,
                            resume=resume,
                            progress=progress,
                            on_client=on_client,
                            on_start=started,
                        ),
                        interrupted,
                    )
                finally:  # (before what the campaign's end or error says)
                    hush()
        except WorkStopped as exc:  # the runs done are kept
            bar.stop()
            if _debug(ctx):
                raise
            _fail(f"{exc} ({state['done']} of {spec.n_runs} in {out}); {resume_command()} "
                  "completes the campaign")  # fmt: skip
        except OSError as exc:  # a full disk: which file, what is kept, how to go on
            bar.stop()
            if _debug(ctx) or not (out / "campaign.json").exists():
                _campaign_handle(ctx, exc, "writing the campaign")
            _fail(f"{_describe(exc)}; the runs done are kept ({state['done']} of "
                  f"{spec.n_runs} in {out}); once it can be written, {resume_command()} "
                  "completes the campaign")  # fmt: skip
        except Exception as exc:
            bar.stop()
            _campaign_handle(
                ctx, exc, f"running the campaign's tasks ({spec.periods()} control periods a "
                f"run, {n_workers} workers here): fewer --workers, or fewer periods a run "
                f"(duration, timing.control_period); the tasks done are kept (--resume)",
            )  # fmt: skip
    _KEPT["note"] = f"the runs are kept in {out}"
    rate = done.done_now / done.wall_s if done.wall_s > 0 else 0.0
    kept = f" ({done.done_before} done before)" if done.done_before else ""
    again = f", {done.rerun} of them again after an error" if done.rerun else ""
    console.print(
        Text(
            f"{_n(done.done_now, 'run')} in {done.wall_s:.1f} s ({rate:.1f} runs/s){kept}"
            f"{again}; of the {_n(done.runs, 'run')} stored: {done.diverged} diverged, "
            f"{done.errors} failed with an error; records in {out}/runs"
        )
    )
    if done.done_before:  # a resume after an upgrade mixed two versions' records, unsaid
        from pkmctl.campaign.store import mixed_versions

        if mixed := mixed_versions(out):
            _say(f"note: {mixed}")
    if done.errors:  # why, in the words of the errors (a divergence is the metrics' part)
        import shlex

        from pkmctl.campaign.stats import error_messages, error_runs, seeds_named
        from pkmctl.campaign.store import read_records

        table = read_records(out, timing=False)
        why = error_messages(table)
        for msg, n in why[:3]:
            where = seeds_named(error_runs(table, msg))
            _say(f"{n} run{'s' if n > 1 else ''} failed ({where}): {msg}")
        if len(why) > 3:
            _say(f"and {len(why) - 3} other errors: pkmctl campaign report {out} lists them")
        args = ["pkmctl", *_plugin_args(ctx), "campaign", "run", spec_file, "--out", str(out)]
        if scheduler:
            args += ["--scheduler", scheduler]
        elif workers is not None:
            args += ["--workers", str(workers)]
        _say(
            f"{_n(done.errors, 'run')} failed with an error (an error is not a result: the "
            f"statistics leave it out); once the cause is fixed, "
            f"{shlex.join([*args, '--resume'])} runs their tasks again (an edited plugin part "
            f"needs another --out)"
        )
        raise typer.Exit(1)


@campaign_app.command("show")
def campaign_show(
    ctx: typer.Context,
    spec_file: Annotated[
        str,
        typer.Argument(
            metavar="SPEC", help="The campaign spec (TOML), or a built-in's name: paper-claims."
        ),
    ],
) -> None:
    """Print a campaign's spec (to copy and edit) and what it expands to; runs nothing.

    The spec goes to stdout (pkmctl campaign show paper-claims > mine.toml), the cells,
    runs, tasks and the time estimate to stderr.
    """
    from pkmctl.campaign.spec import CampaignSpec

    try:
        spec = _interruptible(
            lambda: CampaignSpec.from_toml(Path(spec_file) if spec_file.strip() else spec_file),
            lambda: "",
        )
    except Exception as exc:
        _campaign_handle(ctx, exc, "reading the spec")
    try:
        _to_stdout(spec.text if spec.text.endswith("\n") else spec.text + "\n", "the spec")
    except OSError as exc:
        _handle(ctx, exc)
    from pkmctl.campaign.store import estimate_seconds

    work = estimate_seconds(spec)
    cores = os.cpu_count() or 1
    _say(
        f"campaign {spec.name!r} ({spec.digest}): {_n(spec.n_runs, 'run')} = "
        f"{_n(len(spec.cells), 'cell')} ({spec.design}) x "
        f"{_n(len(spec.controllers), 'controller')} x {_n(len(spec.seeds), 'seed')}, "
        f"{_each(spec)}, in {_n(len(spec.tasks()), 'task')}; estimated {_seconds(work)} "
        f"on one core, {_seconds(work / cores)} on {cores}"
    )
    for i in range(len(spec.cells)):
        cell = spec.cells[i]
        _say(f"  cell {i}: " + (", ".join(f"{k} = {_spec_value(v)}" for k, v in cell.items())
                                or "base"))  # fmt: skip


def _spec_value(v) -> str:
    """A cell's value as the spec writes it: ``"none"`` for no value, not Python's None."""
    return '"none"' if v is None else repr(v)


@campaign_app.command("report")
def campaign_report(
    ctx: typer.Context,
    folder: Annotated[
        str, typer.Argument(metavar="FOLDER", help="A campaign folder (pkmctl campaign run --out).")
    ],
) -> None:
    """Write a campaign's statistics: FOLDER/report/.

    report.md (which controller is better where, in words), summary.csv, paired.csv,
    divergence.csv and figures of each metric against each factor.
    """
    from pkmctl.report.campaign import write_report

    if not (Path(folder) / "spec.toml").is_file():
        _fail(f"{folder!r}: not a campaign folder (no spec.toml; see pkmctl campaign run --out)")
    cancel, finished, box = threading.Event(), threading.Event(), {}

    def work():
        try:
            box["files"] = write_report(folder, cancel=cancel)
            return box["files"]
        finally:
            finished.set()

    def interrupted() -> str:
        # the report runs on in its thread: stop it, and let it remove its staging folder
        # (FOLDER/report/.pkmctl-*.tmp) before the command exits
        cancel.set()
        finished.wait(30)
        return "the report was written already" if "files" in box else "nothing written"

    try:
        files = _interruptible(work, interrupted)
    except OSError as exc:  # a full disk: the file, and that the old report is kept
        if _debug(ctx):
            raise
        _fail(f"{_describe(exc)}; nothing written (the report folder is as it was)")
    except Exception as exc:
        _campaign_handle(ctx, exc, "reading the records and writing the report: nothing written")
    _KEPT["note"] = "the report was written already"
    console.print(Text(f"wrote {files[0]} and {len(files) - 1} figures"))


def _import_benchmarks() -> None:
    """Make the ``benchmarks`` package of this pkmctl's own checkout importable, or fail
    in one line: the checkout beside an editable install, else the current folder if its
    src/pkmctl holds the same files as the pkmctl running. Any ``benchmarks/bench.py``
    in the current folder ran first, another project's or an older pkmctl's (a tester)."""
    import hashlib

    from pkmctl import _jit

    def same_pkmctl(root: Path) -> bool:
        package = root / "src" / "pkmctl"
        if not (root / "benchmarks" / "bench.py").is_file() or not package.is_dir():
            return False
        if package.resolve() == Path(__file__).resolve().parent:
            return True
        h = hashlib.sha256()
        _jit._hash_files(package.rglob("*.py"), h, package)
        return h.hexdigest()[:20] == _jit.package_stamp()

    here = Path(__file__).resolve().parents[2]  # src/pkmctl/cli.py -> the checkout
    for root in (here, Path.cwd()):
        if same_pkmctl(root):
            loaded = getattr(sys.modules.get("benchmarks"), "__file__", None) or ""
            if not Path(loaded).resolve().is_relative_to(root):  # another found first
                for name in [m for m in sys.modules if m.split(".")[0] == "benchmarks"]:
                    del sys.modules[name]
            sys.path.insert(0, str(root))
            return
    _fail(
        "pkmctl bench runs the benchmarks/ of this pkmctl's source checkout: none beside "
        "it (an installed copy), and the current folder is no checkout of the same files; "
        "run it from the checkout it was installed from (pip install -e . there)"
    )


from pkmctl import cli_identify as _cli_identify  # noqa: E402, F401  (registers excite, identify)


def main() -> None:
    """The ``pkmctl`` command: :data:`app`, then an exit without the interpreter's final
    garbage collections. Every object dies with the process; ``gc.freeze()`` takes them
    out of the collector's sight, so that the shutdown does not traverse them again:
    that took about 0.45 s after a warm ``pkmctl reproduce`` (Numba's, matplotlib's and
    pydantic's objects; docs/performance.md). The shutdown still clears the modules
    (freeing what they hold), flushes the standard streams and runs the atexit
    functions."""
    import gc

    # an interrupt's "after X s" from the command's start, pkmctl's imports included
    # (it counted from the step it stopped: "interrupted after 0.0 s" 2.15 s into
    # excite); a later main() in the same process (tests) from its own start
    from pkmctl._start import T0

    _KEPT.update(t0=time.perf_counter() if _KEPT["mains"] else T0, in_main=True)
    _KEPT["mains"] += 1
    _quiet_matplotlib_home()
    for stream in (sys.stdout, sys.stderr):  # paths, names, a spec's text in any
        try:  # encoding: what it cannot write is escaped (\xe9), not a traceback
            stream.reconfigure(errors="backslashreplace")
        except (AttributeError, ValueError, OSError):
            pass
    try:
        app(prog_name="pkmctl")
    except OSError as exc:  # (typer lets it through: a traceback of 40 lines)
        if not _stdout_failed(exc):
            raise
        # stdout full or closed (> /dev/full, a pipe whose reader quit): the files the
        # command wrote are whole; say so on stderr, and leave nothing for the final flush
        sys.stderr.write(f"error: stdout: {exc.strerror or exc}; the files written are whole\n")
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        sys.exit(1)
    finally:
        _KEPT["in_main"] = False
        gc.freeze()
        # the command has ended and said so: a Ctrl-C now, in the interpreter's shutdown,
        # was exit 130 without a word, or a traceback of the atexit functions with exit 0
        # (a tester, 1 in 3)
        import signal

        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                signal.signal(sig, signal.SIG_IGN)


def _quiet_matplotlib_home() -> None:
    """With a HOME that cannot be written, matplotlib printed a warning of two lines (its
    config folder, "it is highly recommended to set the MPLCONFIGDIR environment
    variable") where pkmctl says its own in one: give it a temporary folder, as it would
    take itself, silently, removed at exit."""
    if os.environ.get("MPLCONFIGDIR"):
        return
    xdg = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    folder = os.path.join(xdg, "matplotlib")
    while not os.path.exists(folder) and os.path.dirname(folder) != folder:
        folder = os.path.dirname(folder)  # where matplotlib would make it (made by it)
    if os.path.isdir(folder) and os.access(folder, os.W_OK | os.X_OK):
        return
    import atexit
    import shutil
    import tempfile

    os.environ["MPLCONFIGDIR"] = tmp = tempfile.mkdtemp(prefix="pkmctl-matplotlib-")
    atexit.register(shutil.rmtree, tmp, ignore_errors=True)


def _stdout_failed(exc: OSError) -> bool:
    """Whether ``exc`` came from writing to stdout (directly or through rich)."""
    tb = exc.__traceback__
    while tb is not None:
        owner = tb.tb_frame.f_locals.get("self")
        if owner is sys.stdout or getattr(owner, "file", None) is sys.stdout:
            return True
        tb = tb.tb_next
    return False
