"""The controllers as objects a user (or a hardware loop) steps from Python.

Contract of a :class:`Controller` (like SciPy's ``OdeSolver``):

1. It is built from a controller model (a :class:`~pkmctl.Mechanism`, never the
   plant's), :class:`~pkmctl.Gains` and the control period, and runs the compiled step
   of a registered controller part (:mod:`pkmctl.parts`): the same code as the loop.
2. ``step(X, Xdot, X_d, Xdot_d, Xddot_d)`` returns the task-space force F (3,) and
   advances the controller's state by one period. A non-finite input (NaN, inf) raises
   :class:`~pkmctl.errors.NonFiniteInputError` and leaves the state as it was: one bad
   sample from a sensor must not poison the s-dot filter or Theta^ for good. (The
   compiled closed loop checks its state in its own way and does not pay for this.)
3. Its whole state is :attr:`Controller.state` (a copy); :meth:`Controller.restore`
   puts a snapshot back (bit-identical continuation), :meth:`Controller.reset` the
   initial state (Theta^ kept if asked: after an e-stop, restart the s-dot filter alone).
4. One instance may be stepped from several threads: a lock keeps each step whole (the
   compiled step releases the GIL, and two threads' inputs mixed in its one set of
   buffers: a tester).
5. The first step compiles (seconds on an empty cache, ~10 ms from it): call
   :meth:`Controller.prepare` before a real-time loop.
"""

from __future__ import annotations

import math
import numbers
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numba
import numpy as np
from numpy.typing import ArrayLike

from pkmctl._jit import specialise
from pkmctl.control.gains import Gains
from pkmctl.control.sliding import SLIDING_STATE
from pkmctl.errors import InvalidPoseError, NonFiniteInputError, NonFiniteOutputError
from pkmctl.fuzzy import FLC, FuzzySystem, MamdaniSystem
from pkmctl.fuzzy.term import term_system
from pkmctl.model.mechanism import Mechanism
from pkmctl.parts import PartContext, controller_step, get_part, global_values, names

if TYPE_CHECKING:
    from pkmctl.sim.scenario import Scenario

_HALF_PI = math.pi / 2

__all__ = [
    "AFSMC",
    "CONTROLLERS",
    "CTC",
    "FSMC",
    "PD",
    "SMC",
    "Controller",
    "ControllerState",
    "make_controller",
]


@dataclass(frozen=True, eq=False)
class ControllerState:
    """A snapshot of a controller's state.

    s_prev : (3,) s at the previous step; sdot : (3,) filtered sdot estimate (both None
    for a controller without a sliding surface); theta_hat : (36,) Theta^ (AFSMC), (48,)
    Theta_ext^ (afsmc-ext), or None; steps : control periods taken; raw : the part's
    whole state array.
    """

    s_prev: np.ndarray | None
    sdot: np.ndarray | None
    theta_hat: np.ndarray | None
    steps: int
    raw: np.ndarray
    #: raw as taken (a copy): which of raw and a named field was edited, for restore
    taken: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __eq__(self, other: object) -> bool:
        """The same steps and numbers; NaN equals NaN (a diverged state's snapshot equals
        itself), and ``taken`` is not compared. (A dataclass's ``==`` compared the arrays
        as tuples and raised NumPy's "truth value of an array is ambiguous".)"""
        if not isinstance(other, ControllerState):
            return NotImplemented
        if self.steps != other.steps:
            return False
        for a, b in zip(self._numbers(), other._numbers(), strict=True):
            if (a is None) != (b is None):
                return False
            if a is not None and not np.array_equal(a, b, equal_nan=True):
                return False
        return True

    __hash__ = None  # type: ignore[assignment]  # (its arrays can change: no dict key)

    def _numbers(self) -> tuple[np.ndarray | None, ...]:
        return self.s_prev, self.sdot, self.theta_hat, self.raw


def _entry(p, state, work, y, ref, X, Xdot, X_d, Xdot_d, Xddot_d, F, saved):
    """One step from Python's five vectors: 1; or none (0) if an input is non-finite, the
    state untouched; or 2 if finite inputs gave a force that is not, the state restored
    from ``saved`` (scratch of its size). The vectors are copied into y and ref here, in
    compiled code (cheaper than five NumPy slice assignments)."""
    for i in range(3):
        y[i], y[3 + i] = X[i], Xdot[i]
        ref[i], ref[3 + i], ref[6 + i] = X_d[i], Xdot_d[i], Xddot_d[i]
    for i in range(y.shape[0]):
        if not math.isfinite(y[i]):
            return 0
    for i in range(ref.shape[0]):
        if not math.isfinite(ref[i]):
            return 0
    for i in range(state.shape[0]):
        saved[i] = state[i]
    controller_step(p, state, work, y, ref, F)
    for i in range(3):
        if not math.isfinite(F[i]):
            for j in range(state.shape[0]):
                state[j] = saved[j]
            return 2
    return 1


def _as_vec3(a, name: str) -> np.ndarray:
    """a as a C-contiguous float64 (3,) array (the compiled entry's one argument type)."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.shape == (3,):
        if a.flags.c_contiguous and a.flags.aligned and a.flags.writeable:
            return a
    try:
        a = np.array(a, dtype=np.float64)  # a copy: contiguous, aligned, writeable
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {a!r:.80}: expected 3 numbers") from None
    if a.shape != (3,):
        raise ValueError(f"{name}: expected shape (3,), got {a.shape}")
    return a


_STEP_INPUTS = (("X", 0), ("Xdot", 3), ("X_d", 6), ("Xdot_d", 9), ("Xddot_d", 12))


def _non_finite(buf: np.ndarray) -> str:
    """The first non-finite input of ``buf`` = [X, Xdot, X_d, Xdot_d, Xddot_d], for messages."""
    for name, i in _STEP_INPUTS:
        v = buf[i : i + 3]
        if not np.isfinite(v).all():
            return f"{name} = [{', '.join(repr(float(x)) for x in v)}]"
    return "an input"


class Controller:
    """One registered controller, stepped from Python (see the module docstring).

    ``Controller(model, gains, period=T_c, name="pd")`` builds any registered controller;
    the subclasses :class:`SMC`, :class:`FSMC`, :class:`AFSMC`, :class:`PD` and
    :class:`CTC` fix the name.
    ``flc`` is the fuzzy term's system of FSMC/AFSMC (default: the paper's FLC): any
    two-input, one-output MamdaniSystem or FuzzySystem, e.g. ``read_fis(path)``
    (:func:`pkmctl.fuzzy.term.term_system`; ValueError otherwise).
    """

    name: ClassVar[str] = ""

    def __init__(
        self,
        model: Mechanism,
        gains: Gains | None = None,
        *,
        period: float,
        flc: MamdaniSystem | FuzzySystem | None = None,
        name: str | None = None,
        scenario=None,
    ) -> None:
        if not isinstance(model, Mechanism):
            raise TypeError("model: expected a pkmctl.Mechanism (the controller's own model)")
        if isinstance(period, bool) or not isinstance(period, numbers.Real):
            raise ValueError(f"period = {period!r}: must be a number > 0 (s)")
        if not 0 < float(period) < math.inf:
            raise ValueError(f"period = {period!r}: must be > 0 (s)")
        self.name = name or type(self).name
        self.part = get_part("controller", self.name)
        self.model = model
        if gains is not None and not isinstance(gains, Gains):
            raise TypeError(
                f"gains: expected a pkmctl.Gains (e.g. Gains(K=...), or "
                f"scenario.controller_gains()), got {type(gains).__name__} {gains!r:.80}"
            )
        self.gains = Gains() if gains is None else gains
        self.period = float(period)
        # the fuzzy term's system (two inputs, one output), as the loop compiles it
        self.flc = FLC() if flc is None else term_system(flc)
        # with a scenario, what the loop gives: its [controller_model] terms (rotor
        # inertia, friction) reach the controller's feed-forward
        plant = model if scenario is None else scenario.plant()
        ctx = PartContext(plant, model, self.gains, self.period, self.flc, scenario)
        self.params, self._initial, self._work = self.part.make(ctx)
        self._state = self._initial.copy()
        self._steps = 0
        self._lock = threading.Lock()
        self._new_buffers()
        self._step = specialise(_entry, (self.part.params,), self.part.sources, refcount=False,
                                values=global_values([self.part]))  # fmt: skip

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(name={self.name!r}, period={self.period:g} s, "
            f"{self._steps} steps taken)"
        )

    @classmethod
    def from_scenario(cls, scenario: Scenario | str, name: str | None = None) -> Controller:
        """Controller ``name`` exactly as a simulation of ``scenario`` builds it: the
        controllers' model (``[controller_model]``, with its rotor inertia and friction
        feed-forward), gains, control period and fuzzy system. For a hardware loop on
        the machine the scenario describes (e.g. ``prototype-tuned``), where
        ``make_controller(name, scenario.controller_mechanism(), ...)`` would leave out
        the feed-forward. ``name`` defaults to the class's (``PD.from_scenario(sc)`` is
        PD; it was AFSMC, unsaid: a tester), and to "afsmc" on :class:`Controller`; a
        name another class's is refused. The step assumes the scenario's control
        period between calls: run the hardware loop at it."""
        from pkmctl.sim.scenario import Scenario

        if isinstance(scenario, str):
            scenario = Scenario.builtin(scenario)
        if not isinstance(scenario, Scenario):
            raise TypeError(
                f"scenario: expected a pkmctl.Scenario or a built-in name, got {scenario!r}"
            )
        if name is None:
            name = cls.name or "afsmc"
        key = name.lower() if isinstance(name, str) and name.lower() in CONTROLLERS else name
        if not isinstance(key, str) or key not in names("controller"):
            raise ValueError(f"controller = {name!r}: must be one of {names('controller')}")
        if cls is not Controller and key != cls.name:
            raise ValueError(
                f"{cls.__name__}.from_scenario: controller = {name!r} is not {cls.name!r}; "
                f"Controller.from_scenario(scenario, {key!r}) builds it"
            )
        kind = CONTROLLERS.get(key, Controller) if cls is Controller else cls
        return kind(scenario.controller_mechanism(), scenario.controller_gains(),
                    period=scenario.timing.control_period, flc=scenario.fuzzy_system(),
                    name=key, scenario=scenario)  # fmt: skip

    def _new_buffers(self) -> None:
        # One buffer [y | ref], so a message can name the first non-finite input.
        self._io = np.empty(15)
        self._y, self._ref = self._io[0:6], self._io[6:15]
        self._saved = np.empty_like(self._state)  # the state before a step (see _entry)
        self._fast = None  # the compiled entry point, once known (see step)

    @property
    def _adaptive(self) -> bool:
        return self.part.log_name == "theta_hat"

    def reset(self, *, keep_theta_hat: bool = False) -> None:
        """Restore the initial state (no previous s, sdot = 0, Theta^ = the model's Theta);
        with ``keep_theta_hat``, Theta^ stays as adapted (after an e-stop: the s-dot
        filter starts again, what the adaptation learnt is kept)."""
        with self._lock:
            keep = self._state[SLIDING_STATE:].copy() if keep_theta_hat else None
            self._state[:] = self._initial
            if keep is not None and self._adaptive:
                self._state[SLIDING_STATE:] = keep
            self._steps = 0

    def restore(self, snapshot: ControllerState) -> None:
        """Put back a state taken from :attr:`state` (of this controller, or of one built
        the same way): the steps that follow are those that followed the snapshot, bit
        for bit. ``s_prev``, ``sdot`` and ``theta_hat`` are copies of parts of ``raw``:
        whichever of a field and its part of raw was changed is put back (None: raw's);
        both changed apart is refused."""
        raw = getattr(snapshot, "raw", None)
        if not isinstance(raw, np.ndarray) or raw.shape != self._state.shape:
            raise ValueError(
                f"snapshot: expected a {self.name} controller's state (raw of shape "
                f"{self._state.shape}), got {type(snapshot).__name__}"
            )
        state, named = self._edited(snapshot, raw)
        # (a NaN state was put back, and every later step blamed "these finite inputs";
        # steps = -5 printed "-5 steps taken": a code reader)
        if not np.isfinite(state).all():
            bad = int(np.flatnonzero(~np.isfinite(state))[0])
            where = f"raw[{bad}]"
            for name, part in named.items():
                if part.start <= bad < part.stop:
                    where = f"{name}[{bad - part.start}]"
            raise ValueError(
                f"snapshot.{where} = {float(state[bad])!r}: a {self.name} controller's state "
                f"must be finite"
            )
        steps = getattr(snapshot, "steps", None)
        if isinstance(steps, bool) or not isinstance(steps, numbers.Integral) or steps < 0:
            raise ValueError(f"snapshot.steps = {steps!r}: must be an integer >= 0")
        with self._lock:
            self._state[:] = state
            self._steps = int(snapshot.steps)

    def _edited(self, snapshot: ControllerState, raw: np.ndarray) -> tuple[np.ndarray, dict]:
        """The state a snapshot stands for, and which named fields it took (their parts). The
        named fields are copies of raw's parts: restore put back raw alone, so an edited
        Theta^ (or a NaN in it) was dropped without a word (a tester). Whichever of a
        field and its part of raw was edited since :attr:`state` took them is used (the
        copy taken says which); a field left as None is raw's; both edited apart is
        refused, not guessed between."""
        state, used = raw.copy(), {}
        taken = getattr(snapshot, "taken", None)
        if not isinstance(taken, np.ndarray) or taken.shape != raw.shape:
            taken = None
        for name, part in self._named_parts().items():
            value = getattr(snapshot, name, None)
            if value is None:
                continue
            if part is None:
                raise ValueError(
                    f"snapshot.{name}: a {self.name} controller has none: leave it None"
                )
            try:
                value = np.asarray(value, dtype=float)
                got = f"shape {value.shape}"
            except (TypeError, ValueError):
                value, got = None, type(getattr(snapshot, name)).__name__
            if value is None or value.shape != raw[part].shape:
                raise ValueError(
                    f"snapshot.{name}: expected None or an array of shape {raw[part].shape} "
                    f"(a copy of snapshot.raw[{part.start}:{part.stop}]), got {got}"
                )
            if np.array_equal(value, raw[part], equal_nan=True) or (
                taken is not None and np.array_equal(value, taken[part], equal_nan=True)
            ):
                continue  # as raw holds it, or as taken while raw was edited: raw's
            if taken is not None and np.array_equal(raw[part], taken[part], equal_nan=True):
                state[part], used[name] = value, part  # the field was edited: its values
                continue
            i = int(np.flatnonzero(value != raw[part])[0])
            why = "both were changed" if taken is not None else "which was changed is unknown"
            raise ValueError(
                f"snapshot.{name}[{i}] = {float(value[i])!r} and snapshot.raw"
                f"[{part.start + i}] = {float(raw[part][i])!r} differ: {name} is a copy of "
                f"that part of raw, and {why}; make them equal, or set {name} = None to "
                f"put back raw's"
            )
        return state, used

    def prepare(self) -> float:
        """Compile the step (or load it from the disk cache) now, not at the first call
        of a real-time loop; the seconds it took. The state is not touched."""
        t0 = time.perf_counter()
        with self._lock:
            if self._fast is None:
                vec = np.zeros(3)
                args = (self.params, self._state, self._work, self._y, self._ref,
                        vec, vec, vec, vec, vec, np.empty(3), self._saved)  # fmt: skip
                sig = tuple(numba.typeof(a) for a in args)
                self._step.compile(sig)
                self._fast = self._step.overloads[sig].entry_point
        return time.perf_counter() - t0

    def _named_parts(self) -> dict[str, slice | None]:
        """The parts of the state array that :attr:`state` names (None: not this
        controller's)."""
        n = self._state.shape[0]
        sliding = n >= SLIDING_STATE and self.name in ("smc", "fsmc", "afsmc", "afsmc-ext")
        return {
            "s_prev": slice(0, 3) if sliding else None,
            "sdot": slice(3, 6) if sliding else None,
            "theta_hat": slice(SLIDING_STATE, n) if self._adaptive else None,
        }

    @property
    def state(self) -> ControllerState:
        st = self._state
        named = {k: None if part is None else st[part].copy()
                 for k, part in self._named_parts().items()}  # fmt: skip
        return ControllerState(**named, steps=self._steps, raw=st.copy(), taken=st.copy())

    def step(
        self, X: ArrayLike, Xdot: ArrayLike, X_d: ArrayLike, Xdot_d: ArrayLike, Xddot_d: ArrayLike
    ) -> np.ndarray:
        """One control period: the task-space force F (3,) (N, N m, N m on z, alpha,
        beta) for the measured (X, Xdot), m and rad, m/s and rad/s. One call is one
        control period of the controller's ``period``: a missed period is not made up.

        F is not split, limited nor delayed: the limb forces are
        ``model.actuator_forces(X, F)``, and the drives' limits are the caller's to apply.

        Raises :class:`~pkmctl.errors.NonFiniteInputError` (the state unchanged) if any
        input holds NaN or inf, :class:`~pkmctl.errors.NonFiniteOutputError` (the state
        unchanged) if finite inputs give a force that is not (inputs so large that it
        overflows), :class:`~pkmctl.errors.InvalidPoseError` (the state unchanged) if X
        or X_d is outside the model's valid set (z > 0, |alpha|, |beta| < pi/2), and
        ``ValueError`` if one is not 3 numbers. Only that is checked: a glitch inside
        the valid set (z = 5 m, a 10 m/s velocity sample) gives the force the law
        computes for it (-215 kN for z = 5 m on AFSMC) and moves Theta^. Check your
        measurements' plausibility (the machine's stroke and speeds) before the step.
        """
        args = (
            self.params, self._state, self._work, self._y, self._ref,
            _as_vec3(X, "X"), _as_vec3(Xdot, "Xdot"), _as_vec3(X_d, "X_d"),
            _as_vec3(Xdot_d, "Xdot_d"), _as_vec3(Xddot_d, "Xddot_d"), np.empty(3),
            self._saved,
        )  # fmt: skip
        for name, x in (("X", args[5]), ("X_d", args[7])):
            bad = x[0] <= 0.0 or abs(x[1]) >= _HALF_PI or abs(x[2]) >= _HALF_PI
            if bad and math.isfinite(x[0] + x[1] + x[2]):  # NaN, inf: refused as such below
                raise InvalidPoseError(
                    f"{self.name} step: {name} = {x.tolist()} is not a valid pose (z > 0, "
                    "|alpha|, |beta| < pi/2); the controller's state is unchanged"
                )
        with self._lock:
            return self._locked_step(args)

    def _locked_step(self, args: tuple) -> np.ndarray:
        # The compiled entry checks the 15 inputs before it steps (a few ns; the loop
        # has its own fast path and never calls it).
        if self._fast is None:
            ok = self._step(*args)
            # Every later call has the same argument types (the vectors are made so by
            # _as_vec3), so call the compiled entry point for them directly: Numba's
            # dispatcher would spend ~2.5 us per call re-deriving the bundle's type.
            sig = tuple(numba.typeof(a) for a in args)
            cres = self._step.overloads.get(sig)
            self._fast = cres.entry_point if cres is not None else self._step
        else:
            ok = self._fast(*args)
        if ok == 0:
            raise NonFiniteInputError(
                f"{self.name} step: {_non_finite(self._io)} is not finite "
                f"(the controller's state is unchanged)"
            )
        F = args[-2]
        if ok == 2:  # finite inputs too large for the law (Xdot = 1e300)
            raise NonFiniteOutputError(
                f"{self.name} step: the force F = {F.tolist()} is not finite for these finite "
                f"inputs (X = {args[5].tolist()}, Xdot = {args[6].tolist()}); the "
                "controller's state is unchanged"
            )
        self._steps += 1
        return F

    def __deepcopy__(self, memo) -> Controller:
        """An independent controller: its own state and work, the same (immutable) params."""
        import copy

        twin = copy.copy(self)
        twin._lock = threading.Lock()
        twin._state, twin._initial = self._state.copy(), self._initial.copy()
        twin._work = copy.deepcopy(self._work, memo)
        twin._new_buffers()
        return twin

    def __getstate__(self) -> dict:
        d = self.__dict__.copy()
        del d["_step"], d["part"], d["_fast"], d["_lock"]  # made again on unpickling
        return d

    def __setstate__(self, d: dict) -> None:
        self.__dict__.update(d)
        self._lock = threading.Lock()
        self.part = get_part("controller", self.name)
        self._step = specialise(_entry, (self.part.params,), self.part.sources, refcount=False,
                                values=global_values([self.part]))  # fmt: skip
        self._new_buffers()  # pickle does not keep _y and _ref as views of _io


class SMC(Controller):
    """Sliding mode control with a boundary layer (eq. 25)."""

    name = "smc"


class FSMC(Controller):
    """Fuzzy sliding mode control: the switching term replaced by the FLC (eq. 26)."""

    name = "fsmc"


class AFSMC(Controller):
    """Adaptive fuzzy sliding mode control: regressor-based model with Theta^ adapted (eq. 46)."""

    name = "afsmc"

    @property
    def gamma_vec(self) -> np.ndarray:
        return self.params.gamma_vec

    @property
    def theta_min(self) -> np.ndarray:
        return self.params.theta_min

    @property
    def theta_max(self) -> np.ndarray:
        return self.params.theta_max


class PD(Controller):
    """PD in task space plus the model's gravity (a baseline, DESIGN.md §6)."""

    name = "pd"


class CTC(Controller):
    """Computed torque (a baseline, DESIGN.md §6)."""

    name = "ctc"


#: The controllers with a class of their own, by name; every other registered one
#: (afsmc-ext, a user's: :func:`pkmctl.parts.names`) is a plain :class:`Controller`.
CONTROLLERS: dict[str, type[Controller]] = {c.name: c for c in (SMC, FSMC, AFSMC, PD, CTC)}


def make_controller(name: str, model: Mechanism, gains: Gains | None = None, **kw) -> Controller:
    """Build any registered controller by name ("smc", "fsmc", "afsmc", "afsmc-ext", "pd",
    "ctc", or a user's part)."""
    if not isinstance(name, str):
        raise ValueError(f"controller = {name!r}: must be one of {names('controller')}")
    key = name.lower() if name.lower() in CONTROLLERS else name
    cls = CONTROLLERS.get(key, Controller)
    return cls(model, gains, name=key, **kw)
