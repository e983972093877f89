"""The ``pkmctl`` command (DESIGN.md §5): a thin layer over the library.

    pkmctl reproduce [--scenario NAME|FILE] [--out DIR] [--seed N] [--duration S]
    pkmctl simulate SCENARIO.toml [--controller NAME] [--out DIR] [--format parquet|csv]
    pkmctl scenario [NAME]
    pkmctl bench [--quick] [--json PATH]

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
    help="Model, control and simulate the 2RPU-2SPR parallel manipulator (SMC, FSMC, AFSMC).",
)
# Tables need ~100 columns; a pipe or a CI log would otherwise get rich's 80.
console = Console(width=max(Console().width, 110))
err_console = Console(stderr=True)


def _fail(message: str, code: int = 2) -> None:
    err_console.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _load_scenario(spec: str):
    from .scenario import BUILTINS, Scenario

    if spec in BUILTINS:
        return Scenario.builtin(spec)
    path = Path(spec)
    if path.suffix.lower() == ".toml" or path.exists():
        return Scenario.from_toml(path)
    return Scenario.builtin(spec)  # raises: unknown built-in, with the list


def _rmse_table(results: dict, title: str) -> Table:
    from .metrics import RMSE_KEYS

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
    """Run SMC, FSMC and AFSMC; write Table 4, Figures 10-26, report.md and the time series."""
    from .errors import PkmctlError
    from .experiment import reproduce as run

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
    steps = ["smc", "fsmc", "afsmc", "series", "table", "figures", "report"]
    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        console=err_console,
        transient=False,
    ) as bar:
        task = bar.add_task("starting (first run compiles, ~1-2 min)", total=len(steps))
        count = {"n": -1}

        def progress(msg: str) -> None:
            count["n"] += 1
            bar.update(task, completed=count["n"], description=msg)

        try:
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
    controller: Annotated[str, typer.Option(help="smc, fsmc or afsmc.")] = "afsmc",
    out: Annotated[Path, typer.Option(help="Output folder for the time series.")] = Path(
        "pkmctl-out"
    ),
    fmt: Annotated[str, typer.Option("--format", help="parquet or csv.")] = "parquet",
) -> None:
    """Run one controller on a scenario; write its time series (CSV) and metadata (JSON)."""
    from .controllers import CONTROLLERS
    from .errors import PkmctlError
    from .results_io import save_result
    from .simulation import simulate as run

    if fmt not in ("parquet", "csv"):
        _fail(f"--format = {fmt!r}: must be parquet or csv")
    if controller not in CONTROLLERS:
        _fail(f"--controller = {controller!r}: must be one of {', '.join(CONTROLLERS)}")
    try:
        sc = _load_scenario(scenario_file)
    except (PkmctlError, ValueError) as exc:
        _fail(str(exc))
    try:
        with console.status(f"simulating {controller} on {sc.name!r}"):
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
    from .errors import PkmctlError
    from .scenario import Scenario

    try:
        sys.stdout.write(Scenario.builtin(name).to_toml())
    except PkmctlError as exc:
        _fail(str(exc))


@app.command()
def bench(
    quick: Annotated[bool, typer.Option(help="Short runs (a smoke test).")] = False,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write results as JSON.")] = None,
) -> None:
    """Measure speed on this machine: steps/s, FLC, latency, batch, and peers in one run."""
    from .bench import machine_line, rows, run_all

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

        from .results_io import atomic_write

        with atomic_write(json_out) as fh:
            json.dump(results, fh, indent=2)
        console.print(f"wrote {json_out}")


def main() -> None:  # pragma: no cover - console entry
    app()
