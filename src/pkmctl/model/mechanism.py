"""The mechanism: geometry and the 9 bodies of the 2RPU-2SPR manipulator (DESIGN.md §1).

:class:`Mechanism` is frozen data plus methods that call the compiled kernels of
:mod:`pkmctl.model.kinematics` and :mod:`pkmctl.model.dynamics`. Every method takes one pose
``X`` of shape (3,) or a batch of shape (N, 3) and returns the matching shape:
``(...)`` for one pose, ``(N, ...)`` for a batch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from pkmctl._jit import kernel
from pkmctl.errors import ConvergenceError, InvalidPoseError
from pkmctl.model.dynamics import (
    N_THETA,
    actuator_forces_kernel,
    dynamics_kernel,
    make_work,
    regressor_kernel,
)
from pkmctl.model.kinematics import GEOM_SIZE, N_BODIES, forward_kinematics_kernel, limb_jacobian
from pkmctl.model.machine import N_THETA_EXT, extended_regressor_kernel

__all__ = ["BODY_NAMES", "Body", "Mechanism", "PAPER_TABLE2"]

BODY_NAMES = (
    "platform",
    "lower limb 1",
    "lower limb 2",
    "lower limb 3",
    "lower limb 4",
    "upper limb 1",
    "upper limb 2",
    "upper limb 3",
    "upper limb 4",
)

#: The paper's Table 2 (SI units), with the centre-of-mass distances of DESIGN.md §1
#: (l_1, l_2 place the limb centres at heights 0.22 m and 0.49 m at home, as Table 2 does).
PAPER_TABLE2: dict[str, Any] = {
    "r_a": 0.2,  # m, platform radius
    "r_b": 0.339,  # m, base radius
    "platform": {"mass": 12.75, "inertia": (0.077, 0.107, 0.183)},
    "lower_limb": {"mass": 0.95, "inertia": (2.88e-2, 2.89e-2, 0.05e-2), "com": 0.2243},
    "upper_limb": {"mass": 1.10, "inertia": (2.65e-2, 2.67e-2, 0.03e-2), "com": 0.2141},
    "g": 9.807,  # m/s^2
}

#: Largest condition number of J accepted as a valid pose.
MAX_CONDITION = 1e6
#: Smallest singular value of J accepted (m per m or per rad): below it the platform can move
#: while no limb length changes to first order (e.g. the platform flat in the base plane).
MIN_SINGULAR_VALUE = 1e-6
#: Shortest limb accepted as a valid pose (m): below it u_i is ill-defined.
MIN_LIMB_LENGTH = 1e-3


@dataclass(frozen=True)
class Body:
    """A rigid body: mass (kg) and principal inertia (I_xx, I_yy, I_zz) in its frame (kg m^2)."""

    mass: float
    inertia: tuple[float, float, float]

    def as_theta(self) -> np.ndarray:
        """Theta_b = [m, I_xx, I_yy, I_zz], shape (4,)."""
        return np.array([self.mass, *self.inertia], dtype=float)


def _check_theta(theta: np.ndarray, *, physical: bool) -> None:
    if theta.shape != (N_THETA,):
        raise ValueError(f"theta: expected shape ({N_THETA},), got {theta.shape}")
    if not np.all(np.isfinite(theta)):
        raise ValueError("theta: must be finite")
    for b in range(N_BODIES):
        m, ixx, iyy, izz = theta[4 * b : 4 * b + 4]
        name = BODY_NAMES[b]
        if m <= 0:
            raise ValueError(f"theta[{4 * b}] ({name} mass) = {m}: must be > 0")
        for k, ik in enumerate((ixx, iyy, izz)):
            if ik <= 0:
                raise ValueError(f"theta[{4 * b + 1 + k}] ({name} inertia) = {ik}: must be > 0")
        if physical:
            tol = 1e-12 * (ixx + iyy + izz)
            if ixx + iyy < izz - tol or iyy + izz < ixx - tol or izz + ixx < iyy - tol:
                raise ValueError(
                    f"theta[{4 * b + 1}:{4 * b + 4}] ({name} inertia) = "
                    f"({ixx}, {iyy}, {izz}): must satisfy the triangle inequality "
                    "I_a + I_b >= I_c"
                )


@dataclass(frozen=True, eq=False)
class Mechanism:
    """The 2RPU-2SPR manipulator: geometry and inertial parameters (DESIGN.md §1).

    Parameters
    ----------
    r_a, r_b : float
        Platform and base radii (m), ``0 < r_a < r_b``.
    l1, l2 : ndarray, shape (4,)
        Distance of the lower-limb centre of mass from its base joint and of the
        upper-limb centre of mass from its platform joint, per limb (m).
    theta : ndarray, shape (36,)
        Inertial parameters ``[Theta_0 ... Theta_8]``, ``Theta_b = [m, I_xx, I_yy, I_zz]``
        in the body order of :data:`BODY_NAMES`.
    g : float
        Gravitational acceleration (m/s^2), along -z.

    Use :meth:`paper` for the paper's machine and :meth:`from_bodies` to build another.
    """

    r_a: float
    r_b: float
    l1: np.ndarray
    l2: np.ndarray
    theta: np.ndarray
    g: float = 9.807
    _geom: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        l1 = np.array(self.l1, dtype=float).reshape(-1)
        l2 = np.array(self.l2, dtype=float).reshape(-1)
        theta = np.array(self.theta, dtype=float).reshape(-1)
        for name, val in (("r_a", self.r_a), ("r_b", self.r_b), ("g", self.g)):
            if not (isinstance(val, int | float) and math.isfinite(val)):
                raise ValueError(f"{name} = {val!r}: must be a finite number")
        if not 0 < self.r_a < self.r_b:
            raise ValueError(f"r_a = {self.r_a}, r_b = {self.r_b}: need 0 < r_a < r_b")
        if self.g < 0:
            raise ValueError(f"g = {self.g}: must be >= 0")
        for name, arr in (("l1", l1), ("l2", l2)):
            if arr.shape != (4,) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(f"{name} = {arr}: need 4 finite distances >= 0 (m)")
        _check_theta(theta, physical=True)
        for arr in (l1, l2, theta):
            arr.setflags(write=False)
        object.__setattr__(self, "l1", l1)
        object.__setattr__(self, "l2", l2)
        object.__setattr__(self, "theta", theta)
        geom = np.concatenate([[self.r_a, self.r_b], l1, l2, [self.g]]).astype(float)
        assert geom.shape == (GEOM_SIZE,)
        geom.setflags(write=False)
        object.__setattr__(self, "_geom", geom)

    # ------------------------------------------------------------------ construction
    @classmethod
    def paper(cls) -> Mechanism:
        """The paper's manipulator (Table 2, DESIGN.md §1)."""
        t = PAPER_TABLE2
        return cls.from_bodies(
            r_a=t["r_a"],
            r_b=t["r_b"],
            platform=Body(t["platform"]["mass"], t["platform"]["inertia"]),
            lower_limb=Body(t["lower_limb"]["mass"], t["lower_limb"]["inertia"]),
            upper_limb=Body(t["upper_limb"]["mass"], t["upper_limb"]["inertia"]),
            l1=t["lower_limb"]["com"],
            l2=t["upper_limb"]["com"],
            g=t["g"],
        )

    @classmethod
    def from_bodies(
        cls,
        *,
        r_a: float,
        r_b: float,
        platform: Body,
        lower_limb: Body | list[Body],
        upper_limb: Body | list[Body],
        l1: float | list[float],
        l2: float | list[float],
        g: float = 9.807,
    ) -> Mechanism:
        """Build a mechanism from its bodies; one limb Body or distance is used for all four."""
        lower = [lower_limb] * 4 if isinstance(lower_limb, Body) else list(lower_limb)
        upper = [upper_limb] * 4 if isinstance(upper_limb, Body) else list(upper_limb)
        if len(lower) != 4 or len(upper) != 4:
            raise ValueError("lower_limb, upper_limb: need one Body or a list of 4")
        theta = np.concatenate([b.as_theta() for b in [platform, *lower, *upper]])
        return cls(
            r_a=float(r_a),
            r_b=float(r_b),
            l1=np.broadcast_to(np.asarray(l1, dtype=float), (4,)),
            l2=np.broadcast_to(np.asarray(l2, dtype=float), (4,)),
            theta=theta,
            g=float(g),
        )

    def with_theta(self, theta: np.ndarray, *, physical: bool = True) -> Mechanism:
        """The same geometry with other inertial parameters ``theta`` (36,).

        ``physical=False`` skips the triangle-inequality check (positivity is always
        checked), e.g. for an adaptive estimate.
        """
        theta = np.array(theta, dtype=float).reshape(-1)
        _check_theta(theta, physical=physical)
        new = object.__new__(Mechanism)
        for name in ("r_a", "r_b", "l1", "l2", "g", "_geom"):
            object.__setattr__(new, name, getattr(self, name))
        theta.setflags(write=False)
        object.__setattr__(new, "theta", theta)
        return new

    @property
    def geometry(self) -> np.ndarray:
        """The geometry vector of the compiled kernels, shape (11,), read-only."""
        return self._geom

    @property
    def home(self) -> np.ndarray:
        """Home pose [0.7, 0, 0] (DESIGN.md §1)."""
        return np.array([0.7, 0.0, 0.0])

    def __repr__(self) -> str:
        return (
            f"Mechanism(r_a={self.r_a}, r_b={self.r_b}, mass={self.total_mass:.3f} kg, "
            f"l1={self.l1.tolist()}, l2={self.l2.tolist()})"
        )

    @property
    def total_mass(self) -> float:
        return float(self.theta[0::4].sum())

    # ------------------------------------------------------------------ kinematics
    def check_pose(self, X: ArrayLike) -> None:
        """Raise :class:`InvalidPoseError` unless every pose of X (3,) or (N, 3) is valid."""
        Xb, _ = _as_batch(X, "X")
        _check_poses(self._geom, Xb)

    def inverse_kinematics(self, X: ArrayLike) -> np.ndarray:
        """Limb lengths q (4,) or (N, 4) of pose(s) X (eq. 4)."""
        Xb, single = _as_batch(X, "X")
        q, _ = _check_poses(self._geom, Xb)
        return q[0] if single else q

    def jacobian(self, X: ArrayLike) -> np.ndarray:
        """Limb Jacobian J = dq/dX (4, 3) or (N, 4, 3), with qdot = J Xdot (eq. 8)."""
        Xb, single = _as_batch(X, "X")
        _, J = _check_poses(self._geom, Xb)
        return J[0] if single else J

    def condition_number(self, X: ArrayLike) -> np.ndarray | float:
        """2-norm condition number of J (sigma_max / sigma_min), float or (N,)."""
        Xb, single = _as_batch(X, "X")
        _check_basic(Xb)
        q, J = limbs_batch(self._geom, Xb)
        c = np.linalg.cond(J)
        return float(c[0]) if single else c

    def checked_condition_numbers(self, X: ArrayLike) -> np.ndarray:
        """:meth:`check_pose` and :meth:`condition_number` of poses X (N, 3) in one pass
        (one SVD per pose, not two): raises as :meth:`check_pose`, else returns (N,)."""
        Xb, _ = _as_batch(X, "X")
        return _checked_poses(self._geom, Xb)[2]

    def forward_kinematics(
        self,
        q: ArrayLike,
        guess: ArrayLike | None = None,
        *,
        tol: float = 1e-12,
        max_iter: int = 100,
        least_squares: bool = False,
    ) -> np.ndarray:
        """Pose X (3,) or (N, 3) whose limb lengths are q (4,) or (N, 4).

        Levenberg-Marquardt over the four lengths from ``guess`` (home by default).
        Raises :class:`pkmctl.errors.ConvergenceError` naming the residual when the
        lengths are not reached to ``tol`` (m) within ``max_iter`` iterations.

        Four lengths over-determine three coordinates, and measured ones (an encoder's
        counts, 62.5 nm on the prototype: DESIGN.md §7) fit no pose exactly: with
        ``least_squares=True`` X is the pose nearest them, min |q(X) - q|, accepted where
        a Gauss-Newton step is below 1e-10 (m, rad) instead of at a residual under
        ``tol``; the residual, ``inverse_kinematics(X) - q``, is the lengths'
        inconsistency and yours to judge. Without it, lengths that no pose has are refused
        as such, with the nearest pose's residual (they read "did not converge", at a
        converged least-squares pose: a tester's 200 of 200 rounded length sets).
        """
        qa = np.asarray(q, dtype=float)
        single = qa.ndim == 1
        qb = np.atleast_2d(qa)
        if qb.ndim != 2 or qb.shape[1] != 4:
            raise ValueError(f"q: expected shape (4,) or (N, 4), got {qa.shape}")
        if not np.all(np.isfinite(qb)) or np.any(qb <= 0):
            raise ValueError("q: limb lengths must be finite and > 0")
        if not (isinstance(tol, int | float | np.floating) and 0 < tol < math.inf):
            raise ValueError(f"tol = {tol!r}: must be a finite number > 0 (m)")
        if isinstance(max_iter, bool) or not isinstance(max_iter, int | np.integer) or max_iter < 1:
            raise ValueError(f"max_iter = {max_iter!r}: must be an integer >= 1")
        g = self.home if guess is None else np.asarray(guess, dtype=float)
        g2 = np.atleast_2d(g)
        if g2.ndim != 2 or g2.shape[1] != 3 or g2.shape[0] not in (1, qb.shape[0]):
            raise ValueError(
                f"guess: expected shape (3,) or ({qb.shape[0]}, 3) as q, got {np.shape(g)}"
            )
        gb = np.broadcast_to(g2, (qb.shape[0], 3))
        try:
            _check_basic(gb)
        except InvalidPoseError as exc:
            raise InvalidPoseError(f"guess: {exc}".replace("guess: X", "guess")) from None
        out = np.empty((qb.shape[0], 3))
        for n in range(qb.shape[0]):
            X, res, it = forward_kinematics_kernel(
                self._geom, qb[n].copy(), gb[n].copy(), tol, max_iter
            )
            if not res < tol:
                # at the nearest pose (a minimum of |r|^2, where LM stops finding a lower
                # cost), or stopped on the way to it: a Gauss-Newton step tells which
                qx, J = limbs_batch(self._geom, X[None, :])
                Jn = J[0]
                step = np.linalg.solve(Jn.T @ Jn, Jn.T @ (qx[0] - qb[n]))
                nearest = bool(np.abs(step).max() <= _FK_STEP)
                if least_squares and nearest:
                    out[n] = X - step
                    continue
                if nearest and res <= 16 * np.finfo(float).eps * np.abs(qb[n]).max():
                    out[n] = X  # reached to rounding: a tol below it cannot be met
                    continue
                if nearest:
                    raise ConvergenceError(
                        f"no pose has the limb lengths q = {qb[n].tolist()}: the nearest "
                        f"misses them by {res:.3e} m (tol {tol:g} m); for measured or "
                        "rounded lengths, forward_kinematics(q, least_squares=True) gives "
                        "that pose",
                        residual=float(res),
                    )
                raise ConvergenceError(
                    f"forward kinematics did not converge for q = {qb[n].tolist()}: "
                    f"residual {res:.3e} m after {it} iterations (tol {tol:g} m)",
                    residual=float(res),
                )
            out[n] = X
        _check_poses(self._geom, out)
        return out[0] if single else out

    # ------------------------------------------------------------------ dynamics
    def mass_matrix(self, X: ArrayLike) -> np.ndarray:
        """Mass matrix M(X), (3, 3) or (N, 3, 3)."""
        Xb, single = _as_batch(X, "X")
        _check_poses(self._geom, Xb)
        M, _, _ = _dynamics_batch(self._geom, self.theta, Xb, np.zeros_like(Xb))
        return M[0] if single else M

    def coriolis_matrix(self, X: ArrayLike, Xdot: ArrayLike) -> np.ndarray:
        """Coriolis/centrifugal matrix C(X, Xdot), (3, 3) or (N, 3, 3); Mdot - 2C is skew."""
        Xb, single = _as_batch(X, "X")
        Xdb = _like(Xdot, Xb, "Xdot")
        _check_poses(self._geom, Xb)
        _, C, _ = _dynamics_batch(self._geom, self.theta, Xb, Xdb)
        return C[0] if single else C

    def gravity(self, X: ArrayLike) -> np.ndarray:
        """Gravity vector G(X) = dV/dX, (3,) or (N, 3)."""
        Xb, single = _as_batch(X, "X")
        _check_poses(self._geom, Xb)
        _, _, G = _dynamics_batch(self._geom, self.theta, Xb, np.zeros_like(Xb))
        return G[0] if single else G

    def inverse_dynamics(self, X: ArrayLike, Xdot: ArrayLike, Xddot: ArrayLike) -> np.ndarray:
        """M Xddot + C Xdot + G, (3,) or (N, 3): the force F the plant needs (no disturbance)."""
        Xb, single = _as_batch(X, "X")
        Xdb, Xddb = _like(Xdot, Xb, "Xdot"), _like(Xddot, Xb, "Xddot")
        _check_poses(self._geom, Xb)
        F = _inverse_dynamics_batch(self._geom, self.theta, Xb, Xdb, Xddb)
        return F[0] if single else F

    def regressor(
        self, X: ArrayLike, Xdot: ArrayLike, Xr_dot: ArrayLike, Xr_ddot: ArrayLike
    ) -> np.ndarray:
        """Regressor Y (3, 36) or (N, 3, 36): Y Theta = M Xr_ddot + C(X, Xdot) Xr_dot + G."""
        Xb, single = _as_batch(X, "X")
        args = [
            _like(a, Xb, n) for a, n in ((Xdot, "Xdot"), (Xr_dot, "Xr_dot"), (Xr_ddot, "Xr_ddot"))
        ]
        _check_poses(self._geom, Xb)
        Y = _regressor_batch(self._geom, Xb, *args)
        return Y[0] if single else Y

    def extended_regressor(
        self,
        X: ArrayLike,
        Xdot: ArrayLike,
        Xr_dot: ArrayLike,
        Xr_ddot: ArrayLike,
        friction_velocity: float = 1e-3,
    ) -> np.ndarray:
        """Extended regressor Y_ext (3, 48) or (N, 3, 48) of DESIGN.md §7.

        Y_ext Theta_ext = M Xr_ddot + C(X, Xdot) Xr_dot + G
        + J^T diag(m_r) (J Xr_ddot + Jdot Xr_dot) + J^T (F_c tanh(qdot / v_s) + F_v qdot),
        qdot = J Xdot, with Theta_ext = [Theta (36), m_r (4, kg), F_c (4, N), F_v (4, N s/m)]
        and v_s = ``friction_velocity`` (m/s).
        """
        if not (isinstance(friction_velocity, int | float) and 0 < friction_velocity < math.inf):
            raise ValueError(
                f"friction_velocity = {friction_velocity!r}: must be a finite number > 0 (m/s)"
            )
        Xb, single = _as_batch(X, "X")
        args = [
            _like(a, Xb, n) for a, n in ((Xdot, "Xdot"), (Xr_dot, "Xr_dot"), (Xr_ddot, "Xr_ddot"))
        ]
        _check_poses(self._geom, Xb)
        Y = extended_regressor_batch(self._geom, Xb, *args, float(friction_velocity))
        return Y[0] if single else Y

    def actuator_forces(self, X: ArrayLike, F: ArrayLike) -> np.ndarray:
        """Minimum-norm actuator forces tau_a = J (J^T J)^-1 F, (4,) or (N, 4)."""
        Xb, single = _as_batch(X, "X")
        Fb = _like(F, Xb, "F")
        _, J = _check_poses(self._geom, Xb)
        tau = np.empty((Xb.shape[0], 4))
        for n in range(Xb.shape[0]):
            actuator_forces_kernel(J[n], Fb[n], tau[n])
        return tau[0] if single else tau


# ---------------------------------------------------------------------- helpers
def _as_batch(X, name: str) -> tuple[np.ndarray, bool]:
    a = np.asarray(X, dtype=float)
    if a.ndim == 1 and a.shape == (3,):
        return a.reshape(1, 3), True
    if a.ndim == 2 and a.shape[1] == 3:
        return np.ascontiguousarray(a), False
    raise ValueError(f"{name}: expected shape (3,) or (N, 3), got {a.shape}")


def _like(V, Xb: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(V, dtype=float)
    if a.shape == (3,):
        a = np.broadcast_to(a, Xb.shape)
    if a.shape != Xb.shape:
        raise ValueError(f"{name}: expected shape {Xb.shape[1:] if len(Xb) == 1 else Xb.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: must be finite")
    return np.ascontiguousarray(a)


def _check_basic(Xb: np.ndarray) -> None:
    if not np.all(np.isfinite(Xb)):
        raise InvalidPoseError("X: pose must be finite")
    bad = np.flatnonzero(Xb[:, 0] <= 0)
    if bad.size:
        raise InvalidPoseError(f"X[{bad[0]}]: z = {Xb[bad[0], 0]} m, the valid range is z > 0")
    for k, name in ((1, "alpha"), (2, "beta")):
        bad = np.flatnonzero(np.abs(Xb[:, k]) >= np.pi / 2)
        if bad.size:
            raise InvalidPoseError(
                f"X[{bad[0]}]: {name} = {Xb[bad[0], k]} rad, the valid range is |{name}| < pi/2"
            )


def _check_poses(geom: np.ndarray, Xb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate a batch of poses; return their limb lengths (N, 4) and Jacobians (N, 4, 3)."""
    q, J, _ = _checked_poses(geom, Xb)
    return q, J


def _checked_poses(geom: np.ndarray, Xb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_check_poses`, and the condition numbers of J (N,) from the same SVD."""
    _check_basic(Xb)
    q, J = limbs_batch(geom, Xb)
    short = np.argwhere(q < MIN_LIMB_LENGTH)
    if short.size:
        n, i = short[0]
        raise InvalidPoseError(
            f"X[{n}] = {Xb[n].tolist()}: limb {i + 1} is degenerate "
            f"(q = {q[n, i]:.3g} m, need >= {MIN_LIMB_LENGTH} m)"
        )
    sv = np.linalg.svd(J, compute_uv=False)
    cond = sv[:, 0] / np.maximum(sv[:, -1], 1e-300)
    bad = np.flatnonzero(~((cond < MAX_CONDITION) & (sv[:, -1] > MIN_SINGULAR_VALUE)))
    if bad.size:
        n = bad[0]
        raise InvalidPoseError(
            f"X[{n}] = {Xb[n].tolist()}: J is near-singular (condition number {cond[n]:.3g}, "
            f"smallest singular value {sv[n, -1]:.3g}; need < {MAX_CONDITION:g} and "
            f"> {MIN_SINGULAR_VALUE:g})"
        )
    return q, J, cond


#: A Gauss-Newton step (m, rad) under which :meth:`Mechanism.forward_kinematics` takes a
#: pose for the lengths' least-squares one. Levenberg-Marquardt stops where the cost, of
#: order (1e-8 m)^2 for rounded lengths, no longer falls in its last bits: up to 6e-13
#: from the minimum in 200 sets of the prototype's rounded lengths.
_FK_STEP = 1e-10


@kernel
def limbs_batch(geom, Xb):
    n = Xb.shape[0]
    q = np.empty((n, 4))
    J = np.empty((n, 4, 3))
    R = np.empty((3, 3))
    for k in range(n):
        limb_jacobian(geom, Xb[k], R, J[k], q[k])
    return q, J


@kernel
def _dynamics_batch(geom, theta, Xb, Xdb):
    n = Xb.shape[0]
    M = np.empty((n, 3, 3))
    C = np.empty((n, 3, 3))
    G = np.empty((n, 3))
    work = make_work()
    e = np.zeros(3)
    Cv = np.empty(3)
    for k in range(n):
        for j in range(3):  # C column by column: C e_j
            e[:] = 0.0
            e[j] = 1.0
            dynamics_kernel(geom, theta, Xb[k], Xdb[k], e, work, M[k], Cv, G[k])
            C[k, :, j] = Cv
    return M, C, G


@kernel
def _inverse_dynamics_batch(geom, theta, Xb, Xdb, Xddb):
    n = Xb.shape[0]
    F = np.empty((n, 3))
    work = make_work()
    M, Cv, G = np.empty((3, 3)), np.empty(3), np.empty(3)
    for k in range(n):
        dynamics_kernel(geom, theta, Xb[k], Xdb[k], Xdb[k], work, M, Cv, G)
        for i in range(3):
            F[k, i] = M[i, 0] * Xddb[k, 0] + M[i, 1] * Xddb[k, 1] + M[i, 2] * Xddb[k, 2]
            F[k, i] += Cv[i] + G[i]
    return F


@kernel
def _regressor_batch(geom, Xb, Xdb, Xrdb, Xrddb):
    n = Xb.shape[0]
    Y = np.empty((n, 3, N_THETA))
    work = make_work()
    for k in range(n):
        regressor_kernel(geom, Xb[k], Xdb[k], Xrdb[k], Xrddb[k], work, Y[k])
    return Y


@kernel
def extended_regressor_batch(geom, Xb, Xdb, Xrdb, Xrddb, vs):
    n = Xb.shape[0]
    Y = np.empty((n, 3, N_THETA_EXT))
    work = make_work()
    for k in range(n):
        extended_regressor_kernel(geom, Xb[k], Xdb[k], Xrdb[k], Xrddb[k], vs, work, Y[k])
    return Y
