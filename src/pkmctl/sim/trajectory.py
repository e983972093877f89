"""Reference trajectories X_d(t) with their first two derivatives.

The paper's trajectory (eq. 54) is a sinusoid per coordinate:
alpha = pi/6 sin 2t, beta = pi/6 cos 2t, z = 0.7 + 0.02 sin 2t. An exciting trajectory
for identification (DESIGN.md §9, ``pkmctl excite``) is a finite Fourier series per
coordinate (Swevers et al. 1997).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TRAJECTORIES", "Fourier", "Sinusoid", "paper_trajectory"]


@dataclass(frozen=True)
class Sinusoid:
    """X_d,i(t) = offset_i + amplitude_i sin(omega_i t + phase_i), per coordinate [z, alpha, beta].

    Units: offset and amplitude in m / rad, omega in rad/s, phase in rad.
    """

    offset: tuple[float, float, float]
    amplitude: tuple[float, float, float]
    omega: tuple[float, float, float]
    phase: tuple[float, float, float]

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """X_d, Xdot_d, Xddot_d at times t (N,), each of shape (N, 3)."""
        t = np.asarray(t, dtype=float).reshape(-1, 1)
        c, a, w, p = (
            np.asarray(v, dtype=float)
            for v in (self.offset, self.amplitude, self.omega, self.phase)
        )
        arg = w * t + p
        sn, cs = np.sin(arg), np.cos(arg)
        return c + a * sn, a * w * cs, -a * w * w * sn


@dataclass(frozen=True)
class Fourier:
    """A finite Fourier series per coordinate [z, alpha, beta] (Swevers' form):

    X_i(t) = offset_i + sum_l [a_il / (w l) sin(w l t) - b_il / (w l) cos(w l t)],
    w = 2 pi ``base_frequency`` (Hz), l = 1..H; so Xdot_i = sum_l a_il cos + b_il sin.

    ``a`` and ``b`` are (3, H) in m/s or rad/s. Periodic with period 1 / base_frequency.
    """

    base_frequency: float
    offset: tuple[float, float, float]
    a: tuple[tuple[float, ...], ...]
    b: tuple[tuple[float, ...], ...]

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """X_d, Xdot_d, Xddot_d at times t (N,), each of shape (N, 3)."""
        t = np.asarray(t, dtype=float).reshape(-1)
        a, b = np.asarray(self.a, dtype=float), np.asarray(self.b, dtype=float)
        w = 2.0 * math.pi * self.base_frequency * np.arange(1, a.shape[1] + 1)  # (H,)
        arg = t[:, None] * w[None, :]  # (N, H)
        sn, cs = np.sin(arg), np.cos(arg)
        X = np.asarray(self.offset, dtype=float) + (sn @ (a / w).T) - (cs @ (b / w).T)
        Xd = cs @ a.T + sn @ b.T
        Xdd = (-sn * w) @ a.T + (cs * w) @ b.T
        return X, Xd, Xdd


def paper_trajectory() -> Sinusoid:
    """The paper's eq. 54."""
    return Sinusoid(
        offset=(0.7, 0.0, 0.0),
        amplitude=(0.02, math.pi / 6, math.pi / 6),
        omega=(2.0, 2.0, 2.0),
        phase=(0.0, 0.0, math.pi / 2),
    )


#: Name -> class registry of trajectory kinds (the ``kind`` key of a scenario's trajectory).
TRAJECTORIES: dict[str, type] = {"sinusoid": Sinusoid, "fourier": Fourier}
