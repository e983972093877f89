"""A log of a perfectly tracked trajectory: the data an identification is tested on.

The machine of a scenario moves exactly along a trajectory; its limb forces are the
inverse dynamics computed without the regressor: M Xddot + C Xdot + G of the closed
form (:meth:`Mechanism.inverse_dynamics`), the rotors' J^T diag(m_r) qddot (qddot by
five-point central differences of the exact limb lengths) and the friction J^T f(J Xdot)
of DESIGN.md §7, split over the limbs at minimum norm, plus an optional internal force in
the null space of J^T (which must change nothing). Measurement effects are optional and seeded:
encoder quantisation (screw lead / counts per rev), Gaussian noise on q (m) and on tau (N).
This is the Monte Carlo set-up of the BIRDy benchmark: one trajectory, many noise draws.
"""

from __future__ import annotations

import numpy as np

from pkmctl.ident.identify import Log
from pkmctl.model.machine import reflected_inertia
from pkmctl.sim.scenario import Scenario

__all__ = ["synthetic_log"]


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
    d = 1e-3  # s: qddot by a five-point central difference of the exact lengths (~1e-10)
    qs = [mech.inverse_kinematics(traj.evaluate(t + k * d)[0]) for k in (-2, -1, 0, 1, 2)]
    q = qs[2]
    qdd = (-qs[0] + 16.0 * qs[1] - 30.0 * q + 16.0 * qs[3] - qs[4]) / (12.0 * d * d)
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
