"""The 2RPU-2SPR manipulator as a MuJoCo model (DESIGN.md §10): an independent plant.

Needs MuJoCo (``pip install "mujoco>=3.1"``, or ``pip install ".[mujoco]"`` in a checkout of
pkmctl); ``import pkmctl`` does not.

:func:`build_mjcf` writes an MJCF model of a :class:`~pkmctl.Mechanism` from the
Mechanism's own data (radii, centre-of-mass distances, the 36 inertial parameters, g, home
pose) and the §7 options that MuJoCo models the same way (rotor inertia as ``armature``,
viscous friction as ``damping``); :func:`initial_qpos` and :func:`initial_qvel` put it in a
consistent state for a task pose X = [z, alpha, beta] and rate Xdot;
:func:`task_acceleration` solves its constrained dynamics exactly (no constraint softness);
:func:`agreement` compares it with the closed form; :class:`MujocoMachine` steps it as the
loop's ``mujoco`` plant (:mod:`pkmctl.sim.stepped`).

Model
-----
- Platform: a body with a free joint (6 dofs; none of the closed form's reduction to 3 is
  built in, the closures remove the other 3). Its frame is R, the centre of mass is at its
  origin p, the inertia diagonal in that frame; a payload (§7) is merged into its mass,
  centre of mass and (full) inertia.
- Limb bodies: each MuJoCo body frame is the limb frame R_i = [x_i, u_i x x_i, u_i] of
  DESIGN.md §1, so both limb inertias are ``diaginertia`` (no ``fullinertia`` needed) at
  ``(0, 0, l1)`` from the base joint (lower) and ``(0, 0, -l2)`` from the platform joint
  (upper).
- RPU limbs 1, 3: a chain from the base: a hinge about e_x at b_i, the lower body, a slide
  along u_i driven by a ``motor`` (gear 1, no ctrlrange), the upper body, closed to the
  platform by one ``connect`` at a_i. The universal joint's one rotational constraint (the
  platform's y axis perpendicular to e_x) is implied by the two RPU point closures (a_1 and
  a_3 both stay in the plane x = 0, so p_x = 0 and (R e_y)_x = 0), so a point closure gives
  the same mechanism without two redundant rows.
- SPR limbs 2, 4: the chain hangs from the platform: a hinge about the platform's y axis w
  at a_i, the upper body, the slide with its motor (axis -u_i, so positive force still
  extends the limb), the lower body, closed to the base by one ``connect`` at b_i. A
  spherical joint is exactly a point constraint, so every joint of the machine is exact,
  with the one-axis joints in the tree and every closure a point (DESIGN.md §10).
- Equality constraints: ``solimp`` at MuJoCo's stiffest impedance, d = 0.9999 (the
  regulariser is then 1e-4 of the diagonal constraint-space inverse inertia), ``solref``
  time constant 0.5 ms (10 steps; MuJoCo's floor is 2 steps), damping ratio 1. The time
  constant sets how fast the closures take up their load and so the trajectory error, about
  in proportion to its square: 1.2e-8, 2.9e-9, 7.3e-10, 1.2e-10 after 20 ms at 2, 1, 0.5,
  0.2 ms (10 states); at 0.1 ms (MuJoCo's floor) the acceleration error stayed near 3e-6
  instead of settling.
- Contacts off, RK4, timestep 5e-5 s, gravity -g along z with the Mechanism's g, dense
  constraint Jacobian. Geoms are visual only (no mass: every body has an explicit
  ``inertial``; no contacts), so the model can be looked at (``pkmctl mujoco-model``).

Why the SPR chains do not start at the base: the literal alternative (a ball at b_i, the
slide, the upper body, then a knuckle body carrying the platform revolute, ``weld`` ed to the
platform) was built and measured. MuJoCo rejects a massless knuckle, and with any knuckle
small enough not to change the dynamics the weld's rotational rows are regularised by the
knuckle's tiny inverse inertia: relative acceleration errors of 5.6e-2 (knuckle 0.1 kg,
1e-4 kg m^2) to 4.8e-1 (1e-3 kg, 1e-7 kg m^2) at d = 0.9999, saturating rather than
scaling with 1 - d. Carving 0.5 kg knuckles out of the platform's mass still gave 5.5e-2,
and heavier ones break the flat platform's inertia triangle inequality (I_xx + I_yy only
just exceeds I_zz). The platform-rooted SPR chain of this module has the same joints and
bodies and is 3 to 4 orders of magnitude closer.
"""

from __future__ import annotations

import math
import os

# headless rendering: EGL unless the user chose (MuJoCo reads this on import)
os.environ.setdefault("MUJOCO_GL", "egl")
try:
    import mujoco
except ImportError:  # one line, the fix in it
    raise ImportError(
        'pkmctl.plants.mujoco needs MuJoCo: pip install "mujoco>=3.1" (or, in a checkout of '
        'pkmctl, pip install ".[mujoco]")'
    ) from None
import numpy as np

from pkmctl.errors import InvalidPoseError
from pkmctl.model.kinematics import LIMB_ANGLES_DEG
from pkmctl.model.mechanism import Mechanism
from pkmctl.plants import MUJOCO_SOLREF, mujoco_max_timestep

#: The loop's status code (pkmctl.sim.loop.STATUS) for a stepper whose state blew up.
STEPPER_BLEW_UP = 4

__all__ = [
    "SCENARIO_FIELDS",
    "MujocoMachine",
    "agreement",
    "build_mjcf",
    "build_model",
    "initial_qpos",
    "initial_qvel",
    "limb_lengths",
    "render_poses",
    "platform_pose",
    "platform_rate",
    "platform_task_acceleration",
    "scenario_error",
    "scenario_options",
    "task_acceleration",
]

#: Zero-based indices of the RPU limbs (1, 3) and SPR limbs (2, 4), DESIGN.md §1.
RPU_LIMBS = (0, 2)
SPR_LIMBS = (1, 3)
#: RK4 step (s): the plant's sub-step of DESIGN.md §4.
TIMESTEP = 5e-5
#: Equality-constraint softness: (time constant s, damping ratio), and MuJoCo's stiffest
#: impedance (its mjMAXIMP = 0.9999) at every violation.
SOLREF = MUJOCO_SOLREF
SOLIMP = (0.9999, 0.9999, 1e-3, 0.5, 2.0)


# ---------------------------------------------------------------------- geometry (DESIGN §1)
def _platform_frame(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Platform centre p = [0, -z tan(alpha), z] and orientation R = R_x(alpha) R_y(beta)."""
    z, a, b = (float(v) for v in X)
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
    return np.array([0.0, -z * np.tan(a), z]), rx @ ry


def _limb_geometry(robot: Mechanism, X: np.ndarray) -> dict[str, np.ndarray]:
    """Joint points, limb lengths and limb frames of DESIGN.md §1 at pose X.

    Returns
    -------
    dict
        ``p`` (3,), ``R`` (3, 3), ``a`` (4, 3) platform points in A, ``b`` (4, 3) base
        points in B, ``q`` (4,) limb lengths, ``frames`` (4, 3, 3) limb frames
        R_i = [x_i, u_i x x_i, u_i] as columns.
    """
    th = np.deg2rad(np.asarray(LIMB_ANGLES_DEG, dtype=float))
    dirs = np.stack([np.cos(th), np.sin(th), np.zeros(4)], axis=1)
    dirs[np.abs(dirs) < 1e-15] = 0.0  # exact zeros, as the compiled kernels use
    a, b = robot.r_a * dirs, robot.r_b * dirs
    p, R = _platform_frame(X)
    d = p + a @ R.T - b
    q = np.linalg.norm(d, axis=1)
    u = d / q[:, None]
    frames = np.empty((4, 3, 3))
    for i in range(4):
        x = R[:, 1] if i in SPR_LIMBS else np.array([1.0, 0.0, 0.0])  # w = R_x(alpha) e_y
        frames[i] = np.column_stack([x, np.cross(u[i], x), u[i]])
    return {"p": p, "R": R, "a": a, "b": b, "q": q, "frames": frames}


# ---------------------------------------------------------------------- MJCF
def _f(*values: float) -> str:
    """Numbers in their shortest exact (round-trip) form, space separated; -0 printed as 0."""
    return " ".join(repr(float(v) + 0.0) for v in np.ravel(values))


def _quat(R: np.ndarray) -> str:
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R, dtype=float).ravel())
    return _f(*quat)


def _inertial(theta_b: np.ndarray, com_z: float) -> str:
    m, ixx, iyy, izz = theta_b
    return f'<inertial pos="0 0 {_f(com_z)}" mass="{_f(m)}" diaginertia="{_f(ixx, iyy, izz)}"/>'


def _platform_inertial(theta_0: np.ndarray, mass: float, offset: np.ndarray) -> str:
    """The platform's inertial element, with a point mass ``mass`` at ``offset`` (platform
    frame) merged in: the joint centre of mass c and the inertia about it (parallel axes)."""
    m0, ixx, iyy, izz = theta_0
    if mass == 0.0:
        return f'<inertial pos="0 0 0" mass="{_f(m0)}" diaginertia="{_f(ixx, iyy, izz)}"/>'
    total = m0 + mass
    c = mass * offset / total

    def point(m: float, r: np.ndarray) -> np.ndarray:  # a point mass's inertia about 0
        return m * (np.dot(r, r) * np.eye(3) - np.outer(r, r))

    inertia = np.diag([ixx, iyy, izz]) + point(m0, -c) + point(mass, offset - c)
    full = (inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2],
            inertia[1, 2])  # fmt: skip
    return f'<inertial pos="{_f(*c)}" mass="{_f(total)}" fullinertia="{_f(*full)}"/>'


def _rod(kind: str, length: float, radius: float) -> str:
    """A visual rod along the body's z axis from its origin (no mass, no contact)."""
    rgba = "0.75 0.45 0.2 1" if kind == "cylinder" else "0.6 0.6 0.65 1"
    return (
        f'<geom type="{kind}" fromto="0 0 0 0 0 {_f(length)}" size="{_f(radius)}" '
        f'rgba="{rgba}" {_VISUAL}/>'
    )


#: Geom attributes of a purely visual geom: no mass, no collision.
_VISUAL = 'mass="0" contype="0" conaffinity="0" group="1"'
#: How far short of the limb's far joint its drawn rod ends at home (m).
ROD_SHORT = 0.05


def build_mjcf(
    robot: Mechanism,
    *,
    timestep: float = TIMESTEP,
    solref: tuple[float, float] = SOLREF,
    solimp: tuple[float, ...] = SOLIMP,
    rotor_inertia: float = 0.0,
    screw_lead: float = 0.01,
    friction_viscous: float = 0.0,
    friction_coulomb: float = 0.0,
    payload_mass: float = 0.0,
    payload_offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    integrator: str = "RK4",
) -> str:
    """An MJCF model of ``robot``; the module docstring says how each joint is built.

    The model is defined at the Mechanism's home pose, so ``qpos0`` is consistent, and a
    slide joint measures its limb's length from there: q_i = qpos(slide_i) + q_i(home)
    (see :func:`limb_lengths`).

    Parameters
    ----------
    robot : Mechanism
        Geometry, inertial parameters, g and the home pose come from here.
    timestep : float
        RK4 step (s).
    integrator : str
        MuJoCo's integrator: "RK4" (the loop's) or "Euler" (semi-implicit, for timing).
    solref, solimp : tuple of float
        Softness of every equality constraint (MuJoCo's ``solref`` and ``solimp``).
    rotor_inertia : float
        Rotor inertia J_m per motor (kg m^2, DESIGN.md §7); each slide gets the reflected
        inertia m_r = J_m (2 pi / screw_lead)^2 as its ``armature``, which adds
        1/2 m_r qdot_i^2 to the kinetic energy exactly as §7's M += J^T diag(m_r) J.
    screw_lead : float
        Ball-screw lead (m) that reflects ``rotor_inertia`` onto the limb.
    friction_viscous : float
        F_v (N s/m): the slides' ``damping``, the force -F_v qdot_i of §7.
    friction_coulomb : float
        F_c (N): must be 0. §7's dry friction is the smooth F_c tanh(qdot_i / v_s), a force
        of the state; MuJoCo's ``frictionloss`` is a soft constraint solved with the
        closures (no v_s, its own regulariser), so the two machines would differ by model,
        not by error: it is refused rather than mapped.
    payload_mass, payload_offset : float, (3,) floats
        A point mass (kg) at ``payload_offset`` (m, platform frame), as §7's payload: added
        to the platform's own mass, centre of mass and inertia (its ``fullinertia`` about
        the joint centre of mass), so the platform stays one body.

    Returns
    -------
    str
        The MJCF text. Names: body and free joint ``platform``; bodies ``lower{i}`` and
        ``upper{i}``, joints ``base{i}`` (RPU) or ``top{i}`` (SPR) and ``slide{i}``,
        actuators ``limb{i}`` and equality constraints ``closure{i}``, i = 1..4.

    Raises
    ------
    ValueError
        If an option is out of range, or ``friction_coulomb`` is not 0 (see above).
    RuntimeError
        If the geometry rebuilt here disagrees with ``robot.inverse_kinematics``.
    """
    if integrator not in ("RK4", "Euler"):
        raise ValueError(f"integrator = {integrator!r}: must be 'RK4' or 'Euler'")
    if friction_coulomb != 0.0:
        raise ValueError(
            f"friction_coulomb = {friction_coulomb!r}: MuJoCo's dry friction (frictionloss) is "
            "a soft constraint, not the tanh force of the rigid plant (docs/machine.md); "
            "only 0 can be modelled"
        )
    for name, v, lo in (("rotor_inertia", rotor_inertia, 0.0), ("friction_viscous",
                        friction_viscous, 0.0)):  # fmt: skip
        if not (np.isfinite(v) and v >= lo):
            raise ValueError(f"{name} = {v!r}: must be finite and >= 0")
    if not (np.isfinite(screw_lead) and screw_lead > 0.0):
        raise ValueError(f"screw_lead = {screw_lead!r}: must be finite and > 0")
    if not (np.isfinite(timestep) and timestep > 0.0):
        raise ValueError(f"timestep = {timestep!r}: must be finite and > 0 (s)")
    if timestep > mujoco_max_timestep(solref):
        raise ValueError(
            f"timestep = {timestep:g}: must be <= {solref[0] / 2:g} s, half the closures' "
            f"time constant (solref {solref[0]:g} s), which MuJoCo would raise to twice "
            "a longer step, the closures then lagging"
        )
    if not (np.isfinite(payload_mass) and payload_mass >= 0.0):
        raise ValueError(f"payload_mass = {payload_mass!r}: must be finite and >= 0")
    offset = np.asarray(payload_offset, dtype=float)
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise ValueError(f"payload_offset = {payload_offset!r}: must be 3 finite numbers (m)")
    with np.errstate(over="ignore"):  # (a Python float's square raises OverflowError)
        armature = float(rotor_inertia * np.float64(2.0 * np.pi / screw_lead) ** 2)
    if not np.isfinite(armature):  # (the scenario's ranges keep it finite; the API may not)
        raise ValueError(
            f"screw_lead = {screw_lead!r}: reflects rotor_inertia = {rotor_inertia!r} as "
            "an infinite armature"
        )
    slide_options = f' armature="{_f(armature)}" damping="{_f(friction_viscous)}"'
    home = robot.home
    geo = _limb_geometry(robot, home)
    q_ik = robot.inverse_kinematics(home)
    if not np.allclose(geo["q"], q_ik, rtol=0.0, atol=1e-12):
        raise RuntimeError(f"limb geometry disagrees with the Mechanism: {geo['q']} vs {q_ik}")
    theta = np.asarray(robot.theta, dtype=float).reshape(9, 4)
    p, R, a, b, frames, q0 = (geo[k] for k in ("p", "R", "a", "b", "frames", "q"))

    platform: list[str] = []  # inside the platform body
    world: list[str] = []  # inside worldbody
    equality: list[str] = []
    actuators: list[str] = []
    for i in range(4):
        n = i + 1
        lower, upper = theta[1 + i], theta[5 + i]
        l1, l2 = float(robot.l1[i]), float(robot.l2[i])
        # the drawn rod reaches from the limb's tip to 5 cm short of its other joint at
        # home: drawn 2 l2 long (its mass's extent), a limb longer than 2 (l1 + l2) =
        # 0.877 m, as in half the paper's run, showed a gap between rod and tube
        rod = max(2 * l2, float(q0[i]) - ROD_SHORT)
        actuators.append(f'<motor name="limb{n}" joint="slide{n}" gear="1"/>')
        if i in RPU_LIMBS:
            world += [
                f'<body name="lower{n}" pos="{_f(*b[i])}" quat="{_quat(frames[i])}">',
                f'  <joint name="base{n}" type="hinge" axis="1 0 0"/>',
                f"  {_inertial(lower, l1)}",
                f"  {_rod('cylinder', 2 * l1, 0.02)}",
                f'  <body name="upper{n}" pos="0 0 {_f(q0[i])}">',
                f'    <joint name="slide{n}" type="slide" axis="0 0 1"{slide_options}/>',
                f"    {_inertial(upper, -l2)}",
                f"    {_rod('capsule', -rod, 0.012)}",
                f'    <site name="tip{n}"/>',
                "  </body>",
                "</body>",
            ]
            platform.append(f'<site name="joint{n}" pos="{_f(*a[i])}"/>')
            equality.append(f'<connect name="closure{n}" site1="tip{n}" site2="joint{n}"/>')
        else:
            platform += [
                f'<body name="upper{n}" pos="{_f(*a[i])}" quat="{_quat(R.T @ frames[i])}">',
                f'  <joint name="top{n}" type="hinge" axis="1 0 0"/>',
                f"  {_inertial(upper, -l2)}",
                f"  {_rod('capsule', -rod, 0.012)}",
                f'  <body name="lower{n}" pos="0 0 {_f(-q0[i])}">',
                f'    <joint name="slide{n}" type="slide" axis="0 0 -1"{slide_options}/>',
                f"    {_inertial(lower, l1)}",
                f"    {_rod('cylinder', 2 * l1, 0.02)}",
                f'    <site name="foot{n}"/>',
                "  </body>",
                "</body>",
            ]
            world.append(f'<site name="base{n}" pos="{_f(*b[i])}"/>')
            equality.append(f'<connect name="closure{n}" site1="foot{n}" site2="base{n}"/>')

    def block(lines: list[str], indent: int) -> str:
        return ("\n" + " " * indent).join(lines)

    m0 = theta[0]
    return f"""<mujoco model="pkmctl 2RPU-2SPR">
  <compiler angle="radian"/>
  <option timestep="{_f(timestep)}" integrator="{integrator}" gravity="0 0 {_f(-robot.g)}"
          jacobian="dense">
    <flag contact="disable"/>
  </option>
  <default>
    <equality solref="{_f(*solref)}" solimp="{_f(*solimp)}"/>
  </default>
  <visual>
    <global offwidth="800" offheight="600"/>
  </visual>
  <worldbody>
    <light pos="0 -1 3" dir="0 0.3 -1" directional="true"/>
    <geom type="cylinder" pos="0 0 -0.01" size="{_f(1.2 * robot.r_b, 0.01)}"
          rgba="0.5 0.5 0.5 1" {_VISUAL}/>
    <body name="platform" pos="{_f(*p)}" quat="{_quat(R)}">
      <freejoint name="platform"/>
      {_platform_inertial(m0, payload_mass, offset)}
      <geom type="cylinder" size="{_f(robot.r_a, 0.01)}" rgba="0.3 0.5 0.8 1" {_VISUAL}/>
      {block(platform, 6)}
    </body>
    {block(world, 4)}
  </worldbody>
  <equality>
    {block(equality, 4)}
  </equality>
  <actuator>
    {block(actuators, 4)}
  </actuator>
</mujoco>
"""


#: :func:`build_mjcf`'s machine options and the scenario fields they are read from.
SCENARIO_FIELDS = {
    "rotor_inertia": "plant.rotor_inertia",
    "screw_lead": "plant.screw_lead",
    "friction_viscous": "plant.friction_viscous",
    "friction_coulomb": "plant.friction_coulomb",
    "payload_mass": "payload.mass",
    "payload_offset": "payload.offset",
    "timestep": "timing.control_period / timing.substeps",
}


def scenario_options(scenario) -> dict:
    """:func:`build_mjcf`'s machine options from a :class:`~pkmctl.Scenario`: its
    ``[plant]`` options and ``[payload]`` (DESIGN.md §7), keyed as :data:`SCENARIO_FIELDS`."""
    ps, pl = scenario.plant_spec, scenario.payload
    return {
        "rotor_inertia": float(ps.rotor_inertia),
        "screw_lead": float(ps.screw_lead),
        "friction_viscous": float(ps.friction_viscous),
        "friction_coulomb": float(ps.friction_coulomb),
        "payload_mass": float(pl.mass),
        "payload_offset": tuple(float(v) for v in pl.offset),
    }


def scenario_error(message: str, given: dict | None = None) -> str:
    """``message`` of :func:`build_mjcf` with its leading option named as the user gave it:
    ``--rotor-inertia`` if in ``given`` (an option name to the flag), else the scenario
    field (``plant.friction_coulomb``)."""
    for name, field in SCENARIO_FIELDS.items():
        if message.startswith(f"{name} = "):
            return (given or {}).get(name, field) + message[len(name) :]
    return message


def build_model(robot: Mechanism, **kwargs) -> mujoco.MjModel:
    """Compile :func:`build_mjcf` (keyword arguments are passed on)."""
    return mujoco.MjModel.from_xml_string(build_mjcf(robot, **kwargs))


# ---------------------------------------------------------------------- state
def _joint(model: mujoco.MjModel, name: str) -> int:
    return int(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name))


def _platform_adr(model: mujoco.MjModel) -> tuple[int, int]:
    """qpos and dof addresses of the platform's free joint."""
    j = _joint(model, "platform")
    return int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])


def _slides(model: mujoco.MjModel) -> np.ndarray:
    return np.array([_joint(model, f"slide{n}") for n in range(1, 5)])


def _equality_rows(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """Residual (nefc,) and Jacobian (nefc, nv) of the equality constraints at data.qpos."""
    mujoco.mj_fwdPosition(model, data)
    ne = data.nefc
    return data.efc_pos[:ne].copy(), data.efc_J[: ne * model.nv].reshape(ne, model.nv).copy()


def limb_lengths(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """Limb lengths (4,) of a configuration: the slide positions plus their offsets.

    A slide's body sits ``|body_pos|`` from its parent's joint point along the slide axis
    when the slide is at zero, so that is the offset (the limb length at home, ``qpos0``).
    """
    j = _slides(model)
    offset = np.linalg.norm(model.body_pos[model.jnt_bodyid[j]], axis=1)
    return np.asarray(qpos)[model.jnt_qposadr[j]] + offset


def platform_pose(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """Task pose [z, alpha, beta] of the platform's free joint in ``qpos``.

    R = R_x(alpha) R_y(beta) has second column (0, cos a, sin a) and first row
    (cos b, 0, sin b).
    """
    qadr, _ = _platform_adr(model)
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, np.asarray(qpos[qadr + 3 : qadr + 7], dtype=float))
    R = R.reshape(3, 3)
    return np.array([qpos[qadr + 2], np.arctan2(R[2, 1], R[1, 1]), np.arctan2(R[0, 2], R[0, 0])])


def initial_qpos(
    model: mujoco.MjModel,
    robot: Mechanism,
    X: np.ndarray,
    *,
    tol: float = 1e-13,
    max_iter: int = 50,
) -> np.ndarray:
    """A configuration with the platform at pose X and every closure satisfied.

    The platform's free joint is set from X (p and R of DESIGN.md §1). The limb joints are
    then solved from the home configuration by Gauss-Newton on MuJoCo's own equality
    residual and Jacobian (``efc_pos``, ``efc_J``) over the limb dofs only, so the limb
    lengths come from the MuJoCo geometry, not from the closed form; they must equal the
    closed form's within 1 um (the machine's assembly branch). If they do not (a limb
    through its base joint closes the chain too), the poses from home to X are followed
    in steps of at most 0.02 (m or rad), each solved from the last.

    Parameters
    ----------
    model : mujoco.MjModel
        A model from :func:`build_mjcf`.
    robot : Mechanism
        Checks that X is a valid pose.
    X : array_like, shape (3,)
        Task pose [z, alpha, beta].
    tol : float
        Largest closure residual accepted (m).
    max_iter : int
        Gauss-Newton iterations allowed.

    Returns
    -------
    ndarray, shape (nq,)

    Raises
    ------
    pkmctl.errors.InvalidPoseError
        If the Mechanism rejects X.
    RuntimeError
        If the residual does not reach ``tol``.
    """
    X = np.asarray(X, dtype=float)
    robot.check_pose(X)
    want = _limb_geometry(robot, X)["q"]  # the closed form's limb lengths, all > 0
    qpos, res = _closed(model, model.qpos0, X, tol, max_iter)
    if res < tol and _assembled_as(model, qpos, want):
        return qpos
    # The solve from home closed the chains on another branch (a limb turned through its
    # base joint, its length negative: a tester found 72 of 720 poses with |alpha|,
    # |beta| <= 1.1 rad), or did not close: follow the poses from home to X instead,
    # each step from the last, which stays on the machine's branch.
    qpos = model.qpos0.copy()
    X0 = platform_pose(model, qpos)
    steps = max(1, math.ceil(float(np.max(np.abs(X - X0))) / _STEP))
    for s in np.linspace(0.0, 1.0, steps + 1)[1:]:
        qpos, res = _closed(model, qpos, X0 + s * (X - X0), tol, max_iter)
        if res >= tol:
            break
    if res < tol and _assembled_as(model, qpos, want):
        return qpos
    raise RuntimeError(
        f"closure not reached for X = {X.tolist()} on the machine's branch: residual "
        f"{res:.3e} m, limb lengths {limb_lengths(model, qpos).tolist()} against "
        f"{want.tolist()}"
    )


#: The largest change of z (m) or an angle (rad) between two poses of the path that
#: :func:`initial_qpos` follows from home when the direct solve lands on another branch.
_STEP = 0.02


def _assembled_as(model: mujoco.MjModel, qpos: np.ndarray, want: np.ndarray) -> bool:
    """Whether the limb lengths of ``qpos`` are the closed form's (within 1 um): a chain
    closed with a limb through its base joint has the same end points, another length."""
    return bool(np.max(np.abs(limb_lengths(model, qpos) - want)) < 1e-6)


def _closed(model: mujoco.MjModel, start: np.ndarray, X: np.ndarray, tol: float,
            max_iter: int) -> tuple[np.ndarray, float]:  # fmt: skip
    """``start`` with the platform at X and its limb joints solved by Gauss-Newton on
    MuJoCo's own equality residual and Jacobian over the limb dofs; (qpos, residual)."""
    qadr, dadr = _platform_adr(model)
    p, R = _platform_frame(X)
    qpos = np.array(start, dtype=float)
    qpos[qadr : qadr + 3] = p
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, R.ravel())
    qpos[qadr + 3 : qadr + 7] = quat
    limb = np.setdiff1d(np.arange(model.nv), np.arange(dadr, dadr + 6))
    data = mujoco.MjData(model)
    res = np.inf
    for _ in range(max_iter):
        data.qpos[:] = qpos
        r, J = _equality_rows(model, data)
        res = float(np.max(np.abs(r)))
        if res < tol:
            return qpos, res
        dq = np.zeros(model.nv)
        dq[limb] = -np.linalg.lstsq(J[:, limb], r, rcond=None)[0]
        mujoco.mj_integratePos(model, qpos, dq, 1.0)
    return qpos, res


def _platform_qvel(X: np.ndarray, Xdot: np.ndarray) -> np.ndarray:
    """Free-joint velocity from Xdot: world linear velocity of p, angular velocity in A.

    omega = alpha_dot e_x + beta_dot R_x(alpha) e_y, so
    R^T omega = (alpha_dot cos b, beta_dot, alpha_dot sin b).
    """
    z, a, b = X
    zd, ad, bd = Xdot
    pyd = -zd * np.tan(a) - z * ad / np.cos(a) ** 2
    return np.array([0.0, pyd, zd, ad * np.cos(b), bd, ad * np.sin(b)], dtype=float)


def initial_qvel(model: mujoco.MjModel, qpos: np.ndarray, X, Xdot) -> np.ndarray:
    """Joint velocities with the platform at rate Xdot and every closure at rest.

    The limb joint rates are the least-squares solution of J_eq qvel = 0 (MuJoCo's
    constraint Jacobian at ``qpos``) given the platform's free-joint velocity.

    Parameters
    ----------
    model : mujoco.MjModel
        A model from :func:`build_mjcf`.
    qpos : ndarray, shape (nq,)
        A consistent configuration (:func:`initial_qpos`) at pose X.
    X, Xdot : array_like, shape (3,)
        Task pose and rate.

    Returns
    -------
    ndarray, shape (nv,)
    """
    _, dadr = _platform_adr(model)
    plat = np.arange(dadr, dadr + 6)
    limb = np.setdiff1d(np.arange(model.nv), plat)
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    _, J = _equality_rows(model, data)
    qvel = np.zeros(model.nv)
    qvel[plat] = _platform_qvel(np.asarray(X, dtype=float), np.asarray(Xdot, dtype=float))
    qvel[limb] = -np.linalg.lstsq(J[:, limb], J[:, plat] @ qvel[plat], rcond=None)[0]
    return qvel


def platform_task_acceleration(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """[z_ddot, alpha_ddot, beta_ddot] from ``data.qacc`` of the platform's free joint.

    Differentiating R^T omega = (alpha_dot cos b, beta_dot, alpha_dot sin b) gives
    alpha_ddot = wdot_x cos b + wdot_z sin b (the beta_dot terms cancel) and
    beta_ddot = wdot_y; z_ddot is the world z acceleration of p.
    """
    _, dadr = _platform_adr(model)
    beta = platform_pose(model, data.qpos)[2]
    acc = data.qacc[dadr : dadr + 6]
    return np.array([acc[2], acc[3] * np.cos(beta) + acc[5] * np.sin(beta), acc[4]])


# ---------------------------------------------------------------------- checks
def agreement(
    robot: Mechanism,
    n: int = 20,
    seed: int = 0,
    *,
    horizon: float = 0.02,
    **model_kwargs,
) -> dict[str, float | int | list[float]]:
    """Compare the MuJoCo model with the closed form at ``n`` random states.

    States: z uniform in [0.7, 1.3] times the home z, alpha and beta uniform in
    [-0.3, 0.3] rad (poses the Mechanism rejects are drawn again), Xdot uniform in
    +-(0.1 m/s, 1 rad/s, 1 rad/s), actuator forces tau = the gravity-compensating forces
    plus uniform +-100 N per limb.

    (a) Limb lengths: the slide positions plus their offsets (:func:`limb_lengths`), with
    the closure solved on MuJoCo's residual (:func:`initial_qpos`), against
    ``robot.inverse_kinematics(X)``. (b) Task accelerations of ``mj_forward``
    (:func:`platform_task_acceleration`) against Xddot = M^-1 (J^T tau - C Xdot - G).
    (c) Trajectories: from the same state with tau held, ``horizon`` seconds of ``mj_step``
    against the closed form integrated by ``solve_ivp`` (DOP853, rtol 1e-12).

    Findings (MuJoCo 4.0.0, the paper's machine, n = 20, seed 0):

    - Limb lengths agree to 2e-15 m; closure residuals are <= 5e-15 m and closure velocity
      residuals <= 1e-15 m/s.
    - Accelerations agree to 8e-4 m/s^2 (z), 3.8e-3 rad/s^2 (alpha), 6e-5 rad/s^2 (beta),
      at most 3.6e-4 of the largest component of Xddot (accelerations up to 15 m/s^2,
      12 rad/s^2, 160 rad/s^2). The error is MuJoCo's regulariser alone: the Newton
      solver converges in one iteration (the problem is quadratic), tightening its
      tolerance changes nothing, and the error scales exactly with 1 - d (2.0e-3, 2.0e-4,
      2.0e-5 relative at d = 0.99, 0.999, 0.9999 at one state, with or without velocity).
      d = 0.9999 is MuJoCo's ceiling, so about 1e-5 to 1e-4 relative is as close as this
      model can get.
    - MuJoCo 4 includes J_dot v in the constraint acceleration of connect constraints
      (``efc_aref`` is non-zero at consistent states with velocity), so there is no
      velocity-dependent bias: the error is the same at rest and at 2 rad/s.
    - Trajectories agree far better than (b) suggests: after 20 ms the poses differ by at
      most 9.6e-10 (m or rad; the platform moving up to 0.04), and after 0.2 s of larger
      motions (up to 0.18) by 2.6e-10. The (b) error exists only while the closures carry
      no deflection, as at a state set by hand: within a few solref time constants they take
      up a deflection of ~1e-9 m whose spring force carries the regulariser's share, and
      the relative acceleration error falls from ~4e-6 to ~1e-8. So for simulation the
      error to quote is that sag (``closure_residual_end`` of :func:`steps_per_second`) and
      (c), not (b).

    Parameters
    ----------
    robot : Mechanism
        The machine modelled and the reference.
    n : int
        Number of random states.
    seed : int
        Seed of the generator.
    horizon : float
        Duration of each trajectory of (c) (s).
    **model_kwargs
        Passed to :func:`build_mjcf`.

    Returns
    -------
    dict
        ``n``, ``nv``, ``neq``, ``nefc``; ``q_err_max_m`` (max |q_mujoco - q_closed_form|);
        ``closure_residual_max`` (m) and ``closure_velocity_max`` (m/s) of the initial
        states; ``xddot_err_max`` (max abs error per component: m/s^2, rad/s^2, rad/s^2);
        ``xddot_rel_err_max`` (max over states of |error|_inf / |Xddot|_inf);
        ``xddot_scale`` (max |Xddot| per component); ``traj_err_max`` (max over states and
        components of |X_mujoco(horizon) - X_closed_form(horizon)|, m or rad) and
        ``traj_motion_max`` (max |X(horizon) - X(0)| of the closed form, for scale).
    """
    model = build_model(robot, **model_kwargs)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    z0 = float(robot.home[0])
    q_err = res_max = vel_max = rel_max = traj_err = traj_motion = 0.0
    nsteps = max(1, round(horizon / model.opt.timestep))
    acc_err = np.zeros(3)
    acc_scale = np.zeros(3)
    done = 0
    while done < n:
        X = np.array([z0 * rng.uniform(0.7, 1.3), *rng.uniform(-0.3, 0.3, 2)])
        try:
            robot.check_pose(X)
        except InvalidPoseError:
            continue
        Xdot = rng.uniform(-1.0, 1.0, 3) * np.array([0.1, 1.0, 1.0])
        tau = robot.actuator_forces(X, robot.gravity(X)) + rng.uniform(-100.0, 100.0, 4)
        qpos = initial_qpos(model, robot, X)
        qvel = initial_qvel(model, qpos, X, Xdot)
        data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, tau
        r, J = _equality_rows(model, data)
        res_max = max(res_max, float(np.max(np.abs(r))))
        vel_max = max(vel_max, float(np.max(np.abs(J @ qvel))))
        dq = limb_lengths(model, qpos) - robot.inverse_kinematics(X)
        q_err = max(q_err, float(np.max(np.abs(dq))))

        mujoco.mj_forward(model, data)
        xdd_mj = platform_task_acceleration(model, data)
        F = robot.jacobian(X).T @ tau - robot.coriolis_matrix(X, Xdot) @ Xdot - robot.gravity(X)
        xdd = np.linalg.solve(robot.mass_matrix(X), F)
        err = np.abs(xdd_mj - xdd)
        acc_err = np.maximum(acc_err, err)
        acc_scale = np.maximum(acc_scale, np.abs(xdd))
        rel_max = max(rel_max, float(err.max() / np.abs(xdd).max()))

        for _ in range(nsteps):
            mujoco.mj_step(model, data)
        X_cf = _closed_form_trajectory(robot, X, Xdot, tau, nsteps * model.opt.timestep)
        traj_err = max(traj_err, float(np.max(np.abs(platform_pose(model, data.qpos) - X_cf))))
        traj_motion = max(traj_motion, float(np.max(np.abs(X_cf - X))))
        done += 1
    return {
        "n": n,
        "nv": int(model.nv),
        "neq": int(model.neq),
        "nefc": int(data.nefc),
        "q_err_max_m": q_err,
        "closure_residual_max": res_max,
        "closure_velocity_max": vel_max,
        "xddot_err_max": acc_err.tolist(),
        "xddot_rel_err_max": rel_max,
        "xddot_scale": acc_scale.tolist(),
        "traj_err_max": traj_err,
        "traj_motion_max": traj_motion,
    }


def _closed_form_trajectory(robot, X, Xdot, tau, duration: float) -> np.ndarray:
    """Pose after ``duration`` s of the closed-form dynamics with actuator forces ``tau``."""
    from scipy.integrate import solve_ivp  # imported here: it takes 0.3 s

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        x, xd = y[:3], y[3:]
        F = robot.jacobian(x).T @ tau - robot.coriolis_matrix(x, xd) @ xd - robot.gravity(x)
        return np.concatenate([xd, np.linalg.solve(robot.mass_matrix(x), F)])

    y0 = np.concatenate([X, Xdot])
    sol = solve_ivp(rhs, (0.0, duration), y0, method="DOP853", rtol=1e-12, atol=1e-12)
    if not sol.success:
        raise RuntimeError(f"closed-form integration failed: {sol.message}")
    return sol.y[:3, -1]


def platform_rate(model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """Task rate [z_dot, alpha_dot, beta_dot] (3,) from the platform's free-joint velocity.

    The inverse of :func:`initial_qvel`'s map: z_dot is the world z velocity of p, and
    R^T omega = (alpha_dot cos b, beta_dot, alpha_dot sin b).
    """
    _, dadr = _platform_adr(model)
    beta = platform_pose(model, qpos)[2]
    v = qvel[dadr : dadr + 6]
    return np.array([v[2], v[3] * np.cos(beta) + v[5] * np.sin(beta), v[4]])


def _constraint_bias(model: mujoco.MjModel, data: mujoco.MjData, h: float) -> np.ndarray:
    """J_dot qvel (nefc,): the closures' acceleration at qacc = 0, by a central difference of
    J(q) qvel along qvel over +-h seconds (error O(h^2); h = 1e-5 s gives ~1e-12 relative)."""
    work = mujoco.MjData(model)
    qvel = data.qvel.copy()
    out = []
    for sign in (1.0, -1.0):
        work.qpos[:] = data.qpos
        mujoco.mj_integratePos(model, work.qpos, qvel, sign * h)
        _, J = _equality_rows(model, work)
        out.append(J @ qvel)
    return (out[0] - out[1]) / (2.0 * h)


def task_acceleration(model: mujoco.MjModel, data: mujoco.MjData, *, h: float = 1e-5):
    """Xddot (3,) of the rigid constrained dynamics of the MuJoCo model, solved exactly.

    MuJoCo's own ``qacc`` is that of *soft* closures (a regulariser of 1 - d of the
    constraint-space inverse inertia, and a spring-damper on the residual). This solves
    instead, from MuJoCo's quantities at ``data`` (run ``mj_forward`` first): the joint-space
    mass matrix M (nv, nv) (``mj_fullM``, armature included), the smooth force
    f = qfrc_actuator + qfrc_passive + qfrc_applied - qfrc_bias (``qfrc_smooth``), and the
    closure Jacobian J (nefc, nv) (``efc_J``, rank nv - 3 = 11 of 12 rows: the RPU pair's
    redundant row). With N (nv, 3) an orthonormal basis of the null space of J (the 3
    freedoms) and a particular qacc_p = -J^+ J_dot qvel (so J qacc = -J_dot qvel holds),

        qacc = qacc_p + N (N^T M N)^-1 N^T (f - M qacc_p),

    the constrained (Gauss's principle) acceleration, independent of ``solref``/``solimp``.
    Returns it as task accelerations via :func:`platform_task_acceleration`.

    Returns
    -------
    ndarray, shape (3,)
        [z_ddot, alpha_ddot, beta_ddot].
    """
    nv = model.nv
    M = np.empty((nv, nv))
    mujoco.mj_fullM(model, data, M)
    f = data.qfrc_smooth.copy()
    ne = data.nefc
    J = data.efc_J[: ne * nv].reshape(ne, nv).copy()
    U, s, Vt = np.linalg.svd(J)
    rank = int(np.sum(s > s[0] * 1e-10))
    N = Vt[rank:].T
    qacc_p = -np.linalg.pinv(J, rcond=1e-10) @ _constraint_bias(model, data, h)
    qacc = qacc_p + N @ np.linalg.solve(N.T @ M @ N, N.T @ (f - M @ qacc_p))
    work = mujoco.MjData(model)
    work.qpos[:], work.qacc[:] = data.qpos, qacc
    return platform_task_acceleration(model, work)


# ---------------------------------------------------------------------- the loop's plant
#: Largest closure residual (m) a run may reach before it counts as a constraint blow-up:
#: the soft closures sag ~1e-9 m under the paper's loads (:func:`agreement`).
CLOSURE_LIMIT = 1e-6
#: MuJoCo's warnings that mean its state is no longer the machine's (it resets silently).
_FATAL_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
)


class MujocoMachine:
    """The MuJoCo model of a Mechanism, stepped by RK4 as the loop's ``mujoco`` plant.

    Parameters
    ----------
    robot : Mechanism
        The true machine.
    timestep : float
        The RK4 step (s): the loop's sub-step T_c / substeps.
    **options
        Passed to :func:`build_mjcf` (``rotor_inertia``, ``friction_viscous``, ...).

    Notes
    -----
    The limb forces are MuJoCo's ``ctrl`` and the task-space disturbance tau_d' (3,) an
    ``xfrc_applied`` at the platform's centre p: force (0, 0, d_z) and torque
    d_alpha e_x + d_beta w, w = R_x(alpha) e_y, whose virtual work on dX is d . dX
    (dp/dalpha and dp/dbeta have no z part; the rotation's are e_x and w). MuJoCo applies
    it at the body's centre of mass, which a payload moves to p + r: the torque is then
    less r x (0, 0, d_z), the same wrench about p. Both are held
    over each RK4 step (MuJoCo holds its inputs over a step); the closed-form loop holds
    the limb forces of an ideal actuator too, and evaluates the disturbance's map at each
    stage, which differs by O(h alpha_dot) of a force held within 1 % of its size.
    """

    def __init__(self, robot: Mechanism, *, timestep: float = TIMESTEP, **options) -> None:
        self.robot = robot
        self.model = build_model(robot, timestep=timestep, **options)
        self.data = mujoco.MjData(self.model)
        qadr, dadr = _platform_adr(self.model)
        self._qadr, self._dadr = qadr, dadr
        j = _slides(self.model)
        self._slide_qadr = self.model.jnt_qposadr[j]
        self._slide_offset = np.linalg.norm(self.model.body_pos[self.model.jnt_bodyid[j]], axis=1)
        body = int(mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "platform"))
        d = self.data  # views, valid for the life of d (efc_* are reallocated every step)
        self._qpos, self._qvel, self._ctrl = d.qpos, d.qvel, d.ctrl
        self._xfrc = d.xfrc_applied[body]
        # the centre of mass in the platform frame: off p only with a payload
        self._com = (
            self.model.body_ipos[body].tolist() if self.model.body_ipos[body].any() else None
        )
        self._warnings = d.warning.number
        self._fatal = np.array([int(w) for w in _FATAL_WARNINGS])

    def reset(self, x: np.ndarray) -> None:
        """Put the machine at x = [X, Xdot] (6,), every closure satisfied and at rest."""
        mujoco.mj_resetData(self.model, self.data)  # in place: the views stay valid
        qpos = initial_qpos(self.model, self.robot, x[:3])
        self.data.qpos[:] = qpos
        self.data.qvel[:] = initial_qvel(self.model, qpos, x[:3], x[3:6])
        mujoco.mj_forward(self.model, self.data)

    def step(self, tau: np.ndarray, dist: np.ndarray) -> None:
        """One RK4 step under limb forces tau (4,) and disturbance dist (3,), held."""
        self._ctrl[:] = tau
        # w = R e_y = (0, cos a, sin a), from the platform's quaternion
        qw, qx, qy, qz = self._qpos[self._qadr + 3 : self._qadr + 7].tolist()
        wy, wz = 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz + qw * qx)
        if self._com is None:
            self._xfrc[2:6] = (dist[0], dist[1], dist[2] * wy, dist[2] * wz)
        else:  # MuJoCo applies the wrench at the centre of mass r = R c from p: move it there
            cx, cy, cz = self._com
            rx = (1.0 - 2.0 * (qy * qy + qz * qz)) * cx + 2.0 * (qx * qy - qw * qz) * cy
            rx += 2.0 * (qx * qz + qw * qy) * cz
            ry = 2.0 * (qx * qy + qw * qz) * cx + (1.0 - 2.0 * (qx * qx + qz * qz)) * cy
            ry += 2.0 * (qy * qz - qw * qx) * cz
            fz = dist[0]
            self._xfrc[2:6] = (fz, dist[1] - ry * fz, dist[2] * wy + rx * fz, dist[2] * wz)
        mujoco.mj_step(self.model, self.data)

    def read(self, x: np.ndarray, q: np.ndarray) -> int:
        """Write [X, Xdot] into x (6,) and the limb lengths into q (4,); return a status:
        0, or 1 non-finite, 4 (STEPPER_BLEW_UP) a MuJoCo warning (MuJoCo then resets its
        state) or a closure residual over :data:`CLOSURE_LIMIT` (the pose check, status 2,
        is the loop's).

        The maps of :func:`platform_pose` and :func:`platform_rate` on scalars, through
        views made once (this runs once a period; the binding's accessors cost ~1 us each).
        """
        if self._warnings[self._fatal].any():
            return STEPPER_BLEW_UP
        a, v = self._qadr, self._dadr
        qp = self._qpos.tolist()
        qv = self._qvel.tolist()
        if not (math.isfinite(sum(qp)) and math.isfinite(sum(qv))):
            return 1
        qw, qx, qy, qz = qp[a + 3 : a + 7]
        alpha = math.atan2(2.0 * (qy * qz + qw * qx), 1.0 - 2.0 * (qx * qx + qz * qz))
        beta = math.atan2(2.0 * (qx * qz + qw * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        cb, sb = math.cos(beta), math.sin(beta)
        x[0:6] = (qp[a + 2], alpha, beta, qv[v + 2], qv[v + 3] * cb + qv[v + 5] * sb, qv[v + 4])
        q[:] = self._qpos[self._slide_qadr] + self._slide_offset
        if abs(self.data.efc_pos).max(initial=0.0) > CLOSURE_LIMIT:
            return STEPPER_BLEW_UP
        return 0


def render_poses(
    robot: Mechanism, poses: np.ndarray, *, width: int = 640, height: int = 480,
    shadow_size: int | None = None,
):  # fmt: skip
    """Offscreen images of the machine at task poses X (k, 3).

    ``shadow_size`` is the side of the shadow map; by default twice the image's larger
    side, rounded up to a power of two (at least 1024, at most MuJoCo's 4096).

    Returns
    -------
    list of ndarray, each shape (height, width, 3), uint8

    Raises
    ------
    RuntimeError
        One line, if no OpenGL backend renders here (``MUJOCO_GL`` = egl or osmesa).
    ValueError
        If ``shadow_size`` is outside [64, 16384].
    """
    if shadow_size is not None and not 64 <= shadow_size <= 16384:
        raise ValueError(f"shadow_size = {shadow_size}: must be in [64, 16384]")
    backend = getattr(mujoco, "GLContext", None)
    headless = backend is not None and backend.__module__.split(".")[-1] in ("egl", "osmesa")
    if not headless and not os.environ.get("DISPLAY"):  # GLFW would abort the process
        raise RuntimeError(
            "MuJoCo cannot render here: no display and no offscreen backend "
            "(set MUJOCO_GL=egl or osmesa before MuJoCo is first imported)"
        )
    model = build_model(robot)
    # MuJoCo's default shadow map is 4096 x 4096, which a software GL allocates, clears
    # and draws for every image. A map twice the image's larger side draws the same
    # shadows (640 x 480: 63 of 307,200 pixels differ, on the shadows' edges) in 0.07 s
    # less a call and 50 MB less memory (docs/performance.md).
    if shadow_size is None:
        side = 2 ** math.ceil(math.log2(2 * max(width, height)))
        shadow_size = min(int(model.vis.quality.shadowsize), max(1024, side))
    model.vis.quality.shadowsize = int(shadow_size)
    # the offscreen buffer must hold the image: build_mjcf's 800 x 600 made width 1024 "cannot
    # render here" in six lines of MuJoCo's (a code reader)
    model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), int(width))
    model.vis.global_.offheight = max(int(model.vis.global_.offheight), int(height))
    data = mujoco.MjData(model)
    try:
        renderer = mujoco.Renderer(model, height, width)
    except Exception as exc:  # the GL backends raise many types
        gl = os.environ.get("MUJOCO_GL", "default")
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise RuntimeError(f"MuJoCo cannot render here (MUJOCO_GL={gl}): {first}") from None
    cam = mujoco.MjvCamera()
    cam.lookat[:] = (0.0, 0.0, 0.45 * float(robot.home[0]))
    cam.distance, cam.azimuth, cam.elevation = 2.6 * float(robot.home[0]), 60.0, -15.0
    images = []
    try:
        for X in np.asarray(poses, dtype=float).reshape(-1, 3):
            data.qpos[:] = initial_qpos(model, robot, X)
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera=cam)
            images.append(renderer.render().copy())
    finally:
        renderer.close()
    return images
