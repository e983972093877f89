"""Results to and from disk in open formats: a time-series table plus a JSON metadata file.

``save_result(result, directory)`` writes ``<stem>.parquet`` (or ``<stem>.csv`` with
``fmt="csv"``): one row per control period with t, X, Xdot, X_desired, Xdot_desired, q,
q_desired, F, tau, tau_desired, disturbance, the measured q1_m..q4_m when the sensor is
not ideal (and the pose and velocity it gave, z_m ... betadot_m) and, for AFSMC,
theta_hat; and ``<stem>.json`` (the scenario as TOML text, the controller, the parts,
``info``, the metrics, the loop's metric accumulators, the column names and the table's
file name). A part's own log (``Result.logs``) is saved as the columns
``log_<name>_0``, ``log_<name>_1``, ... and the parts' ``final_state`` in the JSON (they
were not saved before 2026-12-07, without a word). ``load_result`` reads them back into a
:class:`~pkmctl.Result`, bit for bit (the measured columns, where absent, are the true
ones, as an ideal sensor gave them); a decimated run's metrics (``logging.every`` > 1)
come back from the accumulators, not from the rows it logged.

The JSON is standard JSON (any parser reads it): a number that is not finite is written
as ``null`` (an unbounded actuator's ``force_limit``, a limb speed not measured), and read
back as what it stood for. A scenario whose fuzzy term is a ``.fis`` file carries the
file's text (``fis_text``): the result reads back after the file moved or changed, with
the system the run used.

Parquet is the default: a 10 s run at 20 kHz has 200,000 rows and 35 to 93 columns (93:
afsmc-ext's 48 estimates on an encoder), and a part's own logs add theirs,
which takes ~8 s to print as CSV with round-trip precision and ~0.2 s as Parquet
(any dataframe library or DuckDB reads it; columns are stored byte-stream-split and
zstd-compressed, about 54 MB for an AFSMC run).

The two files are one result: both are written to temporary names in the same folder
and renamed together (:func:`~pkmctl.io.atomic.atomic_files`), so a failure or Ctrl-C
leaves the previous pair as it was, never a new table beside an old JSON. The JSON
records the SHA-256 of the table file's bytes (``table_sha256``), and ``load_result``
refuses a table that does not match it (for a JSON written before it did, a table whose
row count is not ``samples``).
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
from pathlib import Path

import numpy as np

from pkmctl.io.atomic import atomic_files, atomic_write
from pkmctl.sim import metrics
from pkmctl.sim.result import Result
from pkmctl.sim.scenario import Scenario, ScenarioError

__all__ = ["atomic_write", "load_result", "save_result"]

FORMAT_VERSION = 1
# (field, width, column names)
_FIELDS = (
    ("X", 3, ("z", "alpha", "beta")),
    ("Xdot", 3, ("zdot", "alphadot", "betadot")),
    ("X_desired", 3, ("z_d", "alpha_d", "beta_d")),
    ("Xdot_desired", 3, ("zdot_d", "alphadot_d", "betadot_d")),
    ("q", 4, ("q1", "q2", "q3", "q4")),
    ("q_desired", 4, ("q1_d", "q2_d", "q3_d", "q4_d")),
    ("F", 3, ("F_z", "F_alpha", "F_beta")),
    ("tau", 4, ("tau1", "tau2", "tau3", "tau4")),
    ("tau_desired", 4, ("tau1_d", "tau2_d", "tau3_d", "tau4_d")),
    ("disturbance", 3, ("d_z", "d_alpha", "d_beta")),
)


_MEASURED = ("q1_m", "q2_m", "q3_m", "q4_m")
#: What the sensor gave the controller, saved when it differs from the truth.
_SEEN = (
    ("X_measured", ("z_m", "alpha_m", "beta_m")),
    ("Xdot_measured", ("zdot_m", "alphadot_m", "betadot_m")),
)


def _columns(result: Result) -> tuple[list[str], list[np.ndarray]]:
    """Column names and the columns: strided views of the result's arrays, which
    pyarrow copies into its own pool (memory reused column after column and file after
    file; a contiguous copy per block here came from fresh pages each time, which cost
    more than the copy: docs/performance.md)."""
    names, blocks = ["t"], [result.t.reshape(-1, 1)]
    for name, _, cols in _FIELDS:
        names += list(cols)
        blocks.append(getattr(result, name))
    if not np.array_equal(result.q_measured, result.q):
        names += list(_MEASURED)  # what an encoder gave (pkmctl identify reads these)
        blocks.append(result.q_measured)
    for name, cols in _SEEN:
        seen, true = getattr(result, name), getattr(result, name.removesuffix("_measured"))
        if not np.array_equal(seen, true):
            names += list(cols)
            blocks.append(seen)
    if result.theta_hat is not None:
        names += [f"theta_hat{k}" for k in range(result.theta_hat.shape[1])]
        blocks.append(result.theta_hat)
    for name, log in result.logs.items():  # a part's own log: log_NAME_0, log_NAME_1, ...
        log = np.asarray(log, dtype=np.float64).reshape(result.t.size, -1)
        names += [f"{LOG_PREFIX}{name}_{k}" for k in range(log.shape[1])]
        blocks.append(log)
    columns = [b[:, j] for b in blocks for j in range(b.shape[1])]
    return names, columns


#: The columns of a part's own log (``Result.logs``) are LOG_PREFIX + its name + ``_k``.
LOG_PREFIX = "log_"


FORMATS = ("parquet", "csv")


def provenance() -> dict:
    """The software that made an output: pkmctl's version, the content hashes of its
    sources (``pkmctl_sources``: every module; ``kernel_sources``: the compiled ones, which
    key the disk cache), and Python's, NumPy's and Numba's versions. Only campaign.json
    said which pkmctl made it (a tester)."""
    return dict(_provenance())


@functools.cache
def _provenance() -> dict:
    import platform
    from importlib.metadata import version

    import pkmctl
    from pkmctl import _jit

    return {
        "pkmctl": pkmctl.__version__,
        "pkmctl_sources": _jit.package_stamp(),
        "kernel_sources": _jit.source_stamp(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": version("numba"),
    }


def provenance_line() -> str:
    """:func:`provenance` in a sentence, for a report."""
    p = provenance()
    return (
        f"Made by pkmctl {p['pkmctl']} (sources {p['pkmctl_sources']}, kernels "
        f"{p['kernel_sources']}) on Python {p['python']}, NumPy {p['numpy']}, Numba "
        f"{p['numba']}."
    )


def save_result(
    result: Result,
    directory: str | os.PathLike[str],
    stem: str | None = None,
    *,
    fmt: str = "parquet",
) -> tuple[Path, Path]:
    """Write the time series (``<stem>.parquet`` or ``.csv``) and ``<stem>.json``, both or
    neither: on any error, Ctrl-C included, the folder keeps its previous files. Then the
    table of ``stem`` in the other format, an earlier run's, is removed: the new
    ``<stem>.json`` does not describe it.

    Returns the two paths (table, metadata). A target that is a folder raises
    :class:`~pkmctl.errors.OutputError` before anything is written.
    """
    if fmt not in FORMATS:
        raise ValueError(f"fmt = {fmt!r}: must be one of {', '.join(FORMATS)}")
    if not isinstance(result, Result):
        raise TypeError(f"result = {result!r:.60}: must be a pkmctl Result (of simulate)")
    if stem is not None and (
        not isinstance(stem, str) or stem in (".", "..") or Path(stem).name != stem or "\\" in stem
    ):  # "../x" wrote outside ``directory``
        raise ValueError(f"stem = {stem!r}: must be a file name, without a folder")
    if stem == "":  # (it fell back to the controller's name, unsaid)
        raise ValueError("stem = '': must be a file name, or None for the controller's name")
    directory = Path(directory)
    stem = stem or result.controller
    names, columns = _columns(result)
    table_path, json_path = directory / f"{stem}.{fmt}", directory / f"{stem}.json"
    meta = {  # all of it before any file is written: an error here leaves nothing
        "format_version": FORMAT_VERSION,
        "controller": result.controller,
        "success": result.success,
        "message": result.message,
        "samples": int(result.t.size),
        "columns": names,
        "table": table_path.name,
        "table_sha256": None,  # of the table file's bytes, once written
        # one logged row still has the loop's metrics over every period
        "metrics": metrics.summary(result)
        if result.t.size > 1 or result.loop_metrics is not None
        else None,
        "loop_metrics": None if result.loop_metrics is None else result.loop_metrics.to_dict(),
        "scenario_toml": result.scenario.to_toml(),
        "parts": dict(result.parts),
        "info": _plain({k: v for k, v in result.info.items() if k != "software"}),
        # a part's own logs (their columns' widths) and every part's final state
        "logs": {
            name: int(np.asarray(log).reshape(result.t.size, -1).shape[1])
            for name, log in result.logs.items()
        },  # fmt: skip
        "final_state": _plain(result.final_state),
        # the software that made the run: a loaded result keeps its own (None: made
        # before it was recorded); a re-save labelled it with the one saving it (a tester)
        "software": result.info["software"] if "software" in result.info else provenance(),
    }
    fis = result.scenario.fuzzy.fis
    if fis is not None:
        try:
            meta["fis_text"] = Path(fis).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            pass  # gone since the run: the result names it, as before
    meta = _finite(meta)
    json.dumps(meta, allow_nan=False)  # a value JSON cannot hold fails here, not midway
    try:
        with atomic_files(table_path, json_path) as (table_tmp, json_tmp):
            _write_table(table_tmp, names, columns, fmt)
            with open(table_tmp, "rb") as fh:  # streamed: a 10 s run's CSV is 335 MB
                meta["table_sha256"] = hashlib.file_digest(fh, "sha256").hexdigest()
            with open(json_tmp, "w", encoding="utf-8", newline="\n") as fh:
                json.dump(meta, fh, indent=2, allow_nan=False)
    except OSError as exc:  # a full disk or a file size limit: which file (it named none)
        if exc.filename is not None:
            raise
        raise OSError(exc.errno, exc.strerror or str(exc), str(table_path)) from exc
    remove_other_formats(directory, stem, fmt)
    return table_path, json_path


def remove_other_formats(directory: Path, stem: str, fmt: str) -> list[Path]:
    """Remove ``<stem>.<format>`` in ``directory`` for every format but ``fmt``: an earlier
    run's table, which stayed beside a new ``<stem>.json`` that does not describe it
    (``identify`` then trusted that json). Returns the files removed."""
    gone = []
    for other in FORMATS:
        stale = Path(directory) / f"{stem}.{other}"
        if other != fmt and (stale.is_file() or stale.is_symlink()):
            stale.unlink()
            gone.append(stale)
    return gone


#: Rows a CSV block formats at once (bounded memory: a 10 s run's file is 330 MB).
_CSV_ROWS = 4096


def _write_table(path: Path, names: list[str], columns: list[np.ndarray], fmt: str) -> None:
    """Write the columns to ``path`` as ``fmt`` (a temporary file: see :func:`save_result`)."""
    if fmt == "csv":
        with open(path, "w", encoding="utf-8", newline="\n") as fh:
            # Each double as Python's repr: the shortest text that reads back to it, and
            # always with a "." or an exponent ("%.17g" wrote 0.0 as "0", so pyarrow,
            # pandas, polars and DuckDB read a column of whole numbers (t logged every
            # second, a zero disturbance) as integers, and -0.0 lost its sign: a tester)
            data = np.column_stack(columns)
            fh.write(",".join(names) + "\n")
            row = ",".join(["%r"] * data.shape[1]) + "\n"
            for start in range(0, data.shape[0], _CSV_ROWS):
                block = data[start : start + _CSV_ROWS]
                fh.write((row * block.shape[0]) % tuple(block.ravel().tolist()))
        return
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table(dict(zip(names, columns, strict=True)))
    # Byte-stream-split + zstd suits floating-point series (a standard Parquet encoding):
    # 8x faster to write and 40 % smaller than the dictionary default.
    # pyarrow's own file on the path's bytes: a str path goes to pyarrow as UTF-8 (a
    # non-ASCII folder under LANG=C was a UnicodeEncodeError), and a Python file object
    # makes pyarrow's thread pool call back into Python, which aborted the interpreter at
    # exit ("terminate called without an active exception": apache/arrow#34314, #50482)
    with pa.OSFile(os.fsencode(path), "wb") as fh:
        pq.write_table(
            table,
            fh,
            compression="zstd",
            use_dictionary=False,
            column_encoding="BYTE_STREAM_SPLIT",
        )


def _plain(value):
    """``value`` with NumPy scalars and arrays as Python numbers and lists (for JSON)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _finite(value):
    """``value`` with every float that is not finite replaced by None (standard JSON)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _scenario(meta: dict) -> Scenario:
    """The run's scenario; its ``.fis`` from the copy the JSON carries when the file is
    gone or has changed since (kept in pkmctl's cache folder, named by its content)."""
    text = meta["scenario_toml"]
    fis_text = meta.get("fis_text")
    if fis_text is not None:
        import tomllib

        from pkmctl import _jit  # so spelled, this module (no compiled code) is no kernel source

        data = tomllib.loads(text)
        path = Path(data["fuzzy"]["fis"])
        try:
            same = path.read_text(encoding="utf-8") == fis_text
        except (OSError, UnicodeDecodeError):
            same = False
        if not same:
            digest = hashlib.sha256(fis_text.encode()).hexdigest()[:16]
            copy = _jit.cache_root() / "fis" / f"{digest}-{path.name}"
            if not copy.exists():
                copy.parent.mkdir(parents=True, exist_ok=True)
                with atomic_write(copy) as fh:
                    fh.write(fis_text)
            data["fuzzy"]["fis"] = str(copy)
            return Scenario.from_dict(data)
    return Scenario.from_toml(text)


def load_result(json_path: str | os.PathLike[str]) -> Result:
    """Read a result written by :func:`save_result` (give the ``.json`` path)."""
    json_path = Path(json_path)
    try:
        meta = json.loads(json_path.read_text(encoding="utf-8"))
        if not isinstance(meta, dict):
            raise ValueError
    except (UnicodeDecodeError, ValueError):  # (json.JSONDecodeError is a ValueError)
        beside = json_path.with_suffix(".json")
        hint = (
            f": give {beside}, written beside it"
            if beside != json_path and beside.is_file()
            else ""
        )
        raise ValueError(
            f"{json_path}: not the JSON file save_result writes beside a result's table{hint}"
        ) from None
    if meta.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{json_path}: unsupported format_version {meta.get('format_version')}")
    names = meta["columns"]
    table_path = json_path.with_name(meta["table"])
    blob = table_path.read_bytes()  # once: the bytes checked are the bytes read
    recorded = meta.get("table_sha256")  # None in a JSON written before it was recorded
    if recorded is not None and hashlib.sha256(blob).hexdigest() != recorded:
        raise ValueError(
            f"{table_path} does not match {json_path}: its SHA-256 is not the table_sha256 "
            f"the JSON records (the two files come from different saves)"
        )
    if table_path.suffix == ".csv":
        # (a StringIO of the decoded text held 4 bytes a character: 1.9 GB for 335 MB)
        text = io.TextIOWrapper(io.BytesIO(blob), encoding="utf-8")
        data = np.loadtxt(text, delimiter=",", skiprows=1, ndmin=2)
    else:
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pq.read_table(pa.BufferReader(blob))
        data = np.column_stack([table.column(n).to_numpy() for n in names])
    if data.shape[1] != len(names):
        raise ValueError(f"{table_path}: expected {len(names)} columns")
    if "samples" in meta and data.shape[0] != meta["samples"]:
        raise ValueError(
            f"{table_path} does not match {json_path}: {data.shape[0]} rows, the JSON's "
            f"samples = {meta['samples']} (the two files come from different saves)"
        )
    fields, col = {"t": data[:, 0]}, 1
    for name, width, _ in _FIELDS:
        fields[name] = data[:, col : col + width]
        col += width
    # (the truth where the sensor's own was not saved: Result fills in what is None)
    fields["q_measured"] = None
    if names[col : col + 4] == list(_MEASURED):
        fields["q_measured"] = data[:, col : col + 4]
        col += 4
    for name, cols in _SEEN:
        fields[name] = None
        if names[col : col + 3] == list(cols):
            fields[name] = data[:, col : col + 3]
            col += 3
    n_theta = sum(1 for n in names[col:] if n.startswith("theta_hat"))
    theta = data[:, col : col + n_theta] if n_theta else None
    col += n_theta
    logs = {}
    for name, width in meta.get("logs", {}).items():
        logs[name] = data[:, col : col + width]
        col += width
    final_state = {  # (a state that is not finite was written as null)
        k: np.array([np.nan if x is None else x for x in v], dtype=np.float64)
        for k, v in meta.get("final_state", {}).items()
    }
    lm = meta.get("loop_metrics")
    try:
        scenario = _scenario(meta)
    except ScenarioError as exc:  # which file: a part not imported, or an edited JSON
        raise ScenarioError(f"{json_path}: its scenario: {exc}") from None
    return Result(
        loop_metrics=None if lm is None else metrics.LoopMetrics.from_dict(lm),
        scenario=scenario,
        controller=meta["controller"],
        theta_hat=theta,
        success=meta["success"],
        message=meta["message"],
        parts=dict(meta.get("parts", {})),
        info={**meta.get("info", {}), "software": meta.get("software")},
        logs=logs,
        final_state=final_state,
        **fields,
    )
