"""The ``pkmctl`` command (DESIGN.md §5): a thin layer over the library.

    pkmctl reproduce [--scenario NAME|FILE] [--out DIR] [--seed N] [--duration S]
    pkmctl simulate SCENARIO.toml [--controller NAME] [--out DIR] [--format parquet|csv]
    pkmctl scenario [NAME]
    pkmctl bench [--quick] [--json PATH]
    pkmctl mujoco-model --out FILE.xml [--scenario NAME|FILE] [--rotor-inertia J] ...

Bad input exits with status 2 and a one-line message on stderr.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Model, control and simulate the 2RPU-2SPR parallel manipulator "
    "(SMC, FSMC, AFSMC, PD, CTC).",
)
# Tables need ~100 columns; a pipe or a CI log would otherwise get rich's 80.
console = Console(width=max(Console().width, 110))
err_console = Console(stderr=True)


def _fail(message: str, code: int = 2) -> None:
    err_console.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _load_scenario(spec: str):
    from pkmctl.sim.scenario import BUILTINS, Scenario

    if spec in BUILTINS:
        return Scenario.builtin(spec)
    path = Path(spec)
    if path.suffix.lower() == ".toml" or path.exists():
        return Scenario.from_toml(path)
    return Scenario.builtin(spec)  # raises: unknown built-in, with the list


def _announce_compiles(bar: Progress | None = None, task=None):
    """Say what compiles while it compiles: in the progress bar on a terminal (with the
    elapsed time), as plain lines otherwise (a log, CI)."""
    from pkmctl._jit import announce

    def say(event: str, what: str, seconds: float) -> None:
        if event == "start":
            msg = f"compiling {what} (once per machine)…"
        else:
            msg = f"compiled {what} in {seconds:.1f} s"
        if bar is not None and err_console.is_terminal:
            bar.update(task, description=msg)
        else:
            err_console.print(msg, highlight=False)

    return announce(say)


def _rmse_table(results: dict, title: str) -> Table:
    from pkmctl.sim.metrics import RMSE_KEYS

    table = Table(title=title)
    table.add_column("RMSE", no_wrap=True)
    for k in RMSE_KEYS:
        table.add_column(
            k.replace("_deg", " °").replace("_mm", " mm").replace("_m", " m"),
            justify="right",
            no_wrap=True,
        )
    for name, res in results.items():
        r = res.rmse()
        table.add_row(name, *(f"{r[k]:.4g}" for k in RMSE_KEYS))
    return table


@app.command()
def reproduce(
    scenario: Annotated[
        str, typer.Option(help="Built-in scenario name (paper, paper-1khz) or a TOML file.")
    ] = "paper",
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("pkmctl-out"),
    seed: Annotated[int | None, typer.Option(help="Disturbance seed (overrides).")] = None,
    duration: Annotated[float | None, typer.Option(help="Duration in s (overrides).")] = None,
) -> None:
    """Run SMC, FSMC, AFSMC, PD and CTC; write Table 4, Figures 10-26, report.md, time series."""
    from pkmctl.errors import PkmctlError
    from pkmctl.experiment import reproduce as run

    try:
        sc = _load_scenario(scenario)
        if duration is not None or seed is not None:
            changes = {}
            if duration is not None:
                changes["timing.duration"] = duration
            if seed is not None:
                changes["disturbance.seed"] = seed
            sc = sc.replace(**changes)
    except (PkmctlError, ValueError) as exc:
        _fail(str(exc))
    from pkmctl.experiment import CONTROLLER_ORDER

    steps = [*CONTROLLER_ORDER, "series", "table", "figures", "report"]
    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        console=err_console,
        transient=False,
    ) as bar:
        task = bar.add_task("starting", total=len(steps))
        count = {"n": -1}

        def progress(msg: str) -> None:
            count["n"] += 1
            bar.update(task, completed=count["n"], description=msg)
            if not err_console.is_terminal:
                err_console.print(msg, highlight=False)

        try:
            with _announce_compiles(bar, task):
                output = run(sc, out, progress=progress)
        except (PkmctlError, ValueError) as exc:
            _fail(str(exc), code=1)
        bar.update(task, completed=len(steps), description="done")
    console.print(_rmse_table(output.results, f"RMSE, scenario {sc.name!r}"))
    console.print(f"wrote {len(output.files)} files to {out}/ in {output.wall_time_s:.1f} s")
    console.print(f"report: {out / 'report.md'}")


@app.command()
def simulate(
    scenario_file: Annotated[str, typer.Argument(help="Scenario TOML file or built-in name.")],
    controller: Annotated[
        str, typer.Option(help="A registered controller: smc, fsmc, afsmc, pd, ctc.")
    ] = "afsmc",
    out: Annotated[Path, typer.Option(help="Output folder for the time series.")] = Path(
        "pkmctl-out"
    ),
    fmt: Annotated[str, typer.Option("--format", help="parquet or csv.")] = "parquet",
) -> None:
    """Run one controller on a scenario; write its time series (Parquet or CSV) and metadata
    (JSON)."""
    from pkmctl.errors import PkmctlError
    from pkmctl.io.results import save_result
    from pkmctl.parts import names
    from pkmctl.sim.simulate import simulate as run

    if fmt not in ("parquet", "csv"):
        _fail(f"--format = {fmt!r}: must be parquet or csv")
    if controller not in names("controller"):
        _fail(f"--controller = {controller!r}: must be one of {', '.join(names('controller'))}")
    try:
        sc = _load_scenario(scenario_file)
    except (PkmctlError, ValueError) as exc:
        _fail(str(exc))
    try:
        with console.status(f"simulating {controller} on {sc.name!r}"), _announce_compiles():
            result = run(sc, controller=controller)
    except PkmctlError as exc:
        _fail(str(exc), code=1)
    table_path, json_path = save_result(result, out, fmt=fmt)
    console.print(_rmse_table({controller: result}, f"RMSE, scenario {sc.name!r}"))
    console.print(f"wrote {table_path} and {json_path}")


@app.command()
def scenario(
    name: Annotated[str, typer.Argument(help="Built-in scenario name.")] = "paper",
) -> None:
    """Print a built-in scenario as TOML (edit it and pass it to reproduce or simulate)."""
    from pkmctl.errors import PkmctlError
    from pkmctl.sim.scenario import Scenario

    try:
        sys.stdout.write(Scenario.builtin(name).to_toml())
    except PkmctlError as exc:
        _fail(str(exc))


@app.command()
def bench(
    quick: Annotated[bool, typer.Option(help="Short runs (a smoke test).")] = False,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write results as JSON.")] = None,
) -> None:
    """Measure speed on this machine: steps/s, FLC, latency, batch, and peers in one run.

    The measuring code is not installed with pkmctl: it lives in the checkout's
    ``benchmarks/`` folder, which this command finds from the current directory or
    beside an editable install.
    """
    _import_benchmarks()
    from benchmarks.bench import machine_line, rows, run_all

    try:
        results = run_all(quick=quick, progress=lambda m: err_console.print(f"[dim]{m}[/]"))
    except RuntimeError as exc:
        _fail(str(exc), code=1)
    table = Table(title=machine_line(results), title_justify="left")
    for col, justify in (("measurement", "left"), ("result", "right"), ("target", "right")):
        table.add_column(col, justify=justify, no_wrap=True)
    table.add_column("held", justify="center", no_wrap=True)
    for label, text, target, held in rows(results):
        table.add_row(label, text, target, f"[red]{held}[/]" if held == "NO" else held)
    console.print(table)
    if json_out is not None:
        import json

        from pkmctl.io.atomic import atomic_write

        with atomic_write(json_out) as fh:
            json.dump(results, fh, indent=2)
        console.print(f"wrote {json_out}")


@app.command("mujoco-model")
def mujoco_model(
    out: Annotated[Path, typer.Option(help="The MJCF file to write (FILE.xml).")],
    scenario: Annotated[
        str, typer.Option(help="Built-in scenario name or TOML file: its true plant.")
    ] = "paper",
    rotor_inertia: Annotated[
        float, typer.Option(help="Rotor inertia per motor, kg m^2 (slide armature).")
    ] = 0.0,
    screw_lead: Annotated[float, typer.Option(help="Ball-screw lead, m.")] = 0.01,
    friction_viscous: Annotated[
        float, typer.Option(help="Viscous friction, N s/m (slide damping).")
    ] = 0.0,
    friction_coulomb: Annotated[
        float, typer.Option(help="Coulomb friction, N: refused unless 0 (see the message).")
    ] = 0.0,
) -> None:
    """Write the scenario's machine as a MuJoCo model (MJCF), e.g. for MuJoCo's viewer."""
    from pkmctl.errors import PkmctlError
    from pkmctl.io.atomic import atomic_write

    try:
        from pkmctl.plants.mujoco import build_mjcf
    except ImportError as exc:
        _fail(str(exc))
    if out.is_dir():
        _fail(f"--out {out}: is a folder, give a file name (FILE.xml)")
    try:
        text = build_mjcf(
            _load_scenario(scenario).plant(),
            rotor_inertia=rotor_inertia,
            screw_lead=screw_lead,
            friction_viscous=friction_viscous,
            friction_coulomb=friction_coulomb,
        )
    except (PkmctlError, ValueError) as exc:
        _fail(str(exc))
    try:
        with atomic_write(out) as fh:
            fh.write(text)
    except OSError as exc:
        _fail(f"--out {out}: cannot write: {exc.strerror or exc}")
    console.print(f"wrote {out}")


def _import_benchmarks() -> None:
    """Make the checkout's ``benchmarks`` package importable, or fail in one line."""
    import importlib.util

    if importlib.util.find_spec("benchmarks.bench") is not None:
        return
    here = Path(__file__).resolve().parents[2]  # src/pkmctl/cli.py -> the checkout
    for root in (Path.cwd(), here):
        if (root / "benchmarks" / "bench.py").is_file():
            sys.path.insert(0, str(root))
            return
    _fail("pkmctl bench runs from a source checkout: no benchmarks/bench.py here or beside pkmctl")


def main() -> None:  # pragma: no cover - console entry
    app()
