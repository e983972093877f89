"""What ``pkmctl identify`` writes: report.md, figures, estimate.json and the estimate as a
scenario ``[controller_model]`` block (controller_model.toml)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import tomli_w

from pkmctl.ident.base import PARAMETER_NAMES, PARAMETER_UNITS
from pkmctl.ident.identify import Identification
from pkmctl.io.atomic import atomic_write
from pkmctl.io.results import provenance, provenance_line

__all__ = ["OUTPUT_NAMES", "remove_stale", "write_identification"]

#: The figures' three axes, in the style of reproduce's ("α (°)", "t (s)").
_AXES = (("Jᵀτ, z", "N"), ("Jᵀτ, α", "N·m"), ("Jᵀτ, β", "N·m"))

#: Every file ``pkmctl identify`` may write into its folder: a run removes those of an
#: earlier run it does not write itself (and never any other file).
OUTPUT_NAMES = (
    "report.md",
    "estimate.json",
    "controller_model.toml",
    "fit.png",
    "residuals.png",
    "parameters.png",
    "validation.png",
)


def remove_stale(folder: Path, written: list[Path]) -> list[Path]:
    """Remove the files of :data:`OUTPUT_NAMES` in ``folder`` that this run did not write
    (``written``), so the folder holds one run's outputs; return those removed."""
    keep = {Path(p).name for p in written}
    gone = []
    for name in OUTPUT_NAMES:
        path = Path(folder) / name
        if name not in keep and (path.is_file() or path.is_symlink()):
            path.unlink()
            gone.append(path)
    return gone


def _figures(idn: Identification, folder: Path, validation: dict | None, source: str) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    obs = idn.observation
    yhat = idn.base.reduce(obs.W) @ idn.wls.beta
    out = []

    def save(fig, name):
        path = folder / name
        with atomic_write(path, "wb") as fh:
            fig.savefig(fh, format="png", dpi=110)
        plt.close(fig)
        out.append(path)

    fig, axs = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for a, (ax, (name, unit)) in enumerate(zip(axs, _AXES, strict=True)):
        ax.plot(obs.t, obs.y[:, a], color="0.2", lw=1.2, label="measured Jᵀτ")
        ax.plot(obs.t, yhat[:, a], color="C1", lw=0.9, ls="--", label="predicted (WLS)")
        ax.set_ylabel(f"{name} ({unit})")
    axs[0].legend(loc="upper right", fontsize=8)
    axs[0].set_title(f"Identification data ({Path(source).name}): measured and predicted Jᵀτ")
    axs[-1].set_xlabel("t (s)")
    fig.tight_layout()
    save(fig, "fit.png")

    fig, axs = plt.subplots(3, 1, figsize=(9, 6), sharex=True)
    for a, (ax, (name, unit)) in enumerate(zip(axs, _AXES, strict=True)):
        ax.plot(obs.t, obs.y[:, a] - yhat[:, a], color="C3", lw=0.8)
        ax.axhline(0.0, color="0.5", lw=0.5)
        ax.set_ylabel(f"{name} ({unit})")
    axs[0].set_title(
        f"Residuals (WLS) on {Path(source).name}, RMS "
        + ", ".join(f"{v:.3g} {u}" for v, (_, u) in zip(idn.wls.rms, _AXES, strict=True))
    )
    axs[-1].set_xlabel("t (s)")
    fig.tight_layout()
    save(fig, "residuals.png")

    r = idn.base.count
    fig, ax = plt.subplots(figsize=(10, 0.25 * r + 1.5))
    pct = 196.0 * idn.wls.std / np.abs(idn.wls.beta)
    ypos = np.arange(r)[::-1]
    ax.barh(ypos, np.minimum(pct, 200.0), color=np.where(pct > 100, "C3", "C0"))
    # each bar is a base parameter: a combination, named in full (report.md's table, #)
    labels = [
        f"#{k + 1} " + (e if len(e) <= 48 else e[:46] + "…")
        for k, e in enumerate(idn.base.expressions)
    ]
    ax.set_yticks(ypos, labels, fontsize=7)
    from matplotlib.patches import Patch

    ax.legend(handles=[Patch(color="C0", label="half-width ≤ 100 %"),
                       Patch(color="C3", label="> 100 %: not determined")],
              fontsize=7, loc="lower right")  # fmt: skip
    ax.set_xlabel("half-width of the 95 % interval, % of the estimate (bars capped at 200)")
    ax.set_title(f"Base parameters: how well {Path(source).name} determines each (WLS)")
    ax.set_xscale("log")
    fig.tight_layout()
    save(fig, "parameters.png")

    if validation is not None:
        vo = validation["observation"]
        fig, axs = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
        for a, (ax, (name, unit)) in enumerate(zip(axs, _AXES, strict=True)):
            ax.plot(vo.t, vo.y[:, a], color="0.2", lw=1.2, label="measured")
            ax.plot(vo.t, validation["predicted"][:, a], color="C2", lw=0.9, ls="--",
                    label="predicted")  # fmt: skip
            ax.set_ylabel(f"{name} ({unit})")
        axs[0].legend(loc="upper right", fontsize=8)
        axs[0].set_title(
            f"Validation on {_tail(validation['source'])} (estimate from {_tail(source)}): "
            f"relative error {100 * validation['relative_error']:.3g} %"
        )
        axs[-1].set_xlabel("t (s)")
        fig.tight_layout()
        save(fig, "validation.png")
    return out


def _comment(text: str) -> str:
    """``text`` on one line of a TOML comment."""
    return " ".join(text.split())


def _fmt(v: float) -> str:
    return f"{v:.6g}"


def _markdown(idn: Identification, validation: dict | None, source: str) -> str:
    obs, base = idn.observation, idn.base
    n_used = obs.t.size
    lines = [
        "# Identification report",
        "",
        f"Log: `{source}`: {obs.samples_in} samples at {obs.sample_rate:g} Hz. "
        f"Used: {n_used} samples (3 equations each) after:",
        "",
    ]
    machine = idn.scenario or "the scenario given"
    lines += [f"- {why}: {k} samples discarded" for why, k in obs.discarded.items()]
    lines += [
        "",
        f"Machine (geometry, and the prior of the physical estimate): {machine}.",
        "",
        f"Pose by least-squares forward kinematics (largest residual "
        f"{obs.fk_residual:.3g} m); filters: the pose by a zero-phase Butterworth low-pass, "
        f"order 4, at {obs.diff_cutoff:g} Hz, before differentiation (it removes "
        f"{1e6 * obs.length_noise:.3g} um rms from each length, a bound on their noise; "
        f"the Coulomb columns take the limb rates filtered at {obs.rate_cutoff:.4g} Hz, "
        "as high as that noise allows); J^T tau and the "
        f"regressor by the same zero-phase FIR low-pass (Hamming window, {obs.fir_taps} "
        f"taps) at {obs.cutoff:g} Hz (parallel filtering), decimated by {obs.decimation}; "
        f"force timing: the force acting at t is the logged "
        f"one at t {'-' if obs.force_lead >= 0 else '+'} {abs(obs.force_lead):.4g} s; "
        "friction smoothing v_s = "
        f"{idn.friction_velocity:g} m/s (assumed, not identified).",
        "",
        f"**{base.count} base parameters** (of 48 standard ones), condition number of the "
        f"base observation matrix **{idn.cond:.4g}**. Identification took "
        f"{idn.seconds:.2f} s"
        + (
            f" (and {idn.compile_seconds:.1f} s more compiling kernels, once per machine)."
            if idn.compile_seconds >= 0.05
            else "."
        )
        + f" {provenance_line()}",
        "",
        "| fit | residual RMS z [N] | alpha [N m] | beta [N m] | relative error |",
        "|---|---:|---:|---:|---:|",
    ]
    fits = [("OLS", idn.ols), ("WLS", idn.wls)]
    if idn.physical_fit is not None:
        fits.append(("physically consistent", idn.physical_fit))
    for name, f in fits:
        lines.append(
            f"| {name} | {f.rms[0]:.4g} | {f.rms[1]:.4g} | {f.rms[2]:.4g} | "
            f"{100 * f.relative_error:.4g} % |"
        )
    if validation is not None:
        ea = validation["relative_error_axis"]
        lines += [
            "",
            f"**Validation** on `{validation['source']}`: predicted J^T tau against the "
            f"measured one, relative error {100 * validation['relative_error']:.4g} % "
            f"(z {100 * ea[0]:.3g} %, alpha {100 * ea[1]:.3g} %, beta {100 * ea[2]:.3g} %).",
        ]
    lines += [
        "",
        "## Base parameters",
        "",
        "Standard deviations by a delete-a-block jackknife; intervals: estimate ± 1.96 std.",
        "",
        "| # | base parameter | unit | OLS | WLS | std (%) | 95 % interval |"
        + (" physical |" if idn.physical_fit is not None else ""),
        "|---:|---|---|---:|---:|---:|---|" + ("---:|" if idn.physical_fit is not None else ""),
    ]
    for k in range(base.count):
        b, s = idn.wls.beta[k], idn.wls.std[k]
        row = (
            f"| {k + 1} | {base.expressions[k]} | {base.units[k]} | {_fmt(idn.ols.beta[k])} | "
            f"{_fmt(b)} | {idn.wls.std_percent[k]:.3g} | [{_fmt(b - 1.96 * s)}, "
            f"{_fmt(b + 1.96 * s)}] |"
        )
        if idn.physical_fit is not None:
            row += f" {_fmt(idn.physical_fit.beta[k])} |"
        lines.append(row)
    if idn.physical is not None:
        lines += [
            "",
            "## Physically consistent standard parameters",
            "",
            "Masses > 0, principal inertias satisfying the triangle inequality, rotor masses "
            "and friction >= 0. The data determine the base parameters above; this is one "
            "physically consistent vector that fits them, pulled weakly towards the prior "
            "(the scenario's controller model) in the directions the data cannot see, so a "
            "standard parameter that is not a base parameter by itself is not identified "
            "on its own"
            + (
                f"; {len(idn.active_bounds)} ended on their bounds: "
                f"{', '.join(idn.active_bounds)} (SI units; the lower bounds are 1 g and "
                "1e-7 kg·m²)"
                if idn.active_bounds
                else ""
            )
            + ". This vector is the `[controller_model]` block of `controller_model.toml`.",
            "",
            "| parameter | unit | estimate |",
            "|---|---|---:|",
        ]
        lines += [
            f"| {n} | {u} | {_fmt(v)} |"
            for n, u, v in zip(PARAMETER_NAMES, PARAMETER_UNITS, idn.physical, strict=True)
        ]
    if idn.notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in idn.notes]
    lines += [
        "",
        "Figures: `fit.png` (measured and predicted J^T tau), `residuals.png`, "
        "`parameters.png` (the width of each interval)"
        + (", `validation.png`." if validation is not None else "."),
        "",
    ]
    return "\n".join(lines)


def _tail(path: str) -> str:
    """A log's file name with its folder (two runs' logs are both pd.parquet)."""
    p = Path(path)
    return str(Path(p.parent.name) / p.name) if p.parent.name else p.name


def write_identification(
    idn: Identification, folder: Path, *, source: str, validation: dict | None = None
) -> list[Path]:
    """Write report.md, estimate.json, controller_model.toml (if there is a physically
    consistent estimate) and the figures into ``folder``; return their paths."""
    folder = Path(folder)
    paths = _figures(idn, folder, validation, source)
    report = folder / "report.md"
    with atomic_write(report) as fh:
        fh.write(_markdown(idn, validation, source))
    data = {
        "log": source,
        "scenario": idn.scenario,
        "base_parameters": [
            {
                "name": n,
                "expression": e,
                "unit": u,
                "ols": float(idn.ols.beta[k]),
                "wls": float(idn.wls.beta[k]),
                "std": float(idn.wls.std[k]),
            }
            for k, (n, e, u) in enumerate(
                zip(idn.base.names, idn.base.expressions, idn.base.units, strict=True)
            )
        ],
        "K": idn.base.K.tolist(),
        "cond": idn.cond,
        "rms_wls": idn.wls.rms.tolist(),
        "relative_error_wls": idn.wls.relative_error,
        "samples_used": int(idn.observation.t.size),
        "discarded": idn.observation.discarded,
        "force_lead": idn.observation.force_lead,
        "sample_rate": idn.observation.sample_rate,
        "cutoff": idn.observation.cutoff,
        "diff_cutoff": idn.observation.diff_cutoff,
        "fk_residual": idn.observation.fk_residual,
        "length_noise": idn.observation.length_noise,
        "rate_cutoff": idn.observation.rate_cutoff,
        "active_bounds": list(idn.active_bounds),
        "theta_ext_physical": None if idn.physical is None else idn.physical.tolist(),
        "validation_log": None if validation is None else validation["source"],
        "validation_relative_error": None if validation is None else validation["relative_error"],
    }
    data["software"] = provenance()
    est = folder / "estimate.json"
    with atomic_write(est) as fh:
        json.dump(data, fh, indent=1)
    paths = [report, est, *paths]
    if idn.physical is not None:
        cm = folder / "controller_model.toml"
        with atomic_write(cm) as fh:
            fh.write(
                f"# The identified model (pkmctl identify) from {_comment(source)}\n"
                f"# on {_comment(idn.scenario or 'the scenario given')}.\n"
                "# Replace a scenario's whole [controller_model] table with this one (every\n"
                "# scenario pkmctl scenario prints has one; theta_ext sets what its other\n"
                "# keys would, and TOML refuses a table declared twice):\n"
                "# Theta_ext = [Theta (36), m_r (4, kg), F_c (4, N), F_v (4, N s/m)]\n"
            )
            fh.write(tomli_w.dumps({"controller_model": idn.controller_model()}))
        paths.insert(2, cm)
    return paths
