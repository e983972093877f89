"""Table 4 of the paper, side by side with ours, as CSV and markdown (DESIGN.md §4).

Renders only: every number comes from :mod:`pkmctl.sim.metrics` or from
:data:`PAPER_TABLE4`; this module formats them.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

from pkmctl.sim.metrics import RMSE_KEYS, chattering_index, last_time, peak_forces, rmse

if TYPE_CHECKING:
    from pkmctl.sim.result import Result

__all__ = [
    "CONTROLLER_ORDER",
    "controller_label",
    "PAPER_DURATION_S",
    "PAPER_TABLE4",
    "RMSE_AFTER_S",
    "ordered",
    "rmse_after",
    "table4_csv",
    "table4_markdown",
]

#: The order of the controllers in every table and figure: the paper's three, then the
#: baselines; any other controller follows in the order it was given.
CONTROLLER_ORDER: tuple[str, ...] = ("smc", "fsmc", "afsmc", "pd", "ctc")


def controller_label(name: str) -> str:
    """How a controller is named in reports: its part's label (e.g. "AFSMC")."""
    from pkmctl.parts import PartError, get_part

    try:
        return get_part("controller", name).label
    except PartError:
        return name


#: The "RMSE after the first second" of DESIGN.md §4 starts here (s).
RMSE_AFTER_S = 1.0

#: Table 4 of the paper: RMSE over the whole 10 s run (eq. 55-57), z in mm, alpha and
#: beta in degrees, q1..q4 in m. The paper's rows "MSC" and "FMSC" mean SMC and FSMC.
PAPER_TABLE4: dict[str, dict[str, float]] = {
    "smc": {
        "z_mm": 0.545968,
        "alpha_deg": 0.918397,
        "beta_deg": 6.12032,
        "q1_m": 0.0120748,
        "q2_m": 0.0266254,
        "q3_m": 0.00977163,
        "q4_m": 0.0173405,
    },
    "fsmc": {
        "z_mm": 0.218587,
        "alpha_deg": 0.825874,
        "beta_deg": 4.73001,
        "q1_m": 0.00969521,
        "q2_m": 0.0193492,
        "q3_m": 0.00668029,
        "q4_m": 0.0140356,
    },
    "afsmc": {
        "z_mm": 0.377072,
        "alpha_deg": 0.184167,
        "beta_deg": 2.66612,
        "q1_m": 0.00153664,
        "q2_m": 0.0094806,
        "q3_m": 0.00061928,
        "q4_m": 0.0075560,
    },
}

#: Length of the paper's run over which Table 4 is taken (s; DESIGN.md §4).
PAPER_DURATION_S = 10.0

#: Column headers with units, one per key of :data:`~pkmctl.sim.metrics.RMSE_KEYS`.
_HEADERS: dict[str, str] = {
    "z_mm": "z (mm)",
    "alpha_deg": "α (°)",
    "beta_deg": "β (°)",
    "q1_m": "q1 (m)",
    "q2_m": "q2 (m)",
    "q3_m": "q3 (m)",
    "q4_m": "q4 (m)",
}


def ordered(results: Mapping[str, Result]) -> list[tuple[str, Result]]:
    """The (name, result) pairs in :data:`CONTROLLER_ORDER`, then any others as given.

    Parameters
    ----------
    results : mapping of str to Result
        Keyed by controller name (``"smc"``, ``"fsmc"``, ``"afsmc"``).

    Returns
    -------
    list of (str, Result)
    """
    present = [c for c in results if results[c] is not None]
    known = [c for c in CONTROLLER_ORDER if c in present]
    return [(c, results[c]) for c in known + [c for c in present if c not in known]]


def rmse_after(result: Result, t_from: float = RMSE_AFTER_S) -> dict[str, float] | None:
    """RMSE from ``t_from`` on (:func:`pkmctl.sim.metrics.rmse`), or None if the run ends before.

    Parameters
    ----------
    result : Result
    t_from : float
        Start of the window (s).

    Returns
    -------
    dict of str to float, or None
        Keys of :data:`~pkmctl.sim.metrics.RMSE_KEYS`.
    """
    if result.t.size == 0 or last_time(result) < t_from:  # the run's end, not its log's
        return None
    return rmse(result, t_from=t_from)


def table4_csv(results: Mapping[str, Result]) -> str:
    """Our Table 4 (RMSE over the whole run, eq. 55-57) as CSV at full float precision.

    Parameters
    ----------
    results : mapping of str to Result
        Keyed by controller name; rows appear in :data:`CONTROLLER_ORDER`, then any
        others, only for those present.

    Returns
    -------
    str
        Header ``controller,z_mm,alpha_deg,beta_deg,q1_m,q2_m,q3_m,q4_m`` and one row
        per controller, values written with :func:`repr` (they read back exactly).
    """
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["controller", *RMSE_KEYS])
    for name, result in ordered(results):
        values = result.rmse()
        writer.writerow([name, *(repr(float(values[k])) for k in RMSE_KEYS)])
    return buf.getvalue()


def _fmt(x: float | None, spec: str = ".4g") -> str:
    """``x`` to the significant digits of ``spec``, trailing zeros kept (0.7000 beside
    0.3225, not 0.7), "—" for None or a non-finite value."""
    if x is None or not math.isfinite(x):
        return "—"
    text = format(x, "#" + spec)
    return text[:-1] if text.endswith(".") else text  # 5222., not a decimal point alone


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _header(cells: list[str]) -> list[str]:
    return [_row(cells), _row(["---"] * len(cells))]


def table4_markdown(results: Mapping[str, Result]) -> str:
    """Table 4, ours beside the paper's, and a table of what Table 4 does not show.

    Parameters
    ----------
    results : mapping of str to Result
        Keyed by controller name.

    Returns
    -------
    str
        Markdown: (1) for each controller the row "ours" and, for the paper's three,
        "paper" (Table 4) and "ours / paper"; (2) our RMSE after the first second (the
        paper gives none); (3) our peak actuator forces |τ_i| (N) and chattering index (N/s).
    """
    pairs = ordered(results)
    lines = ["**Table 4 — RMSE over the whole run (eq. 55-57), ours and the paper's**", ""]
    lines += _header(["controller", "source", *(_HEADERS[k] for k in RMSE_KEYS)])
    for name, result in pairs:
        label = controller_label(name)
        ours = result.rmse()
        lines.append(_row([label, "ours", *(_fmt(ours[k]) for k in RMSE_KEYS)]))
        paper = PAPER_TABLE4.get(name)
        if paper is None:  # a baseline: the paper has no row for it
            continue
        lines.append(_row([label, "paper", *(repr(paper[k]) for k in RMSE_KEYS)]))
        ratio = [_fmt(ours[k] / paper[k], ".2g") for k in RMSE_KEYS]  # 0.0012, not 0.00
        lines.append(_row([label, "ours / paper", *ratio]))

    lines += ["", f"**RMSE after the first {RMSE_AFTER_S:g} s (ours; the paper gives none)**", ""]
    lines += _header(["controller", *(_HEADERS[k] for k in RMSE_KEYS)])
    for name, result in pairs:
        after = rmse_after(result)
        cells = [_fmt(None if after is None else after[k]) for k in RMSE_KEYS]
        lines.append(_row([controller_label(name), *cells]))

    lines += ["", "**Actuator forces (ours): peak |τ_i| and chattering index**", ""]
    lines += _header(
        [
            "controller",
            *(f"peak τ{i} (N)" for i in range(1, 5)),
            *(f"chattering τ{i} (N/s)" for i in range(1, 5)),
        ]
    )
    for name, result in pairs:
        peaks = [_fmt(float(v), ".4g") for v in peak_forces(result)]
        chat = [_fmt(float(v), ".3g") for v in chattering_index(result)]
        lines.append(_row([controller_label(name), *peaks, *chat]))
    return "\n".join(lines) + "\n"
