"""Controller gains: Table 3 of the paper as data, our adaptation gain, and the baselines'.

The diagonal matrices are (3,) arrays over [z, alpha, beta].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

__all__ = ["BASELINE_GAINS", "TABLE3", "Gains"]

#: Table 3 of the paper (diagonals over [z, alpha, beta]); the one copy of it.
TABLE3: dict[str, list[float] | float] = {
    "lam": [50.0, 20.0, 20.0],  # lambda (1/s)
    "K": [1000.0, 200.0, 200.0],  # N s/m, N m s/rad
    "Lam": [150.0, 40.0, 40.0],  # N, N m
    "eps": 0.01,
    "Ks": [10.0, 10.0, 10.0],
    "Ksd": [0.5, 0.5, 0.5],
    "Ku": [50.0, 30.0, 30.0],  # N, N m
}

#: Defaults of the baselines (DESIGN.md §6), derived from Table 3 so that the
#: comparison is like for like:
#: - PD, F = K_p e + K_d edot + G^(X): K_d = K and K_p = lambda K, i.e. the SMC's linear
#:   term K s without its model feedforward and switching (N/m, N m/rad; N s/m, ...).
#: - CTC, F = M^(Xddot_d + K_d edot + K_p e) + C^ Xdot + G^: the error dynamics
#:   e'' + K_d e' + K_p e = 0 with a double pole at -lambda: K_p = lambda^2 (1/s^2),
#:   K_d = 2 lambda (1/s).
BASELINE_GAINS: dict[str, list[float]] = {
    "pd_kp": [50000.0, 4000.0, 4000.0],
    "pd_kd": [1000.0, 200.0, 200.0],
    "ctc_kp": [2500.0, 400.0, 400.0],
    "ctc_kd": [100.0, 40.0, 40.0],
}


def _vec3(name: str, v) -> np.ndarray:
    a = np.array(v, dtype=float).reshape(-1)
    if a.shape == (1,):
        a = np.repeat(a, 3)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} = {v!r}: need 3 finite numbers (the diagonal)")
    a.setflags(write=False)
    return a


def _default(name: str):
    return field(default_factory=lambda: np.array((TABLE3 | BASELINE_GAINS)[name]))


@dataclass(frozen=True, eq=False)
class Gains:
    """Controller gains.

    Attributes
    ----------
    lam : lambda, the sliding-surface slope (1/s), > 0.
    K : linear gain on s (N s/m, N m s/rad), >= 0.
    Lam : switching gain of the SMC (N, N m), >= 0.
    eps : boundary-layer width of sat(s / eps), in s's units (m/s on z, rad/s on the
        angles: one number for all three), > 0.
    Ks, Ksd : input scalings of the FLC for s (s/m, s/rad) and sdot (s^2/m, s^2/rad):
        the FLC's inputs are numbers without units, > 0.
    Ku : output scaling of the FLC (N, N m), >= 0.
    gamma : adaptation gain gamma of Gamma = gamma diag(Theta_0^2) (1/J), >= 0.
    filter_periods : tau_f / T_c of the sdot low-pass filter, >= 1.
    theta_bounds : (lo, hi) projection bounds of Theta^ as multiples of Theta_0,
        0 < lo <= 1 <= hi.
    pd_kp, pd_kd : the PD baseline's gains (N/m, N m/rad; N s/m, N m s/rad), >= 0.
    ctc_kp, ctc_kd : the computed-torque baseline's gains (1/s^2; 1/s), >= 0.
    """

    lam: np.ndarray = _default("lam")
    K: np.ndarray = _default("K")
    Lam: np.ndarray = _default("Lam")
    eps: float = float(TABLE3["eps"])
    Ks: np.ndarray = _default("Ks")
    Ksd: np.ndarray = _default("Ksd")
    Ku: np.ndarray = _default("Ku")
    gamma: float = 0.5
    filter_periods: float = 20.0
    theta_bounds: tuple[float, float] = (0.1, 10.0)
    pd_kp: np.ndarray = _default("pd_kp")
    pd_kd: np.ndarray = _default("pd_kd")
    ctc_kp: np.ndarray = _default("ctc_kp")
    ctc_kd: np.ndarray = _default("ctc_kd")

    def __post_init__(self) -> None:
        positive = {"lam", "Ks", "Ksd"}
        for name in ("lam", "K", "Lam", "Ks", "Ksd", "Ku", *BASELINE_GAINS):
            a = _vec3(name, getattr(self, name))
            bad = np.any(a <= 0) if name in positive else np.any(a < 0)
            if bad:
                raise ValueError(
                    f"{name} = {a.tolist()}: every entry must be "
                    f"{'> 0' if name in positive else '>= 0'}"
                )
            object.__setattr__(self, name, a)
        for name in ("eps", "gamma", "filter_periods"):
            v = getattr(self, name)
            if not isinstance(v, int | float) or not math.isfinite(v):
                raise ValueError(f"{name} = {v!r}: must be a finite number")
        if not self.eps > 0:
            raise ValueError(f"eps = {self.eps}: must be > 0")
        if self.gamma < 0:
            raise ValueError(f"gamma = {self.gamma}: must be >= 0")
        if self.filter_periods < 1:
            raise ValueError(f"filter_periods = {self.filter_periods}: must be >= 1")
        lo, hi = self.theta_bounds
        if not 0 < lo <= 1 <= hi < math.inf:
            raise ValueError(f"theta_bounds = {self.theta_bounds}: need 0 < lo <= 1 <= hi")
        object.__setattr__(self, "theta_bounds", (float(lo), float(hi)))

    @classmethod
    def paper(cls) -> Gains:
        """Table 3 of the paper, with our default gamma (the paper gives none)."""
        return cls()

    def as_dict(self) -> dict:
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = (
                v.tolist()
                if isinstance(v, np.ndarray)
                else (list(v) if isinstance(v, tuple) else v)
            )
        return out
