"""The result store: one Parquet file per task, the spec beside them (DESIGN.md §8).

Layout of a campaign folder::

    spec.toml            the spec as written
    scenario.toml        its base scenario (the spec may name a file elsewhere)
    fuzzy.fis            a copy of the .fis file the base scenario names, if any (the
                         stored scenario names this copy)
    fis/0123abcd....fis  copies of the .fis files a factor's values name (campaign.json's
                         fis_copies maps each value as written to its copy)
    campaign.json        its digest, runs, tasks, task size, record columns, the
                         source hash of each user part (a plugin's) its runs use, and
                         each session that ran tasks (when, where, which versions)
    runs/task-00017.parquet    the records of task 17, written atomically, once

Each file appears whole or not at all (:func:`pkmctl.io.atomic.atomic_write`), and no
file has two writers, so a crash loses at most the tasks in flight and a resume runs
exactly the tasks without a file. Only files named as one of the campaign's tasks
count (not a stray ``task-00017 (copy).parquet``), and a run found in two files is
refused. Read every record with :func:`read_records`
(pyarrow) or query them with DuckDB (:func:`query`)::

    SELECT controller, avg(rmse_after_1s_z_mm) FROM 'DIR/runs/*.parquet' GROUP BY 1
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from pkmctl.campaign.spec import (
    LEGACY_TASK_MULTIPLE,
    LEGACY_TASK_SECONDS,
    TASK_MULTIPLE,
    TASK_SECONDS,
    CampaignSpec,
    SpecError,
)
from pkmctl.io.atomic import atomic_write, unless_stopped
from pkmctl.parts import part_digest
from pkmctl.sim import cost
from pkmctl.sim.metrics import RMSE_KEYS

__all__ = [
    "TIMING_COLUMNS",
    "check_store",
    "completed_tasks",
    "factor_column",
    "metric_columns",
    "open_store",
    "part_digest",
    "query",
    "read_records",
    "read_spec",
    "record_session",
    "stored_inputs",
    "user_parts",
    "schema",
    "stored_statuses",
    "task_grouping",
    "task_seconds",
    "write_task",
]

#: Columns that say how long a run took and where: they differ between two runs of the
#: same campaign; every other column is reproducible bit for bit.
TIMING_COLUMNS = ("wall_s", "kernel_s", "worker")
GROUP_KEYS = {
    "rmse": RMSE_KEYS,
    "rmse_after_1s": RMSE_KEYS,
    "max_error": RMSE_KEYS,
    "chattering_N_per_s": ("1", "2", "3", "4"),
    "peak_force_N": ("1", "2", "3", "4"),
}


def factor_column(path: str) -> str:
    """The record column of a factor: ``f.`` and its dotted path."""
    return f"f.{path}"


def metric_columns(groups) -> list[str]:
    """The record columns of the kept metric groups, e.g. ``rmse_after_1s_z_mm``."""
    return [f"{g}_{k}" for g in groups for k in GROUP_KEYS[g]]


def _numeric(values) -> bool:
    return all(
        v is None or (isinstance(v, int | float) and not isinstance(v, bool)) for v in values
    )


def _strings(values) -> bool:
    return all(v is None or isinstance(v, str) for v in values)


def schema(spec: CampaignSpec) -> pa.Schema:
    """The records' columns: key, factors, status, metrics, timing."""
    fields = [
        pa.field("spec_hash", pa.string()),
        pa.field("cell", pa.int64()),
        pa.field("controller", pa.string()),
        pa.field("seed", pa.int64()),
        pa.field("task", pa.int64()),
    ]
    for p in spec.factors:
        numeric = _numeric([c[p] for c in spec.cells])
        fields.append(pa.field(factor_column(p), pa.float64() if numeric else pa.string()))
    fields += [
        pa.field("status", pa.string()),
        pa.field("diverged_at", pa.float64()),
        pa.field("message", pa.string()),
    ]
    fields += [pa.field(m, pa.float64()) for m in metric_columns(spec.metrics)]
    fields += [
        pa.field("wall_s", pa.float64()),
        pa.field("kernel_s", pa.float64()),
        pa.field("worker", pa.string()),
    ]
    return pa.schema(fields)


def factor_value(spec: CampaignSpec, path: str, value):
    """A cell's factor value as its column stores it: a float if every value of the factor
    is a number (or none), the text itself if every one is a string (or none), else JSON
    text (a list, or a mix)."""
    values = [c[path] for c in spec.cells]
    if _numeric(values):
        return None if value is None else float(value)
    if _strings(values):
        return value
    return json.dumps(value)


#: A fuzzy system's file, copied into the campaign folder (:func:`open_store`).
FIS_COPY = "fuzzy.fis"


def _stored_scenario(spec: CampaignSpec) -> str:
    """The base scenario as ``scenario.toml`` holds it: its ``.fis`` file, if any, is the
    copy beside it (:data:`FIS_COPY`, relative: the folder can move)."""
    if spec.base.fuzzy.fis is None:
        return spec.base.to_toml()
    import tomli_w

    data = spec.base.model_dump(exclude_none=True, by_alias=True)
    data["fuzzy"]["fis"] = FIS_COPY
    return tomli_w.dumps(data)


def cell_parts(spec: CampaignSpec) -> dict[tuple[int, str], dict]:
    """The parts (kind -> :class:`~pkmctl.parts.Part`) each combination of the campaign
    runs, by (a cell that runs it, controller): one entry per controller and distinct
    machine (the cells that set no ``plant.*``, ``sensor.*`` or ``actuators.*`` field
    differently run the same parts)."""
    from pkmctl.sim.simulate import resolve_parts

    first: dict[str, int] = {}
    for i, cell in enumerate(spec.cells):
        first.setdefault(machine_key(cell), i)
    out = {}
    for i in first.values():
        sc = spec.scenario(i)
        for c in spec.controllers:
            out[(i, c)] = resolve_parts(sc, c)
    return out


#: The scenario sections that choose a run's plant, sensor and actuator.
_MACHINE = ("plant", "sensor", "actuators")


def machine_key(cell: dict) -> str:
    """What of a cell chooses its parts: cells of one key run the same parts."""
    machine = {f: v for f, v in cell.items() if f.split(".")[0] in _MACHINE}
    return json.dumps(machine, sort_keys=True, default=str)


def loop_key(parts: dict) -> tuple[tuple[str, str], ...]:
    """What of a combination chooses its compiled loop: its parts, by role and name. The
    values of a cell's ``plant.*``, ``sensor.*`` and ``actuators.*`` fields (a force
    limit, a friction) are the loop's arguments, not part of it."""
    return tuple((role, parts[role].name) for role in sorted(parts))


#: (kept under their old names: pkmctl.sim.cost holds the model)
ESTIMATE_PERIOD = cost.PERIOD
ESTIMATE_RUN = cost.RUN


def estimate_seconds(spec: CampaignSpec, runs=None) -> float:
    """Estimated seconds of work of ``runs`` (default: all the campaign's) on one core of
    a machine like ours, unloaded: each run's periods at the cost of its loop, its
    sub-steps and its parts (:mod:`pkmctl.sim.cost`), plus a run's cost outside it."""
    from pkmctl.sim.lanes import lane_count, lanes_supported

    parts = {(machine_key(spec.cells[i]), c): p for (i, c), p in cell_parts(spec).items()}
    durations = spec.durations()
    loops, scale = {}, {}
    for key, p in parts.items():
        if p["plant"].stepper is not None:
            loops[key], scale[key] = "stepped", 1.0
        elif lanes_supported(p):
            loops[key], scale[key] = "lanes", 8 / max(1, min(8, lane_count()))
        else:
            loops[key], scale[key] = "single", 1.0
    if runs is None:
        runs = [(cell, c) for cell in range(len(spec.cells)) for c in spec.controllers
                for _ in spec.seeds]  # fmt: skip
    total = 0.0
    for cell, c in runs:
        timing = spec.base.timing
        period = float(spec.cells[cell].get("timing.control_period", timing.control_period))
        substeps = int(spec.cells[cell].get("timing.substeps", timing.substeps))
        key = (machine_key(spec.cells[cell]), c)
        loop = loops[key]
        each = cost.period_seconds(parts[key], substeps, loop) * scale[key]
        total += each * round(durations[cell] / period) + cost.RUN[loop]
    return total


def uncompiled_loops(spec: CampaignSpec) -> int:
    """How many combinations :func:`uncompiled_combinations` gives."""
    return len(uncompiled_combinations(spec))


def uncompiled_combinations(spec: CampaignSpec) -> set[tuple[tuple[str, str], ...]]:
    """The campaign's combinations of pkmctl's own parts, as their :func:`loop_key`, that
    have no loop that ran on this machine with these sources: the workers compile those
    first, which :func:`estimate_seconds` leaves out (a tester's estimate of 1.1 s took
    250 s on an empty cache). Cells that differ only in a value (``actuators.force_limit``)
    run one loop: counted once (they were counted apart, and the progress line waited
    for a task of each, minutes after the loop had compiled: a tester). The loops asked
    for are those its tasks run
    (:func:`~pkmctl.campaign.execute.run_task`): the lane loop for a batch of several
    seeds, the single loop for a run alone (a rest of half a batch or less; asking for
    the lane loop of a campaign of 3 seeds, which never builds it, said "plus
    compiling" on every run: a tester)."""
    from pkmctl.sim.lanes import lane_batches, lane_count, lanes_compiled, lanes_supported
    from pkmctl.sim.loop import is_compiled

    parts = {(machine_key(spec.cells[i]), c): p for (i, c), p in cell_parts(spec).items()}
    needs: dict[tuple[str, str], set[int]] = {}
    widths: dict[tuple[str, int], set[int]] = {}  # (controller, runs in a task): widths
    L = lane_count()
    for t in spec.tasks():
        key_cell = machine_key(spec.cells[t.runs[0].cell])
        for c in dict.fromkeys(r.controller for r in t.runs):
            key = (key_cell, c)
            k = sum(r.controller == c for r in t.runs)
            if (c, k) not in widths:
                n = L if lanes_supported(parts[key]) else 1
                widths[(c, k)] = {min(w, 2) for w in lane_batches(k, n)}
            needs.setdefault(key, set()).update(widths[(c, k)])

    def compiled(p, need: set[int]) -> bool:
        return all(lanes_compiled(p) if w > 1 else is_compiled(p) for w in need)

    return {
        loop_key(p)
        for key, p in parts.items()
        if all(part.builtin for part in p.values()) and not compiled(p, needs.get(key, {1}))
    }


def mixed_versions(out: str | Path) -> str:
    """A sentence when the campaign in ``out`` was run by more than one version of pkmctl's
    code (its sessions' ``pkmctl_sources``; a resume after an upgrade), else "". Records
    of both are kept and cannot be told apart (a tester: nothing said it)."""
    try:
        sessions = json.loads((Path(out) / "campaign.json").read_text(encoding="utf-8"))
        sessions = sessions.get("sessions", [])
    except (OSError, ValueError, AttributeError):
        return ""
    seen: dict[str, str] = {}
    for entry in sessions:
        if isinstance(entry, dict) and entry.get("pkmctl_sources"):
            seen.setdefault(entry["pkmctl_sources"], str(entry.get("pkmctl", "?")))
    if len(seen) < 2:
        return ""
    named = ", ".join(f"{v} (sources {k})" for k, v in seen.items())
    return (
        f"its records were made by {len(seen)} versions of pkmctl's code: {named}, in the "
        "order of their sessions in campaign.json; run into another folder to keep them apart"
    )


def user_parts(spec: CampaignSpec) -> dict[str, dict]:
    """The user parts (not pkmctl's: a plugin's) the campaign's runs use, by ``"KIND
    NAME"``: ``sha256`` (16 hex digits) of their source files' content and of the values
    their compiled code freezes in (:func:`pkmctl.parts.global_values`), and ``files``,
    where they were read. Part of what a campaign is: a resume with another version of a
    part is refused (:func:`open_store`), else its records would mix two versions."""
    parts = {}
    for combo in cell_parts(spec).values():
        for part in combo.values():
            if not part.builtin:
                parts[f"{part.kind} {part.name}"] = part
    return {key: part_digest(part) for key, part in sorted(parts.items())}


def _check_parts(out: Path, old: dict, parts: dict[str, dict]) -> None:
    """Refuse a resume whose user parts' sources differ from those the campaign started
    with (a folder made before they were recorded has none to compare)."""
    for key, now in parts.items():
        then = (old.get("user_parts") or {}).get(key)
        if then is None or then.get("sha256") == now["sha256"]:
            continue
        kind, name = key.split(" ", 1)
        files = ", ".join(Path(f).name for f in now["files"]) or "no file"
        raise SpecError(
            f"--resume: {kind} {name!r}: its source, or a value its code reads, changed "
            f"since the campaign in {str(out)!r} started ({files}); its records would mix "
            f"two versions of it: restore them, or run the campaign into another --out"
        )


def _manifest(spec: CampaignSpec, fis_copies: dict[str, str] | None = None,
              parts: dict[str, dict] | None = None) -> dict:  # fmt: skip
    out = {
        "name": spec.name,
        "spec_hash": spec.digest,
        "runs": spec.n_runs,
        "tasks": len(spec.tasks(TASK_SECONDS, TASK_MULTIPLE)),
        "task_seconds": TASK_SECONDS,
        "task_multiple": TASK_MULTIPLE,
        "columns": schema(spec).names,
        # spec.toml as written: while its text is this, it is read with the stored inputs
        "spec_text_sha256": hashlib.sha256(spec.text.encode()).hexdigest(),
    }
    if fis_copies:
        out["fis_copies"] = fis_copies
    if parts:
        out["user_parts"] = parts
    return out


#: The folder of the copies of the .fis files a factor's values name (:func:`open_store`).
FIS_COPIES = "fis"


def _factor_fis(spec: CampaignSpec) -> dict[str, tuple[str, bytes]]:
    """The ``.fis`` files a factor's values name: each value as written to the name of its
    copy in the campaign folder (``fis/`` and 16 hex digits of its SHA-256) and its
    content, read now (the content the spec hash holds)."""
    import hashlib

    out = {}
    for value, path in (spec.fis_files or {}).items():
        try:
            data = Path(path).read_bytes()
        except OSError as exc:
            raise SpecError(f"fuzzy.fis = {value!r}: {exc.strerror or exc}") from None
        out[value] = (f"{FIS_COPIES}/{hashlib.sha256(data).hexdigest()[:16]}.fis", data)
    return out


def record_session(out: str | Path, where: str, parts: dict[str, dict] | None = None) -> dict:
    """Append to ``campaign.json`` how this session of the campaign runs its tasks:
    when, where (``where``: the workers or the scheduler), and the versions that make
    the records (pkmctl, the hash of its kernel sources, Python, NumPy, Numba,
    pyarrow, and each user part's source hash, ``parts``: :func:`user_parts`). A resume
    by other sources shows there. Returns the entry."""
    import datetime
    import platform
    from importlib.metadata import version

    import numpy

    import pkmctl

    # Numba's version from the metadata and _jit from the package: this module holds no
    # compiled code, so it must not look like a kernel source to _jit's hash (a text test)
    from pkmctl import _jit

    entry = {
        "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "where": where,
        "host": platform.node(),
        "pkmctl": pkmctl.__version__,
        "kernel_sources": _jit.source_stamp(),
        "pkmctl_sources": _jit.package_stamp(),
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "numba": version("numba"),
        "pyarrow": pa.__version__,
    }
    if parts:
        entry["user_parts"] = {k: v["sha256"] for k, v in parts.items()}
    path = Path(out) / "campaign.json"
    manifest = json.loads(path.read_text(encoding="utf-8"))
    manifest.setdefault("sessions", []).append(entry)
    with atomic_write(path) as fh:
        json.dump(manifest, fh, indent=2)
    return entry


def task_grouping(out: str | Path) -> tuple[float, int]:
    """(task seconds, seeds multiple) the campaign in ``out`` was started with: its tasks
    are ``spec.tasks(*task_grouping(out))``. :data:`LEGACY_TASK_SECONDS` and
    :data:`LEGACY_TASK_MULTIPLE` for a folder made before either was recorded."""
    try:
        manifest = json.loads((Path(out) / "campaign.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise SpecError(f"{str(out)!r}: not a readable campaign folder ({exc})") from None
    return (
        float(manifest.get("task_seconds", LEGACY_TASK_SECONDS)),
        int(manifest.get("task_multiple", LEGACY_TASK_MULTIPLE)),
    )


def task_seconds(out: str | Path) -> float:
    """The task size the campaign in ``out`` was started with (:func:`task_grouping`)."""
    return task_grouping(out)[0]


def check_store(out: Path, spec: CampaignSpec, *, resume: bool,
                parts: dict[str, dict] | None = None) -> None:  # fmt: skip
    """Refuse what :func:`open_store` refuses, writing nothing."""
    manifest = out / "campaign.json"
    if manifest.exists():
        if not resume:
            raise SpecError(
                f"--out {str(out)!r}: holds a campaign already (use --resume to complete it, "
                f"or another --out)"
            )
        try:
            old = json.loads(manifest.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise SpecError(f"{manifest}: unreadable ({exc})") from None
        if old.get("spec_hash") != spec.digest:
            raise SpecError(
                f"--resume: {str(out)!r} holds campaign {old.get('spec_hash')!r}, this spec is "
                f"{spec.digest!r} (a different spec; use another --out)"
            )
        _check_parts(out, old, user_parts(spec) if parts is None else parts)
    else:
        stray = sorted((out / "runs").glob("task-*.parquet"))
        if stray:  # records of a campaign whose campaign.json is gone: not this one's
            raise SpecError(
                f"--out {str(out)!r}: runs/ holds {len(stray)} task files ({stray[0].name}, "
                f"...) but no campaign.json: another campaign's? Use another --out"
            )


def open_store(out: Path, spec: CampaignSpec, *, resume: bool,
               parts: dict[str, dict] | None = None) -> Path:  # fmt: skip
    """Prepare ``out`` for ``spec``: a new store, or (``resume``) an existing one of the
    same spec. Refuses an existing store without ``resume``, one of another spec, and a
    resume with a user part whose source changed (``parts``: :func:`user_parts`, computed
    if not given). Returns the folder of the task files."""
    parts = user_parts(spec) if parts is None else parts
    check_store(out, spec, resume=resume, parts=parts)
    with unless_stopped(out):  # (the command's Ctrl-C said "nothing written": see there)
        return _open_store(out, spec, parts)


def _open_store(out: Path, spec: CampaignSpec, parts: dict[str, dict]) -> Path:
    manifest = out / "campaign.json"
    if not manifest.exists():
        fis = None
        if spec.base.fuzzy.fis is not None:
            try:
                fis = Path(spec.base.fuzzy.fis).read_bytes()
            except OSError as exc:
                raise SpecError(f"fuzzy.fis = {spec.base.fuzzy.fis!r}: {exc.strerror}") from None
        factor_fis = _factor_fis(spec)
        out.mkdir(parents=True, exist_ok=True)
        with atomic_write(out / "spec.toml") as fh:
            fh.write(spec.text)
        if fis is not None:  # the content the spec hash holds, whatever happens to the file
            with atomic_write(out / FIS_COPY, "wb") as fh:
                fh.write(fis)
        for name, data in factor_fis.values():  # the same for a factor's values
            (out / FIS_COPIES).mkdir(exist_ok=True)
            with atomic_write(out / name, "wb") as fh:
                fh.write(data)
        with atomic_write(out / "scenario.toml") as fh:
            fh.write(_stored_scenario(spec))
        with atomic_write(manifest) as fh:
            json.dump(_manifest(spec, {v: n for v, (n, _) in factor_fis.items()}, parts), fh,
                      indent=2)  # fmt: skip
    runs = out / "runs"
    runs.mkdir(exist_ok=True)
    return runs


def read_spec(out: str | Path) -> CampaignSpec:
    """The spec of the campaign in ``out``, its base scenario read from the copy stored
    beside it; checked against the hash the campaign was run with."""
    import tomllib

    out = Path(out)
    try:
        text = (out / "spec.toml").read_text(encoding="utf-8-sig")  # as CampaignSpec reads it
        data = tomllib.loads(text)
        manifest = json.loads((out / "campaign.json").read_text(encoding="utf-8"))
        digest = manifest["spec_hash"]
    except (OSError, ValueError, KeyError) as exc:
        raise SpecError(f"{str(out)!r}: not a readable campaign folder ({exc})") from None
    _need_plugins(out, manifest)
    data["scenario"], fis_files = _stored(out, manifest)
    from pkmctl.sim.scenario import ScenarioError

    try:
        spec = CampaignSpec.from_dict(data, text=text, folder=out, fis_files=fis_files)
    except (SpecError, ScenarioError) as exc:  # a check added after the folder was made
        raise SpecError(
            f"{str(out)!r}: its spec is refused as read now ({exc}): made by an earlier "
            "pkmctl, or edited; its records are the Parquet files in its runs/ folder, "
            "which DuckDB or pyarrow read as they are"
        ) from None
    if spec.digest != digest and digest in spec.legacy_digests():
        # a folder made before a .fis file counted by its content (and was copied here)
        import dataclasses

        spec = dataclasses.replace(spec, digest=digest)
    if spec.digest != digest:
        raise SpecError(
            f"{str(out)!r}: its spec hashes to {spec.digest!r}, its records to {digest!r} "
            f"(edited after the run?)"
        )
    return spec


def _stored(out: Path, manifest: dict) -> tuple[str, dict[str, str]]:
    """(the stored base scenario, the stored copies of the .fis files a factor's values
    name: each value as written to its copy). A folder made before they were copied has
    none: its values are read as they were then, relative to the working directory."""
    copies = manifest.get("fis_copies", {})
    fis_files = {v: str((out / name).absolute()) for v, name in copies.items()}
    return str((out / "scenario.toml").absolute()), fis_files


def stored_inputs(folder: str | Path, text: str) -> tuple[str, dict[str, str] | None] | None:
    """For a campaign folder's own ``spec.toml`` of ``text``: (its stored scenario, its
    stored .fis copies, or None for a folder that has none) that the spec is read with
    while it is the campaign's, so that the folder is complete on its own (``pkmctl
    campaign run DIR/spec.toml --out DIR --resume``); None if ``folder`` is not a campaign
    folder, or the text is not the one the campaign was started with (edited since: it
    is read as written; a folder made before the text was recorded: always the copies)."""
    folder = Path(folder)
    try:
        manifest = json.loads((folder / "campaign.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not (isinstance(manifest, dict) and (folder / "scenario.toml").is_file()):
        return None
    recorded = manifest.get("spec_text_sha256")
    if recorded is not None and recorded != hashlib.sha256(text.encode()).hexdigest():
        return None
    scenario, fis_files = _stored(folder, manifest)
    return scenario, (fis_files or None)


def _need_plugins(out: Path, manifest: dict) -> None:
    """Refuse, with the hint to pass them, a folder whose user parts are not registered."""
    from pkmctl.parts import names

    for key, info in (manifest.get("user_parts") or {}).items():
        kind, name = key.split(" ", 1)
        try:
            known = name in names(kind)
        except Exception:  # noqa: BLE001 - a kind this pkmctl does not know: from_dict says
            continue
        if not known:
            files = ", ".join(info.get("files", [])) or "a plugin"
            raise SpecError(
                f"{str(out)!r}: its runs use the {kind} {name!r}, which is not registered: "
                f"pass the plugin that registers it (it was read from {files}), "
                f"pkmctl --plugin FILE.py campaign ..."
            )


def _task_path(runs: Path, index: int) -> Path:
    return runs / f"task-{index:05d}.parquet"


def _foreign(path: Path, hashes, digest: str) -> SpecError:
    other = sorted(set(hashes) - {digest})
    return SpecError(
        f"{path}: records of campaign {other[0]!r}, not of this folder's {digest!r} (a file "
        f"of another campaign: move it out of runs/)"
    )


def _own_files(runs: Path, n_tasks: int | None = None) -> dict[int, Path]:
    """The campaign's own task files in ``runs``, by task index: ``task-00017.parquet``
    exactly (below ``n_tasks`` if given). Anything else there, such as a copy a file
    manager made (``task-00017 (copy).parquet``), is not a record of the campaign."""
    own = {}
    for p in runs.glob("task-*.parquet"):
        digits = p.stem.removeprefix("task-")
        if not (digits.isascii() and digits.isdigit()):
            continue
        index = int(digits)
        if p.name == _task_path(runs, index).name and (n_tasks is None or index < n_tasks):
            own[index] = p
    return dict(sorted(own.items()))


def completed_tasks(runs: Path, digest: str | None = None, tasks=None) -> set[int]:
    """Indices of the tasks whose file exists (a file is whole, or absent); only files
    named as the campaign's task files count (:func:`_own_files`). With ``digest``, a
    file holding records of another campaign (another spec hash) is a
    :class:`SpecError` naming it: it would count as done and mix into the report. With
    ``tasks`` (the campaign's :class:`~pkmctl.campaign.spec.Task` list), so is a file
    that does not hold exactly the runs of its task (another task's file copied to its
    name): its task would count as done, never run."""
    done = set()
    by_index = {t.index: t for t in tasks or ()}
    for index, p in _own_files(runs).items():
        if digest is not None or tasks is not None:
            t = _read(p, columns=["spec_hash", "cell", "controller", "seed"])
            hashes = t.column("spec_hash").unique()
            if digest is not None and set(hashes.to_pylist()) != {digest}:
                raise _foreign(p, hashes.to_pylist(), digest)
            if index in by_index:
                _check_runs(p, by_index[index], t)
        done.add(index)
    return done


def _check_runs(path: Path, task, table: pa.Table) -> None:
    """Refuse, in one line naming it, a task file whose records are not exactly the runs
    of its ``task`` (each once), as an unreadable one is refused (:func:`_read`)."""
    held = list(zip(*(table.column(k).to_pylist() for k in ("cell", "controller", "seed")),
                    strict=True))  # fmt: skip
    want = [(r.cell, r.controller, r.seed) for r in task.runs]
    if sorted(held, key=repr) == sorted(want, key=repr):
        return
    stray = [k for k in held if k not in set(want)]
    if stray:
        why = (f"it holds run (cell {stray[0][0]}, {stray[0][1]}, seed {stray[0][2]}), not "
               f"one of task {task.index}'s: another task's file copied to its name?")  # fmt: skip
    else:
        why = f"it holds {len(held)} records of the {len(want)} runs of task {task.index}"
    raise SpecError(
        f"{path}: not this task's records ({why}); delete it, and --resume runs its task again"
    )


def stored_statuses(runs: Path, n_tasks: int | None = None) -> dict[int, dict[str, int]]:
    """Per task file of the campaign (below ``n_tasks`` if given), how many of its records
    have each status: ``{17: {"ok": 6, "error": 2}}``."""
    out = {}
    for index, p in _own_files(runs, n_tasks).items():
        counts: dict[str, int] = {}
        for s in _read(p, columns=["status"]).column("status").to_pylist():
            counts[s] = counts.get(s, 0) + 1
        out[index] = counts
    return out


def _read(path: Path, **options) -> pa.Table:
    """A task file's table; one line naming the file if it cannot be read (it is written
    whole or not at all, so something else damaged it: pyarrow said only "Parquet magic
    bytes not found in footer")."""
    try:
        # pyarrow's file on the path's bytes (a str path went to pyarrow as UTF-8: LANG=C
        # failed; a Python file object aborted the interpreter at exit, apache/arrow#50482)
        with pa.OSFile(os.fsencode(path)) as fh:
            return pq.read_table(fh, **options)
    except (pa.ArrowException, OSError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        why = re.sub(r"^Could not open Parquet input source '[^']*': ", "", why)  # (the path)
        raise SpecError(
            f"{path}: not a readable task file ({why}); delete it, and --resume runs its task again"
        ) from None


def write_task(runs: Path, index: int, table: pa.Table) -> Path:
    """Write one task's records atomically (the file appears whole or not at all)."""
    buf = io.BytesIO()
    pq.write_table(table, buf)
    path = _task_path(runs, index)
    try:
        with atomic_write(path, "wb") as fh:
            fh.write(buf.getvalue())
    except OSError as exc:  # a full disk said "No space left on device", naming no file
        if exc.filename is not None or exc.errno is None:
            raise
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    return path


def read_records(out: str | Path, *, timing: bool = True) -> pa.Table:
    """Every record of a campaign folder, sorted by cell, controller (the spec's order)
    and seed; without the :data:`TIMING_COLUMNS` if ``timing`` is False."""
    out = Path(out)
    spec = read_spec(out)
    files = _own_files(out / "runs", len(spec.tasks(*task_grouping(out))))
    sch = schema(spec)
    tables = []
    seen: dict[tuple, Path] = {}
    for f in files.values():
        t = _read(f, schema=sch)
        hashes = t.column("spec_hash").unique().to_pylist()
        if hashes and set(hashes) != {spec.digest}:
            raise _foreign(f, hashes, spec.digest)
        keys = zip(*(t.column(k).to_pylist() for k in ("cell", "controller", "seed")), strict=True)
        for key in keys:
            if key in seen:  # counted twice, it would weigh twice in every statistic
                raise SpecError(
                    f"{f}: run (cell {key[0]}, {key[1]}, seed {key[2]}) is also in "
                    f"{seen[key]}: a run recorded twice (move the stray file out of runs/)"
                )
            seen[key] = f
        tables.append(t)
    table = pa.concat_tables(tables) if tables else sch.empty_table()
    table = _plain_strings(spec, table)
    order = {c: i for i, c in enumerate(spec.controllers)}
    ctrl_rank = pa.array([order[c] for c in table.column("controller").to_pylist()], pa.int64())
    table = table.append_column("_rank", ctrl_rank)
    table = table.sort_by([("cell", "ascending"), ("_rank", "ascending"), ("seed", "ascending")])
    table = table.drop_columns(["_rank"])
    if not timing:
        table = table.drop_columns(list(TIMING_COLUMNS))
    return table


def _plain_strings(spec: CampaignSpec, table: pa.Table) -> pa.Table:
    """Factors of string values as the text itself: folders made before stored them as
    JSON text (``"ideal"`` with its quotes); those records read as the new ones."""
    for p in spec.factors:
        values = [c[p] for c in spec.cells]
        if _numeric(values) or not _strings(values):
            continue
        col = factor_column(p)
        old = {json.dumps(v): v for v in values if v is not None}
        stored = table.column(col).to_pylist()
        if any(v in old for v in stored):
            fixed = pa.array([old.get(v, v) for v in stored], pa.string())
            table = table.set_column(table.schema.get_field_index(col), col, fixed)
    return table


def query(out: str | Path, sql: str):
    """Run DuckDB ``sql`` over the records, which it sees as the view ``runs``; returns a
    pyarrow table. ``query(dir, "SELECT controller, count(*) FROM runs GROUP BY 1")``"""
    import duckdb

    con = duckdb.connect()
    try:
        own = [str(p) for p in _own_files(Path(out) / "runs").values()]
        if own:  # the campaign's task files only, not a stray copy beside them
            files = "[" + ", ".join("'" + p.replace("'", "''") + "'" for p in own) + "]"
        else:  # none: DuckDB says so
            files = "'" + str(Path(out) / "runs" / "task-*.parquet").replace("'", "''") + "'"
        con.execute(f"CREATE VIEW runs AS SELECT * FROM read_parquet({files})")
        rel = con.sql(sql)
        fetch = getattr(rel, "to_arrow_table", None) or rel.arrow  # DuckDB 2 / 1
        return fetch()
    finally:
        con.close()
