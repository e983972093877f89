"""Base parameters of the extended model (DESIGN.md §9): the identifiable combinations.

Jᵀτ = W(X, Xdot, Xddot) Θ_ext with W the extended regressor (3, 48) of DESIGN.md §7 and
Θ_ext = [Θ (36), m_r (4), F_c (4), F_v (4)]. Some columns of W are zero or linear
combinations of others at every state, so only r combinations β = K Θ_ext (the base
parameters) can be found from data: W Θ_ext = W_b β for every state, W_b the r
independent columns. They are found numerically (Gautier 1990): W stacked over random
states, its columns scaled to unit norm, QR with column pivoting; the rank r is where
|R_ii| / |R_00| falls below ``tol``, the pivoted first r columns are the independent ones
and the others are expressed in them through R_11⁻¹ R_12.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from pkmctl.model.machine import N_THETA_EXT
from pkmctl.model.mechanism import Mechanism

__all__ = ["PARAMETER_NAMES", "PARAMETER_UNITS", "BaseParameters", "base_parameters"]

_BODIES = ("platform", *(f"lower{i}" for i in range(1, 5)), *(f"upper{i}" for i in range(1, 5)))

#: Names of the 48 standard parameters, in the order of Θ_ext.
PARAMETER_NAMES: tuple[str, ...] = (
    *(f"{q}_{b}" for b in _BODIES for q in ("m", "Ixx", "Iyy", "Izz")),
    *(f"m_r{i}" for i in range(1, 5)),
    *(f"Fc{i}" for i in range(1, 5)),
    *(f"Fv{i}" for i in range(1, 5)),
)
#: Units of the 48 standard parameters.
PARAMETER_UNITS: tuple[str, ...] = (
    *(u for _ in _BODIES for u in ("kg", "kg m^2", "kg m^2", "kg m^2")),
    *("kg",) * 4,
    *("N",) * 4,
    *("N s/m",) * 4,
)

#: Workspace the random states are drawn from: z (m), |alpha|, |beta| (rad).
_Z_RANGE = (0.62, 0.78)
_ANGLE = 0.5


@dataclass(frozen=True, eq=False)
class BaseParameters:
    """The r identifiable combinations β = K Θ_ext of the 48 standard parameters.

    ``independent`` (r,): the standard parameters whose columns of W are kept, so
    W_b = W[..., independent]; ``K`` (r, 48); ``names`` (r,): for each, the standard
    parameter it starts with; ``expressions`` (r,): "m_platform + 2·m_upper1 + ...";
    ``units`` (r,); ``rank_gap``: |R_rr| / |R_r-1,r-1| of the scaled QR (small: a clean
    rank decision).
    """

    independent: np.ndarray
    K: np.ndarray
    names: tuple[str, ...]
    expressions: tuple[str, ...]
    units: tuple[str, ...]
    rank_gap: float

    @property
    def count(self) -> int:
        return int(self.independent.size)

    def base(self, theta_ext: np.ndarray) -> np.ndarray:
        """β (r,) of a standard parameter vector Θ_ext (48,)."""
        return self.K @ np.asarray(theta_ext, dtype=float)

    def reduce(self, W: np.ndarray) -> np.ndarray:
        """W_b (..., r) from an extended regressor W (..., 48)."""
        return W[..., self.independent]

    def table(self) -> str:
        """One line per base parameter: index, name, unit, expression."""
        width = max(len(n) for n in self.names)
        return "\n".join(
            f"{k + 1:3d}  {n:<{width}}  [{u}]  {e}"
            for k, (n, u, e) in enumerate(
                zip(self.names, self.units, self.expressions, strict=True)
            )
        )


def random_states(
    mechanism: Mechanism, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n valid poses (cond J < 100) in the workspace, with random rates and accelerations."""
    X = np.empty((0, 3))
    while X.shape[0] < n:
        cand = np.column_stack(
            [
                rng.uniform(*_Z_RANGE, 2 * n),
                rng.uniform(-_ANGLE, _ANGLE, 2 * n),
                rng.uniform(-_ANGLE, _ANGLE, 2 * n),
            ]
        )
        ok = mechanism.condition_number(cand) < 100.0
        X = np.vstack([X, cand[ok]])
    X = X[:n]
    Xd = rng.uniform(-1, 1, (n, 3)) * np.array([0.1, 1.0, 1.0])
    Xdd = rng.uniform(-1, 1, (n, 3)) * np.array([1.0, 10.0, 10.0])
    return X, Xd, Xdd


def base_parameters(
    mechanism: Mechanism,
    friction_velocity: float = 1e-3,
    *,
    n_states: int = 300,
    seed: int = 0,
    tol: float = 1e-8,
) -> BaseParameters:
    """The base parameters of ``mechanism``'s extended model (its geometry only).

    ``friction_velocity`` is v_s of the smooth sign (m/s); ``n_states`` random states
    (seeded) are stacked; a scaled pivot |R_ii| / |R_00| below ``tol`` ends the rank.
    """
    rng = np.random.default_rng(seed)
    X, Xd, Xdd = random_states(mechanism, n_states, rng)
    W = mechanism.extended_regressor(X, Xd, Xd, Xdd, friction_velocity).reshape(-1, N_THETA_EXT)
    norms = np.linalg.norm(W, axis=0)
    live = norms > 1e-12 * norms.max()  # columns of round-off only (1e-33) are zero columns
    scale = np.where(live, norms, 1.0)
    _, R, piv = scipy.linalg.qr(np.where(live, W / scale, 0.0), mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    r = int(np.sum(d > tol * d[0]))
    gap = float(d[r] / d[r - 1]) if r < d.size else 0.0
    P1, P2 = piv[:r], piv[r:]
    Bn = scipy.linalg.solve_triangular(R[:r, :r], R[:r, r:])  # scaled dependencies
    B = Bn * scale[P2][None, :] / scale[P1][:, None]
    B[np.abs(B) < 1e-9 * max(1.0, np.abs(B).max(initial=0.0))] = 0.0
    # Natural order: the base parameters sorted by their leading standard parameter.
    order = np.argsort(P1)
    P1, B = P1[order], B[order]
    K = np.zeros((r, N_THETA_EXT))
    K[np.arange(r), P1] = 1.0
    K[:, P2] = B
    names = tuple(PARAMETER_NAMES[j] for j in P1)
    units = tuple(PARAMETER_UNITS[j] for j in P1)
    exprs = []
    for k in range(r):
        terms = [PARAMETER_NAMES[P1[k]]]
        for j in np.flatnonzero(K[k]):
            if j == P1[k]:
                continue
            c = K[k, j]
            sign = "-" if c < 0 else "+"
            mag = abs(c)
            coef = "" if abs(mag - 1.0) < 1e-12 else f"{mag:.6g}·"
            terms.append(f"{sign} {coef}{PARAMETER_NAMES[j]}")
        exprs.append(" ".join(terms))
    return BaseParameters(P1.copy(), K, names, tuple(exprs), units, gap)
