"""A log of a perfectly tracked trajectory: the data an identification is tested on.

The machine of a scenario moves exactly along a trajectory; its limb forces are the
inverse dynamics computed without the regressor: M Xddot + C Xdot + G of the closed
form (:meth:`Mechanism.inverse_dynamics`), the rotors' J^T diag(m_r) qddot (qddot = J
Xddot + Jdot Xdot, exactly: :func:`limb_accelerations`) and the friction J^T f(J Xdot)
of DESIGN.md §7, split over the limbs at minimum norm, plus an optional internal force in
the null space of J^T (which must change nothing). Measurement effects are optional and seeded:
encoder quantisation (screw lead / counts per rev), Gaussian noise on q (m) and on tau (N).
This is the Monte Carlo set-up of the BIRDy benchmark: one trajectory, many noise draws.
"""

from __future__ import annotations

import numpy as np

from pkmctl._jit import kernel
from pkmctl.ident.identify import Log
from pkmctl.model.kinematics import limb_jacobian_rate
from pkmctl.model.machine import reflected_inertia
from pkmctl.sim.scenario import Scenario

__all__ = ["limb_accelerations", "synthetic_log"]


@kernel
def _limb_accelerations(geom, X, Xd, Xdd, qdd):
    R, Jq, q, Jdv = np.empty((3, 3)), np.empty((4, 3)), np.empty(4), np.empty(4)
    for k in range(X.shape[0]):
        limb_jacobian_rate(geom, X[k], Xd[k], Xd[k], R, Jq, q, Jdv)
        for i in range(4):
            qdd[k, i] = Jq[i, 0] * Xdd[k, 0] + Jq[i, 1] * Xdd[k, 1] + Jq[i, 2] * Xdd[k, 2] + Jdv[i]


def limb_accelerations(geometry: np.ndarray, X, Xd, Xdd) -> np.ndarray:
    """Limb accelerations qddot = J Xddot + Jdot Xdot (N, 4) along poses X, velocities Xd
    and accelerations Xdd (N, 3), exactly. (Five-point central differences of the limb
    lengths, used before, carried ~2e-9 m/s^2 of rounding and truncation; through the
    rotors' 10.9 kg that was most of the error of a noise-free identification.)"""
    X, Xd, Xdd = (np.ascontiguousarray(a, dtype=float) for a in (X, Xd, Xdd))
    qdd = np.empty((X.shape[0], 4))
    _limb_accelerations(np.ascontiguousarray(geometry, dtype=float), X, Xd, Xdd, qdd)
    return qdd


def synthetic_log(
    scenario: Scenario,
    *,
    rate: float = 1000.0,
    duration: float | None = None,
    quantise: bool = False,
    q_noise: float = 0.0,
    tau_noise: float = 0.0,
    internal: float = 0.0,
    seed: int = 0,
) -> Log:
    """t, q, tau sampled at ``rate`` (Hz) along ``scenario``'s trajectory on its machine
    (the plant and its §7 options, no payload), over ``duration`` (s; the scenario's)."""
    T = scenario.timing.duration if duration is None else duration
    t = np.arange(0.0, T + 0.5 / rate, 1.0 / rate)
    traj = scenario.trajectory.build()
    X, Xd, Xdd = traj.evaluate(t)
    mech = scenario.plant()
    ps = scenario.plant_spec
    F = mech.inverse_dynamics(X, Xd, Xdd)
    J = mech.jacobian(X)
    q = mech.inverse_kinematics(X)
    qdd = limb_accelerations(mech.geometry, X, Xd, Xdd)
    qd = np.einsum("nij,nj->ni", J, Xd)
    m_r = reflected_inertia(ps.rotor_inertia, ps.screw_lead)
    f = m_r * qdd + ps.friction_coulomb * np.tanh(qd / ps.friction_velocity)
    f = f + ps.friction_viscous * qd
    F = F + np.einsum("nij,ni->nj", J, f)
    JtJ = np.einsum("nji,njk->nik", J, J)
    tau = np.einsum("nij,nj->ni", J, np.linalg.solve(JtJ, F[..., None])[..., 0])
    rng = np.random.default_rng(seed)
    if internal:
        # a force in the null space of J^T: (I - J (J^T J)^-1 J^T) z
        z = rng.normal(0.0, internal, tau.shape)
        proj = np.einsum(
            "nij,nj->ni", J, np.linalg.solve(JtJ, np.einsum("nji,nj->ni", J, z)[..., None])[..., 0]
        )
        tau = tau + z - proj
    if q_noise:
        q = q + rng.normal(0.0, q_noise, q.shape)
    if quantise:
        res = ps.screw_lead / scenario.sensor.counts_per_rev
        q = res * np.round(q / res)
    if tau_noise:
        tau = tau + rng.normal(0.0, tau_noise, tau.shape)
    return Log(t, q, tau, f"synthetic ({scenario.name}, seed {seed})", ("t", "q", "tau"))
