"""A campaign's report: report.md, summary.csv, paired.csv and figures (DESIGN.md §8).

Renders only: the numbers come from :mod:`pkmctl.campaign.stats`. Every sentence of
report.md is generated from them: which controller is better where (the 95 % interval
of the paired mean difference excludes zero), and where the data cannot tell.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pkmctl.campaign import stats
from pkmctl.campaign.spec import CampaignSpec, SpecError
from pkmctl.campaign.store import factor_column, mixed_versions, read_records, read_spec
from pkmctl.io.atomic import atomic_write, staged_folder

__all__ = ["REPORT_FILES", "comparison_lines", "write_report"]

#: Every entry a report writes into ``DIR/report``; one it does not write this time (say
#: ``answer.md`` after the ``[[compare]]`` went) is removed, so nothing stale stays.
REPORT_FILES = (
    "report.md",
    "summary.csv",
    "paired.csv",
    "divergence.csv",
    "comparison.csv",
    "answer.md",
    "figures",
)


def _g(x) -> str:
    """A number to read (4 significant digits)."""
    if x is None:
        return "none"
    if isinstance(x, float):
        return "n/a" if not math.isfinite(x) else f"{x:.4g}"
    return str(x)


def _level(x) -> str:
    """A factor's value, in as few digits as tell it from any other: ``0.001``, ``10``,
    ``1.00001`` (never rounded: two cells must not read the same)."""
    if x is None:
        return "none"
    if isinstance(x, float):
        short = f"{x:g}"
        return short if math.isfinite(x) and float(short) == x else repr(x)
    if isinstance(x, list):
        return "[" + ", ".join(repr(v) if isinstance(v, float) else _level(v) for v in x) + "]"
    return str(x)


def _full(x) -> str:
    """A number for a CSV: every digit (the shortest text that reads back to it); an empty
    field where there is none, so that a reader types the column as numbers ("n/a" made
    DuckDB read it as text)."""
    if x is None:
        return ""
    if isinstance(x, float):
        return "" if not math.isfinite(x) else repr(x)
    return str(x)


_DIGITS: dict[tuple[str, str], int] = {}


def _digits(spec: CampaignSpec, factor: str) -> int:
    """The fewest significant digits (3 to 17) in which the factor's float values all read
    apart: a drawn value printed 16 (``theta_scale = 0.6582751372901796``)."""
    key = (spec.digest, factor)
    if key not in _DIGITS:
        floats = {c[factor] for c in spec.cells if isinstance(c[factor], float)}
        floats = {v for v in floats if math.isfinite(v)}
        _DIGITS[key] = next(
            (d for d in range(3, 18) if len({f"{v:.{d}g}" for v in floats}) == len(floats)), 17
        )
    return _DIGITS[key]


def _value_in(spec: CampaignSpec, factor: str, x) -> str:
    """:func:`_level`, a float that %g does not hold in the fewest digits that tell it
    from the factor's other values."""
    if isinstance(x, float) and math.isfinite(x) and float(f"{x:g}") != x:
        return f"{x:.{_digits(spec, factor)}g}"
    return _level(x)


def _cell_name(spec: CampaignSpec, cell: int) -> str:
    if cell < 0:
        return "all cells"
    if not spec.factors:
        return "the base scenario"
    varied = spec.factors
    if spec.center is not None:  # one at a time: name only what differs from the centre
        varied = [p for p in spec.factors if spec.cells[cell][p] != spec.center[p]]
        if not varied:
            return "the centre"
    return ", ".join(f"{p} = {_value_in(spec, p, spec.cells[cell][p])}" for p in varied)


def _ratio(r: dict) -> str:
    """The controller's error over the baseline's with the interval: ``0.31× [0.29, 0.33]``;
    near 1 with three decimals (1.003 is a 0.3 % difference, not "1")."""
    v = r["ratio"]
    if not math.isfinite(v):
        return "n/a"
    fmt = "{:.3f}" if 0.9 < v < 1.1 else "{:.2g}"
    if not math.isfinite(r["ratio_lo"]):
        return fmt.format(v) + "×"
    lo, hi = r["ratio_lo"], r["ratio_hi"]
    # An interval off 1 must not read [1.000, ...], nor [1, 1.4] (as one that holds 1 does,
    # outside (0.9, 1.1) too: a mutation tester): as many digits as show it.
    near = fmt == "{:.3f}"
    for d in range(3 if near else 2, 11):
        fmt = f"{{:.{d}f}}" if near else f"{{:.{d}g}}"
        a, b = fmt.format(lo), fmt.format(hi)
        if float(a) > 1 if lo > 1 else float(b) < 1 if hi < 1 else True:
            break
    return f"{fmt.format(v)}× [{a}, {b}]"


_MARK = {"controller": "better", "baseline": "worse", "unclear": "cannot tell"}


def comparison_lines(spec: CampaignSpec, rows: list[dict], q, metrics: list[str]) -> list[str]:
    """The answer to one ``[[compare]]`` question, in markdown: per cell a row of the
    ratio of ``q.controller``'s error to ``q.baseline``'s on each metric, with its
    interval and verdict, then the cells where it pays off, in words."""
    head = ["condition", *(m.removeprefix("rmse_after_1s_") for m in metrics)]
    out = [
        f"Per cell, {q.name}: {q.controller}'s mean error "
        f"over {q.baseline}'s on the same runs (below 1: {q.controller} is better), with "
        "its 95 % interval; better / worse when the interval of the paired mean difference "
        "excludes zero.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    cells = [*range(len(spec.cells)), -1]
    for cell in cells:
        mine = {r["metric"]: r for r in rows if r["cell"] == cell}
        entries = []
        for m in metrics:
            r = mine[m]
            fail = ""
            if r["controller_failed"] or r["baseline_failed"]:  # ("failed 16/16" read as
                # 16 of 16, and took divergences, a result, for failures)
                fail = (f"; runs not ok: {q.controller} {r['controller_failed']}, "
                        f"{q.baseline} {r['baseline_failed']}")  # fmt: skip
            mark = _MARK[r["better"]]
            if r["better"] == "unclear" and r["pairs"] < stats.MIN_PAIRS:
                # a tight interval beside "cannot tell" reads as a contradiction
                mark = f"no verdict ({_n(r['pairs'], 'pair')} < {stats.MIN_PAIRS})"
            entries.append(f"{_ratio(r)} {mark}{fail}")
        out.append(f"| {_cell_name(spec, cell)} | " + " | ".join(entries) + " |")
    return [*short_answer(spec, rows, q, metrics), "", *out]


#: A short answer names the cells of a verdict up to this many, else gives their range.
_LIST = 4


def _partial(r: dict) -> bool:
    """Whether a comparison row's pairs leave out runs that ended ok (the other side's
    run of the seed failed, or has no value)."""
    return r["controller_runs_all"] != r["pairs"] or r["baseline_runs_all"] != r["pairs"]


def _means(r: dict, q) -> str:
    """Both means of a comparison row: the pairs' (every run that ended ok, when no seed
    failed on one side only); else the pairs' means said to be so, then each one's mean
    over all its runs that ended ok (``summary.csv``'s), which the pairs do not show."""
    pairs = (f": {q.controller} {_g(r['controller_mean'])}, {q.baseline} "
             f"{_g(r['baseline_mean'])}")  # fmt: skip
    if not _partial(r):  # every run that ended ok is in a pair: the means say it all
        return pairs
    if not r["pairs"]:
        pairs = ": no pair"
    else:
        pairs = f", in the {r['pairs']} pairs where both ended ok" + pairs
    each = "; ".join(
        f"{who} {_g(r[f'{side}_mean_all'])} over {r[f'{side}_runs_all']} runs"
        if r[f"{side}_runs_all"]
        else f"{who} none"
        for who, side in ((q.controller, "controller"), (q.baseline, "baseline"))
    )
    return pairs + f" (over all their runs that ended ok: {each})"


def short_answer(spec: CampaignSpec, rows: list[dict], q, metrics: list[str]) -> list[str]:
    """One line per metric: in how many cells ``q.controller`` is better, worse, or the
    data cannot tell; for each verdict its cells (up to :data:`_LIST`) or the range of
    its ratios, from the lowest to the highest, with their cells."""
    out = [f"**{q.name}** ({q.controller} against {q.baseline}), error ratio "
           f"{q.controller} / {q.baseline} with its 95 % interval:"]  # fmt: skip
    ref = 0 if spec.center is not None else -1
    for m in metrics:
        mine = [r for r in rows if r["metric"] == m and r["cell"] >= 0]
        pays = sorted((r for r in mine if r["better"] == "controller"), key=lambda r: r["ratio"])
        hurts = [r for r in mine if r["better"] == "baseline"]
        unclear = [r for r in mine if r["better"] == "unclear"]
        c0 = next(r for r in rows if r["metric"] == m and r["cell"] == ref)
        pooled = next(r for r in rows if r["metric"] == m and r["cell"] == -1)
        line = (
            f"- {m}: better in {len(pays)} of {len(mine)} cells, worse in {len(hurts)}, "
            f"cannot tell in {len(unclear)}{_few(unclear)}"
        )
        for word, group in (("better", pays), ("worse", hurts)):
            group = sorted(group, key=lambda r: r["ratio"])
            if 0 < len(group) <= _LIST:
                line += f"; {word} at " + "; ".join(
                    f"{_cell_name(spec, r['cell'])} ({_ratio(r)})" for r in group
                )
            elif group:  # many cells: the range, from the best to the worst ratio
                lo, hi = group[0], group[-1]
                line += (
                    f"; {word} from {_ratio(lo)} ({_cell_name(spec, lo['cell'])}) to "
                    f"{_ratio(hi)} ({_cell_name(spec, hi['cell'])})"
                )
        if 0 < len(unclear) <= _LIST:
            line += "; cannot tell at " + "; ".join(_cell_name(spec, r["cell"]) for r in unclear)
        if ref < 0:  # a grid: its reference is the pooled row; one phrase, not two
            line += f". Over all cells{_means(pooled, q)}; ratio {_ratio(pooled)}."
        else:
            line += (
                f". At {_cell_name(spec, ref)}"
                + _means(c0, q)
                + f"; over all cells {_ratio(pooled)}"
                + (f" ({pooled['pairs']} pairs)." if _partial(pooled) else ".")
            )
        out.append(line)
    failed = [
        r for r in rows if r["metric"] == metrics[0] and r["cell"] >= 0
        and (r["controller_failed"] or r["baseline_failed"])
    ]  # fmt: skip
    for r in failed:
        out.append(
            f"- at {_cell_name(spec, r['cell'])}: "
            f"{_not_ok(r, 'controller', q.controller)}; {_not_ok(r, 'baseline', q.baseline)}"
            " (not in the pairs)."
        )
    return out


def _not_ok(r: dict, side: str, who: str) -> str:
    """How ``who``'s runs of a comparison row that did not end ok did not: diverged (a
    result: the controller's) or failed with an error (not a result)."""
    n, div = r[f"{side}_failed"], r.get(f"{side}_diverged", 0)
    if not n:
        return f"every {who} run ended ok"
    if div == n:
        return f"{_n(n, f'{who} run')} diverged"
    if not div:
        return f"{_n(n, f'{who} run')} failed with an error"
    return f"{_n(n, f'{who} run')} did not end ok ({div} diverged, {n - div} failed with an error)"


def _n(count: int, noun: str) -> str:
    """``1 seed``, ``2 seeds``."""
    return f"{count} {noun}{'s' * (count != 1)}"


def _write_csv(path: Path, rows: list[dict]) -> None:
    with atomic_write(path) as fh:
        if not rows:
            return
        w = csv.DictWriter(fh, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow(
                {k: _full(v) if isinstance(v, float) or v is None else v for k, v in r.items()}
            )


#: Units of the factors people vary most (a factor is a dotted scenario field).
_FACTOR_UNITS = {
    "payload.mass": "kg", "disturbance.amplitude": "N, N·m", "disturbance.hold": "s",
    "timing.control_period": "s", "timing.duration": "s", "sensor.noise": "m",
    "sensor.delay_periods": "periods", "actuators.lag": "s", "actuators.force_limit": "N",
    "actuators.delay_periods": "periods", "actuators.peak_torque": "N·m",
    "plant.friction_coulomb": "N", "plant.friction_viscous": "N·s/m",
    "plant.rotor_inertia": "kg·m²", "controller_model.theta_scale": "× Θ", "initial.X": "m, rad",
}  # fmt: skip
_METRIC_WORDS = (("rmse_after_1s_", "RMSE after 1 s"), ("rmse_", "RMSE"),
                 ("max_error_", "largest |error|"), ("chattering_N_per_s", "chattering index"),
                 ("peak_force_N", "peak force"))  # fmt: skip
_UNITS = {"mm": "mm", "deg": "°", "m": "m"}  # of the error keys' suffixes (metrics.RMSE_KEYS)


def _metric_label(metric: str) -> str:
    """'RMSE after 1 s, α (°)' for the record column 'rmse_after_1s_alpha_deg'."""
    for prefix, words in _METRIC_WORDS:
        if metric.startswith(prefix):
            rest = metric[len(prefix) :].lstrip("_")
            if prefix.startswith(("chattering", "peak")):
                unit = "N/s" if prefix.startswith("chattering") else "N"
                return f"{words}{', limb ' + rest if rest else ''} ({unit})"
            from pkmctl.report.document import _QUANTITY

            if rest in _QUANTITY:  # z_mm, alpha_deg, ..., q4_m
                return f"{words}, {_QUANTITY[rest]} ({_UNITS[rest.rsplit('_', 1)[1]]})"
            return f"{words}, {rest}"
    return metric


def _tick(x) -> str:
    """A factor's value under its point: :func:`_level`, a list's numbers as short
    (``[10, 10, 10]``, not ``[10.0, 10.0, 10.0]``: the ticks of ``disturbance.amplitude``
    ran into each other)."""
    if isinstance(x, list):
        return "[" + ", ".join(_tick(v) for v in x) + "]"
    return _level(x)


def _log_y(rows: list[dict]) -> bool:
    """Whether a figure's y axis is logarithmic: means 20 or more times apart, and every
    interval above 0 (an interval cut at 0, of 2 seeds, is a bar to the axis's bottom on
    a log scale, drawn as if it went on: the review of the cut)."""
    means = [r["mean"] for r in rows if math.isfinite(r["mean"])]
    low = [r["lo"] for r in rows if math.isfinite(r["lo"])]
    return (
        bool(means) and min(means) > 0 and max(means) >= 20 * min(means) and all(v > 0 for v in low)
    )


def _plot(spec, table, metric: str, factor: str, path: Path) -> int:
    """One figure: ``metric`` against ``factor``, per controller (each in its colour of
    ``reproduce``), with intervals; the points in the order of the factor's values
    (numbers: ascending, on a log axis when they are positive and span 10x or more). A
    point whose runs did not all end ok is marked with how many failed (left out of its
    mean); a value where every run failed is an x on the axis. Returns the runs left
    out."""
    from matplotlib.transforms import blended_transform_factory

    from pkmctl.report.figures import controller_colors
    from pkmctl.report.tables import controller_label

    rows = stats.by_factor(spec, table, metric, factor)
    fig = Figure(figsize=(7, 4.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    values = list(dict.fromkeys(repr(r["value"]) for r in rows))
    numeric = all(
        isinstance(r["value"], int | float) and not isinstance(r["value"], bool) for r in rows
    )
    xs_all = [float(r["value"]) for r in rows] if numeric else []
    if numeric and min(xs_all) > 0 and max(xs_all) >= 10 * min(xs_all):
        ax.set_xscale("log")  # control periods 80x apart: the smallest was at the left edge
    colors = controller_colors(spec.controllers)
    on_axis = blended_transform_factory(ax.transData, ax.transAxes)
    left_out, all_failed = 0, []
    for k, ctrl in enumerate(spec.controllers):
        mine = [r for r in rows if r["controller"] == ctrl]
        if numeric:  # a line in the order of x, not of the cells (one-at-a-time: the centre first)
            mine.sort(key=lambda r: float(r["value"]))
            xs = [float(r["value"]) for r in mine]
        else:
            xs = [values.index(repr(r["value"])) + 0.05 * k for r in mine]
        ys = [r["mean"] for r in mine]
        err = [
            [max(r["mean"] - r["lo"], 0) if math.isfinite(r["lo"]) else 0 for r in mine],
            [max(r["hi"] - r["mean"], 0) if math.isfinite(r["hi"]) else 0 for r in mine],
        ]
        color = colors[ctrl]
        ax.errorbar(xs, ys, yerr=err, marker="o", capsize=3, color=color,
                    label=controller_label(ctrl))  # fmt: skip
        for x, r in zip(xs, mine, strict=True):
            if not r["failed"]:
                continue
            left_out += r["failed"]
            if math.isfinite(r["mean"]):
                ax.annotate(f"{r['failed']} failed", (x, r["mean"]), xytext=(4, 4),
                            textcoords="offset points", fontsize=7, color=color)  # fmt: skip
            else:  # no run ended ok: no mean to draw, an x on the axis says so, one
                # controller above the other (at one x they would hide each other)
                y = 0.02 + 0.06 * k
                ax.plot([x], [y], marker="x", color=color, transform=on_axis,
                        clip_on=False, linestyle="none")  # fmt: skip
                all_failed.append((x, y, f"{controller_label(ctrl)}: all {r['failed']} failed",
                                   color))  # fmt: skip
    if not numeric:
        labels = [_tick(r["value"]) for r in rows[: len(values)]]
        long = sum(len(t) for t in labels) > 60 or max(len(t) for t in labels) > 14
        ax.set_xticks(range(len(values)), labels, rotation=20 if long else 0,
                      ha="right" if long else "center", fontsize=8)  # fmt: skip
    if _log_y(rows):
        ax.set_yscale("log")  # controllers 20x apart: on a linear axis the best are a line at 0
    ax.autoscale_view()
    for x, y, text, color in all_failed:  # inside the axes: at the right, written leftwards
        right = ax.transAxes.inverted().transform(ax.transData.transform((x, 1.0)))[0] > 0.5
        ax.annotate(text, (x, y), xycoords=on_axis, xytext=(-6 if right else 4, -3),
                    textcoords="offset points", fontsize=7, color=color,
                    ha="right" if right else "left")  # fmt: skip
    unit = _FACTOR_UNITS.get(factor)
    ax.set_xlabel(f"{factor} ({unit})" if unit else factor)
    ax.set_ylabel(f"{_metric_label(metric)}\nmean, 95 % interval")
    ax.set_title(f"{metric} against {factor}", fontsize=9)  # the record's column, for queries
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())
    return left_out


def _few(unclear: list[dict]) -> str:
    """Why the data cannot tell, where it is the number of pairs: '' if no cell is short;
    and what cost those cells their pairs: runs that did not end ok (listed under "Runs
    that did not end ok"), a metric not finite in runs that did (a PD diverging in every
    run of a cell read as if too few seeds had been asked for)."""
    short = [r for r in unclear if r["pairs"] < stats.MIN_PAIRS]
    if not short:
        return ""
    many = "all" if len(short) == len(unclear) else f"{len(short)} of them"
    why = []
    lost = [r for r in short if _failed(r) > 0]
    if lost:
        div = sum(r.get("controller_diverged", 0) + r.get("baseline_diverged", 0) for r in lost)
        how = (
            "that diverged" if div == sum(map(_failed, lost))
            else "that failed with an error" if "controller_diverged" in lost[0] and not div
            else "that did not end ok"
        )  # fmt: skip
        why.append(f"in {len(lost)} of them, runs {how} took pairs away, listed below")
    undefined = sum(r.get("undefined", 0) > 0 for r in short)
    if undefined:
        why.append(f"in {undefined} of them, the metric is not finite in runs that ended ok")
    not_run = sum(r.get("not_run", 0) > 0 for r in short)
    if not_run:
        why.append(f"in {not_run} of them, runs not run yet (the campaign is not complete)")
    because = f"; {'; '.join(why)}" if why else ""
    return f" ({many} with fewer than the {stats.MIN_PAIRS} pairs a verdict takes{because})"


def _failed(r: dict) -> int:
    """The runs of a row's pairs that did not end ok (either side)."""
    keys = ("a_failed", "b_failed", "controller_failed", "baseline_failed")
    return sum(int(r.get(k, 0)) for k in keys)


def _no_pair(a: str, b: str, r: dict) -> str:
    """Why a comparison over all cells has no pair: which side's runs did not end ok, or
    the metric not finite where both did."""
    parts = [f"{n} run{'s' * (n != 1)} of {who} did not end ok" for who, n in
             ((a, r.get("a_failed", 0)), (b, r.get("b_failed", 0))) if n]  # fmt: skip
    if r.get("not_run", 0):
        parts.append(f"{r['not_run']} pairs not run yet (the campaign is not complete)")
    if r.get("undefined", 0):
        parts.append(
            f"in {r['undefined']} pairs that ended ok the metric is not finite (e.g. a "
            "chattering index of a run too short for it)"
        )
    return f"- {a} vs {b}: no pair to compare: " + ("; ".join(parts) or "no runs") + "."


def _words(spec, paired: list[dict], metric: str) -> list[str]:
    out = []
    for r in (r for r in paired if r["metric"] == metric and r["cell"] == -1):
        a, b = r["a"], r["b"]
        if r["pairs"] == 0:
            out.append(_no_pair(a, b, r))
            continue
        ties = int(r.get("ties", 0))
        tied = f", equal in {100 * ties / r['pairs']:.0f} %" if ties else ""
        head = (
            f"- **{a} vs {b}** over all cells ({r['pairs']} pairs): mean difference "
            f"{_g(r['mean'])} [{_g(r['lo'])}, {_g(r['hi'])}], {a} lower in "
            f"{100 * r['win_rate_a']:.0f} % of pairs{tied}: "
        )
        if r["better"] == "a":
            head += f"{a} is better."
        elif r["better"] == "b":
            head += f"{b} is better."
        elif r["pairs"] < stats.MIN_PAIRS:
            head += f"too few pairs to tell (a verdict takes at least {stats.MIN_PAIRS})."
        else:
            head += "the data cannot tell them apart."
        out.append(head)
        cells = [x for x in paired if x["metric"] == metric and x["a"] == a and x["b"] == b]
        cells = [x for x in cells if x["cell"] >= 0]
        for who, label in (("a", a), ("b", b)):
            where = [x for x in cells if x["better"] == who]
            if where:
                out.append(
                    f"  - {label} better in {len(where)} of {len(cells)} cells: "
                    + "; ".join(
                        f"{_cell_name(spec, x['cell'])} (by {_g(abs(x['mean']))} "
                        f"[{_g(abs(x['hi']) if who == 'a' else x['lo'])}, "
                        f"{_g(abs(x['lo']) if who == 'a' else x['hi'])}])"
                        for x in where
                    )
                )
        unclear = [x for x in cells if x["better"] == "unclear"]
        if unclear:
            out.append(
                f"  - cannot tell in {len(unclear)} of {len(cells)} cells{_few(unclear)}: "
                + "; ".join(_cell_name(spec, x["cell"]) for x in unclear)
            )
    return out


def _each(spec: CampaignSpec) -> str:
    """How long each run is: ``4.2 s each``, or the range when cells differ
    (``timing.duration`` a factor)."""
    durations = spec.durations()
    lo, hi = min(durations), max(durations)
    if lo == hi:
        return f"{lo:g} s each"
    return f"{lo:g}-{hi:g} s each (by cell)"


def _answer_header(spec: CampaignSpec, table) -> str:
    ok = sum(s == "ok" for s in table.column("status").to_pylist())
    centre = (
        f" around the centre, the base scenario {spec.base.name!r}"
        if spec.center is not None
        else ""
    )
    return (
        f"Campaign {spec.name!r} ({spec.digest}): {table.num_rows} of {spec.n_runs} runs "
        f"recorded, {ok} ended ok; {len(spec.cells)} cells ({spec.design}{centre}), "
        f"{_n(len(spec.seeds), 'seed')}, {_each(spec)}.\n\n"
    )


def write_report(out: str | Path, cancel=None) -> list[Path]:
    """Write ``out/report/`` (report.md, summary.csv, paired.csv, divergence.csv,
    figures/METRIC_vs_FACTOR.png, and answer.md and comparison.csv if the spec asks
    questions with ``[[compare]]``) from the campaign in ``out``, all at once; the files
    of :data:`REPORT_FILES` it does not write this time are removed.

    ``cancel``: a :class:`threading.Event`; once set, the report stops at the next figure
    or file with :class:`KeyboardInterrupt` and its staging folder is removed (Ctrl-C of
    ``pkmctl campaign report``, which runs this in a thread)."""

    def check() -> None:
        if cancel is not None and cancel.is_set():
            raise KeyboardInterrupt

    out = Path(out)
    spec = read_spec(out)
    table = read_records(out)
    if table.num_rows == 0:  # nothing to say, and empty figures would say it badly
        raise SpecError(
            f"{str(out)!r}: no run recorded yet (0 of {spec.n_runs}); pkmctl campaign run "
            f"SPEC --out {out} --resume runs them; nothing written"
        )
    metrics = stats.headline_metrics(spec, table)
    # (not the headline's again: with only actuator metrics kept they are the headline;
    # every row and verdict came twice; a reviewer)
    actuators = [m for m in stats.actuator_metrics(spec, table) if m not in metrics]
    summary = stats.cell_stats(spec, table, metrics + actuators)
    paired = stats.paired_differences(spec, table, metrics + actuators)
    div = [r for r in summary if r["metric"] == metrics[0]]
    statuses = table.column("status").to_pylist()
    lines = [
        f"# Campaign {spec.name!r} ({spec.digest})",
        "",
        spec.description,
        "",
        f"{table.num_rows} of {spec.n_runs} runs recorded: {len(spec.cells)} cells x "
        f"{len(spec.controllers)} controllers ({', '.join(spec.controllers)}) x "
        f"{_n(len(spec.seeds), 'seed')}, {_each(spec)}, base scenario "
        f"{spec.base.name!r}. Factors: "
        + (", ".join(spec.factors) if spec.factors else "none")
        + ".",
        "",
        "Lower is better. Intervals are bootstrap 95 % intervals of the mean; a difference "
        f"counts only when its interval excludes zero, over at least {stats.MIN_PAIRS} pairs.",
        "",
        *(line for note in spec.fuzzy_offset_notes() for line in (f"**Warning**: {note}.", "")),
        *((f"**Note**: {mixed}.", "") if (mixed := mixed_versions(out)) else ()),
        "## Which controller is better where",
        "",
    ]
    if len(spec.controllers) < 2:
        lines += [f"One controller ({spec.controllers[0]}): no pair to compare; its numbers "
                  "per cell are below.", ""]  # fmt: skip
    else:
        for m in metrics:
            lines += [f"### {m}", "", *_words(spec, paired, m), ""]
        if actuators:  # what the tracking cost the drives, compared the same way
            kept = [w for g, w in (("chattering_N_per_s", "chattering index (N/s)"),
                                   ("peak_force_N", "peak force (N)"))
                    if any(m.startswith(g) for m in actuators)]  # fmt: skip
            lines += ["### The actuators", "",
                      f"Each limb's {' and '.join(kept)}, kept by the spec's metrics: lower "
                      "is smoother, gentler on the drives.", ""]  # fmt: skip
            for m in actuators:
                lines += [f"#### {m}", "", *_words(spec, paired, m), ""]
    answers = []
    for q in spec.compare:
        rows = stats.comparison(spec, table, q.controller, q.baseline, metrics)
        answers += [*comparison_lines(spec, rows, q, metrics), ""]
    if answers:
        at = lines.index("## Which controller is better where")
        lines[at:at] = ["## The questions of this campaign", "", *answers]
    lines += ["## Divergence", ""]
    n_bad = sum(s != "ok" for s in statuses)
    if n_bad == 0:
        lines.append("No run diverged or failed.")
    else:
        for r in div:
            if r["n"] > r["ok"]:
                cell, ctrl = r["cell"], r["controller"]
                why = stats.error_messages(table, cell, ctrl)
                lines.append(
                    f"- {ctrl}: {r['n'] - r['ok']} of {r['n']} runs did not end ok "
                    f"({r['diverged']} diverged) at {_cell_name(spec, cell)}"
                    + "".join(
                        f"; {n} error ("
                        + stats.seeds_named(stats.error_runs(table, m, cell, ctrl), cells=False)
                        + f"): {m}"
                        for m, n in why
                    )
                )
    missing = [r for r in summary if r.get("missing")]
    if missing:
        lines += ["", "Runs that ended ok without a finite value of a metric (left out of its "
                  "mean, interval and pairs):"]  # fmt: skip
        lines += [f"- {r['controller']}, {r['metric']}: {r['missing']} of {r['ok']} at "
                  f"{_cell_name(spec, r['cell'])}" for r in missing]  # fmt: skip
    lines += ["", "## Per cell and controller", ""]
    cols = ["controller", "n", "ok", "mean", "median", "95 % interval"]
    for m in metrics:
        lines += [f"### {m}", "", "| cell | " + " | ".join(cols) + " |"]
        lines.append("|" + "---|" * (len(cols) + 1))
        for r in (r for r in summary if r["metric"] == m):
            lines.append(
                f"| {_cell_name(spec, r['cell'])} | {r['controller']} | {r['n']} | {r['ok']} | "
                f"{_g(r['mean'])} | {_g(r['median'])} | [{_g(r['lo'])}, {_g(r['hi'])}] |"
            )
        lines.append("")
    figures = []
    check()
    with staged_folder(out / "report") as stage:
        (stage / "figures").mkdir()
        lines += ["## Each metric against each factor", ""]
        if spec.design == "grid" and len(spec.factors) > 1:
            lines += [
                "Each point pools the cells at that value of its factor over the other "
                "factors' values, so its interval holds their effect too (and an "
                "interaction between factors is averaged away); the table per cell below "
                "keeps them apart.",
                "",
            ]
        left_out = 0
        for m in metrics:
            for p in spec.factors:
                check()
                name = f"{m}_vs_{p}.png"
                left_out += _plot(spec, table, m, p, stage / "figures" / name)
                figures.append(name)
                lines.append(f"![{m} against {p}](figures/{name})")
        lines.append("")
        if left_out:
            lines += [
                'Points are means over the runs that ended ok: a point marked "k failed" '
                'leaves out k runs that diverged or failed, and an x on the axis with "all '
                'k failed" marks a value where no run ended ok (no mean to draw).',
                "",
            ]
        check()
        _write_csv(stage / "summary.csv", summary)
        _write_csv(stage / "paired.csv", [r | {"cell": r["cell"]} for r in paired])
        _write_csv(stage / "divergence.csv", [
            {k: r[k] for k in ("cell", *map(factor_column, spec.factors), "controller", "n",
                               "ok", "diverged")} for r in div
        ])  # fmt: skip
        if spec.compare:
            _write_csv(stage / "comparison.csv", [
                {"question": q.name, "controller": q.controller, "baseline": q.baseline, **r}
                for q in spec.compare
                for r in stats.comparison(spec, table, q.controller, q.baseline, metrics)
            ])  # fmt: skip
        if answers:  # the answer alone, to quote (README.md, docs/campaigns.md)
            with atomic_write(stage / "answer.md") as fh:
                fh.write(_answer_header(spec, table) + "\n".join(answers).rstrip() + "\n")
        with atomic_write(stage / "report.md") as fh:
            fh.write("\n".join(lines).replace("\n\n\n", "\n\n") + "\n")
        check()
        written = {e.name for e in stage.iterdir()}
    report = out / "report"
    for name in REPORT_FILES:  # those of an earlier report this one does not write
        if name not in written and (report / name).is_file():
            (report / name).unlink()
    return [report / "report.md", *(report / "figures" / f for f in figures)]
