"""SMC, FSMC and AFSMC (DESIGN.md §3; the paper's eq. 25, 26, 46 and 50-51 corrected).

Notation: e = X_d - X, s = edot + lambda e (the sliding surface), Xr_dot = Xdot_d + lambda e,
Xr_ddot = Xddot_d + lambda edot.

- SMC   (eq. 25): F = M^ Xr_ddot + C^ Xr_dot + G^(X_d) + K s + Lambda sat(s / eps)
- FSMC  (eq. 26): F = M^ Xr_ddot + C^ Xr_dot + G^(X_d) + K s + u_f
- AFSMC (eq. 46): F = Y(X, Xdot, Xr_dot, Xr_ddot) Theta^ + K s + u_f,
  dTheta^/dt = Gamma Y^T s, projected onto [theta_min, theta_max]

with u_f,i = -K_u,i FLC(K_s,i s_i, K_sdot,i sdot_i). The minus makes the paper's rule
table (positive s -> negative output) stabilising: s^T u_f >= 0.

The controllers are discrete: :meth:`Controller.step` is one control period T_c.
sdot is estimated by the backward difference of s over one period, low-pass
filtered with time constant tau_f = ``filter_periods`` T_c (DESIGN.md §3). On the
first step there is no previous s: the difference is taken as 0.

One compiled kernel, :func:`control_step`, implements all three laws; the closed
loop calls it directly, the classes here call it for users (and a hardware loop).

Contract of a :class:`Controller` (like SciPy's ``OdeSolver``):

1. It is built from a controller model (a :class:`~pkmctl.Mechanism`, never the
   plant's), :class:`Gains` and the control period.
2. ``step(X, Xdot, X_d, Xdot_d, Xddot_d)`` returns the task-space force F (3,) and
   advances the controller's state by one period.
3. Its whole state is :attr:`Controller.state` (a copy: previous s, filtered sdot,
   Theta^, step count); :meth:`Controller.reset` restores the initial state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import ClassVar

import numpy as np

from ._jit import kernel
from .dynamics import N_THETA, WORK_SHAPES, dynamics_kernel, gravity_kernel, regressor_kernel
from .fuzzy import FLC, MamdaniSystem, flc_eval
from .kinematics import GEOM_SIZE
from .mechanism import Mechanism

__all__ = [
    "AFSMC",
    "CONTROLLERS",
    "FSMC",
    "SMC",
    "Controller",
    "ControllerState",
    "Gains",
    "adapt",
    "control_step",
    "make_controller",
    "sliding_surface",
]

KIND_SMC, KIND_FSMC, KIND_AFSMC = 0, 1, 2
#: Size of a controller's compiled memory: s_prev, sdot, started flag, then scratch.
MEM_SIZE = 16


def _vec3(name: str, v) -> np.ndarray:
    a = np.array(v, dtype=float).reshape(-1)
    if a.shape == (1,):
        a = np.repeat(a, 3)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} = {v!r}: need 3 finite numbers (the diagonal)")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Gains:
    """Controller gains; the diagonal matrices of Table 3 as (3,) arrays over [z, alpha, beta].

    Attributes
    ----------
    lam : lambda, the sliding-surface slope (1/s), > 0.
    K : linear gain on s (N s/m, N m s/rad), >= 0.
    Lam : switching gain of the SMC (N, N m), >= 0.
    eps : boundary-layer width of sat(s / eps), > 0.
    Ks, Ksd : input scalings of the FLC for s and sdot, > 0.
    Ku : output scaling of the FLC (N, N m), >= 0.
    gamma : adaptation gain gamma of Gamma = gamma diag(Theta_0^2) (1/J), >= 0.
    filter_periods : tau_f / T_c of the sdot low-pass filter, >= 1.
    theta_bounds : (lo, hi) projection bounds of Theta^ as multiples of Theta_0,
        0 < lo <= 1 <= hi.
    """

    lam: np.ndarray = field(default_factory=lambda: np.array([50.0, 20.0, 20.0]))
    K: np.ndarray = field(default_factory=lambda: np.array([1000.0, 200.0, 200.0]))
    Lam: np.ndarray = field(default_factory=lambda: np.array([150.0, 40.0, 40.0]))
    eps: float = 0.01
    Ks: np.ndarray = field(default_factory=lambda: np.array([10.0, 10.0, 10.0]))
    Ksd: np.ndarray = field(default_factory=lambda: np.array([0.5, 0.5, 0.5]))
    Ku: np.ndarray = field(default_factory=lambda: np.array([50.0, 30.0, 30.0]))
    gamma: float = 0.5
    filter_periods: float = 20.0
    theta_bounds: tuple[float, float] = (0.1, 10.0)

    def __post_init__(self) -> None:
        for name, positive in (
            ("lam", True),
            ("K", False),
            ("Lam", False),
            ("Ks", True),
            ("Ksd", True),
            ("Ku", False),
        ):
            a = _vec3(name, getattr(self, name))
            if np.any(a <= 0) if positive else np.any(a < 0):
                raise ValueError(
                    f"{name} = {a.tolist()}: every entry must be {'> 0' if positive else '>= 0'}"
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

    def matrix(self) -> np.ndarray:
        """(6, 3) array [lam, K, Lam, Ks, Ksd, Ku] for the compiled kernel."""
        return np.array([self.lam, self.K, self.Lam, self.Ks, self.Ksd, self.Ku])


@dataclass(frozen=True)
class ControllerState:
    """A snapshot of a controller's state.

    s_prev : (3,) s at the previous step; sdot : (3,) filtered sdot estimate;
    theta_hat : (36,) Theta^ (AFSMC) or None; steps : control periods taken.
    """

    s_prev: np.ndarray
    sdot: np.ndarray
    theta_hat: np.ndarray | None
    steps: int


@kernel(inline="always")
def sliding_surface(lam, X, Xd, Xdes, Xddes, Xdddes, s, xr_d, xr_dd):
    """Fill s = edot + lam e, Xr_dot = Xdot_d + lam e, Xr_ddot = Xddot_d + lam edot (3,)."""
    for i in range(3):
        e = Xdes[i] - X[i]
        ed = Xddes[i] - Xd[i]
        s[i] = ed + lam[i] * e
        xr_d[i] = Xddes[i] + lam[i] * e
        xr_dd[i] = Xdddes[i] + lam[i] * ed


@kernel(inline="always")
def adapt(theta_hat, Y, s, Tc, gamma_vec, th_min, th_max):
    """One period of dTheta^/dt = Gamma Y^T s (explicit Euler), projected onto the bounds.

    The paper's eq. 50-51 have the sign and the derivative wrong (DESIGN.md §3).
    """
    for k in range(theta_hat.shape[0]):
        upd = 0.0
        for i in range(Y.shape[0]):
            upd += Y[i, k] * s[i]
        v = theta_hat[k] + Tc * gamma_vec[k] * upd
        theta_hat[k] = min(th_max[k], max(th_min[k], v))


@kernel(inline="always", refcount=False)
def control_step(
    kind,
    geom,
    theta_model,
    gains,
    eps,
    flc_tables,
    Tc,
    alpha_f,
    X,
    Xd,
    Xdes,
    Xddes,
    Xdddes,
    mem,
    theta_hat,
    gamma_vec,
    th_min,
    th_max,
    work,
    M,
    C,
    G,
    Y,
    F,
):
    """One control period of SMC (kind 0), FSMC (1) or AFSMC (2); fills F (3,).

    ``mem`` (16,) holds [s_prev (3), sdot (3), started, then scratch]; ``theta_hat``
    (36,) is updated in place by the AFSMC's projected adaptive law (explicit Euler).
    ``gains`` (6, 3) = [lam, K, Lam, Ks, Ksd, Ku].
    """
    s, xr_d, xr_dd = mem[7:10], mem[10:13], mem[13:16]
    sliding_surface(gains[0], X, Xd, Xdes, Xddes, Xdddes, s, xr_d, xr_dd)
    # sdot: backward difference over one period, then first-order low-pass (DESIGN.md §3)
    for i in range(3):
        raw = (s[i] - mem[i]) / Tc if mem[6] > 0.0 else 0.0
        mem[3 + i] += alpha_f * (raw - mem[3 + i])
        mem[i] = s[i]
    mem[6] = 1.0
    if kind == 2:
        regressor_kernel(geom, X, Xd, xr_d, xr_dd, work, Y)
        for i in range(3):
            acc = 0.0
            for k in range(Y.shape[1]):
                acc += Y[i, k] * theta_hat[k]
            F[i] = acc
    else:
        gravity_kernel(geom, theta_model, Xdes, work, G)  # G^(X_d), as eq. 25-26 write it
        for i in range(3):
            F[i] = G[i]
        dynamics_kernel(geom, theta_model, X, Xd, xr_d, work, M, C, G)  # C holds C^ Xr_dot
        for i in range(3):
            F[i] += M[i, 0] * xr_dd[0] + M[i, 1] * xr_dd[1] + M[i, 2] * xr_dd[2] + C[i]
    for i in range(3):
        F[i] += gains[1, i] * s[i]
        if kind == 0:
            F[i] += gains[2, i] * min(1.0, max(-1.0, s[i] / eps))
        else:
            F[i] -= gains[5, i] * flc_eval(flc_tables, gains[3, i] * s[i], gains[4, i] * mem[3 + i])
    if kind == 2:
        adapt(theta_hat, Y, s, Tc, gamma_vec, th_min, th_max)


# A Controller keeps its constants, state and workspace in one flat float64 buffer, so
# that a call from Python passes 8 arrays (the buffer, the FLC tables and the inputs)
# instead of 16 arrays and two tuples: Numba's dispatcher takes ~1 us per tuple argument.
_BUFFER_PARTS = (
    ("geom", (GEOM_SIZE,)),
    ("theta", (N_THETA,)),
    ("gains", (6, 3)),
    ("gamma_vec", (N_THETA,)),
    ("theta_min", (N_THETA,)),
    ("theta_max", (N_THETA,)),
    ("mem", (MEM_SIZE,)),
    ("theta_hat", (N_THETA,)),
    ("M", (3, 3)),
    ("C", (3,)),
    ("G", (3,)),
    ("Y", (3, N_THETA)),
) + tuple((f"work{i}", shape) for i, shape in enumerate(WORK_SHAPES))  # make_work's arrays
_GEOM, _THETA, _GAINS, _GAMMA, _TH_MIN, _TH_MAX, _MEM, _THETA_HAT, _M, _C, _G, _Y, _WORK = range(13)
_PART_INDEX = {name: i for i, (name, _) in enumerate(_BUFFER_PARTS)}
_O = tuple(
    int(sum(np.prod(sh) for _, sh in _BUFFER_PARTS[:i])) for i in range(len(_BUFFER_PARTS) + 1)
)
_BUFFER_SIZE = _O[-1]


def _buffer_view(buf: np.ndarray, name: str) -> np.ndarray:
    i = _PART_INDEX[name]
    return buf[_O[i] : _O[i + 1]].reshape(_BUFFER_PARTS[i][1])


@kernel(inline="always", refcount=False)
def _part(buf, i):
    """Part i of a Controller's buffer, flat (a view)."""
    return buf[_O[i] : _O[i + 1]]


@kernel(refcount=False)
def _step_from_buffer(kind, eps, Tc, alpha_f, ints, reals, buf, X, Xd, Xdes, Xddes, Xdddes, F):
    """control_step on a Controller's buffer (the parts of _BUFFER_PARTS, as views)."""
    work = (
        _part(buf, _WORK).reshape(WORK_SHAPES[0]),
        _part(buf, _WORK + 1).reshape(WORK_SHAPES[1]),
        _part(buf, _WORK + 2).reshape(WORK_SHAPES[2]),
        _part(buf, _WORK + 3).reshape(WORK_SHAPES[3]),
        _part(buf, _WORK + 4).reshape(WORK_SHAPES[4]),
        _part(buf, _WORK + 5).reshape(WORK_SHAPES[5]),
        _part(buf, _WORK + 6),
        _part(buf, _WORK + 7).reshape(WORK_SHAPES[7]),
    )
    control_step(
        kind, _part(buf, _GEOM), _part(buf, _THETA), _part(buf, _GAINS).reshape((6, 3)), eps,
        (ints, reals), Tc, alpha_f, X, Xd, Xdes, Xddes, Xdddes, _part(buf, _MEM),
        _part(buf, _THETA_HAT), _part(buf, _GAMMA), _part(buf, _TH_MIN), _part(buf, _TH_MAX),
        work, _part(buf, _M).reshape((3, 3)), _part(buf, _C), _part(buf, _G),
        _part(buf, _Y).reshape((3, N_THETA)), F,
    )  # fmt: skip


def _as_vec3(a, name: str) -> np.ndarray:
    if type(a) is np.ndarray and a.dtype == np.float64 and a.shape == (3,):
        return a if a.flags.c_contiguous else a.copy()
    a = np.ascontiguousarray(a, dtype=float)
    if a.shape != (3,):
        raise ValueError(f"{name}: expected shape (3,), got {a.shape}")
    return a


class Controller:
    """Base class: one small interface for SMC, FSMC and AFSMC (see the module docstring)."""

    name: ClassVar[str] = ""
    kind: ClassVar[int] = -1

    def __init__(
        self,
        model: Mechanism,
        gains: Gains | None = None,
        *,
        period: float,
        flc: MamdaniSystem | None = None,
    ) -> None:
        if not isinstance(model, Mechanism):
            raise TypeError("model: expected a pkmctl.Mechanism (the controller's own model)")
        if not (isinstance(period, int | float) and 0 < period < math.inf):
            raise ValueError(f"period = {period!r}: must be > 0 (s)")
        self.model = model
        self.gains = Gains() if gains is None else gains
        self.period = float(period)
        self.flc = FLC() if flc is None else flc
        self._tables = self.flc.compiled()
        self._alpha_f = 1.0 / self.gains.filter_periods
        th0 = model.theta
        lo, hi = self.gains.theta_bounds
        self._buf = np.zeros(_BUFFER_SIZE)
        view = lambda name: _buffer_view(self._buf, name)  # noqa: E731
        view("geom")[:] = model.geometry
        view("theta")[:] = th0
        view("gains")[:] = self.gains.matrix()
        view("theta_min")[:] = lo * th0
        view("theta_max")[:] = hi * th0
        # Gamma = gamma diag(Theta_0^2): every parameter adapts at the same relative rate
        # for the same share of the force (DESIGN.md §4 asks for a per-parameter scaling).
        view("gamma_vec")[:] = self.gains.gamma * th0**2
        self.reset()

    # Views into the buffer, made on access, so that copy.deepcopy and pickle (which copy
    # the buffer) give a controller whose views are its own.
    theta_min = property(lambda self: _buffer_view(self._buf, "theta_min"))
    theta_max = property(lambda self: _buffer_view(self._buf, "theta_max"))
    gamma_vec = property(lambda self: _buffer_view(self._buf, "gamma_vec"))
    _gm = property(lambda self: _buffer_view(self._buf, "gains"))
    _mem = property(lambda self: _buffer_view(self._buf, "mem"))
    _theta_hat = property(lambda self: _buffer_view(self._buf, "theta_hat"))

    def reset(self) -> None:
        """Restore the initial state (no previous s, sdot = 0, Theta^ = the model's Theta)."""
        self._mem[:] = 0.0
        self._theta_hat[:] = self.model.theta
        self._steps = 0

    @property
    def state(self) -> ControllerState:
        return ControllerState(
            s_prev=self._mem[:3].copy(),
            sdot=self._mem[3:6].copy(),
            theta_hat=self._theta_hat.copy() if self.kind == KIND_AFSMC else None,
            steps=self._steps,
        )

    def step(self, X, Xdot, X_d, Xdot_d, Xddot_d) -> np.ndarray:
        """One control period: the task-space force F (3,) for the measured (X, Xdot)."""
        F = np.empty(3)
        _step_from_buffer(
            self.kind,
            self.gains.eps,
            self.period,
            self._alpha_f,
            self._tables.ints,
            self._tables.reals,
            self._buf,
            _as_vec3(X, "X"),
            _as_vec3(Xdot, "Xdot"),
            _as_vec3(X_d, "X_d"),
            _as_vec3(Xdot_d, "Xdot_d"),
            _as_vec3(Xddot_d, "Xddot_d"),
            F,
        )
        self._steps += 1
        return F


class SMC(Controller):
    """Sliding mode control with a boundary layer (eq. 25)."""

    name = "smc"
    kind = KIND_SMC


class FSMC(Controller):
    """Fuzzy sliding mode control: the switching term replaced by the FLC (eq. 26)."""

    name = "fsmc"
    kind = KIND_FSMC


class AFSMC(Controller):
    """Adaptive fuzzy sliding mode control: regressor-based model with Theta^ adapted (eq. 46)."""

    name = "afsmc"
    kind = KIND_AFSMC


#: Name -> class registry (like SciPy's ``METHODS``).
CONTROLLERS: dict[str, type[Controller]] = {"smc": SMC, "fsmc": FSMC, "afsmc": AFSMC}


def make_controller(name: str, model: Mechanism, gains: Gains | None = None, **kw) -> Controller:
    """Build a controller by name ("smc", "fsmc", "afsmc")."""
    try:
        cls = CONTROLLERS[name.lower()]
    except (KeyError, AttributeError):
        raise ValueError(f"controller = {name!r}: must be one of {sorted(CONTROLLERS)}") from None
    return cls(model, gains, **kw)
