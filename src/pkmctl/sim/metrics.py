"""Metrics of a closed-loop :class:`~pkmctl.Result` (DESIGN.md §4, eq. 55-57).

Pure functions: a result in, numbers out. Errors are desired minus actual.

Where the numbers come from (``source``): the compiled loop accumulates every metric
here over every control period (:class:`LoopMetrics`, ``result.loop_metrics``), and the
log holds every period only when ``logging.every`` is 1. ``source="auto"`` (the default)
takes the accumulators whenever the run carries them and they cover the window asked
for, so that nothing is computed twice (a report asks for the same RMSE several times;
from a 200,000-row log each costs ~10 ms), and the log otherwise (a result read from an
older file, a window the loop did not accumulate on a full log); ``"log"`` and
``"loop"`` choose one. The two agree to the last bit (tests/test_logging.py): the loop
adds the same terms in the same order as NumPy's reductions along the time axis. The
true limb speeds are the exception (einsum against a compiled dot product, last bit):
with a full log, ``auto`` takes them and the time over the speed limit from the log.

The accumulators cover the windows of :data:`WINDOWS` (t_from = 0, 0.2 s and 1 s); on a
decimated log any other ``t_from`` raises ``ValueError``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "ERROR_SCALE",
    "LIMIT_MARGIN",
    "RMSE_KEYS",
    "SUMMARY_GROUPS",
    "WINDOWS",
    "LoopMetrics",
    "chattering_index",
    "first_period",
    "gravity_mismatch",
    "limb_speed",
    "max_error",
    "mean_error",
    "peak_forces",
    "rmse",
    "sample_count",
    "summary",
    "surface_gain",
    "time_at_force_limit",
    "time_over_speed_limit",
]

RMSE_KEYS = ("z_mm", "alpha_deg", "beta_deg", "q1_m", "q2_m", "q3_m", "q4_m")
#: Table 4's units of the errors [z, alpha, beta, q1..q4]: mm, deg, deg, m.
ERROR_SCALE = np.array([1e3, 180 / np.pi, 180 / np.pi, 1, 1, 1, 1])
#: The t_from of the windows the loop accumulates: the whole run, after the first
#: ~0.2 s that dominate every whole-run RMSE (DESIGN.md §4, the report's transient),
#: and after the first second (DESIGN.md §4's second RMSE).
WINDOWS = (0.0, 0.2, 1.0)
#: A limb counts as at its force limit when |tau_i| >= limit (1 - this).
LIMIT_MARGIN = 1e-9
_SAME_TIME = 1e-12  # s: t_k >= t_from - this is "from t_from on", as _errors selects


def first_period(t_from: float, period: float) -> int:
    """The first k with k T_c >= t_from - 1e-12 (the sample selection of every metric)."""
    k = max(0, int(np.ceil((t_from - _SAME_TIME) / period)) - 1)
    while float(k) * period < t_from - _SAME_TIME:
        k += 1
    return k


@dataclass(frozen=True, eq=False)
class LoopMetrics:
    """What the compiled loop accumulated over every control period of one run.

    Errors in Table 4's units (z mm, alpha and beta deg, q m), the columns of
    :data:`RMSE_KEYS`; one row per window of ``windows`` (t_from, s), whose first period
    is ``starts`` and which holds ``count`` periods. ``sum_error``, ``sum_squared_error``,
    ``max_abs_error`` (W, 7); ``chattering_sum`` (4,) = sum over k >= 1 of
    |tau(k) - tau(k-1)| (N); ``peak_force`` (4,) max |tau| (N); ``force_limit`` and
    ``speed_limit`` the actuator's (N, m/s; inf: none, :attr:`pkmctl.parts.Part.limits`);
    ``periods_at_force_limit`` periods with some |tau_i| at the limit;
    ``peak_limb_speed`` (4,) max |J(X) Xdot| of each limb (m/s, true, accumulated only
    with a speed limit, else NaN) and ``periods_over_speed_limit``. ``periods`` ran,
    ``period`` T_c (s).
    """

    periods: int
    period: float
    windows: tuple[float, ...]
    starts: tuple[int, ...]
    sum_error: np.ndarray
    sum_squared_error: np.ndarray
    max_abs_error: np.ndarray
    chattering_sum: np.ndarray
    peak_force: np.ndarray
    force_limit: float
    periods_at_force_limit: int
    speed_limit: float
    peak_limb_speed: np.ndarray
    periods_over_speed_limit: int

    @property
    def count(self) -> np.ndarray:
        """Periods in each window, (W,)."""
        return np.array([max(0, self.periods - s) for s in self.starts], dtype=np.int64)

    def window(self, t_from: float) -> int:
        """The row of the window that starts at ``t_from``; ValueError if none does."""
        for i, w in enumerate(self.windows):
            if abs(w - t_from) <= _SAME_TIME:
                return i
        raise ValueError(
            f"t_from = {t_from:g}: the loop accumulated the metrics "
            f"from t = {', '.join(f'{w:g}' for w in self.windows)} s only"
        )

    @property
    def duration(self) -> float:
        """t of the last period minus t of the first (s), as the log's t[-1] - t[0]."""
        return (self.periods - 1) * self.period if self.periods > 1 else np.nan

    def to_dict(self) -> dict:
        """JSON-ready (floats round-trip: json writes repr)."""
        out = {}
        for k, v in self.__dict__.items():
            out[k] = v.tolist() if isinstance(v, np.ndarray) else v
        return out

    @classmethod
    def from_dict(cls, d: dict) -> LoopMetrics:
        arrays = ("sum_error", "sum_squared_error", "max_abs_error", "chattering_sum",
                  "peak_force", "peak_limb_speed")  # fmt: skip
        kw = {k: (np.array(v, dtype=float) if k in arrays else v) for k, v in d.items()}
        for k in ("force_limit", "speed_limit"):  # null in the JSON: no limit
            if kw.get(k) is None:
                kw[k] = math.inf
        kw["windows"], kw["starts"] = tuple(kw["windows"]), tuple(kw["starts"])
        return cls(**kw)


def _use_loop(result, source: str, t_from: float | None = None, *, exact: bool = True) -> bool:
    """Whether to read the loop's accumulators (see the module's docstring): ``t_from``
    the window asked for (None: the whole run, or no window); ``exact`` False for the
    metrics whose two sources may differ in the last bit."""
    if source not in ("auto", "log", "loop"):
        raise ValueError(f"source = {source!r}: must be 'auto', 'log' or 'loop'")
    every = _every(result)
    if source == "log" and every > 1:
        raise ValueError(
            f"source = 'log': this run logged one row every {every} periods "
            "(logging.every); its metrics over every period are source='loop'"
        )
    lm = getattr(result, "loop_metrics", None)
    if source == "auto" and lm is not None and not _logged_by(result, lm, every):
        # the arrays are not the run's log (cut, say, with dataclasses.replace): the loop's
        # sums are of the whole run, and rmse() gave them for a window of it (a tester)
        if every > 1:
            raise ValueError(
                f"the result's {result.t.size} rows are not the {_rows(lm, every)} its loop "
                "logged (cut or replaced): its metrics over every period describe the whole "
                "run; use the whole result, or source='loop' for them"
            )
        return False
    if source == "loop" or (source == "auto" and every > 1):
        if lm is None:
            raise ValueError("this result carries no loop metrics (read from an older file?)")
        return True
    if source == "log" or lm is None or not exact:
        return False
    return t_from is None or any(abs(w - t_from) <= _SAME_TIME for w in lm.windows)


def _rows(lm: LoopMetrics, every: int) -> int:
    return -(-lm.periods // every)


def _logged_by(result, lm: LoopMetrics, every: int) -> bool:
    """Whether ``result``'s rows are those its loop logged: their count, and the times of
    the first and last (a run's log starts at t = 0, one row every ``every`` periods)."""
    t = result.t
    if t.size != _rows(lm, every):
        return False
    if t.size == 0:
        return True
    last = (t.size - 1) * every * lm.period
    return abs(t[0]) <= _SAME_TIME and abs(t[-1] - last) <= _SAME_TIME + 1e-9 * abs(last)


def _every(result) -> int:
    return int(getattr(result, "every", 1))


def _errors(result, t_from: float = 0.0, *, samples: bool = False) -> np.ndarray:
    """(N, 7) errors [z (mm), alpha (deg), beta (deg), q1..q4 (m)] from t_from on;
    ``samples``: refuse N = 0."""
    # into one array, not np.hstack: its row-by-row copy cost 5x the subtractions
    e = np.empty((result.t.size, 7))
    np.subtract(result.X_desired, result.X, out=e[:, :3])
    np.subtract(result.q_desired, result.q, out=e[:, 3:])
    if result.t.size and result.t[0] < t_from - _SAME_TIME:  # else every sample: no copy
        e = e[result.t >= t_from - _SAME_TIME]
    if samples and e.shape[0] == 0:
        raise _no_samples(t_from)
    e *= ERROR_SCALE
    return e


def _keyed(values: np.ndarray) -> dict[str, float]:
    return dict(zip(RMSE_KEYS, values.tolist(), strict=True))


def _no_samples(t_from: float) -> ValueError:
    # (max_error and mean_error had no check: numpy's "zero-size array to reduction
    # operation", or NaN with warnings; a tester)
    return ValueError(f"t_from = {t_from}: no samples after it")


def _loop_window(result, t_from: float, *, samples: bool = False) -> tuple[LoopMetrics, int, int]:
    """The loop's accumulators, the row of ``t_from``'s window and its periods;
    ``samples``: refuse a window with none."""
    lm = result.loop_metrics
    try:
        i = lm.window(t_from)
    except ValueError as exc:  # why the log cannot give it, or that it can
        every = _every(result)
        why = (f"the log keeps one period in {every} (logging.every)" if every > 1
               else "source='log' gives any t_from")  # fmt: skip
        raise ValueError(f"{exc}; {why}") from None
    n = int(lm.count[i])
    if samples and n == 0:
        raise _no_samples(t_from)
    return lm, i, n


def sample_count(result, *, t_from: float = 0.0, source: str = "auto") -> int:
    """How many control samples the metrics from ``t_from`` on average over (every
    period at t >= t_from, however many of them the log kept)."""
    if _use_loop(result, source, t_from):
        return _loop_window(result, t_from)[2]
    return int(np.sum(result.t >= t_from - _SAME_TIME))


def rmse(result, *, t_from: float = 0.0, source: str = "auto") -> dict[str, float]:
    """RMSE over the control samples at t >= t_from (eq. 55-57; Table 4's units)."""
    if _use_loop(result, source, t_from):
        lm, i, n = _loop_window(result, t_from, samples=True)
        return _keyed(np.sqrt(lm.sum_squared_error[i] / n))
    return _keyed(np.sqrt(np.mean(_errors(result, t_from, samples=True) ** 2, axis=0)))


def max_error(result, *, t_from: float = 0.0, source: str = "auto") -> dict[str, float]:
    """Largest |error| at t >= t_from, same keys and units as :func:`rmse`."""
    if _use_loop(result, source, t_from):
        lm, i, _ = _loop_window(result, t_from, samples=True)
        return _keyed(lm.max_abs_error[i])
    return _keyed(np.max(np.abs(_errors(result, t_from, samples=True)), axis=0))


def mean_error(result, *, t_from: float = 0.0, source: str = "auto") -> dict[str, float]:
    """Mean (signed) error at t >= t_from, same keys and units as :func:`rmse`."""
    if _use_loop(result, source, t_from):
        lm, i, n = _loop_window(result, t_from, samples=True)
        return _keyed(lm.sum_error[i] / n)
    return _keyed(np.mean(_errors(result, t_from, samples=True), axis=0))


def chattering_index(result, *, source: str = "auto") -> np.ndarray:
    """Mean |tau_a(k) - tau_a(k-1)| per second of each actuator (N/s), shape (4,)."""
    if _use_loop(result, source):
        lm = result.loop_metrics
        return lm.chattering_sum / lm.duration
    d = np.abs(np.diff(result.tau, axis=0))
    duration = result.t[-1] - result.t[0] if result.t.size > 1 else np.nan
    return d.sum(axis=0) / duration


def peak_forces(result, *, source: str = "auto") -> np.ndarray:
    """max |tau_a| of each actuator over the run (N), shape (4,)."""
    if _use_loop(result, source):
        return result.loop_metrics.peak_force.copy()
    return np.max(np.abs(result.tau), axis=0)


def _limits(result) -> tuple[float, float]:
    lm = getattr(result, "loop_metrics", None)
    return (np.inf, np.inf) if lm is None else (lm.force_limit, lm.speed_limit)


def time_at_force_limit(result, *, source: str = "auto") -> float | None:
    """Time (s) during which some limb's force is at the actuators' limit (|tau_i| >=
    limit (1 - 1e-9)), counted per control period; None if the actuators have no limit.

    The applied force, not the command: a drive with a torque ``lag`` reaches its limit
    up to ln(1e9) = 20.7 lags (4 ms at the prototype's 0.2 ms) after its command is
    clipped, so a clipping shorter than that may count nothing here."""
    limit = _limits(result)[0]
    if not np.isfinite(limit):
        return None
    Tc = result.scenario.timing.control_period
    if _use_loop(result, source):
        return result.loop_metrics.periods_at_force_limit * Tc
    at = np.any(np.abs(result.tau) >= limit * (1 - LIMIT_MARGIN), axis=1)
    return int(at.sum()) * Tc


def _true_limb_speeds(result) -> np.ndarray:
    """|J(X) Xdot| (N, 4) of the true machine at the logged samples (m/s)."""
    J = result.scenario.plant().jacobian(result.X)
    return np.abs(np.einsum("nij,nj->ni", J, result.Xdot))


def limb_speed(result, *, source: str = "auto") -> np.ndarray | None:
    """Peak true limb speed max |J(X) Xdot| of each limb (m/s), shape (4,); None if the
    actuators have no speed limit (the loop accumulates it only then)."""
    if not np.isfinite(_limits(result)[1]):
        return None
    if _use_loop(result, source, exact=False):
        return result.loop_metrics.peak_limb_speed.copy()
    return _true_limb_speeds(result).max(axis=0)


def time_over_speed_limit(result, *, source: str = "auto") -> float | None:
    """Time (s) during which some limb moves faster than the actuators' speed limit
    (true speeds, counted per control period); None if there is no limit."""
    limit = _limits(result)[1]
    if not np.isfinite(limit):
        return None
    Tc = result.scenario.timing.control_period
    if _use_loop(result, source, exact=False):
        return result.loop_metrics.periods_over_speed_limit * Tc
    return int(np.any(_true_limb_speeds(result) > limit, axis=1).sum()) * Tc


def last_time(result) -> float:
    """The time of the run's last control period, whatever rows its log kept."""
    return _last_time(result)


def _last_time(result) -> float:
    lm = getattr(result, "loop_metrics", None)
    if _every(result) > 1 and lm is not None:
        return (lm.periods - 1) * lm.period
    return float(result.t[-1])


#: The groups of :func:`summary`, in its order.
SUMMARY_GROUPS = (
    "rmse",
    "rmse_after_1s",
    "max_error",
    "chattering_N_per_s",
    "peak_force_N",
    "time_at_force_limit_s",
    "peak_limb_speed_m_per_s",
    "time_over_speed_limit_s",
)


def summary(result, groups=None, *, source: str = "auto") -> dict:
    """All metrics of one run, JSON-ready; only ``groups`` (of :data:`SUMMARY_GROUPS`)
    if given. From the log, the errors are computed once for all groups (a campaign's
    runs spend a measurable share of their time here); the numbers are those of
    :func:`rmse` and :func:`max_error`, bit for bit."""
    want = SUMMARY_GROUPS if groups is None else tuple(g for g in SUMMARY_GROUPS if g in groups)
    unknown = set(groups or ()) - set(SUMMARY_GROUPS)
    if unknown:
        raise ValueError(f"groups: {sorted(unknown)[0]!r} unknown (choose from {SUMMARY_GROUPS})")
    from_log = not _use_loop(result, source)
    errs = from_log and bool({"rmse", "rmse_after_1s", "max_error"} & set(want))
    e = _errors(result) if errs else None
    out: dict = {}
    for g in want:
        if g == "rmse":
            out[g] = (
                _keyed(np.sqrt(np.mean(e**2, axis=0))) if from_log else rmse(result, source=source)
            )
        elif g == "rmse_after_1s":
            if _last_time(result) < 1.0:
                out[g] = None
            elif from_log:
                late = e[result.t >= 1.0 - _SAME_TIME]
                out[g] = _keyed(np.sqrt(np.mean(late**2, axis=0)))
            else:
                out[g] = rmse(result, t_from=1.0, source=source)
        elif g == "max_error":
            out[g] = (
                _keyed(np.max(np.abs(e), axis=0)) if from_log else max_error(result, source=source)
            )
        elif g == "chattering_N_per_s":
            out[g] = chattering_index(result, source=source).tolist()
        elif g == "peak_force_N":
            out[g] = peak_forces(result, source=source).tolist()
        elif g == "time_at_force_limit_s":
            out[g] = time_at_force_limit(result, source=source)
        elif g == "peak_limb_speed_m_per_s":
            speed = limb_speed(result, source=source)
            out[g] = None if speed is None else speed.tolist()
        else:
            out[g] = time_over_speed_limit(result, source=source)
    return out


def surface_gain(scenario, controller: str) -> np.ndarray | None:
    """Gain from s to F near s = 0 (N s/m, N m s/rad), shape (3,), at sdot = 0, as the
    controller part states it (None if it states none); a constant force error dG then
    leaves a steady error of about dG / (gain lambda).

    SMC: K + Lambda / eps (inside the boundary layer); FSMC and AFSMC:
    K + K_u K_s |dFLC/ds*(0, 0)| (slope of the scenario's fuzzy surface); PD: K_p / lambda.
    """
    from pkmctl.parts import get_part

    part = get_part("controller", controller)
    if part.surface_gain is None:
        return None
    gain = part.surface_gain(scenario.controller_gains(), scenario.fuzzy_system())
    return np.asarray(gain, dtype=float)


def gravity_mismatch(scenario) -> np.ndarray:
    """G(X) - G^(X) at the trajectory's offset pose: what the controller model misses (3,),
    the payload's weight included (the controllers' model does not know it; it was left
    out, and a report said gravity "does not explain" errors it explained: a tester)."""
    X = np.asarray(scenario.trajectory.offset, dtype=float)
    G = scenario.plant().gravity(X) + scenario.payload_forces(X)[0]
    return G - scenario.controller_mechanism().gravity(X)
