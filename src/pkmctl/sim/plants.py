"""Plants: what the loop integrates (DESIGN.md §6). Built in: ``rigid``, the closed form of §2,
with the options of §7 (reflected rotor inertia, joint friction, a payload), and
``mujoco``, the same machine stepped in MuJoCo (§10, :mod:`pkmctl.sim.stepped`).

A plant's state starts with [X (3), Xdot (3)] (the task-space pose and its rate);
the sensor reads it there. See :mod:`pkmctl.parts` for the contract.

With every option off (the default) the plant runs exactly the arithmetic of the rigid
model: the options' terms sit behind one test of ``machine`` and add nothing, so the
paper's numbers do not change in a single bit (tests/test_machine.py pins them).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pkmctl._jit import kernel
from pkmctl.model.dynamics import (
    JDV,
    JQ,
    Q,
    actuator_forces_kernel,
    dynamics_kernel,
    forward_dynamics,
    inverse_dynamics,
    make_work,
    task_force,
)
from pkmctl.model.machine import add_payload, add_rotor_inertia, friction_law, reflected_inertia
from pkmctl.parts import PartContext, PartError, builtin_part

__all__ = ["MujocoPlant", "RigidPlant", "machine_dynamics", "rigid_plant"]


def _rigid_work(p) -> tuple:
    """(the dynamics workspace, M (3, 3), C Xdot, G, f (3,), R (3, 3) the payload's scratch)."""
    e = np.empty
    return make_work(), e((3, 3)), e(3), e(3), e(3), e((3, 3))


class RigidPlant(NamedTuple):
    """The rigid machine: geometry (11,) and Theta (36,) of the true plant, and the options of
    DESIGN.md §7: reflected rotor inertia m_r (4,) kg, friction F_c (4,) N, F_v (4,) N s/m
    and its smoothing velocity v_s (m/s), a payload (kg) at payload_offset (3,) m in the
    platform frame. ``machine`` is 1.0 when any option is on, else 0.0 (the rigid model)."""

    geom: np.ndarray
    theta: np.ndarray
    m_r: np.ndarray
    f_c: np.ndarray
    f_v: np.ndarray
    v_s: float
    payload: float
    payload_offset: np.ndarray
    machine: float

    @classmethod
    def from_context(cls, ctx: PartContext) -> RigidPlant:
        sc = ctx.scenario
        if sc is None:
            return rigid_plant(ctx.plant)
        ps, pl = sc.plant_spec, sc.payload
        return rigid_plant(
            ctx.plant,
            rotor_inertia=ps.rotor_inertia,
            screw_lead=ps.screw_lead,
            friction_coulomb=ps.friction_coulomb,
            friction_viscous=ps.friction_viscous,
            friction_velocity=ps.friction_velocity,
            payload_mass=pl.mass,
            payload_offset=pl.offset,
        )


def rigid_plant(
    mechanism,
    *,
    rotor_inertia: float = 0.0,
    screw_lead: float = 0.01,
    friction_coulomb: float = 0.0,
    friction_viscous: float = 0.0,
    friction_velocity: float = 1e-3,
    payload_mass: float = 0.0,
    payload_offset=(0.0, 0.0, 0.0),
) -> RigidPlant:
    """The bundle of the ``rigid`` plant for a :class:`~pkmctl.Mechanism` and the options of
    DESIGN.md §7 (units: kg m^2, m, N, N s/m, m/s, kg, m); all off by default."""
    m_r = reflected_inertia(float(rotor_inertia), float(screw_lead))
    on = rotor_inertia > 0 or friction_coulomb > 0 or friction_viscous > 0 or payload_mass > 0
    full = np.full
    return RigidPlant(
        mechanism.geometry,
        mechanism.theta,
        full(4, m_r),
        full(4, float(friction_coulomb)),
        full(4, float(friction_viscous)),
        float(friction_velocity),
        float(payload_mass),
        np.array(payload_offset, dtype=float),
        1.0 if on else 0.0,
    )


@kernel(inline="always", refcount=False)
def _machine_terms(p, X, Xd, v, work, M, Cv, G, f):
    """Add the options' terms: rotor inertia and payload to M, C v, G; friction to f. J and
    Jdot v at (X, Xd, v) are what dynamics_kernel has just left in the workspace."""
    Jq, Jdv = work[0][JQ], work[0][JDV]
    add_rotor_inertia(p.m_r, Jq, Jdv, M, Cv)
    if p.payload > 0.0:
        add_payload(p.geom, p.payload, p.payload_offset, X, Xd, v, work[5], M, Cv, G)
    for i in range(4):
        qd = Jq[i, 0] * Xd[0] + Jq[i, 1] * Xd[1] + Jq[i, 2] * Xd[2]
        fr = friction_law(p.f_c[i], p.f_v[i], p.v_s, qd)
        for a in range(3):
            f[a] -= Jq[i, a] * fr


@kernel(refcount=False)
def rigid_derivative(p, x, tau, dist, work, dx):
    """dx = [Xdot, M^-1 (J^T tau + tau_d' - C Xdot - G)] (eq. 24), with the §7 terms if on."""
    w, M, C, G, f = work[0], work[1], work[2], work[3], work[4]
    X, Xd = x[0:3], x[3:6]
    dynamics_kernel(p.geom, p.theta, X, Xd, Xd, w, M, C, G)  # C holds C Xdot
    Jq = w[JQ]
    for i in range(3):
        f[i] = Jq[0, i] * tau[0] + Jq[1, i] * tau[1] + Jq[2, i] * tau[2] + Jq[3, i] * tau[3]
        f[i] += dist[i]
        dx[i] = Xd[i]
    if p.machine > 0.0:
        _machine_terms(p, X, Xd, Xd, work, M, C, G, f)
    forward_dynamics(M, C, G, f, dx[3:6])


@kernel(refcount=False)
def rigid_observe(p, x, tau, work, q, F):
    """q and J^T tau from the kinematics the last derivative left in ``work``."""
    w = work[0]
    for i in range(4):
        q[i] = w[Q][i]
    task_force(w[JQ], tau, F)


@kernel
def _machine_dynamics(p, X, Xd, v):
    work = _rigid_work_jit()
    M, Cv, G, f = work[1], work[2], work[3], work[4]
    dynamics_kernel(p.geom, p.theta, X, Xd, v, work[0], M, Cv, G)
    f[:] = 0.0
    if p.machine > 0.0:
        _machine_terms(p, X, Xd, v, work, M, Cv, G, f)
    return M.copy(), Cv.copy(), G.copy(), -f


@kernel
def _rigid_work_jit():
    e = np.empty
    return make_work(), e((3, 3)), e(3), e(3), e(3), e((3, 3))


@kernel
def desired_machine_forces(p, Xd, Xdd, Xddd, q_out, tau_out):
    """q_d (N, 4) and the minimum-norm limb forces tau_d (N, 4) that drive the plant ``p``,
    every option of §7 included, along X_d (N, 3) with its rates: J^T tau_d = M Xddot_d +
    C Xdot_d + G - f, f = -J^T (F_c tanh(qdot_d / v_s) + F_v qdot_d) as the plant's
    derivative adds it (its inverse, by the same code: tests/test_machine.py)."""
    work = _rigid_work_jit()
    M, Cv, G, f = work[1], work[2], work[3], work[4]
    F = np.empty(3)
    for k in range(Xd.shape[0]):
        dynamics_kernel(p.geom, p.theta, Xd[k], Xdd[k], Xdd[k], work[0], M, Cv, G)
        f[:] = 0.0
        if p.machine > 0.0:
            _machine_terms(p, Xd[k], Xdd[k], Xdd[k], work, M, Cv, G, f)
        inverse_dynamics(M, Cv, G, Xddd[k], F)
        for i in range(3):
            F[i] -= f[i]
        actuator_forces_kernel(work[0][JQ], F, tau_out[k])
        q_out[k, :] = work[0][Q]


def machine_dynamics(p: RigidPlant, X, Xdot, v) -> tuple[np.ndarray, ...]:
    """The plant's own M (3, 3), C(X, Xdot) v (3,), G (3,) and the friction force J^T f (3,)
    at one state, with every option of ``p`` (the same code as the plant's derivative)."""
    a = [np.ascontiguousarray(z, dtype=float) for z in (X, Xdot, v)]
    return _machine_dynamics(p, *a)


builtin_part(
    "plant",
    "rigid",
    {"derivative": rigid_derivative, "observe": rigid_observe},
    params=RigidPlant,
    build=None,
    state_size=6,
    work=_rigid_work,
    description="the closed-form rigid machine (docs/model.md; options: docs/machine.md)",
)


class MujocoPlant(NamedTuple):
    """The machine stepped in MuJoCo (DESIGN.md §10); geometry (11,) and Theta (36,) of the
    true plant, for ``observe``'s log of J(X)^T tau (the MuJoCo model is built from the
    same Mechanism, :mod:`pkmctl.plants.mujoco`)."""

    geom: np.ndarray
    theta: np.ndarray

    @classmethod
    def from_context(cls, ctx: PartContext) -> MujocoPlant:
        # MuJoCo is checked here, where every run's parts are built before its loop
        # compiles: without it, `reproduce` compiled five loops for minutes, then refused
        _need_mujoco()
        return cls(ctx.plant.geometry, ctx.plant.theta)


def _need_mujoco() -> None:
    """One line with the install command when MuJoCo cannot be imported."""
    try:
        import pkmctl.plants.mujoco  # noqa: F401
    except ImportError as exc:
        raise PartError(f"plant 'mujoco': {exc}") from None


@kernel(refcount=False)
def mujoco_observe(p, x, tau, work, q, F):
    """q and J^T tau at X from the closed-form kinematics (the loop overwrites q with the
    lengths MuJoCo's slides give: 2e-15 m apart when assembled, up to 44 nm in a run (the
    paper's first ms, 5.5 kN a limb; docs/machine.md), as MuJoCo's equality constraints are
    soft; a sensor reads the pose's)."""
    w, M, C, G = work[0], work[1], work[2], work[3]  # the rigid plant's work tuple
    dynamics_kernel(p.geom, p.theta, x[0:3], x[3:6], x[3:6], w, M, C, G)
    for i in range(4):
        q[i] = w[Q][i]
    task_force(w[JQ], tau, F)


def _mujoco_stepper(p: MujocoPlant, ctx: PartContext, h: float):
    """A :class:`pkmctl.plants.mujoco.MujocoMachine` of the true plant at RK4 step h (s), with
    the scenario's [plant] options and payload (DESIGN.md §7, §10)."""
    _need_mujoco()
    from pkmctl.plants.mujoco import MujocoMachine, scenario_error, scenario_options

    options = {} if ctx.scenario is None else scenario_options(ctx.scenario)
    try:
        return MujocoMachine(ctx.plant, timestep=h, **options)
    except ValueError as exc:  # the option MuJoCo cannot model, named as the scenario's field
        raise PartError(f"plant 'mujoco': {scenario_error(str(exc))}") from None


builtin_part(
    "plant",
    "mujoco",
    {"observe": mujoco_observe},
    params=MujocoPlant,
    build=None,
    state_size=6,
    work=_rigid_work,
    stepper=_mujoco_stepper,
    description="the same machine in MuJoCo, RK4 at the loop's sub-step (docs/machine.md)",
)
