"""The parts of the closed loop: their contract, their registries, and how users add one.

Every control period the loop runs sensor → controller → actuator → plant (DESIGN.md
§6). A *part* is

1. a **parameter bundle**: an instance of a ``typing.NamedTuple`` class of arrays and
   floats. Its *type* selects the compiled step functions (one class, one part); the
   loop is compiled once per combination of the four types and cached on disk;
2. a **state**: a float64 array of the size the part declares, owned by the loop,
   advanced in place, returned in ``Result.final_state[kind]``;
3. a **work** tuple: the arrays a part needs as scratch, made once per run by its
   ``work(p)`` function (or ``work=n``: one float64 array of n), so no step allocates;
4. **step functions**, compiled without reference counting (they must not allocate or
   return arrays). Their signatures, by kind (all arrays float64, shapes fixed):

   ========== ================================================================
   plant      ``derivative(p, x, tau, dist, work, dx)``: dx = dx/dt at x under the
              limb forces tau (4,) and the task-space disturbance dist (3,). x
              starts with [X (3), Xdot (3)]; the rest is the plant's own.
              ``observe(p, x, tau, work, q, F)``: the true limb lengths q (4,) and
              the task-space force F = J(X)^T tau (3,), for the log; called right
              after ``derivative`` at the same x (it may reuse ``work``).
   sensor     ``measure(p, state, work, x, y)``: what the controller sees,
              y = [X^ (3), Xdot^ (3)], from the plant state x at the sample time.
   controller ``step(p, state, work, y, ref, F)``: the task-space force F (3,) from
              y (6,) and ref = [X_d, Xdot_d, Xddot_d] (9,).
   actuator   ``command(p, state, work, y, F, cmd)``: the limb commands cmd (4,) from
              F at the measured pose; ``force(p, state, cmd, tau)``: the limb forces
              tau (4,) that reach the plant. The first ``continuous`` entries of an
              actuator's state are integrated with the plant by RK4 through
              ``derivative(p, state, cmd, dstate)`` (a drive's torque lag).
   ========== ================================================================

   The limb Jacobian at the measured pose is computed once a period, not twice: a
   controller whose step leaves it in its work declares where (``limb_jacobian``, the
   path of a (4, 3) array in its work tuple, e.g. ``(0, 5)``: the Jacobian at y[:3] with
   the controllers' model, ``ctx.model``, bit for bit what
   :func:`pkmctl.model.kinematics.limb_jacobian` gives), and an actuator that can use it
   has ``command_at(p, state, work, y, F, Jq, cmd)``, ``command`` given that Jacobian.
   The loop calls ``command_at`` when both sides have it, else ``command``. Every
   built-in controller (afsmc-ext included) and both built-in actuators do (it saves
   ~0.1 µs a period).

   A plant may instead be *stepped* outside compiled code (another engine, e.g. MuJoCo):
   it registers a ``stepper(p, ctx, h)`` that returns an object with ``reset(x)``,
   ``step(tau, dist)`` (one sub-step of h seconds under held tau (4,) and dist (3,)) and
   ``read(x, q) -> status``, and no ``derivative``; the loop of :mod:`pkmctl.sim.stepped`
   then runs the compiled sensor, controller, actuator and ``observe`` once a period and
   the stepper between periods.

   A controller may also log a row per period (``log(p, state, row)``, ``log_size``
   and ``log_name``; AFSMC logs Θ̂ as ``theta_hat``), and so may a sensor, right after
   ``measure`` (the encoder logs its quantised lengths q̂ as ``q_measured``). A sensor
   that cannot measure (forward kinematics failed) writes NaN into y: the loop stops
   there and :func:`pkmctl.simulate` raises ``SimulationDiverged`` naming the time.
5. optionally a **report**, ``report(p, final_state) -> dict``, plain Python, run once
   after the loop: what the part counted (the drive: speed-limit violations), put into
   ``Result.info``; an actuator may state its **limits**, ``limits(p) -> (force, speed)``
   (N per limb, m/s of limb speed; inf: none), which the loop's metrics count periods
   against (time at the force limit, time over the speed limit, peak limb speed).

Each kind has a registry (name → :class:`Part`); scenarios and the CLI choose parts by
name. A user adds one from their own module with a decorator
(:func:`register_controller`, :func:`register_sensor`, :func:`register_actuator`,
:func:`register_plant`) without editing pkmctl; see docs/parts.md.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import inspect
import marshal
import os
import re
import site
import sys
import sysconfig
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import CodeType, ModuleType
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol, TypeVar

import numpy as np
from numba import njit
from numba.core import types
from numba.extending import overload

from pkmctl._jit import JIT_OPTIONS, NO_REFCOUNT
from pkmctl.errors import PkmctlError, short_repr

if TYPE_CHECKING:
    from pkmctl.control.gains import Gains
    from pkmctl.fuzzy import FuzzySystem, MamdaniSystem
    from pkmctl.model import Mechanism

__all__ = [
    "KINDS",
    "Part",
    "PartContext",
    "PartError",
    "get_part",
    "names",
    "register_actuator",
    "register_controller",
    "register_plant",
    "register_sensor",
]

#: The four kinds of part, in the order the loop runs them, and their step functions.
ROLES: dict[str, dict[str, int]] = {
    "sensor": {"measure": 5, "log": 3},
    "controller": {"step": 6, "log": 3},
    "actuator": {"command": 6, "force": 4, "derivative": 4, "command_at": 7},
    "plant": {"derivative": 6, "observe": 6},
}
KINDS = tuple(ROLES)
_REQUIRED = {
    "sensor": ("measure",),
    "controller": ("step",),
    "actuator": ("command", "force"),
    "plant": ("derivative", "observe"),
}


class PartError(PkmctlError, ValueError):
    """A part that cannot be registered or built (one line: the part, the field, why)."""


@dataclass(frozen=True)
class PartContext:
    """What a part's ``build`` may use to make its parameter bundle.

    ``scenario`` is the :class:`~pkmctl.Scenario` of the run (None when a controller is
    built alone, e.g. for a hardware loop); ``plant`` the true machine, ``model`` the
    controllers' model (never the plant's parameters), ``gains`` the scenario's gains,
    ``period`` the control period T_c (s), ``flc`` the fuzzy system of FSMC/AFSMC (the
    scenario's ``[fuzzy]`` system, compiled as :func:`pkmctl.fuzzy.term.term_system` says:
    the paper's FLC by default).
    """

    plant: Mechanism
    model: Mechanism
    gains: Gains
    period: float
    flc: MamdaniSystem | FuzzySystem
    scenario: Any = None


@dataclass(frozen=True, eq=False)
class Part:
    """One registered part (see the module docstring for the contract)."""

    kind: str
    name: str
    params: type
    build: Callable[[PartContext], Any]
    functions: dict[str, Callable]
    state_size: Callable[[Any], int]
    make_work: Callable[[Any], tuple]
    initial_state: Callable[[Any], np.ndarray] | None = None
    continuous: int = 0
    log_size: Callable[[Any], int] = lambda p: 0
    log_name: str = ""
    description: str = ""
    label: str = ""
    surface_gain: Callable[[Any, Any], np.ndarray] | None = None
    adaptive: bool = False
    report: Callable[[Any, np.ndarray], dict] | None = None
    sources: tuple[str, ...] = ()
    builtin: bool = False
    stepper: Callable[[Any, PartContext, float], Any] | None = None
    limits: Callable[[Any], tuple[float, float]] | None = None
    #: doubles per control period a run's bundle holds (a function of the scenario, e.g.
    #: the encoder's noise drawn up front), counted before anything is allocated
    memory: Callable[[Any], int] | None = None
    #: a controller's: where its work holds the limb Jacobian at y[:3] after each step
    limb_jacobian: tuple[int, ...] | None = None
    compiled: dict[str, Any] = field(default_factory=dict)
    #: step functions in lane form (:mod:`pkmctl.sim.lanes`): every array with a trailing
    #: lane dimension, one for every function the part has (``command_at`` may lack one);
    #: a part without them runs its scalar functions lane by lane
    lanes: dict[str, Callable] = field(default_factory=dict)
    #: the lane work from the lane bundle and the lane count, for the functions of ``lanes``
    lane_work: Callable[[Any, int], tuple] | None = None
    #: whether one run's bundle can go into the lane form (default: always)
    lane_ok: Callable[[Any], bool] | None = None
    #: a controller's: where its lane work holds the limb Jacobian (4, 3, L)
    lane_limb_jacobian: tuple[int, ...] | None = None
    #: the NamedTuple class of the stacked bundle (default: made from ``params``)
    lane_params: type | None = None
    #: the module whose code registered a user's part (by name): what a campaign's local
    #: workers import to register it too (:func:`pkmctl.campaign.execute.part_modules`)
    module: str = ""

    @contextlib.contextmanager
    def _named(self, what: str = "build"):
        """What a user's ``what`` (build, or size, initial state, work; a hook) raises
        comes as a :class:`PartError` naming the part and the exception."""
        try:
            yield
        except PartError:
            raise
        except Exception as exc:
            raise PartError(
                f"{self.kind} {self.name!r}: {what} failed: {type(exc).__name__}: {exc}"
            ) from exc

    def hook(self, what: str, *args: Any) -> Any:
        """The part's Python function ``what`` (``limits``, ``memory``, ``report``) called
        with ``args``, what it raises named as :meth:`_named` says (a user's read
        "ZeroDivisionError ... (an internal error)": a code reader)."""
        with self._named(what):
            return getattr(self, what)(*args)

    def bundle(self, ctx: PartContext) -> Any:
        """The parameter bundle ``build`` makes for ``ctx``, checked (a user's exception
        named as :meth:`_named` says)."""
        with self._named():
            p = self.build(ctx)
        if type(p) is not self.params:
            raise PartError(
                f"{self.kind} {self.name!r}: build returned {type(p).__name__}, "
                f"expected {self.params.__name__}"
            )
        for name, value in zip(p._fields, p, strict=True):
            if not self.builtin and isinstance(value, list | dict | set | str | bytes):
                # Numba took a list for a reflected list and failed to compile the loop
                # with "NRT required but not enabled", naming no field
                raise PartError(
                    f"{self.kind} {self.name!r}: its bundle's field {name!r} is a "
                    f"{type(value).__name__}; compiled code takes numbers, NumPy arrays "
                    "and tuples (np.asarray(...) for a list)"
                )
        return p

    def make(self, ctx: PartContext) -> tuple[Any, np.ndarray, np.ndarray]:
        """(parameter bundle, initial state, work) for one run."""
        with self._named():
            return self._make(ctx)

    def _make(self, ctx: PartContext) -> tuple[Any, np.ndarray, np.ndarray]:
        p = self.bundle(ctx)
        n = int(self.state_size(p))
        if self.continuous > n:  # the loop would integrate entries past the state's end
            raise PartError(
                f"{self.kind} {self.name!r}: continuous = {self.continuous}: more than its "
                f"state_size ({n}); the loop integrates the first `continuous` state entries"
            )
        if self.initial_state is not None:
            state = np.array(self.initial_state(p), dtype=np.float64).reshape(-1)
            if state.shape != (n,):
                raise PartError(
                    f"{self.kind} {self.name!r}: initial_state has shape {state.shape}, "
                    f"state_size says ({n},)"
                )
        else:
            state = np.zeros(n)
        work = self.make_work(p)
        if not (isinstance(work, tuple) and work and _arrays(work)):
            raise PartError(
                f"{self.kind} {self.name!r}: work must give a non-empty tuple of arrays (or of "
                f"tuples of arrays), "
                f"got {type(work).__name__}"
            )
        if self.limb_jacobian is not None:
            self._check_jacobian(work)
        return p, state, work

    def _check_jacobian(self, work: tuple) -> None:
        """The array at ``limb_jacobian`` in the work must be the (4, 3) limb Jacobian: a
        wrong path failed to compile as "cannot index array(float64, 1d, C) with 2
        indices", naming neither (a tester)."""
        at, v = "work", work
        for i in self.limb_jacobian:
            if not isinstance(v, tuple) or i >= len(v):
                what = f"a tuple of {len(v)}" if isinstance(v, tuple) else "an array"
                raise PartError(
                    f"{self.kind} {self.name!r}: limb_jacobian = {self.limb_jacobian!r}: "
                    f"{at} is {what}, which has no [{i}]"
                )
            at, v = f"{at}[{i}]", v[i]
        if not (isinstance(v, np.ndarray) and v.shape == (4, 3) and v.dtype == np.float64):
            what = f"a tuple of {len(v)}" if isinstance(v, tuple) else f"{v.dtype} {v.shape}"
            raise PartError(
                f"{self.kind} {self.name!r}: limb_jacobian = {self.limb_jacobian!r}: {at} is "
                f"{what}; it must be the (4, 3) float64 array of the limb Jacobian"
            )


def _arrays(t) -> bool:
    """True if t is a tuple whose items are arrays or such tuples."""
    return all(isinstance(a, np.ndarray) or (isinstance(a, tuple) and _arrays(a)) for a in t)


_REGISTRY: dict[str, dict[str, Part]] = {k: {} for k in KINDS}
_BY_TYPE: dict[tuple[str, type], Part] = {}


def names(kind: str) -> list[str]:
    """The registered names of one kind of part, sorted."""
    return sorted(_registry(kind))


def _registry(kind: str) -> dict[str, Part]:
    if kind not in _REGISTRY:
        raise PartError(f"part kind {kind!r}: must be one of {', '.join(KINDS)}")
    # The built-in parts register when their modules load, which ``import pkmctl`` (the
    # package any ``pkmctl.*`` import runs first) does: nothing to import here.
    return _REGISTRY[kind]


def get_part(kind: str, name: str) -> Part:
    """The part of that kind registered under ``name``; one-line error if none."""
    reg = _registry(kind)
    try:
        return reg[name]
    except (KeyError, TypeError):
        raise PartError(
            f"{kind} = {short_repr(name)}: must be one of {', '.join(sorted(reg))} (a part of "
            "your own is registered by importing its module: pkmctl --plugin FILE.py, a "
            "Dask worker's --preload FILE.py, or an import in Python)"
        ) from None


def _sizer(v, what: str, kind: str, name: str) -> Callable[[Any], int]:
    if callable(v):

        def size(p, f=v) -> int:  # a user's function: what it gives is checked (2.5 and -3
            n = f(p)  # went through int() and np.zeros)
            if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
                raise PartError(f"{kind} {name!r}: {what} gave {n!r}: must be an integer >= 0")
            return int(n)

        return size
    if isinstance(v, int | np.integer) and not isinstance(v, bool) and v >= 0:
        return lambda p, v=int(v): v
    raise PartError(f"{kind} {name!r}: {what} = {v!r}: must be an integer >= 0 or a function")


def _worker(v, kind: str, name: str) -> Callable[[Any], tuple]:
    if callable(v):
        return v
    if isinstance(v, int | np.integer) and not isinstance(v, bool) and v >= 0:
        return lambda p, v=int(v): (np.zeros(max(1, v)),)
    raise PartError(f"{kind} {name!r}: work = {v!r}: must be an integer >= 0 or a function")


def _origin(part: Part) -> str:
    """Where a registered part comes from: pkmctl, or the file of its functions."""
    if part.builtin:
        return "one of pkmctl's own"
    files = []
    for fn in part.functions.values():
        try:
            files.append(inspect.getsourcefile(fn) or "")
        except TypeError:
            pass
    files = [f for f in files if f]
    return f"by {files[0]}" if files else "by another plugin"


#: Per user part, by (kind, name): the modules of its functions and a hash of the text
#: of their files when it was registered (:func:`_source_stamp`).
_STAMPS: dict[tuple[str, str], tuple] = {}


def _source_stamp(functions: dict[str, Callable]) -> tuple | None:
    """Where a user part's functions are defined (module, name, line), and the SHA-256 of
    the text of each file they are read from (and of the user's modules they reach,
    :func:`user_sources`), now: equal for the same module imported again, also from a
    copy of its file (Dask's ``--preload FILE.py`` imports the file, then reloads the
    copy it made). A function with no file (a notebook cell, a prompt) is stamped by its
    code object instead: running the same cell again registers it again, where it was
    refused and took a kernel restart (a tester); an edited cell is another text. None if
    a file cannot be read: then a second registration is never taken for the first."""
    files: set[str] = set()
    try:
        pys = {role: getattr(fn, "py_func", fn) for role, fn in functions.items()}
        # where each function is defined (not another part of the same file)
        modules = tuple(sorted((role, py.__module__, py.__qualname__, py.__code__.co_firstlineno)
                               for role, py in pys.items()))  # fmt: skip
        for py in pys.values():
            files |= user_sources(py)
        if not files:  # the code itself (with its file name: ipykernel's is the cell's hash)
            codes = (hashlib.sha256(marshal.dumps(py.__code__)).hexdigest() for py in pys.values())
            return modules, ("code", *sorted(codes))
        digests = []
        for f in files:
            with open(f, "rb") as fh:
                digests.append(hashlib.sha256(fh.read()).hexdigest())
        return modules, tuple(sorted(set(digests)))
    except (OSError, TypeError, AttributeError):
        return None


_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def _register(kind: str, name: str, functions: dict[str, Callable], **options) -> Part:
    """:func:`_register_part`, all or nothing: a registration refused (a PartError of its
    lane form, say, checked after the part itself) leaves the registries as they were,
    where it had left the part registered and runnable, and a corrected registration
    refused as "already registered"."""
    saved = [(r, dict(r)) for r in (*_REGISTRY.values(), _BY_TYPE, _STAMPS, _LANE_CLASSES,
                                    _BY_LANE_TYPE)]  # fmt: skip
    try:
        return _register_part(kind, name, functions, **options)
    except BaseException:
        for registry, before in saved:
            registry.clear()
            registry.update(before)
        raise


def _register_part(
    kind: str,
    name: str,
    functions: dict[str, Callable],
    *,
    params: type,
    build: Callable | None,
    state_size=0,
    work=1,
    initial_state=None,
    continuous: int = 0,
    log_size=0,
    log_name: str = "",
    description: str = "",
    label: str = "",
    surface_gain: Callable | None = None,
    adaptive: bool = False,
    report: Callable | None = None,
    builtin: bool = False,
    stepper: Callable | None = None,
    limits: Callable | None = None,
    memory: Callable | None = None,
    limb_jacobian: tuple[int, ...] | None = None,
    lanes: dict[str, Callable] | None = None,
    lane_work: Callable | None = None,
    lane_ok: Callable | None = None,
    module: str = "",
) -> Part:
    reg = _REGISTRY[kind]
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        # (a name is a file name too: simulate writes NAME.parquet; "a/../../b" wrote
        # outside --out)
        raise PartError(
            f"{kind} name {name!r}: must be 1-64 letters, digits, '_', '.' or '-', starting "
            "with a letter or digit"
        )
    if log_name != "" and not (isinstance(log_name, str) and _NAME.fullmatch(log_name)):
        # (a key of result.logs and its CSV columns' prefix: "x,y" wrote a header of more
        # fields than its rows, which pyarrow and pandas refuse; a code reader)
        raise PartError(
            f"{kind} {name!r}: log_name = {short_repr(log_name)}: must be 1-64 letters, "
            "digits, '_', '.' or '-', starting with a letter or digit (or '': the part's name)"
        )
    stamp = None if builtin else _source_stamp(functions)
    if name in reg:
        old = reg[name]
        if stamp is None or _STAMPS.get((kind, name)) != stamp:
            raise PartError(
                f"{kind} {name!r}: a {kind} of that name is already registered ({_origin(old)})"
            )
        # the same module of the same text registering it again, imported twice (Dask's
        # --preload FILE.py imports it, then reloads a copy): the new one replaces it
        del reg[name]
        _BY_TYPE.pop((kind, old.params), None)
    if not (isinstance(params, type) and issubclass(params, tuple) and hasattr(params, "_fields")):
        raise PartError(f"{kind} {name!r}: params = {params!r}: must be a typing.NamedTuple class")
    if (kind, params) in _BY_TYPE:
        other = _BY_TYPE[(kind, params)].name
        raise PartError(
            f"{kind} {name!r}: params class {params.__name__} already belongs to {kind} {other!r}"
        )
    if build is None:
        build = getattr(params, "from_context", None)
    if not callable(build):
        raise PartError(
            f"{kind} {name!r}: give build=... or a classmethod {params.__name__}.from_context(ctx)"
        )
    if initial_state is not None and not callable(initial_state):
        raise PartError(
            f"{kind} {name!r}: initial_state = {initial_state!r:.60}: must be a function of "
            "the bundle giving the state array (e.g. lambda p: np.zeros(n))"
        )
    if stepper is not None and kind != "plant":
        raise PartError(f"{kind} {name!r}: only a plant can have a stepper")
    if limits is not None and (kind != "actuator" or not callable(limits)):
        raise PartError(f"{kind} {name!r}: limits = {limits!r}: only an actuator has limits, "
                        "a function of its bundle giving (force N, speed m/s)")  # fmt: skip
    if limb_jacobian is not None:
        path = tuple(limb_jacobian) if isinstance(limb_jacobian, tuple | list) else ()
        if (
            kind != "controller"
            or not path
            or not all(isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in path)
        ):
            raise PartError(f"{kind} {name!r}: limb_jacobian = {limb_jacobian!r}: a controller's "
                            "path of indices into its work tuple, e.g. (0, 5)")  # fmt: skip
        limb_jacobian = path
    for role in _REQUIRED[kind]:
        if role == "derivative" and stepper is not None:
            continue  # a stepped plant is advanced by its stepper, not integrated by the loop
        if role not in functions:
            raise PartError(f"{kind} {name!r}: missing its {role!r} function")
    sources, compiled = set(), {}
    for role, fn in functions.items():
        if role not in ROLES[kind]:
            raise PartError(f"{kind} {name!r}: unknown function {role!r}")
        py = getattr(fn, "py_func", fn)
        if not inspect.isfunction(py):
            raise PartError(f"{kind} {name!r}: {role} = {fn!r}: must be a function")
        want = ROLES[kind][role]
        sig = inspect.signature(py)
        plain = [
            p
            for p in sig.parameters.values()
            if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) and p.default is p.empty
        ]
        if len(plain) != want or len(sig.parameters) != want:
            # ("takes 5 arguments, the contract needs 5" said nothing)
            odd = "; no keyword-only, default or * arguments" if len(sig.parameters) == want else ""
            raise PartError(
                f"{kind} {name!r}: {role} function {py.__name__}{sig} takes "
                f"{len(sig.parameters)} arguments, the contract needs {want} plain ones "
                f"({_SIGNATURES[kind][role]}){odd}"
            )
        if builtin and py is not fn:  # pkmctl's own kernel: called, and inlined by LLVM
            py.__pkmctl_llvm_inline__ = True
            compiled[role] = fn
        functions[role] = py
        sources |= {inspect.getsourcefile(py) or ""} if builtin else user_sources(py)
    sources.discard("")
    if continuous and "derivative" not in functions:
        raise PartError(f"{kind} {name!r}: continuous = {continuous} needs a derivative function")
    if ("log" in functions) != (log_size != 0):
        # a log function without log_size was never called; log_size without one logged
        # zeros that looked like data
        raise PartError(
            f"{kind} {name!r}: "
            + (
                "a log function needs log_size = m (the columns it writes per row)"
                if "log" in functions
                else f"log_size = {log_size!r} needs a log function (log=..., (p, state, row))"
            )
        )
    part = Part(
        kind=kind,
        name=name,
        params=params,
        build=build,
        functions=dict(functions),
        state_size=_sizer(state_size, "state_size", kind, name),
        make_work=_worker(work, kind, name),
        initial_state=initial_state,
        continuous=int(continuous),
        log_size=_sizer(log_size, "log_size", kind, name),
        log_name=log_name,
        description=description,
        label=label or name.upper(),
        surface_gain=surface_gain,
        adaptive=bool(adaptive),
        report=report,
        sources=tuple(sorted(sources)),
        builtin=builtin,
        stepper=stepper,
        limits=limits,
        memory=memory,
        limb_jacobian=limb_jacobian,
        compiled=compiled,
        module=module,
    )
    reg[name] = part
    _BY_TYPE[(kind, params)] = part
    if stamp is not None:
        _STAMPS[(kind, name)] = stamp
    if lanes:
        part = attach_lanes(kind, name, lanes, lane_work=lane_work, lane_ok=lane_ok)
    return part


def user_sources(fn: Callable) -> set[str]:
    """The source files a user's step function can reach, for the cache key of its loop:
    its own file and, through its globals and closure, the file of every module of the
    user's own code it uses, transitively (``from helper import scale`` as well as
    ``import helper``). Python's, installed libraries' and pkmctl's files are left out
    (pkmctl's own hash covers its kernels). Numba compiles whatever these reach, so an
    edit to any of them must compile the loop anew."""
    found: set[str] = set()
    seen: set[int] = set()

    def module_of(obj: Any) -> Any:
        if isinstance(obj, ModuleType):
            return obj
        obj = getattr(obj, "py_func", obj)  # a Numba dispatcher: its Python function
        if not (inspect.isfunction(obj) or inspect.isclass(obj)):
            return None
        return sys.modules.get(getattr(obj, "__module__", None) or "")

    def visit(namespace: dict[str, Any], file: str | None) -> None:
        if not file or not file.endswith(".py") or file in found:
            return
        if _is_library(file):
            return
        found.add(file)
        for value in list(namespace.values()):
            mod = module_of(value)
            if mod is not None and id(mod) not in seen:
                seen.add(id(mod))
                visit(vars(mod), getattr(mod, "__file__", None))

    def cells(py: Any) -> list[Any]:
        return [c.cell_contents for c in py.__closure__ or () if _filled(c)]

    def visit_used(py: Any) -> None:
        """What a function of the user's reaches through the names its code uses (not its
        module's every global: a script's `if __name__ == "__main__":` block imports
        modules into it that a spawned worker never sees, and the client's and the
        worker's digests of a part registered there differed; a reviewer). A function or
        class of the same module is followed by the names its own code uses."""
        if id(py) in seen:
            return
        seen.add(id(py))
        g = py.__globals__
        for v in [g[n] for n in sorted(_code_names(py.__code__)) if n in g] + cells(py):
            f = getattr(v, "py_func", v)
            if inspect.isfunction(f) and f.__globals__ is g:
                visit_used(f)
                continue
            own = getattr(sys.modules.get(getattr(f, "__module__", None) or ""), "__dict__", None)
            if inspect.isclass(f) and own is g:
                for m in list(vars(f).values()):
                    m = getattr(m, "__func__", m)
                    if inspect.isfunction(m) and m.__globals__ is g:
                        visit_used(m)
                continue
            mod = module_of(v)
            if mod is not None and id(mod) not in seen:
                seen.add(id(mod))
                visit(vars(mod), getattr(mod, "__file__", None))

    py = getattr(fn, "py_func", fn)
    file = inspect.getsourcefile(py)
    if file and file.endswith(".py") and not _is_library(file):
        found.add(file)
        visit_used(py)
    elif file:  # a library's function: its module's imports, as for any module
        visit({**py.__globals__, **{f"cell{i}": c for i, c in enumerate(cells(py))}}, file)
    if file and file not in found:  # the function's own file, even if a library's
        found.add(file)
    # a function typed at a prompt or in a notebook cell has no file on disk: its code
    # is in global_values instead
    return {f for f in found if os.path.isfile(f)}


_SIMPLE = (bool, int, float, complex, str, bytes, type(None), np.generic)


def _code_names(code: CodeType) -> set[str]:
    """The global names a code object and the code nested in it use."""
    out = set(code.co_names)
    for c in code.co_consts:
        if isinstance(c, CodeType):
            out |= _code_names(c)
    return out


def global_values(parts: Iterable[Part], *, functions: Iterable[Callable] = ()) -> str:
    """A digest of what the user's parts compile in besides their files' text, for the
    cache key of their loop (with :func:`user_sources`): Numba freezes a global value a
    compiled function reads (a number, string, tuple or array, read from the
    environment or a settings file, say) into the machine code, so the loop of another
    value must be another loop. Covers the globals and closure values each step function
    reads, and those of the user's own functions it calls, transitively; and the code
    of a function with no file on disk (typed at a prompt, ``python -c``). Built-in
    parts add nothing. ``functions``: more to cover the same way (a campaign adds each
    part's Python functions, ``build`` among them, whose values make its bundles)."""
    h = hashlib.sha256()
    seen: set[int] = set()

    def users(py: Any) -> bool:
        try:
            file = inspect.getsourcefile(py) or ""
        except TypeError:
            return False
        return not _is_library(file)

    def value(tag: str, v: Any, depth: int = 0) -> None:
        # the same text for the same value in every process: an object array's bytes are
        # its pointers, and repr(2**20000) raises (a reviewer); a dict of gains is data too
        try:
            if isinstance(v, np.ndarray):
                h.update(f"{tag}:{v.dtype.str}{v.shape}\0".encode())
                if v.dtype.hasobject:
                    value(f"{tag}.items", v.tolist(), depth + 1)
                else:  # (its bytes as they are: tobytes() copied a 200 MB table)
                    h.update(np.ascontiguousarray(v).reshape(-1).view(np.uint8))
            elif isinstance(v, int) and not isinstance(v, bool):
                h.update(f"{tag}=int:{v:x}\0".encode())
            elif isinstance(v, _SIMPLE):
                h.update(f"{tag}={v!r}\0".encode())
            elif isinstance(v, (tuple, list)) and depth < 4:
                h.update(f"{tag}:{type(v).__name__}{len(v)}\0".encode())
                for i, item in enumerate(v):
                    value(f"{tag}[{i}]", item, depth + 1)
            elif isinstance(v, dict) and depth < 4:
                h.update(f"{tag}:dict{len(v)}\0".encode())
                for k in sorted(v, key=repr):
                    value(f"{tag}[{k!r}]", v[k], depth + 1)
        except Exception:  # noqa: BLE001 - a hash of provenance never stops a run
            h.update(f"{tag}:unhashable {type(v).__name__}\0".encode())

    def item(tag: str, v: Any) -> None:
        fn = getattr(v, "py_func", v)
        if inspect.isfunction(fn):
            if users(fn):
                visit(fn)
        elif not isinstance(v, ModuleType):
            value(tag, v)

    def visit(py: Any) -> None:
        if id(py) in seen:
            return
        seen.add(id(py))
        # (a script's module is __main__ here and __mp_main__ in a spawned worker)
        module = "__main__" if py.__module__ == "__mp_main__" else py.__module__
        where = f"{module}.{py.__qualname__}"
        try:
            on_disk = os.path.isfile(inspect.getsourcefile(py) or "")
        except TypeError:
            on_disk = False
        if not on_disk:
            h.update(marshal.dumps(py.__code__))
        used = _code_names(py.__code__)
        modules: set[int] = set()  # each module once a function: no cycles (pkg.sub.pkg)
        for name in sorted(used & py.__globals__.keys()):
            v = py.__globals__[name]
            if isinstance(v, ModuleType):
                attributes(f"{where}:{name}", v, used, modules, 0)
            else:
                item(f"{where}:{name}", v)
        for i, c in enumerate(py.__closure__ or ()):
            if _filled(c):
                item(f"{where}:cell{i}", c.cell_contents)
        # Numba compiles a default value in as a constant: `def scaled(x, g=GAIN)` ran
        # the first GAIN's loop for every later one (a code reader)
        for i, d in enumerate(py.__defaults__ or ()):
            item(f"{where}:default{i}", d)
        for k, d in sorted((py.__kwdefaults__ or {}).items()):
            item(f"{where}:default[{k}]", d)

    def attributes(tag: str, mod: ModuleType, used: set[str], modules: set[int], depth: int):
        """helper.scale, settings.GAIN: the module's attributes the code's names reach,
        and through a module among them its own (cfgpkg.sub.GAIN, whose value was never
        hashed: the first value's loop ran for every other one; a code reader), a few
        levels deep, each module once."""
        if id(mod) in modules or depth > 4:
            return
        modules.add(id(mod))
        namespace = getattr(mod, "__dict__", None) or {}
        for attr in sorted(used & namespace.keys()):
            v = namespace[attr]
            if isinstance(v, ModuleType):
                attributes(f"{tag}.{attr}", v, used, modules, depth + 1)
            else:
                item(f"{tag}.{attr}", v)

    for part in parts:
        if part.builtin:
            continue
        for fn in (*part.functions.values(), *(part.lanes or {}).values()):
            visit(getattr(fn, "py_func", fn))
    for fn in functions:
        fn = getattr(fn, "py_func", getattr(fn, "__func__", fn))
        if inspect.isfunction(fn) and users(fn):
            visit(fn)
    return h.hexdigest()[:16] if seen else ""


def _part_files(part) -> list[str]:
    """The user's source files of a part: those its compiled loop's cache hashes
    (:attr:`~pkmctl.parts.Part.sources`) and those of its Python functions (``build``,
    ``work``, ``report``...), which make its bundles and info."""
    files = set(part.sources)
    for fn in _python_functions(part):
        try:
            file = inspect.getsourcefile(fn) or ""
        except TypeError:
            continue
        if file:
            files |= user_sources(fn)
    return sorted(files)


def _python_functions(part) -> list:
    """A user part's own Python functions (``build``, ``work``, ``report``...): not
    compiled, but they make its bundles and info."""
    package = Path(__file__).resolve().parent
    out = []
    for fn in (part.build, part.make_work, part.initial_state, part.state_size, part.log_size,
               part.report, part.limits, part.memory, part.stepper, part.lane_work,
               part.lane_ok):  # fmt: skip
        fn = getattr(fn, "__func__", fn)  # a classmethod's function
        if not inspect.isfunction(fn):
            continue
        try:
            file = inspect.getsourcefile(fn) or ""
        except TypeError:
            file = ""
        if not (file and Path(file).resolve().is_relative_to(package)):
            out.append(fn)
    return out


def part_digest(part) -> dict:
    """What identifies a user part's version: ``sha256`` (16 hex digits) of its source
    files' content, as they are now, and of the global values its code reads, and
    ``files``. A campaign records it (:func:`pkmctl.campaign.store.user_parts`) and its
    workers report it for the parts they ran, checked against the client's; a Result
    of a user part keeps it in ``info["software"]["user_parts"]``."""
    files = _part_files(part)
    digests = []
    for f in files:
        try:
            digests.append(hashlib.sha256(Path(f).read_bytes()).hexdigest())
        except OSError:
            digests.append("unreadable:" + Path(f).name)
    # the values its functions read too: gains imported from a helper module ("from
    # gains import K1") changed between a campaign's sessions unseen (a tester)
    values = global_values([part], functions=_python_functions(part))
    h = hashlib.sha256("\0".join([*sorted(digests), values]).encode())
    return {"sha256": h.hexdigest()[:16], "files": files}


def _filled(cell: Any) -> bool:
    try:
        cell.cell_contents  # noqa: B018
    except ValueError:  # an empty cell
        return False
    return True


class _Library(NamedTuple):
    """Where files are not the user's, as folder prefixes (each ending in a separator)."""

    python: tuple[str, ...]  # Python's own modules, except under a site folder
    sites: tuple[str, ...]  # where installed packages go
    packages: tuple[str, ...]  # pkmctl and what it stands on, wherever they are


@functools.cache
def _library_folders() -> _Library:
    """Where files are not the user's: Python's own, pkmctl's, and the installed packages
    pkmctl stands on (its requirements, extras included, and theirs, transitively). Any
    other installed package may be the user's own (docs/parts.md: a package the Dask
    workers import), and its files count: they were all left out, and an edit to a
    part's helper installed in site-packages ran the old compiled loop (a tester).
    Python's own folder holds site-packages outside a venv (pyenv, a Python built from
    source: lib/python3.11/site-packages), so the site folders are cut out of it."""
    paths = sysconfig.get_paths()

    def folder(f: str) -> str:
        return os.path.join(os.path.realpath(f), "")

    python = {folder(f) for f in (paths["stdlib"], os.path.dirname(os.__file__)) if f}
    sites = {paths[k] for k in ("purelib", "platlib") if k in paths}
    sites |= set(site.getsitepackages()) | {site.getusersitepackages()}
    sites = {folder(f) for f in sites if f}
    packages = [folder(os.path.dirname(os.path.abspath(__file__)))]  # pkmctl
    deps = _dependencies()
    if deps is None:  # pkmctl run from its source, not installed: every installed package
        packages += sorted(sites)
        deps = []
    for dist in deps:
        for top in _top_level(dist):
            where = os.path.realpath(str(dist.locate_file(top)))
            if os.path.isdir(where):
                packages.append(os.path.join(where, ""))
            elif os.path.isfile(where + ".py"):
                packages.append(where + ".py")
    return _Library(tuple(sorted(python)), tuple(sorted(sites)), tuple(dict.fromkeys(packages)))


def _is_library(path: str, where: _Library | None = None) -> bool:
    """Whether a file is Python's, pkmctl's or a package's pkmctl stands on (not the
    user's): ``where`` defaults to this interpreter's :func:`_library_folders`."""
    where = where or _library_folders()
    path = os.path.realpath(path)
    if any(path.startswith(f) for f in where.packages):
        return True
    return any(path.startswith(f) for f in where.python) and not any(
        path.startswith(f) for f in where.sites
    )


def _dependencies() -> list | None:
    """The installed distributions pkmctl requires, with their own, transitively; None
    if pkmctl itself is not installed."""
    from importlib import metadata

    seen: dict[str, Any] = {}
    todo = ["pkmctl"]
    while todo:
        name = re.sub(r"[-_.]+", "-", todo.pop()).lower()
        if name in seen:
            continue
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            seen[name] = None
            continue
        seen[name] = dist
        for req in dist.requires or []:
            m = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", req)
            if m:
                todo.append(m.group(1))
    if seen.get("pkmctl") is None:
        return None
    return [d for n, d in seen.items() if d is not None and n != "pkmctl"]


def _top_level(dist) -> set[str]:
    """The top-level import names a distribution installs."""
    text = dist.read_text("top_level.txt")
    if text:
        return {t.strip() for t in text.splitlines() if t.strip()}
    tops = set()
    for f in dist.files or ():
        first = f.parts[0] if f.parts else ""
        if first.endswith((".dist-info", ".egg-info", ".data")) or first in ("..", "__pycache__"):
            continue
        if first.endswith(".py") or "." not in first:
            tops.add(first.removesuffix(".py"))
    return tops


def attach_lanes(
    kind: str,
    name: str,
    lanes: dict[str, Callable],
    *,
    lane_work: Callable | None,
    lane_ok: Callable | None = None,
    lane_limb_jacobian: tuple[int, ...] | None = None,
    lane_params: type | None = None,
) -> Part:
    """Give a registered part lane forms of its step functions (:mod:`pkmctl.sim.lanes`):
    ``lanes`` role → function with the role's signature, every array with a trailing lane
    dimension, for every function the part has (``command_at`` may lack one);
    ``lane_work(lane_bundle, L)`` their work; ``lane_ok(bundle)`` whether a run's bundle
    may be stacked (else the part runs lane by lane); a controller's
    ``lane_limb_jacobian``, as ``limb_jacobian`` in its lane work."""
    part = get_part(kind, name)
    fns, compiled, sources = {}, dict(part.compiled), set(part.sources)
    for role, fn in lanes.items():
        if role not in part.functions:
            raise PartError(f"{kind} {name!r}: a lane form of {role!r}, which it does not have")
        py = getattr(fn, "py_func", fn)
        if not inspect.isfunction(py):
            raise PartError(f"{kind} {name!r}: lane {role} = {fn!r}: must be a function")
        if part.builtin and py is not fn:
            py.__pkmctl_llvm_inline__ = True
            compiled["lane_" + role] = fn
        fns[role] = py
        if not part.builtin:
            sources |= user_sources(py)
    if not callable(lane_work):
        raise PartError(f"{kind} {name!r}: lane functions need lane_work(lane_bundle, lanes)")
    # a stacked bundle reaches every function in lane form: a scalar log beside a lane
    # step registered, ran alone, then failed every simulate_many and campaign as "does
    # not compile" (a code reader); command_at may lack one (the loop calls command)
    missing = [r for r in part.functions if r not in fns and r != "command_at"]
    if missing:
        raise PartError(
            f"{kind} {name!r}: lanes = {{{', '.join(repr(r) for r in fns)}}}: must give a "
            f"lane form of every function the part has (here also: {', '.join(missing)})"
        )
    from dataclasses import replace

    new = replace(part, lanes=fns, lane_work=lane_work, lane_ok=lane_ok, compiled=compiled,
                  lane_limb_jacobian=lane_limb_jacobian, lane_params=lane_params,
                  sources=tuple(sorted(sources)))  # fmt: skip
    _REGISTRY[kind][name] = new
    _BY_TYPE[(kind, part.params)] = new
    cls = lane_params or lane_class(part.params)
    _LANE_CLASSES[part.params] = cls
    _BY_LANE_TYPE[(kind, cls)] = new
    return new


# ---------------------------------------------------------------- lanes
# L runs at once (pkmctl.sim.lanes): every state and array of the contract gets a
# trailing lane dimension. A part with lane functions gets its L bundles stacked into
# one bundle of its lane class (same fields, each with a trailing lane dimension: a
# float becomes (L,)); any other part gets EachLane(the L bundles), and its scalar
# functions run lane by lane on views (slower, same arithmetic). No lane-form type
# depends on L (a tuple's length is part of its type): EachLane's tuples are padded to
# at least EACH_LANE_MIN entries, so one compiled lane loop serves every L up to it.
EACH_LANE_MIN = 8
_LANE_CLASSES: dict[type, type] = {}
_BY_LANE_TYPE: dict[tuple[str, type], Part] = {}


class EachLane(NamedTuple):
    """The L bundles of a part without lane functions, run one lane at a time (padded
    with the first lane's bundle to EACH_LANE_MIN entries; the lanes past L are never
    run)."""

    each: tuple


def lane_class(params: type) -> type:
    """The lane-form NamedTuple class of a bundle class (the same fields)."""
    cls = _LANE_CLASSES.get(params)
    if cls is None:
        cls = NamedTuple("Lane" + params.__name__, [(f, Any) for f in params._fields])
        cls.__module__ = params.__module__
        cls.__doc__ = f"{params.__name__} in lane form: every field with a trailing lane axis."
        # Importable where its bundle class is: Numba's disk cache pickles the types of a
        # compiled function's signature, and a class found by its name comes back as the
        # same class in the next process (else the cached lane loops never match and
        # every process compiles them again, ~20 s each).
        module = sys.modules.get(params.__module__)
        if module is not None and not hasattr(module, cls.__name__):
            setattr(module, cls.__name__, cls)
        _LANE_CLASSES[params] = cls
    return cls


class LaneMismatch(PartError):
    """Runs that cannot share a lane loop (their bundles differ in more than numbers)."""


def _stack_field(name: str, values: list) -> Any:
    v0 = values[0]
    if isinstance(v0, np.ndarray):
        if any(v.shape != v0.shape or v.dtype != v0.dtype for v in values):
            raise LaneMismatch(f"field {name!r}: the runs' arrays differ in shape")
        return np.ascontiguousarray(np.stack(values, axis=-1))
    if isinstance(v0, tuple):  # a nested bundle (e.g. fuzzy tables): shared, not stacked
        same = all(
            len(v) == len(v0)
            and all(
                np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b
                for a, b in zip(v, v0, strict=True)
            )
            for v in values
        )
        if not same:
            raise LaneMismatch(f"field {name!r}: the runs' {type(v0).__name__} differ")
        return v0
    if all(isinstance(v, bool | int | np.integer) for v in values):
        return np.array(values, dtype=np.int64)
    # the type of every run's number: int64 for all when the first run's was an int
    # truncated the others' floats (1000.75 ran as 1000, unlike its own run; a code
    # reader); an int is exact in float64, as its own run computes int * float
    return np.array(values, dtype=np.float64)


def stack_lanes(part: Part, bundles: list[tuple]) -> tuple[Any, np.ndarray, tuple]:
    """(lane bundle, lane state (n, L), lane work) of the runs' (params, state, work)."""
    ps = [b[0] for b in bundles]
    state = np.ascontiguousarray(np.stack([b[1] for b in bundles], axis=-1))
    if part.lanes and (part.lane_ok is None or all(part.lane_ok(p) for p in ps)):
        cls = lane_class(part.params)
        lp = cls(*(_stack_field(f, [getattr(p, f) for p in ps]) for f in part.params._fields))
        return lp, state, part.lane_work(lp, len(ps))
    from numba import typeof

    if len({typeof(p) for p in ps}) > 1 or len({typeof(b[2]) for b in bundles}) > 1:
        raise LaneMismatch(f"{part.kind} {part.name!r}: the runs' bundles differ in types")
    pad = max(EACH_LANE_MIN - len(ps), 0)
    works = tuple(b[2] for b in bundles)
    return EachLane(tuple(ps) + (ps[0],) * pad), state, works + works[:1] * pad


_SIGNATURES = {
    "sensor": {"measure": "p, state, work, x, y", "log": "p, state, row"},
    "controller": {"step": "p, state, work, y, ref, F", "log": "p, state, row"},
    "actuator": {
        "command": "p, state, work, y, F, cmd",
        "force": "p, state, cmd, tau",
        "derivative": "p, state, cmd, dstate",
        "command_at": "p, state, work, y, F, Jq, cmd",
    },
    "plant": {
        "derivative": "p, x, tau, dist, work, dx",
        "observe": "p, x, tau, work, q, F",
    },
}


def _others(kind: str, main_role: str) -> str:
    return ", ".join(r for r in ROLES[kind] if r != main_role) or "none"


_F = TypeVar("_F", bound=Callable[..., Any])


class _Decorate(Protocol):
    def __call__(self, fn: _F, /) -> _F: ...


class _Register(Protocol):
    """``register_<kind>(name, params=P, ...)``: a decorator that returns its function
    unchanged (so a user's annotated step function keeps its types)."""

    def __call__(
        self,
        name: str,
        *,
        params: type,
        build: Callable[..., Any] | None = None,
        **options: Any,
    ) -> _Decorate: ...


def _decorator(kind: str, main_role: str) -> _Register:
    def register(
        name: str, *, params: type, build: Callable[..., Any] | None = None, **options: Any
    ) -> _Decorate:
        extra = {r: options.pop(r) for r in list(options) if r in ROLES[kind]}
        if main_role in extra:  # it replaced the decorated function without a word
            raise PartError(
                f"{kind} {name!r}: {main_role}= is not an option: the decorated function is its "
                f"{main_role}; the options give its other functions ({_others(kind, main_role)})"
            )
        # module and builtin are pkmctl's to set: module= was listed among the options,
        # then raised a TypeError, and builtin=True was taken (a code reader)
        allowed = set(inspect.signature(_register_part).parameters) - {
            "kind", "name", "functions", "module", "builtin"}  # fmt: skip
        unknown = sorted(set(options) - allowed)
        if unknown:  # (a TypeError naming _register, an internal function, before)
            raise PartError(
                f"{kind} {name!r}: unknown option {unknown[0]!r}; the options are "
                f"{', '.join(sorted(allowed))} and its functions {', '.join(ROLES[kind])}"
            )

        def deco(fn: _F, /) -> _F:
            # the registering module: its frame calls this one (the step may be another
            # module's: `from helpers import law; register_controller(...)(law)`, whose
            # workers imported helpers alone; a reviewer)
            caller = sys._getframe(1).f_globals.get("__name__", "")
            _register(kind, name, {main_role: fn, **extra}, params=params, build=build,
                      module=caller, **options)  # fmt: skip
            return fn

        return deco

    register.__name__ = f"register_{kind}"
    register.__doc__ = f"""Register a {kind}: ``@register_{kind}(name, params=P, ...)`` on its
    ``{main_role}({_SIGNATURES[kind][main_role]})`` function.

    ``params``: the NamedTuple class of its parameter bundle; ``build(ctx)`` (or a
    classmethod ``params.from_context(ctx)``) makes one from a :class:`PartContext`.
    Options: ``state_size`` (int, or a function of the bundle), ``work`` (an int n for
    one float64 array of n, or a function of the bundle giving a tuple of arrays),
    ``initial_state`` (function of the bundle), ``description``, ``label`` (its name in
    reports), ``limits`` (an actuator's (force N, speed m/s) from its bundle, inf: none),
    ``memory`` (doubles per control period its bundle holds, a function of the scenario,
    counted in the memory check before a run), and the other step functions of a {kind}
    ({_others(kind, main_role)}).
    Raises :class:`PartError` (one line) on a taken name or a wrong signature.
    """
    return register


register_sensor = _decorator("sensor", "measure")
register_controller = _decorator("controller", "step")
register_actuator = _decorator("actuator", "command")
register_plant = _decorator("plant", "derivative")


def builtin_part(kind: str, name: str, functions: dict[str, Callable], **options) -> Part:
    """Register one of pkmctl's own parts (sources covered by pkmctl's cache hash)."""
    return _register(kind, name, dict(functions), builtin=True, **options)


# ---------------------------------------------------------------- compiled dispatch
# One stub per step function; its overload finds the part by the Numba type of the
# parameter bundle and inlines the part's function at the call site (Numba IR inlining,
# compiled without reference counting). Selection happens at compile time, and the
# loop's disk cache key is the bundles' types (DESIGN.md §6). Inlining matters: a call
# passes every array of the bundles and work tuples as separate scalars (a work tuple of
# 12 arrays is ~100 words on the stack), which cost the loop a third of its speed. The
# loop calls each step function from one place only (the RK4 stages are a loop), so
# each part's code appears once in it and compiling stays quick.

_OPTIONS = JIT_OPTIONS | NO_REFCOUNT


def _compiled(part: Part, role: str):
    disp = part.compiled.get(role)
    if disp is None:
        disp = njit(**_OPTIONS)(part.functions[role])
        part.compiled[role] = disp
    return disp


def _lookup(kind: str, p) -> Part | None:
    cls = getattr(p, "instance_class", None) if isinstance(p, types.BaseNamedTuple) else None
    return _BY_TYPE.get((kind, cls))


def _lane_of(argnames: str) -> str:
    """The call of a step function on lane l of its lane-form arguments."""

    def one(a: str) -> str:
        return {"p": "p.each[l]", "work": "work[l]", "Jq": "Jq[:, :, l]"}.get(a, f"{a}[:, l]")

    return ", ".join(one(a) for a in argnames.split(","))


def _lane_resolve(kind: str, role: str, p):
    """The implementation for a lane-form bundle ``p`` (None: not one)."""
    if not isinstance(p, types.BaseNamedTuple):
        return None
    argnames = _SIGNATURES[kind][role].replace(" ", "")
    cls = getattr(p, "instance_class", None)
    if cls is EachLane:  # the scalar function, lane by lane
        inner = p.types[0]
        if _lookup(kind, getattr(inner, "dtype", None)) is None:
            return None
        local: dict[str, Any] = {"stub": _STUBS[(kind, role)]}
        lanes = argnames.split(",")[1]  # the state (plant: x), (n, L)
        exec(f"def impl({argnames}):\n    for l in range({lanes}.shape[1]):\n"
             f"        stub({_lane_of(argnames)})\n", local)  # fmt: skip
        return local["impl"]
    part = _BY_LANE_TYPE.get((kind, cls))
    if part is None:
        return None
    if role not in part.functions:  # an optional step the part does not have
        return _noop(argnames)
    if role not in part.lanes:
        return None  # no lane form: Numba reports a typing error
    disp = part.compiled.get("lane_" + role)
    return _caller(argnames, disp) if disp is not None else part.lanes[role]


def _caller(argnames: str, disp):
    """An implementation that calls ``disp``: one of pkmctl's kernels, compiled once and
    kept in the disk cache, which LLVM inlines into the loop (``llvm_inline``), so that a
    loop does not type-infer the part's body again."""
    local: dict[str, Any] = {"fn": disp}
    exec(f"def impl({argnames}):\n    return fn({argnames})\n", local)
    return local["impl"]


def _resolver(kind: str, role: str):
    argnames = _SIGNATURES[kind][role].replace(" ", "")

    def resolve(p):
        part = _lookup(kind, p)
        if part is None:  # a lane-form bundle, or not a bundle of this kind (typing error)
            return _lane_resolve(kind, role, p)
        if role in part.functions and role in part.compiled and part.builtin:
            return _caller(argnames, part.compiled[role])
        if role in part.functions:
            return part.functions[role]  # inlined into the caller (see above)
        return _noop(argnames)  # an optional step the part does not have: nothing to do

    return resolve


def _noop(argnames: str):
    local: dict[str, Any] = {}
    exec(f"def impl({argnames}):\n    return None\n", local)
    return local["impl"]


def _stub(kind: str, role: str):
    n = ROLES[kind][role]
    argnames = _SIGNATURES[kind][role].replace(" ", "")
    src = (
        f"def stub({argnames}):\n    raise TypeError('{kind}_{role} runs in compiled code only')\n"
    )
    ns: dict[str, Any] = {}
    exec(src, ns)  # a plain stub with the contract's argument names
    stub = ns["stub"]
    stub.__name__ = stub.__qualname__ = f"{kind}_{role}"

    resolve = _resolver(kind, role)
    ns = {"resolve": resolve}
    exec(f"def typer({argnames}):\n    return resolve({argnames.split(',')[0]})\n", ns)
    typer = ns["typer"]
    assert len(argnames.split(",")) == n
    overload(stub, jit_options=_OPTIONS, strict=False, inline="always")(typer)
    _STUBS[(kind, role)] = stub
    return stub


_STUBS: dict[tuple[str, str], Callable] = {}


sensor_measure = _stub("sensor", "measure")
sensor_log = _stub("sensor", "log")
controller_step = _stub("controller", "step")
controller_log = _stub("controller", "log")
actuator_command = _stub("actuator", "command")
actuator_command_at = _stub("actuator", "command_at")
actuator_force = _stub("actuator", "force")
actuator_derivative = _stub("actuator", "derivative")
plant_derivative = _stub("plant", "derivative")
plant_observe = _stub("plant", "observe")


def actuator_command_after(act, ast, aw, y, F, ctrl, cw, cmd):
    """The actuator's command after the controller's step: ``command_at`` with the limb
    Jacobian the controller left in its work, if both parts have it, else ``command``."""
    raise TypeError("actuator_command_after runs in compiled code only")


@overload(actuator_command_after, jit_options=_OPTIONS, strict=False, inline="always")
def _command_after(act, ast, aw, y, F, ctrl, cw, cmd):
    a, c = _lookup("actuator", act), _lookup("controller", ctrl)
    lanes = a is None and c is None
    if lanes:  # lane forms: the Jacobian is shared only where both are stacked
        a = _BY_LANE_TYPE.get(("actuator", getattr(act, "instance_class", None)))
        c = _BY_LANE_TYPE.get(("controller", getattr(ctrl, "instance_class", None)))
    if a is None or c is None:
        if lanes:
            return _lane_command(act, ctrl)
        return None
    if lanes and ("command_at" not in a.lanes or c.lane_limb_jacobian is None):
        return _lane_command(act, ctrl)
    path = c.lane_limb_jacobian if lanes else c.limb_jacobian
    if path is not None and "command_at" in a.functions:
        at = "cw" + "".join(f"[{i}]" for i in path)
        body = f"actuator_command_at(act, ast, aw, y, F, {at}, cmd)"
    else:
        body = "actuator_command(act, ast, aw, y, F, cmd)"
    local: dict[str, Any] = {"actuator_command": actuator_command,
                             "actuator_command_at": actuator_command_at}  # fmt: skip
    exec(f"def impl(act, ast, aw, y, F, ctrl, cw, cmd):\n    return {body}\n", local)
    return local["impl"]


def _lane_command(act, ctrl):
    if not isinstance(act, types.BaseNamedTuple) or not isinstance(ctrl, types.BaseNamedTuple):
        return None

    def impl(act, ast, aw, y, F, ctrl, cw, cmd):
        return actuator_command(act, ast, aw, y, F, cmd)

    return impl


class NoParams(NamedTuple):
    """A placeholder field for parts without parameters (Numba needs one field)."""

    unused: float = 0.0
