"""``report.md``: the scenario, Table 4 beside the paper's, the figures and a discussion.

Every claim of the discussion is computed from the numbers it is about (rankings,
ratios, shares), so the text stays true when the numbers change. Renders only: the
numbers come from :mod:`pkmctl.sim.metrics` and :data:`~pkmctl.report.tables.PAPER_TABLE4`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pkmctl.sim.metrics import (
    LIMIT_MARGIN,
    RMSE_KEYS,
    chattering_index,
    last_time,
    limb_speed,
    peak_forces,
    rmse,
    sample_count,
    time_at_force_limit,
    time_over_speed_limit,
)
from pkmctl.sim.scenario import FUZZY_CONTROLLERS

from .figures import FIGURES
from .tables import (
    CONTROLLER_ORDER,
    PAPER_DURATION_S,
    PAPER_TABLE4,
    RMSE_AFTER_S,
    controller_label,
    ordered,
    rmse_after,
    table4_markdown,
)

if TYPE_CHECKING:
    from pkmctl.sim.result import Result

__all__ = ["render_report"]

_QUANTITY = {
    "z_mm": "z",
    "alpha_deg": "α",
    "beta_deg": "β",
    "q1_m": "q1",
    "q2_m": "q2",
    "q3_m": "q3",
    "q4_m": "q4",
}
_T_TRANSIENT = 0.2  # s: "the first ~0.2 s" of DESIGN.md §4
_TIE = 0.01  # relative spread below which our three values count as a tie
_CAPTIONS = {spec.filename: spec for spec in FIGURES}


def _seconds(x: float) -> str:
    """A duration with a readable unit (µs, ms or s)."""
    if x == 0.0:
        return "0 s"
    if x < 1e-3:
        return f"{x * 1e6:.3g} µs"
    if x < 1.0:
        return f"{x * 1e3:.3g} ms"
    return f"{x:.4g} s"


def _ranking(values: Mapping[str, float]) -> list[str]:
    """Controller names from the lowest value to the highest."""
    return sorted(values, key=lambda c: values[c])


def _chain(names: Sequence[str]) -> str:
    return " < ".join(controller_label(c) for c in names)


def _words(items: Sequence[str]) -> str:
    items = list(items)
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


def _span(lo: float, hi: float, spec: str) -> str:
    """``"a–b"``, or ``"a"`` when both print the same."""
    a, b = format(lo, spec), format(hi, spec)
    return a if a == b else f"{a}–{b}"


def _paper_pairs(pairs: list[tuple[str, Result]]) -> list[tuple[str, Result]]:
    """The runs of the controllers that the paper's Table 4 has a row for."""
    return [(c, r) for c, r in pairs if c in PAPER_TABLE4]


def _order(x: float, y: float) -> int:
    """1 if x > y, -1 if x < y, 0 within :data:`_TIE` of each other (a tie)."""
    lo, hi = sorted((x, y))
    if lo > 0 and hi / lo - 1.0 < _TIE:
        return 0
    return 1 if x > y else -1


def _ranking_sentences(pairs: list[tuple[str, Result]]) -> list[str]:
    pairs = _paper_pairs(pairs)
    names = [c for c, _ in pairs]
    if len(names) < 2:  # (it said "only one controller was run" after SMC, PD and CTC)
        return [
            f"- Rankings: {'only one' if names else 'none'} of the paper's controllers "
            f"({_words([controller_label(c) for c in PAPER_TABLE4])}) was run, so there is "
            f"nothing to rank against its Table 4."
        ]
    ours = {c: r.rmse() for c, r in pairs}
    same, differ, ties, no_order = [], [], [], []
    for k in RMSE_KEYS:
        values = {c: ours[c][k] for c in names}
        paper = {c: PAPER_TABLE4[c][k] for c in names}
        mine, theirs = _ranking(values), _ranking(paper)
        # pair by pair: two of ours within _TIE of each other are a tie, whose order says
        # nothing (q2: SMC and AFSMC 0.07 % apart made the order "differ" from the paper's)
        pairs_k = list(itertools.combinations(names, 2))
        tied = [(a, b) for a, b in pairs_k if _order(values[a], values[b]) == 0]
        opposed = [(a, b) for a, b in pairs_k
                   if _order(values[a], values[b]) * _order(paper[a], paper[b]) < 0]  # fmt: skip
        if tied and len(tied) == len(pairs_k):  # all of ours within _TIE: no order at all
            lo, hi = min(values.values()), max(values.values())
            no_order.append(f"{_QUANTITY[k]} (±{50 * (hi / lo - 1.0):.2g} %)")
        elif not opposed:
            same.append(_QUANTITY[k])
            if tied:
                ties.append(f"on {_QUANTITY[k]} " + ", ".join(
                    f"{controller_label(a)} and {controller_label(b)} are "
                    f"{100 * abs(values[a] / values[b] - 1.0):.2g} % apart" for a, b in tied
                ))  # fmt: skip
        else:
            differ.append(f"{_QUANTITY[k]} (ours {_chain(mine)}; paper {_chain(theirs)})")
    n, m = len(same), len(RMSE_KEYS) - len(no_order)
    count = "none" if n == 0 else ("all" if n == m else f"{n}")
    lines = [
        f"- **Ranking, whole-run RMSE**: ours orders the controllers as the paper's Table 4 "
        f"does for {count} of the {m} quantities ours order"
        + (f" ({_words(same)})" if same and n < m else "")
        + (
            f", counting two of ours within {100 * _TIE:g} % as either order ({'; '.join(ties)})"
            if ties
            else ""
        )  # fmt: skip
        + "."
        + (f" It differs for {_words(differ)}." if differ else "")
    ]
    if no_order:
        lines.append(
            f"  On {_words(no_order)} ours are all within {100 * _TIE:g} % of each other: "
            "no order, and nothing said about which tracks better."
        )
    start = {k: _start_shares(pairs, k) for k in RMSE_KEYS}
    early = [k for k, v in start.items() if v and len(v) == len(pairs) and min(v.values()) >= 50]
    if early:  # (the β caveat alone left α and the limbs' rankings read as tracking)
        lo = min(min(start[k].values()) for k in early)
        hi = max(max(start[k].values()) for k in early)
        lines.append(
            f"  On {_words([_QUANTITY[k] for k in early])} every controller's whole-run "
            f"squared error is mostly its first {_T_TRANSIENT:g} s ({lo:.3g}-{hi:.4g} %): "
            "those rankings compare the start, not the tracking (after 1 s: below)."
        )
    ratios = np.array([ours[c][k] / PAPER_TABLE4[c][k] for c in names for k in RMSE_KEYS])
    below = int(np.sum(ratios < 1.0))
    line = (
        f"- **Ours / paper**: the ratio ranges from {ratios.min():.2g} to {ratios.max():.2g} "
        f"(median {np.median(ratios):.2g}); {below} of our {ratios.size} RMSEs are below "
        "the paper's."
    )
    duration = pairs[0][1].scenario.timing.duration
    if not math.isclose(duration, PAPER_DURATION_S):
        line += (
            f" Our run lasts {duration:g} s and the paper's {PAPER_DURATION_S:g} s, so "
            "whole-run RMSEs are not directly comparable (the start weighs more in a "
            "shorter run)."
        )
    lines.append(line)
    return lines


#: The task coordinates' RMSE keys, their column in X and how an offset is shown.
_START = (("z_mm", 0, 1e3, " mm"), ("alpha_deg", 1, 180 / math.pi, "°"),
          ("beta_deg", 2, 180 / math.pi, "°"))  # fmt: skip


def _start_shares(pairs: list[tuple[str, Result]], key: str) -> dict[str, float]:
    """Per controller, the share (%) of the whole run's squared error in ``key`` that the
    first :data:`_T_TRANSIENT` s hold (runs not longer than that are left out)."""
    shares: dict[str, float] = {}
    for c, r in pairs:
        if last_time(r) <= _T_TRANSIENT:
            continue
        n_all, n_after = sample_count(r), sample_count(r, t_from=_T_TRANSIENT)
        sse_all = n_all * rmse(r)[key] ** 2
        sse_after = n_after * rmse(r, t_from=_T_TRANSIENT)[key] ** 2
        if sse_all > 0:
            shares[c] = 100 * (1 - sse_after / sse_all)
    return shares


def _shares_words(shares: dict[str, float], quantity: str) -> str:
    words = _words([f"{v:.4g} % ({controller_label(c)})" for c, v in shares.items()])
    text = f" The first {_T_TRANSIENT:g} s hold {words} of the squared {quantity} error"
    start = [controller_label(c) for c, v in shares.items() if v >= 50.0]
    if len(start) == len(shares):
        return text + ", so the whole-run RMSE measures the start, not the tracking."
    if start:
        rest = [controller_label(c) for c, v in shares.items() if v < 50.0]
        return text + (
            f": for {_words(start)} the whole-run RMSE measures mostly the start, for "
            f"{_words(rest)} mostly the tracking."
        )
    return text + ": the whole-run RMSE measures mostly the tracking here."


def _transient_sentences(pairs: list[tuple[str, Result]]) -> list[str]:
    ref = pairs[0][1]
    sc = ref.scenario
    offsets = {
        key: (abs(ref.X_desired[0, col] - ref.X[0, col]) * scale, unit)
        for key, col, scale, unit in _START
        if abs(ref.X_desired[0, col] - ref.X[0, col]) >= 1e-9 * (1e3 if col == 0 else 1)
    }  # z in m: 1 um; angles in rad: ~6e-8 degrees
    lines = []
    others = [k for k in offsets if k != "beta_deg"]
    if others:
        said = _words([f"{_QUANTITY[k]} {offsets[k][0]:.3g}{offsets[k][1]}" for k in others])
        line = f"- **Start off the trajectory**: the run starts {said} off its trajectory."
        for k in others:
            shares = _start_shares(pairs, k)
            if shares:
                line += _shares_words(shares, _QUANTITY[k])
        lines.append(line)
    if "beta_deg" not in offsets:
        if not offsets:
            lines.append("- **Start**: the run starts on its trajectory, so no initial "
                         "transient dominates.")  # fmt: skip
        return lines
    e0 = offsets["beta_deg"][0]
    lam = float(sc.gains.lam[2])
    T = last_time(ref) - float(ref.t[0]) + sc.timing.control_period  # a decimated log too
    estimate = e0 / math.sqrt(2.0 * lam * T)
    paper_estimate = e0 / math.sqrt(2.0 * lam * PAPER_DURATION_S)
    ours = [r.rmse()["beta_deg"] for _, r in pairs]
    paper = [PAPER_TABLE4[c]["beta_deg"] for c, _ in _paper_pairs(pairs)]
    line = (
        f"- **The first instants dominate**: β starts {e0:.3g}° off its trajectory. A "
        f"controller that reaches the sliding surface quickly then lets the error decay as "
        f"e^(−λ_β t), whose RMSE over T = {T:.3g} s is ≈ {e0:.3g}°/√(2·{lam:g}·{T:.3g}) = "
        f"{estimate:.3g}°. Our whole-run β RMSEs are "
        f"{_words([f'{v:.4g}°' for v in ours])} "
        f"({_span(min(ours) / estimate, max(ours) / estimate, '.2f')} × the estimate)"
        + (
            f"; the paper's are {_words([f'{v:.3g}°' for v in paper])} "
            f"({_span(min(paper) / paper_estimate, max(paper) / paper_estimate, '.2f')} × "
            f"the same estimate for a {PAPER_DURATION_S:g} s run from rest at home, "
            f"{paper_estimate:.3g}°: the paper states neither, DESIGN.md §4 assumes both)."
            if paper
            else "."
        )
    )
    shares = _start_shares(pairs, "beta_deg")
    if shares:
        line += _shares_words(shares, "β")
    return [*lines, line]


def _after_sentences(pairs: list[tuple[str, Result]]) -> list[str]:
    after = {c: rmse_after(r) for c, r in pairs}
    after = {c: v for c, v in after.items() if v is not None}
    if len(after) < 2:
        return [
            f"- **After {RMSE_AFTER_S:g} s**: the runs are too short to compare the RMSE "
            f"after the first {RMSE_AFTER_S:g} s."
        ]
    best: dict[str, list[str]] = {c: [] for c in after}
    for k in RMSE_KEYS:
        best[_ranking({c: after[c][k] for c in after})[0]].append(_QUANTITY[k])
    parts = [
        f"{controller_label(c)} for {_words(q)}" for c, q in best.items() if q
    ]  # fmt: skip
    spread = {
        k: max(v[k] for v in after.values()) / min(v[k] for v in after.values())
        for k in RMSE_KEYS
        if min(v[k] for v in after.values()) > 0
    }
    line = (
        f"- **After the first {RMSE_AFTER_S:g} s**, where the controllers differ, the lowest "
        f"RMSE is {_words(parts)}."
    )
    if spread:
        k_max = max(spread, key=spread.get)
        line += (
            f" The largest spread between controllers is on {_QUANTITY[k_max]} "
            f"(×{spread[k_max]:.3g} from best to worst)."
        )
    return [line]


def _force_limit(result: Result) -> float | None:
    """The actuators' force limit (N) the loop applied: a ``force_limit`` of the ideal
    actuator or a drive's peak torque through its screw; None if unbounded."""
    lm = getattr(result, "loop_metrics", None)
    if lm is not None and math.isfinite(lm.force_limit):
        return float(lm.force_limit)
    return result.scenario.actuators.force_limit if lm is None else None


def _force_sentences(pairs: list[tuple[str, Result]]) -> list[str]:
    ref = pairs[0][1]
    limit = _force_limit(ref)
    peaks = []
    every = int(getattr(ref, "every", 1))
    for c, r in pairs:
        p = peak_forces(r)  # over every period (the loop's own, when the log is decimated)
        i = int(np.argmax(p))
        if every > 1:  # the log does not hold the peak's period: no time to give
            peaks.append(f"{p[i]:.4g} N ({controller_label(c)}, τ{i + 1})")
            continue
        at = np.abs(r.tau[:, i]) >= (limit or np.inf) * (1 - LIMIT_MARGIN)
        if at.any():  # saturated: when, not the instant of a rounding's maximum
            t0, t1 = (_seconds(float(r.t[k])) for k in np.flatnonzero(at)[[0, -1]])
            when = f"at the limit at t = {t0}" if t0 == t1 else f"at the limit from {t0} to {t1}"
        else:
            when = f"at t = {_seconds(float(r.t[int(np.argmax(np.abs(r.tau[:, i])))]))}"
        peaks.append(f"{p[i]:.4g} N ({controller_label(c)}, τ{i + 1} {when})")
    desired = float(np.max(np.abs(ref.tau_desired)))
    where = "" if every == 1 else f" at the logged periods (one in {every})"
    bound = (
        "unbounded, as in the paper (which gives no limits)"
        if limit is None
        else f"limited to ±{round(limit, 1):g} N in this scenario"
    )
    chat = [
        f"{float(np.mean(chattering_index(r))):.3g} N/s ({controller_label(c)})" for c, r in pairs
    ]
    line = (
        f"- **Forces**: the peak |τ_i| is {_words(peaks)}, against at most {desired:.3g} N for "
        f"the desired driving forces{where}; the actuators are {bound}."
    )
    if limit is not None:
        held = [(c, time_at_force_limit(r)) for c, r in pairs]
        if any(v for _, v in held):
            line += " Some limb's force is at the limit for " + _words(
                [f"{_seconds(v)} ({controller_label(c)})" for c, v in held]
            ) + "."  # fmt: skip
    speeds = [(c, limb_speed(r), time_over_speed_limit(r)) for c, r in pairs]
    if all(v is not None for _, v, _ in speeds):
        top = float(ref.loop_metrics.speed_limit)  # there is one: limb_speed gave speeds
        over = [(c, float(np.max(v)), t) for c, v, t in speeds]
        line += " The peak true limb speed is " + _words(
            [f"{v:.3g} m/s ({controller_label(c)})" for c, v, _ in over]
        ) + f" against the drives' {top:.3g} m/s"  # fmt: skip
        if any(t for _, _, t in over):
            line += (
                ", exceeded for "
                + _words([f"{_seconds(t)} ({controller_label(c)})" for c, _, t in over])
                + " (not enforced here; a real drive would fault)"
            )
        line += "."
    hold = ref.scenario.disturbance.hold
    stepped = any(a != 0 for a in ref.scenario.disturbance.amplitude)
    line += (
        f" The chattering index (mean |Δτ| per second, averaged over the four actuators) is "
        f"{_words(chat)}"
        + (
            f"; it counts every change of force, the controllers' answer to the random "
            f"disturbance (redrawn every {_seconds(hold)}) included, so in a loop that does "
            f"not chatter it measures mostly that answer (README: the paper scenario's)."
            if stepped
            else "."
        )
    )
    return [line, *_chatter_sentences(pairs)]


#: A controller whose largest per-limb chattering index is this many times the median of
#: the controllers' is said to chatter (the prototype's SMC: 20 x FSMC's, unsaid before).
CHATTER_RATIO = 5.0


def _chatter_sentences(pairs: list[tuple[str, Result]]) -> list[str]:
    """Who chatters (a per-limb index far above the others'), and whether AFSMC's forces
    are smoother than FSMC's on limbs 2 and 4, as the paper finds (its Figs. 24, 26)."""
    idx = {c: chattering_index(r) for c, r in pairs}
    out = []
    if len(idx) >= 3:
        typical = float(np.median([np.max(v) for v in idx.values()]))
        for c, v in idx.items():
            limbs = [i for i in range(4) if v[i] >= CHATTER_RATIO * typical]
            if typical > 0 and limbs:
                out.append(
                    f"- **{controller_label(c)} chatters**: its chattering index on "
                    + _words([f"τ{i + 1} {v[i]:.3g} N/s" for i in limbs])
                    + f" is {np.max(v[limbs]) / typical:.3g} × the median of the controllers' "
                    f"largest ({typical:.3g} N/s): its forces ring, which a real drive and "
                    "screw would feel (Figs. 23-26)."
                )
    if "afsmc" in idx and "fsmc" in idx:
        a, f = idx["afsmc"][[1, 3]], idx["fsmc"][[1, 3]]
        ratio = float(np.mean(a) / np.mean(f)) if np.mean(f) > 0 else math.nan
        verdict = (
            "smoother, as the paper finds" if ratio < 0.9
            else "not smoother: the paper's finding is not reproduced here" if ratio < 1.1
            else "rougher: the opposite of the paper's finding"
        )  # fmt: skip
        out.append(
            "- **AFSMC's forces against FSMC's**: the paper finds AFSMC's driving forces on "
            "limbs 2 and 4 smoother than SMC's and FSMC's (its Figs. 24 and 26). Here "
            f"AFSMC's chattering index on τ2 and τ4 is {a[0]:.3g} and {a[1]:.3g} N/s, FSMC's "
            f"{f[0]:.3g} and {f[1]:.3g} ({ratio:.3f} ×): {verdict}."
        )
    return out


def _sampling_sentence(pairs: list[tuple[str, Result]]) -> list[str]:
    timing = pairs[0][1].scenario.timing
    used = pairs[0][1].parts
    sensor, actuator = used.get("sensor", "ideal"), used.get("actuator", "ideal")
    held = (
        "its actuator forces are held over the period (zero-order hold)"
        if actuator == "ideal"
        else f"its force commands are held over the period and applied through the "
        f"`{actuator}` actuator's own dynamics"
    )
    sees = "" if sensor == "ideal" else f" from the `{sensor}` sensor's measurement"
    return [
        f"- **Sampling**: the paper's study is continuous time; here the controller runs "
        f"every T_c = {_seconds(timing.control_period)}{sees} and {held}, with the plant "
        f"integrated by RK4 ({timing.substeps} sub-step{'s' if timing.substeps != 1 else ''} "
        f"per period)."
    ]


def _why_sentences(pairs: list[tuple[str, Result]]) -> list[str]:
    """Why the steady z errors differ: gravity the model misses over the surface gain."""
    from pkmctl.parts import get_part
    from pkmctl.sim.metrics import gravity_mismatch, mean_error, surface_gain

    sc = pairs[0][1].scenario
    dG = float(gravity_mismatch(sc)[0])
    lam = float(sc.gains.lam[0])
    if abs(dG) < 1e-9 or last_time(pairs[0][1]) < 1.0:
        return []
    parts = []
    predicted: dict[str, float] = {}
    gained: list[str] = []
    steady = {c: abs(mean_error(r, t_from=1.0)["z_mm"]) for c, r in pairs}
    for c, r in pairs:
        measured = mean_error(r, t_from=1.0)["z_mm"]
        label = controller_label(c)
        if get_part("controller", c).adaptive:
            parts.append(
                f"{label} adapts the masses, and its mean z error after 1 s is {measured:.3g} mm"
            )
            continue
        sg = surface_gain(sc, c)
        if sg is None:
            parts.append(f"{label} shows {measured:.3g} mm{_swing(r)}")
            continue
        gain = float(sg[0])
        if not gain > 0.0:  # (a valid zero gain divided by zero and lost the runs: a reader)
            parts.append(
                f"{label} has no gain from s to F on z near s = 0, so nothing there meets "
                f"the missing gravity, and shows {measured:.3g} mm{_swing(r)}"
            )
            continue
        gained.append(label)  # (after the check: "PD meets it ... PD has no gain": a review)
        predicted[c] = 1e3 * dG / (gain * lam)
        parts.append(
            f"{label} (gain near s = 0: {gain:.4g} N·s/m) predicts {predicted[c]:.3g} mm "
            f"and shows {measured:.3g} mm{_swing(r)}"
        )
    tail = ""
    measured = {c: mean_error(r, t_from=1.0)["z_mm"] for c, r in pairs if c in predicted}
    # the estimate holds where each error has its predicted sign and size (within 3x)
    holds = all(
        predicted[c] * measured[c] > 0 and 1 / 3 <= measured[c] / predicted[c] <= 3
        for c in predicted
    )
    if predicted and not holds:
        ps, cm = sc.plant_spec, sc.controller_model
        friction = (ps.friction_coulomb, ps.friction_viscous)
        more = [name for name, on in (
            ("rotor inertia", ps.rotor_inertia > 0 and cm.rotor_inertia != ps.rotor_inertia),
            ("joint friction", any(friction)
             and (cm.friction_coulomb, cm.friction_viscous) != friction),
            ("a payload", sc.payload.mass > 0),
            (f"the `{sc.actuators.kind}` actuator's dynamics", sc.actuators.kind != "ideal"),
        ) if on]  # fmt: skip
        tail = (
            " The measured errors do not have the predicted sign and size: the missing "
            "gravity does not explain them here"
            + (
                f"; the plant also has {_words(more)}, which the controllers' model lacks."
                if more
                else "."
            )  # fmt: skip
        )
    elif len(predicted) >= 2:
        stiff = min(predicted, key=lambda c: abs(predicted[c]))
        best = min(predicted, key=lambda c: steady[c])
        tail = f" The stiffest surface ({controller_label(stiff)}) " + (
            "holds z best among these, as predicted."
            if stiff == best
            else f"does not hold z best ({controller_label(best)} does): the prediction "
            "misses something here."
        )
    # (the controllers that ran with a surface gain, where it said "SMC and FSMC" whatever
    # ran, PD included: a code reader)
    if gained:
        meet = (
            f" {_words(gained)} meet{'s' if len(gained) == 1 else ''} it with the gain from "
            f"s to F near the surface, leaving a steady error of about ΔG/(gain·λ_z)"
        )
    else:
        meet = ""
    return [
        f"- **Why the z errors differ**: the controllers' model is "
        f"{100 * (1 - sc.controller_model.theta_scale):.0f} % light, so at the mean pose it "
        f"misses {dG:.3g} N of gravity on z.{meet} (each measured as its mean z error "
        f"after 1 s): {'; '.join(parts)}.{tail}"
    ]


def _swing(result: Result) -> str:
    """ ", swinging from a to b mm" where the z error after 1 s moves by more than its mean
    (a PD without feedforward follows the trajectory's frequency: no steady value); ""
    otherwise or for a decimated log."""
    from pkmctl.sim.metrics import _errors

    if int(getattr(result, "every", 1)) > 1:
        return ""
    e = _errors(result, 1.0)[:, 0]
    if e.size < 2 or np.ptp(e) <= abs(float(np.mean(e))):
        return ""
    return f" (its error swings from {e.min():.3g} to {e.max():.3g} mm with the trajectory)"


#: Fields the report's run sentence states already, left out of its list of differences.
_STATED = ("timing.duration", "disturbance.seed", "fuzzy.")


def _value(v) -> str:
    if isinstance(v, list):
        if len(v) > 6:
            return f"({len(v)} values)"
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, float):
        return f"{v:g}"
    return "none" if v is None else str(v)


def _differences_sentence(sc) -> str:
    """What the run's scenario changed from the built-in of its name (else the built-in it
    differs least from): an edited file that kept `name = "prototype"` gave the built-in's
    report word for word, and a report on another trajectory compared with the paper's
    Table 4 unsaid (a tester)."""
    from pkmctl.sim.scenario import BUILTINS, Scenario

    def changed(ref: str) -> list[tuple[str, object, object]]:
        out, kind = [], None
        for k, a, b in sc.differences(Scenario.builtin(ref)):
            if k.startswith(_STATED):
                continue
            if k.startswith("trajectory."):  # another kind of trajectory: one item
                if k == "trajectory.kind":
                    kind = (k, a, b)
                if kind is not None:
                    continue
            out.append((k, a, b))
        return ([kind] if kind else []) + out

    if sc.name in BUILTINS:
        ref = sc.name
    else:
        ref = min(BUILTINS, key=lambda name: len(changed(name)))
    text = ""
    if diffs := changed(ref):
        shown = [f"{k} = {_value(a)} (built-in: {_value(b)})" for k, a, b in diffs[:8]]
        more = f", and {len(diffs) - 8} more" if len(diffs) > 8 else ""
        text += f" It differs from the built-in “{ref}” in {'; '.join(shown)}{more}."
    paper = Scenario.builtin("paper")
    moved = [what for key, what in (("trajectory", "trajectory"), ("initial", "initial state"))
             if getattr(sc, key) != getattr(paper, key)]  # fmt: skip
    if moved:
        text += (
            f" **Warning**: its {' and '.join(moved)} {'are' if len(moved) > 1 else 'is'} not "
            "the paper's (eq. 54, from rest at z = 0.7 m): Table 4's paper rows, and our "
            "ratios to them, come from another experiment."
        )
    return text


def render_report(
    results: Mapping[str, Result],
    *,
    figures: Sequence[Path | str],
    scenario_name: str,
    wall_time_s: float | None = None,
) -> str:
    """The markdown of ``report.md`` for one reproduction run.

    Parameters
    ----------
    results : mapping of str to Result
        Keyed by controller name (``"smc"``, ``"fsmc"``, ``"afsmc"``); all from the
        same scenario. Timing, seed and limits are read from the first.
    figures : sequence of Path or str, keyword-only
        The figure files (as returned by :func:`~pkmctl.report.make_figures`); each
        is linked as ``figures/<file name>``, so report.md sits beside ``figures/``.
    scenario_name : str, keyword-only
        Name shown in the title and scenario line.
    wall_time_s : float or None, keyword-only
        Wall-clock time of the run, shown if given.

    Returns
    -------
    str
        Markdown: title, scenario, Table 4 (:func:`~pkmctl.report.table4_markdown`),
        a discussion computed from the numbers, and the figures with captions.

    Raises
    ------
    ValueError
        If ``results`` holds no run (a name the paper does not have, a part of your own,
        is reported like the paper's five).
    """
    pairs = ordered(results)
    if not pairs:  # (it said "no known controller", which an unknown one never was)
        raise ValueError(
            f"results: no run among {sorted(results)} (a Result for each controller name, "
            f"such as {', '.join(CONTROLLER_ORDER)})"
        )
    sc = pairs[0][1].scenario
    lines = [f"# pkmctl — the paper's experiment, scenario “{scenario_name}”", ""]
    if sc.description:
        lines += [sc.description, ""]
    limit = _force_limit(pairs[0][1])
    run = (
        f"Scenario **{scenario_name}**: T_c = {_seconds(sc.timing.control_period)}, "
        f"duration {sc.timing.duration:g} s, disturbance seed {sc.disturbance.seed}, "
        f"actuators {'unbounded' if limit is None else f'limited to ±{round(limit, 1):g} N'}; "
        f"controllers {_words([controller_label(c) for c, _ in pairs])}."
    )
    used = pairs[0][1].parts
    if used.get("plant"):  # which machine ran: the closed form or MuJoCo's, and what fed it
        from pkmctl.parts import get_part

        run += (
            f" Plant `{used['plant']}`: {get_part('plant', used['plant']).description}; "
            f"sensor `{used.get('sensor', 'ideal')}`, actuator `{used.get('actuator', 'ideal')}`."
        )
    fuzzy = sc.fuzzy
    if fuzzy.fis is not None and any(c in FUZZY_CONTROLLERS for c, _ in pairs):
        # FSMC and AFSMC ran on another fuzzy system than the paper's: Table 4 compares
        # them with the paper's all the same (a tester found no word of it)
        run += (
            f" FSMC and AFSMC's fuzzy term: the `.fis` file `{fuzzy.fis}` "
            f"(inputs {fuzzy.input_range}"
            + (f", tabulated at {fuzzy.samples} points an input" if fuzzy.samples else "")
            + "), in place of the built-in FLC of the paper."
        )
        if note := sc.fuzzy_offset_note():
            run += f" **Warning**: {note}."
    run += _differences_sentence(sc)
    if wall_time_s is not None:
        run += f" Wall time {wall_time_s:.1f} s."
    from pkmctl.io.results import provenance_line

    run += " " + provenance_line()
    lines += [run, ""]
    for c, r in pairs:
        if not r.success:
            lines += [f"**Warning**: the {controller_label(c)} run failed: {r.message}.", ""]

    lines += ["## Table 4", "", table4_markdown(results).rstrip("\n"), ""]

    lines += ["## Discussion", ""]
    lines += _ranking_sentences(pairs)
    lines += _transient_sentences(pairs)
    lines += _after_sentences(pairs)
    lines += _force_sentences(pairs)
    lines += _why_sentences(pairs)
    lines += _sampling_sentence(pairs)
    lines.append("")

    lines += ["## Figures", ""]
    for f in figures:
        name = Path(f).name
        spec = _CAPTIONS.get(name)
        title = spec.title if spec else name
        caption = spec.caption if spec else ""
        lines += [f"![{title}](figures/{name})", "", f"*{title}.* {caption}".rstrip(), ""]
    return "\n".join(lines).rstrip("\n") + "\n"
