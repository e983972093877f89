"""An exciting trajectory for identification (DESIGN.md §9, Swevers et al. 1997).

A finite Fourier series per coordinate (:class:`pkmctl.sim.trajectory.Fourier`), whose
coefficients minimise the condition number of the base observation matrix W_b stacked
over one period, subject to, at every sample of the period: the workspace (|alpha|,
|beta| <= 0.5 rad, z in :data:`Z_RANGE`), cond(J) <= :data:`MAX_COND_J`, the limb
speeds and forces of the scenario's drives with a margin (the controller needs room
to correct). The start and end are at rest at the scenario's initial pose: per
coordinate sum_l a_l = 0 (Xdot(0) = 0), sum_l l b_l = 0 (Xddot(0) = 0) and
sum_l b_l / l = 0 (X(0) = offset), imposed exactly by optimising in their null space.
Forces are predicted with the scenario's true machine (the designer's nominal model:
for the prototype, the catalogue values of DESIGN.md §7) and its payload.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from pkmctl.ident.base import BaseParameters, base_parameters
from pkmctl.model.machine import reflected_inertia
from pkmctl.model.mechanism import extended_regressor_batch, limbs_batch
from pkmctl.sim.scenario import Scenario
from pkmctl.sim.trajectory import Fourier

__all__ = ["MAX_COND_J", "Z_RANGE", "Excitation", "design_excitation", "observation_condition"]

#: The z range of the exciting trajectory (m).
Z_RANGE = (0.62, 0.78)
#: Largest |alpha|, |beta| (rad).
MAX_ANGLE = 0.5
#: Largest condition number of J along the trajectory.
MAX_COND_J = 50.0
#: Fractions of the drives' peak force and maximum limb speed the design may use.
FORCE_MARGIN, SPEED_MARGIN = 0.5, 0.8
#: A design whose cond(W_b) exceeds this does not excite every base parameter.
MAX_COND_DESIGN = 1e8
_LIMITS = (
    "|alpha|, |beta| <= 0.5 rad",
    "z >= 0.62 m",
    "z <= 0.78 m",
    "cond(J) <= 50",
    "limb speeds <= 80 % of the drives'",
    "limb forces <= 50 % of the drives'",
)


@dataclass(frozen=True, eq=False)
class Excitation:
    """A designed trajectory and what it reaches (units: s, m, rad, N, m/s)."""

    trajectory: Fourier
    duration: float
    cond: float  # of W_b over the duration, the designed trajectory
    cond_paper: float  # of W_b over the same duration, eq. 54
    peak_force: float  # largest predicted |tau_i| (N), against force_limit
    force_limit: float
    peak_speed: float  # largest |qdot_i| (m/s), against speed_limit
    speed_limit: float
    max_cond_j: float
    z_range: tuple[float, float]
    max_angle: float
    seconds: float
    base: BaseParameters

    def __repr__(self) -> str:
        # the dataclass's wrote each number as np.float64(...) and the whole trajectory
        tr = self.trajectory
        return (
            f"Excitation({len(tr.a[0])} harmonics of {tr.base_frequency:g} Hz, "
            f"{self.duration:g} s: cond(W_b) {self.cond:.4g} (eq. 54: {self.cond_paper:.4g}), "
            f"peak force {self.peak_force:.4g} of {self.force_limit:.4g} N, peak speed "
            f"{self.peak_speed:.3g} of {self.speed_limit:.3g} m/s)"
        )

    def scenario(self, base: Scenario) -> Scenario:
        """``base`` with this trajectory, its duration, at rest at X(0)."""
        tr = self.trajectory  # at rest at its offset at t = 0 (the design's constraints;
        # evaluated, the series gives it to rounding: -5e-17 rad read as an edit, a tester)
        return base.replace(
            name=f"{base.name}-excite",
            description=(
                f"{base.name} on an exciting Fourier trajectory (pkmctl excite): "
                f"{len(tr.a[0])} harmonics of {tr.base_frequency:g} Hz, "
                f"cond(W_b) {self.cond:.3g} (eq. 54: {self.cond_paper:.3g})."
            ),
            trajectory={
                "kind": "fourier",
                "base_frequency": tr.base_frequency,
                "offset": list(tr.offset),
                "a": [list(r) for r in tr.a],
                "b": [list(r) for r in tr.b],
            },
            **{
                "timing.duration": self.duration,
                "initial.X": [float(v) for v in tr.offset],
                "initial.Xdot": [0.0, 0.0, 0.0],
            },
        )


def _machine(sc: Scenario) -> tuple[np.ndarray, float]:
    """The scenario's true Θ_ext (48,) and v_s."""
    ps = sc.plant_spec
    m_r = reflected_inertia(ps.rotor_inertia, ps.screw_lead)
    th = np.concatenate(
        [
            sc.plant().theta,
            np.full(4, m_r),
            np.full(4, ps.friction_coulomb),
            np.full(4, ps.friction_viscous),
        ]
    )
    return th, ps.friction_velocity


def _limits(sc: Scenario) -> tuple[float, float]:
    """Force (N) and speed (m/s) limits of the scenario's actuators."""
    a, lead = sc.actuators, sc.plant_spec.screw_lead
    if a.kind == "drive":
        force = 2 * math.pi * a.efficiency * a.peak_torque / lead
        speed = a.max_speed / 60.0 * lead
    else:
        force = a.force_limit if a.force_limit is not None else 2160.0
        speed = 5000.0 / 60.0 * lead
    return force, speed


def assumed_limits(sc: Scenario) -> str | None:
    """What :func:`_limits` assumed for actuators that state no limit (None if none):
    the prototype drive's (the paper's ideal actuators have none; excite showed them as
    the scenario's, a tester)."""
    a = sc.actuators
    if a.kind == "drive":
        return None
    force, speed = _limits(sc)
    parts = []
    if a.force_limit is None:
        parts.append(f"force {force:g} N")
    parts.append(f"speed {speed:.3g} m/s")
    return (
        f"the scenario's {a.kind!r} actuators state no "
        + ("force or speed limit" if a.force_limit is None else "speed limit")
        + f": the design kept to the prototype drive's ({', '.join(parts)}, before the "
        "margins)"
    )


def observation_condition(sc: Scenario, base: BaseParameters, X, Xd, Xdd) -> float:
    """cond(W_b) of the stacked base regressor along samples X, Xd, Xdd (N, 3)."""
    vs = sc.plant_spec.friction_velocity
    W = sc.plant().extended_regressor(X, Xd, Xd, Xdd, vs)
    return float(np.linalg.cond(base.reduce(W).reshape(-1, base.count)))


def _null(A: np.ndarray) -> np.ndarray:
    return scipy.linalg.null_space(A)


def _cond(A: np.ndarray) -> float:
    """2-norm condition number of A (m, n), m >= n, from the eigenvalues of A^T A (fast;
    exact enough below 1e7)."""
    ev = np.linalg.eigvalsh(A.T @ A)
    return math.sqrt(ev[-1] / ev[0]) if ev[0] > 0 else math.inf


def _split(J: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Minimum-norm limb forces J (J^T J)^-1 F, (N, 4) for J (N, 4, 3), F (N, 3)."""
    JtJ = np.einsum("nji,njk->nik", J, J)
    return np.einsum("nij,nj->ni", J, np.linalg.solve(JtJ, F[..., None])[..., 0])


def design_software() -> str:
    """What the design's path depends on besides its inputs: pkmctl's, SciPy's and the
    BLAS libraries' versions and threads, e.g. "pkmctl 0.2.0, SciPy 1.17.1, BLAS
    openblas 0.3.31 SkylakeX 2 threads". SciPy's SLSQP takes another path when OpenBLAS
    starts with one thread (``OPENBLAS_NUM_THREADS=1``, ``OMP_NUM_THREADS=1``, one CPU):
    the last bits of its steps differ and the restarts end elsewhere (cond 4,621 against
    5,017 by default, a tester), even on an objective that calls no BLAS."""
    import scipy
    from threadpoolctl import threadpool_info

    import pkmctl

    blas = sorted(
        {
            f"{i.get('internal_api')} {i.get('version')} {i.get('architecture', '')} "
            f"{i.get('num_threads')} thread{'s' if i.get('num_threads') != 1 else ''}"
            for i in threadpool_info()
            if i.get("user_api") == "blas"
        }
    )
    return f"pkmctl {pkmctl.__version__}, SciPy {scipy.__version__}, BLAS " + (
        "; ".join(" ".join(b.split()) for b in blas) or "unknown"
    )


def _ceil_g(x: float) -> float:
    from pkmctl.ident.identify import ceil_g

    return ceil_g(x)


def design_excitation(
    scenario: Scenario,
    *,
    harmonics: int = 5,
    base_frequency: float = 0.2,
    periods: int = 2,
    samples: int = 200,
    restarts: int = 4,
    seed: int = 0,
    max_iter: int = 200,
    progress: Callable[[int, int], None] | None = None,
) -> Excitation:
    """Design an exciting trajectory for ``scenario``'s machine (see the module);
    ``progress(starts done, restarts)`` is called as each random start ends."""
    t0 = time.perf_counter()
    # each argument checked, as the command's options are (restarts = 0 raised a TypeError,
    # samples = 0 numpy's zero-size reduction, base_frequency = 0 a ZeroDivisionError, and
    # periods = 0 "designed" a run of 0 s: a code reader)
    why = {
        "harmonics": " (rest at both ends takes 3 conditions)",
        "samples": " (points a period, 4 x harmonics: the top harmonic's peaks seen)",
    }
    for name, value, lo in (("harmonics", harmonics, 3), ("periods", periods, 1),
                            ("samples", samples, None), ("restarts", restarts, 1),
                            ("seed", seed, 0), ("max_iter", max_iter, 1)):  # fmt: skip
        lo = 4 * int(harmonics) if lo is None else lo  # (harmonics checked first)
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < lo:
            raise ValueError(f"{name} = {value!r}: must be an integer >= {lo}{why.get(name, '')}")
    H = int(harmonics)
    try:
        f = float(base_frequency)
    except (TypeError, ValueError):
        f = math.nan
    if not 0.0 < f <= 10.0:  # NaN too; the command's range
        raise ValueError(f"base_frequency = {base_frequency!r}: must be in (0, 10] Hz")
    if periods / f > 3600.0:
        raise ValueError(
            f"base_frequency = {f:g}: a run of periods = {periods} would last "
            f"{periods / f:.4g} s, over timing.duration's 3600 s: must be >= "
            f"{_ceil_g(periods / 3600.0):g} Hz"  # (rounded up: ">= 0.001944" refused it)
        )
    plant = scenario.plant()
    theta_ext, vs = _machine(scenario)
    base = base_parameters(plant, vs)
    f_lim, v_lim = _limits(scenario)
    X0 = np.asarray(scenario.initial.X, dtype=float)
    ls = np.arange(1, H + 1, dtype=float)
    Na = _null(np.ones((1, H)))  # sum a = 0
    Nb = _null(np.vstack([ls, 1.0 / ls]))  # sum l b = 0, sum b / l = 0
    na, nb = Na.shape[1], Nb.shape[1]
    t = np.linspace(0.0, 1.0 / f, samples, endpoint=False)
    w = 2 * math.pi * f

    def unpack(x: np.ndarray) -> Fourier:
        x = x.reshape(3, na + nb)
        a = x[:, :na] @ Na.T
        b = x[:, na:] @ Nb.T
        return Fourier(f, tuple(X0), tuple(map(tuple, a)), tuple(map(tuple, b)))

    geom = plant.geometry

    def kinematics(x):
        tr = unpack(x)
        X, Xd, Xdd = tr.evaluate(t)
        _, J = limbs_batch(geom, X)  # no checks: the constraints keep X valid
        W = extended_regressor_batch(geom, X, Xd, Xd, Xdd, vs)
        return X, Xd, Xdd, J, W

    def constraints(x) -> np.ndarray:
        X, Xd, Xdd, J, W = kinematics(x)
        sv = np.linalg.svd(J, compute_uv=False)
        qd = np.einsum("nij,nj->ni", J, Xd)
        tau = _split(J, W @ theta_ext + scenario.payload_forces(X, Xd, Xdd))
        return np.array(
            [
                (MAX_ANGLE - np.abs(X[:, 1:]).max()) / MAX_ANGLE,
                (X[:, 0].min() - Z_RANGE[0]) / 0.1,
                (Z_RANGE[1] - X[:, 0].max()) / 0.1,
                (MAX_COND_J - (sv[:, 0] / sv[:, -1]).max()) / MAX_COND_J,
                (SPEED_MARGIN * v_lim - np.abs(qd).max()) / v_lim,
                (FORCE_MARGIN * f_lim - np.abs(tau).max()) / f_lim,
            ]
        )

    def objective(x) -> float:
        X, _, _, _, W = kinematics(x)
        if X[:, 0].min() <= 0 or np.abs(X[:, 1:]).max() >= 1.2:
            return 20.0
        return math.log10(_cond(base.reduce(W).reshape(-1, base.count)))

    # The trajectory starts and ends at rest at the initial pose: it must meet the limits.
    at_rest = constraints(np.zeros(3 * (na + nb)))
    if at_rest.min() < 0:
        broken = ", ".join(_LIMITS[k] for k in np.flatnonzero(at_rest < 0))
        raise ValueError(
            f"initial.X = {[round(float(v), 6) for v in X0]}: the exciting trajectory starts "
            f"and ends at rest there, but it breaks its limits ({broken}; z in "
            f"{Z_RANGE[0]}-{Z_RANGE[1]} m): set initial.X inside them"
        )

    def shrink_to_limits(x: np.ndarray) -> tuple[np.ndarray, bool]:
        """x shrunk by 0.2 % steps (X - X(0) is linear in the coefficients; speeds, forces
        and the workspace excursion shrink with it) until every limit holds on the grid
        ``t``, at most 200 steps; whether it got there."""
        for _ in range(200):
            if constraints(x).min() >= 0:
                return x, True
            x = 0.998 * x
        return x, constraints(x).min() >= 0

    rng = np.random.default_rng(seed)
    best = None
    scale = np.array([0.06, 0.4, 0.4]) * w  # m/s, rad/s: X near the limits
    for start in range(restarts):
        x0 = (rng.normal(size=(3, na + nb)) * scale[:, None] / math.sqrt(H)).ravel()
        for _shrink in range(30):  # start feasible
            if constraints(x0).min() >= 0:
                break
            x0 *= 0.85
        res = scipy.optimize.minimize(
            objective,
            x0,
            method="SLSQP",
            constraints=[{"type": "ineq", "fun": constraints}],
            options={"maxiter": max_iter, "ftol": 1e-4},
        )
        # SLSQP meets its constraints to ~1e-5, not exactly: an optimum over a limit by a
        # hair is shrunk onto it, not thrown away for the starting point (which made the
        # result depend on the last bits of the regressor: one restart in four happened to
        # land inside by 1e-11)
        x, ok = shrink_to_limits(res.x)
        if not ok:
            x = x0
        val = objective(x)
        if best is None or val < best[0]:
            best = (val, x)
        if progress is not None:
            progress(start + 1, restarts)
    # The design saw `samples` points a period; between them a limit may be crossed by a
    # hair: shrink the motion (X - X(0) is linear in the coefficients) until a grid twenty
    # times finer meets every limit.
    t_fine = t
    t = np.linspace(0.0, 1.0 / f, 20 * samples + 1)
    x, ok = shrink_to_limits(best[1])
    t = t_fine
    if not ok:
        broken = ", ".join(_LIMITS[k] for k in np.flatnonzero(constraints(x) < 0))
        raise ValueError(
            f"scenario {scenario.name!r}: no exciting trajectory meets the limits ({broken}); "
            "try another --seed or fewer --harmonics"
        )
    tr = unpack(x)
    duration = periods / f
    # What it reaches, checked on a grid four times finer than the design's.
    tt = np.linspace(0.0, duration, 4 * samples * periods + 1)
    X, Xd, Xdd = tr.evaluate(tt)
    J = plant.jacobian(X)
    W = plant.extended_regressor(X, Xd, Xd, Xdd, vs)
    tau = _split(J, W @ theta_ext + scenario.payload_forces(X, Xd, Xdd))
    qd = np.einsum("nij,nj->ni", J, Xd)
    cond = float(np.linalg.cond(base.reduce(W).reshape(-1, base.count)))
    Xp, Xdp, Xddp = scenario.builtin("paper").trajectory.build().evaluate(tt)
    cond_paper = observation_condition(scenario, base, Xp, Xdp, Xddp)
    if not cond <= MAX_COND_DESIGN:
        raise ValueError(
            f"scenario {scenario.name!r}: the best trajectory found inside the limits has "
            f"cond(W_b) = {cond:.3g} (eq. 54: {cond_paper:.3g}), above {MAX_COND_DESIGN:g}: it "
            "does not excite every base parameter; try another --seed, or move initial.X "
            "away from the limits"
        )
    return Excitation(
        trajectory=tr,
        duration=duration,
        cond=cond,
        cond_paper=cond_paper,
        peak_force=float(np.abs(tau).max()),
        force_limit=f_lim,
        peak_speed=float(np.abs(qd).max()),
        speed_limit=v_lim,
        max_cond_j=float(np.linalg.cond(J).max()),
        z_range=(float(X[:, 0].min()), float(X[:, 0].max())),
        max_angle=float(np.abs(X[:, 1:]).max()),
        seconds=time.perf_counter() - t0,
        base=base,
    )
