"""Run a campaign's tasks: local worker processes by default, a Dask cluster by address.

A task (:meth:`CampaignSpec.tasks`) is a pure function of the spec and its runs:
:func:`run_task` returns its records as a pyarrow table and touches no file. The
client writes each table to the store as it arrives (:func:`pkmctl.campaign.store.
write_task`), so workers need no shared file system, a retried task (Dask reruns the
tasks of a lost worker) cannot leave a second copy, and the records do not depend on
where or in which order the tasks ran. With its records a task sends back the source
hash of each user part (a plugin's) it ran: a worker that imported another version of
the plugin than the client's (a Dask worker's own copy) makes error records that say so
(:func:`_same_sources`), not records of code the campaign does not record.

Local execution uses a ``ProcessPoolExecutor`` of spawned processes rather than a Dask
``LocalCluster``: it starts in a fraction of a second, opens no ports, and needs no
scheduler process; a worker lost to a crash breaks the pool, which is rebuilt and the
unfinished tasks submitted again. Each worker process loads the compiled loops from
pkmctl's disk cache once (or compiles them once) and keeps them for all its tasks.
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa

from pkmctl.campaign.spec import CampaignSpec, Task
from pkmctl.campaign.store import (
    cell_parts,
    check_store,
    completed_tasks,
    factor_column,
    factor_value,
    loop_key,
    machine_key,
    metric_columns,
    open_store,
    part_digest,
    read_spec,
    record_session,
    schema,
    stored_statuses,
    task_grouping,
    uncompiled_combinations,
    user_parts,
    write_task,
)
from pkmctl.errors import PkmctlError

__all__ = ["CampaignRun", "dashboard_link", "run_campaign", "run_task"]

_RETRIES = 3


def _metric_values(spec: CampaignSpec, summary: dict | None) -> dict:
    from pkmctl.campaign.store import GROUP_KEYS

    out = {}
    for g in spec.metrics:
        keys = GROUP_KEYS[g]
        v = None if summary is None else summary.get(g)
        if isinstance(v, dict):
            vals = [v[k] for k in keys]
        elif isinstance(v, list):
            vals = v
        else:
            vals = [None] * len(keys)
        out.update(
            {f"{g}_{k}": (None if x is None else float(x)) for k, x in zip(keys, vals, strict=True)}
        )
    return out


def _log_buffers(prep, parts, lanes: int, seeds: list):
    """Log arrays the runs of a task share (one cell, one controller), as the lanes of one
    stack: each batch overwrites the last one's logs, already measured, so only the first
    batch touches fresh memory (as ``simulate_many(keep="metrics")``). The controller's
    log size is its bundle's for the first of ``seeds`` whose build does not raise; if
    every one raises, a dict of each seed's exception is raised in a ``_Refused``."""
    from pkmctl.parts import PartContext
    from pkmctl.sim.loop import LogBuffers
    from pkmctl.sim.simulate import _with_seed

    ctrl = parts["controller"]
    refused = {}
    for seed in seeds:  # a build may refuse some seeds only: its runs record that alone
        sc = _with_seed(prep.scenario, seed)
        ctx = PartContext(prep.plant, prep.model, prep.gains, sc.timing.control_period,
                          prep.flc, sc)  # fmt: skip
        try:
            n_log = int(ctrl.log_size(ctrl.bundle(ctx)))
        except Exception as exc:  # noqa: BLE001 - that seed's run records it
            refused[seed] = exc
            continue
        return LogBuffers.stacked(lanes, prep.t.size, n_log)
    raise _Refused(refused)


class _Refused(Exception):
    """Every seed's build raised: ``errors`` maps each seed to its exception."""

    def __init__(self, errors: dict) -> None:
        super().__init__(next(iter(errors.values())) if errors else "no seeds")
        self.errors = errors


#: The last cells' prepared scenarios of this process, by (spec digest, cell).
_PREPARED: dict[tuple[str, int], object] = {}


def _prepared(spec: CampaignSpec, cell: int):
    """The cell's scenario, validated and prepared for metrics-only runs: computed for the
    first task of a cell that this process runs, and kept for its next ones (a cell's
    tasks, one per controller and chunk of seeds, come one after another). 8-9 ms a task
    of 1 s runs (the scenario's validation, the desired trajectory of every period),
    about a tenth of its cost outside the loops. The digest covers all that makes the
    records, and nothing writes into a prepared scenario."""
    from pkmctl.sim.simulate import metrics_only, prepare

    key = (spec.digest, cell)
    prep = _PREPARED.get(key)
    if prep is None:
        prep = prepare(metrics_only(spec.scenario(cell)), None)
        while len(_PREPARED) >= 4:
            _PREPARED.pop(next(iter(_PREPARED)))
        _PREPARED[key] = prep
    return prep


def _outcomes(prep, parts, seeds: list, buffers: list) -> tuple[list, float]:
    """(per seed a Result or the exception its run raised, wall seconds per run): the
    seeds in one lane loop (:mod:`pkmctl.sim.lanes`) when there are several."""
    from pkmctl.sim.simulate import run_prepared, run_prepared_lanes

    t0 = time.perf_counter()
    if len(seeds) > 1:
        try:
            out = run_prepared_lanes(prep, parts, seeds, buffers)
        except Exception as exc:  # noqa: BLE001 - every run of the batch records it
            out = [exc] * len(seeds)
    else:
        try:
            out = [run_prepared(prep, parts, seeds[0], buffers[0])]
        except Exception as exc:  # noqa: BLE001 - recorded; the campaign goes on
            out = [exc]
    return out, (time.perf_counter() - t0) / len(seeds)


def run_task(spec: CampaignSpec, task: Task, lanes: int | None = None) -> pa.Table:
    """Run one task's runs; their records (:func:`pkmctl.campaign.store.schema`).

    The runs of a task (one cell, one controller) go ``lanes`` at a time through one lane
    loop (default: the machine's SIMD width when the parts have lane forms, else 1); a
    rest of half a batch or less goes one run at a time
    (:func:`~pkmctl.sim.lanes.lane_batches`). A run that diverges is a record with status
    ``"diverged"``, ``diverged_at`` its time and no metrics; any other error of a run is
    status ``"error"`` with its message.
    Pure: same spec and task, same records (but the timing columns).
    """
    from pkmctl.errors import SimulationDiverged
    from pkmctl.sim.lanes import in_batches, lane_count, lanes_supported, padded_lanes
    from pkmctl.sim.metrics import summary
    from pkmctl.sim.simulate import resolve_parts

    rows = []
    host = f"{socket.gethostname()}:{os.getpid()}"
    cell = task.runs[0].cell  # one cell a task
    factors = {factor_column(p): factor_value(spec, p, spec.cells[cell][p]) for p in spec.factors}
    # Records hold the metrics the loop computes over every period (not recomputed from a
    # log): the runs log nothing but t = 0.
    prep = _prepared(spec, cell)
    batches: list[tuple[list, list]] = []  # (runs, their outcomes)
    for controller in dict.fromkeys(r.controller for r in task.runs):
        runs = [r for r in task.runs if r.controller == controller]
        try:
            parts = resolve_parts(prep.scenario, controller)
            _imported(parts)
            n = lanes if lanes is not None else lane_count() if lanes_supported(parts) else 1
            chunks = in_batches(runs, n)
            widest = max(len(c) for c in chunks)
            # builds the controller's bundle: a user's build that refuses this cell is
            # every run's error record, not the campaign's end
            buffers = _log_buffers(prep, parts, padded_lanes(widest) if widest > 1 else 1,
                                   [r.seed for r in runs])  # fmt: skip
        except _Refused as exc:  # every run's build raised: each records its own error
            batches.append((runs, [(exc.errors[r.seed], math.nan) for r in runs]))
            continue
        except Exception as exc:  # noqa: BLE001 - recorded; the campaign goes on
            batches.append((runs, [(exc, math.nan)] * len(runs)))
            continue
        for chunk in chunks:
            out, wall = _outcomes(prep, parts, [r.seed for r in chunk], buffers)
            done = []
            for r in out:  # the metrics now: the next batch overwrites the logs
                if isinstance(r, Exception):
                    done.append((r, wall))
                else:
                    m = summary(r, spec.metrics, source="loop")  # the kept groups
                    done.append(((m, r.info["kernel_seconds"]), wall))
            batches.append((chunk, done))
    for chunk, done in batches:
        for run, (outcome, wall) in zip(chunk, done, strict=True):
            status, at, msg, metrics, kernel = "ok", None, "", None, math.nan
            if isinstance(outcome, SimulationDiverged):
                status, at, msg = "diverged", float(outcome.time), str(outcome)
                if outcome.partial is not None:
                    kernel = outcome.partial.info.get("kernel_seconds", math.nan)
            elif isinstance(outcome, Exception):
                status, msg = "error", f"{type(outcome).__name__}: {outcome}"
            else:
                metrics, kernel = outcome
            row = {
                "spec_hash": spec.digest,
                "cell": run.cell,
                "controller": run.controller,
                "seed": run.seed,
                "task": task.index,
            }
            row.update(factors)
            row.update(status=status, diverged_at=at, message=msg)
            row.update(_metric_values(spec, metrics))
            row.update(wall_s=wall, kernel_s=float(kernel), worker=host)
            rows.append(row)
    order = {(r.controller, r.seed): i for i, r in enumerate(task.runs)}
    rows.sort(key=lambda row: order[(row["controller"], row["seed"])])
    return pa.Table.from_pylist(rows, schema=schema(spec))


def _imported(parts) -> None:
    """Refuse a user part whose module this worker could not import as it started: the
    module ran part way (the part registered) and its runs failed with its import's error
    as the part's, "in the period starting at t = 0 s" (a review)."""
    from pkmctl.parts import PartError
    from pkmctl.sim.workers import IMPORT_FAILED

    for part in parts.values():
        why = None if part.builtin else IMPORT_FAILED.get(part.module.split(".")[0])
        if why is None:
            why = None if part.builtin else IMPORT_FAILED.get(part.module)
        if why is not None:
            raise PartError(
                f"{part.kind} {part.name!r}: this worker could not import its module "
                f"{part.module}: {why}"
            )


#: The source hash of each user part this process ran (:func:`_ran_sources`), by part:
#: taken when it first ran it, as the code it runs is the code imported then.
_RAN: dict[int, tuple[object, str]] = {}


def _ran_sources(spec: CampaignSpec, task: Task) -> dict[str, dict[str, str]]:
    """By controller of ``task``: the source hash (:func:`~pkmctl.campaign.store.
    part_digest`) of each user part its runs use in this process, by ``"KIND NAME"``
    (empty for pkmctl's own parts; a controller this process cannot resolve is left out:
    its runs are error records already)."""
    from pkmctl.sim.simulate import resolve_parts

    scenario = _prepared(spec, task.runs[0].cell).scenario
    out = {}
    for controller in dict.fromkeys(r.controller for r in task.runs):
        try:
            parts = resolve_parts(scenario, controller)
        except Exception:  # noqa: BLE001, S112 - run_task records it for every run
            continue
        hashes = {}
        for part in parts.values():
            if part.builtin:
                continue
            seen = _RAN.get(id(part))
            if seen is None or seen[0] is not part:
                seen = _RAN[id(part)] = (part, part_digest(part)["sha256"])
            hashes[f"{part.kind} {part.name}"] = seen[1]
        out[controller] = hashes
    return out


def _task_result(spec: CampaignSpec, task: Task) -> tuple[pa.Table, dict, str]:
    """What a worker sends back for ``task``: its records (:func:`run_task`), the source
    hash of each user part they were made with there (:func:`_ran_sources`) and of its
    pkmctl (:func:`pkmctl._jit.package_stamp`), for the client to check against the
    campaign's (:func:`_same_sources`)."""
    from pkmctl import _jit

    ran = _ran_sources(spec, task)
    return run_task(spec, task), ran, _jit.package_stamp()


def _same_sources(
    spec: CampaignSpec, table: pa.Table, ran: dict, parts: dict, code: str | None = None
) -> pa.Table:
    """``table``, with each run whose user part was another version than the campaign's
    (``ran``: :func:`_ran_sources` of the worker; ``parts``: :func:`~pkmctl.campaign.
    store.user_parts` of this process, in campaign.json) made an error record that says
    so: a worker that imported another version of a plugin (a Dask worker's own copy) ran
    it, and its records are not those of the code the campaign records. Every run, if
    the worker's pkmctl (``code``, its package stamp) is not this process's: a Dask worker
    with another pkmctl, or one started before a file was edited, went unnoticed (a
    tester's changed line made 8 records differ, exit 0). As any error record, they are
    run again by ``--resume`` (once the workers run the campaign's code), and the other
    runs are kept."""
    from pkmctl import _jit

    mine = _jit.package_stamp()
    if code is not None and code != mine:
        message = (
            f"CodeMismatch: the worker ran another pkmctl (its modules' hash {code}; this "
            f"campaign's {mine}): run the same pkmctl on every worker (restart a worker "
            "started before pkmctl changed), then --resume"
        )
        rows = table.to_pylist()
        for row in rows:
            row.update(status="error", diverged_at=None, message=message)
            row.update(dict.fromkeys(metric_columns(spec.metrics)))
        return pa.Table.from_pylist(rows, schema=table.schema)
    why = {}
    for controller, hashes in ran.items():
        for key, h in hashes.items():
            want = (parts.get(key) or {}).get("sha256")
            if h != want and controller not in why:
                kind, name = key.split(" ", 1)
                why[controller] = (
                    f"PluginMismatch: {kind} {name!r}: the worker ran another version of it "
                    f"(source hash {h}; the campaign's is {want or 'none'}): make the workers "
                    "import the plugin this campaign was started with, then --resume"
                )
    if not why:
        return table
    rows = table.to_pylist()
    for row in rows:
        if row["controller"] in why:
            row.update(status="error", diverged_at=None, message=why[row["controller"]])
            row.update(dict.fromkeys(metric_columns(spec.metrics)))
    return pa.Table.from_pylist(rows, schema=table.schema)


@dataclass
class CampaignRun:
    """What :func:`run_campaign` did: runs done now and before, failures, wall time.

    ``failures`` counts the runs of this session that did not end ok; ``diverged`` and
    ``errors`` the records of the whole folder (this session's and earlier ones') with
    status ``"diverged"`` and ``"error"``; ``rerun`` the runs of tasks run again because
    they held an error record."""

    out: Path
    runs: int
    done_before: int
    done_now: int
    failures: int
    tasks_now: int
    wall_s: float
    complete: bool
    diverged: int = 0
    errors: int = 0
    rerun: int = 0


class _Progress:
    """Calls ``callback(done=, failures=, total=, rate=)``, and ``compiling=`` too when it
    takes it (the CLI: a rate over the workers' first compiles gave "about 3.9 h left"
    for 6 minutes of work)."""

    def __init__(self, callback):
        import inspect

        self.callback = callback
        self.compiling = False
        if callback is not None:
            try:
                params = inspect.signature(callback).parameters.values()
            except (TypeError, ValueError):
                params = []
            self.compiling = any(p.name == "compiling" or p.kind is p.VAR_KEYWORD for p in params)

    def __call__(self, compiling: int = 0, **kw):
        if self.callback is not None:
            if self.compiling:
                kw["compiling"] = compiling
            self.callback(**kw)


def _local_results(spec: CampaignSpec, tasks: list[Task], workers: int) -> Iterable:
    """(task, :func:`_task_result`) as tasks finish, on ``workers`` spawned processes; a broken pool
    (a worker killed) is rebuilt and its unfinished tasks run again."""
    from concurrent.futures import FIRST_COMPLETED, wait
    from concurrent.futures.process import BrokenProcessPool

    from pkmctl.sim.workers import spawn_pool

    if workers == 1:  # no process to start: run here
        for t in tasks:
            yield t, _task_result(spec, t)
        return
    todo = list(tasks)
    modules = part_modules(spec)
    for attempt in range(_RETRIES + 1):
        pool = spawn_pool(workers, modules)
        try:
            futures = {pool.submit(_task_result, spec, t): t for t in todo}
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in finished:
                    task = futures[f]
                    try:
                        result = f.result()
                    except BrokenProcessPool:
                        continue
                    todo.remove(task)
                    yield task, result
            if not todo:
                return
        except BrokenProcessPool:
            pass
        finally:
            pool.shutdown(wait=False, cancel_futures=True)
        if attempt == _RETRIES:
            raise WorkStopped(
                f"a worker process died {_RETRIES + 1} times, running {_tasks_named(spec, todo)}: "
                "a run there ends its process (a plugin that exits, a crash in compiled "
                "code, the system's out-of-memory killer; from a script, a run_campaign "
                'call outside an if __name__ == "__main__": guard, which each worker runs '
                "again); the runs done are kept"
            )


def part_modules(spec: CampaignSpec) -> tuple[str, ...]:
    """The modules, by name, that registered the user parts the campaign's runs use, for
    local worker processes to import: a part registered from Python (``import my_law``
    in a script or notebook, no ``--plugin``) made every one of its runs an error record
    (a tester). A part registered in ``__main__`` is refused here when ``__main__`` has
    no file (a notebook, a prompt): no worker can import it. A script's ``__main__`` is
    run again in each worker, which then registers what the script registers at its top
    level."""
    from pkmctl.campaign.spec import SpecError
    from pkmctl.campaign.store import cell_parts

    names: dict[str, None] = {}
    for combo in cell_parts(spec).values():
        for part in combo.values():
            if part.builtin:
                continue
            module = part.module
            if module in ("__main__", "__mp_main__"):
                if not getattr(sys.modules.get("__main__"), "__file__", None):
                    raise SpecError(
                        f"{part.kind} {part.name!r} is registered in a notebook or at a "
                        "prompt, which worker processes cannot import: define it in a "
                        "module and import that, or run with workers=1"
                    )
                continue
            if module and not module.startswith("pkmctl."):
                names[_importable(module)] = None
    return tuple(names)


def _importable(module: str) -> str:
    """How a worker can import ``module``: by its name, or by its file where the name
    does not lead to it (loaded from a path off sys.path; a reviewer)."""
    from importlib.machinery import PathFinder

    try:  # by sys.path alone (importlib.util.find_spec answers from sys.modules)
        found = PathFinder.find_spec(module.split(".")[0]) is not None
    except (ImportError, ValueError):
        found = False
    file = getattr(sys.modules.get(module), "__file__", None) or ""
    return module if found or not file.endswith(".py") else file


class WorkStopped(PkmctlError, RuntimeError):
    """The campaign's workers cannot go on: a local worker process that keeps dying, a
    Dask cluster that lost its scheduler or the workers holding the campaign (one line;
    the runs done are kept and ``--resume`` completes the campaign)."""


def _tasks_named(spec: CampaignSpec, tasks: list[Task], most: int = 3) -> str:
    """``task 3 (cell 1: payload.mass = 5, controller crasher)``, up to ``most`` of them."""

    def one(t: Task) -> str:
        cells = sorted({r.cell for r in t.runs})
        ctrl = ", ".join(dict.fromkeys(r.controller for r in t.runs))
        where = ", ".join(f"{k} = {v}" for k, v in spec.cells[cells[0]].items())
        cell = f"cell {cells[0]}" + (f": {where}" if where else "")
        if len(cells) > 1:
            cell = f"cells {cells[0]}-{cells[-1]}"
        return f"task {t.index} ({cell}; controller {ctrl})"

    more = f" and {len(tasks) - most} more" if len(tasks) > most else ""
    return "; ".join(one(t) for t in tasks[:most]) + more


def dashboard_link(client) -> str | None:
    """The dashboard's address of a Dask client's scheduler, or None if it runs none or
    it does not answer from here within 1 s. (``dask scheduler --no-dashboard`` still
    serves HTTP at the dashboard's port, 8787 by default, where the link's page is a 404:
    a tester was given that link.)"""
    import urllib.request

    try:
        info = client.scheduler_info()
        if "dashboard" not in info.get("services", {}):
            return None
        link = client.dashboard_link
        with urllib.request.urlopen(link, timeout=1.0) as page:  # noqa: S310 - http(s) only
            return link if page.status == 200 and link.startswith(("http:", "https:")) else None
    except Exception:  # noqa: BLE001 - a link is a courtesy; the campaign goes on
        return None


class SchedulerError(PkmctlError, OSError):
    """The Dask scheduler given cannot be reached (one line: the address and why)."""


#: Seconds a scheduler has to answer Dask's handshake (docs/campaigns.md: "within 10 s").
CONNECT_SECONDS = 10.0


def _handshake(address: str, seconds: float) -> None:
    """Connect to ``address`` and exchange Dask's handshake, all within ``seconds``.

    ``Client(address, timeout=...)`` bounds the TCP connection only: a server that accepts
    it but is not Dask (an HTTP server) never answers the handshake, and the client waited
    for ever; one that answers something else made it allocate what the first bytes
    announce (a MemoryError)."""
    import asyncio

    from distributed.comm import connect

    async def probe():  # a refused connection is retried: its error comes before ours
        comm = await connect(address, timeout=round(0.8 * seconds, 1))
        await comm.close()

    asyncio.run(asyncio.wait_for(probe(), seconds))


def _connect(address: str, seconds: float | None = None):
    """A Dask client of the scheduler at ``address``, before anything is written: an address
    that is malformed, does not answer Dask's handshake within ``seconds`` (default
    :data:`CONNECT_SECONDS`), or answers something else is a :class:`SchedulerError`."""
    from distributed import Client

    seconds = CONNECT_SECONDS if seconds is None else seconds

    def fail(why: str) -> SchedulerError:
        return SchedulerError(f"--scheduler {address!r}: cannot connect ({why}); nothing written")

    try:
        _handshake(address, seconds)
    except TimeoutError:  # asyncio's too, since Python 3.11
        raise fail(f"no Dask handshake within {seconds:g} s: not a Dask scheduler?") from None
    except MemoryError:
        raise fail("its answer is not Dask's protocol: not a Dask scheduler?") from None
    except Exception as exc:  # noqa: BLE001 - whatever the address does, one line
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise fail(why) from None
    try:
        return Client(address, timeout=f"{seconds:g}s")
    except MemoryError:
        raise fail("its answer is not Dask's protocol: not a Dask scheduler?") from None
    except Exception as exc:  # noqa: BLE001 - one line, nothing written
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise fail(why) from None


def _dask_results(spec: CampaignSpec, tasks: list[Task], client, on_client=None) -> Iterable:
    """(task, :func:`_task_result`) as tasks finish on the Dask cluster at ``address``.

    A task lost with its worker is run again by the scheduler on another worker; the
    scheduler gives up on a task after it was on ``distributed.scheduler.allowed-failures``
    (default 3) workers that died. ``retries`` covers a task that raises (run_task
    records a run's own errors, so that is the worker's trouble: memory, a broken
    import). Keys are the spec hash and task number, so a task is never run twice for
    one client, and its table is written once, as it arrives."""
    import logging
    from concurrent.futures import CancelledError

    from distributed import KilledWorker, as_completed

    # its own traceback of a lost scheduler; the one line is ours (WorkStopped)
    log = logging.getLogger("distributed.client")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        yield from _dask_stream(spec, tasks, client, on_client, as_completed)
    except KilledWorker as exc:  # (it read "KilledWorker: ... (an internal error ...)")
        key = str(exc.task)
        which = [t for t in tasks if key == f"pkmctl-{spec.digest}-task-{t.index}"]
        raise WorkStopped(
            f"{_tasks_named(spec, which) if which else key} ended each worker process it ran "
            f"on, {exc.allowed_failures + 1} of them (the scheduler's allowed-failures): a run "
            "there ends its process (a plugin that exits, a crash in compiled code, the "
            "system's out-of-memory killer); the runs done are kept"
        ) from None
    except (CancelledError, OSError) as exc:
        # (a lost scheduler cancels every future; Dask's CommClosedError, an OSError, may
        # come first; a task's own error is raised as it was)
        if isinstance(exc, OSError) and not _comm_closed(exc):
            raise
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise WorkStopped(
            f"the Dask cluster stopped the campaign's work ({type(exc).__name__}: {_clip(why)}): "
            "its scheduler went away, or every worker holding the campaign's spec did (a run "
            "that ends its worker process takes the spec with each worker it runs on: if "
            "--resume stops the same way, local workers, without --scheduler, name its "
            "task); the runs done are kept"
        ) from None
    finally:
        log.setLevel(level)


def _comm_closed(exc: BaseException) -> bool:
    from distributed.comm.core import CommClosedError

    return isinstance(exc, CommClosedError | ConnectionRefusedError | ConnectionResetError)


def _clip(text: str, limit: int = 160) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _dask_stream(spec, tasks, client, on_client, as_completed) -> Iterable:
    with client:
        if on_client is not None:
            on_client(client)
        try:
            spec_f = client.scatter(spec, broadcast=True)
        except Exception as exc:  # noqa: BLE001 - the workers' own failure, one line
            if isinstance(exc, OSError) and _comm_closed(exc):
                raise
            why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise WorkStopped(
                f"the Dask workers could not take the campaign's spec ({type(exc).__name__}: "
                f"{_clip(why)}): do they run this pkmctl (a worker started before pkmctl "
                "changed, another version on that machine) with the plugins' modules? "
                "Restart them; no run was made"
            ) from None
        futures = {
            client.submit(
                _task_result,
                spec_f,
                t,
                key=f"pkmctl-{spec.digest}-task-{t.index}",
                pure=True,
                retries=_RETRIES,
            ): t
            for t in tasks
        }
        for f in as_completed(futures):
            yield futures[f], f.result()


def task_states(spec: CampaignSpec, out: str | Path) -> tuple[list[Task], set[int], set[int]]:
    """The tasks of the campaign folder ``out`` (in the grouping it was started with), the
    indices of those with a file, and of those whose file holds an error record (a resume
    runs the tasks without a file and those: docs/campaigns.md, "Errors"). A file of
    another campaign, or holding another task's runs, is a SpecError naming it."""
    runs_dir = Path(out) / "runs"
    tasks = spec.tasks(*task_grouping(out))
    done = completed_tasks(runs_dir, spec.digest, tasks)
    erred = {i for i, c in stored_statuses(runs_dir, len(tasks)).items() if c.get("error")}
    return tasks, done, erred


def run_campaign(
    spec: CampaignSpec,
    out: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    progress: Callable | None = None,
    on_client: Callable | None = None,
    stop_after: int | None = None,
    on_start: Callable[[], None] | None = None,
) -> CampaignRun:
    """Run (or, with ``resume``, complete) a campaign into the store at ``out``.

    Parameters
    ----------
    spec : CampaignSpec
        The validated campaign.
    out : path
        The campaign folder (:mod:`pkmctl.campaign.store`).
    workers : int, optional
        Local worker processes (default: every core). Ignored with ``scheduler``.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``): run there.
    resume : bool
        Complete the campaign in ``out`` (the same spec): run only the tasks without a
        file and those whose file holds an error record (a run that raised). Without it
        an existing campaign folder is refused.
    progress : callable, optional
        Called as ``progress(done=, failures=, total=, rate=)`` after each task, with
        ``compiling=`` too if it takes it: the combinations of parts and controller whose
        loops the workers are compiling first (none of their tasks has ended).
    on_client : callable, optional
        Called with the Dask client once connected (e.g. to print its dashboard link).
    stop_after : int, optional
        Stop after this many tasks (a deliberate interruption, for tests).
    on_start : callable, optional
        Called once every check has passed and the folder is held, before the first task
        (the CLI prints what will run then, not above a refusal).
    """
    out = Path(out)
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"--workers = {workers}: must be >= 1")
    client = _connect(scheduler) if scheduler is not None else None
    try:  # the client is closed however this ends, also with no task left to send
        return _run(spec, out, client, scheduler, workers, resume, progress, on_client,
                    stop_after, on_start)  # fmt: skip
    finally:
        if client is not None:
            client.close()


def compile_user_parts(spec: CampaignSpec) -> int:
    """Compile (or load from the disk cache) the loop of every combination of parts the
    campaign runs that holds a user part (a plugin's), in this process, before anything
    is written: a part that does not compile stops the campaign here, in one line
    (:class:`~pkmctl.parts.PartError`), instead of making every one of its runs an error
    record. One control period of the combination's first cell is run, through the loop
    its tasks use (lanes or not); an error of that run itself (a step that raises) is
    left to the runs, which record it. The workers then load the compiled loop from the
    cache. Returns the combinations compiled."""
    from numba.core.errors import NumbaError

    from pkmctl.parts import PartError
    from pkmctl.sim.lanes import lanes_supported
    from pkmctl.sim.simulate import metrics_only, prepare, run_prepared, run_prepared_lanes

    n = 0
    for (cell, _), parts in cell_parts(spec).items():
        if all(p.builtin for p in parts.values()):
            continue
        sc = spec.scenario(cell)
        sc = sc.replace(**{"timing.duration": sc.timing.control_period})
        n += 1
        try:
            prep = prepare(metrics_only(sc), None)
            if lanes_supported(parts):
                run_prepared_lanes(prep, parts, [spec.seeds[0]] * 2)
            else:
                run_prepared(prep, parts, spec.seeds[0])
        except PartError as exc:
            if isinstance(exc.__cause__, NumbaError):
                raise PartError(f"{exc}; nothing run") from exc
        except Exception:  # noqa: BLE001, S110 - the run's own error: its records say it
            pass
    return n


def _run(
    spec, out, client, scheduler, workers, resume, progress, on_client, stop_after, on_start=None
):
    """:func:`run_campaign` once connected (``client``: a Dask client, or None: local)."""
    parts = user_parts(spec)
    if client is None and workers > 1:
        part_modules(spec)  # a part no worker process can import: refused before anything
    check_store(out, spec, resume=resume, parts=parts)  # refused before compiling
    _check_plants(spec)
    compile_user_parts(spec)
    runs_dir = open_store(out, spec, resume=resume, parts=parts)
    with _folder_lock(out, runs_dir):
        if on_start is not None:
            on_start()
        return _run_locked(spec, out, runs_dir, client, scheduler, workers, progress,
                           on_client, stop_after, parts)  # fmt: skip


def _check_plants(spec: CampaignSpec) -> None:
    """Each plant kind the cells use, built once here: a plant 'mujoco' without MuJoCo
    was an error record per run (exit 1) after the workers had compiled their loops."""
    from pkmctl.campaign.store import cell_parts
    from pkmctl.sim.simulate import check_machine

    seen = set()
    for (i, _), combo in cell_parts(spec).items():
        if combo["plant"].name not in seen:
            seen.add(combo["plant"].name)
            check_machine(spec.scenario(i))


@contextlib.contextmanager
def _folder_lock(out: Path, runs_dir: Path):
    """Hold the campaign folder for this run: a second ``campaign run --resume`` into it
    while one runs is refused, where it ran every task not yet written a second time (a
    tester: 72 runs twice). An flock on ``runs/``, which no run replaces; the system
    releases it when the process ends, however it ends."""
    from pkmctl.errors import OutputError

    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: no lock
        yield
        return
    fd = os.open(runs_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise OutputError(
                f"{str(out)!r}: another pkmctl campaign run is running into this folder; "
                "wait for it to end (or stop it), then --resume"
            ) from None
        yield
    finally:
        os.close(fd)


def _run_locked(spec, out, runs_dir, client, scheduler, workers, progress, on_client,
                stop_after, parts):  # fmt: skip
    """:func:`_run` once the store is open and held."""
    if spec.base.fuzzy.fis is not None or spec.fis_files:  # the runs read the folder's
        spec = read_spec(out)  # copies of the .fis files: their content is the spec hash's
    tasks, done, erred = task_states(spec, out)
    todo = [t for t in tasks if t.index not in done or t.index in erred]
    before = sum(len(t.runs) for t in tasks if t.index in done and t.index not in erred)
    rerun = sum(len(t.runs) for t in tasks if t.index in erred)
    where = f"dask {scheduler}" if scheduler else f"{workers} local worker" + "s" * (workers > 1)
    if todo:  # (a resume with nothing left to run added a session: docs/campaigns.md
        record_session(out, where, parts)  # records "each session that ran tasks")
    t0 = time.perf_counter()
    report = _Progress(progress)
    now = failures = n_tasks = 0
    # the combinations whose loops the workers compile first: one is done when a task of
    # it has ended
    compiling = uncompiled_combinations(spec) if report.compiling else set()
    loops = {(machine_key(spec.cells[i]), c): loop_key(p)
             for (i, c), p in cell_parts(spec).items()} if compiling else {}  # fmt: skip
    report(done=before, failures=0, total=spec.n_runs, rate=0.0, compiling=len(compiling))
    if client is not None:
        stream = _dask_results(spec, todo, client, on_client)
    else:
        stream = _local_results(spec, todo, min(workers, max(1, len(todo))))
    try:
        for task, (table, ran, code) in stream:
            table = _same_sources(spec, table, ran, parts, code)  # the campaign's code?
            write_task(runs_dir, task.index, table)
            n_tasks += 1
            now += table.num_rows
            failures += sum(s != "ok" for s in table.column("status").to_pylist())
            elapsed = time.perf_counter() - t0
            for r in task.runs:
                compiling.discard(loops.get((machine_key(spec.cells[r.cell]), r.controller)))
            report(done=before + now, failures=failures, total=spec.n_runs, rate=now / elapsed,
                   compiling=len(compiling))  # fmt: skip
            if stop_after is not None and n_tasks >= stop_after:
                break
    finally:
        close = getattr(stream, "close", None)
        if close is not None:
            close()
    complete = len(completed_tasks(runs_dir)) == len(tasks)
    counts = stored_statuses(runs_dir, len(tasks)).values()
    return CampaignRun(out, spec.n_runs, before, now, failures, n_tasks,
                       time.perf_counter() - t0, complete,
                       diverged=sum(c.get("diverged", 0) for c in counts),
                       errors=sum(c.get("error", 0) for c in counts), rerun=rerun)  # fmt: skip
