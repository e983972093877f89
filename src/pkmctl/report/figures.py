"""Figures 10-26 of the paper, redrawn from our runs (DESIGN.md §4).

Renders only. Uses :class:`matplotlib.figure.Figure` with the Agg canvas directly,
never :mod:`matplotlib.pyplot`, so no global figure state is created or left behind.

Every figure has two panels, because one scale cannot show both the start and the
rest of the run: the initial 30° β error and the kilonewton forces of the first
milliseconds dwarf everything after them.

- 10-16 (tracking of z, α, β and limb lengths q1..q4): the whole run above, the
  first 0.3 s below (where the controllers differ visibly).
- 17-19 (tracking errors): the whole run above, t ≥ 1 s below.
- 20-22 (box plots of the errors): the whole run left, t ≥ 1 s right.
- 23-26 (actuator forces): the first 50 ms at full scale (the kilonewton peak),
  then t ≥ 50 ms with the y axis fitted to the steady part (t ≥ 0.5 s), then a
  50 ms window mid-run at the log's full resolution, where the controllers' ripple
  differs. A panel whose window holds fewer than two logged rows (``logging.every``)
  says so.

Long series are thinned for plotting to at most ``_MAX_POINTS`` points per line by
min/max decimation (each bucket keeps its smallest and largest value, so chattering
shows as a band rather than aliasing away), with the first 0.2 s given their own
budget so the transient stays resolved.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cbook import boxplot_stats
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, NullLocator

from pkmctl.io.atomic import atomic_write, make_folder

from .tables import CONTROLLER_ORDER, RMSE_AFTER_S, controller_label, ordered

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from pkmctl.sim.result import Result

__all__ = [
    "FIGURES",
    "FigureJob",
    "FigureSpec",
    "draw_figure",
    "figure_names",
    "figure_workers",
    "make_figures",
    "start_figures",
]

_MAX_POINTS = 5000  # per plotted line
_T_TRANSIENT = 0.2  # s: the part of the run that gets its own point budget
_T_ZOOM_START = 0.3  # s: length of the "first instants" panel of figures 10-16
_FORCE_SPLIT = 0.05  # s: figures 23-26 split here (the force peak is over within ~10 ms)
_FORCE_DETAIL = 0.05  # s: length of the full-resolution window of figures 23-26
_FORCE_STEADY_FROM = 0.5  # s: the steady y range of figures 23-26 is fitted from here
_MAX_FLIERS = 300  # per box
_FIGSIZE = {"force": (8.0, 8.0)}  # inches; the others are 8 x 6
# Fixed margins (fractions of the figure): a constrained layout would double the
# rendering time, and every figure here has the same simple grid.
_GRID_V = {"left": 0.1, "right": 0.98, "bottom": 0.08, "top": 0.9, "hspace": 0.5}
_GRID_H = {"left": 0.1, "right": 0.98, "bottom": 0.08, "top": 0.88, "wspace": 0.42}
# Panel titles at a fixed height (just above the axes, where matplotlib's automatic
# placement puts them when no tick labels are on top): the automatic placement measures
# every tick label of the axes again, about 15 % of a figure's drawing time.
_TITLE = {"fontsize": "small", "y": 1.0}


def _color(name: str) -> str:
    """A controller's colour: the same in every figure (tab10, in CONTROLLER_ORDER)."""
    i = CONTROLLER_ORDER.index(name) if name in CONTROLLER_ORDER else len(CONTROLLER_ORDER)
    return f"C{i % 10}"


def controller_colors(names: Sequence[str]) -> dict[str, str]:
    """Each of ``names``' colour: the paper's controllers their own (:func:`_color`, as in
    ``reproduce``), any other the next tab10 colour none of those has, in the order given
    (a campaign's figures took matplotlib's cycle in the spec's order, so AFSMC was
    orange, FSMC's colour, in one and blue in the next)."""
    free = [f"C{i}" for i in range(len(CONTROLLER_ORDER), 10)]
    others = [n for n in names if n not in CONTROLLER_ORDER]
    return {
        n: _color(n) if n in CONTROLLER_ORDER else free[others.index(n) % len(free)] for n in names
    }


_DESIRED_STYLE = {"color": "black", "linestyle": "--", "linewidth": 1.2, "label": "desired"}
_RAD2DEG = 180.0 / math.pi


@dataclass(frozen=True)
class FigureSpec:
    """One figure: number, kind, the series it shows, its title and caption.

    ``kind`` is ``"tracking"``, ``"error"``, ``"box"`` or ``"force"``. ``quantity``
    names the series (``"z"``, ``"alpha"``, ``"beta"``, ``"q1"``.., ``"tau1"``..).
    """

    number: int
    kind: str
    quantity: str
    title: str
    caption: str

    @property
    def filename(self) -> str:
        """``figNN.png``."""
        return f"fig{self.number}.png"


# quantity -> (accessor of actual, accessor of desired, scale to plot units, y label)
_Accessor = Callable[["Result"], np.ndarray]
_SERIES: dict[str, tuple[_Accessor, _Accessor, float, str]] = {
    "z": (lambda r: r.X[:, 0], lambda r: r.X_desired[:, 0], 1e3, "z (mm)"),
    "alpha": (lambda r: r.X[:, 1], lambda r: r.X_desired[:, 1], _RAD2DEG, "α (°)"),
    "beta": (lambda r: r.X[:, 2], lambda r: r.X_desired[:, 2], _RAD2DEG, "β (°)"),
}
for _i in range(4):
    _SERIES[f"q{_i + 1}"] = (
        lambda r, i=_i: r.q[:, i],
        lambda r, i=_i: r.q_desired[:, i],
        1.0,
        f"q{_i + 1} (m)",
    )
    _SERIES[f"tau{_i + 1}"] = (
        lambda r, i=_i: r.tau[:, i],
        lambda r, i=_i: r.tau_desired[:, i],
        1.0,
        f"τ{_i + 1} (N)",
    )
_ERROR_LABEL = {"z": "z error (mm)", "alpha": "α error (°)", "beta": "β error (°)"}
_NAME = {"z": "z", "alpha": "α", "beta": "β"}


def _specs() -> tuple[FigureSpec, ...]:
    specs = []
    for n, x in zip((10, 11, 12), ("z", "alpha", "beta"), strict=True):
        specs.append(
            FigureSpec(
                n,
                "tracking",
                x,
                f"Fig. {n} — {_NAME[x]} tracking",
                f"Tracking of {_NAME[x]}: desired and each controller that ran.",
            )
        )
    for i in range(1, 5):
        n = 12 + i
        specs.append(
            FigureSpec(
                n,
                "tracking",
                f"q{i}",
                f"Fig. {n} — limb length q{i}",
                f"Length of limb {i}: desired and each controller that ran.",
            )
        )
    for n, x in zip((17, 18, 19), ("z", "alpha", "beta"), strict=True):
        specs.append(
            FigureSpec(
                n,
                "error",
                x,
                f"Fig. {n} — {_NAME[x]} tracking error",
                f"Tracking error of {_NAME[x]} (desired − actual); lower panel from "
                f"t = {RMSE_AFTER_S:g} s.",
            )
        )
    for n, x in zip((20, 21, 22), ("z", "alpha", "beta"), strict=True):
        specs.append(
            FigureSpec(
                n,
                "box",
                x,
                f"Fig. {n} — {_NAME[x]} error box plot",
                f"Box plots of the {_NAME[x]} tracking error: whole run and "
                f"t ≥ {RMSE_AFTER_S:g} s.",
            )
        )
    for i in range(1, 5):
        n = 22 + i
        specs.append(
            FigureSpec(
                n,
                "force",
                f"tau{i}",
                f"Fig. {n} — actuator force τ{i}",
                f"Force of actuator {i} for each controller that ran, against the desired "
                f"driving force.",
            )
        )
    return tuple(specs)


#: Figures 10-26, in order.
FIGURES: tuple[FigureSpec, ...] = _specs()


# ---------------------------------------------------------------- decimation
def _minmax(t: np.ndarray, y: np.ndarray, budget: int) -> tuple[np.ndarray, np.ndarray]:
    """Thin (t, y) to about ``budget`` points, keeping each bucket's min and max in order."""
    n = t.size
    if n <= budget:
        return t, y
    nb = max(1, budget // 2)
    size = math.ceil(n / nb)
    nfull = n // size
    head = y[: nfull * size].reshape(nfull, size)
    base = np.arange(nfull) * size
    imin = base + np.argmin(head, axis=1)
    imax = base + np.argmax(head, axis=1)
    idx = np.concatenate([np.minimum(imin, imax), np.maximum(imin, imax)])
    if nfull * size < n:  # the ragged tail
        tail = np.arange(nfull * size, n)
        idx = np.concatenate([idx, tail[[np.argmin(y[tail]), np.argmax(y[tail])]]])
    idx = np.unique(idx)
    return t[idx], y[idx]


def _thin(t: np.ndarray, y: np.ndarray, budget: int = _MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Thin a series for plotting, giving t < 0.2 s its own share of the point budget."""
    if t.size <= budget:
        return t, y
    k = int(np.searchsorted(t, _T_TRANSIENT))
    t0, y0 = _minmax(t[:k], y[:k], (2 * budget) // 5)
    t1, y1 = _minmax(t[k:], y[k:], budget - t0.size)
    return np.concatenate([t0, t1]), np.concatenate([y0, y1])


def _window(
    t: np.ndarray, y: np.ndarray, lo: float, hi: float = math.inf
) -> tuple[np.ndarray, np.ndarray]:
    """The samples with lo <= t <= hi (t ascending, as every run's: views, not copies)."""
    i0 = int(np.searchsorted(t, lo - 1e-12, side="left"))
    i1 = int(np.searchsorted(t, hi + 1e-12, side="right"))
    return t[i0:i1], y[i0:i1]


# ---------------------------------------------------------------- drawing
def _plot_lines(
    ax: Axes,
    curves: list[tuple[str, np.ndarray, np.ndarray]],
    desired: tuple[np.ndarray, np.ndarray] | None,
    lo: float = 0.0,
    hi: float = math.inf,
    log: bool = False,
) -> bool:
    """The curves (and the desired one, dashed on top) between t = lo and hi; ``log``:
    the panel's y axis will be logarithmic (which curves lie on one another is judged
    there). False, and a note in the panel, where no curve has two logged samples in the
    window (a thinned log, ``logging.every``: the panels were blank axes with data-like
    ticks and no word: a code reader)."""
    if all(_window(t, y, lo, hi)[0].size < 2 for _, t, y in curves):
        t = curves[0][1]
        _empty(ax, f"the log keeps a row every {t[1] - t[0]:.3g} s:\nfewer than 2 in this window"
               if t.size > 1 else "the log has fewer than 2 rows")  # fmt: skip
        return False
    thinned = [(name, *_thin(*_window(t, y, lo, hi))) for name, t, y in curves]
    # the widest band underneath: a thinned curve alternates each bin's min and max, a band
    # as wide as its ripple; drawn in controller order, PD's band hid SMC's, FSMC's, AFSMC's
    width = [float(np.mean(np.abs(np.diff(yw)))) if yw.size > 1 else 0.0 for _, _, yw in thinned]
    rank = np.argsort(np.argsort(-np.nan_to_num(np.array(width), nan=np.inf)))
    styles = _shared_styles([thinned[i] for i in np.argsort(rank)], log=log)
    colors = controller_colors([name for name, _, _ in curves])
    for (name, tw, yw), z in zip(thinned, rank, strict=True):
        ax.plot(tw, yw, color=colors[name], linewidth=1.0, label=controller_label(name),
                zorder=2.0 + 0.01 * z, linestyle=styles[name])  # fmt: skip
    if desired is not None:
        tw, yw = _thin(*_window(*desired, lo, hi))
        # on top: dashed, it shows the curves under it (underneath, the force figures'
        # bands hid it all but a stub)
        ax.plot(tw, yw, **_DESIRED_STYLE, zorder=3.0)
    ax.grid(True, alpha=0.3)
    return True


#: Curves closer than this share of the panel's range (its samples' 0.1-99.9 %) over most
#: of their samples lie on one another: two pixels of a panel 200 px high.
_COINCIDE = 0.01
#: Dash length (points) of curves that share a line.
_DASH = 4.0


def _shared_styles(
    drawn: list[tuple[str, np.ndarray, np.ndarray]], log: bool = False
) -> dict[str, object]:
    """The line style of each curve, given in drawing order: solid, but curves that lie
    on one another (half their samples or more within :data:`_COINCIDE` of the panel's
    range) share their line in turns, each dashed in its own slot over the first, solid
    one. In Fig. 24 AFSMC's force lies within 0.3 N of FSMC's (99 % of the samples after
    50 ms), against a range of 61 N: drawn over it, FSMC's hid it (0 green pixels in the
    middle panel), and the paper's comparison of the two could not be seen."""
    styles: dict[str, object] = {name: "-" for name, _, _ in drawn}
    if log:  # on a log axis, a decade apart is apart however small both are (a review:
        # SMC's 5e-5 deg beta error was dashed as on FSMC's 6e-4)
        with np.errstate(divide="ignore", invalid="ignore"):
            drawn = [(n, t, np.log10(np.where(y > 0, y, np.nan))) for n, t, y in drawn]
    finite = [yw[np.isfinite(yw)] for _, _, yw in drawn]
    data = np.concatenate(finite) if finite else np.empty(0)
    if data.size == 0:
        return styles
    lo, hi = np.percentile(data, [0.1, 99.9])
    tol = _COINCIDE * float(hi - lo)
    groups: list[list[int]] = []
    for i, (_, tw, yw) in enumerate(drawn):
        for g in groups:
            _, t0, y0 = drawn[g[0]]
            # thinned, a curve keeps each bin's min and max where they fall: the times
            # of two curves differ by up to a bin (2 samples) or two
            same = t0.shape == tw.shape and (
                tw.size < 2 or np.max(np.abs(t0 - tw)) <= 4 * (tw[-1] - tw[0]) / tw.size
            )
            if same and np.mean(np.abs(y0 - yw) <= tol) >= 0.5:
                g.append(i)
                break
        else:
            groups.append([i])
    for g in groups:
        m = len(g)
        for k, i in enumerate(g[1:]):  # the first solid underneath; each other in its slot
            styles[drawn[i][0]] = (k * _DASH, (_DASH, (m - 1) * _DASH))
    return styles


def _empty(ax: Axes, text: str) -> None:
    """A panel with nothing to show in this run: ``text`` in a frame, without the axes'
    0-1 ticks and labels (they read as data)."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlabel("")
    ax.set_ylabel("")


def _legend_above(ax: Axes) -> None:
    """The legend in one row over a band of headroom added above the curves: placed
    "best" inside, it covered the last second of every curve (Figs. 10, 11, 17)."""
    from matplotlib.lines import Line2D

    handles, labels = ax.get_legend_handles_labels()
    if not handles:  # a panel with a note instead of curves
        return
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo, hi + _LEGEND_ROOM * (hi - lo))
    # a controller's line solid: where it shares a line with another (_shared_styles) it is
    # dashed in this panel only, and a dashed entry read as the desired one's style
    solid = [
        h if lab == _DESIRED_STYLE["label"] else Line2D([], [], color=h.get_color(), linewidth=1.0)
        for h, lab in zip(handles, labels, strict=True)
    ]
    ax.legend(solid, labels, loc="upper center", fontsize="small", ncols=len(labels))


#: Headroom for the legend, a fraction of the curves' y range.
_LEGEND_ROOM = 0.3


def _steady_limits(arrays: list[np.ndarray]) -> tuple[float, float] | None:
    """A y range holding the 0.1-99.9 % of the steady-part samples, with a margin."""
    data = np.concatenate([a for a in arrays if a.size]) if arrays else np.empty(0)
    data = data[np.isfinite(data)]
    if data.size == 0:
        return None
    lo, hi = np.percentile(data, [0.1, 99.9])
    pad = 0.15 * (hi - lo) if hi > lo else max(1.0, abs(hi) * 0.1)
    return float(lo - pad), float(hi + pad)


def _draw_tracking(fig: Figure, spec: FigureSpec, pairs: list[tuple[str, Result]]) -> None:
    actual, desired, scale, ylabel = _SERIES[spec.quantity]
    curves = [(n, r.t, scale * actual(r)) for n, r in pairs]
    ref = pairs[0][1]
    des = (ref.t, scale * desired(ref))
    top, bottom = fig.subplots(2, 1, height_ratios=[3, 2], gridspec_kw=_GRID_V)
    if _plot_lines(top, curves, des):
        top.set_ylabel(ylabel)
        top.set_xlabel("t (s)")
    top.set_title("whole run", **_TITLE)
    _legend_above(top)
    hi = min(_T_ZOOM_START, float(ref.t[-1]))
    if _plot_lines(bottom, curves, des, 0.0, hi):
        bottom.set_xlim(0.0, hi)
        bottom.set_ylabel(ylabel)
        bottom.set_xlabel("t (s)")
    bottom.set_title(f"first {hi:g} s", **_TITLE)


def _errors(spec: FigureSpec, pairs: list[tuple[str, Result]]):
    actual, desired, scale, _ = _SERIES[spec.quantity]
    return [(n, r.t, scale * (desired(r) - actual(r))) for n, r in pairs]


def _draw_error(fig: Figure, spec: FigureSpec, pairs: list[tuple[str, Result]]) -> None:
    curves = _errors(spec, pairs)
    ylabel = _ERROR_LABEL[spec.quantity]
    top, bottom = fig.subplots(2, 1, gridspec_kw=_GRID_V)
    if _plot_lines(top, curves, None):
        top.axhline(0.0, color="black", linewidth=0.6)
        top.set_ylabel(ylabel)
        top.set_xlabel("t (s)")
    top.set_title("whole run", **_TITLE)
    _legend_above(top)
    t_end = max(float(t[-1]) for _, t, _ in curves)
    if t_end > RMSE_AFTER_S:
        # |error| on a log axis: errors 1,000 times apart (SMC's and CTC's β) are all seen,
        # where a linear zoom fitted to the largest showed the others as a line at 0
        mags = [(n, t, np.abs(e)) for n, t, e in curves]
        tops = [float(np.max(_window(t, e, RMSE_AFTER_S)[1], initial=0.0)) for _, t, e in mags]
        if _plot_lines(bottom, mags, None, RMSE_AFTER_S, log=max(tops) > 0):
            if max(tops) > 0:
                bottom.set_yscale("log")
                floor = min(v for v in tops if v > 0) * 1e-2  # zero crossings: spikes below
                bottom.set_ylim(bottom=floor)
            bottom.set_xlim(RMSE_AFTER_S, t_end)
            bottom.set_ylabel(ylabel)
            bottom.set_xlabel("t (s)")
        bottom.set_title(f"t ≥ {RMSE_AFTER_S:g} s: |error| (log scale)", **_TITLE)
    else:
        _empty(bottom, f"run shorter than {RMSE_AFTER_S:g} s")
        bottom.set_title(f"t ≥ {RMSE_AFTER_S:g} s", **_TITLE)


def _box_stats(name: str, data: np.ndarray) -> dict:
    stats = boxplot_stats(data, whis=1.5)[0]
    fliers = np.sort(stats["fliers"])
    if fliers.size > _MAX_FLIERS:  # evenly spaced in rank, extremes kept
        fliers = fliers[np.linspace(0, fliers.size - 1, _MAX_FLIERS).round().astype(int)]
    stats["fliers"] = fliers
    stats["label"] = controller_label(name)
    return stats


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def _symlog(ax, reach: float, linscale: float) -> float:
    """A symlog y axis linear within ±lin, the smallest 1, 2 or 5 × 10^k >= ``reach``;
    returns lin. Its ticks: 0 and ±lin, then the decades from 3 lin up, so no decade tick
    falls inside the linear part (matplotlib's own put 10^-1 a third of the way up a
    linear part of ±0.5, at a tenth of a decade's height below 10^0)."""
    k = math.floor(math.log10(reach))
    lin = next(m * 10.0**k for m in (1, 2, 5, 10) if m * 10.0**k >= reach * (1 - 1e-12))
    ax.set_yscale("symlog", linthresh=lin, linscale=linscale)
    lo, hi = ax.get_ylim()  # the autoscaled limits, margins on the symlog scale
    top = max(abs(lo), abs(hi))
    ticks = [0.0, lin]
    d = 10.0 ** math.ceil(math.log10(3 * lin) - 1e-12)
    while d <= top * (1 + 1e-12):
        ticks.append(d)
        d *= 10.0
    ticks = sorted({s * t for t in ticks for s in (1.0, -1.0) if lo <= s * t <= hi})

    def label(v: float, _pos=None) -> str:  # 10¹, 0.5, 5×10⁻⁴; a minus sign, not a hyphen
        sign = "−" if v < 0 else ""
        if v == 0.0:
            return "0"
        e = math.log10(abs(v))
        if abs(v) > lin and abs(e - round(e)) < 1e-9:
            return f"{sign}10{str(round(e)).translate(_SUPERSCRIPT)}"
        if abs(v) >= 0.01:
            return f"{sign}{abs(v):g}"
        m, x = f"{abs(v):.0e}".split("e")
        return f"{sign}{m}×10{str(int(x)).translate(_SUPERSCRIPT)}"

    ax.set_yticks(ticks)
    ax.yaxis.set_major_formatter(FuncFormatter(label))
    ax.yaxis.set_minor_locator(NullLocator())
    ax.set_ylim(lo, hi)
    return lin


def _draw_box(fig: Figure, spec: FigureSpec, pairs: list[tuple[str, Result]]) -> None:
    curves = _errors(spec, pairs)
    ylabel = _ERROR_LABEL[spec.quantity]
    left, right = fig.subplots(1, 2, gridspec_kw=_GRID_H)
    for ax, lo, title in (
        (left, 0.0, "whole run"),
        (right, RMSE_AFTER_S, f"t ≥ {RMSE_AFTER_S:g} s"),
    ):
        stats, colors = [], []
        each = controller_colors([name for name, _, _ in curves])
        for name, t, e in curves:
            _, ew = _window(t, e, lo)
            if ew.size:
                stats.append(_box_stats(name, ew))
                colors.append(each[name])
        if stats:
            art = ax.bxp(
                stats,
                patch_artist=True,
                flierprops={"marker": ".", "markersize": 2, "alpha": 0.5},
                medianprops={"color": "black"},
            )
            for patch, c in zip(art["boxes"], colors, strict=True):
                patch.set_facecolor(c)
                patch.set_alpha(0.6)
            if lo == 0.0:  # the transient's fliers span orders of magnitude beyond the boxes
                reach = max(max(abs(st["whislo"]), abs(st["whishi"])) for st in stats)
                far = max(
                    (np.max(np.abs(st["fliers"])) for st in stats if st["fliers"].size), default=0.0
                )
                if reach > 0 and far > 10 * reach:
                    lin = _symlog(ax, reach, 2.0)
                    title += f" (symlog: linear within ±{lin:g}, the whiskers)"
            else:  # controllers 20x apart (SMC's and CTC's beta): the smallest box linear
                reaches = [max(abs(st["whislo"]), abs(st["whishi"])) for st in stats]
                small = min((r for r in reaches if r > 0), default=0.0)
                if small > 0 and max(reaches) > 20 * small:
                    lin = _symlog(ax, small, 1.0)
                    title += f" (symlog: linear within ±{lin:g})"
        else:
            _empty(ax, "no samples")
            ax.set_title(title, **_TITLE)
            continue
        ax.axhline(0.0, color="black", linewidth=0.6)
        ax.grid(True, axis="y", alpha=0.3)
        ax.set_ylabel(ylabel)
        ax.set_title(title, **_TITLE)


def _draw_force(fig: Figure, spec: FigureSpec, pairs: list[tuple[str, Result]]) -> None:
    actual, desired, _, ylabel = _SERIES[spec.quantity]
    curves = [(n, r.t, actual(r)) for n, r in pairs]
    ref = pairs[0][1]
    des = (ref.t, desired(ref))
    t_end = float(ref.t[-1])
    top, middle, bottom = fig.subplots(3, 1, gridspec_kw=_GRID_V)
    split = min(_FORCE_SPLIT, t_end)
    drawn = [top] if _plot_lines(top, curves, des, 0.0, split) else []
    top.set_xlim(0.0, split)
    top.set_title(f"first {split * 1e3:g} ms (full scale)", **_TITLE)
    if t_end > _FORCE_SPLIT:
        steady_from = _FORCE_STEADY_FROM if t_end > _FORCE_STEADY_FROM else _FORCE_SPLIT
        if _plot_lines(middle, curves, des, _FORCE_SPLIT):
            drawn.append(middle)
            middle.set_xlim(_FORCE_SPLIT, t_end)
            limits = _steady_limits(
                [_window(t, y, steady_from)[1] for _, t, y in curves]
                + [_window(*des, steady_from)[1]]
            )
            if limits is not None:
                middle.set_ylim(*limits)
        middle.set_title(
            f"t ≥ {split * 1e3:g} ms, y axis fitted to t ≥ {steady_from:g} s "
            "(bands: min/max envelope of the samples)",
            **_TITLE,
        )
        # a short window at full resolution, in the middle of the steady part
        lo = max(steady_from, 0.5 * t_end - 0.5 * _FORCE_DETAIL)
        hi = min(t_end, lo + _FORCE_DETAIL)
        if _plot_lines(bottom, curves, des, lo, hi):
            drawn.append(bottom)
            bottom.set_xlim(lo, hi)
        bottom.set_title(f"detail: {lo:.4g}-{hi:.4g} s", **_TITLE)
    else:
        for ax in (middle, bottom):
            _empty(ax, "run too short")
    if drawn:  # (on the first panel with curves: a thinned log's may have none)
        _legend_above(drawn[0])
    for ax in drawn:
        ax.set_ylabel(ylabel)
        ax.set_xlabel("t (s)")  # three time ranges: each axis says it is time


_DRAW = {"tracking": _draw_tracking, "error": _draw_error, "box": _draw_box, "force": _draw_force}


def _save_atomic(fig: Figure, path: Path, dpi: float) -> None:
    """Write ``fig`` as PNG through the one atomic writer."""
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=dpi)


def _check(results: Mapping[str, Result]) -> list[tuple[str, Result]]:
    pairs = ordered(results)
    if not pairs:
        raise ValueError(
            f"results: no known controller among {sorted(results)} "
            f"(expected some of {list(CONTROLLER_ORDER)})"
        )
    for name, r in pairs:
        if r.t.size < 2:
            raise ValueError(f"results[{name!r}]: needs at least 2 samples, has {r.t.size}")
    return pairs


def _check_dpi(dpi: float) -> None:
    if not (dpi > 0):
        raise ValueError(f"dpi = {dpi}: must be > 0")


def _render(spec: FigureSpec, pairs: list[tuple[str, Result]], dpi: float = 100.0) -> Figure:
    fig = Figure(figsize=_FIGSIZE.get(spec.kind, (8.0, 6.0)), dpi=dpi)
    FigureCanvasAgg(fig)
    _DRAW[spec.kind](fig, spec, pairs)
    fig.suptitle(spec.title)
    return fig


def _draw_one(spec: FigureSpec, pairs: list[tuple[str, Result]], outdir: Path, dpi: float) -> Path:
    fig = _render(spec, pairs)
    path = outdir / spec.filename
    _save_atomic(fig, path, dpi)  # a Figure without pyplot is freed with its last reference
    return path


_SUFFIX = {"tracking": "", "force": "", "error": " error", "box": " box"}


def figure_names() -> dict[str, int]:
    """The names :func:`draw_figure` takes, with their figure's number: "z", "alpha",
    "beta", "q1"-"q4" (tracking, 10-16), "z error"... (17-19), "z box"... (20-22),
    "tau1"-"tau4" (actuator forces, 23-26)."""
    return {spec.quantity + _SUFFIX[spec.kind]: spec.number for spec in FIGURES}


def draw_figure(
    results: Mapping[str, Result] | Result, figure: int | str, *, dpi: float = 110
) -> Figure:
    """One of figures 10-26 (DESIGN.md §4) drawn as :func:`make_figures` (``pkmctl
    reproduce``) draws its file, as a matplotlib Figure: no pyplot, so no global state.
    ``fig.savefig(path)`` writes the same PNG as ``make_figures(..., dpi=dpi)``.

    Parameters
    ----------
    results : Result, or a mapping of str to Result
        One run, or several to compare, keyed by the name each is shown under (as in
        :func:`make_figures`; the paper's controllers first, in their order and colours,
        then the others as given, each its own colour; the desired curve is the first's).
    figure : int or str
        The figure's number (10-26) or its name (:func:`figure_names`: "z", "alpha
        error", "beta box", "tau1", ...).
    dpi : float, keyword-only
        The figure's resolution (``reproduce``'s, 110, by default).

    Raises
    ------
    ValueError
        An unknown figure number or name, no results, a run of fewer than 2 samples, or
        ``dpi`` not > 0.
    TypeError
        ``figure`` neither a whole number nor a string; ``results`` neither a Result nor
        a mapping of Results.
    """
    from numbers import Integral

    from pkmctl.sim.result import Result

    names = figure_names()
    allowed = f"a number from {FIGURES[0].number} to {FIGURES[-1].number} or one of " + ", ".join(
        names
    )
    if isinstance(figure, str):
        number = names.get(" ".join(figure.lower().split()))
    elif isinstance(figure, Integral) and not isinstance(figure, bool):
        number = int(figure)
    else:
        raise TypeError(f"figure = {figure!r}: {allowed}")
    spec = next((s for s in FIGURES if s.number == number), None)
    if spec is None:
        raise ValueError(f"figure = {figure!r}: {allowed}")
    if isinstance(results, Result):
        results = {results.controller: results}
    if not isinstance(results, Mapping) or not all(isinstance(r, Result) for r in results.values()):
        raise TypeError(
            f"results = {type(results).__name__}: a Result, or a mapping of names to Results"
        )
    pairs = _check(results)
    _check_dpi(dpi)
    return _render(spec, pairs, dpi)


# The runs a forked drawing process reads: set before the processes are forked, so that
# each child finds them in its copy of the parent's memory (nothing is pickled).
_FORKED_PAIRS: list[tuple[str, Result]] = []


def _child_start(parent: int) -> None:
    import signal

    from pkmctl.sim.workers import die_with_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    # forked: the parent's SIGTERM handler (Ctrl-C's, in the CLI) would make the signal
    # die_with_parent sends a KeyboardInterrupt the pool's worker loop outlives
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    die_with_parent(parent)


def _child_draw(number: int, outdir: str, dpi: float) -> str:
    spec = next(s for s in FIGURES if s.number == number)
    return str(_draw_one(spec, _FORKED_PAIRS, Path(outdir), dpi))


class FigureJob:
    """Figures being drawn while the caller goes on (:func:`start_figures`).

    :meth:`wait` returns the paths in figure order, or raises what a drawing raised;
    :meth:`cancel` stops the drawing (the caller's error path)."""

    def __init__(self, pool, futures: list, paths: list[Path] | None = None):
        self._pool, self._futures, self._paths = pool, futures, paths
        if pool is not None:
            _ACTIVE.append(self)

    def wait(self) -> list[Path]:
        """Block until every figure is written; their paths, in figure order."""
        if self._paths is None:
            from concurrent.futures.process import BrokenProcessPool

            try:
                self._paths = [Path(f.result()) for f in self._futures]
            except BrokenProcessPool as exc:
                raise RuntimeError(f"drawing figures: a drawing process died ({exc})") from None
            finally:
                self.cancel()
        return self._paths

    def cancel(self) -> None:
        """Stop drawing (figures not started are not drawn) and end the processes."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
            _ACTIVE.remove(self)

    def kill(self) -> None:
        """End the drawing processes at once (an interrupt: a drawing must not write into
        a folder being removed)."""
        import os
        import signal

        pool = self._pool
        for proc in list(getattr(pool, "_processes", {}).values()) if pool else []:
            try:
                os.kill(proc.pid, signal.SIGKILL)
            except OSError:
                pass
            proc.join(1.0)


#: The figure jobs drawing now (:func:`stop_drawing`).
_ACTIVE: list[FigureJob] = []


def stop_drawing() -> None:
    """Kill the processes of every figure job still drawing (the CLI's interrupt path,
    which leaves the run's thread as it is)."""
    for job in list(_ACTIVE):
        job.kill()


def figure_workers() -> int:
    """Processes :func:`start_figures` draws in by default: one per core, at most 4; 1
    (in this process) where processes cannot be forked (not Linux) or on one core."""
    import os
    import sys

    if not sys.platform.startswith("linux"):
        return 1
    return max(1, min(4, len(os.sched_getaffinity(0))))


def start_figures(
    results: Mapping[str, Result], outdir: Path | str, *, dpi: float = 110,
    workers: int | None = None,
) -> FigureJob:  # fmt: skip
    """Start drawing figures 10-26 into ``outdir`` in ``workers`` forked processes
    (default :func:`figure_workers`) and return at once; the runs are shared with the
    processes through the fork, not copied. With ``workers = 1`` the figures are drawn
    here, before this returns. Arguments and errors as :func:`make_figures`."""
    import gc
    import multiprocessing
    import os
    import sys
    import warnings
    from concurrent.futures import ProcessPoolExecutor

    global _FORKED_PAIRS
    pairs = _check(results)
    _check_dpi(dpi)
    outdir = Path(outdir)
    make_folder(outdir)  # (not inside a staging folder an interrupt removed)
    workers = figure_workers() if workers is None else int(workers)
    if workers <= 1:
        return FigureJob(None, [], [_draw_one(spec, pairs, outdir, dpi) for spec in FIGURES])
    for stream in (sys.stdout, sys.stderr):  # a child must not print the parent's buffer
        stream.flush()
    pool = ProcessPoolExecutor(
        min(workers, len(FIGURES)), mp_context=multiprocessing.get_context("fork"),
        initializer=_child_start, initargs=(os.getpid(),),
    )  # fmt: skip
    _FORKED_PAIRS = pairs
    # Objects the children only read stay out of their collector's sight: a full collection
    # in a child would otherwise walk (and so copy, page by page) the parent's whole heap.
    frozen = not gc.get_freeze_count()
    if frozen:
        gc.freeze()
    try:
        # the box plots sort every sample and the force figures hold three panels: first
        order = sorted(FIGURES, key=lambda s: s.kind not in ("box", "force"))
        with warnings.catch_warnings():  # the processes fork at the first submit
            # Python >= 3.12 warns of forking a multi-threaded process; the children only
            # draw and write files (docs/architecture.md, "pkmctl reproduce")
            warnings.filterwarnings("ignore", "This process .* is multi-threaded",
                                    DeprecationWarning)  # fmt: skip
            futures = {
                s.number: pool.submit(_child_draw, s.number, str(outdir), dpi) for s in order
            }
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    finally:
        _FORKED_PAIRS = []  # forked already: the children hold their copy
        if frozen:
            gc.unfreeze()
    return FigureJob(pool, [futures[s.number] for s in FIGURES])


def make_figures(
    results: Mapping[str, Result], outdir: Path | str, *, dpi: float = 110,
    workers: int = 1,
) -> list[Path]:  # fmt: skip
    """Draw figures 10-26 (DESIGN.md §4) as ``fig10.png`` ... ``fig26.png`` in ``outdir``.

    Parameters
    ----------
    results : mapping of str to Result
        Keyed by controller name (``"smc"``, ``"fsmc"``, ``"afsmc"``); the controllers
        present are drawn, in that order. The desired curves come from the first.
    outdir : Path or str
        Created if missing. Each file is written to a temporary file in the same
        directory and renamed into place, so a reader never sees a partial PNG.
    dpi : float, keyword-only
        Resolution of the PNGs.
    workers : int, keyword-only
        Processes to draw in (forked, Linux; :func:`start_figures`); 1 draws here.

    Returns
    -------
    list of Path
        The 17 files written, in figure order.

    Raises
    ------
    ValueError
        If ``results`` holds none of the known controllers, or a run is empty.
    """
    return start_figures(results, outdir, dpi=dpi, workers=workers).wait()
