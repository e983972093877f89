"""``simulate``: one scenario, one controller, the loop of parts → :class:`Result`.

The scenario names the plant, sensor and actuator (``plant.kind``, ``sensor.kind``,
``actuators.kind``); ``controller`` names the controller. Each is looked up in the
registry of its kind (:mod:`pkmctl.parts`), built from the scenario, and run in the
compiled loop (:mod:`pkmctl.sim.loop`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np

from pkmctl._jit import kernel
from pkmctl.control.gains import Gains
from pkmctl.errors import InsufficientMemory, SimulationDiverged
from pkmctl.fuzzy import FuzzySystem, MamdaniSystem
from pkmctl.model.dynamics import (
    JQ,
    Q,
    actuator_forces_kernel,
    dynamics_kernel,
    inverse_dynamics,
    make_work,
)
from pkmctl.model.kinematics import limb_jacobian
from pkmctl.model.mechanism import Mechanism
from pkmctl.parts import Part, PartContext, PartError, get_part
from pkmctl.sim import metrics
from pkmctl.sim.loop import (
    STATUS,
    Inputs,
    LogBuffers,
    is_compiled,
    metric_params,
    metric_values,
    run_parts,
)
from pkmctl.sim.result import Result
from pkmctl.sim.scenario import BUILTINS, Scenario, ScenarioError, reference_outside
from pkmctl.sim.stepped import run_stepped

__all__ = [
    "check_memory",
    "desired_forces",
    "desired_limb_lengths",
    "memory_needed",
    "metrics_only",
    "part_memory",
    "precompile",
    "prepare",
    "resolve_parts",
    "run_prepared",
    "simulate",
    "simulate_many",
]

# Doubles per logged row: what prepare keeps (t, reference 9, q_d 4, tau_d 4) plus the
# trajectory's temporaries (3 x 3), and the loop's logs (LogBuffers: 26 columns).
_PREPARED_COLUMNS = 1 + 9 + 4 + 4 + 9
_LOG_COLUMNS = 3 + 3 + 6 + 3 + 4 + 4 + 3
# Per period of a chunk of a decimated run's inputs: t, the trajectory (3 x 3), the
# reference 9, q_d 4, tau_d 4 and the disturbance index.
_CHUNK_COLUMNS = 1 + 9 + 9 + 4 + 4 + 1
#: Periods per chunk of a run's inputs (a decimated run's: about 15 MB of arrays; a
#: whole run's are views of the prepared ones); a run reports progress after each.
CHUNK_PERIODS = 1 << 16
#: A decimated run of at most this many periods (13 s at 20 kHz) has all its chunks of
#: inputs computed once by :func:`prepare` and kept (14 doubles a period, 29 MB at most),
#: for all its runs and lane batches; a longer one computes each chunk when it runs.
CACHED_PERIODS = 4 * CHUNK_PERIODS
#: A run logged every period, watched (``progress``): its chunks are a 1/PROGRESS_STEPS of
#: it, but at least PROGRESS_MIN_PERIODS and at most CHUNK_PERIODS: a 10 s run at 20 kHz
#: reports 98 times, not 4. Its inputs are views of the prepared arrays, so the chunk size
#: changes nothing else (tests/test_logging.py); a 1 s PD run in 78 chunks instead of 1
#: took no longer beyond the run-to-run spread (61-96 ms, 15 alternating rounds).
PROGRESS_STEPS = 100
PROGRESS_MIN_PERIODS = 2048
# Per period of those kept chunks: the reference 9, q_d 4 and the disturbance index.
_CACHED_COLUMNS = 9 + 4 + 1
# logging.every values a refusal suggests (the smallest of these round numbers that fits)
_EVERY_SUGGESTIONS = tuple(m * 10**e for e in range(7) for m in (1, 2, 5))[1:]


def memory_needed(
    periods: int,
    controller_log: int = 0,
    *,
    runs: int = 1,
    every: int = 1,
    sensor_log: int = 0,
    disturbance_values: int = 0,
    part_values: int = 0,
    saved: bool = False,
) -> int:
    """Bytes of the arrays ``runs`` runs of ``periods`` control periods allocate, each
    logging every ``every``-th period: the prepared reference (every period, or the
    logged rows and one chunk of inputs at a time when decimated), the disturbance index,
    the logs, a controller log of ``controller_log`` and a sensor log of ``sensor_log``
    columns, ``disturbance_values`` held disturbance values (3 each) and ``part_values``
    doubles per period in the parts' bundles (:func:`part_memory`) per run; with
    ``saved``, the copy of one run's table that :func:`~pkmctl.save_result` makes (pyarrow
    copies the columns, CSV stacks them: a 20 s AFSMC run's save added 217-279 MB)."""
    rows = -(-periods // every)
    per_run = rows * (_LOG_COLUMNS + controller_log + sensor_log) + 3 * disturbance_values
    per_run += periods * part_values
    table = rows * (_LOG_COLUMNS + controller_log + sensor_log) if saved else 0
    if every == 1:
        shared = periods * (_PREPARED_COLUMNS + 1)  # + the disturbance index (int64)
    else:
        shared = rows * _PREPARED_COLUMNS + min(periods, CHUNK_PERIODS) * _CHUNK_COLUMNS
        if periods <= CACHED_PERIODS:
            shared += periods * _CACHED_COLUMNS
    return 8 * (shared + runs * per_run + table)


def check_saved_memory(scenario: Scenario, controller: str) -> None:
    """:func:`prepare`'s memory check for a run of ``controller`` whose result is then
    saved (``pkmctl simulate``): the save's copy of the table counted too, so that a run
    that fits but could not be saved is refused before it computes."""
    n, every = scenario.timing.periods, scenario.logging.every
    cols = log_columns(scenario, resolve_parts(scenario, controller))
    holds, parts = disturbance_count(scenario), part_memory(scenario, controller)

    def need(e: int) -> int:
        return memory_needed(n, cols, every=e, disturbance_values=holds, part_values=parts,
                             saved=True)  # fmt: skip

    Tc = scenario.timing.control_period
    check_memory(need(every), f"a {n * Tc:g} s run at T_c = {Tc:g} s and its save",
                 decimated=need, every=every, periods=n)  # fmt: skip


def part_memory(scenario: Scenario, controller: str | None = None) -> int:
    """Doubles per control period the bundles of the scenario's sensor, actuator and
    plant hold (their parts' ``memory``; the encoder's noise, say), and those of
    ``controller``'s (a controller's ``memory`` was not counted: a code reader)."""
    parts = list(_machine_parts(scenario).values())
    if controller is not None:
        parts.append(get_part("controller", controller))
    return sum(_memory_of(p, scenario) for p in parts if p.memory is not None)


def _memory_of(part: Part, scenario: Scenario) -> int:
    """A part's ``memory(scenario)``, checked: what it raises named as its part's, and a
    whole number >= 0 (a user's raised as "an internal error", and "lots" or NaN gave
    int()'s words: a code reader)."""
    value = part.hook("memory", scenario)
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float | np.integer | np.floating)
        or not (math.isfinite(value) and value >= 0 and float(value).is_integer())
    ):
        raise PartError(
            f"{part.kind} {part.name!r}: memory gave {value!r:.60}: must be a whole number "
            "of doubles per control period, >= 0"
        )
    return int(value)


def _available_memory() -> int | None:
    """Bytes this process can still allocate: MemAvailable, capped by a cgroup limit."""
    avail = None
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return None
    room = _cgroup_room()
    if room is not None:
        avail = min(avail if avail is not None else 2**63, room)
    return avail


#: A container's memory limit and use: (folder, limit file, use file), cgroup v2 then v1.
_CGROUPS = (
    ("/sys/fs/cgroup", "memory.max", "memory.current"),
    ("/sys/fs/cgroup/memory", "memory.limit_in_bytes", "memory.usage_in_bytes"),
)


def _cgroup_room(cgroups=_CGROUPS) -> int | None:
    """Bytes the first readable cgroup's limit leaves (None: no such file, or no limit;
    v1's "no limit" is a number near 2**63). v1 was not read, and a v1 container's
    limit not seen (a tester)."""
    for folder, limit_file, used_file in cgroups:
        try:
            with open(os.path.join(folder, limit_file), encoding="ascii") as fh:
                limit = fh.read().strip()
            with open(os.path.join(folder, used_file), encoding="ascii") as fh:
                used = int(fh.read().strip())
            bound = None if limit == "max" else int(limit)
        except (OSError, ValueError):
            continue
        if bound is None or bound >= 2**60:
            return None
        return bound - used
    return None


def _gib(n: int) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**28 else f"{n / 2**20:.0f} MiB"


def check_memory(need: int, what: str, *, decimated=None, every: int = 1, periods: int = 0) -> None:
    """Raise :class:`~pkmctl.errors.InsufficientMemory` (one line) if ``need`` bytes do not
    fit in the memory available, before anything is allocated.

    ``decimated(N)``, if given, is the need with ``logging.every = N``: the message then
    offers the smallest N (1, 2, 5, 10, 20, ... up to ``periods``) that would fit.
    """
    have = _available_memory()
    if have is None or need <= have:
        return
    hint = ""
    if decimated is not None:
        for n in _EVERY_SUGGESTIONS:
            if every < n <= periods and decimated(n) <= have:
                hint = (
                    f"log one row every {n} periods (logging.every = {n} needs "
                    f"{_gib(decimated(n))}; the metrics still cover every period), "
                )
                break
    raise InsufficientMemory(
        f"{what} needs {_gib(need)} of memory for its arrays, this machine has "
        f"{_gib(max(have, 0))} available: {hint}shorten timing.duration or lengthen "
        f"timing.control_period"
    )


def desired_forces(
    plant: Mechanism, Xd, Xdd, Xddd, scenario: Scenario | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """q_d (N, 4) and tau_a,d = J (J^T J)^-1 [M Xddot_d + C Xdot_d + G](X_d) (N, 4).

    The desired limb lengths and driving forces of Figures 13-16 and 23-26, from the
    true model, along a trajectory (N, 3) that the scenario has already validated; with
    ``scenario``, the true machine's: its rotor inertia, friction and payload (§7) too
    (the prototype's limbs need ~90 N more than the rigid model's while tracking).
    """
    from pkmctl.sim.plants import RigidPlant, desired_machine_forces

    Xd, Xdd, Xddd = (np.ascontiguousarray(a, dtype=float) for a in (Xd, Xdd, Xddd))
    q_des, tau_des = np.empty((Xd.shape[0], 4)), np.empty((Xd.shape[0], 4))
    machine = None
    if scenario is not None:
        ctx = PartContext(plant=plant, model=plant, gains=None, period=0.0, flc=None,
                          scenario=scenario)  # fmt: skip
        machine = RigidPlant.from_context(ctx)
    if machine is not None and machine.machine > 0.0:
        desired_machine_forces(machine, Xd, Xdd, Xddd, q_des, tau_des)
    else:  # the rigid model: the arithmetic of the paper's runs, bit for bit
        _desired_kernel(plant.geometry, plant.theta, Xd, Xdd, Xddd, q_des, tau_des)
    return q_des, tau_des


def desired_limb_lengths(plant: Mechanism, Xd) -> np.ndarray:
    """q_d (N, 4) along a trajectory (N, 3): what :func:`desired_forces` gives as q_d, bit
    for bit, from the limb kinematics alone (no body kinematics, no dynamics)."""
    Xd = np.ascontiguousarray(Xd, dtype=float)
    q_des = np.empty((Xd.shape[0], 4))
    _limb_lengths_kernel(plant.geometry, Xd, q_des)
    return q_des


@kernel
def _limb_lengths_kernel(geom, Xd, q_out):
    R, Jq = np.empty((3, 3)), np.empty((4, 3))
    for k in range(Xd.shape[0]):
        limb_jacobian(geom, Xd[k], R, Jq, q_out[k])


@kernel
def _desired_kernel(geom, theta, Xd, Xdd, Xddd, q_out, tau_out):
    work = make_work()
    M, Cv, G, F = np.empty((3, 3)), np.empty(3), np.empty(3), np.empty(3)
    for k in range(Xd.shape[0]):
        dynamics_kernel(geom, theta, Xd[k], Xdd[k], Xdd[k], work, M, Cv, G)
        inverse_dynamics(M, Cv, G, Xddd[k], F)
        actuator_forces_kernel(work[JQ], F, tau_out[k])
        q_out[k, :] = work[Q]


def disturbance_count(scenario: Scenario) -> int:
    """How many held values the disturbance draws for the run."""
    t_end = scenario.timing.periods * scenario.timing.control_period
    return int(math.floor(t_end / scenario.disturbance.hold + 1e-9)) + 1


def _disturbance_values(scenario: Scenario) -> np.ndarray:
    d = scenario.disturbance
    rng = np.random.default_rng(d.seed)
    return np.asarray(d.amplitude) * rng.uniform(-1.0, 1.0, size=(disturbance_count(scenario), 3))


def _disturbance_index(k0: int, k1: int, Tc: float, hold: float) -> np.ndarray:
    """Period k starts at k Tc; the value held then is number floor(k Tc / hold)."""
    return np.floor(np.arange(k0, k1) * Tc / hold + 1e-9).astype(np.int64)


def _desired(scenario: Scenario, plant: Mechanism, periods: np.ndarray, forces: bool = True):
    """t (m,), the reference [X_d, Xdot_d, Xddot_d] (m, 9), q_d and tau_d (m, 4) at the
    periods k of ``periods`` (each row computed alone: any subset gives the same bits);
    without ``forces``, tau_d is None and q_d comes from the limb kinematics alone (the
    same bits, a test checks)."""
    t = periods * scenario.timing.control_period
    Xdes, Xddes, Xdddes = scenario.trajectory.build().evaluate(t)
    outside = reference_outside(t, Xdes)  # the scenario's check sampled it every 1 ms at most
    if outside:
        raise ScenarioError(outside)
    if forces:
        q_des, tau_des = desired_forces(plant, Xdes, Xddes, Xdddes, scenario)
    else:
        q_des, tau_des = desired_limb_lengths(plant, Xdes), None
    reference = np.ascontiguousarray(np.hstack([Xdes, Xddes, Xdddes]))
    return t, reference, q_des, tau_des


@dataclass(frozen=True, eq=False)
class Prepared:
    """What every run of one scenario shares, whatever the seed and controller: the
    desired trajectory, limb lengths and forces at the logged periods (every period, or
    every ``logging.every``-th), and for a log of every period the disturbance index."""

    scenario: Scenario
    plant: Mechanism
    model: Mechanism
    t: np.ndarray  # (rows,)
    reference: np.ndarray  # (rows, 9): X_d, Xdot_d, Xddot_d
    q_des: np.ndarray
    tau_des: np.ndarray
    flc: MamdaniSystem | FuzzySystem  # the fuzzy term's system ([fuzzy])
    gains: Gains  # the controllers' gains (a seed changes none of them)
    periods: int
    every: int
    dist_index: np.ndarray | None  # (periods,) when every == 1
    # a decimated run of at most CACHED_PERIODS: its chunks of inputs by (k0, k1),
    # computed once for all its runs
    cached: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None

    def chunk(self, k0: int, k1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The loop's inputs for periods k0 .. k1 - 1 (:class:`pkmctl.sim.loop.Inputs`):
        views of the prepared arrays when they hold every period, else the kept chunk, else
        computed."""
        if self.every == 1:
            return self.reference[k0:k1], self.q_des[k0:k1], self.dist_index[k0:k1]
        if self.cached is not None and (k0, k1) in self.cached:
            return self.cached[k0, k1]
        return _chunk(self.scenario, self.plant, k0, k1)


def _chunk(scenario: Scenario, plant: Mechanism, k0: int, k1: int):
    """The reference (k1 - k0, 9), q_d (k1 - k0, 4) and disturbance index of periods
    k0 .. k1 - 1 (row by row: the bits of any other chunk's rows)."""
    _, reference, q_des, _ = _desired(scenario, plant, np.arange(k0, k1), False)
    Tc, hold = scenario.timing.control_period, scenario.disturbance.hold
    return reference, q_des, _disturbance_index(k0, k1, Tc, hold)


def _resolve(scenario: Scenario | str | os.PathLike[str], duration: float | None) -> Scenario:
    """The scenario (a built-in's name, a .toml file or a Scenario) with ``duration`` if
    given."""
    if duration is not None and (
        isinstance(duration, bool)
        or not isinstance(duration, int | float | np.integer | np.floating)
    ):  # float("0.1") took a string the scenario itself refuses
        raise TypeError(f"duration = {duration!r}: must be a number of seconds")
    if isinstance(scenario, os.PathLike) or (
        isinstance(scenario, str) and scenario not in BUILTINS and scenario.endswith(".toml")
    ):  # a file, as the CLI's NAME|FILE ("unknown built-in" for "my.toml": a tester)
        scenario = Scenario.from_toml(Path(scenario))
    elif isinstance(scenario, str):
        return Scenario.builtin(scenario, None if duration is None else float(duration))
    if not isinstance(scenario, Scenario):
        raise TypeError(
            f"scenario: expected a pkmctl.Scenario, a built-in name or a .toml file, got "
            f"{scenario!r}"
        )
    if duration is not None:
        return scenario.replace(**{"timing.duration": float(duration)})
    return scenario


def prepare(
    scenario: Scenario | str,
    duration: float | None,
    log_columns: int = 0,
    controller: str | None = None,
) -> Prepared:
    """Everything the runs of ``scenario`` share (for runs of many seeds or controllers
    on one scenario: :func:`run_prepared`); its memory is checked before anything is
    allocated, with ``log_columns`` more columns in the log of one run (its controller's
    and sensor's, :func:`log_columns`) and ``controller``'s part memory."""
    scenario = _resolve(scenario, duration)
    plant = scenario.plant()
    Tc = scenario.timing.control_period
    n = scenario.timing.periods
    if n < 1:
        raise ScenarioError("timing.duration: shorter than one control period")
    every = scenario.logging.every
    holds, parts = disturbance_count(scenario), part_memory(scenario, controller)
    # Refuse what cannot fit before allocating any of it (a 1 h run at 20 kHz: ~27 GiB).
    check_memory(
        memory_needed(n, log_columns, every=every, disturbance_values=holds, part_values=parts),
        f"a {n * Tc:g} s run at T_c = {Tc:g} s" + (f" logged every {every}" if every > 1 else ""),
        decimated=lambda e: memory_needed(
            n, log_columns, every=e, disturbance_values=holds, part_values=parts
        ),  # fmt: skip
        every=every,
        periods=n,
    )
    t, reference, q_des, tau_des = _desired(scenario, plant, np.arange(0, n, every))
    index = _disturbance_index(0, n, Tc, scenario.disturbance.hold) if every == 1 else None
    model = scenario.controller_mechanism()
    flc = scenario.fuzzy_system()
    # A decimated run (e.g. a campaign's runs, metrics_only): its chunks once here, not once
    # per run or lane batch (7 ms a second of run at 20 kHz), unless the run is too long.
    cached = None
    if every > 1 and n <= CACHED_PERIODS:
        bounds = [(k0, min(n, k0 + CHUNK_PERIODS)) for k0 in range(0, n, CHUNK_PERIODS)]
        cached = {(k0, k1): _chunk(scenario, plant, k0, k1) for k0, k1 in bounds}
    return Prepared(
        scenario, plant, model, t, reference, q_des, tau_des, flc,
        scenario.controller_gains(), n, every, index, cached,
    )  # fmt: skip


def metrics_only(scenario: Scenario) -> Scenario:
    """The scenario logging one row (t = 0): for runs judged by their metrics alone, which
    the loop accumulates over every period whatever ``logging.every`` is (campaign tasks,
    ``simulate_many(keep="metrics")``). Nothing else changes. A log of every period
    costs a lane loop about a fifth of its time (docs/performance.md), a 10 s run ~45 MB
    of memory, and its desired forces (which no metric reads) 14 ms a second of run."""
    logging = scenario.logging.model_copy(update={"every": max(1, scenario.timing.periods)})
    return scenario.model_copy(update={"logging": logging})  # valid: every in [1, periods]


def _with_seed(scenario: Scenario, seed: int) -> Scenario:
    """The scenario with another disturbance seed (validated here: nothing else changes)."""
    if not (
        isinstance(seed, int | np.integer) and not isinstance(seed, bool) and 0 <= seed <= 2**63 - 1
    ):
        raise ScenarioError(f"disturbance.seed = {seed!r}: must be an integer in [0, 2^63 - 1]")
    dist = scenario.disturbance.model_copy(update={"seed": int(seed)})
    return scenario.model_copy(update={"disturbance": dist})


def resolve_parts(scenario: Scenario, controller: str) -> dict[str, Part]:
    """The registered parts (sensor, controller, actuator, plant) a run of
    ``controller`` on ``scenario`` uses."""
    if not isinstance(controller, str):
        raise PartError(f"controller = {controller!r}: must be a registered controller's name")
    machine = _machine_parts(scenario)
    return {
        "plant": machine["plant"],
        "sensor": machine["sensor"],
        "controller": get_part("controller", controller),
        "actuator": machine["actuator"],
    }


def _machine_parts(scenario: Scenario) -> dict[str, Part]:
    """The parts the scenario itself names: its plant, sensor and actuator."""
    return {
        "plant": get_part("plant", scenario.plant_spec.kind),
        "sensor": get_part("sensor", scenario.sensor.kind),
        "actuator": get_part("actuator", scenario.actuators.kind),
    }


def simulate(
    scenario: Scenario | str | os.PathLike[str],
    controller: str = "afsmc",
    *,
    duration: float | None = None,
    seed: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Result:
    """Run one closed-loop experiment; ``duration`` and ``seed`` override the scenario's.

    ``scenario``: a :class:`Scenario`, a built-in's name, or a ``.toml`` file (a path, or
    a name ending in ``.toml``), as the CLI takes them. ``controller`` is any registered
    controller ("smc", "fsmc", "afsmc", "pd", "ctc", or a user's,
    :func:`pkmctl.register_controller`). Raises
    :class:`~pkmctl.SimulationDiverged` (with the partial result) if the state becomes
    non-finite or the pose leaves z > 0, |alpha|, |beta| < pi/2, checked every period.
    The model's other bounds (limbs over 1 mm, J's conditioning: docs/model.md) are not
    checked in the loop: a run may pass near a singular pose and end normally (a fuzzer's
    initial.Xdot = [0, 60, 0] reached alpha = 1.53 rad). ``progress(periods done, periods)`` is
    called as the run goes, from the thread that runs it: about every 1 % of the run
    (:data:`PROGRESS_STEPS`; every :data:`CHUNK_PERIODS` periods for a run logged every
    ``logging.every`` > 1 periods), or every :data:`pkmctl.sim.stepped.PROGRESS_PERIODS`
    for a plant stepped from Python (MuJoCo's).
    """
    if progress is not None and not callable(progress):
        raise TypeError(f"progress = {progress!r:.60}: must be a function (done, total) or None")
    scenario = _resolve(scenario, duration)
    parts = resolve_parts(scenario, controller)
    prep = prepare(scenario, None, log_columns(scenario, parts), parts["controller"].name)
    return run_prepared(prep, parts, seed, progress=progress)


def log_columns(scenario: Scenario, parts: dict[str, Part]) -> int:
    """Columns the controller's and the sensor's logs add to a run's log (the AFSMC's 36
    of Theta^, the encoder's 4 lengths): a constant size is read as it is, else from the
    part's parameter bundle (built, not its state or work)."""
    ctx = None
    n = 0
    for kind in ("controller", "sensor"):
        part = parts[kind]
        try:
            n += int(part.log_size(None))
            continue
        except Exception:  # a size that reads the bundle
            pass
        if ctx is None:
            ctx = _context(scenario)
        n += int(part.log_size(part.bundle(ctx)))
    return n


def check_machine(scenario: Scenario) -> None:
    """Build the scenario's plant, sensor and actuator bundles: what refuses to build (a
    plant 'mujoco' without MuJoCo) says so before a loop compiles (``reproduce`` compiled
    five for minutes in its workers, then refused)."""
    ctx = _context(scenario)
    for part in _machine_parts(scenario).values():
        part.bundle(ctx)


def _context(scenario: Scenario) -> PartContext:
    """What a part's build sees of ``scenario`` (no seed of a run)."""
    return PartContext(plant=scenario.plant(), model=scenario.controller_mechanism(),
                       gains=scenario.controller_gains(), period=scenario.timing.control_period,
                       flc=scenario.fuzzy_system(), scenario=scenario)  # fmt: skip


def _build(parts: dict[str, Part], ctx: PartContext, plant_state: np.ndarray) -> dict:
    bundles = {}
    for kind, part in parts.items():
        bundles[kind] = part.make(ctx)  # a user's exception named (Part.make)
    p, x0, w = bundles["plant"]
    if x0.shape[0] < 6:
        raise PartError(f"plant {parts['plant'].name!r}: state_size must be >= 6 ([X, Xdot, ...])")
    x0[:6] = plant_state
    return bundles


@dataclass(eq=False)
class _Run:
    """One run, set up: its scenario, context, bundles, the loop's inputs and limits."""

    scenario: Scenario
    ctx: PartContext
    bundles: dict
    inputs: Inputs
    starts: tuple
    force_limit: float
    speed_limit: float


#: Log names a result keeps in its own fields, with the width each must have.
_RESULT_LOGS = {"q_measured": 4}


def _check_log_names(parts: dict[str, Part], bundles: dict) -> None:
    """Refuse logs a result cannot keep apart: a sensor and a controller logging under one
    name (the sensor's rows replaced the controller's, without a word), or a log named as a
    result's own field with another width (``q_measured`` of 3 columns ran, then could
    not be saved)."""
    named = {}
    for kind in ("sensor", "controller"):
        part = parts[kind]
        width = int(part.log_size(bundles[kind][0]))
        if width == 0:
            continue
        name = part.log_name or part.name
        if name in named:
            other = parts[named[name]]
            raise PartError(
                f"{named[name]} {other.name!r} and {kind} {part.name!r} both log as {name!r}: "
                "give one of them another log_name"
            )
        named[name] = kind
        if name in _RESULT_LOGS and width != _RESULT_LOGS[name]:
            raise PartError(
                f"{kind} {part.name!r}: log_name {name!r} is the result's field of "
                f"{_RESULT_LOGS[name]} columns, its log_size gives {width}: another name, or "
                f"{_RESULT_LOGS[name]} columns"
            )


def _set_up(prep: Prepared, parts: dict[str, Part], seed: int | None, check_logs: bool) -> _Run:
    scenario = prep.scenario if seed is None else _with_seed(prep.scenario, seed)
    Tc = scenario.timing.control_period
    ctx = PartContext(
        plant=prep.plant,
        model=prep.model,
        gains=prep.gains,
        period=Tc,
        flc=prep.flc,
        scenario=scenario,
    )
    x0 = np.concatenate([scenario.initial.X, scenario.initial.Xdot]).astype(float)
    bundles = _build(parts, ctx, x0)
    _check_log_names(parts, bundles)
    n, every = prep.periods, prep.every
    holds = disturbance_count(scenario)
    if check_logs:  # the prepared arrays exist already: only the logs are new
        n_log = int(parts["controller"].log_size(bundles["controller"][0]))
        n_slog = int(parts["sensor"].log_size(bundles["sensor"][0]))

        def logs_need(e: int) -> int:
            rows = -(-n // e)
            return 8 * (rows * (_LOG_COLUMNS + n_log + n_slog) + 3 * holds)

        check_memory(logs_need(every), f"the logs of a {n * Tc:g} s run",
                     decimated=logs_need, every=every, periods=n)  # fmt: skip
    force_limit, speed_limit = math.inf, math.inf
    if parts["actuator"].limits is not None:
        act = parts["actuator"]
        limits = act.hook("limits", bundles["actuator"][0])
        try:
            force_limit, speed_limit = (float(v) for v in limits)
        except (TypeError, ValueError):
            force_limit = math.nan
        # (> 0: (-1, -1) put every period "at the force limit", and NaN read as none: a
        # code reader)
        if not (force_limit > 0 and speed_limit > 0):
            raise PartError(
                f"actuator {act.name!r}: limits gave {limits!r:.60}: must be two numbers > 0 "
                "(force N, speed m/s; inf: none)"
            ) from None
    starts = tuple(metrics.first_period(w, Tc) for w in metrics.WINDOWS)
    mp = metric_params(starts, metrics.ERROR_SCALE, force_limit * (1 - metrics.LIMIT_MARGIN),
                       speed_limit, prep.plant.geometry)  # fmt: skip
    inputs = Inputs(
        periods=n,
        every=every,
        chunk_size=CHUNK_PERIODS,  # (a whole run's inputs are views: chunks for progress)
        chunk=prep.chunk,
        dist_values=_disturbance_values(scenario),
        metrics=mp,
    )
    return _Run(scenario, ctx, bundles, inputs, starts, force_limit, speed_limit)


def run_prepared(
    prep: Prepared,
    parts: dict[str, Part],
    seed: int | None,
    buffers: LogBuffers | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Result:
    """One run of ``prep``'s scenario with ``parts`` and disturbance ``seed`` (None: the
    scenario's); ``buffers`` lets runs of one length share their log arrays; ``progress``
    as in :func:`simulate`."""
    run = _set_up(prep, parts, seed, buffers is None)
    stepped = parts["plant"].stepper is not None
    if progress is not None and prep.every == 1:  # finer chunks: only the reports change
        n = run.inputs.periods
        size = min(CHUNK_PERIODS, max(PROGRESS_MIN_PERIODS, -(-n // PROGRESS_STEPS)))
        run.inputs = replace(run.inputs, chunk_size=size)
    out = (run_stepped if stepped else run_parts)(
        parts,
        run.bundles,
        *((run.ctx,) if stepped else ()),
        period=run.scenario.timing.control_period,
        substeps=run.scenario.timing.substeps,
        inputs=run.inputs,
        buffers=buffers,
        progress=progress,
    )
    return _result(prep, parts, run, out)


def run_prepared_lanes(
    prep: Prepared,
    parts: dict[str, Part],
    seeds: list[int | None],
    buffers: list[LogBuffers] | None = None,
) -> list[Result | Exception]:
    """The runs of ``seeds`` at once in SIMD lanes (:mod:`pkmctl.sim.lanes`), one lane
    each: per seed the Result :func:`run_prepared` gives, or the exception it raises
    (:class:`~pkmctl.SimulationDiverged` for a lane that stopped). A plant stepped
    outside compiled code (MuJoCo) has no lanes: its runs go one at a time."""
    from pkmctl.sim.lanes import run_lanes

    if parts["plant"].stepper is not None:  # stepped outside compiled code: one at a time
        out: list[Result | Exception] = []
        for i, s in enumerate(seeds):
            try:
                out.append(run_prepared(prep, parts, s, None if buffers is None else buffers[i]))
            except SimulationDiverged as exc:
                out.append(exc)
        return out
    results: list[Result | Exception] = []
    runs = []  # (index in seeds, its run): those whose parts built
    for i, s in enumerate(seeds):
        try:
            runs.append((i, _set_up(prep, parts, s, buffers is None)))
            results.append(None)
        except PartError as exc:  # a build that refuses this seed: its own error, the
            results.append(exc)  # others run (a campaign stored all with the first's)
    if not runs:
        return results
    sc = runs[0][1].scenario
    outs = run_lanes(
        parts,
        [r.bundles for _, r in runs],
        period=sc.timing.control_period,
        substeps=sc.timing.substeps,
        inputs=[r.inputs for _, r in runs],
        buffers=buffers,
    )
    users = _user_part_digests(parts)  # once for the batch (0.6 ms or more a digest)
    for (i, run), out in zip(runs, outs, strict=True):
        try:
            results[i] = _result(prep, parts, run, out, users)
        except SimulationDiverged as exc:
            results[i] = exc
    return results


def _user_part_digests(parts: dict[str, Part]) -> dict[str, dict]:
    """:func:`pkmctl.parts.part_digest` of each user part, by ``"KIND NAME"``: a run's
    JSON said nothing of the version of the user's controller that made it (a tester)."""
    from pkmctl.parts import part_digest

    return {f"{k} {p.name}": part_digest(p) for k, p in parts.items() if not p.builtin}


def _result(prep: Prepared, parts: dict[str, Part], run: _Run, out,
            users: dict[str, dict] | None = None) -> Result:  # fmt: skip
    """The Result of one run's LoopOutput; raises SimulationDiverged if it stopped."""
    scenario, bundles = run.scenario, run.bundles
    Tc, every = scenario.timing.control_period, prep.every
    force_limit, speed_limit, starts = run.force_limit, run.speed_limit, run.starts
    m, lg = out.steps, out.logs
    rows = -(-m // every)
    values = metric_values(out.metrics, run.inputs.metrics)
    if not math.isfinite(speed_limit):
        values["peak_limb_speed"] = np.full(4, np.nan)
    loop_metrics = metrics.LoopMetrics(
        periods=m, period=Tc, windows=metrics.WINDOWS, starts=starts,
        force_limit=force_limit, speed_limit=speed_limit, **values,
    )  # fmt: skip
    ctrl = parts["controller"]
    logs = {}
    theta_hat = None
    if out.controller_log is not None:
        if ctrl.log_name == "theta_hat":
            theta_hat = out.controller_log
        else:
            logs[ctrl.log_name or ctrl.name] = out.controller_log
    q_measured = lg["q"]
    if out.sensor_log is not None:
        name = parts["sensor"].log_name or parts["sensor"].name
        if name == "q_measured":
            q_measured = out.sensor_log
        else:
            logs[name] = out.sensor_log
    info = {"kernel_seconds": out.kernel_seconds, "steps": m}
    for kind, part in parts.items():
        if part.report is not None:
            said = part.hook("report", bundles[kind][0], out.final_state[kind])
            if not isinstance(said, dict):  # ("'int' object is not iterable": a reader)
                raise PartError(
                    f"{kind} {part.name!r}: report gave {said!r:.60}: must be a dict of "
                    "what to add to the result's info"
                )
            info.update(said)
    if users is None:
        users = _user_part_digests(parts)
    if users:  # which version of a user's part made it
        from pkmctl.io.results import provenance

        info["software"] = {**provenance(), "user_parts": users}
    ref = prep.reference
    result = Result(
        scenario=scenario,
        controller=ctrl.name,
        t=prep.t[:rows],
        X=lg["X"],
        Xdot=lg["Xdot"],
        X_desired=ref[:rows, 0:3],
        Xdot_desired=ref[:rows, 3:6],
        q=lg["q"],
        q_desired=prep.q_des[:rows],
        F=lg["F"],
        tau=lg["tau"],
        tau_desired=prep.tau_des[:rows],
        disturbance=lg["disturbance"],
        theta_hat=theta_hat,
        X_measured=lg["y"][:, 0:3],
        Xdot_measured=lg["y"][:, 3:6],
        q_measured=q_measured,
        logs=logs,
        final_state=out.final_state,
        parts={k: p.name for k, p in parts.items()},
        success=out.status == 0,
        message="ok" if out.status == 0 else STATUS[out.status],
        info=info,
        loop_metrics=loop_metrics,
    )
    if out.status:
        tk = m * Tc
        x = out.final_state["plant"]
        raise SimulationDiverged(
            f"simulation diverged at t = {tk:.6g} s ({ctrl.name}): {STATUS[out.status]}, "
            f"X = {np.array2string(x[:3], precision=4)}, Xdot = "
            f"{np.array2string(x[3:6], precision=4)}",
            time=tk,
            state=x[:6].copy(),
            partial=result,
        )
    return result


@overload
def simulate_many(
    scenario: Scenario | str | os.PathLike[str],
    controller: str = ...,
    *,
    seeds: Iterable[int],
    duration: float | None = ...,
    workers: int | None = ...,
    keep: Literal["results"] = ...,
    lanes: int | None = ...,
    diverged: Literal["raise", "keep"] = ...,
    progress: Callable[[int, int], None] | None = ...,
) -> list[Result]: ...


@overload
def simulate_many(
    scenario: Scenario | str | os.PathLike[str],
    controller: str = ...,
    *,
    seeds: Iterable[int],
    duration: float | None = ...,
    workers: int | None = ...,
    keep: Literal["metrics"],
    lanes: int | None = ...,
    diverged: Literal["raise", "keep"] = ...,
    progress: Callable[[int, int], None] | None = ...,
) -> list[dict[str, Any]]: ...


@overload
def simulate_many(
    scenario: Scenario | str | os.PathLike[str],
    controller: str = ...,
    *,
    seeds: Iterable[int],
    duration: float | None = ...,
    workers: int | None = ...,
    keep: str = ...,
    lanes: int | None = ...,
    diverged: str = ...,
    progress: Callable[[int, int], None] | None = ...,
) -> list[Result] | list[dict[str, Any]]: ...


def simulate_many(
    scenario: Scenario | str | os.PathLike[str],
    controller: str = "afsmc",
    *,
    seeds: Iterable[int],
    duration: float | None = None,
    workers: int | None = None,
    keep: str = "results",
    lanes: int | None = None,
    diverged: str = "raise",
    progress: Callable[[int, int], None] | None = None,
) -> list[Result] | list[dict[str, Any]]:
    """Run one scenario for several disturbance seeds, in SIMD lanes and parallel threads.

    The scenario, its desired trajectory and desired forces are prepared once. The seeds
    go in batches of ``lanes`` runs that one compiled loop advances at once
    (:mod:`pkmctl.sim.lanes`; default: the machine's SIMD width when the parts have lane
    forms, else 1, one run at a time; a rest of at most half a batch goes one run at a
    time, :func:`~pkmctl.sim.lanes.lane_batches`); the compiled loop releases the GIL, so
    ``workers`` threads (default: the number of cores) run batches side by side. Results
    come back in the order of ``seeds``, each what :func:`simulate` gives for its seed;
    the first failing run's error is raised. A run that diverges stops alone (its lane),
    and ``diverged`` says what then: ``"raise"`` raises its
    :class:`~pkmctl.errors.SimulationDiverged`, which names the seed (``.seed``) and
    holds the partial result; ``"keep"`` puts in its place the partial
    :class:`Result` (``success`` False, ``message`` why), or with ``keep="metrics"``
    ``{"seed": s, "diverged_at": t, "message": why}``, and returns every run.

    ``keep="results"`` returns the :class:`Result` of every run. ``keep="metrics"``
    returns ``{"seed": s, **metrics.summary(result, source="loop")}`` per run instead:
    the metrics the loop accumulates over every period, which need no log, so those runs
    log only t = 0 (:func:`metrics_only`), and each worker reuses its log buffers: a
    campaign of many seeds then never touches fresh memory after its first runs
    (first-touch page faults of ~45 MB per 10 s run limited thread scaling; see
    docs/performance.md).

    ``progress(runs done, runs)`` is called from the calling thread as the batches end,
    in the order of ``seeds`` (a notebook's 100 seeds showed nothing until all had run).
    A Ctrl-C returns at once; batches already running end in the background.
    """
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from pkmctl.sim.lanes import in_batches, lane_count, lanes_supported, padded_lanes
    from pkmctl.sim.metrics import summary

    if keep not in ("results", "metrics"):
        raise ValueError(f"keep = {keep!r}: must be 'results' or 'metrics'")
    if progress is not None and not callable(progress):
        raise TypeError(f"progress = {progress!r:.60}: must be a function (done, total) or None")
    if diverged not in ("raise", "keep"):
        raise ValueError(f"diverged = {diverged!r}: must be 'raise' or 'keep'")
    if isinstance(seeds, (int, np.integer, str, bytes)) or not hasattr(seeds, "__iter__"):
        raise TypeError(f"seeds = {seeds!r}: must be a list of integers, e.g. range(5)")
    seeds = list(seeds)
    workers = (os.cpu_count() or 1) if workers is None else workers
    if not (_is_int(workers) and workers >= 1):
        raise ValueError(f"workers = {workers!r}: must be an integer >= 1")
    if lanes is not None and not (_is_int(lanes) and 1 <= lanes <= 64):
        raise ValueError(f"lanes = {lanes!r}: must be an integer in [1, 64]")
    lanes = None if lanes is None else int(lanes)
    workers = int(workers)
    sc = _resolve(scenario, duration)
    if keep == "metrics":  # the metrics alone: no log
        sc = metrics_only(sc)
    parts = resolve_parts(sc, controller)
    for s in seeds:
        _with_seed(sc, s)  # fail fast on a bad seed, before any run
    if lanes is None:
        lanes = lane_count() if lanes_supported(parts) else 1
    chunks = in_batches(seeds, lanes)
    _check_many(sc, parts, keep, len(seeds), min(workers, len(chunks)) * padded_lanes(lanes))
    prep = prepare(sc, None)
    local = threading.local()
    n_log = 0
    if keep == "metrics":
        ctx = PartContext(prep.plant, prep.model, prep.gains,
                          prep.scenario.timing.control_period, prep.flc, prep.scenario)  # fmt: skip
        n_log = int(parts["controller"].log_size(parts["controller"].bundle(ctx)))

    def buffers(n: int) -> list[LogBuffers]:  # a thread's batches: lanes of one stack
        if not hasattr(local, "buffers"):  # as many as a padded lane loop logs into
            local.buffers = LogBuffers.stacked(padded_lanes(lanes), prep.t.size, n_log)
        return local.buffers if n > 1 else local.buffers[:1]

    def batch(chunk: list) -> list:
        bufs = buffers(len(chunk)) if keep == "metrics" else None
        if len(chunk) == 1:
            try:
                out = [run_prepared(prep, parts, chunk[0], None if bufs is None else bufs[0])]
            except SimulationDiverged as exc:
                out = [exc]
        else:
            out = run_prepared_lanes(prep, parts, chunk, bufs)
        for i, (s, r) in enumerate(zip(chunk, out, strict=True)):
            if isinstance(r, SimulationDiverged):
                r = _seeded(r, int(s))
                if diverged == "raise":
                    raise r
                out[i] = (
                    r.partial
                    if keep == "results"
                    else {"seed": int(s), "diverged_at": r.time, "message": str(r)}
                )
            elif isinstance(r, Exception):
                raise r
            elif keep == "metrics":
                out[i] = {"seed": int(s), **summary(r, source="loop")}
        return out

    # not `with`: its exit waits for the batches running, whose compiled loops cannot be
    # interrupted, so a Ctrl-C (or a run that diverged, raised) came back only when they
    # had ended: 14 s after the signal for 16 runs of 60 s (a tester). Now it returns at
    # once, the queue dropped; the batches running end in the background.
    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        out = []
        for rs in pool.map(batch, chunks):
            out += rs
            if progress is not None:
                progress(len(out), len(seeds))
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
    return out


def _is_int(v) -> bool:
    """An integer, Python's or NumPy's (as seeds may be), not a bool."""
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _seeded(exc: SimulationDiverged, seed: int) -> SimulationDiverged:
    """``exc`` saying which of simulate_many's seeds diverged (``.seed``)."""
    out = SimulationDiverged(f"seed {seed}: {exc}", time=exc.time, state=exc.state,
                             partial=exc.partial)  # fmt: skip
    out.seed = seed
    out.__cause__ = exc.__cause__
    return out


def _check_many(sc: Scenario, parts: dict[str, Part], keep: str, runs: int, live: int) -> None:
    """simulate_many's memory, before anything is computed: ``prepare`` checks one run,
    but the batches in flight log ``live`` runs at once (threads x lanes), and with
    ``keep="results"`` every one of the ``runs`` runs keeps its logs to the end."""
    n, every, Tc = sc.timing.periods, sc.logging.every, sc.timing.control_period
    cols = log_columns(sc, parts) if keep == "results" else 0
    holds, values = disturbance_count(sc), part_memory(sc, parts["controller"].name)
    count = max(runs, live) if keep == "results" else live

    def need(e: int) -> int:
        return memory_needed(n, cols, runs=count, every=e, disturbance_values=holds,
                             part_values=values)  # fmt: skip

    if count > 1:
        what = f"{runs} runs of {n * Tc:g} s at T_c = {Tc:g} s" + (
            f" logged every {every}" if every > 1 else ""
        ) + (" (keep='results' holds every run's log)" if keep == "results" else
             f" ({live} at a time)")  # fmt: skip
        check_memory(need(every), what, decimated=need if keep == "results" else None,
                     every=every, periods=n)  # fmt: skip


def _compile_group(scenario_toml: str, job: tuple[str, list[str]]) -> str:
    """In a worker process, one job of :func:`_plan`: ``("loops", names)`` runs each
    controller for one period, which compiles its loop (and every kernel it calls) into
    the disk cache; ``("steps", names)`` calls each controller's compiled step once from Python,
    which compiles its own kernels (the fuzzy term, the regressor) without a loop, and
    the model's batch kernel of ``Mechanism.gravity``. Returns "" or the first error (the
    caller will meet it again)."""
    what, controllers = job
    try:
        sc = Scenario.from_toml(scenario_toml)
        if what == "steps":
            prep_ctx = PartContext(sc.plant(), sc.controller_mechanism(),
                                   sc.controller_gains(), sc.timing.control_period,
                                   sc.fuzzy_system(), sc)  # fmt: skip
            vec, ref = np.zeros((6, 6)), np.zeros((1, 9))  # as the loop passes them
            vec[0, :3] = sc.initial.X
            for c in controllers:
                part = resolve_parts(sc, c)["controller"]
                params, state, work = part.make(prep_ctx)
                step = part.compiled.get("step")
                if step is not None:  # a built-in kernel, cached as the loop will call it
                    step(params, state, work, vec[0], ref[0], vec[1, 0:3])
            # and the model's batch kernel, which a report's gravity paragraph would
            # otherwise compile after the runs (5 s): here it overlaps the first loop's
            sc.plant().gravity(np.asarray(sc.trajectory.offset, dtype=float))
            return ""
        sc = sc.replace(**{"timing.duration": sc.timing.control_period, "logging.every": 1})
        for c in controllers:
            simulate(sc, controller=c)
    except Exception as exc:  # noqa: BLE001 - reported by the run that follows
        return f"{type(exc).__name__}: {exc}"
    return ""


def _plan(todo: list[str], heavy: set[str], n: int) -> list[list[tuple[str, list[str]]]]:
    """The jobs of :func:`precompile`, in phases of at most ``n`` >= 2 jobs that run side
    by side, one phase after the other.

    Every loop compiles the plant's kernels, and a process compiles a kernel once; the
    controllers in ``heavy`` (a fuzzy term: the costliest kernels) have large kernels of
    their own. So the first phase compiles each kernel once, on one core each: one loop
    without a heavy controller (the plant's, the trajectory's and the metrics' kernels)
    beside the heavy controllers' own kernels, stepped without a loop. The second phase
    builds the other loops, dealt over the workers, from the cached kernels. With no
    heavy controller there is one phase, the loops dealt out."""
    first = next((c for c in todo if c not in heavy), None)
    if first is None or not heavy:
        return [[("loops", g) for g in (todo[i::n] for i in range(n)) if g]]
    rest = [c for c in todo if c != first]
    return [
        [("loops", [first]), ("steps", [c for c in rest if c in heavy])],
        [("loops", g) for g in (rest[i::n] for i in range(n)) if g],
    ]


def precompile(
    scenario: Scenario,
    controllers,
    *,
    workers: int | None = None,
    on_start=None,
) -> list[str]:
    """Compile the loops of ``controllers`` on ``scenario``'s parts into the disk cache,
    in parallel worker processes, before a run that needs them all.

    Numba compiles one function at a time per process; with several loops to build and
    several cores, worker processes build them side by side, in the phases of
    :func:`_plan` so that no kernel is compiled twice. Loops already compiled on this
    machine, and combinations with parts registered outside pkmctl (a worker would not
    import them), are skipped; so is everything when fewer than two workers would run, or
    when the disk cache cannot be written (:func:`pkmctl._jit.cache_writable`).
    Calls ``on_start(controllers, workers)`` before it starts; returns the controllers
    whose loops were compiled.
    """
    from pkmctl import _jit

    from .workers import spawn_pool

    if not _jit.cache_writable():  # the workers' compiled loops could not be shared
        return []
    todo, heavy = [], set()
    for c in controllers:
        parts = resolve_parts(scenario, c)
        if all(p.builtin for p in parts.values()) and not is_compiled(parts):
            todo.append(c)
            if "flc" in parts["controller"].params._fields:
                heavy.add(c)
    n = min(len(todo), os.cpu_count() or 1, workers or len(todo))
    if n < 2:
        return []
    check_machine(scenario)
    phases = _plan(todo, heavy, n)
    n = max(len(p) for p in phases)
    if on_start is not None:
        on_start(todo, n)
    text = scenario.to_toml()
    with spawn_pool(n) as pool:
        for jobs in phases:
            list(pool.map(_compile_group, [text] * len(jobs), jobs))
    return todo
