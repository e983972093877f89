"""``simulate``: one scenario, one controller, the loop of parts → :class:`Result`.

The scenario names the plant, sensor and actuator (``plant.kind``, ``sensor.kind``,
``actuators.kind``); ``controller`` names the controller. Each is looked up in the
registry of its kind (:mod:`pkmctl.parts`), built from the scenario, and run in the
compiled loop (:mod:`pkmctl.sim.loop`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from pkmctl._jit import kernel
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
from pkmctl.model.mechanism import Mechanism
from pkmctl.parts import Part, PartContext, PartError, get_part
from pkmctl.sim.loop import STATUS, LogBuffers, is_compiled, run_parts
from pkmctl.sim.result import Result
from pkmctl.sim.scenario import Scenario, ScenarioError
from pkmctl.sim.stepped import run_stepped

__all__ = [
    "check_memory",
    "desired_forces",
    "memory_needed",
    "precompile",
    "simulate",
    "simulate_many",
]

# Doubles per control period: what _prepare keeps (t, reference 9, q_d 4, tau_d 4) plus
# the trajectory's temporaries (3 x 3), and the loop's logs (LogBuffers: 26 columns).
_PREPARED_COLUMNS = 1 + 9 + 4 + 4 + 9
_LOG_COLUMNS = 3 + 3 + 6 + 3 + 4 + 4 + 3


def memory_needed(periods: int, controller_log: int = 0, *, runs: int = 1) -> int:
    """Bytes of the arrays ``runs`` runs of ``periods`` control periods allocate (their
    prepared reference, their logs and a controller log of ``controller_log`` columns)."""
    return 8 * periods * (_PREPARED_COLUMNS + runs * (_LOG_COLUMNS + controller_log))


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
    try:  # a container's limit (cgroup v2)
        with open("/sys/fs/cgroup/memory.max", encoding="ascii") as fh:
            limit = fh.read().strip()
        with open("/sys/fs/cgroup/memory.current", encoding="ascii") as fh:
            used = int(fh.read().strip())
        if limit != "max":
            avail = min(avail if avail is not None else 2**63, int(limit) - used)
    except (OSError, ValueError):
        pass
    return avail


def _gib(n: int) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**28 else f"{n / 2**20:.0f} MiB"


def check_memory(need: int, what: str) -> None:
    """Raise :class:`~pkmctl.errors.InsufficientMemory` (one line) if ``need`` bytes do not
    fit in the memory available, before anything is allocated."""
    have = _available_memory()
    if have is not None and need > have:
        raise InsufficientMemory(
            f"{what} needs {_gib(need)} of memory for its arrays, this machine has "
            f"{_gib(max(have, 0))} available: shorten timing.duration or lengthen "
            f"timing.control_period"
        )


def desired_forces(plant: Mechanism, Xd, Xdd, Xddd) -> tuple[np.ndarray, np.ndarray]:
    """q_d (N, 4) and tau_a,d = J (J^T J)^-1 [M Xddot_d + C Xdot_d + G](X_d) (N, 4).

    The desired limb lengths and driving forces of Figures 13-16 and 23-26, from the
    true model, along a trajectory (N, 3) that the scenario has already validated.
    """
    Xd, Xdd, Xddd = (np.ascontiguousarray(a, dtype=float) for a in (Xd, Xdd, Xddd))
    q_des, tau_des = np.empty((Xd.shape[0], 4)), np.empty((Xd.shape[0], 4))
    _desired_kernel(plant.geometry, plant.theta, Xd, Xdd, Xddd, q_des, tau_des)
    return q_des, tau_des


@kernel
def _desired_kernel(geom, theta, Xd, Xdd, Xddd, q_out, tau_out):
    work = make_work()
    M, Cv, G, F = np.empty((3, 3)), np.empty(3), np.empty(3), np.empty(3)
    for k in range(Xd.shape[0]):
        dynamics_kernel(geom, theta, Xd[k], Xdd[k], Xdd[k], work, M, Cv, G)
        inverse_dynamics(M, Cv, G, Xddd[k], F)
        actuator_forces_kernel(work[JQ], F, tau_out[k])
        q_out[k, :] = work[Q]


def _disturbance(scenario: Scenario, n: int, Tc: float):
    d = scenario.disturbance
    t_end = n * Tc
    n_hold = int(math.floor(t_end / d.hold + 1e-9)) + 1
    rng = np.random.default_rng(d.seed)
    values = np.asarray(d.amplitude) * rng.uniform(-1.0, 1.0, size=(n_hold, 3))
    # period k starts at k Tc; the value held then is number floor(k Tc / hold)
    index = np.floor(np.arange(n) * Tc / d.hold + 1e-9).astype(np.int64)
    return values, index


@dataclass(frozen=True, eq=False)
class _Prepared:
    """What every run of one scenario shares, whatever the seed and controller."""

    scenario: Scenario
    plant: Mechanism
    model: Mechanism
    t: np.ndarray
    reference: np.ndarray  # (n, 9): X_d, Xdot_d, Xddot_d
    q_des: np.ndarray
    tau_des: np.ndarray
    flc: MamdaniSystem | FuzzySystem  # the fuzzy term's system ([fuzzy])


def _prepare(scenario: Scenario | str, duration: float | None) -> _Prepared:
    if isinstance(scenario, str):
        scenario = Scenario.builtin(scenario)
    if not isinstance(scenario, Scenario):
        raise TypeError(
            f"scenario: expected a pkmctl.Scenario or a built-in name, got {scenario!r}"
        )
    if duration is not None:
        scenario = scenario.replace(**{"timing.duration": float(duration)})
    plant = scenario.plant()
    Tc = scenario.timing.control_period
    n = int(round(scenario.timing.duration / Tc))
    if n < 1:
        raise ScenarioError("timing.duration: shorter than one control period")
    # Refuse what cannot fit before allocating any of it (a 1 h run at 20 kHz: ~27 GiB).
    check_memory(memory_needed(n), f"a {n * Tc:g} s run at T_c = {Tc:g} s")
    t = np.arange(n) * Tc
    Xdes, Xddes, Xdddes = scenario.trajectory.build().evaluate(t)
    q_des, tau_des = desired_forces(plant, Xdes, Xddes, Xdddes)
    reference = np.ascontiguousarray(np.hstack([Xdes, Xddes, Xdddes]))
    model = scenario.controller_mechanism()
    flc = scenario.fuzzy_system()
    return _Prepared(scenario, plant, model, t, reference, q_des, tau_des, flc)


def _with_seed(scenario: Scenario, seed: int) -> Scenario:
    """The scenario with another disturbance seed (validated here: nothing else changes)."""
    if not (isinstance(seed, int | np.integer) and 0 <= seed <= 2**63 - 1):
        raise ScenarioError(f"disturbance.seed = {seed!r}: must be an integer in [0, 2^63 - 1]")
    dist = scenario.disturbance.model_copy(update={"seed": int(seed)})
    return scenario.model_copy(update={"disturbance": dist})


def _parts(scenario: Scenario, controller: str) -> dict[str, Part]:
    if not isinstance(controller, str):
        raise PartError(f"controller = {controller!r}: must be a registered controller's name")
    return {
        "plant": get_part("plant", scenario.plant_spec.kind),
        "sensor": get_part("sensor", scenario.sensor.kind),
        "controller": get_part("controller", controller),
        "actuator": get_part("actuator", scenario.actuators.kind),
    }


def simulate(
    scenario: Scenario | str,
    controller: str = "afsmc",
    *,
    duration: float | None = None,
    seed: int | None = None,
) -> Result:
    """Run one closed-loop experiment; ``duration`` and ``seed`` override the scenario's.

    ``controller`` is any registered controller ("smc", "fsmc", "afsmc", "pd", "ctc",
    or a user's, :func:`pkmctl.register_controller`). Raises
    :class:`~pkmctl.SimulationDiverged` (with the partial result) if the state becomes
    non-finite or the pose leaves the valid set.
    """
    prep = _prepare(scenario, duration)
    return _run(prep, _parts(prep.scenario, controller), seed)


def _build(parts: dict[str, Part], ctx: PartContext, plant_state: np.ndarray) -> dict:
    bundles = {}
    for kind, part in parts.items():
        try:
            bundles[kind] = part.make(ctx)
        except PartError:
            raise
        except Exception as exc:  # a user's build: name the part
            raise PartError(f"{kind} {part.name!r}: build failed: {exc}") from exc
    p, x0, w = bundles["plant"]
    if x0.shape[0] < 6:
        raise PartError(f"plant {parts['plant'].name!r}: state_size must be >= 6 ([X, Xdot, ...])")
    x0[:6] = plant_state
    return bundles


def _run(
    prep: _Prepared,
    parts: dict[str, Part],
    seed: int | None,
    buffers: LogBuffers | None = None,
) -> Result:
    scenario = prep.scenario if seed is None else _with_seed(prep.scenario, seed)
    Tc = scenario.timing.control_period
    ctx = PartContext(
        plant=prep.plant,
        model=prep.model,
        gains=scenario.controller_gains(),
        period=Tc,
        flc=prep.flc,
        scenario=scenario,
    )
    x0 = np.concatenate([scenario.initial.X, scenario.initial.Xdot]).astype(float)
    bundles = _build(parts, ctx, x0)
    n = prep.t.size
    if buffers is None:  # the prepared arrays exist already: only the logs are new
        n_log = int(parts["controller"].log_size(bundles["controller"][0]))
        check_memory(8 * n * (_LOG_COLUMNS + n_log), f"the logs of a {n * Tc:g} s run")
    dvals, didx = _disturbance(scenario, n, Tc)
    stepped = parts["plant"].stepper is not None
    out = (run_stepped if stepped else run_parts)(
        parts,
        bundles,
        *((ctx,) if stepped else ()),
        period=Tc,
        substeps=scenario.timing.substeps,
        reference=prep.reference,
        dist_values=dvals,
        dist_index=didx,
        buffers=buffers,
    )
    m, lg = out.steps, out.logs
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
            info.update(part.report(bundles[kind][0], out.final_state[kind]))
    ref = prep.reference
    result = Result(
        scenario=scenario,
        controller=ctrl.name,
        t=prep.t[:m],
        X=lg["X"],
        Xdot=lg["Xdot"],
        X_desired=ref[:m, 0:3],
        Xdot_desired=ref[:m, 3:6],
        q=lg["q"],
        q_desired=prep.q_des[:m],
        F=lg["F"],
        tau=lg["tau"],
        tau_desired=prep.tau_des[:m],
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


def simulate_many(
    scenario: Scenario | str,
    controller: str = "afsmc",
    *,
    seeds,
    duration: float | None = None,
    workers: int | None = None,
    keep: str = "results",
) -> list:
    """Run one scenario for several disturbance seeds in parallel threads.

    The scenario, its desired trajectory and desired forces are prepared once; the
    compiled loop releases the GIL, so ``workers`` threads (default: the number of
    cores) run side by side in one process. Results come back in the order of
    ``seeds``; the first failing run's error is raised.

    ``keep="results"`` returns the :class:`Result` of every run. ``keep="metrics"``
    returns ``{"seed": s, **metrics.summary(result)}`` per run instead, and each
    worker logs every run into the same buffers: a campaign of many seeds then never
    touches fresh memory after its first runs (first-touch page faults of ~45 MB per
    10 s run are what limits thread scaling otherwise; see docs/performance.md).
    """
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from pkmctl.sim.metrics import summary

    if keep not in ("results", "metrics"):
        raise ValueError(f"keep = {keep!r}: must be 'results' or 'metrics'")
    seeds = list(seeds)
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers = {workers}: must be >= 1")
    prep = _prepare(scenario, duration)
    parts = _parts(prep.scenario, controller)
    for s in seeds:
        _with_seed(prep.scenario, s)  # fail fast on a bad seed, before any run
    local = threading.local()
    n_log = 0
    if keep == "metrics":
        ctx = PartContext(prep.plant, prep.model, prep.scenario.controller_gains(),
                          prep.scenario.timing.control_period, prep.flc, prep.scenario)  # fmt: skip
        n_log = int(parts["controller"].log_size(parts["controller"].build(ctx)))

    def one(seed):
        if keep == "results":
            return _run(prep, parts, seed)
        if not hasattr(local, "buffers"):
            local.buffers = LogBuffers(prep.t.size, n_log)
        result = _run(prep, parts, seed, local.buffers)
        return {"seed": int(seed), **summary(result)}

    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(one, seeds))


def _die_with_parent() -> None:
    """A compiling worker ends when the process that started it does (Ctrl-C, a kill)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL(None).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG (Linux)
    except (OSError, AttributeError):
        pass


def _compile_group(scenario_toml: str, controllers: list[str]) -> str:
    """In a worker process: run each controller for one period, which compiles its loop
    into the disk cache. Returns "" or the first error (the caller will meet it again)."""
    try:
        sc = Scenario.from_toml(scenario_toml)
        sc = sc.replace(**{"timing.duration": sc.timing.control_period})
        for c in controllers:
            simulate(sc, controller=c)
    except Exception as exc:  # noqa: BLE001 - reported by the run that follows
        return f"{type(exc).__name__}: {exc}"
    return ""


def _groups(todo: list[str], fuzzy: set[str], n: int) -> list[list[str]]:
    """Deal ``todo`` over ``n`` >= 2 workers. Controllers that share the fuzzy kernels go
    to one worker (those kernels are the costliest to compile, once per process); the
    others are dealt out over the rest."""
    others = [c for c in todo if c not in fuzzy]
    if fuzzy and others:
        rest = [others[i :: n - 1] for i in range(n - 1)]
        return [[c for c in todo if c in fuzzy], *(g for g in rest if g)]
    return [g for g in (todo[i::n] for i in range(n)) if g]


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
    several cores, worker processes build them side by side (each compiles the model
    kernels it needs too, on its own core). Loops already compiled on this machine, and
    combinations with parts registered outside pkmctl (a worker would not import them),
    are skipped; so is everything when fewer than two workers would run. Calls
    ``on_start(controllers, workers)`` before it starts; returns the controllers whose
    loops were compiled.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    todo, fuzzy = [], set()
    for c in controllers:
        parts = _parts(scenario, c)
        if all(p.builtin for p in parts.values()) and not is_compiled(parts):
            todo.append(c)
            if "flc" in parts["controller"].params._fields:
                fuzzy.add(c)
    n = min(len(todo), os.cpu_count() or 1, workers or len(todo))
    if n < 2:
        return []
    groups = _groups(todo, fuzzy, n)
    n = len(groups)
    if on_start is not None:
        on_start(todo, n)
    text = scenario.to_toml()
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(n, mp_context=spawn, initializer=_die_with_parent) as pool:
        list(pool.map(_compile_group, [text] * n, groups))
    return todo
