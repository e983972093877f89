"""Metrics of a closed-loop :class:`~pkmctl.Result` (DESIGN.md §4, eq. 55-57).

Pure functions: a result in, numbers out. Errors are desired minus actual.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "RMSE_KEYS",
    "chattering_index",
    "gravity_mismatch",
    "max_error",
    "mean_error",
    "peak_forces",
    "rmse",
    "summary",
    "surface_gain",
]

RMSE_KEYS = ("z_mm", "alpha_deg", "beta_deg", "q1_m", "q2_m", "q3_m", "q4_m")
_SCALE = np.array([1e3, 180 / np.pi, 180 / np.pi, 1, 1, 1, 1])


def _errors(result, t_from: float = 0.0) -> np.ndarray:
    """(N, 7) errors [z (mm), alpha (deg), beta (deg), q1..q4 (m)] from t_from on."""
    sel = result.t >= t_from - 1e-12
    e = np.hstack([result.X_desired - result.X, result.q_desired - result.q])[sel]
    return e * _SCALE


def rmse(result, *, t_from: float = 0.0) -> dict[str, float]:
    """RMSE over the control samples at t >= t_from (eq. 55-57; Table 4's units)."""
    e = _errors(result, t_from)
    if e.shape[0] == 0:
        raise ValueError(f"t_from = {t_from}: no samples after it")
    return dict(zip(RMSE_KEYS, np.sqrt(np.mean(e**2, axis=0)).tolist(), strict=True))


def max_error(result, *, t_from: float = 0.0) -> dict[str, float]:
    """Largest |error| at t >= t_from, same keys and units as :func:`rmse`."""
    e = _errors(result, t_from)
    return dict(zip(RMSE_KEYS, np.max(np.abs(e), axis=0).tolist(), strict=True))


def chattering_index(result) -> np.ndarray:
    """Mean |tau_a(k) - tau_a(k-1)| per second of each actuator (N/s), shape (4,)."""
    d = np.abs(np.diff(result.tau, axis=0))
    duration = result.t[-1] - result.t[0] if result.t.size > 1 else np.nan
    return d.sum(axis=0) / duration


def peak_forces(result) -> np.ndarray:
    """max |tau_a| of each actuator over the run (N), shape (4,)."""
    return np.max(np.abs(result.tau), axis=0)


def summary(result) -> dict:
    """All metrics of one run, JSON-ready."""
    return {
        "rmse": rmse(result),
        "rmse_after_1s": rmse(result, t_from=1.0) if result.t[-1] >= 1.0 else None,
        "max_error": max_error(result),
        "chattering_N_per_s": chattering_index(result).tolist(),
        "peak_force_N": peak_forces(result).tolist(),
    }


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
    """G(X) - G^(X) at the trajectory's offset pose: what the controller model misses (3,)."""
    X = np.asarray(scenario.trajectory.offset, dtype=float)
    return scenario.plant().gravity(X) - scenario.controller_mechanism().gravity(X)


def mean_error(result, *, t_from: float = 0.0) -> dict[str, float]:
    """Mean (signed) error at t >= t_from, same keys and units as :func:`rmse`."""
    e = _errors(result, t_from)
    return dict(zip(RMSE_KEYS, np.mean(e, axis=0).tolist(), strict=True))
