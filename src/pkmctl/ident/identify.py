"""Identification from a logged run (DESIGN.md §9): IDIM-LS and WLS (Gautier).

From limb lengths q(t) and limb forces tau(t):

1. pose X by least-squares forward kinematics (Gauss-Newton, warm-started at the
   previous sample; quantised lengths fit no pose exactly, but lengths whose residual
   exceeds what quantisation and noise explain, :func:`fk_limit`, are refused: another
   machine's, or neighbouring columns swapped; q1<->q3 and q2<->q4, mirror images, fit
   a mirrored pose and are left to step 7);
2. X low-pass filtered (zero-phase Butterworth, order 4, at ``diff_cutoff``, a tenth of
   the sample rate by default, which must be :data:`MIN_POSE_TO_CUTOFF` times the
   cutoff), Xdot and Xddot by sixth-order central differences;
3. the observation J(X)^T tau = W(X, Xdot, Xddot) Theta_ext at every sample (the internal
   forces, in the null space of J^T, carry no information), then y and every column of
   W filtered by the same zero-phase FIR low-pass at ``cutoff`` ("parallel filtering",
   Gautier: a linear filter keeps y = W Theta exact, friction's steps included), only
   where its whole support lies inside the log (2 / cutoff seconds from each end, and
   the differentiating filter's transients), at the samples kept by decimation to
   2.5 * cutoff; reduced to the base parameters (:mod:`pkmctl.ident.base`). Force timing:
   the force acting at t is the logged one at t - ``force_lead`` (0: instantaneous
   readings; a log of commands each held over a control period T needs +T/2; ``None``
   estimates it by least misfit over +-:data:`LEAD_SEARCH` samples, refused at the edge;
   samples whose filter would read forces from beyond the log's ends are dropped);
4. ordinary least squares, then weighted least squares with each axis weighted by the
   inverse of its OLS residual standard deviation;
5. standard deviations from a delete-a-block jackknife (:func:`_jackknife`): the
   filter makes neighbouring residuals correlated, and the textbook sigma^2 (W^T W)^-1
   would claim too much precision; a force lead estimated from the log is refitted in
   every replicate (dy/dlead as one more column), so its uncertainty is included;
6. optionally, a physically consistent standard parameter vector: masses > 0, principal
   inertias satisfying the triangle inequality (written as I_xx = L_y + L_z, ... with
   L >= 0), rotor masses and friction >= 0, fitted to the same weighted data (bounded
   least squares), the directions the data cannot see taken from a prior (the
   scenario's controller model);
7. fit-quality gates (:func:`_check_fit`): a WLS mass clearly below 0, a relative
   residual above ``max_residual`` or an m_platform far from the prior's is refused
   (forces of the wrong sign or units, swapped columns, another machine).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.optimize
import scipy.signal

from pkmctl.errors import PkmctlError
from pkmctl.ident.base import PARAMETER_NAMES, PARAMETER_UNITS, BaseParameters, base_parameters
from pkmctl.model.kinematics import N_BODIES
from pkmctl.model.machine import N_THETA_EXT
from pkmctl.model.mechanism import Mechanism
from pkmctl.sim.scenario import Scenario

__all__ = [
    "Identification",
    "IdentificationError",
    "Log",
    "Observation",
    "check_log_file",
    "fk_limit",
    "identify",
    "max_cutoff",
    "minimum_duration",
    "observe",
    "predict",
    "read_log",
    "sample_rate",
]

#: Fewest samples a fit needs after trimming and decimation, per base parameter.
MIN_SAMPLES_PER_PARAMETER = 3
#: The pose is filtered at this fraction of the sample rate before differentiation
#: (a tenth: 100 Hz at 1 kHz), far above the parallel filter's cutoff: W is nonlinear in
#: the state, so the state must keep what the dynamics holds above the cutoff.
DIFF_CUTOFF_RATIO = 0.1
#: Blocks of the delete-a-block jackknife (the standard deviations).
JACKKNIFE_BLOCKS = 40
#: The rate the observation is decimated to, in multiples of the cutoff: 2.5 leaves
#: neighbouring samples of filtered white noise nearly uncorrelated.
DECIMATED_RATE = 2.5
#: The range of a log's largest |tau| (N) that least squares handles in float64 (its
#: squares must neither underflow nor overflow): it failed at 1e-157 N and 1e303 N.
FORCE_RANGE = (1e-100, 1e100)
#: Largest relative deviation of a sampling interval from the median (a gap beyond it).
MAX_JITTER = 0.01
#: The pose filter must be at least this many times above the parallel filter's cutoff,
#: so the cutoff may be at most fs / 50. Measured on a PD run of the exciting trajectory
#: (1 kHz log, cutoff 10 Hz) decimated: the estimate moved from the 1 kHz one by at most
#: 2.0 of its std at 500 Hz (pose filter 5 x cutoff), 5.7 at 250 Hz (2.5 x), 10 at 200 Hz
#: (2 x) and 26 at 100 Hz (1 x).
MIN_POSE_TO_CUTOFF = 5.0
#: Largest forward-kinematics residual (m) that measurement error explains. Four lengths
#: fit three coordinates, so only the error's component along the one direction J^T does
#: not see is left over: about 2.4 x the encoder noise's std at worst over 60 s at 1 kHz
#: (measured: 3e-8 m with quantisation alone, 2.4e-6 m at 1e-6 m of noise, 5e-6 m with
#: lengths rounded to 10 um), against 1.4e-3 m for another machine's geometry and 0.11 m
#: for swapped columns. The limit is this or FK_NOISE_FACTOR x the scenario's sensor.noise.
MAX_FK_RESIDUAL = 2e-5
FK_NOISE_FACTOR = 8.0
#: ``force_lead=None`` searches this many samples either side of 0.
LEAD_SEARCH = 10
#: Largest relative residual |y - W b| / |y| of the physically consistent fit (of WLS
#: without it) before the log is refused (``max_residual``). Measured (2026-12-06):
#: genuine logs 0.059-0.12 % (noisy synthetic draws 0.059-0.070 %, PD runs 0.07-0.09 %,
#: one decimated to 500 Hz 0.12 %); bad logs 12.2-12.9 % (q2<->q4 or tau2<->tau4, mirror
#: images), 12.4-14.4 % (tau1<->tau2), 22 % (one limb's force negated), 28 % (q1<->q3),
#: 99.8 % (every force negated). 5 %: 40 x the worst genuine log, 2.4 x below the best
#: bad one; a real machine's unmodelled effects may need more (the CLI's --max-residual).
MAX_RELATIVE_RESIDUAL = 0.05
#: A WLS mass more than this many std below 0 is refused (forces of the wrong sign).
#: Measured: genuine logs' most negative mass -2.3 std (a limb's ~1 kg mass, std 1.3 kg,
#: with the friction's v_s mis-modelled), -0.8 std over 20 noisy draws; every force
#: negated: -22.5 std (m_platform).
NEGATIVE_MASS_STD = 5.0
#: Allowed ratio of the identified m_platform to the scenario's prior (its controller
#: model, the CAD). A CAD mass is right to tens of %, measured 0.97-2.0 x on genuine logs;
#: forces in kN give 1e-3 x, motor torques (N m) instead of limb forces l / (2 pi eta) x
#: (measured 0.0018 x at the prototype's 10 mm lead; < 0.1 x for any lead below 0.56 m).
MASS_RATIO = (0.1, 10.0)
#: What a log that fits badly, or only with negative masses, most likely has wrong.
_LIKELY_CAUSES = (
    "forces of the wrong sign (a drive whose positive force retracts the limb), forces in "
    "other units, swapped q or tau columns (q1<->q3 and q2<->q4 are mirror images that fit "
    "the geometry), or another machine (give its --scenario)"
)


class IdentificationError(PkmctlError, ValueError):
    """A log that cannot be identified from (one line: the file, the cause)."""


@dataclass(frozen=True, eq=False)
class Log:
    """A run's time series: t (N,) s, q (N, 4) m, tau (N, 4) N; ``source`` where it came
    from and the columns used; ``what`` names it in errors ("log", "--validate")."""

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    source: str = "log"
    columns: tuple[str, ...] = ()
    what: str = "log"

    @property
    def where(self) -> str:
        """How errors name this log: ``log 'run.csv'``, ``--validate 'other.csv'``."""
        return f"{self.what} {_printable(self.source)!r}"


def _printable(text: str, limit: int = 120) -> str:
    """``text`` with non-printable characters escaped (a binary file's bytes must not
    reach the terminal), cut to ``limit`` characters."""
    out = "".join(c if c.isprintable() else c.encode("unicode_escape").decode() for c in text)
    return out if len(out) <= limit else out[: limit - 3] + "..."


def check_log_file(path: str | Path, *, what: str = "log") -> Path:
    """``path`` as a Path if it is a readable file; else a one-line IdentificationError
    (checked before any long work)."""
    path = Path(path)
    where = f"{what} {_printable(str(path))!r}"
    if path.is_dir():
        raise IdentificationError(f"{where}: is a folder, not a file (give the .csv or .parquet)")
    if not path.is_file():
        if path.exists():  # a FIFO, a device, a socket: not a log to read twice
            raise IdentificationError(f"{where}: not a regular file (give the .csv or .parquet)")
        raise IdentificationError(f"{where}: no such file")
    if not os.access(path, os.R_OK):
        raise IdentificationError(f"{where}: not readable (permission denied)")
    return path


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _sniff(path: Path) -> str:
    """Why a table that failed to read failed, when its first bytes say so ("" if not):
    a Parquet file named otherwise, a CSV named .parquet, binary data, a comment line
    (pyarrow's own message quoted the binary bytes, or a column count)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return ""
    parquet = path.suffix.lower() == ".parquet"
    if head.startswith(b"PAR1") and not parquet:
        return "a Parquet file under another name (name it .parquet)"
    try:
        text = head.decode("utf-8-sig") if b"\0" not in head else None
    except UnicodeDecodeError as exc:  # (a character cut at the 4096th byte is text)
        text = head[: exc.start].decode("utf-8-sig") if exc.start > len(head) - 4 else None
    if text is None:
        return "binary data, neither a Parquet file nor a CSV table"
    if parquet:
        return "text, not a Parquet file (a CSV table? name it .csv)"
    if text.lstrip().startswith("#"):
        return (
            "the first line is a comment ('#...'): remove it; the first line must name the "
            "columns t, q1..q4, tau1..tau4"
        )
    first = text.lstrip().splitlines()[0] if text.strip() else ""
    for sep, name in ((";", "';'"), ("\t", "tabs")):
        if sep in first and "," not in first:  # (a European CSV: ';' and decimal commas)
            return (
                f"the columns are separated by {name} (the header: {_printable(first, 60)!r}); "
                "identify reads comma-separated values with '.' decimals"
            )
    return ""


def _parse_failure(path: Path, message: str) -> str:
    """What a CSV parse error means, where pyarrow's words do not say it ("" if not): a
    last line cut short (a log copied while written), memory exhausted."""
    if "malloc" in message and "failed" in message:
        raise MemoryError(message)  # the command's out-of-memory line, not "unreadable"
    if "Expected" in message and "columns, got" in message:
        try:
            with open(path, "rb") as fh:
                lines = fh.read().rstrip(b"\r\n").splitlines()
        except OSError:
            return ""
        if len(lines) > 2 and lines[-1].count(b",") < lines[0].count(b","):
            return (
                f"the last line (data row {len(lines) - 1}) is incomplete, "
                f"{lines[-1].count(b',') + 1} of {lines[0].count(b',') + 1} columns: the "
                "file was cut short (copied while written?); remove that line"
            )
    return ""


def _read_table(path: Path, what: str = "log") -> tuple[dict, dict[str, int], list[str]]:
    """The columns of a Parquet or CSV table by name (float arrays; None for a non-numeric
    one, its type's name for a date or time one), the names that occur more than once
    (name: count; not read) and the header."""
    where = f"{what} {_printable(str(path))!r}"
    check_log_file(path, what=what)
    try:  # (pyarrow's file on the path's bytes: pyarrow takes a str path as UTF-8, and a
        # non-ASCII one under LANG=C was "binary data, neither a Parquet file nor a CSV
        # table"; a Python file object aborted the interpreter at exit, apache/arrow#50482)
        import pyarrow as pa

        with pa.OSFile(os.fsencode(path)) as fh:
            if path.suffix.lower() == ".parquet":
                import pyarrow.parquet as pq

                table = pq.read_table(fh)
            else:
                import pyarrow.csv as pacsv

                table = pacsv.read_csv(fh)
    except Exception as exc:  # pyarrow's errors: ArrowInvalid, OSError, ...
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        hint = _sniff(path) or _parse_failure(path, first)
        if hint:
            raise IdentificationError(f"{where}: {hint}") from None
        raise IdentificationError(
            f"{where}: not a readable Parquet or CSV table ({_printable(first, 80)})"
        ) from None
    header = [name.strip() for name in table.column_names]
    if header and all(_is_number(n) for n in header):
        raise IdentificationError(
            f"{where}: the header is missing (the first line is numbers: "
            f"{_printable(','.join(table.column_names), 60)!r}); the first line must name the "
            "columns t, q1..q4, tau1..tau4"
        )
    counts: dict[str, int] = {}
    for name in header:
        counts[name] = counts.get(name, 0) + 1
    dups = {n: k for n, k in counts.items() if k > 1}
    out = {}
    for i, name in enumerate(header):
        if name in dups:
            continue  # an error only if it is needed
        col = table.column(i)  # by position: a name may occur twice
        if pa.types.is_temporal(col.type):  # (ISO times became ns since 1970: a code reader)
            out[name] = str(col.type)  # an error only if it is needed
            continue
        try:
            out[name] = col.to_numpy(zero_copy_only=False).astype(float)
        except (TypeError, ValueError):
            out[name] = None  # a non-numeric column: an error only if it is needed
    return out, dups, header


def read_log(path: str | Path, *, what: str = "log") -> Log:
    """Read t, q1..q4 and tau1..tau4 from a Parquet or CSV file.

    pkmctl's own time series (``pkmctl simulate``) carry the true lengths q1..q4 and, when
    the sensor is not ideal, the measured q1_m..q4_m: the measured ones are used. A real
    machine's CSV needs columns t (s), q1..q4 (m), tau1..tau4 (N, limb forces). ``what``
    names the log in errors ("log", "--validate").
    """
    path = Path(path)
    if path.suffix.lower() == ".json" and path.is_file():  # pkmctl's metadata: its table
        import json

        try:
            path = path.with_name(json.loads(path.read_text(encoding="utf-8"))["table"])
        except (ValueError, KeyError, TypeError, UnicodeDecodeError):
            raise IdentificationError(
                f"{what} {_printable(str(path))!r}: not the metadata of a pkmctl time series"
            ) from None
    cols, dups, header = _read_table(path, what)
    where = f"{what} {_printable(str(path))!r}"
    qn = [f"q{i}_m" for i in range(1, 5)]
    if not all(n in cols or n in dups for n in qn):
        qn = [f"q{i}" for i in range(1, 5)]
    need = ["t", *qn, *(f"tau{i}" for i in range(1, 5))]
    twice = [n for n in need if n in dups]
    if twice:
        n = twice[0]
        places = [str(k + 1) for k, h in enumerate(header) if h == n]
        raise IdentificationError(
            f"{where}: column {n} occurs {dups[n]} times (columns {', '.join(places)}): "
            "which one holds the data is ambiguous; rename or remove the others"
        )
    missing = [n for n in need if n not in cols]
    if missing:
        shown = _printable(",".join(header), 80)
        hint = (
            "; identify reads comma-separated values"
            if len(header) == 1 and any(c in header[0] for c in ";\t ")
            else ""
        )
        raise IdentificationError(
            f"{where}: missing column(s) {', '.join(missing)} (need t, q1..q4 in m, "
            f"tau1..tau4 in N; the header read: {shown!r}, {len(header)} column(s){hint})"
        )
    for n in need:
        if isinstance(cols[n], str):
            raise IdentificationError(
                f"{where}: column {n} holds dates or times ({cols[n]}), not numbers: {n} must "
                "be in seconds (e.g. from the log's start)"
            )
        if cols[n] is None:
            raise IdentificationError(f"{where}: column {n} is not numeric")
        bad = np.flatnonzero(~np.isfinite(cols[n]))
        if bad.size:
            raise IdentificationError(
                f"{where}: column {n} holds {bad.size} non-finite value(s), the first at "
                f"data row {bad[0] + 1} ({cols[n][bad[0]]})"
            )
    t = cols["t"]
    q = np.column_stack([cols[n] for n in qn])
    tau = np.column_stack([cols[f"tau{i}"] for i in range(1, 5)])
    return Log(t, q, tau, str(path), tuple(need), what)


def _check_times(log: Log) -> float:
    """The sampling interval (s, the mean, once each is within :data:`MAX_JITTER` of the
    median); one-line errors for what identification cannot use."""
    where = log.where
    t = log.t
    if t.size < 20:
        raise IdentificationError(f"{where}: {t.size} samples, too few (need >= 20)")
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        k = back[0]
        raise IdentificationError(
            f"{where}: time is not increasing at data row {k + 2} (t = {t[k + 1]:.9g} s after "
            f"{t[k]:.9g} s)"
        )
    h = float(np.median(dt))
    gap = np.flatnonzero(np.abs(dt - h) > MAX_JITTER * h)
    if gap.size:
        k = gap[0]
        raise IdentificationError(
            f"{where}: uneven sampling at t = {t[k]:.9g} s (interval {dt[k]:.6g} s, median "
            f"{h:.6g} s; {gap.size} such): a gap or jitter beyond {100 * MAX_JITTER:g} %; "
            "resample the log or cut it there"
        )
    # the mean interval, now that each is within the jitter allowed: at t ~ 1.7e9 s (epoch
    # times) float64 gives intervals of 0.99993 or 1.00017 ms, and the median picked one
    # (1000.07 Hz, decimation to 25.0018 Hz: a code reader); the mean is the span's
    h = float((t[-1] - t[0]) / (t.size - 1))
    names = log.columns[1:5] if len(log.columns) == 9 else tuple(f"q{i}" for i in range(1, 5))
    bad = np.argwhere(log.q <= 0)
    if bad.size:
        k, i = bad[0]
        raise IdentificationError(
            f"{where}: column {names[i]} at data row {k + 1} (t = {t[k]:.9g} s) is "
            f"{log.q[k, i]:g}: limb lengths must be > 0 m"
        )
    zero = [i for i in range(4) if not np.any(log.tau[:, i])]
    if len(zero) == 4:
        raise IdentificationError(
            f"{where}: tau1..tau4 are all zero: the forces carry no information"
        )
    if zero:
        raise IdentificationError(
            f"{where}: column tau{zero[0] + 1} is all zero: a limb's force is missing from "
            "the log, and the fit would be meaningless"
        )
    # least squares squares the forces: beyond these they under- or overflow float64 (1e-200
    # x a log's forces raised a ZeroDivisionError, 1e-160 x "SVD did not converge" and 1e300
    # x a timing diagnosis: a code reader); a real log is in N, far inside
    top = float(np.max(np.abs(log.tau)))
    if not FORCE_RANGE[0] <= top <= FORCE_RANGE[1]:
        raise IdentificationError(
            f"{where}: the largest |tau| is {top:.3g} N, too {'small' if top < 1 else 'large'}"
            f" for the fit (allowed: {FORCE_RANGE[0]:g} to {FORCE_RANGE[1]:g} N): the forces "
            "must be in N"
        )
    return h


def sample_rate(h: float) -> float:
    """The sample rate (Hz) of a log sampled every ``h`` s, to 6 significant digits: a
    mean interval of 0.0010000001 s is 1 kHz (decimation by 40, not 39, at 10 Hz)."""
    return float(f"{1.0 / h:.6g}")


def floor_g(x: float, digits: int = 6) -> float:
    """``x`` to ``digits`` significant digits, rounded down: printed with ``:g`` it is not
    above ``x`` (a largest cutoff of 6.6666667 Hz printed 6.66667, which identify refused
    at the same log: a code reader)."""
    s = float(f"{x:.{digits}g}")
    if not (math.isfinite(x) and s > x):
        return s
    return float(f"{s - 10.0 ** (math.floor(math.log10(abs(s))) - digits + 1):.{digits}g}")


def ceil_g(x: float, digits: int = 6) -> float:
    """``x`` to ``digits`` significant digits, rounded up (see :func:`floor_g`)."""
    return -floor_g(-x, digits)


def max_cutoff(fs: float) -> float:
    """The largest parallel filter cutoff (Hz) for a log sampled at ``fs`` Hz: the pose
    filter (at :data:`DIFF_CUTOFF_RATIO` x fs) must be :data:`MIN_POSE_TO_CUTOFF` times
    above it."""
    return DIFF_CUTOFF_RATIO * fs / MIN_POSE_TO_CUTOFF


#: The parallel filter's cutoff (Hz) unless one is given.
DEFAULT_CUTOFF = 10.0

#: The parallel filter's gain that ``pkmctl excite`` asks at its trajectory's top harmonic
#: (:func:`cutoff_for`): the Hamming FIR of :func:`_lowpass` halves an amplitude at its
#: cutoff and keeps 0.9 of it up to about 0.79 x the cutoff, nothing beyond 1.4 x.
MIN_HARMONIC_GAIN = 0.9


def filter_gain(cutoff: float, fs: float, f: float) -> float:
    """The gain of the parallel filter at ``cutoff`` Hz (a log at ``fs`` Hz) at ``f`` Hz."""
    h = _lowpass(cutoff, fs)
    k = np.arange(h.size) - h.size // 2
    return float(abs(np.sum(h * np.exp(-2j * np.pi * f / fs * k))))


def cutoff_for(f: float, fs: float, least: float = DEFAULT_CUTOFF) -> float | None:
    """The least cutoff (Hz, to 0.1 Hz, at least ``least``, or :func:`max_cutoff` if that
    is lower) whose parallel filter keeps :data:`MIN_HARMONIC_GAIN` of a harmonic at ``f``
    Hz in a log at ``fs`` Hz; None if even :func:`max_cutoff` does not (identify would
    filter the harmonic away). A log below 500 Hz allows no 10 Hz cutoff: it gave 10, and
    excite printed an identify command that identify refused (a tester)."""
    top = floor_g(max_cutoff(fs))  # (printed with :g, it must not round up past the limit)
    if filter_gain(top, fs, f) < MIN_HARMONIC_GAIN:
        return None
    lo, hi = min(least, top), top
    if filter_gain(lo, fs, f) >= MIN_HARMONIC_GAIN:
        return lo
    while hi - lo > 0.05:  # the gain at f rises with the cutoff
        mid = 0.5 * (lo + hi)
        if filter_gain(mid, fs, f) >= MIN_HARMONIC_GAIN:
            hi = mid
        else:
            lo = mid
    return min(top, math.ceil(hi * 10.0 - 1e-9) / 10.0)


def highest_harmonic(fs: float) -> float:
    """The highest frequency (Hz, to 0.01 Hz) of which the parallel filter at the largest
    cutoff a log at ``fs`` Hz allows keeps :data:`MIN_HARMONIC_GAIN`."""
    top = max_cutoff(fs)
    lo, hi = 0.0, top
    while hi - lo > 0.005:
        mid = 0.5 * (lo + hi)
        if filter_gain(top, fs, mid) >= MIN_HARMONIC_GAIN:
            lo = mid
        else:
            hi = mid
    return math.floor(lo * 100.0) / 100.0


def minimum_duration(cutoff: float, parameters: int, fs: float = 1000.0) -> float:
    """Seconds of log an identification at ``cutoff`` Hz needs for ``parameters`` base
    parameters: the filters' support at both ends (the FIR, 4 / cutoff s, and the pose
    filter's transients, 6 / (0.1 fs) s each side) and parameters + 1 jackknife blocks of
    2 / cutoff s. In whole samples, as :func:`observe` counts them: 12.8 Hz at 1 kHz needed
    1.5 ms more than the seconds said (a code reader)."""
    half, trans = 2.0 * fs / cutoff, 6.0 / DIFF_CUTOFF_RATIO
    if math.isfinite(half):
        half, trans = math.ceil(half), math.ceil(trans)
    support = 2.0 * (half + trans + 3.0) / fs
    return support + (parameters + 1) * 2.0 / cutoff


@dataclass(frozen=True, eq=False)
class Observation:
    """The samples a fit uses: t (n,), X, Xdot, Xddot (n, 3), y = J^T tau (n, 3) and W
    (n, 3, 48); ``discarded`` says how many samples were dropped and why; ``fk_residual``
    is the largest forward-kinematics residual |q(X) - q| (m); ``diff_cutoff`` the pose
    filter's cutoff (Hz, Butterworth order 4, zero-phase) and ``fir_taps`` the length of
    the parallel filter (a Hamming-window FIR at ``cutoff``)."""

    t: np.ndarray
    X: np.ndarray
    Xd: np.ndarray
    Xdd: np.ndarray
    y: np.ndarray
    W: np.ndarray
    sample_rate: float
    cutoff: float
    decimation: int
    samples_in: int
    discarded: dict[str, int]
    fk_residual: float
    force_lead: float  # s: the force acting at t is the logged one at t - force_lead
    diff_cutoff: float = math.nan
    fir_taps: int = 0
    #: With a force lead given: (the best lead of the ±LEAD_SEARCH samples, the relative
    #: misfit of least squares at it, at the given lead); None when the lead was searched.
    lead_check: tuple[float, float, float] | None = None
    #: What the pose filter removes from the lengths, rms (m): their noise, or more (it
    #: also takes any motion above ``diff_cutoff``); and the cutoff (Hz) of the limb
    #: rates in the Coulomb columns that this noise allows (:func:`_rate_cutoff`).
    length_noise: float = math.nan
    rate_cutoff: float = math.nan


#: Ratios of a log's lengths to the machine's (their median where forward kinematics
#: failed / the home pose's mean) that name a unit: x 1000 mm, x 100 cm, x 39.37 inches,
#: x 0.001 km; each between the geometric means of its neighbours' factors.
_LENGTH_UNITS = (
    (math.sqrt(100.0 * 1000.0), math.inf, "millimetres"),
    (math.sqrt(39.37 * 100.0), math.sqrt(100.0 * 1000.0), "centimetres"),
    (math.sqrt(39.37 * 10.0), math.sqrt(39.37 * 100.0), "inches"),
    (0.0, math.sqrt(0.001 * 0.01), "kilometres"),
)


def _forward_kinematics(
    mech: Mechanism, log: Log, max_residual: float = math.inf, machine: str = "the scenario"
) -> tuple[np.ndarray, float]:
    """Poses X (n, 3) by least squares and the largest residual |q(X) - q| (m); refused
    if it exceeds ``max_residual``: lengths that no pose of this geometry fits."""
    from pkmctl.model.mechanism import limbs_batch
    from pkmctl.sim.sensors import fk_batch

    X = np.empty((log.t.size, 3))
    q = np.ascontiguousarray(log.q, dtype=float)
    bad, worst = fk_batch(mech.geometry, q, mech.home.copy(), 1e-13, 1e-15, 50, X)
    if bad >= 0:
        home = float(np.mean(mech.inverse_kinematics(mech.home)))
        # lengths in mm read as m: 714 m limbs (a tester); in cm (71 m) or inches the hint
        # was missing (a code reader): the unit whose factor is nearest (geometric means
        # of neighbouring factors as the bounds)
        ratio = float(np.median(q[bad])) / home
        unit = next((u for lo, hi, u in _LENGTH_UNITS if lo < ratio <= hi), None)
        units = (
            f"; lengths of {np.median(q[bad]):.4g} m where the machine's are ~{home:.2g} m: "
            f"in {unit}? (q must be in metres)"
            if unit
            else ""
        )
        raise IdentificationError(
            f"{log.where}: forward kinematics failed at t = {log.t[bad]:.6g} s "
            f"(q = {q[bad].tolist()} m): not lengths of {machine}, or a singular pose{units}"
        )
    if worst > max_residual:
        qx, _ = limbs_batch(mech.geometry, X)
        dev = np.abs(qx - q)
        res = dev.max(axis=1)
        over = np.flatnonzero(res > max_residual)
        k = int(over[0])  # where it starts: an encoder wrap at 6.000 s was named at 6.772 s,
        # the worst row (a tester)
        raise IdentificationError(
            f"{log.where}: the lengths do not fit the geometry of {machine}: forward-"
            f"kinematics residuals over the {max_residual:.3g} m quantisation and sensor "
            f"noise explain from data row {k + 1} (t = {log.t[k]:.6g} s): {over.size} rows, "
            f"the worst {res.max():.3g} m, most on q{int(np.argmax(dev[over].max(axis=0))) + 1}"
            " (a jump or glitch in a length column, q columns swapped or in other units, or "
            "another machine: give its --scenario)"
        )
    return X, float(worst)


#: The share of a force column's samples exactly at its largest or smallest value above
#: which :func:`identify` notes a possible clipping (noise makes a float's extreme unique).
CLIPPED_SHARE = 0.005
#: ... and more than this many times the count of each of the CLIP_NEIGHBOURS levels next to
#: it: forces quantised by the logger (2.16 N, 0.1 % of the drive's rating) sit at their
#: extremes too, and were called clipped (a code reader). Measured on PD and synthetic logs
#: quantised to 1-10 N: a genuine extreme holds at most 2.5 x its neighbours' count;
#: clipped 3 % of the samples, 3.3-14 x (1 % clipped at steps of 5 N or more is lost).
CLIP_LEVEL_RATIO = 3.0
CLIP_NEIGHBOURS = 3


def _clipped(tau: np.ndarray) -> str:
    """Which force columns sit exactly at an extreme value in more than
    :data:`CLIPPED_SHARE` of the samples, far more often than at the levels next to it
    (:data:`CLIP_LEVEL_RATIO`) ("" if none), e.g. "tau3 is exactly -280 or 280 N
    in 4.1 % of the samples" (a tester's clipped logs passed every check)."""
    said = []
    n = tau.shape[0]
    for i in range(tau.shape[1]):
        v = tau[:, i]
        # the levels only where the extremes could be said (a sort of the column: 1.2 s
        # for an hour's log at 1 kHz, where the check took 0.18 s; a review)
        lo, hi = float(v.min()), float(v.max())
        at_ends = np.count_nonzero(v == lo) + (np.count_nonzero(v == hi) if hi != lo else 0)
        if at_ends / max(n, 1) <= CLIPPED_SHARE:
            continue
        levels, counts = np.unique(v, return_counts=True)
        ends = []
        for inward in (slice(0, 1 + CLIP_NEIGHBOURS), slice(None, -2 - CLIP_NEIGHBOURS, -1)):
            c = counts[inward]  # the extreme's count, then its neighbouring levels'
            if c[0] > 2 and c[0] > CLIP_LEVEL_RATIO * c[1:].max(initial=0):
                ends.append(float(levels[inward][0]))
        share = sum(np.count_nonzero(v == e) for e in set(ends)) / max(n, 1)
        if ends and share > CLIPPED_SHARE:
            said.append(
                f"tau{i + 1} is exactly {' or '.join(f'{e:g}' for e in sorted(set(ends)))} N "
                f"in {100 * share:.2g} % of the samples"
            )
    return "; ".join(said)


def _check_poses(
    where: str, mech: Mechanism, X: np.ndarray, t: np.ndarray, first: int = 0
) -> np.ndarray:
    """J (n, 4, 3) of poses X (n, 3), which must be valid (the limits of
    :mod:`pkmctl.model.mechanism`; eigenvalues of J^T J: fast for long logs); X's row 0 is
    the log's data row ``first`` + 1, at time t[0] (t: X's times)."""
    from pkmctl.model.mechanism import (
        MAX_CONDITION,
        MIN_LIMB_LENGTH,
        MIN_SINGULAR_VALUE,
        limbs_batch,
    )

    if not (np.all(X[:, 0] > 0) and np.all(np.abs(X[:, 1:]) < 0.5 * math.pi)):
        raise IdentificationError(f"{where}: the pose leaves the chart (z <= 0 or |angle| >= pi/2)")
    q, J = limbs_batch(mech.geometry, np.ascontiguousarray(X))
    ev = np.linalg.eigvalsh(np.einsum("nji,njk->nik", J, J))  # sigma^2, ascending
    ok = (q.min(axis=1) >= MIN_LIMB_LENGTH) & (ev[:, 0] > MIN_SINGULAR_VALUE**2)
    ok &= ev[:, -1] < MAX_CONDITION**2 * ev[:, 0]
    if not ok.all():
        k = int(np.flatnonzero(~ok)[0])  # (it said "sample k + 1" of the rows checked,
        # three data rows early, and no time: a code reader)
        raise IdentificationError(
            f"{where}: data row {first + k + 1} (t = {t[k]:.6g} s) is at a singular or invalid "
            "pose (its pose filtered for the derivatives)"
        )
    return J


def _lowpass(cutoff: float, fs: float) -> np.ndarray:
    """A linear-phase FIR low-pass (Hamming window), 4 / cutoff seconds long."""
    taps = 2 * math.ceil(2.0 * fs / cutoff) + 1
    return scipy.signal.firwin(taps, cutoff, fs=fs)


def _fir_at(x: np.ndarray, h: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """The zero-phase FIR ``h`` (odd length) applied to x (m, c) at rows ``centres``."""
    half = h.size // 2
    out = np.zeros((centres.size, x.shape[1]))
    for j in range(h.size):
        out += h[j] * x[centres - half + j]
    return out


def _d1(x: np.ndarray, h: float) -> np.ndarray:
    """First derivative, sixth-order central differences (rows 3..n-4 valid)."""
    d = np.full_like(x, np.nan)
    d[3:-3] = (-x[:-6] + 9 * x[1:-5] - 45 * x[2:-4] + 45 * x[4:-2] - 9 * x[5:-1] + x[6:]) / (60 * h)
    return d


def _d2(x: np.ndarray, h: float) -> np.ndarray:
    """Second derivative, sixth-order central differences (rows 3..n-4 valid)."""
    d = np.full_like(x, np.nan)
    d[3:-3] = (
        2 * x[:-6] - 27 * x[1:-5] + 270 * x[2:-4] - 490 * x[3:-3] + 270 * x[4:-2]
        - 27 * x[5:-1] + 2 * x[6:]
    ) / (180 * h * h)  # fmt: skip
    return d


#: Largest cutoff of the limb rates in the Coulomb columns, a fraction of the sample rate.
RATE_CUTOFF_RATIO = 0.4
#: The rates' noise allowed in the Coulomb columns, a fraction of v_s (tanh(qdot / v_s)):
#: more smoothing moves the reversals, more noise blurs them. Measured 2026-12-06 (PD runs
#: of the prototype with 1 um of encoder noise, 6-10 seeds, the 95 % intervals' coverage of
#: the 30 base parameters, on `pkmctl excite`'s trajectory / on another of cond 4,569):
#: the pose filter's 100 Hz as before 82.9 / 52.5 %; 0.25 (133 Hz) 90.0 / 71.2 %; 0.5
#: (210 Hz) 88.8 / 87.9 %; 1.0 (334 Hz) 82.5 / 95.8 %, with force leads near 0 on the
#: first (the drive's is -0.30 ms). With 5 um (5 v_s at 400 Hz) unfiltered rates gave a
#: rotor contrast of -12 kg. Quantisation alone: 400 Hz, 93.3 % (89.4 % before).
RATE_NOISE = 0.5


def _rate_cutoff(q: np.ndarray, fs: float, fd: float, vs: float) -> tuple[float, float]:
    """Cutoff (Hz) of the limb rates for the Coulomb columns: the highest, up to
    :data:`RATE_CUTOFF_RATIO` x fs, at which white noise of the lengths (its std estimated
    from what the pose filter at ``fd`` removes from them) leaves rates of at most
    :data:`RATE_NOISE` x v_s; never below ``fd`` unless ``fd`` is above that cap. (Rate
    noise of a zero-phase filter at f on noise of std s: s 2 pi sqrt(2 f^3 / (3 fs)).)
    Also returns that std (m)."""
    sos = scipy.signal.butter(4, fd, fs=fs, output="sos")
    removed = q - scipy.signal.sosfiltfilt(sos, q, axis=0)
    s2 = float(np.median(np.mean(removed * removed, axis=0))) / max(1e-9, 1.0 - 2.0 * fd / fs)
    top = RATE_CUTOFF_RATIO * fs
    if s2 <= 0.0:
        return top, 0.0
    f = (3.0 * fs * (RATE_NOISE * vs) ** 2 / (2.0 * (2.0 * math.pi) ** 2 * s2)) ** (1.0 / 3.0)
    return float(min(top, max(fd, f))), math.sqrt(s2)


def _check_rate(log: Log, cutoff: float, diff_cutoff: float | None) -> tuple[float, float, float]:
    """The log's interval h (s), sample rate fs and pose filter cutoff fd (Hz), after the
    checks of :func:`_check_times` and of the cutoff against the sample rate."""
    h = _check_times(log)
    fs = sample_rate(h)
    where = log.where
    if not (math.isfinite(cutoff) and cutoff > 0):
        raise IdentificationError(f"cutoff = {cutoff:g} Hz: must be > 0")
    if diff_cutoff is None:
        fd = DIFF_CUTOFF_RATIO * fs
        cmax = max_cutoff(fs)
        if cutoff > cmax:
            raise IdentificationError(
                f"{where}: sampled at {fs:g} Hz, too slowly for cutoff = {cutoff:g} Hz, which "
                f"must be in (0, {floor_g(cmax):g}] Hz for this log (the pose filter, at "
                f"{DIFF_CUTOFF_RATIO:g} x the sample rate, must be >= {MIN_POSE_TO_CUTOFF:g} x "
                f"the cutoff); at {cutoff:g} Hz the log must be sampled at >= "
                f"{ceil_g(cutoff * MIN_POSE_TO_CUTOFF / DIFF_CUTOFF_RATIO):g} Hz"
                + (  # a machine's log at 1 Hz over hours: t in ms (a tester's log said 1 Hz)
                    "; t in milliseconds? (t must be in seconds)"
                    if fs <= 2.0 and log.t[-1] - log.t[0] > 600.0
                    else ""
                )
            )
    else:
        fd = diff_cutoff
        if not (cutoff <= fd < 0.5 * fs):
            raise IdentificationError(
                f"diff_cutoff = {fd:g} Hz: must be in [cutoff, {0.5 * fs:g}) Hz"
            )
    return h, fs, fd


def observe(
    log: Log,
    mechanism: Mechanism,
    *,
    friction_velocity: float = 1e-3,
    cutoff: float = DEFAULT_CUTOFF,
    diff_cutoff: float | None = None,
    decimation: int | None = None,
    force_lead: float | None = None,
    usable: float = 0.0,
    max_fk_residual: float = MAX_FK_RESIDUAL,
    machine: str = "the scenario",
    max_residual: float | None = None,
    excited: Callable[[np.ndarray], None] | None = None,
    check_lead: bool = True,
) -> Observation:
    """The observation of a log (steps 1-3 of the module): see :class:`Observation`.

    ``usable``: seconds the caller needs between the filters' supports (checked before
    any work); ``max_fk_residual`` (m): lengths that fit no pose of ``mechanism`` better
    are refused (``machine`` names it in the error). A given ``force_lead`` must leave
    ``usable`` seconds whose shifted forces were logged (the samples whose filter reaches
    forces from beyond the log's ends are dropped). ``max_residual``: with ``force_lead``
    None, a search whose best lead still leaves more than this relative misfit is refused
    as a problem of the data, not of timing. ``excited(W)`` (W (n, 3, 48)), if given, is
    called before the lead is searched: a log that moves too little to fit is refused for
    that (:func:`check_excitation`), not for a lead that no fit can find. A lead given is,
    with ``check_lead``, compared with the best of the search's (``lead_check``)."""
    h, fs, fd = _check_rate(log, cutoff, diff_cutoff)
    where = log.where
    # the filters' support, before anything is built (a tiny cutoff is a huge FIR)
    n = log.t.size
    # the FIR's half-length (samples), and the differentiating filter's transients (as
    # floats: a cutoff of 1e-308 made them inf, and ceil raised an OverflowError)
    half = 2.0 * fs / cutoff
    edge = half + 6.0 / fd * fs
    if math.isfinite(edge):
        half, edge = math.ceil(half), math.ceil(half) + math.ceil(6.0 / fd * fs)
    span = (n - 1) * h
    need = 2 * (edge + 3) * h + usable
    if span < need * (1.0 - 1e-9):  # (rounding: an interval of 0.99999999999989 ms made
        # 6727 samples 6.726 s short of 6.726 s; excite's runs are timed for that: a code reader)
        # (rounded the right ways, and in samples: 9168 samples, "9.167 s", were refused
        # as needing ">= 9.167 s": a review)
        # (no count where the need is infinite: a cutoff of 1e-308 Hz)
        count = need * (1.0 - 1e-9) / h
        need_n = f", {math.ceil(count) + 1} samples" if math.isfinite(count) else ""
        raise IdentificationError(
            f"{where}: {n} samples ({floor_g(span):g} s), too short for cutoff = {cutoff:g} "
            f"Hz: it needs >= {ceil_g(need):g} s{need_n} (the filters' support, "
            f"{(edge + 3) * h:.3g} s at each end, and {usable:.3g} s between); log a longer "
            "run or raise the cutoff"
        )
    # forces shifted by the lead must have been logged: the first (last) kept sample's
    # FIR reaches back (ahead) to t0 + (edge - half + 3) h, so a lead up to that costs
    # nothing, and each further sample costs one of the usable ones
    margin = (edge - half + 3) * h
    lead_max = margin + (n - 6 - 2 * edge) * h - usable
    if force_lead is not None and not abs(force_lead) <= lead_max:
        raise IdentificationError(
            f"{where}: force_lead = {force_lead:+.4g} s shifts the forces beyond the log's "
            f"ends: this log ({span:.4g} s) allows |force_lead| <= {lead_max:.3g} s (the "
            f"forces it reads must be logged ones over the {usable:.3g} s needed between the "
            "filters' supports); a lead is a fraction of a control period to a few periods"
        )
    X, fk_res = _forward_kinematics(mechanism, log, max_fk_residual, machine)
    Xf = scipy.signal.sosfiltfilt(scipy.signal.butter(4, fd, fs=fs, output="sos"), X, axis=0)
    Xd, Xdd = _d1(Xf, h), _d2(Xf, h)
    inner = slice(3, n - 3)  # where the differences are defined
    from pkmctl.model.mechanism import extended_regressor_batch

    Xi, Xdi, Xddi = (np.ascontiguousarray(a[inner]) for a in (Xf, Xd, Xdd))
    J = _check_poses(where, mechanism, Xi, log.t[inner], inner.start)
    W = extended_regressor_batch(mechanism.geometry, Xi, Xdi, Xdi, Xddi, friction_velocity)
    # The Coulomb columns J_i^T tanh(qdot_i / v_s) from the limb rates of the measured
    # lengths themselves, not from the pose filtered at fd: the friction makes every
    # reversal a kink in qdot (deceleration before it stronger than the acceleration after
    # it), the pose filter rounds the kink, and the filtered rate crossed zero 0.2-1.3 ms
    # late (by 0.6-1.5 mm/s, against v_s = 1 mm/s). Each late step of the regressor left
    # an impulse of ~2 F_c x 0.5 ms per reversal that least squares put into the rotor
    # masses' mirror contrast (m_r1 + m_r3 - m_r2 - m_r4), the friction and, through
    # force_lead 'auto', the force timing (found -0.16 ms for the drive's -0.30 ms).
    # The rates are filtered only as much as the lengths' noise needs (:func:`_rate_cutoff`:
    # quantisation alone, 0.4 fs; noisier encoders down to the pose filter's fd, as before).
    q = np.asarray(log.q, dtype=float)
    fq, noise = _rate_cutoff(q, fs, fd, friction_velocity)
    qf = scipy.signal.sosfiltfilt(scipy.signal.butter(4, fq, fs=fs, output="sos"), q, axis=0)
    qd = np.ascontiguousarray(_d1(qf, h)[inner])
    W[:, :, N_THETA_EXT - 8 : N_THETA_EXT - 4] = np.einsum(
        "nia,ni->nai", J, np.tanh(qd / friction_velocity)
    )
    # Parallel filtering (Gautier): the same linear filter on y and on every column of W
    # keeps y = W Theta exact, also for the friction's steps at velocity reversals. A
    # zero-phase FIR, evaluated only at the samples kept after decimation.
    h_fir = _lowpass(cutoff, fs)
    m = n - 6
    dec = decimation if decimation is not None else max(1, int(fs // (DECIMATED_RATE * cutoff)))
    if dec < 1:
        raise IdentificationError(f"decimation = {dec}: must be >= 1")
    keep = np.arange(edge, m - edge)[::dec]
    decimated = f"decimation by {dec} (to {fs / dec:g} Hz)"
    discarded = {
        f"filter support and transients ({edge / fs:.3g} s at each end)": int(min(n, 2 * edge + 6)),
        decimated: int(max(0, m - 2 * edge) - keep.size),
    }
    if keep.size == 0:
        raise IdentificationError(
            f"{where}: {n} samples ({n * h:.3g} s) leave none after the filters' "
            f"support ({edge} samples at each end); log a longer run"
        )
    W = _fir_at(W.reshape(m, -1), h_fir, keep).reshape(keep.size, 3, -1)
    t_in = log.t[inner]

    def observed(lead: float) -> np.ndarray:
        # the force acting at t: the logged one at t - lead (lead > 0: a log whose forces
        # are each held over the following period, centred half a period later)
        tau = np.column_stack([np.interp(t_in - lead, log.t, log.tau[:, i]) for i in range(4)])
        return _fir_at(np.einsum("nij,ni->nj", J, tau), h_fir, keep)

    A = W.reshape(-1, W.shape[-1])

    def misfit(lead: float, relative: bool = False) -> float:
        y = observed(lead).reshape(-1)
        beta, *_ = np.linalg.lstsq(A, y, rcond=1e-10)
        e = float(np.linalg.norm(y - A @ beta))
        return e / float(np.linalg.norm(y)) if relative else e

    # every sample within +-LEAD_SEARCH (then, searching, the best one's neighbourhood)
    grid = h * np.arange(-LEAD_SEARCH, LEAD_SEARCH + 1)
    lead_check = None
    if force_lead is not None and check_lead:  # a lead given: against the grid's best
        rel = [misfit(v, relative=True) for v in grid]
        k = int(np.argmin(rel))
        lead_check = (float(grid[k]), rel[k], misfit(force_lead, relative=True))
    if force_lead is None:
        if excited is not None:
            excited(W)
        k = int(np.argmin([misfit(v) for v in grid]))
        rel = misfit(grid[k], relative=True)
        if k in (0, grid.size - 1) and max_residual is not None and rel > max_residual:
            raise IdentificationError(
                f"{where}: force lead 'auto': even the best lead searched (+-{LEAD_SEARCH} "
                f"samples) leaves {100 * rel:.4g} % of J^T tau unexplained (relative residual "
                f"of least squares; max_residual = {100 * max_residual:g} %): not a timing "
                f"problem but the data: {_LIKELY_CAUSES}"
            )
        if k in (0, grid.size - 1):
            raise IdentificationError(
                f"{where}: force lead 'auto': the misfit is smallest at the edge of the "
                f"searched +-{LEAD_SEARCH} samples ({1e3 * grid[k]:+.4g} ms): the forces are "
                "further out of step than that, or the log is not what the model describes; "
                "give the lead in seconds"
            )
        force_lead = float(
            scipy.optimize.minimize_scalar(
                misfit, bounds=(grid[k - 1], grid[k + 1]), method="bounded",
                options={"xatol": 1e-6 * h},
            ).x
        )  # fmt: skip
    # drop the samples whose filter would read forces from beyond the log's ends (np.interp
    # would repeat the first or last one): none for a lead within ``margin``
    shifted = t_in[np.concatenate([keep - half, keep + half])] - force_lead
    inside = (shifted[: keep.size] >= log.t[0] - 1e-9 * h) & (
        shifted[keep.size :] <= log.t[-1] + 1e-9 * h
    )
    if not inside.all():  # counted in the log's samples: each kept one stood for ``dec``
        lost = int(np.sum(~inside))
        discarded[decimated] -= lost * (dec - 1)
        discarded[f"force lead {force_lead:+.4g} s: its forces from beyond the log's ends"] = (
            lost * dec
        )
        keep, W = keep[inside], W[inside]
    y = observed(force_lead)
    Xk, Xdk, Xddk = Xf[inner][keep], Xd[inner][keep], Xdd[inner][keep]
    return Observation(
        t_in[keep], Xk, Xdk, Xddk, y, W, fs, cutoff, dec, n, discarded, fk_res, force_lead,
        fd, h_fir.size, lead_check, noise, fq,
    )  # fmt: skip


def _jackknife(
    A: np.ndarray, y: np.ndarray, n: int, blocks: int, lead: np.ndarray | None = None
) -> np.ndarray:
    """Delete-a-block jackknife covariance of the least-squares estimate: A (3n, r) rows in
    time order (3 per sample), y (3n,); ``blocks`` contiguous blocks of samples, each left
    out once. Unlike sigma^2 (A^T A)^-1 or Newey-West on the residuals, it needs no model
    of the residuals' correlation, and a left-out block's noise is not absorbed by the fit
    (measured on this problem: the textbook estimate 1.6 times and Newey-West 1.2 times too
    small in std, this one within 5 %; docs/identification.md).

    ``lead`` (3n,): dy/d(force_lead), when the force lead was estimated from the same data
    (``force_lead=None``). It is then fitted as one more column in every replicate, so the
    lead is re-estimated (to first order) without each block and its uncertainty reaches
    the parameters' covariance (r, r); a lead held fixed there left the std of the mean
    rotor mass 1.6-1.9 times too small (docs/identification.md, step 6)."""
    if lead is not None:
        A = np.column_stack([A, lead])
    AtA, Aty = A.T @ A, A.T @ y
    bs = []
    for g in np.array_split(np.arange(n), blocks):
        rows = slice(3 * g[0], 3 * g[-1] + 3)
        Ag, yg = A[rows], y[rows]
        bs.append(np.linalg.solve(AtA - Ag.T @ Ag, Aty - Ag.T @ yg))
    d = np.array(bs) - np.mean(bs, axis=0)
    cov = (blocks - 1) / blocks * (d.T @ d)
    return cov if lead is None else cov[:-1, :-1]


def _lead_sensitivity(
    log: Log, mech: Mechanism, obs: Observation, vs: float, label: str, fk_max: float
) -> np.ndarray | None:
    """dy/d(force_lead) (3n,) at the estimated lead: central differences of the observation
    over +-1 sample of lead (W does not depend on the lead: only y is used). None if the
    shifted observations keep other samples (a lead near the log's usable margin: cannot
    happen within the +-LEAD_SEARCH samples searched, far inside it)."""
    h = 1.0 / obs.sample_rate
    ys = []
    for lead in (obs.force_lead + h, obs.force_lead - h):
        o = observe(
            log, mech, friction_velocity=vs, cutoff=obs.cutoff, decimation=obs.decimation,
            force_lead=lead, max_fk_residual=fk_max, machine=label, check_lead=False,
        )  # fmt: skip
        if o.t.shape != obs.t.shape or not np.array_equal(o.t, obs.t):
            return None
        ys.append(o.y.reshape(-1))
    return (ys[0] - ys[1]) / (2.0 * h)


@dataclass(frozen=True, eq=False)
class Fit:
    """One least-squares fit: beta (r,), its covariance and std (r,), the residual RMS
    per axis [z N, alpha N m, beta N m] and overall relative error |y - W b| / |y|."""

    beta: np.ndarray
    cov: np.ndarray
    std: np.ndarray
    rms: np.ndarray
    relative_error: float

    @property
    def std_percent(self) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100.0 * self.std / np.abs(self.beta)


@dataclass(frozen=True, eq=False)
class Identification:
    """Everything ``identify`` found (units: SI; see :class:`Fit`)."""

    base: BaseParameters
    observation: Observation
    ols: Fit
    wls: Fit
    cond: float  # of the stacked base observation matrix
    physical: np.ndarray | None  # Theta_ext (48,), physically consistent, or None
    physical_fit: Fit | None
    friction_velocity: float
    seconds: float
    notes: list[str] = field(default_factory=list)
    scenario: str = ""  # the machine (geometry, prior) assumed: its name and origin
    active_bounds: tuple[str, ...] = ()  # of the physically consistent fit, e.g. "Fc1 = 0"
    compile_seconds: float = 0.0  # compiling kernels it needed (once per machine), not in seconds

    def __repr__(self) -> str:
        # the dataclass's showed every array of the observation: 108,480 characters
        rms = ", ".join(f"{v:.3g}" for v in self.wls.rms)
        return (
            f"Identification({self.scenario or 'a log'}: {self.base.count} base parameters "
            f"from {self.observation.t.size} samples, cond {self.cond:.4g}, WLS residual RMS "
            f"[{rms}] (N, N m, N m), {100 * self.wls.relative_error:.3g} %; "
            f"{len(self.notes)} notes; {self.seconds:.2f} s)"
        )

    def controller_model(self) -> dict:
        """A scenario ``[controller_model]`` block with the physically consistent estimate."""
        if self.physical is None:
            raise IdentificationError("no physically consistent estimate (run with physical)")
        return {
            "theta_ext": [float(v) for v in self.physical],
            "friction_velocity": float(self.friction_velocity),
        }


def _fit(
    A: np.ndarray,
    y: np.ndarray,
    n: int,
    blocks: int,
    scale: np.ndarray,
    lead: np.ndarray | None = None,
) -> Fit:
    """Least squares of y on A; the covariance by :func:`_jackknife` (with ``lead``, dy/d
    force_lead weighted as A, when the lead was estimated: the estimate is unchanged, its
    uncertainty includes the lead's)."""
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    e = y - A @ beta
    cov = _jackknife(A, y, n, blocks, lead)
    e3 = (e / np.tile(scale, n)).reshape(n, 3)
    y3 = (y / np.tile(scale, n)).reshape(n, 3)
    return Fit(
        beta,
        cov,
        np.sqrt(np.maximum(np.diag(cov), 0.0)),
        np.sqrt(np.mean(e3 * e3, axis=0)),
        float(np.linalg.norm(e3) / np.linalg.norm(y3)),
    )


def _to_standard() -> np.ndarray:
    """T (48, 48): Theta_ext = T phi, phi = per body [m, L_x, L_y, L_z], then m_r, F_c,
    F_v; I_xx = L_y + L_z, I_yy = L_x + L_z, I_zz = L_x + L_y."""
    T = np.eye(N_THETA_EXT)
    for b in range(N_BODIES):
        o = 4 * b
        T[o + 1 : o + 4, o + 1 : o + 4] = [[0, 1, 1], [1, 0, 1], [1, 1, 0]]
    return T


#: Floor of each standard parameter's scale in the physical fit's pull to the prior.
_UNIT_SCALE = np.array(
    [{"kg": 1.0, "kg m^2": 1e-2, "N": 10.0, "N s/m": 100.0}[u] for u in PARAMETER_UNITS]
)


#: Names of phi (see :func:`_to_standard`): per body m, L_x, L_y, L_z (L_x = (I_yy + I_zz
#: - I_xx) / 2, ...), then the rotor masses and friction as in Theta_ext.
_PHI_NAMES = tuple(
    n.replace("Ixx", "Lx").replace("Iyy", "Ly").replace("Izz", "Lz") for n in PARAMETER_NAMES
)


def _lower_bounds() -> np.ndarray:
    """Lower bounds of phi (48,): masses 1e-3 kg, L 1e-7 kg m^2 (inertias stay > 0),
    rotor masses and friction 0."""
    lo = np.zeros(N_THETA_EXT)
    for b in range(N_BODIES):
        lo[4 * b] = 1e-3  # kg
        lo[4 * b + 1 : 4 * b + 4] = 1e-7  # kg m^2
    return lo


def _physical(
    A: np.ndarray, y: np.ndarray, base: BaseParameters, prior: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Bounded least squares over phi (see :func:`_to_standard`), a tiny pull to the prior
    in the directions the data does not see: Theta_ext (48,) and the indices of phi at
    their bound."""
    T = _to_standard()
    M = A @ base.K @ T
    Tinv = np.linalg.inv(T)
    phi0 = Tinv @ prior
    # scale of each parameter for the pull: the prior's magnitude, at least a unit's worth
    # (a zero prior, e.g. no friction in the model, must not pin the estimate to zero)
    ref = np.maximum(np.abs(prior), _UNIT_SCALE)
    lam = 1e-6 * np.linalg.norm(M) / math.sqrt(N_THETA_EXT)
    Reg = lam * (T / ref[:, None])
    lo = _lower_bounds()
    phi0 = np.clip(phi0, lo, None)
    res = scipy.optimize.lsq_linear(
        np.vstack([M, Reg]),
        np.concatenate([y, lam * prior / ref]),
        bounds=(lo, np.inf),
        method="bvls",
        tol=1e-12,
    )
    return T @ res.x, np.flatnonzero(res.active_mask != 0)


def _compile_time_apart(fn):
    """``fn`` (an identification) with the time a first compilation of the kernels it
    needed took apart from its ``seconds``: in ``compile_seconds``; and BLAS in one thread
    while it runs. Its matrices (a few thousand rows by 48) gain nothing from more, and
    OpenBLAS's threads spinning on a busy 2-core machine made a 60 s log's identification
    take 2.9-5.3 s where one thread took 0.78-0.83 s (measured side by side, 2026-12-07)."""

    @functools.wraps(fn)
    def timed(*args, **kwargs) -> Identification:
        from threadpoolctl import threadpool_limits

        from pkmctl import _jit  # (so written: the text would make this file a kernel source)

        clock = _CompileClock()
        with _jit.announce(clock), threadpool_limits(limits=1, user_api="blas"):
            idn = fn(*args, **kwargs)
        spent = clock.seconds
        return dataclasses.replace(idn, seconds=max(0.0, idn.seconds - spent),
                                   compile_seconds=spent)  # fmt: skip

    return timed


class _CompileClock:
    """The wall time during which at least one compilation ran (in any thread), from
    the compile announcements' events."""

    def __init__(self) -> None:
        self.active, self.since, self.seconds = 0, 0.0, 0.0
        self._lock = threading.Lock()

    def __call__(self, event: str, what: str, seconds: float) -> None:
        with self._lock:
            now = time.perf_counter()
            if event == "start":
                if self.active == 0:
                    self.since = now
                self.active += 1
            elif self.active > 0:
                self.active -= 1
                if self.active == 0:
                    self.seconds += now - self.since


@_compile_time_apart
def identify(
    log: Log,
    scenario: Scenario,
    *,
    cutoff: float = DEFAULT_CUTOFF,
    decimation: int | None = None,
    physical: bool = True,
    friction_velocity: float | None = None,
    force_lead: float | None = 0.0,
    scenario_label: str | None = None,
    max_residual: float | None = MAX_RELATIVE_RESIDUAL,
    mass_ratio: tuple[float, float] | None = MASS_RATIO,
) -> Identification:
    """Identify the base parameters (and a physically consistent Theta_ext) from ``log``
    on ``scenario``'s geometry; the prior of the physical estimate is the scenario's
    controller model. ``scenario_label`` names the scenario in errors and the report
    (default: its name). See the module for the method.

    Refused (:func:`_check_fit`) unless ``max_residual`` is None: a WLS mass more than
    :data:`NEGATIVE_MASS_STD` std below 0, or a relative residual of the physically
    consistent fit (of WLS without ``physical``) above ``max_residual``; unless
    ``mass_ratio`` is None, an m_platform outside ``mass_ratio`` x the prior's.

    ``seconds`` of the result is the identification's own time; a first compilation of
    kernels it needed (once per machine) is ``compile_seconds``, not in it."""
    t0 = time.perf_counter()
    label = scenario_label or f"scenario {scenario.name!r}"
    if max_residual is not None and not 0.0 < max_residual <= 1.0:  # NaN too; before the fit
        raise IdentificationError(
            f"max_residual = {max_residual!r}: must be in (0, 1], a fraction (the command's "
            "--max-residual is in %), or None for no gate"
        )
    _check_mass_ratio_bounds(mass_ratio)
    _check_rate(log, cutoff, None)  # a bad log is refused before any work
    mech = scenario.plant()  # the geometry only: W does not depend on Theta
    vs = scenario.plant_spec.friction_velocity if friction_velocity is None else friction_velocity
    base = base_parameters(mech, vs)
    obs = observe(
        log,
        mech,
        friction_velocity=vs,
        cutoff=cutoff,
        decimation=decimation,
        force_lead=force_lead,
        usable=(base.count + 1) * 2.0 / cutoff,
        max_fk_residual=fk_limit(scenario),
        machine=label,
        max_residual=max_residual,
        excited=lambda W: check_excitation(log.where, base, base.reduce(W).reshape(-1, base.count)),
    )
    n, r = obs.t.size, base.count
    where = log.where
    if n < MIN_SAMPLES_PER_PARAMETER * r:
        raise IdentificationError(
            f"{where}: {n} samples after trimming and decimation, too few for {r} base "
            f"parameters (need >= {MIN_SAMPLES_PER_PARAMETER * r}); log a longer run"
        )
    A = base.reduce(obs.W).reshape(3 * n, r)
    y = obs.y.reshape(3 * n)
    cond = check_excitation(where, base, A)  # (A reduced once, here)
    # blocks at least 2 / cutoff long (the filtered residuals' correlation), at most 40
    span = 2.0 / obs.cutoff * obs.sample_rate / obs.decimation
    blocks = int(min(JACKKNIFE_BLOCKS, n // max(1.0, span)))
    if blocks < r + 1:
        raise IdentificationError(
            f"{where}: {n * obs.decimation / obs.sample_rate:.3g} s of usable log, too short "
            f"to estimate the uncertainty of {r} parameters (need {r + 1} blocks of "
            f"{2.0 / obs.cutoff:g} s); log a longer run"
        )
    # a lead estimated from this log (force_lead None) is one more fitted quantity: its
    # uncertainty belongs in the parameters' (the jackknife fits dy/dlead as a column)
    dy = None
    if force_lead is None:
        dy = _lead_sensitivity(log, mech, obs, vs, label, fk_limit(scenario))
    ones = np.ones(3)
    ols = _fit(A, y, n, blocks, ones, dy)
    sigma = np.maximum(ols.rms, 1e-300)
    w = np.tile(1.0 / sigma, n)
    wls_w = _fit(A * w[:, None], y * w, n, blocks, 1.0 / sigma, None if dy is None else dy * w)
    wls = Fit(wls_w.beta, wls_w.cov, wls_w.std, _residual_rms(A, y, wls_w.beta, n),
              _rel(A, y, wls_w.beta))  # fmt: skip
    phys = phys_fit = None
    notes = []
    cm = scenario.controller_model
    m_r, fc, fv = cm.machine_terms(scenario.plant_spec.screw_lead)
    prior = np.concatenate([scenario.controller_mechanism().theta, m_r, fc, fv])
    if physical:
        phys, at_bound = _physical(A * w[:, None], y * w, base, prior)
        lo = _lower_bounds()
        active = tuple(f"{_PHI_NAMES[j]} = {lo[j]:g}" for j in at_bound)
        bp = base.base(phys)
        phys_fit = Fit(bp, wls.cov, wls.std, _residual_rms(A, y, bp, n), _rel(A, y, bp))
        moved = np.flatnonzero(np.abs(bp - wls.beta) > 2 * wls.std)
        if moved.size:
            KT = base.K @ _to_standard()  # beta in terms of phi: which bounds each holds
            which = []
            for k in moved:
                own = [active[i] for i, j in enumerate(at_bound) if KT[k, j] != 0]
                at = f" (at a bound: {', '.join(own)})" if own else ""
                which.append(f"#{k + 1} {base.expressions[k]}{at}")
            why = (
                f"{len(active)} bound(s) active in the physical fit; one moves the others "
                "through the data's correlations"
                if active
                else "no bound is active: the pull towards the prior moved them"
            )
            notes.append(
                "the physically consistent estimate differs from WLS by more than 2 std in "
                f"{'; '.join(which)} ({why})"
            )
    if obs.lead_check is not None:
        note = lead_note(obs)
        if note:
            notes.append(note)
    if obs.length_noise > NOISY_LENGTHS:
        notes.append(
            f"the lengths' noise, <= {1e6 * obs.length_noise:.3g} um rms, is over "
            f"{1e6 * NOISY_LENGTHS:g} um: identification was measured to work at 1 um of encoder "
            "noise and not at 5 um (the friction columns fail, the rotor masses came out "
            "8.0-13.7 kg for 10.9; docs/identification.md): trust this estimate less"
        )
    if clipped := _clipped(log.tau):
        notes.append(
            f"{clipped}: a logger (or a drive's report) that clips the force there gives a "
            "wrong estimate that passes every check (1-9 % of samples clipped at 280 N gave "
            "a platform of 1.2 kg for 12.75 and a 2.5-3.6 % residual: docs/identification.md); "
            "a drive's own saturation, logged as the force it gives, is fine"
        )
    # a lead given far from 0 (more than a few samples) is another suspect, and so is one
    # that fits much worse than the best near 0 (5 ms late forces at the default 0 were
    # blamed on signs, units and columns only)
    misfit = lead_note(obs)
    far = abs(obs.force_lead) > LEAD_SEARCH / obs.sample_rate
    lead = obs.force_lead if far and not misfit else None
    _check_fit(where, base, wls, phys_fit, prior, max_residual, mass_ratio, lead, misfit,
               searched=force_lead is None)  # fmt: skip
    return Identification(
        base, obs, ols, wls, cond, phys, phys_fit, vs, time.perf_counter() - t0, notes,
        label, active if physical else (),
    )  # fmt: skip


#: Lengths noisier than this (m rms, what the pose filter removes) get a note: 1 um of
#: encoder noise identifies (friction coverage 85-88 %), 5 um does not (docs/identification.md).
NOISY_LENGTHS = 2e-6

#: A given force lead whose relative misfit is more than this many times that of the best
#: lead within +-LEAD_SEARCH samples (more than a sample away) is named in the notes.
#: Measured on a tester's drive log: -0.32 ms best (0.061 %), -3 ms 0.39 %, -20 ms 3.1 %.
LEAD_MISFIT_RATIO = 2.0


def lead_note(obs: Observation) -> str:
    """A note when the force lead given fits much worse than the best one near 0, else ""."""
    if obs.lead_check is None:
        return ""
    best, at_best, at_given = obs.lead_check
    h = 1.0 / obs.sample_rate
    if at_given <= LEAD_MISFIT_RATIO * at_best or abs(obs.force_lead - best) <= h:
        return ""
    return (
        f"the force lead given, {1e3 * obs.force_lead:+.4g} ms, leaves {100 * at_given:.3g} % "
        f"of J^T tau unexplained by least squares; {1e3 * best:+.4g} ms, the best of the "
        f"+-{LEAD_SEARCH} samples around 0, leaves {100 * at_best:.3g} %: check the lead, "
        "or let --force-lead auto estimate it"
    )


def check_excitation(where: str, base: BaseParameters, A: np.ndarray) -> float:
    """cond of the base observation matrix A (3n, base.count); refused if its rank is
    short of ``base.count`` (the trajectory does not move some base parameters: named)."""
    r = base.count
    norms = np.linalg.norm(A, axis=0)
    # columns of rounding alone (a constant pose's accelerations) scaled to unit norm added
    # rank: a constant pose read "rank 5 of 30"
    live = norms > 1e-9 * norms.max(initial=0.0)
    sv = np.linalg.svd(A[:, live] / norms[live], compute_uv=False)
    rank = int(np.sum(sv > 1e-9 * sv[0])) if sv.size else 0
    cond = float(np.linalg.cond(A))
    if rank < r:
        weakest = [base.names[k] for k in np.argsort(np.linalg.norm(A, axis=0))[: r - rank]]
        raise IdentificationError(
            f"{where}: no excitation: the observation matrix has rank {rank} of {r} "
            f"(cond {cond:.3g}); the trajectory does not move {', '.join(weakest)} "
            "(use pkmctl excite)"
        )
    return cond


def _check_mass_ratio_bounds(mass_ratio: object) -> None:
    """``mass_ratio`` is None or (low, high) with 0 <= low <= high (high may be inf):
    refused before the fit, not after it (a bad pair raised a TypeError, or passed
    every mass)."""
    import numbers

    ok = mass_ratio is None
    if not ok:
        try:
            lo, hi = mass_ratio  # type: ignore[misc]
            real = all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in (lo, hi))
            ok = real and 0.0 <= lo <= hi  # (NaN fails; "10", which float() took, failed
            # after the fit with NumPy's UFuncTypeError: a reviewer)
        except (TypeError, ValueError):
            pass
    if not ok:
        raise IdentificationError(
            f"mass_ratio = {mass_ratio!r}: must be None (no check) or (low, high) with "
            "0 <= low <= high, the identified m_platform's bounds as a multiple of the "
            "prior's (default (0.1, 10))"
        )


def _check_fit(
    where: str,
    base: BaseParameters,
    wls: Fit,
    phys_fit: Fit | None,
    prior: np.ndarray,
    max_residual: float | None,
    mass_ratio: tuple[float, float] | None,
    lead: float | None = None,
    misfit: str = "",
    searched: bool = True,
) -> None:
    """Refuse a fit that no genuine log gives (one line each): a clearly negative WLS mass,
    a relative residual above ``max_residual`` (of the physically consistent fit if there
    is one, else of WLS), an m_platform outside ``mass_ratio`` x the prior's (before the
    residual when it is positive and WLS fits: forces in other units). ``lead``: a
    force lead given that is itself suspect (named among the causes); ``misfit``: the
    :func:`lead_note` saying it fits much worse than the best near 0 (named first);
    ``searched`` False: the lead was given (or the default 0), not searched."""
    causes = _LIKELY_CAUSES
    if lead is not None:
        causes += f", or a wrong force_lead = {lead:+.4g} s"
    elif not searched and not misfit:  # (a genuine pkmctl log, copied without its .json,
        # needed -0.25 ms; the message named only signs, units, columns and machines, and
        # the --scenario it advised failed the same way: a tester)
        causes += (
            ", or forces out of step with the lengths by a fraction of a sample (a "
            "controller's logged force acts over the period after it): try force_lead = "
            "auto"
        )
    if misfit:
        causes = f"{misfit}; else {causes}"
    m0 = prior[PARAMETER_NAMES.index("m_platform")]
    ratio = None
    if mass_ratio is not None and "m_platform" in base.expressions and m0 > 0:
        k_m = base.expressions.index("m_platform")
        ratio = wls.beta[k_m] / m0

    def check_mass_ratio() -> None:
        if ratio is None:  # (mass_ratio None: the check is off; unpacked first, it raised)
            return
        lo, hi = mass_ratio
        if lo <= ratio <= hi:
            return
        why = (
            causes
            if ratio <= 0
            else (f"{misfit}; else " if misfit else "")
            + "forces in other units (kN instead of N: 1e-3 x), or motor torques in "
            "N m instead of limb forces (f = 2 pi eta T / lead: lead / (2 pi eta) x); or "
            "the prior is not this machine's (give its --scenario, with its masses)"
        )
        raise IdentificationError(
            f"{where}: m_platform = {wls.beta[k_m]:.4g} kg (WLS) is {ratio:.3g} x the "
            f"scenario's prior {m0:.4g} kg (allowed {lo:g}-{hi:g} x): {why}"
        )

    if max_residual is not None:
        masses = [k for k, e in enumerate(base.expressions) if e.startswith("m_") and " " not in e]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = wls.beta[masses] / wls.std[masses]
        if masses and np.nanmin(z) < -NEGATIVE_MASS_STD:
            k = masses[int(np.nanargmin(z))]
            raise IdentificationError(
                f"{where}: WLS gives {base.expressions[k]} = {wls.beta[k]:.4g} kg, "
                f"{-wls.beta[k] / wls.std[k]:.3g} std below 0 (a mass must be >= 0; allowed: "
                f"at most {NEGATIVE_MASS_STD:g} std below): {causes}"
            )
        if ratio is not None and ratio > 0 and wls.relative_error <= max_residual:
            # a WLS that fits with a positive mass scaled away: the units, first (forces
            # 1e-4 x fit WLS as well as ever, and the physical fit, its masses >= 1 g, left
            # 70 %, "only negative masses ... fit the data": a code reader)
            check_mass_ratio()
        fit, which = (phys_fit, "the physically consistent fit") if phys_fit else (wls, "WLS")
        if not fit.relative_error <= max_residual:
            hint = (
                f" (WLS leaves {100 * wls.relative_error:.3g} %: only negative masses, "
                "inertias or friction fit the data)"
                if fit is not wls and wls.relative_error <= max_residual
                else ""
            )
            raise IdentificationError(
                f"{where}: {which} leaves {100 * fit.relative_error:.4g} % of J^T tau "
                f"unexplained (relative residual; allowed <= max_residual = "
                f"{100 * max_residual:g} %){hint}: {causes}; a real machine whose "
                "unmodelled effects leave more: raise max_residual"
            )
    check_mass_ratio()


def fk_limit(scenario: Scenario) -> float:
    """The largest forward-kinematics residual (m) a genuine log of ``scenario``'s machine
    shows: :data:`MAX_FK_RESIDUAL`, or more for a scenario declaring noisy encoders."""
    return max(MAX_FK_RESIDUAL, FK_NOISE_FACTOR * float(scenario.sensor.noise))


def _residual_rms(A, y, beta, n) -> np.ndarray:
    e = (y - A @ beta).reshape(n, 3)
    return np.sqrt(np.mean(e * e, axis=0))


def _rel(A, y, beta) -> float:
    return float(np.linalg.norm(y - A @ beta) / np.linalg.norm(y))


def predict(ident: Identification, log: Log, scenario: Scenario, *, beta=None) -> dict:
    """Predicted J^T tau on another log with the identified base parameters (WLS unless
    ``beta``): the observation, the prediction and the relative error per axis and overall."""
    obs = observe(
        log,
        scenario.plant(),
        friction_velocity=ident.friction_velocity,
        cutoff=ident.observation.cutoff,
        decimation=None,
        force_lead=ident.observation.force_lead,
        max_fk_residual=fk_limit(scenario),
        machine=ident.scenario or f"scenario {scenario.name!r}",
        check_lead=False,
    )
    b = ident.wls.beta if beta is None else beta
    yhat = ident.base.reduce(obs.W) @ b  # (n, 3)
    err = obs.y - yhat
    return {
        "observation": obs,
        "predicted": yhat,
        "relative_error": float(np.linalg.norm(err) / np.linalg.norm(obs.y)),
        "relative_error_axis": (np.linalg.norm(err, axis=0) / np.linalg.norm(obs.y, axis=0)),
    }


def standard_names() -> tuple[tuple[str, str], ...]:
    """(name, unit) of the 48 standard parameters."""
    return tuple(zip(PARAMETER_NAMES, PARAMETER_UNITS, strict=True))
