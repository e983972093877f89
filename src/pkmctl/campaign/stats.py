"""Statistics of a campaign's records (DESIGN.md §8): per cell and controller, paired.

Lower is better for every metric a campaign keeps (errors, chattering, peak forces).
Intervals are expanded percentile bootstrap 95 % intervals of the mean (Hesterberg 2015:
the percentile interval widened about the estimate by sqrt(n/(n-1)) t_{n-1}/z, see
:func:`expansion`), from a generator seeded by the cell and the metric, so a report is
the same every time it is made.
"""

from __future__ import annotations

import functools
import math
import zlib

import numpy as np
import pyarrow as pa

from pkmctl.campaign.spec import CampaignSpec
from pkmctl.campaign.store import factor_column, factor_value

__all__ = [
    "bootstrap_interval",
    "bootstrap_intervals",
    "bootstrap_ratio_interval",
    "by_factor",
    "cell_stats",
    "comparison",
    "expansion",
    "actuator_metrics",
    "headline_metrics",
    "paired_differences",
]

N_BOOT = 2000
LEVEL = 0.95
#: Fewer pairs than this never name a better controller: even widened, an interval of
#: 2-4 values rests on too little to name one.
MIN_PAIRS = 5
#: Bootstrap means computed at once (rows x resamples x values), to bound the memory.
_CHUNK = 4_000_000


def _resamples(rng: np.random.Generator, n: int, n_boot: int):
    """The bootstrap's resampling indices (n_boot, n) drawn from ``rng``, in blocks of
    rows (first row, block): the same numbers as one ``rng.integers(0, n, (n_boot, n))``
    (the generator's stream, drawn in order), without its n_boot x n array at once: that
    was 32 kB a pair, 3.3 GB for one interval over 100,000 pairs (a tester)."""
    rows = max(1, _CHUNK // max(n, 1))
    for r0 in range(0, n_boot, rows):
        yield r0, rng.integers(0, n, size=(min(rows, n_boot - r0), n))


@functools.cache
def expansion(n: int, level: float = LEVEL) -> float:
    """The factor that widens a percentile bootstrap interval of the mean of ``n`` values
    about the sample mean: ``sqrt(n / (n - 1)) * t_{n-1} / z`` at ``level`` (Hesterberg,
    "What teachers should know about the bootstrap", The American Statistician 69, 2015).

    The plain percentile interval is too narrow at small n: its spread is the plug-in
    variance's (divisor n, not n - 1) and its quantiles are normal ones where Student's t
    applies; with equal controllers it named a winner in 15 % of cells of 5 pairs, 11 % of
    8, 6-7 % of 20 (docs/campaigns.md). The factor is 1.58 at n = 5, 1.29 at 8, 1.10 at
    20 and tends to 1; the interval keeps the bootstrap's shape (a skewed sample gives
    an asymmetric interval). 1.0 for n < 2 (no interval)."""
    from scipy import stats

    if n < 2:
        return 1.0
    a = (1 + level) / 2
    return math.sqrt(n / (n - 1)) * float(stats.t.ppf(a, n - 1) / stats.norm.ppf(a))


@functools.cache
def _t_quantile(dof: int) -> float:
    """Student's t quantile at (1 + LEVEL) / 2 (cached: one per pair count, not per cell)."""
    from scipy import stats

    return float(stats.t.ppf((1 + LEVEL) / 2, dof))


def _expanded(centre, lo, hi, n: int, se):
    """The percentile interval ``lo``, ``hi`` widened about ``centre`` by
    :func:`expansion`, and further if need be to be no narrower than Student's t interval
    of standard error ``se`` (arrays or floats)."""
    t = _t_quantile(n - 1)
    width = np.asarray(hi - lo, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.fmax(expansion(n), np.where(width > 0, 2 * t * se / width, 0.0))
    return centre + k * (lo - centre), centre + k * (hi - centre)


def bootstrap_intervals(
    samples: np.ndarray, *, seed: int, n_boot: int = N_BOOT
) -> tuple[np.ndarray, np.ndarray]:
    """Expanded percentile bootstrap intervals (95 %) of the mean of each row of
    ``samples`` (m, n): (lo (m,), hi (m,)); NaN if n < 2. The rows are resampled with the
    same indices (drawn from ``seed``), so row i's interval is the one
    ``bootstrap_interval(samples[i], seed=seed)`` gives."""
    x = np.asarray(samples, dtype=float)
    if x.ndim != 2:
        raise ValueError(f"samples of shape {x.shape}: must be (rows, values)")
    m, n = x.shape
    if n < 2:
        return np.full(m, math.nan), np.full(m, math.nan)
    a = (1 - LEVEL) / 2
    lo, hi = np.empty(m), np.empty(m)
    step = max(1, _CHUNK // (n_boot * n))  # rows at once: their means (step, n_boot)
    # the draw, kept if it is small; else drawn again (the same numbers) for each row
    kept = list(_resamples(np.random.default_rng(seed), n, n_boot)) if step > 1 else None
    for i in range(0, m, step):
        rows = x[i : i + step]
        means = np.empty((rows.shape[0], n_boot))
        for r0, idx in kept or _resamples(np.random.default_rng(seed), n, n_boot):
            means[:, r0 : r0 + idx.shape[0]] = rows[:, idx].mean(axis=2)
        lo[i : i + step], hi[i : i + step] = np.quantile(means, [a, 1 - a], axis=1)
    se = x.std(axis=1, ddof=1) / math.sqrt(n)
    return _expanded(x.mean(axis=1), lo, hi, n, se)


def bootstrap_interval(x: np.ndarray, *, seed: int, n_boot: int = N_BOOT) -> tuple[float, float]:
    """Expanded percentile bootstrap interval (95 %) of the mean of ``x`` (n,); NaN if
    n < 2 (:func:`bootstrap_intervals`, :func:`expansion`)."""
    x = np.asarray(x, dtype=float)
    if x.size < 2:
        return math.nan, math.nan
    lo, hi = bootstrap_intervals(x[None, :], seed=seed, n_boot=n_boot)
    return float(lo[0]), float(hi[0])


def bootstrap_ratio_interval(
    num: np.ndarray, den: np.ndarray, *, seed: int, n_boot: int = N_BOOT
) -> tuple[float, float]:
    """Expanded percentile bootstrap interval (95 %) of mean(num) / mean(den) over pairs
    (n,), the pairs resampled together, widened about the ratio of the means as
    :func:`bootstrap_interval` (the ratio behaves as a mean of its linearisation); NaN if
    n < 2. When every resampled ratio is positive (errors: always) it is widened on the
    log scale, so it stays inside (0, inf): widened linearly, a skewed one reached below
    0 ("0.74x [-0.22, 0.83]" over six cells of very different scales)."""
    num, den = np.asarray(num, dtype=float), np.asarray(den, dtype=float)
    if num.size < 2:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    ratios = np.empty(n_boot)
    with np.errstate(divide="ignore", invalid="ignore"):
        for r0, idx in _resamples(rng, num.size, n_boot):
            ratios[r0 : r0 + idx.shape[0]] = num[idx].mean(axis=1) / den[idx].mean(axis=1)
        centre = num.mean() / den.mean()
        # the delta method's standard error of the ratio: that of the mean of its
        # linearisation (num - centre * den) / mean(den)
        se = np.std((num - centre * den) / den.mean(), ddof=1) / math.sqrt(num.size)
    a = (1 - LEVEL) / 2
    lo, hi = np.quantile(ratios, [a, 1 - a])
    if centre > 0 and lo > 0:  # every ratio positive: on the log scale (se: the delta method's)
        lo, hi = _expanded(math.log(centre), math.log(lo), math.log(hi), num.size, se / centre)
        return float(np.exp(lo)), float(np.exp(hi))
    lo, hi = _expanded(centre, lo, hi, num.size, se)
    return float(lo), float(hi)


def _seed(*parts) -> int:
    return zlib.crc32(repr(parts).encode())


def _difference_interval(d: np.ndarray, cell: int, a: str, b: str, m: str):
    """The 95 % interval of the mean paired difference ``d`` = a - b of controllers ``a``
    and ``b`` in the spec's order (a first), at ``cell`` on metric ``m``: the one
    computation, and seed, that paired.csv and comparison.csv both report (a comparison
    of b against a negates it): the same difference gets the same interval in both."""
    return bootstrap_interval(d, seed=_seed(cell, a, b, m))


def headline_metrics(spec: CampaignSpec, table: pa.Table) -> list[str]:
    """The task-space metrics a report leads with: RMSE of z, alpha, beta after the first
    second if the runs of every cell go past 1 s, else over the whole run (else the
    largest error, else the first kept group). One group for every cell: the cells of a
    ``timing.duration`` factor of 0.6 and 1.5 s are compared over the whole run, not
    some after 1 s and others (with no such metric) not at all."""
    names = set(table.column_names)
    groups = ("rmse_after_1s", "rmse", "max_error") if all(spec.past_1s()) else (
        "rmse", "max_error")  # fmt: skip
    for group in groups:
        cols = [f"{group}_{k}" for k in ("z_mm", "alpha_deg", "beta_deg")]
        if all(c in names for c in cols) and any(
            v is not None for v in table.column(cols[0]).to_pylist()
        ):
            return cols
    return [c for c in table.column_names if c.startswith(spec.metrics[0] + "_")]


def actuator_metrics(spec: CampaignSpec, table: pa.Table) -> list[str]:
    """The kept actuator metrics with values, limb by limb (chattering, then peak
    force), which a report compares beside the headline: a super-twisting controller
    was "better in 4 of 4 cells" on the RMSEs while its limb 2 chattered 186 times as
    much as AFSMC's, and the report did not say (a tester)."""
    names = set(table.column_names)
    out = []
    for group in ("chattering_N_per_s", "peak_force_N"):
        if group in spec.metrics:
            cols = [f"{group}_{k}" for k in range(1, 5)]
            out += [c for c in cols if c in names and table.column(c).null_count < len(table)]
    return out


def _columns(table: pa.Table, names) -> dict[str, np.ndarray]:
    out = {}
    for n in names:
        col = table.column(n)
        if pa.types.is_integer(col.type) and col.null_count == 0:
            # as integers: a seed above 2^53 is not a float (two seeds would be one)
            out[n] = np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.int64)
        elif pa.types.is_floating(col.type) or pa.types.is_integer(col.type):
            out[n] = np.array(col.to_numpy(zero_copy_only=False), dtype=float)
        else:
            out[n] = np.array(col.to_pylist(), dtype=object)
    return out


def _of_mean(x: np.ndarray, *, seed: int) -> tuple[float, float]:
    """The interval of a metric's mean (:func:`bootstrap_interval`) cut at 0: every metric
    a campaign keeps (spec.METRICS: RMSEs, largest |error|, chattering, peak force) is
    never negative, and the widening about the mean took an interval of 2 seeds to
    -0.004 mm, drawn as a bar off the bottom of a log axis (a tester). The cut interval
    holds every mean the uncut one held that the metric can have. Paired differences,
    which may be negative, keep theirs."""
    lo, hi = bootstrap_interval(x, seed=seed)
    return max(lo, 0.0) if math.isfinite(lo) else lo, hi


def cell_stats(spec: CampaignSpec, table: pa.Table, metrics: list[str]) -> list[dict]:
    """Per cell, controller and metric: runs, divergences, mean, median, 95 % interval.

    Returns rows ``{"cell", "controller", "metric", "n", "ok", "diverged", "missing",
    "mean", "median", "lo", "hi"}`` plus each factor's value (its column name), in the
    order of the cells and the spec's controllers; ``missing`` counts the runs that ended
    ok without a finite value of the metric, left out of the mean and the interval.
    """
    c = _columns(table, ["cell", "controller", "status", *metrics])
    rows = []
    for cell in range(len(spec.cells)):
        for ctrl in spec.controllers:
            sel = (c["cell"] == cell) & (c["controller"] == ctrl)
            ok = sel & (c["status"] == "ok")
            n, n_ok = int(sel.sum()), int(ok.sum())
            div = int((sel & (c["status"] == "diverged")).sum())
            for m in metrics:
                x = c[m][ok]
                missing = int((~np.isfinite(x)).sum())  # ok, but no value (NaN, or none)
                x = x[np.isfinite(x)]
                lo, hi = _of_mean(x, seed=_seed(cell, ctrl, m))
                rows.append(
                    {
                        "cell": cell,
                        **{factor_column(p): spec.cells[cell][p] for p in spec.factors},
                        "controller": ctrl,
                        "metric": m,
                        "n": n,
                        "ok": n_ok,
                        "diverged": div,
                        "missing": missing,
                        "mean": float(x.mean()) if x.size else math.nan,
                        "median": float(np.median(x)) if x.size else math.nan,
                        "lo": lo,
                        "hi": hi,
                    }
                )
    return rows


def _verdict(lo: float, hi: float, n: int) -> str:
    if n < MIN_PAIRS or not (math.isfinite(lo) and math.isfinite(hi)):
        return "unclear"
    return "a" if hi < 0 else "b" if lo > 0 else "unclear"


def paired_differences(spec: CampaignSpec, table: pa.Table, metrics: list[str]) -> list[dict]:
    """Paired differences a - b for each pair of controllers (a before b in the spec),
    per cell (``cell`` >= 0) and over all cells (``cell`` = -1): the runs with the same
    cell and seed where both ended ok.

    Returns rows ``{"cell", "a", "b", "metric", "pairs", "mean", "lo", "hi",
    "win_rate_a", "ties", "better", "a_failed", "b_failed", "undefined"}``:
    ``win_rate_a`` is the share of pairs where a is lower, ``ties`` the pairs where both
    are equal (neither wins), ``better`` is ``"a"`` or ``"b"`` when the 95 % interval of
    the mean difference excludes 0 over at least :data:`MIN_PAIRS` pairs, ``"unclear"``
    when the data cannot tell; what is not a pair: ``a_failed`` / ``b_failed`` the seeds
    whose run of a / b is recorded as not ended ok, ``undefined`` those where both ended
    ok but the metric is not finite in one of them, ``not_run`` those where a's or b's
    run has no record yet (an interrupted campaign).
    """
    c = _columns(table, ["cell", "controller", "seed", "status", *metrics])
    status = {
        (int(cell), ctrl, int(seed)): st
        for cell, ctrl, seed, st in zip(
            c["cell"], c["controller"], c["seed"], c["status"], strict=True
        )  # fmt: skip
    }
    index = {
        (int(cell), ctrl, int(seed)): i
        for i, (cell, ctrl, seed, st) in enumerate(
            zip(c["cell"], c["controller"], c["seed"], c["status"], strict=True)
        )
        if st == "ok"
    }
    rows = []
    ctrls = spec.controllers
    for ia, a in enumerate(ctrls):
        for b in ctrls[ia + 1 :]:
            for m in metrics:
                per_cell: dict[int, list[float]] = {}
                # a not ok, b not ok (recorded so), metric undefined, a or b not run yet
                lost: dict[int, list[int]] = {}
                for cell in range(len(spec.cells)):
                    d, why = [], [0, 0, 0, 0]
                    for s in spec.seeds:
                        i, j = index.get((cell, a, s)), index.get((cell, b, s))
                        sa, sb = status.get((cell, a, s)), status.get((cell, b, s))
                        why[0] += sa is not None and sa != "ok"
                        why[1] += sb is not None and sb != "ok"
                        why[3] += sa is None or sb is None
                        if i is not None and j is not None:
                            va, vb = c[m][i], c[m][j]
                            if math.isfinite(va) and math.isfinite(vb):
                                d.append(va - vb)
                            else:
                                why[2] += 1
                    per_cell[cell], lost[cell] = d, why
                per_cell[-1] = [x for cell in range(len(spec.cells)) for x in per_cell[cell]]
                lost[-1] = [sum(lost[k][i] for k in range(len(spec.cells))) for i in range(4)]
                for cell in [*range(len(spec.cells)), -1]:
                    d = np.asarray(per_cell[cell], dtype=float)
                    lo, hi = _difference_interval(d, cell, a, b, m)
                    rows.append(
                        {
                            "cell": cell,
                            "a": a,
                            "b": b,
                            "metric": m,
                            "pairs": int(d.size),
                            "mean": float(d.mean()) if d.size else math.nan,
                            "lo": lo,
                            "hi": hi,
                            "win_rate_a": float((d < 0).mean()) if d.size else math.nan,
                            "ties": int((d == 0).sum()),
                            "better": _verdict(lo, hi, d.size),
                            "a_failed": lost[cell][0],
                            "b_failed": lost[cell][1],
                            "undefined": lost[cell][2],
                            "not_run": lost[cell][3],
                        }
                    )
    return rows


def by_factor(spec: CampaignSpec, table: pa.Table, metric: str, factor: str) -> list[dict]:
    """Mean and 95 % interval of ``metric`` per value of ``factor`` and controller, over
    every other factor's cells (one-at-a-time: the cells of the factor's axis, the others
    at the centre) and every seed (the runs that ended ok).

    Returns rows ``{"controller", "value", "n", "failed", "mean", "lo", "hi"}``
    (``failed``: the runs at that value that did not end ok, left out of the mean), values
    in the order of first appearance in the cells.
    """
    col = factor_column(factor)
    c = _columns(table, ["cell", "controller", "status", metric, col])
    axis = spec.axis(factor)
    on_axis = np.isin(c["cell"], axis)
    values = []
    for cell in (spec.cells[i] for i in axis):
        if cell[factor] not in values:
            values.append(cell[factor])
    rows = []
    for ctrl in spec.controllers:
        for v in values:
            stored = c[col]
            if stored.dtype == object:
                match = stored == factor_value(spec, factor, v)
            elif v is None:
                match = np.isnan(stored)
            else:
                match = stored == float(v)
            mine = match & on_axis & (c["controller"] == ctrl)
            sel = mine & (c["status"] == "ok")
            x = c[metric][sel]
            x = x[np.isfinite(x)]
            lo, hi = _of_mean(x, seed=_seed(factor, repr(v), ctrl, metric))
            rows.append(
                {
                    "controller": ctrl,
                    "value": v,
                    "n": int(x.size),
                    "failed": int((mine & (c["status"] != "ok")).sum()),
                    "mean": float(x.mean()) if x.size else math.nan,
                    "lo": lo,
                    "hi": hi,
                }
            )
    return rows


def comparison(spec: CampaignSpec, table: pa.Table, controller: str, baseline: str,
               metrics: list[str]) -> list[dict]:  # fmt: skip
    """How much ``controller`` gains over ``baseline``, per cell (``cell`` >= 0) and over
    all cells (``cell`` = -1): the pairs (same cell, same seed) where both ended ok.

    Returns rows ``{"cell", "metric", "pairs", "baseline_mean", "controller_mean",
    "gain", "lo", "hi", "ratio", "ratio_lo", "ratio_hi", "win_rate", "ties", "better",
    "controller_failed", "baseline_failed", "controller_diverged", "baseline_diverged",
    "undefined", "not_run", "controller_mean_all",
    "controller_runs_all", "baseline_mean_all", "baseline_runs_all"}``:
    ``controller_mean`` and ``baseline_mean`` are the means over the pairs only (a
    cell where one of them has no run that ended ok adds nothing to either);
    ``gain`` is the mean of baseline - controller over the pairs (> 0: the controller's
    error is lower) with its 95 % interval, the interval of the same paired difference
    in :func:`paired_differences` (one computation, in the spec's order of the two,
    negated when the controller comes first); ``ratio`` the controller's mean error over
    the baseline's on the pairs (< 1: lower; its interval resamples the pairs),
    ``win_rate`` the share of pairs the controller wins, ``ties`` the pairs where both
    are equal, ``better`` one of ``"controller"``, ``"baseline"``, ``"unclear"`` (as
    :func:`paired_differences`), ``*_failed`` the runs of the cell(s) that did not end
    ok, ``*_diverged`` those of them that diverged (the rest failed with an error),
    ``undefined`` the seeds where both did but the metric is not finite, ``not_run``
    the seeds where either has no record yet (an interrupted campaign), and
    ``*_mean_all`` / ``*_runs_all`` each one's mean over all its runs of the cell(s)
    that ended ok with a finite value, paired or not, and how many those are (the mean
    ``summary.csv`` gives per cell).
    """
    c = _columns(table, ["cell", "controller", "seed", "status", *metrics])
    ok = {}
    failed: dict[tuple[int, str], int] = {}
    diverged: dict[tuple[int, str], int] = {}
    seen = set()  # (cell, controller, seed) of every record: the others are not run yet
    for i, (cell, ctrl, seed, st) in enumerate(
        zip(c["cell"], c["controller"], c["seed"], c["status"], strict=True)
    ):
        seen.add((int(cell), ctrl, int(seed)))
        if st == "ok":
            ok[(int(cell), ctrl, int(seed))] = i
        else:
            failed[(int(cell), ctrl)] = failed.get((int(cell), ctrl), 0) + 1
            if st == "diverged":
                diverged[(int(cell), ctrl)] = diverged.get((int(cell), ctrl), 0) + 1
    # the difference in the spec's order, as paired.csv has it: first - second
    order = {k: i for i, k in enumerate(spec.controllers)}
    first, second = sorted((controller, baseline), key=lambda k: order.get(k, len(order)))
    sign = -1.0 if first == controller else 1.0  # gain = baseline - controller
    rows = []
    for m in metrics:
        base_v: dict[int, list[float]] = {}
        ctrl_v: dict[int, list[float]] = {}
        own: dict[tuple[int, str], list[float]] = {}
        undefined: dict[int, int] = {}
        for cell in range(len(spec.cells)):
            bs, cs = [], []
            undefined[cell] = 0
            for s in spec.seeds:
                i, j = ok.get((cell, controller, s)), ok.get((cell, baseline, s))
                for who, k in ((controller, i), (baseline, j)):
                    if k is not None and math.isfinite(c[m][k]):
                        own.setdefault((cell, who), []).append(c[m][k])
                if i is not None and j is not None:
                    vc, vb = c[m][i], c[m][j]
                    if math.isfinite(vc) and math.isfinite(vb):
                        cs.append(vc)
                        bs.append(vb)
                    else:
                        undefined[cell] += 1
            base_v[cell], ctrl_v[cell] = bs, cs
        base_v[-1] = [x for cell in range(len(spec.cells)) for x in base_v[cell]]
        ctrl_v[-1] = [x for cell in range(len(spec.cells)) for x in ctrl_v[cell]]
        for cell in [*range(len(spec.cells)), -1]:
            b, x = np.asarray(base_v[cell], dtype=float), np.asarray(ctrl_v[cell], dtype=float)
            canonical = (x - b) if first == controller else (b - x)  # first - second
            lo_c, hi_c = _difference_interval(canonical, cell, first, second, m)
            d = sign * canonical  # baseline - controller
            lo, hi = (-hi_c, -lo_c) if sign < 0 else (lo_c, hi_c)
            rlo, rhi = bootstrap_ratio_interval(x, b, seed=_seed(cell, first, second, m))
            verdict = _verdict(-hi, -lo, d.size)  # "a" (the controller) if the gain > 0
            cells = range(len(spec.cells)) if cell < 0 else [cell]
            mine = [v for k in cells for v in own.get((k, controller), [])]
            theirs = [v for k in cells for v in own.get((k, baseline), [])]
            rows.append(
                {
                    "cell": cell,
                    "metric": m,
                    "pairs": int(d.size),
                    "baseline_mean": float(b.mean()) if d.size else math.nan,
                    "controller_mean": float(x.mean()) if d.size else math.nan,
                    "gain": float(sign * canonical.mean()) + 0.0 if d.size else math.nan,
                    "lo": lo,
                    "hi": hi,
                    "ratio": float(x.mean() / b.mean()) if d.size else math.nan,
                    "ratio_lo": rlo,
                    "ratio_hi": rhi,
                    "win_rate": float((d > 0).mean()) if d.size else math.nan,
                    "ties": int((d == 0).sum()),
                    "better": {"a": "controller", "b": "baseline"}.get(verdict, "unclear"),
                    "controller_failed": sum(failed.get((k, controller), 0) for k in cells),
                    "baseline_failed": sum(failed.get((k, baseline), 0) for k in cells),
                    "controller_diverged": sum(diverged.get((k, controller), 0) for k in cells),
                    "baseline_diverged": sum(diverged.get((k, baseline), 0) for k in cells),
                    "undefined": sum(undefined[k] for k in cells),
                    "not_run": sum(
                        (k, controller, q) not in seen or (k, baseline, q) not in seen
                        for k in cells
                        for q in spec.seeds
                    ),
                    "controller_mean_all": float(np.mean(mine)) if mine else math.nan,
                    "controller_runs_all": len(mine),
                    "baseline_mean_all": float(np.mean(theirs)) if theirs else math.nan,
                    "baseline_runs_all": len(theirs),
                }
            )
    return rows


def error_messages(table: pa.Table, cell: int | None = None, controller: str | None = None):
    """The distinct messages of the runs that failed with an error (status ``"error"``, not
    a divergence), most frequent first, as ``[(message, runs)]``; only those of ``cell`` and
    ``controller`` where given."""
    counts: dict[str, int] = {}
    cols = [table.column(k).to_pylist() for k in ("cell", "controller", "status", "message")]
    for c, ctrl, status, msg in zip(*cols, strict=True):
        if status == "error" and cell in (None, c) and controller in (None, ctrl):
            counts[msg] = counts.get(msg, 0) + 1
    return sorted(counts.items(), key=lambda kv: -kv[1])


def error_runs(
    table: pa.Table, message: str, cell: int | None = None, controller: str | None = None
) -> list[tuple[int, str, int]]:
    """The runs (cell, controller, seed) that failed with ``message`` (of ``cell`` and
    ``controller`` where given), in the table's order: which seeds to look at (a tester had
    to query the records to learn them)."""
    cols = [table.column(k).to_pylist() for k in ("cell", "controller", "seed", "status",
                                                  "message")]  # fmt: skip
    return [
        (c, ctrl, seed)
        for c, ctrl, seed, status, msg in zip(*cols, strict=True)
        if status == "error" and msg == message and cell in (None, c)
        and controller in (None, ctrl)
    ]  # fmt: skip


def seeds_named(runs: list[tuple[int, str, int]], most: int = 5, *, cells: bool = True) -> str:
    """``cell 1 seed 5, cell 2 seed 3 and 4 more`` (``seed 5, 7`` without ``cells``)."""
    if cells:
        named = [f"cell {c} {ctrl} seed {s}" for c, ctrl, s in runs[:most]]
    else:
        named = [str(s) for _, _, s in runs[:most]]
    more = f" and {len(runs) - most} more" if len(runs) > most else ""
    return ("" if cells else "seed" + "s" * (len(runs) > 1) + " ") + ", ".join(named) + more
