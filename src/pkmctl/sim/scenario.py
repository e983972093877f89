"""Scenario: every number of an experiment, validated, to and from TOML (DESIGN.md §4).

A scenario names the true plant (mechanism), the controller's model (the plant's
parameters scaled by ``controller_model.theta_scale``, 0.85 in the paper: 15 % low),
the gains (Table 3 and our gamma), the fuzzy system of FSMC/AFSMC (``[fuzzy]``: the
paper's FLC, or a MATLAB ``.fis`` file), the trajectory, the initial state, the
disturbance and the timing. Built-ins: ``"paper"`` (T_c = 50 us) and ``"paper-1khz"`` (T_c = 1 ms).

Bad input raises :class:`ScenarioError` with a one-line message naming the field,
the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import tomllib
import types
import typing
import unicodedata
import warnings
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tomli_w
from numpy.typing import ArrayLike
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic.fields import FieldInfo

from pkmctl.control.gains import BASELINE_GAINS, TABLE3, Gains
from pkmctl.errors import InvalidPoseError, PkmctlError, short_repr
from pkmctl.fuzzy import FLC, FuzzySystem, MamdaniSystem
from pkmctl.fuzzy.engine import FuzzyWarning
from pkmctl.fuzzy.fis import FISError, read_fis
from pkmctl.fuzzy.term import term_system
from pkmctl.model.mechanism import PAPER_TABLE2, Mechanism
from pkmctl.sim.trajectory import TRAJECTORIES, Fourier, Sinusoid, paper_trajectory

__all__ = ["BUILTINS", "Scenario", "ScenarioError", "field_reference", "reference_outside"]

#: A trajectory whose J has a condition number above this is "near a singularity".
MAX_TRAJECTORY_CONDITION = 100.0
#: The most h r for the plant's friction near rest (rate r, RK4 sub-step h): RK4 decays
#: a mode only below 2.785 (Scenario._check_friction_step).
MAX_FRICTION_STEP = 2.5
#: A .fis output at s* = sdot* = 0 beyond this fraction of its range gets a warning.
FUZZY_OFFSET_TOLERANCE = 1e-9
#: The finest ball-screw lead a scenario takes (m): 0.1 mm, below the finest screws made
#: (J_m (2 pi / l)^2 overflowed for l ~ 1e-154 and reflected 3.9e13 kg at 1e-6).
SCREW_LEAD_MIN = 1e-4
#: The built-in controllers with the fuzzy term: they run the scenario's ``[fuzzy]``
#: system (:meth:`Scenario.fuzzy_offset_note` concerns them).
FUZZY_CONTROLLERS = ("fsmc", "afsmc", "afsmc-ext")


class ScenarioError(PkmctlError, ValueError):
    """An invalid scenario (one line: field, value, allowed range)."""


# Every float is finite (allow_inf_nan=False below) and bounded: 1e300 in a velocity
# or an amplitude would pass a bare float check and end as a "diverged" run.
def _vec(n: int, **bounds: float):
    return Annotated[list[Annotated[float, Field(**bounds)]], Field(min_length=n, max_length=n)]


#: The most RK4 sub-steps per control period (``timing.substeps``).
MAX_SUBSTEPS = 1000
Vec3 = _vec(3, ge=-10, le=10)  # poses, offsets, amplitudes (m, rad)
PosVec3 = _vec(3, gt=0, le=1e12)  # gains
NonNegVec3 = _vec(3, ge=0, le=1e12)
LengthVec4 = _vec(4, ge=0, le=10)  # m
Theta36 = _vec(36, gt=0, le=1e6)
OmegaVec3 = _vec(3, ge=-1e4, le=1e4)  # rad/s
PhaseVec3 = _vec(3, ge=-1e3, le=1e3)  # rad
VelocityVec3 = _vec(3, ge=-100, le=100)  # m/s, rad/s
ForceVec3 = _vec(3, ge=0, le=1e6)  # N, N m


class _Model(BaseModel):
    model_config = ConfigDict(
        extra="forbid", strict=True, frozen=True, populate_by_name=True, allow_inf_nan=False
    )

    def __setattr__(self, name: str, value: Any) -> None:
        # pydantic's refusal was four lines with a URL, and no word of replace (a tester)
        raise TypeError(
            f"{type(self).__name__}.{name} = {short_repr(value)}: a scenario cannot be "
            "changed in place; make a changed copy with scenario.replace(**{'section.field': "
            "value}) (e.g. 'gains.lam')"
        )

    def __hash__(self) -> int:
        # frozen, yet pydantic's hash of its values failed on the lists ("unhashable type:
        # 'list'"): a scenario could not be a dict key or in a set. Equal models have
        # equal values, so equal hashes.
        return hash((type(self), _hashable(self.__dict__)))


def _hashable(value: Any) -> Any:
    """``value`` with dicts and lists as tuples (for :meth:`_Model.__hash__`)."""
    if isinstance(value, dict):
        return tuple((k, _hashable(v)) for k, v in value.items())
    if isinstance(value, list | tuple):
        return tuple(_hashable(v) for v in value)
    return value


def _paper_theta() -> list[float]:
    return Mechanism.paper().theta.tolist()


class MechanismSpec(_Model):
    """The true plant: geometry (m) and Theta (36) in the order of DESIGN.md §1."""

    r_a: float = Field(PAPER_TABLE2["r_a"], gt=0, le=10)
    r_b: float = Field(PAPER_TABLE2["r_b"], gt=0, le=10)
    l1: LengthVec4 = Field(default_factory=lambda: [PAPER_TABLE2["lower_limb"]["com"]] * 4)
    l2: LengthVec4 = Field(default_factory=lambda: [PAPER_TABLE2["upper_limb"]["com"]] * 4)
    g: float = Field(PAPER_TABLE2["g"], ge=0, le=100)
    theta: Theta36 = Field(default_factory=_paper_theta)

    def build(self) -> Mechanism:
        return Mechanism(
            r_a=self.r_a, r_b=self.r_b, l1=self.l1, l2=self.l2, theta=self.theta, g=self.g
        )


class GainsSpec(_Model):
    """Table 3 (diagonals over [z, alpha, beta]), the adaptation gain and sdot filter, and
    the baselines' gains (defaults: :data:`~pkmctl.control.gains.BASELINE_GAINS`)."""

    lam: PosVec3 = Field(default_factory=lambda: list(TABLE3["lam"]))
    K: NonNegVec3 = Field(default_factory=lambda: list(TABLE3["K"]))
    Lam: NonNegVec3 = Field(default_factory=lambda: list(TABLE3["Lam"]))
    eps: float = Field(TABLE3["eps"], gt=0, le=1e3)
    Ks: PosVec3 = Field(default_factory=lambda: list(TABLE3["Ks"]))
    Ksd: PosVec3 = Field(default_factory=lambda: list(TABLE3["Ksd"]))
    Ku: NonNegVec3 = Field(default_factory=lambda: list(TABLE3["Ku"]))
    gamma: float = Field(Gains().gamma, ge=0, le=1e6)
    filter_periods: float = Field(Gains().filter_periods, ge=1, le=1e6)
    # (each bound has its own range, which every message about them states: [0, 1e6]
    # for both sent -1 to 0, which _bounds then refused; a tester)
    theta_bounds: Annotated[
        list[Annotated[float, Field(gt=0, le=1e6)]], Field(min_length=2, max_length=2)
    ] = [0.1, 10.0]
    pd_kp: NonNegVec3 = Field(default_factory=lambda: list(BASELINE_GAINS["pd_kp"]))
    pd_kd: NonNegVec3 = Field(default_factory=lambda: list(BASELINE_GAINS["pd_kd"]))
    ctc_kp: NonNegVec3 = Field(default_factory=lambda: list(BASELINE_GAINS["ctc_kp"]))
    ctc_kd: NonNegVec3 = Field(default_factory=lambda: list(BASELINE_GAINS["ctc_kd"]))

    @model_validator(mode="after")
    def _bounds(self) -> GainsSpec:
        lo, hi = self.theta_bounds
        for i, (v, ok, allowed) in enumerate(((lo, 0 < lo <= 1, "(0, 1]"),
                                              (hi, 1 <= hi <= 1e6, "[1, 1e+06]"))):  # fmt: skip
            if not ok:  # (False for NaN)
                raise ValueError(
                    f".theta_bounds[{i}] = {v!r}: must be a finite number in {allowed} "
                    f"({UNITS['gains.theta_bounds']})"
                )
        return self

    def build(self) -> Gains:
        d = self.model_dump()
        d["theta_bounds"] = tuple(d["theta_bounds"])
        return Gains(**d)


class FuzzySpec(_Model):
    """The fuzzy system of FSMC's and AFSMC's fuzzy term (eq. 26; docs/fuzzy.md).

    ``fis``: a MATLAB ``.fis`` file, Mamdani or Sugeno, with 2 inputs (s*, sdot*) and 1
    output (absent: the paper's FLC). A relative path is relative to the folder of the
    scenario file (to the working directory for a scenario made from a dict or TOML
    text); the scenario keeps it absolute. ``engine``: ``"auto"`` runs a system that
    qualifies on the paper's fast kernel and any other on the general engine,
    ``"general"`` always the general engine. ``input_range``: ``"clip"`` (inputs clipped to
    their ranges, as the paper's FLC) or ``"raw"`` (MATLAB's). ``samples``: none (the
    continuous aggregate, exact) or n (MATLAB's defuzzification on n points; 101 there).
    The last two put any system on the general engine.
    """

    fis: str | None = None
    engine: Literal["auto", "general"] = "auto"  # pkmctl.fuzzy.term.ENGINES
    input_range: Literal["clip", "raw"] = "clip"
    samples: int | None = Field(None, ge=3, le=1_000_000)

    @field_validator("fis")
    @classmethod
    def _fis(cls, v: str | None) -> str | None:
        # Read and check the file now: a bad file is a bad scenario, refused before any run.
        if v is None:
            return v
        path = os.path.abspath(Path(v).expanduser())
        try:
            term_system(read_fis(path), source=path)
        except FISError as exc:
            more = len(exc.problems) - 1
            raise ValueError(
                str(exc).splitlines()[0]
                + (f" (and {more} more problem{'s' if more > 1 else ''})" if more else "")
            ) from None
        except ValueError as exc:
            raise ValueError(str(exc)) from None
        return path

    def build(self) -> MamdaniSystem | FuzzySystem:
        """The system the fuzzy term runs (:func:`pkmctl.fuzzy.term.term_system`). The
        paper's FLC is built once per process for each set of options (the systems are
        immutable); a ``.fis`` file is read again each time (it may have changed)."""
        if self.fis is None:
            return _paper_system(self.engine, self.input_range, self.samples)
        return _term_system(read_fis(self.fis), self.engine, self.input_range, self.samples,
                            self.fis)  # fmt: skip


def _term_system(system, engine: str, input_range: str, samples: int | None, source):
    options: dict[str, Any] = {}
    if input_range != "clip":
        options["input_range"] = input_range
    if samples is not None:
        options["samples"] = samples
    return term_system(system, engine=engine, source=source, **options)


@functools.lru_cache(maxsize=16)
def _paper_system(engine: str, input_range: str, samples: int | None):
    # 5 ms a build: a campaign task, simulate_many and every simulate paid it
    return _term_system(FLC(), engine, input_range, samples, None)


def _paper_traj(field_name: str) -> list[float]:
    return list(getattr(paper_trajectory(), field_name))


class TrajectorySpec(_Model):
    """A sinusoid per coordinate: offset + amplitude sin(omega t + phase) (eq. 54 by default)."""

    kind: Literal["sinusoid"] = "sinusoid"
    offset: Vec3 = Field(default_factory=lambda: _paper_traj("offset"))  # m, rad
    amplitude: Vec3 = Field(default_factory=lambda: _paper_traj("amplitude"))  # m, rad
    omega: OmegaVec3 = Field(default_factory=lambda: _paper_traj("omega"))
    phase: PhaseVec3 = Field(default_factory=lambda: _paper_traj("phase"))

    def build(self) -> Sinusoid:
        cls = TRAJECTORIES[self.kind]
        return cls(*(tuple(getattr(self, k)) for k in ("offset", "amplitude", "omega", "phase")))


Coefficients = Annotated[
    list[
        Annotated[
            list[Annotated[float, Field(ge=-100, le=100)]], Field(min_length=1, max_length=20)
        ]
    ],
    Field(min_length=3, max_length=3),
]


class FourierSpec(_Model):
    """A finite Fourier series per coordinate (``pkmctl excite`` designs one, DESIGN.md §9):
    X_i = offset_i + sum_l a_il / (w l) sin(w l t) - b_il / (w l) cos(w l t), w = 2 pi
    ``base_frequency`` (Hz); ``a``, ``b``: 3 rows [z, alpha, beta] of H coefficients (m/s,
    rad/s)."""

    kind: Literal["fourier"] = "fourier"
    base_frequency: float = Field(0.1, gt=0, le=100)  # Hz
    offset: Vec3 = [0.7, 0.0, 0.0]  # m, rad
    a: Coefficients = [[0.0], [0.0], [0.0]]
    b: Coefficients = [[0.0], [0.0], [0.0]]

    @model_validator(mode="after")
    def _shapes(self) -> FourierSpec:
        h = {len(r) for r in self.a} | {len(r) for r in self.b}
        if len(h) != 1:
            raise ValueError(
                f"a and b: every row needs the same number of harmonics (got {sorted(h)})"
            )
        return self

    def build(self) -> Fourier:
        return Fourier(
            self.base_frequency,
            tuple(self.offset),
            tuple(tuple(r) for r in self.a),
            tuple(tuple(r) for r in self.b),
        )


def _trajectory_kind(v: Any) -> str:
    if isinstance(v, dict):
        return v.get("kind", "sinusoid")
    return getattr(v, "kind", "sinusoid")


#: A scenario's trajectory: a sinusoid (eq. 54, the default) or a Fourier series.
AnyTrajectory = Annotated[
    Annotated[TrajectorySpec, Tag("sinusoid")] | Annotated[FourierSpec, Tag("fourier")],
    Discriminator(_trajectory_kind),
]


class InitialSpec(_Model):
    """Initial state of the plant (at rest at home in the paper)."""

    X: Vec3 = [0.7, 0.0, 0.0]  # m, rad
    Xdot: VelocityVec3 = [0.0, 0.0, 0.0]  # m/s, rad/s


class DisturbanceSpec(_Model):
    """tau_d' = amplitude * U(-1, 1) per component, redrawn every ``hold`` s, seeded."""

    amplitude: ForceVec3 = [2.0, 2.0, 2.0]  # N, N m
    hold: float = Field(1e-3, gt=0, le=1e3)
    seed: int = Field(0, ge=0, le=2**63 - 1)


class TimingSpec(_Model):
    """Control period T_c, RK4 sub-steps per period, and duration (s)."""

    control_period: float = Field(5e-5, ge=1e-6, le=0.1)
    substeps: int = Field(1, ge=1, le=MAX_SUBSTEPS)
    duration: float = Field(10.0, gt=0, le=3600)

    @property
    def periods(self) -> int:
        """Control periods of the run, round(duration / control_period)."""
        return int(round(self.duration / self.control_period))


class LoggingSpec(_Model):
    """What the loop keeps of the run: one row every ``every`` control periods (t = 0,
    every T_c, 2 every T_c, ...); 1 = every period (the default). The metrics
    (:mod:`pkmctl.sim.metrics`) are computed over every period inside the loop whatever
    ``every`` is: decimating shrinks the time series, not what the run is judged by. An
    hour at 20 kHz is 72 million periods (tens of GiB of log); every = 200 keeps one row
    per 10 ms. Checked against the run's periods by :class:`Scenario`."""

    # Any here, checked with the run's length in Scenario._physics: the message must give
    # the range [1, periods], which this section alone does not know.
    every: Any = 1


@dataclasses.dataclass(frozen=True)
class _Bounds:
    """A number's allowed range, as the one-line messages say it: "a finite number in
    (0, 1] (m)", "an integer in [0, 2^63 - 1]". The range checks of ``_in_range`` and the
    messages made of pydantic's errors (:func:`_one_line`) both speak through it."""

    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    unit: str = ""

    @classmethod
    def of(cls, metadata: list, *, integer: bool) -> _Bounds:
        """The bounds a field declares (``Field(gt=..., le=...)``, or an ``_in_range``)."""
        for m in metadata:
            declared = getattr(getattr(m, "func", None), "bounds", None)
            if declared is not None:
                return declared
        b: dict[str, Any] = {"integer": integer}
        for m in metadata:
            for attr, key, is_open in (("gt", "lo", True), ("ge", "lo", False),
                                       ("lt", "hi", True), ("le", "hi", False)):  # fmt: skip
                if getattr(m, attr, None) is not None:
                    b[key], b[f"{key}_open"] = getattr(m, attr), is_open
        return cls(**b)

    def _num(self, x: float) -> str:
        if not self.integer:
            return f"{x:g}"
        k = int(x).bit_length()
        if x >= 2**20 and x + 1 == 2**k:
            return f"2^{k} - 1"
        if x >= 2**20 and x == 2 ** (k - 1):
            return f"2^{k - 1}"
        return str(int(x))

    def text(self, plural: bool = False) -> str:
        """What is allowed, without the unit."""
        if self.integer:
            what = "integers" if plural else "an integer"
        else:
            what = "finite numbers" if plural else "a finite number"
        lo, hi = math.isfinite(self.lo), math.isfinite(self.hi)
        if lo and hi:
            return (
                f"{what} in {'(' if self.lo_open else '['}{self._num(self.lo)}, "
                f"{self._num(self.hi)}{')' if self.hi_open else ']'}"
            )
        if lo:
            return f"{what} {'>' if self.lo_open else '>='} {self._num(self.lo)}"
        if hi:
            return f"{what} {'<' if self.hi_open else '<='} {self._num(self.hi)}"
        return what

    def ok(self, v: float) -> bool:
        return (
            math.isfinite(v)
            and (v > self.lo if self.lo_open else v >= self.lo)
            and (v < self.hi if self.hi_open else v <= self.hi)
        )


def _in_range(lo: float, hi: float = math.inf, *, lo_open: bool = False, unit: str = ""):
    """A validator: a finite number in [lo, hi] ((lo, hi] if lo_open), one-line message."""
    bounds = _Bounds(lo, hi, lo_open=lo_open, unit=unit)
    suffix = f" ({unit})" if unit else ""

    def check(v):
        # Before pydantic's own float check (allow_inf_nan=False), whose message would
        # not give the allowed range; anything not a number is left to that check (whose
        # message _one_line words with these bounds, found as check.bounds).
        if not isinstance(v, int | float) or isinstance(v, bool):
            return v
        if not bounds.ok(v):
            raise ValueError(f"= {v!r}: must be {bounds.text()}{suffix}")
        return v

    check.bounds = bounds  # type: ignore[attr-defined]
    return BeforeValidator(check)


def _positive(unit: str, hi: float = math.inf):
    return Annotated[float, _in_range(0.0, hi, lo_open=True, unit=unit)]


def _nonneg(unit: str, hi: float = math.inf):
    return Annotated[float, _in_range(0.0, hi, unit=unit)]


def _check_kind(kind: str, name: str) -> str:
    from pkmctl.parts import names

    known = names(kind)
    if name not in known:
        raise ValueError(
            f"{short_repr(name)}: unknown {kind} (registered: {', '.join(known)}; a part of "
            "your own is registered by importing its module: in Python, import it first; on the "
            "command line, pkmctl --plugin FILE.py COMMAND)"
        )
    return name


class ControllerModelSpec(_Model):
    """The controllers' model: the plant's Theta times ``theta_scale`` (0.85: 15 % low), and
    what the controllers know of the machine of DESIGN.md §7 (each 0 = nothing, the paper's
    design): ``rotor_inertia`` J_m (kg m^2, through the plant's screw lead), friction
    ``friction_coulomb`` F_c (N), ``friction_viscous`` F_v (N s/m) with the smooth sign's
    ``friction_velocity`` v_s (m/s). Every controller adds J^T diag(m_r) (J a + Jdot v) +
    J^T f(J Xdot) to its force (PD: the friction only; docs/machine.md)."""

    theta_scale: float = Field(0.85, gt=0, le=10)
    rotor_inertia: _nonneg("kg m^2", 1.0) = 0.0
    friction_coulomb: _nonneg("N", 1e5) = 0.0
    friction_viscous: _nonneg("N s/m", 1e6) = 0.0
    friction_velocity: _positive("m/s", 1.0) = 1e-3
    #: An explicit model instead: Theta_ext = [Theta (36), m_r (4, kg), F_c (4, N),
    #: F_v (4, N s/m)] of DESIGN.md §7, as ``pkmctl identify`` writes it. Replaces
    #: theta_scale, rotor_inertia and the friction (not friction_velocity).
    theta_ext: (
        Annotated[list[Annotated[float, Field(ge=0, le=1e6)]], Field(min_length=48, max_length=48)]
        | None
    ) = None

    @model_validator(mode="after")
    def _explicit(self) -> ControllerModelSpec:
        if self.theta_ext is None:
            return self
        # refused only away from their defaults: to_toml and replace() write every field,
        # the defaults beside theta_ext included, and must read back
        fields = type(self).model_fields
        both = [
            k
            for k in ("friction_coulomb", "friction_viscous", "rotor_inertia", "theta_scale")
            if k in self.model_fields_set and getattr(self, k) != fields[k].default
        ]
        if both:
            raise ValueError(
                f"theta_ext is given, so {', '.join(both)} must not be (theta_ext holds them)"
            )
        bad = [k for k in range(36) if not self.theta_ext[k] > 0]
        if bad:
            raise ValueError(
                f".theta_ext[{bad[0]}] = {self.theta_ext[bad[0]]!r}: must be a finite number in "
                f"(0, 1e+06] ({UNITS['controller_model.theta_ext'][bad[0]]}): theta_ext[0:36] "
                "are masses and inertias"
            )
        return self

    def machine_terms(self, screw_lead: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The model's m_r (4, kg), F_c (4, N), F_v (4, N s/m) per limb."""
        if self.theta_ext is not None:
            e = np.asarray(self.theta_ext[36:], dtype=float)
            return e[0:4].copy(), e[4:8].copy(), e[8:12].copy()
        m_r = self.rotor_inertia * (2.0 * math.pi / screw_lead) ** 2
        return (
            np.full(4, m_r),
            np.full(4, float(self.friction_coulomb)),
            np.full(4, float(self.friction_viscous)),
        )


class PlantSpec(_Model):
    """The plant part (DESIGN.md §6): ``rigid``, the closed form of §2, or a registered one,
    and the machine's options of §7 (each 0 = off, the paper's ideal machine):
    ``rotor_inertia`` J_m (kg m^2 per motor), ``screw_lead`` l (m), ``friction_coulomb``
    F_c (N per actuated joint), ``friction_viscous`` F_v (N s/m), ``friction_velocity``
    v_s (m/s) of the smooth sign tanh(qdot / v_s)."""

    kind: str = "rigid"
    rotor_inertia: _nonneg("kg m^2", 1.0) = 0.0
    screw_lead: Annotated[float, _in_range(SCREW_LEAD_MIN, 1.0, unit="m")] = 0.01
    friction_coulomb: _nonneg("N", 1e5) = 0.0
    friction_viscous: _nonneg("N s/m", 1e6) = 0.0
    friction_velocity: _positive("m/s", 1.0) = 1e-3

    @field_validator("kind")
    @classmethod
    def _kind(cls, v: str) -> str:
        return _check_kind("plant", v)

    @model_validator(mode="after")
    def _modelled(self) -> PlantSpec:
        # Refused here, not when the run builds its plant: a campaign's cell of MuJoCo with
        # dry friction was a run of error records (and exit 1) after the others had run.
        if self.kind == "mujoco" and self.friction_coulomb != 0.0:
            raise ValueError(
                f".friction_coulomb = {self.friction_coulomb!r}: plant.kind = 'mujoco' cannot "
                "model it (MuJoCo's dry friction, frictionloss, is a soft constraint, not the "
                "rigid plant's tanh force; docs/machine.md); set it to 0.0 or use "
                "plant.kind = 'rigid'"
            )
        return self


class PayloadSpec(_Model):
    """A point mass on the platform (DESIGN.md §8): ``mass`` (kg) at ``offset`` (m, platform
    frame). None (0 kg) in the paper; the controllers' model does not know it."""

    mass: _nonneg("kg", 1e3) = 0.0
    offset: Vec3 = [0.0, 0.0, 0.0]

    @field_validator("offset")
    @classmethod
    def _offset(cls, v: list[float]) -> list[float]:
        if not all(math.isfinite(x) and abs(x) <= 10.0 for x in v):
            raise ValueError(f"= {v!r}: must be 3 finite numbers in [-10, 10] (m)")
        return v


def _unused_fields(spec: _Model, section: str, used: dict[str, frozenset[str]]) -> None:
    """Refuse a field the part's kind never reads, set away from its default: it would be
    ignored without a word (``actuators.force_limit`` on a drive, a noise on the ideal
    sensor). ``used``: the fields each built-in kind reads; a registered kind may read any."""
    reads = used.get(spec.kind)
    if reads is None:
        return
    for name, field in type(spec).model_fields.items():
        if name == "kind" or name in reads:
            continue
        value = getattr(spec, name)
        if value != field.default:
            readers = [k for k, f in used.items() if name in f]
            by = " or ".join(f"{section}.kind = {k!r}" for k in readers)
            fix = "remove it" + (
                "" if field.default is None else f" or set it to {field.default!r}"
            )
            raise ValueError(
                f".{name} = {value!r}: {section}.kind = {spec.kind!r} does not use it "
                f"(only {by} does); {fix}"
            )


class SensorSpec(_Model):
    """The sensor part: ``ideal`` (exact X, Xdot at the sample), ``encoder`` (DESIGN.md §7:
    limb lengths quantised to screw_lead / counts_per_rev, optional Gaussian ``noise`` (m),
    forward kinematics, Xdot^ = J^+ qdot^ with qdot^ a backward difference low-pass
    filtered with time constant ``velocity_filter`` (s), ``delay_periods`` of sample
    age), or a registered one. ``seed`` seeds the noise."""

    kind: str = "ideal"
    counts_per_rev: int = Field(160_000, ge=1, le=2**40)
    noise: _nonneg("m", 1e-2) = 0.0
    delay_periods: int = Field(0, ge=0, le=1)
    velocity_filter: _nonneg("s", 1.0) = 0.0
    seed: int = Field(0, ge=0, le=2**63 - 1)

    @field_validator("kind")
    @classmethod
    def _kind(cls, v: str) -> str:
        return _check_kind("sensor", v)

    @model_validator(mode="after")
    def _used(self) -> SensorSpec:
        # the seed is harmless without noise: a built-in scenario's file keeps it
        every = frozenset({"counts_per_rev", "noise", "delay_periods", "velocity_filter"})
        _unused_fields(self, "sensor", {"ideal": frozenset({"seed"}), "encoder": every | {"seed"}})
        return self


class ActuatorSpec(_Model):
    """The actuator part (``ideal``: the minimum-norm split at the measured pose, with a
    ``force_limit`` (N) per limb, none in the paper; ``drive``: the servo drive of DESIGN.md
    §7, torque ``peak_torque`` (N m), screw ``efficiency``, first-order torque ``lag`` (s),
    ``max_speed`` (rpm, counted, not enforced), ``delay_periods`` of computation delay: the
    command computed from the sample at t_k acts from t_k+1)."""

    kind: str = "ideal"
    force_limit: float | None = Field(None, gt=0, le=1e9)
    peak_torque: _positive("N m", 1e4) = 3.82
    efficiency: _positive("", 1.0) = 0.9
    lag: _nonneg("s", 1.0) = 2e-4
    max_speed: _positive("rpm", 1e6) = 5000.0
    delay_periods: int = Field(0, ge=0, le=1)

    @field_validator("kind")
    @classmethod
    def _kind(cls, v: str) -> str:
        return _check_kind("actuator", v)

    @model_validator(mode="after")
    def _used(self) -> ActuatorSpec:
        drive = frozenset({"peak_torque", "efficiency", "lag", "max_speed", "delay_periods"})
        _unused_fields(self, "actuators", {"ideal": frozenset({"force_limit"}), "drive": drive})
        return self


def reference_outside(t: np.ndarray, X: np.ndarray) -> str:
    """'' if every desired pose X (N, 3) at times t (N,) lies in the valid box (finite,
    z > 0, |alpha|, |beta| < pi/2), else the message naming the first time that does not.
    Cheap (no kinematics): the loop's inputs check it at every control period, where the
    scenario's own check (with the condition number of J) samples every 1 ms at most."""
    bad = (
        ~np.isfinite(X).all(axis=1)
        | (X[:, 0] <= 0.0)
        | (np.abs(X[:, 1:3]) >= np.pi / 2).any(axis=1)
    )
    if not bad.any():
        return ""
    n = int(np.argmax(bad))
    z, a, b = (float(v) for v in X[n])
    return (
        f"trajectory: leaves the valid workspace at t = {t[n]:.6g} s (z = {z:.10g} m, "
        f"alpha = {a:.10g}, beta = {b:.10g} rad; the valid range is z > 0, "
        f"|alpha|, |beta| < pi/2)"
    )


def _plain(value: Any) -> Any:
    """NumPy arrays and scalars as the lists and numbers TOML holds (``replace`` with
    ``np.arange`` seeds or an array of gains; a NumPy integer is no ``int`` to pydantic)."""
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _changed(data: dict[str, Any], changes: dict[str, Any], known: dict | None = None) -> dict:
    """``data`` (a scenario's fields, nested) with the dotted ``changes`` made. A section
    absent from ``data`` is made if ``known`` (the defaults) has it; an unknown section or
    a field of no section is refused here, a new name in a known section is left to
    validation, which lists the section's fields."""
    for key, value in changes.items():
        value = _plain(value)
        *path, last = key.split(".")
        node = data
        for i, p in enumerate(path):
            if isinstance(node, dict) and p not in node and known is not None:
                ref = known
                for q in path[: i + 1]:
                    ref = ref.get(q) if isinstance(ref, dict) else None
                if isinstance(ref, dict):
                    node[p] = {}
            node = node.get(p) if isinstance(node, dict) else None
        if not isinstance(node, dict) or (last not in node and not path):
            sections = known if known is not None else data
            names = ", ".join(k for k, v in sections.items() if isinstance(v, dict))
            raise ScenarioError(f"{key}: unknown field (sections: {names})")
        node[last] = value
    return data


#: Unicode's bidirectional controls (LRM, RLM, ALM, LRE..RLO, LRI..PDI)
_BIDI = frozenset("\u200e\u200f\u061c" + "".join(map(chr, range(0x202A, 0x202F)))
                  + "".join(map(chr, range(0x2066, 0x206A))))  # fmt: skip


class Scenario(_Model):
    """Every number of one experiment (DESIGN.md §4). Build with :meth:`builtin` or TOML."""

    name: str = Field("custom", min_length=1, max_length=100)
    description: str = ""
    # each scenario its own sections: a default instance (hashable, so pydantic does not
    # copy it) was every scenario's without that section, lists included, and
    # `builtin("prototype").gains.lam[0] = 5` changed "paper"'s gains and the scenario
    # recorded in finished results (a tester)
    mechanism: MechanismSpec = Field(default_factory=MechanismSpec)
    controller_model: ControllerModelSpec = Field(default_factory=ControllerModelSpec)
    gains: GainsSpec = Field(default_factory=GainsSpec)
    fuzzy: FuzzySpec = Field(default_factory=FuzzySpec)
    trajectory: AnyTrajectory = Field(default_factory=TrajectorySpec)
    initial: InitialSpec = Field(default_factory=InitialSpec)
    disturbance: DisturbanceSpec = Field(default_factory=DisturbanceSpec)
    timing: TimingSpec = Field(default_factory=TimingSpec)
    logging: LoggingSpec = Field(default_factory=LoggingSpec)
    actuators: ActuatorSpec = Field(default_factory=ActuatorSpec)
    plant_spec: PlantSpec = Field(default_factory=PlantSpec, alias="plant")
    payload: PayloadSpec = Field(default_factory=PayloadSpec)
    sensor: SensorSpec = Field(default_factory=SensorSpec)

    @field_validator("name")
    @classmethod
    def _one_line_name(cls, v: str) -> str:
        # the name heads reports and tables: a newline in it broke report.md's heading
        # also U+0085, U+2028, and the bidi controls (U+202E reversed what a report shows)
        if any(unicodedata.category(c) in ("Cc", "Zl", "Zp") or c in _BIDI for c in v):
            raise ValueError(
                f"= {short_repr(v)}: must be one line of printable text (no newline, tab, control "
                "or bidirectional control character)"
            )
        return v

    @model_validator(mode="after")
    def _physics(self) -> Scenario:
        try:
            plant = self.mechanism.build()
        except ValueError as exc:
            raise ValueError(f"mechanism: {exc}") from None
        try:
            self.controller_mechanism()
        except ValueError as exc:
            raise ValueError(f"controller_model: {exc}") from None
        try:
            plant.check_pose(np.array(self.initial.X))
        except InvalidPoseError as exc:
            raise ValueError(f"initial.X = {self.initial.X}: not a valid pose ({exc})") from None
        t = self.timing
        if t.duration < t.control_period:
            raise ValueError(
                f"timing.duration = {t.duration}: must be >= control_period ({t.control_period})"
            )
        if self.disturbance.hold < t.control_period * (1 - 1e-9):
            raise ValueError(
                f"disturbance.hold = {self.disturbance.hold:g}: must be >= "
                f"timing.control_period ({t.control_period:g} s): the loop holds one value "
                f"over each control period (or a timing.control_period <= "
                f"{self.disturbance.hold:g} s)"
            )
        h = t.control_period / t.substeps
        lag = self.actuators.lag
        if self.actuators.kind == "drive" and 0.0 < lag < h * (1 - 1e-9):
            # RK4 follows the drive's first-order lag (rate -1/lag) well only for lag >= h:
            # a step's gap decays by 0.375 a sub-step for exp(-1) = 0.368 there, by 0.333
            # for 0.135 at h/2, and at h/2.79 not at all (a run with 10 us at h = 0.1 ms
            # "diverged" in 2 ms). A shorter lag is an ideal torque loop at this step
            # (lag 0), or needs a finer one.
            need = math.ceil(t.control_period / lag * (1 - 1e-9))
            raise ValueError(
                f"actuators.lag = {lag:g}: must be 0 (no lag) or >= {h:g} s, the plant's "
                f"RK4 sub-step (timing.control_period / substeps), which cannot follow a "
                "shorter lag; "
                + (
                    f"or raise timing.substeps to >= {need}"
                    if need <= MAX_SUBSTEPS
                    else f"at this control period no lag below {t.control_period / MAX_SUBSTEPS:g}"
                    f" s can be followed ({MAX_SUBSTEPS} sub-steps at most)"
                )
            )
        if self.plant_spec.kind == "mujoco":
            self._check_mujoco_step(h)
        every = self.logging.every
        if not (isinstance(every, int) and not isinstance(every, bool) and 1 <= every <= t.periods):
            raise ValueError(
                f"logging.every = {every!r}: must be an integer in [1, {t.periods}] "
                f"(control periods; {t.periods} is the run's length, timing.duration "
                f"{t.duration:g} s / control_period {t.control_period:g} s)"
            )
        # The whole desired trajectory must stay in the workspace, away from singularities.
        ts = np.linspace(0.0, t.duration, int(min(20001, max(2, t.duration / 1e-3))))
        Xd, _, _ = self.trajectory.build().evaluate(ts)
        outside = reference_outside(ts, Xd)
        if outside:
            raise ValueError(outside)
        try:
            cond = plant.checked_condition_numbers(Xd)
        except InvalidPoseError as exc:
            raise ValueError(f"trajectory: leaves the valid workspace ({exc})") from None
        worst = int(np.argmax(cond))
        if cond[worst] > MAX_TRAJECTORY_CONDITION:
            raise ValueError(
                f"trajectory: comes near a singularity at t = {ts[worst]:.4g} s "
                f"(condition number of J {cond[worst]:.3g}, "
                f"allowed <= {MAX_TRAJECTORY_CONDITION:g})"
            )
        # on the poses just checked: 25 of them, and the initial pose
        sample = Xd[np.linspace(0, len(Xd) - 1, min(25, len(Xd))).astype(int)]
        self._check_friction_step(plant, h, np.vstack([np.asarray(self.initial.X), sample]))
        return self

    def _check_mujoco_step(self, h: float) -> None:
        """Refuse a ``mujoco`` plant whose RK4 sub-step ``h`` is over half its closures'
        time constant (:func:`pkmctl.plants.mujoco_max_timestep`), with or without MuJoCo
        here (a campaign's client may have none, its workers MuJoCo)."""
        from pkmctl.plants import mujoco_max_timestep

        most = mujoco_max_timestep()
        if h > most:
            need = math.ceil(self.timing.control_period / most * (1 - 1e-9))
            raise ValueError(
                f"timing.substeps = {self.timing.substeps}: with plant.kind = 'mujoco' the "
                f"RK4 sub-step (timing.control_period / substeps = {h:g} s) must be <= "
                f"{most:g} s, half the closures' time constant, which MuJoCo would raise to "
                f"twice a longer step, the closures then lagging; set timing.substeps >= {need}"
            )

    def _check_friction_step(self, plant: Mechanism, h: float, X: np.ndarray) -> None:
        """Refuse friction too stiff for the plant's RK4 sub-step ``h``.

        Near rest the friction F_c tanh(qdot / v_s) + F_v qdot of each limb is a damper of
        c = F_c / v_s + F_v (N s/m), which decays the pose rates at up to c k, k the
        largest eigenvalue of (M + m_r J^T J)^-1 J^T J (1/kg; over the valid poses ``X``:
        the initial pose and the trajectory's). RK4 decays a mode of rate r only for
        h r < 2.785; above, the run goes on with exit 0 and limbs creeping 200 x too fast
        (F_c = 1e4 N: 48 mm/s for 0.23) or never coming to rest (v_s = 1e-5). Refused
        above h r = 2.5, with the largest value allowed and the sub-steps that would
        integrate it.
        """
        ps = self.plant_spec
        c = ps.friction_coulomb / ps.friction_velocity + ps.friction_viscous
        if c == 0.0:
            return
        t = self.timing
        from pkmctl.model.machine import reflected_inertia

        m_r = reflected_inertia(ps.rotor_inertia, ps.screw_lead)
        J, M = plant.jacobian(X), plant.mass_matrix(X)
        JtJ = np.einsum("nia,nib->nab", J, J)
        k = float(np.max(np.linalg.eigvals(np.linalg.solve(M + m_r * JtJ, JtJ)).real))
        if h * c * k <= MAX_FRICTION_STEP:
            return
        need = t.control_period * c * k / MAX_FRICTION_STEP  # (inf for v_s = 1e-308: the
        need = math.ceil(need) if need <= MAX_SUBSTEPS else MAX_SUBSTEPS + 1  # ceil raised)
        how = (
            f"or raise timing.substeps to >= {need}"
            if need <= MAX_SUBSTEPS
            else f"{MAX_SUBSTEPS} sub-steps at most cannot at this control period"
        )
        top = MAX_FRICTION_STEP / (h * k)  # the largest c
        step = (
            f"too stiff for the plant's RK4 sub-step h = {h:g} s (timing.control_period / "
            f"substeps): near rest it decays the rates at {c * k:.3g} /s, and h x that = "
            f"{h * c * k:.3g} must be <= {MAX_FRICTION_STEP:g} (RK4 is unstable above 2.785)"
        )
        if ps.friction_viscous >= top:
            raise ValueError(
                f"plant.friction_viscous = {ps.friction_viscous:g}: must be < {top:.4g} N s/m "
                f"here, {step}; {how}"
            )
        fc_max = ps.friction_velocity * (top - ps.friction_viscous)
        raise ValueError(
            f"plant.friction_coulomb = {ps.friction_coulomb:g}: must be <= {fc_max:.4g} N at "
            f"friction_velocity = {ps.friction_velocity:g} m/s and friction_viscous = "
            f"{ps.friction_viscous:g} N s/m (F_c / v_s + F_v <= {top:.4g} N s/m), {step}; {how}"
        )

    # ------------------------------------------------------------------ constructors
    @classmethod
    def builtin(
        cls, name: str, duration: float | None = None, changes: dict[str, Any] | None = None
    ) -> Scenario:
        """A built-in scenario (:data:`BUILTINS`), with ``duration`` (s) instead of its own
        if given, and ``changes`` (dotted fields, as :meth:`replace`): validated once, where
        ``builtin(name).replace(...)`` validates twice (and the first time with the
        built-in's own duration)."""
        try:
            data = BUILTINS[name]
        except KeyError:
            raise ScenarioError(
                f"scenario = {name!r}: unknown built-in (choose from {', '.join(BUILTINS)})"
            ) from None
        if duration is not None:
            data = {**data, "timing": {**data.get("timing", {}), "duration": duration}}
        if changes:
            import copy

            known = cls().model_dump(by_alias=True)
            data = _changed(copy.deepcopy(data), changes, known=known)
        return cls.from_dict(data)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Scenario:
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise ScenarioError(_one_line(exc)) from None

    @classmethod
    def from_toml(cls, source: str | Path, changes: dict[str, Any] | None = None) -> Scenario:
        """Read a scenario from a TOML file path (or TOML text if it contains a newline),
        with ``changes`` (dotted fields, as :meth:`replace`) made before it is validated:
        a file whose trajectory leaves the workspace after 5 s is valid with a duration
        of 1 s."""
        if isinstance(source, Path) or "\n" not in str(source):
            path = Path(source)
            where = f"scenario file {str(path)!r}"
            try:
                text = path.read_text(encoding="utf-8-sig")  # -sig: a Windows editor's BOM
            except OSError as exc:
                raise ScenarioError(f"{where}: {exc.strerror or exc}") from None
            except UnicodeDecodeError as exc:
                raise ScenarioError(
                    f"{where}: not UTF-8 text (byte {exc.object[exc.start]:#04x} "
                    f"at offset {exc.start})"
                ) from None
        else:
            text, where = str(source).removeprefix("\ufeff"), "scenario TOML"
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            from pkmctl.errors import toml_error

            raise ScenarioError(
                f"{where.replace('scenario file', 'scenario TOML')}: {toml_error(exc, text)}"
            ) from None
        if not data:  # an empty file is a mistake, not "the defaults, silently"
            raise ScenarioError(
                f"{where}: empty (no field set; `pkmctl scenario paper` prints a full one)"
            )
        fuzzy = data.get("fuzzy")
        fis = fuzzy.get("fis") if isinstance(fuzzy, dict) else None
        if where != "scenario TOML" and isinstance(fis, str):
            # a .fis file named by a scenario file is relative to that file's folder
            if not Path(fis).expanduser().is_absolute():
                data["fuzzy"] = fuzzy | {"fis": str(Path(source).parent / fis)}
        if changes:
            data = _changed(data, changes, known=cls().model_dump(by_alias=True))
        return cls.from_dict(data)

    def to_toml(self) -> str:
        """The scenario as TOML; :meth:`from_toml` reads it back to an equal scenario. A
        field left unset (TOML has no null) is named in a comment in its section, so that
        the text shows every field (``# force_limit = (not set; optional)``)."""
        data = self.model_dump(exclude_none=True, by_alias=True)
        lines = tomli_w.dumps(data).split("\n")
        unset = {
            name: [k for k, v in section.items() if v is None]
            for name, section in self.model_dump(by_alias=True).items()
            if isinstance(section, dict)
        }
        for name, keys in unset.items():
            if not keys or f"[{name}]" not in lines:
                continue
            at = lines.index(f"[{name}]") + 1
            while at < len(lines) and lines[at].strip() and not lines[at].startswith("["):
                at += 1  # the end of the section's own keys
            lines[at:at] = [f"# {k} = (not set; optional)" for k in keys]
        return "\n".join(lines)

    def replace(self, **changes: Any) -> Scenario:
        """A copy with top-level sections or dotted fields changed, validated again.

        ``scenario.replace(**{"timing.duration": 2.0, "disturbance.seed": 7})`` changes
        those fields alone. A section given whole replaces it, its other fields at their
        defaults: ``replace(timing={"duration": 2.0})`` of the 1 kHz ``prototype`` is a
        run at the default 20 kHz.
        """
        return Scenario.from_dict(_changed(self.model_dump(by_alias=True), changes))

    def differences(self, other: Scenario) -> list[tuple[str, Any, Any]]:
        """The fields (dotted names, as in :meth:`replace`) whose values differ from
        ``other``'s: (name, this value, other's), in the order of the TOML; name and
        description left out."""
        out: list[tuple[str, Any, Any]] = []

        def walk(a: Any, b: Any, where: str) -> None:
            if isinstance(a, dict) and isinstance(b, dict):
                for k in dict.fromkeys([*a, *b]):
                    walk(a.get(k), b.get(k), f"{where}.{k}" if where else k)
            elif a != b:
                out.append((where, a, b))

        mine, theirs = self.model_dump(by_alias=True), other.model_dump(by_alias=True)
        for key in ("name", "description"):
            mine.pop(key, None)
            theirs.pop(key, None)
        walk(mine, theirs, "")
        return out

    # ------------------------------------------------------------------ derived objects
    def plant(self) -> Mechanism:
        """The true mechanism."""
        return self.mechanism.build()

    def payload_forces(
        self, X: ArrayLike, Xd: ArrayLike | None = None, Xdd: ArrayLike | None = None
    ) -> np.ndarray:
        """The payload's share of the true plant's generalised forces, M_p Xdd + C_p(X, Xd)
        Xd + G_p (N, 3) at poses X (N, 3), rates Xd and accelerations Xdd (zeros if not
        given): what Theta's machine (:meth:`plant`) leaves out of the plant the loop runs
        (DESIGN.md §8; zeros without a payload)."""
        from pkmctl.model.machine import add_payload

        X = np.atleast_2d(np.asarray(X, dtype=float))
        Xd = np.zeros_like(X) if Xd is None else np.atleast_2d(np.asarray(Xd, dtype=float))
        Xdd = np.zeros_like(X) if Xdd is None else np.atleast_2d(np.asarray(Xdd, dtype=float))
        F = np.zeros_like(X)
        mass = float(self.payload.mass)
        if mass <= 0.0:
            return F
        geom, offset = self.plant().geometry, np.asarray(self.payload.offset, dtype=float)
        R, M, Cv, G = np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3)
        for n in range(len(X)):
            M[:], Cv[:], G[:] = 0.0, 0.0, 0.0
            add_payload(geom, mass, offset, X[n], Xd[n], Xd[n], R, M, Cv, G)
            F[n] = M @ Xdd[n] + Cv + G
        return F

    def controller_mechanism(self) -> Mechanism:
        """The controllers' model: same geometry, Theta^ = theta_scale * Theta (or the
        first 36 entries of ``controller_model.theta_ext``)."""
        p = self.plant()
        cm = self.controller_model
        if cm.theta_ext is not None:
            return p.with_theta(np.asarray(cm.theta_ext[:36], dtype=float))
        return p.with_theta(cm.theta_scale * p.theta)

    def controller_gains(self) -> Gains:
        return self.gains.build()

    def fuzzy_system(self) -> MamdaniSystem | FuzzySystem:
        """The fuzzy term's system of FSMC/AFSMC, as the loop runs it (``[fuzzy]``)."""
        return self.fuzzy.build()

    def fuzzy_offset_note(self) -> str | None:
        """A warning when the ``.fis`` file's output at s* = sdot* = 0 is not 0 (else
        None): FSMC and AFSMC then push with -K_u FLC(0, 0) when tracking is exact. The
        paper's FLC, and any file symmetric about 0, give 0."""
        if self.fuzzy.fis is None:
            return None
        system = self.fuzzy_system()
        out = system.output if isinstance(system, MamdaniSystem) else system.outputs[0]
        lo, hi = out.universe
        with warnings.catch_warnings():  # a zero-area aggregate is not this note's concern
            warnings.simplefilter("ignore", FuzzyWarning)
            rest = float(system(0.0, 0.0))
        if abs(rest) <= FUZZY_OFFSET_TOLERANCE * (hi - lo):
            return None
        push = ", ".join(f"{-k * rest:.4g}" for k in self.gains.Ku)
        return (
            f"fuzzy.fis {self.fuzzy.fis!r}: FLC(0, 0) = {rest:.4g}, not 0 (output range "
            f"[{lo:g}, {hi:g}]): FSMC and AFSMC (and afsmc-ext) add -Ku FLC(0, 0) = [{push}] "
            "(N, N m, N m on "
            "z, alpha, beta) even when tracking is exact"
        )


_AXES = ("z", "alpha", "beta")
#: Theta's units: [m (kg), I_xx, I_yy, I_zz (kg m^2)] of each of the 9 bodies (DESIGN.md §1).
_THETA_UNITS = ("kg", "kg m^2", "kg m^2", "kg m^2") * 9

#: The unit of every numeric field that has one, by its dotted name (a trajectory's under
#: ``trajectory``, whatever its kind): one for all of a list, or one per element (a
#: [z, alpha, beta] list, Theta). A field absent here has none (a count, a seed, a
#: ratio, a scaling); an ``_in_range`` field says its own. :func:`_one_line` puts it in
#: the message of a field's refusal.
UNITS: dict[str, str | tuple[str, ...]] = {
    "mechanism.r_a": "m",
    "mechanism.r_b": "m",
    "mechanism.l1": "m",
    "mechanism.l2": "m",
    "mechanism.g": "m/s^2",
    "mechanism.theta": _THETA_UNITS,
    "controller_model.theta_scale": "times the plant's Theta",
    "controller_model.theta_ext": _THETA_UNITS + ("kg",) * 4 + ("N",) * 4 + ("N s/m",) * 4,
    "gains.lam": "1/s",
    "gains.K": ("N s/m", "N m s/rad", "N m s/rad"),
    "gains.Lam": ("N", "N m", "N m"),
    "gains.Ku": ("N", "N m", "N m"),
    "gains.gamma": "1/J",
    "gains.filter_periods": "control periods",
    "gains.theta_bounds": "multiples of Theta_0; lo in (0, 1], hi in [1, 1e+06]",
    "gains.pd_kp": ("N/m", "N m/rad", "N m/rad"),
    "gains.pd_kd": ("N s/m", "N m s/rad", "N m s/rad"),
    "gains.ctc_kp": "1/s^2",
    "gains.ctc_kd": "1/s",
    "fuzzy.samples": "points",
    "trajectory.offset": ("m", "rad", "rad"),
    "trajectory.amplitude": ("m", "rad", "rad"),
    "trajectory.omega": "rad/s",
    "trajectory.phase": "rad",
    "trajectory.base_frequency": "Hz",
    "trajectory.a": ("m/s", "rad/s", "rad/s"),
    "trajectory.b": ("m/s", "rad/s", "rad/s"),
    "initial.X": ("m", "rad", "rad"),
    "initial.Xdot": ("m/s", "rad/s", "rad/s"),
    "disturbance.amplitude": ("N", "N m", "N m"),
    "disturbance.hold": "s",
    "timing.control_period": "s",
    "timing.substeps": "RK4 sub-steps per control period",
    "timing.duration": "s",
    "actuators.force_limit": "N",
    "actuators.delay_periods": "control periods",
    "payload.offset": ("m", "m", "m"),
    "sensor.counts_per_rev": "counts per motor revolution",
    "sensor.delay_periods": "control periods",
}
#: How a whole list's units read where they differ along it and are not [z, alpha, beta].
_UNITS_OF_LIST = {
    "mechanism.theta": "kg, kg m^2: [m, I_xx, I_yy, I_zz] of each of the 9 bodies",
    "controller_model.theta_ext": "Theta's kg, kg m^2; m_r kg; F_c N; F_v N s/m",
}


def _unit(key: str, index: int | None, own: str) -> str:
    """The unit of field ``key`` (its element ``index`` if given) for a message."""
    unit = UNITS.get(key, own)
    if isinstance(unit, str):
        return unit
    if index is not None:
        return unit[index]
    if len(set(unit)) == 1:
        return unit[0]
    return _UNITS_OF_LIST.get(key) or ", ".join(unit) + " for " + ", ".join(_AXES)


def _unwrap(annotation: Any, metadata: list | tuple = ()) -> tuple[Any, list, bool]:
    """An annotation without its ``Annotated`` layers and the ``None`` of an optional field:
    (the type, its constraints, whether it is optional)."""
    meta, optional = list(metadata), False
    while True:
        origin = typing.get_origin(annotation)
        if origin is Annotated:
            annotation, *more = typing.get_args(annotation)
            for m in more:
                meta.extend(m.metadata if isinstance(m, FieldInfo) else [m])
        elif origin in (typing.Union, types.UnionType):
            members = [a for a in typing.get_args(annotation) if a is not type(None)]
            if len(members) != 1:
                return annotation, meta, optional
            annotation, optional = members[0], True
        else:
            return annotation, meta, optional


def _declared(loc: tuple) -> tuple[Any, list] | None:
    """What a Scenario declares at ``loc`` (a pydantic error's: a trajectory's tag is a step
    of it, a list's index another): the annotation and its constraints, or None if ``loc``
    leads to no field."""
    annotation: Any = Scenario
    meta: list = []
    for step in loc:
        annotation, meta, _ = _unwrap(annotation, meta)
        if isinstance(step, int):
            if typing.get_origin(annotation) is not list:
                return None
            annotation, meta = typing.get_args(annotation)[0], []
            continue
        models = _models(annotation)
        tagged = [m for m in models if _tag(m) == step] if len(models) > 1 else []
        if tagged:  # a tagged union's member
            annotation, meta = tagged[0], []
            continue
        fields = {f.alias or n: f for m in models[:1] for n, f in m.model_fields.items()}
        if step not in fields:
            return None
        annotation, meta = fields[step].annotation, list(fields[step].metadata)
    return annotation, meta


def _field_names(loc: tuple) -> str:
    """The fields (their TOML names) of the model at ``loc`` in a Scenario, or '' if ``loc``
    does not lead to a model (a trajectory's tag is a step of ``loc``, as pydantic says)."""
    declared = _declared(loc)
    models = _models(_unwrap(declared[0])[0]) if declared else []
    if len(models) != 1:
        return ""
    return ", ".join(f.alias or n for n, f in models[0].model_fields.items())


def _count(meta: list) -> str:
    lo = max((m.min_length for m in meta if getattr(m, "min_length", None) is not None), default=0)
    hi = min((m.max_length for m in meta if getattr(m, "max_length", None) is not None),
             default=None)  # fmt: skip
    if hi is None:
        return f"at least {lo}"
    return str(lo) if lo == hi else f"{lo} to {hi}"


def _allowed(annotation: Any, meta: list, plural: bool = False) -> tuple[str, str, bool] | None:
    """What a field declared as ``annotation`` with constraints ``meta`` allows, from
    those declarations: (the words, the unit it states itself, whether it may be left
    out); None for a type with no words here."""
    annotation, meta, optional = _unwrap(annotation, meta)
    own = ""
    if annotation in (int, float):
        bounds = _Bounds.of(meta, integer=annotation is int)
        text, own = bounds.text(plural), bounds.unit
    elif typing.get_origin(annotation) is list:
        inner = _allowed(typing.get_args(annotation)[0], [], plural=True)
        if inner is None:
            return None
        text, own = f"{'lists' if plural else 'a list'} of {_count(meta)} {inner[0]}", inner[1]
    elif typing.get_origin(annotation) is Literal:
        text = "one of " + ", ".join(repr(a) for a in typing.get_args(annotation))
    elif annotation is str:
        text = f"text of {_count(meta)} characters" if meta else "text"
    elif models := _models(annotation):
        if len(models) == 1:
            names = ", ".join(f.alias or n for n, f in models[0].model_fields.items())
        else:
            names = "kind = " + " or ".join(repr(_tag(m)) for m in models) + ", ..."
        text = f"a table ({names})"
    else:
        return None
    return text, own, optional


def _models(annotation: Any) -> list[type]:
    """The pydantic models an annotation is or holds (a union's members, None dropped)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for a in typing.get_args(annotation) for m in _models(a)]


def _tag(model: type) -> Any:
    field = model.model_fields.get("kind")
    return None if field is None else field.default


def _loc_text(parts: list) -> str:
    """A field as the messages name it: ``mechanism.l1[0]``, ``trajectory.a[2][0]``."""
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else ("." if out else "") + str(p)
    return out or "scenario"


def field_reference() -> str:
    """Every scenario field with what it allows and its unit, as a Markdown table, made
    from the declarations the messages are made of (docs/architecture.md holds it; a test
    keeps the two the same). The ranges were written nowhere but in the messages (a
    tester planning a 2-hour run learned of the 1-hour limit from its refusal)."""
    from pkmctl.parts import get_part, names

    rows: list[tuple[str, str, str]] = []

    def walk(model: Any, prefix: str, kind: str | None) -> None:
        for n, f in model.model_fields.items():
            key = f"{prefix}.{f.alias or n}" if prefix else f.alias or n
            annotation, meta, _ = _unwrap(f.annotation, list(f.metadata))
            models = _models(annotation)
            if models and typing.get_origin(annotation) is not list:
                if len(models) > 1:  # a tagged union: its kinds, then each one's fields
                    tags = ", ".join(repr(_tag(m)) for m in models)
                    rows.append((f"`{key}.kind`", f"one of {tags}", ""))
                for m in models:
                    walk(m, key, _tag(m) if len(models) > 1 else kind)
                continue
            if kind and n == "kind":
                continue
            shown = f"{key} (kind {kind!r})" if kind and not key.endswith(".kind") else key
            allowed = _allowed(f.annotation, list(f.metadata))
            if key == "logging.every":
                words = "an integer in [1, the run's control periods]"
            elif key.endswith(".kind") and prefix in ("plant", "sensor", "actuators"):
                part = "actuator" if prefix == "actuators" else prefix
                own = [x for x in names(part) if get_part(part, x).builtin]
                words = f"one of {', '.join(repr(x) for x in own)}, or a part of your own"
            else:
                words = allowed[0] + (", or left out" if allowed[2] else "") if allowed else "?"
            unit = _unit(key, None, allowed[1] if allowed else "")
            rows.append((f"`{shown}`", words, unit))

    walk(Scenario, "", None)
    lines = ["| field | allowed | unit |", "|---|---|---|"]
    lines += [f"| {k} | {w} | {u} |" for k, w, u in rows]
    return "\n".join(lines) + "\n"


def _one_line(exc: ValidationError) -> str:
    """The first of pydantic's errors in one line: the field, the value and what is allowed.

    A check of ours (a ``ValueError``) says it all itself; pydantic's own (a bound, a
    list's length, a type, nan) names one bound at best, so it is worded anew from what
    the field declares (:func:`_allowed`: its bounds, length, choices) and its unit
    (:data:`UNITS`): ``disturbance.amplitude = [5.0, 5.0]: must be a list of 3 finite
    numbers in [0, 1e+06] (N, N m, N m for z, alpha, beta)``."""
    err = exc.errors()[0]
    # the trajectory's kind tag ("sinusoid", "fourier") is pydantic's, not a field
    parts = [p for i, p in enumerate(err["loc"]) if not (i == 1 and err["loc"][0] == "trajectory")]
    loc = _loc_text(parts)
    if err["type"] == "union_tag_invalid":  # an unknown trajectory kind
        ctx = err.get("ctx", {})
        return (
            f"{loc}.kind = {short_repr(ctx.get('tag'))}: must be one of "
            f"{str(ctx.get('expected_tags', '')).replace(chr(39), '')}"
        )
    msg = err["msg"].removeprefix("Value error, ")
    if err["type"] == "extra_forbidden":  # a typo: the fields the section has
        allowed = _field_names(err["loc"][:-1])
        where = _loc_text(parts[:-1])
        return f"{loc}: unknown field" + (f" ({where}: {allowed})" if allowed else "")
    if err["type"] in ("value_error", "assertion_error"):
        if msg.startswith("= "):  # a range check that shows the value: "field = v: ..."
            return f"{loc} {msg}"
        if msg.startswith("."):  # a section's check naming one of its fields: ".f = v: ..."
            return f"{loc}{msg}"
        return f"{loc}: {msg}" if loc != "scenario" else msg
    declared = _declared(err["loc"])
    allowed = _allowed(*declared) if declared is not None else None
    if allowed is not None:  # a bound, a length, a type, nan: say the whole range
        words, own, optional = allowed
        key = ".".join(p for p in parts if isinstance(p, str))
        index = next((p for p in parts if isinstance(p, int)), None)
        unit = _unit(key, index, own)
        msg = (
            f"must be {words}"
            + (f" ({unit})" if unit else "")
            + (", or left out" if optional else "")
        )
    value = err.get("input")
    shown = short_repr(value)
    if shown != repr(value):
        if isinstance(value, list):  # its length, which the cut text hides (35 for 36)
            shown += f" ({len(value)} numbers)"
    more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
    return f"{loc} = {shown}: {msg}{more}"


#: The machine as built (DESIGN.md §7; docs/machine.md says which numbers are catalogue
#: values and which are assumptions).
PROTOTYPE_PLANT: dict[str, Any] = {
    "kind": "rigid",
    "rotor_inertia": 0.277e-4,  # kg m^2, ECMA-C20604SS (catalogue)
    "screw_lead": 0.01,  # m (assumed)
    "friction_coulomb": 30.0,  # N (assumed)
    "friction_viscous": 300.0,  # N s/m (assumed)
    "friction_velocity": 1e-3,  # m/s (assumed)
}
PROTOTYPE_DRIVE: dict[str, Any] = {
    "kind": "drive",
    "peak_torque": 3.82,  # N m (catalogue)
    "efficiency": 0.9,  # (assumed)
    "lag": 2e-4,  # s (assumed)
    "max_speed": 5000.0,  # rpm (the paper)
    "delay_periods": 1,
}
#: The controllers' model of the machine as built: the same catalogue values and
#: assumptions as the plant (a designer who has the datasheet and measured the friction).
PROTOTYPE_MODEL: dict[str, Any] = {
    "theta_scale": 0.85,
    "rotor_inertia": PROTOTYPE_PLANT["rotor_inertia"],
    "friction_coulomb": PROTOTYPE_PLANT["friction_coulomb"],
    "friction_viscous": PROTOTYPE_PLANT["friction_viscous"],
    "friction_velocity": PROTOTYPE_PLANT["friction_velocity"],
}
#: RK4 sub-steps per 1 ms period of the prototype, chosen by measurement (docs/machine.md).
PROTOTYPE_SUBSTEPS = 10

#: The sections every prototype scenario shares: the 1 kHz loop and the machine as built.
PROTOTYPE_MACHINE: dict[str, Any] = {
    "timing": {"control_period": 1e-3, "substeps": PROTOTYPE_SUBSTEPS, "duration": 10.0},
    "plant": PROTOTYPE_PLANT,
    "sensor": {"kind": "encoder", "counts_per_rev": 160_000},
    "actuators": PROTOTYPE_DRIVE,
}

#: Built-in scenarios as data (DESIGN.md §4).
BUILTINS: dict[str, dict[str, Any]] = {
    "paper": {
        "name": "paper",
        "description": "The paper's experiment (eq. 54, Table 3, 15 % model error, 2 N "
        "disturbance), sampled at 20 kHz: the discrete equivalent of its continuous design.",
    },
    "paper-1khz": {
        "name": "paper-1khz",
        "description": "The paper's experiment with the same gains on a 1 kHz servo loop.",
        "timing": {"control_period": 1e-3, "substeps": 20, "duration": 10.0},
    },
    "prototype": {
        "name": "prototype",
        "description": "The paper's experiment (trajectory, initial state, disturbance, Table 3 "
        "gains, 15 % model error) on the machine as built (docs/machine.md): 1 kHz motion "
        "controller, servo drives on ball screws (peak torque, torque lag), reflected rotor "
        "inertia, joint friction, 17-bit encoders with forward kinematics, one period of "
        "computation delay.",
        **PROTOTYPE_MACHINE,
    },
    "prototype-model": {
        "name": "prototype-model",
        "description": "prototype, with the controllers' model given the reflected rotor "
        "inertia and the joint friction (the plant's values): rotor and friction feed-forward "
        "in every controller (PD: friction only). Theta^ still 0.85 Theta.",
        **PROTOTYPE_MACHINE,
        "controller_model": PROTOTYPE_MODEL,
    },
    "prototype-tuned": {
        "name": "prototype-tuned",
        "description": "prototype-model, with the sliding-mode controllers' beta-axis gains "
        "(K, Lam, Ku) cut tenfold for the 1 kHz loop, and the run starting on the trajectory "
        "(X_d(0), Xdot_d(0)) instead of at rest at home: no saturated start.",
        **PROTOTYPE_MACHINE,
        "controller_model": PROTOTYPE_MODEL,
        "gains": {"K": [1000.0, 200.0, 20.0], "Lam": [150.0, 40.0, 4.0], "Ku": [50.0, 30.0, 3.0]},
        "initial": {"X": [0.7, 0.0, math.pi / 6], "Xdot": [0.04, math.pi / 3, 0.0]},
    },
}
