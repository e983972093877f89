"""A campaign spec: base scenario, factors, controllers, seeds, duration, metrics kept.

The TOML (docs/campaigns.md)::

    name = "payload-vs-model-error"
    scenario = "paper"             # a built-in name or a scenario TOML file
    controllers = ["smc", "afsmc"]
    seeds = 10                     # 0..9, or a list [3, 7, 11]
    duration = 2.0                 # s, overrides timing.duration
    metrics = ["rmse", "rmse_after_1s"]

    [factors."payload.mass"]       # a grid: every value
    values = [0.0, 5.0, 10.0]

    [factors."controller_model.theta_scale"]   # seeded draws
    distribution = "uniform"       # uniform | loguniform | normal
    low = 0.3
    high = 1.0
    samples = 4
    seed = 1

The cells are the Cartesian product of the factors' values (grid values or draws), in
the order the factors are written (``design = "grid"``, the default), or, with
``design = "one-at-a-time"``, the base scenario (the centre) and each factor's values
in turn with every other factor at the base's value. Every controller runs every cell
with every seed, so comparisons are paired. ``"none"`` as a grid value means no value
(e.g. ``actuators.force_limit``: no limit). Fields set together with a factor's values
go in ``with``::

    [factors."timing.control_period"]
    values = [5e-5, 1e-3]
    with = { "timing.substeps" = [1, 20] }   # one entry per value

A built-in campaign (:data:`BUILTIN_CAMPAIGNS`, e.g. ``paper-claims``) is named like a
built-in scenario: ``CampaignSpec.from_toml("paper-claims")``.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pkmctl.errors import PkmctlError
from pkmctl.sim.scenario import BUILTINS, FUZZY_CONTROLLERS, Scenario, ScenarioError

__all__ = [
    "BUILTIN_CAMPAIGNS",
    "DESIGNS",
    "DISTRIBUTIONS",
    "METRICS",
    "CampaignSpec",
    "Comparison",
    "Run",
    "SpecError",
    "Task",
]


class SpecError(PkmctlError, ValueError):
    """An invalid campaign spec (one line: the field, the value, what is allowed)."""


#: Metric groups a campaign can keep (pkmctl.sim.metrics.summary's keys).
METRICS = ("rmse", "rmse_after_1s", "max_error", "chattering_N_per_s", "peak_force_N")
#: Seeded distributions of a sampled factor and their parameters.
DISTRIBUTIONS = {
    "uniform": ("low", "high"),
    "loguniform": ("low", "high"),
    "normal": ("mean", "std"),
}
#: How the factors' values combine into cells (see the module docstring).
DESIGNS = ("grid", "one-at-a-time")
_TOP = {
    "name",
    "description",
    "scenario",
    "controllers",
    "seeds",
    "duration",
    "metrics",
    "design",
    "factors",
    "compare",
}
_SPECS = Path(__file__).resolve().parent / "specs"
#: Built-in campaigns: name -> spec file shipped with pkmctl (``pkmctl campaign run NAME``).
BUILTIN_CAMPAIGNS = {p.stem: p for p in sorted(_SPECS.glob("*.toml"))}
#: Seconds of work per compiled control period and per run outside the loop: the task
#: size estimate (measured on the shared 2-core development machine: 3-6 us a period, ~10 ms a
#: run for prepare, build and metrics). Deterministic, so a task's runs never depend on
#: the machine: resuming elsewhere finds the same tasks.
SECONDS_PER_PERIOD = 5e-6
SECONDS_PER_RUN = 0.01
#: Estimated work per task. Dask costs ~1 ms per task, but a task also pays ~30 ms of
#: its own (the cell's scenario, the trajectory and desired forces, the fuzzy system, a
#: Parquet file written and synced), which 1 s of work makes ~3 %. A campaign folder
#: records the value it was started with, and a resume groups the runs by that value
#: (before it was recorded it was 0.2 s: :data:`LEGACY_TASK_SECONDS`).
TASK_SECONDS = 1.0
LEGACY_TASK_SECONDS = 0.2
#: A task's seeds come in multiples of this (when the cell has that many): whole batches
#: of SIMD lanes (:func:`pkmctl.sim.lanes.lane_batches`), 8 for AVX-512 and two of 4 for
#: AVX2, on any machine, so that the grouping stays deterministic. Recorded in the folder
#: too; a folder started before it was recorded grouped by 1 (:data:`LEGACY_TASK_MULTIPLE`).
TASK_MULTIPLE = 8
LEGACY_TASK_MULTIPLE = 1
#: Runs a campaign may hold (cells x controllers x seeds), checked before the cells, seeds
#: and runs are built: a spec of 10^8 seeds is refused at once, not after filling the
#: memory with them. A million runs of 0.5 s is about six days of a core.
MAX_RUNS = 1_000_000
#: Fields a factor cannot set: each run sets them itself (``seeds`` set the disturbance's).
RUN_FIELDS = {"disturbance.seed": "each run's seed sets it: list the seeds in seeds = [...]"}
#: Scenario sections a factor cannot vary because they change no record (by the first
#: component of the dotted path): their cells would be bit-identical runs, counted as
#: independent pairs by the statistics.
NO_RECORD_FIELDS = {
    "logging": "the records' metrics are computed in the loop over every period, whatever "
    "is logged",
    "name": "a scenario's label",
    "description": "a scenario's label",
}


def _no_record(field: str) -> str | None:
    """Why a factor over ``field`` changes no record (None: it may change them)."""
    return NO_RECORD_FIELDS.get(field.split(".")[0])


@dataclass(frozen=True)
class Run:
    """One run: a cell (index into the cells), a controller, a disturbance seed."""

    cell: int
    controller: str
    seed: int


@dataclass(frozen=True)
class Comparison:
    """A question a report answers: does ``controller`` do better than ``baseline``?

    Spec: ``[[compare]]`` with ``name`` (e.g. "adaptation"), ``controller``, ``baseline``.
    It shapes the report only, not the records (it is not part of the spec hash).
    """

    name: str
    controller: str
    baseline: str


@dataclass(frozen=True)
class Task:
    """Runs done together by one worker (one cell, one controller, some seeds)."""

    index: int
    runs: tuple[Run, ...]


def _fail(msg: str) -> SpecError:
    return SpecError(msg)


def _linked(path: str, body: dict, n: int) -> dict[str, list]:
    """A grid factor's ``with``: fields set together with each of its ``n`` values."""
    where = f"factors.{path!r}.with"
    linked = body.get("with", {})
    if not isinstance(linked, dict) or not linked:
        raise _fail(f"{where} = {linked!r}: must be a table of dotted paths to lists of values")
    out = {}
    for field, vals in linked.items():
        if field == path:
            raise _fail(f"{where}: {field!r} is the factor itself")
        if field in RUN_FIELDS:
            raise _fail(f"{where}.{field!r}: a campaign cannot set it ({RUN_FIELDS[field]})")
        if _no_record(field):
            raise _fail(f"{where}.{field!r}: it changes no record ({_no_record(field)}); "
                        f"remove it")  # fmt: skip
        if not isinstance(vals, list) or len(vals) != n:
            raise _fail(f"{where}.{field!r} = {vals!r}: must be a list of {n} values, one a value")
        out[field] = [None if v == "none" else v for v in vals]
    return out


def _factor_values(path: str, body: Any, runs_per_cell: int = 1) -> tuple[list, dict[str, list]]:
    """A factor's values, and the fields set together with them (``with``).
    ``runs_per_cell`` (controllers x seeds) bounds a distribution's ``samples`` before
    anything is drawn (:data:`MAX_RUNS`)."""
    where = f"factors.{path!r}"
    if not isinstance(body, dict):
        raise _fail(f"{where} = {body!r}: must be a table with values = [...] or a distribution")
    if "values" in body:
        extra = set(body) - {"values", "with"}
        if extra:
            raise _fail(f"{where}: unknown key {sorted(extra)[0]!r} beside values")
        values = body["values"]
        if not isinstance(values, list) or not values:
            raise _fail(f"{where}.values = {values!r}: must be a non-empty list")
        values = [None if v == "none" else v for v in values]
        for i, v in enumerate(values):  # identical cells would count as independent pairs
            if any(_same(v, w) for w in values[:i]):
                raise _fail(f"{where}.values = {body['values']!r}: a value named twice ({v!r})")
        return values, (_linked(path, body, len(values)) if "with" in body else {})
    kind = body.get("distribution")
    if kind is None and body:  # neither values nor a distribution: a typo (value = [...])
        raise _fail(
            f"{where}: unknown key {sorted(body)[0]!r} (give values = [...], or a "
            f"distribution = {' | '.join(DISTRIBUTIONS)} with its parameters)"
        )
    if not isinstance(kind, str) or kind not in DISTRIBUTIONS:  # (a list: unhashable)
        raise _fail(
            f"{where}.distribution = {kind!r}: must be one of {', '.join(DISTRIBUTIONS)} "
            f"(or give values = [...])"
        )
    a, b = DISTRIBUTIONS[kind]
    allowed = {"distribution", a, b, "samples", "seed"}
    extra = set(body) - allowed
    if extra:
        raise _fail(f"{where}: unknown key {sorted(extra)[0]!r} (allowed: {', '.join(allowed)})")
    n = body.get("samples")
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise _fail(f"{where}.samples = {n!r}: must be an integer >= 1")
    if n * runs_per_cell > MAX_RUNS:  # before n draws are made (10^8 of them: 800 MB)
        raise _too_many(n * runs_per_cell, f"{where}.samples = {n}")
    seed = body.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise _fail(f"{where}.seed = {seed!r}: must be an integer >= 0")
    p = []
    for k in (a, b):
        v = body.get(k)
        if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
            raise _fail(f"{where}.{k} = {v!r}: must be a finite number")
        p.append(float(v))
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        if not p[0] < p[1]:
            raise _fail(f"{where}: low = {p[0]} must be < high = {p[1]}")
        if not math.isfinite(p[1] - p[0]):  # (NumPy's OverflowError: an internal error)
            raise _fail(f"{where}: low = {p[0]}, high = {p[1]}: high - low must be finite")
        draws = rng.uniform(p[0], p[1], n)
    elif kind == "loguniform":
        if not 0 < p[0] < p[1]:
            raise _fail(f"{where}: need 0 < low < high, got {p[0]}, {p[1]}")
        draws = np.exp(rng.uniform(math.log(p[0]), math.log(p[1]), n))
    else:
        if not p[1] > 0:
            raise _fail(f"{where}.std = {p[1]}: must be > 0")
        draws = rng.normal(p[0], p[1], n)
    return draws.tolist(), {}


def _check_drawn_kinds(base, factors: dict) -> None:
    """Refuse a distribution over a field that takes an integer or a list: every draw is
    one real number, and was refused as "outside the field's range; narrow the
    distribution", which no narrowing mends (a tester)."""
    for path, body in factors.items():
        if not (isinstance(body, dict) and "distribution" in body):
            continue
        now: Any = base
        for name in path.split("."):
            now = getattr(now, name, None)
        if isinstance(now, bool) or now is None or isinstance(now, float):
            continue
        if isinstance(now, int | np.integer):
            kind = "an integer"
        elif isinstance(now, list | tuple | np.ndarray):
            kind = f"a list of {len(now)} numbers"
        else:
            continue
        raise _fail(
            f"factors.{path!r}: a distribution draws one real number a cell, and this field "
            f"takes {kind} (now {_shown(now)}): give its values instead (values = [...])"
        )


def _shown(value) -> str:
    return repr(value.tolist() if isinstance(value, np.ndarray) else value)


def _same(a, b) -> bool:
    """Two factor values that make the same cell (5 and 5.0 do; True and 1 do not)."""
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def _check_fields(parsed: dict) -> None:
    """Refuse a factor a run overrides, and a field set twice in a cell: a factor that is
    also in another factor's ``with``, or a field in two factors' ``with``."""
    for p in parsed:
        if p in RUN_FIELDS:
            raise _fail(f"factors.{p!r}: a campaign cannot vary it ({RUN_FIELDS[p]})")
        if _no_record(p):
            raise _fail(
                f"factors.{p!r}: it changes no record ({_no_record(p)}): its cells would be "
                f"identical runs counted as independent pairs; remove the factor"
            )
    setter: dict[str, str] = {}
    for p, (_, linked) in parsed.items():
        for field in linked:
            if field in parsed:
                raise _fail(
                    f"factors.{p!r}.with.{field!r}: {field} is set twice, as a factor and in "
                    f"this with (make it one or the other)"
                )
            if field in setter:
                raise _fail(
                    f"factors.{p!r}.with.{field!r}: {field} is set twice, also in "
                    f"factors.{setter[field]!r}.with (set it in one factor's with only)"
                )
            setter[field] = p


def _too_many(n_runs: int, what: str) -> SpecError:
    return _fail(
        f"{what}: {n_runs} runs (cells x controllers x seeds), more than the {MAX_RUNS} a "
        f"campaign holds: split it into campaigns of fewer cells or seeds"
    )


def fis_digest(path: str) -> str:
    """``sha256:`` and the SHA-256 of a ``.fis`` file's bytes: what a campaign's hash holds
    for a fuzzy system read from a file (its content, not where it is)."""
    try:
        return "sha256:" + hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        raise ScenarioError(f"fuzzy.fis = {path!r}: {exc.strerror or exc}") from None


#: The scenario field of a fuzzy system's ``.fis`` file.
FIS_FIELD = "fuzzy.fis"


def _with_fis(cell: dict, fis_files: dict) -> dict:
    """``cell`` with its ``.fis`` file (if a factor or a ``with`` names one) replaced by
    ``fis_files[value]``: the file it resolves to, or its content's digest."""
    v = cell.get(FIS_FIELD)
    if isinstance(v, str) and v in fis_files:
        return {**cell, FIS_FIELD: fis_files[v]}
    return cell


def _fis_files(parsed: dict, folder: Path) -> dict[str, str]:
    """Each ``.fis`` file a factor's values (or a ``with``) name, as written, to its path:
    relative to the spec's folder, as the scenario file the spec names."""
    named = []
    for p, (values, linked) in parsed.items():
        if p == FIS_FIELD:
            named += values
        named += linked.get(FIS_FIELD, [])
    out = {}
    for v in named:
        if isinstance(v, str):
            path = Path(v).expanduser()
            out[v] = str(path if path.is_absolute() else folder / path)
    return out


def _same_fis_twice(factors: dict, parsed: dict, fis_files: dict) -> None:
    """Refuse two values of a ``fuzzy.fis`` factor naming files of the same content:
    their cells would be identical (as a value named twice)."""
    if FIS_FIELD not in parsed:
        return
    seen: dict[str, str] = {}
    for v in parsed[FIS_FIELD][0]:
        if not isinstance(v, str):
            continue
        digest = fis_digest(fis_files.get(v, v))
        if digest in seen:
            raise _fail(
                f"factors.{FIS_FIELD!r}.values = {factors[FIS_FIELD]['values']!r}: a value "
                f"named twice ({v!r} holds the same fuzzy system as {seen[digest]!r}, byte "
                f"for byte)"
            )
        seen[digest] = v


def _identity(base: Scenario, cells, controllers, seeds, metrics, *, fis_files=None,
              fis_path: bool = False, factor_fis_path: bool = False):  # fmt: skip
    """The SHA-256 (16 hex digits) of what determines a campaign's records. A ``.fis``
    file counts by its content, the base scenario's and those a factor's values name
    (``fis_files``: each value as written to its file); ``fis_path``: every one by its
    path or value as written, as folders made before 2026-12 did; ``factor_fis_path``:
    a factor's by its value as written, as folders made before 2026-12-06 did."""
    # logging.every changes no record (metrics are computed over every period in the
    # loop), so it is not part of what the campaign is: a store made before the option
    # existed, or with another value, still resumes
    dumped = base.model_dump(mode="json", by_alias=True, exclude={"logging"})
    if base.fuzzy.fis is not None and not fis_path:
        dumped["fuzzy"]["fis"] = fis_digest(base.fuzzy.fis)
    if fis_files and not (fis_path or factor_fis_path):
        digests = {v: fis_digest(f) for v, f in fis_files.items()}
        cells = [_with_fis(c, digests) for c in cells]
    identity = {
        "base": dumped,
        "cells": cells,
        "controllers": controllers,
        "seeds": seeds,
        "metrics": metrics,
    }
    blob = json.dumps(identity, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def _load_base(ref: Any, folder: Path) -> Scenario:
    if not isinstance(ref, str) or not ref:
        raise _fail(
            f"scenario = {ref!r}: must be a built-in name ({', '.join(BUILTINS)}) or a file"
        )
    if ref in BUILTINS:
        return Scenario.builtin(ref)
    path = Path(ref) if Path(ref).is_absolute() else folder / ref
    if path.suffix.lower() == ".toml" or path.exists():
        return Scenario.from_toml(path)
    return Scenario.builtin(ref)  # raises with the list of built-ins


@dataclass(frozen=True, eq=False)
class CampaignSpec:
    """A validated campaign: the base scenario, the cells, controllers, seeds.

    ``cells[i]`` maps each factor's dotted path to its value in cell i; every
    ``scenario(i)`` was validated when the spec was read, so runs cannot meet a bad
    value; a cell also holds the fields set with its factors' values (``with``).
    ``text`` is the spec as written, ``digest`` the SHA-256 (16 hex digits) of what
    determines the records: the base scenario, the cells, controllers, seeds, duration
    and metrics. With ``design = "one-at-a-time"``, ``center`` maps each factor to the
    base scenario's value (cell 0 is the centre).
    """

    name: str
    description: str
    base: Scenario
    factors: tuple[str, ...]
    cells: tuple[dict, ...]
    controllers: tuple[str, ...]
    seeds: tuple[int, ...]
    duration: float
    metrics: tuple[str, ...]
    text: str
    digest: str
    design: str = "grid"
    center: dict | None = None
    compare: tuple[Comparison, ...] = ()
    #: The ``.fis`` files a factor's values name: each value as written to its file.
    fis_files: dict | None = None

    @classmethod
    def from_toml(cls, source: str | Path) -> CampaignSpec:
        """Read and validate a spec from a file path, a built-in campaign's name
        (:data:`BUILTIN_CAMPAIGNS`), or TOML text (if it has a newline).

        Raises :class:`SpecError` or :class:`~pkmctl.ScenarioError` in one line; every
        cell's scenario is built and validated, so nothing runs from a bad spec.
        """
        if not str(source).strip():  # (Path("") is ".": "'.': Is a directory")
            raise _fail(
                f"campaign spec = {str(source)!r}: must name a file or a built-in campaign "
                f"({', '.join(BUILTIN_CAMPAIGNS)})"
            )
        if str(source) in BUILTIN_CAMPAIGNS and not Path(source).exists():
            source = BUILTIN_CAMPAIGNS[str(source)]
        if isinstance(source, Path) or "\n" not in str(source):
            path = Path(source)
            try:
                # -sig: a Windows editor's BOM is no part of the text (nor of its hash)
                text = path.read_text(encoding="utf-8-sig")
            except FileNotFoundError:
                raise _fail(
                    f"campaign spec {str(path)!r}: no such file, nor a built-in campaign "
                    f"(choose from {', '.join(BUILTIN_CAMPAIGNS)})"
                ) from None
            except UnicodeDecodeError as exc:  # (Python's words: "'utf-8' codec can't ...")
                raise _fail(
                    f"campaign spec {str(path)!r}: not UTF-8 text (byte "
                    f"0x{exc.object[exc.start]:02x} at offset {exc.start})"
                ) from None
            except OSError as exc:
                raise _fail(
                    f"campaign spec {str(path)!r}: {getattr(exc, 'strerror', None) or exc}"
                ) from None
            folder = path.absolute().parent
            where = f"campaign spec {str(path)!r}"
        else:
            text, folder, where = str(source).removeprefix("\ufeff"), Path.cwd(), "campaign spec"
            path = None
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            from pkmctl.errors import toml_error

            raise _fail(f"{where}: {toml_error(exc, text)}") from None
        if not data:  # (it ran a campaign of every key's default, unsaid: a fuzzer)
            raise _fail(
                f"{where}: empty (no key set; `pkmctl campaign show paper-claims` prints a "
                "full one)"
            )
        if path is not None and path.name == "spec.toml":
            from pkmctl.campaign.store import stored_inputs

            stored = stored_inputs(folder, text)
            if stored is not None:  # a campaign folder's own spec: its stored copies
                scenario, fis_files = stored
                data = {**data, "scenario": scenario}
                return cls.from_dict(data, text=text, folder=folder, fis_files=fis_files)
        return cls.from_dict(data, text=text, folder=folder)

    @classmethod
    def from_dict(cls, data: dict, *, text: str = "", folder: Path | None = None,
                  fis_files: dict | None = None) -> CampaignSpec:  # fmt: skip
        """Validate a spec given as a dict (the TOML's content). ``fis_files`` maps the
        ``.fis`` files a factor's values name, as written, to the files to read (a campaign
        folder's copies); by default they are relative to ``folder``."""
        extra = set(data) - _TOP
        if extra:
            raise _fail(f"{sorted(extra)[0]}: unknown key (allowed: {', '.join(sorted(_TOP))})")
        base = _load_base(data.get("scenario", "paper"), folder or Path.cwd())
        from pkmctl.parts import names

        controllers = data.get("controllers", ["smc", "fsmc", "afsmc"])
        known = names("controller")
        if not isinstance(controllers, list) or not controllers:
            raise _fail(f"controllers = {controllers!r}: must be a non-empty list of names")
        for c in controllers:
            if c not in known:
                raise _fail(
                    f"controllers: {c!r} is not a registered controller ({', '.join(known)}; "
                    f"your own: pass the plugin that registers it, pkmctl --plugin FILE.py "
                    f"campaign ...)"
                )
        if len(set(controllers)) != len(controllers):
            raise _fail(f"controllers = {controllers!r}: a controller is named twice")
        seeds = data.get("seeds", 1)
        count = isinstance(seeds, int) and not isinstance(seeds, bool)
        if count and seeds < 1:
            raise _fail(f"seeds = {seeds}: must be >= 1 (zero runs)")
        if count and seeds * len(controllers) > MAX_RUNS:  # before a list of them is made
            raise _too_many(seeds * len(controllers), f"seeds = {seeds}")
        if count:
            seeds = list(range(seeds))
        if not isinstance(seeds, list) or not seeds:
            raise _fail(
                f"seeds = {seeds!r}: must be a count >= 1 or a non-empty list of integers"
                + (" (zero runs)" if seeds == [] else "")
            )
        for s in seeds:
            if not isinstance(s, int) or isinstance(s, bool) or not 0 <= s <= 2**63 - 1:
                raise _fail(f"seeds: {s!r} must be an integer in [0, 2^63 - 1]")
        if len(set(seeds)) != len(seeds):
            raise _fail(f"seeds = {seeds!r}: a seed is named twice")
        duration = data.get("duration", base.timing.duration)
        if not isinstance(duration, int | float) or isinstance(duration, bool):
            raise _fail(f"duration = {duration!r}: must be a number of seconds")
        metrics = data.get("metrics", ["rmse", "rmse_after_1s"])
        if not isinstance(metrics, list) or not metrics:
            raise _fail(f"metrics = {metrics!r}: must be a non-empty list of {', '.join(METRICS)}")
        for m in metrics:
            if m not in METRICS:
                raise _fail(f"metrics: {m!r} unknown (choose from {', '.join(METRICS)})")
        if len(set(metrics)) != len(metrics):
            raise _fail(f"metrics = {metrics!r}: a metric named twice")
        factors = data.get("factors", {})
        if not isinstance(factors, dict):
            raise _fail(f"factors = {factors!r}: must be a table of dotted paths")
        design = data.get("design", "grid")
        if design not in DESIGNS:
            raise _fail(f"design = {design!r}: must be one of {', '.join(DESIGNS)}")
        per_cell = len(controllers) * len(seeds)
        parsed = {p: _factor_values(p, body, per_cell) for p, body in factors.items()}
        _check_fields(parsed)
        _check_drawn_kinds(base, factors)
        if fis_files is None:
            fis_files = _fis_files(parsed, folder or Path.cwd())
        _same_fis_twice(factors, parsed, fis_files)
        try:
            base = base.replace(**{"timing.duration": float(duration)})
        except ScenarioError as exc:  # (named as the field the spec has: it said
            # "timing.duration = -1.0", a key the user never wrote: a code reader)
            text = str(exc)
            if not text.startswith("timing.duration = ") or ": " not in text:
                raise
            raise ScenarioError(
                f"duration = {duration!r} (timing.duration): {text.split(': ', 1)[1]}"
            ) from None
        center = None
        if design == "grid":
            n_cells = math.prod(len(v) for v, _ in parsed.values())
        else:
            center = {p: _base_value(base, p) for p in parsed}
            n_cells = 1 + sum(
                sum(not _same(v, center[p]) for v in values) for p, (values, _) in parsed.items()
            )
        n_runs = n_cells * len(controllers) * len(seeds)
        if n_runs > MAX_RUNS:  # before the cells are built and validated
            raise _too_many(
                n_runs,
                " x ".join(
                    f"{n} {w}" + "s" * (n != 1)
                    for n, w in (
                        (n_cells, "cell"),
                        (len(controllers), "controller"),
                        (len(seeds), "seed"),
                    )
                ),
            )
        if design == "grid":
            cells = tuple(
                _cell(parsed, dict(zip(parsed, combo, strict=True)))
                for combo in itertools.product(*(range(len(v)) for v, _ in parsed.values()))
            )
        else:
            cells = _one_at_a_time(base, parsed, center)
        drawn = {f: b for f, b in factors.items() if isinstance(b, dict) and "distribution" in b}
        for cell in cells:
            try:
                _cell_scenario(base, _with_fis(cell, fis_files))  # raises its one-line error
            except ScenarioError as exc:  # a draw out of range: which factor drew it
                field = str(exc).split(" = ", 1)[0].split(": ", 1)[0]
                if field not in drawn:
                    raise
                raise _fail(
                    f"factors.{field!r}: a draw of its {drawn[field]['distribution']} "
                    f"distribution (seed {drawn[field].get('seed', 0)}) is outside the "
                    f"field's range: {exc}; narrow the distribution"
                ) from None
        _check_gains_read(base, parsed, controllers)
        if "rmse_after_1s" in metrics and "rmse" not in metrics:
            _check_after_1s(base, cells, float(duration), metrics)
        compare = _comparisons(data.get("compare", []), controllers)
        name = data.get("name", "campaign")
        if not isinstance(name, str) or not name:
            raise _fail(f"name = {name!r}: must be a non-empty string")
        return cls(
            name=name,
            description=str(data.get("description", "")),
            base=base,
            factors=tuple(parsed),
            cells=cells,
            controllers=tuple(controllers),
            seeds=tuple(seeds),
            duration=float(duration),
            metrics=tuple(metrics),
            text=text,
            digest=_identity(base, cells, controllers, seeds, metrics, fis_files=fis_files),
            design=design,
            center=center,
            compare=compare,
            fis_files=fis_files,
        )

    # ------------------------------------------------------------------ derived
    @classmethod
    def builtin(cls, name: str) -> CampaignSpec:
        """A built-in campaign by name (:data:`BUILTIN_CAMPAIGNS`)."""
        if name not in BUILTIN_CAMPAIGNS:
            raise _fail(
                f"campaign {name!r}: unknown built-in (choose from {', '.join(BUILTIN_CAMPAIGNS)})"
            )
        return cls.from_toml(BUILTIN_CAMPAIGNS[name])

    def axis(self, factor: str) -> list[int]:
        """The cells that vary ``factor`` alone: every cell of a grid; in a one-at-a-time
        design the cells where every other factor is at the centre."""
        if self.center is None:
            return list(range(len(self.cells)))
        others = [p for p in self.factors if p != factor]
        return [i for i, c in enumerate(self.cells) if all(c[p] == self.center[p] for p in others)]

    @property
    def n_runs(self) -> int:
        return len(self.cells) * len(self.controllers) * len(self.seeds)

    def scenario(self, cell: int) -> Scenario:
        """The validated scenario of cell ``cell``."""
        return _cell_scenario(self.base, _with_fis(self.cells[cell], self.fis_files or {}))

    def fuzzy_offset_notes(self) -> list[str]:
        """One :meth:`Scenario.fuzzy_offset_note` per ``.fis`` file the cells run whose
        output at rest is not 0, if a controller with the fuzzy term is among the
        controllers (:data:`~pkmctl.sim.scenario.FUZZY_CONTROLLERS`)."""
        if not set(FUZZY_CONTROLLERS) & set(self.controllers):
            return []
        first: dict = {}  # each .fis value (None: the base's) -> its first cell
        for i, cell in enumerate(self.cells):
            first.setdefault(cell.get(FIS_FIELD), i)
        notes = (self.scenario(i).fuzzy_offset_note() for i in first.values())
        return [n for n in notes if n]

    def durations(self) -> list[float]:
        """Each cell's run duration, s (the spec's ``duration``, or a ``timing.duration``
        factor's value)."""
        return [float(c.get("timing.duration", self.duration)) for c in self.cells]

    def past_1s(self) -> list[bool]:
        """Per cell, whether its runs have control samples at t >= 1 s, so that the
        ``rmse_after_1s`` metrics exist (:func:`pkmctl.sim.metrics.summary`)."""
        return [_past_1s(self.base, c, d) for c, d in zip(self.cells, self.durations(),
                                                             strict=True)]  # fmt: skip

    def legacy_digest(self) -> str:
        """The hash a folder made before a ``.fis`` file counted by its content has: with
        the file's path instead (:func:`pkmctl.campaign.store.read_spec` accepts it)."""
        return _identity(self.base, self.cells, list(self.controllers), list(self.seeds),
                         list(self.metrics), fis_path=True)  # fmt: skip

    def legacy_digests(self) -> list[str]:
        """The hashes folders made before have, when a ``.fis`` file counts in this
        spec's: every ``.fis`` file by its path (:meth:`legacy_digest`), or the base's by
        its content and a factor's by its value as written (before 2026-12-06)."""
        out = []
        if self.base.fuzzy.fis is not None or self.fis_files:
            out.append(self.legacy_digest())
        if self.fis_files:
            out.append(_identity(self.base, self.cells, list(self.controllers),
                                 list(self.seeds), list(self.metrics),
                                 fis_files=self.fis_files, factor_fis_path=True))  # fmt: skip
        return out

    def periods(self) -> int:
        """Control periods of the longest run (the base's period and duration; factors
        may change them)."""
        return max(
            int(round(d / float(c.get("timing.control_period",
                                      self.base.timing.control_period))))
            for c, d in zip(self.cells, self.durations(), strict=True)
        )  # fmt: skip

    def run_seconds(self) -> float:
        """Estimated seconds of one run on one core (the constants above)."""
        return SECONDS_PER_RUN + SECONDS_PER_PERIOD * self.periods()

    def tasks(
        self, task_seconds: float = TASK_SECONDS, multiple: int = TASK_MULTIPLE
    ) -> list[Task]:
        """The runs grouped into tasks of about ``task_seconds`` of estimated work each,
        rounded up to a ``multiple`` of seeds: one cell and controller per task, its seeds
        in chunks. Depends on the spec, ``task_seconds`` and ``multiple`` only (a campaign
        folder records both)."""
        per = math.ceil(task_seconds / self.run_seconds())
        per = max(1, min(len(self.seeds), -(-per // multiple) * multiple))
        out = []
        for cell in range(len(self.cells)):
            for c in self.controllers:
                for i in range(0, len(self.seeds), per):
                    runs = tuple(Run(cell, c, s) for s in self.seeds[i : i + per])
                    out.append(Task(len(out), runs))
        return out


def _cell(parsed: dict, picks: dict[str, int]) -> dict:
    """A cell: each factor at its picked value, with the fields linked to that value."""
    cell = {}
    for p, i in picks.items():
        values, linked = parsed[p]
        cell[p] = values[i]
        cell.update({f: vals[i] for f, vals in linked.items()})
    return cell


def _base_value(base: Scenario, path: str):
    node: Any = base.model_dump(mode="json", by_alias=True)
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            raise ScenarioError(f"{path}: unknown field")
        node = node[part]
    return node


def _one_at_a_time(base: Scenario, parsed: dict, center: dict) -> tuple[dict, ...]:
    """The centre (every factor at the base's value), then each factor's other values in
    turn, the rest at the centre. A value equal to the base's is the centre, not a cell.

    The centre takes the ``with`` fields of each factor's value that equals the base's
    (``values = [5e-5, 1e-3]`` with ``substeps = [4, 20]`` and a base at 5e-5: the centre
    runs 4 sub-steps), and every cell of another factor keeps them, as it keeps the rest
    of the centre. No field is in two factors' ``with`` (:func:`_check_fields`), so this
    is well defined. A field whose ``with`` value is the base's stays out of the cells
    (it changes nothing, and the cells and the spec hash stay as they were)."""
    middle = dict(center)
    for p, (values, linked) in parsed.items():
        at = next((i for i, v in enumerate(values) if _same(v, center[p])), None)
        if at is not None:
            middle.update({f: vals[at] for f, vals in linked.items()
                           if not _same(vals[at], _base_value(base, f))})  # fmt: skip
    cells = [middle]
    for p, (values, linked) in parsed.items():
        for i, v in enumerate(values):
            if _same(v, center[p]):
                continue
            cell = dict(middle)
            cell[p] = v
            cell.update({f: vals[i] for f, vals in linked.items()})
            cells.append(cell)
    return tuple(cells)


def _past_1s(base: Scenario, cell: dict, duration: float) -> bool:
    """Whether the runs of ``cell`` (of ``duration`` s) have a control sample at t >= 1 s:
    the last is at (periods - 1) T_c, as :func:`pkmctl.sim.metrics.summary` finds it."""
    period = float(cell.get("timing.control_period", base.timing.control_period))
    return (int(round(duration / period)) - 1) * period >= 1.0


def _check_after_1s(base: Scenario, cells, duration: float, metrics: list) -> None:
    """Refuse ``rmse_after_1s`` as the only RMSE kept when a cell's runs end before 1 s:
    its columns would be empty there, and the report would have nothing to compare (with
    ``rmse`` kept too, the report compares over the whole run instead)."""
    for i, cell in enumerate(cells):
        d = float(cell.get("timing.duration", duration))
        if not _past_1s(base, cell, d):
            where = (f"timing.duration = {cell['timing.duration']!r} (cell {i})"
                     if "timing.duration" in cell else f"duration = {duration!r}")  # fmt: skip
            raise _fail(
                f"metrics = {metrics!r} with {where}: rmse_after_1s needs runs longer than "
                f"1 s (a control sample at t >= 1 s); keep rmse too (the whole run) or make "
                f"the runs longer"
            )


def _comparisons(body: Any, controllers: list[str]) -> tuple[Comparison, ...]:
    if not isinstance(body, list):
        raise _fail(f"compare = {body!r}: must be a list of tables ([[compare]])")
    out = []
    for i, q in enumerate(body):
        where = f"compare[{i}]"
        if not isinstance(q, dict) or set(q) != {"name", "controller", "baseline"}:
            raise _fail(f"{where} = {q!r}: must have name, controller and baseline (only)")
        for k in ("controller", "baseline"):
            if q[k] not in controllers:
                raise _fail(f"{where}.{k} = {q[k]!r}: not one of the campaign's controllers")
        if q["controller"] == q["baseline"]:
            raise _fail(f"{where}: controller and baseline are both {q['controller']!r}")
        for j, other in enumerate(out):  # the same question twice: the same answer twice
            if other.name == str(q["name"]) or (other.controller, other.baseline) == (
                q["controller"],
                q["baseline"],
            ):
                what = "name" if other.name == str(q["name"]) else "controller and baseline"
                raise _fail(
                    f"{where} = {q!r}: the same {what} as compare[{j}] (a question asked twice)"
                )
        out.append(Comparison(str(q["name"]), q["controller"], q["baseline"]))
    return tuple(out)


def _check_gains_read(base: Scenario, parsed: dict, controllers: list[str]) -> None:
    """Refuse a factor over a gain that none of the controllers reads: each one's parameter
    bundle is the same at every value of it, so its cells would be identical runs counted
    as independent pairs (a tester's ``gains.gamma`` over smc and pd). Asked only when every
    controller is pkmctl's own (a user's part may read any gain) and of a factor that sets
    nothing else (no ``with``)."""
    from pkmctl.parts import PartContext, get_part

    fields = [f for f, (_, with_) in parsed.items() if f.startswith("gains.") and not with_]
    parts = [get_part("controller", c) for c in controllers]
    if not fields or not all(part.builtin for part in parts):
        return
    for field in fields:
        seen = []
        for value in parsed[field][0]:
            sc = _cell_scenario(base, {field: value})
            ctx = PartContext(plant=sc.plant(), model=sc.controller_mechanism(),
                              gains=sc.controller_gains(), period=sc.timing.control_period,
                              flc=sc.fuzzy_system(), scenario=sc)  # fmt: skip
            seen.append([part.bundle(ctx) for part in parts])
        if all(_same_bundle(seen[0], other) for other in seen[1:]):
            raise _fail(
                f"factors.{field!r}: none of the controllers ({', '.join(controllers)}) reads "
                "it: its cells would be identical runs counted as independent pairs; remove "
                "the factor, or add a controller that reads it"
            )


def _same_bundle(a, b) -> bool:
    """Two parameter bundles (nested tuples of numbers and arrays) equal to the bit."""
    if isinstance(a, tuple | list):
        return (isinstance(b, tuple | list) and len(a) == len(b)
                and all(_same_bundle(x, y) for x, y in zip(a, b, strict=True)))  # fmt: skip
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(a, b)
    return a == b


def _cell_scenario(base: Scenario, cell: dict) -> Scenario:
    try:
        return base.replace(**cell) if cell else base
    except ScenarioError:
        raise
    except Exception as exc:  # noqa: BLE001 - a value pydantic's strict mode cannot take
        raise ScenarioError(f"{next(iter(cell))}: {exc}") from None
