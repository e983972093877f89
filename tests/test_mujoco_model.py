"""The MuJoCo model of the machine against the closed form (DESIGN.md §10, issue 13 point 2)."""

import os
import subprocess
import sys

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="MuJoCo is not installed (pkmctl[mujoco])")
mj = pytest.importorskip("pkmctl.plants.mujoco")

import pkmctl  # noqa: E402
from pkmctl.errors import InvalidPoseError  # noqa: E402
from tests.conftest import seeded_cache  # noqa: E402

N_STATES = 200


def _states(robot, n: int, seed: int):
    """(X, Xdot, tau) at n random valid states: z in [0.7, 1.3] home z, |angles| <= 0.3 rad,
    Xdot within (0.1 m/s, 1 rad/s, 1 rad/s), tau = gravity forces + U(-100, 100) N."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        X = np.array([robot.home[0] * rng.uniform(0.7, 1.3), *rng.uniform(-0.3, 0.3, 2)])
        try:
            robot.check_pose(X)
        except InvalidPoseError:
            continue
        Xdot = rng.uniform(-1.0, 1.0, 3) * np.array([0.1, 1.0, 1.0])
        tau = robot.actuator_forces(X, robot.gravity(X)) + rng.uniform(-100.0, 100.0, 4)
        out.append((X, Xdot, tau))
    return out


def _closed_form(robot, X, Xdot, tau, m_r=0.0, f_v=0.0):
    """Xddot of §2, with §7's reflected rotor inertia m_r and viscous friction F_v:
    (M + J^T m_r J) Xddot = J^T (tau - F_v J Xdot - m_r Jdot Xdot) - C Xdot - G."""
    J = robot.jacobian(X)
    h = 1e-6
    Jdot_Xdot = (robot.jacobian(X + h * Xdot) - robot.jacobian(X - h * Xdot)) @ Xdot / (2 * h)
    M = robot.mass_matrix(X) + m_r * J.T @ J
    f = J.T @ (tau - f_v * J @ Xdot - m_r * Jdot_Xdot)
    return np.linalg.solve(M, f - robot.coriolis_matrix(X, Xdot) @ Xdot - robot.gravity(X))


def _set(model, data, robot, X, Xdot, tau):
    qpos = mj.initial_qpos(model, robot, X)
    data.qpos[:], data.ctrl[:] = qpos, tau
    data.qvel[:] = mj.initial_qvel(model, qpos, X, Xdot)
    mujoco.mj_forward(model, data)


@pytest.fixture(scope="module")
def model(robot):
    return mj.build_model(robot)


def test_the_machine_is_assembled_on_its_own_branch_at_large_tilts(robot, model):
    """From home, Gauss-Newton closed the chains at X = [0.45, 0.3, 0.9] with limb 4
    turned through its base joint (length -0.3807 m, the closure exact): the MuJoCo run
    diverged where the rigid one did not, or ran on another machine without a word. Every
    pose of a sample with |alpha|, |beta| <= 1.1 rad now has the closed form's lengths."""
    X = np.array([0.45, 0.3, 0.9])
    direct, res = mj._closed(model, model.qpos0, X, 1e-13, 50)  # the solve from home alone
    assert res < 1e-13 and mj.limb_lengths(model, direct)[3] < 0  # the case is the flip
    rng = np.random.default_rng(3)
    poses = [X]
    while len(poses) < 60:
        Y = np.array([rng.uniform(0.3, 0.95), *rng.uniform(-1.1, 1.1, 2)])
        try:
            robot.check_pose(Y)
        except InvalidPoseError:
            continue
        poses.append(Y)
    for Y in poses:
        qpos = mj.initial_qpos(model, robot, Y)
        want = robot.inverse_kinematics(Y)  # the closed form's lengths, all > 0
        np.testing.assert_allclose(mj.limb_lengths(model, qpos), want, rtol=0, atol=1e-9)
        np.testing.assert_allclose(mj.platform_pose(model, qpos), Y, rtol=0, atol=1e-12)


def test_limb_lengths_and_rates_from_the_mujoco_state(robot, model):
    data = mujoco.MjData(model)
    for X, Xdot, tau in _states(robot, N_STATES, seed=1):
        _set(model, data, robot, X, Xdot, tau)
        q = mj.limb_lengths(model, data.qpos)
        assert np.max(np.abs(q - robot.inverse_kinematics(X))) <= 1e-12
        np.testing.assert_allclose(mj.platform_pose(model, data.qpos), X, rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            mj.platform_rate(model, data.qpos, data.qvel), Xdot, rtol=0, atol=1e-12
        )


def test_exact_constrained_acceleration_equals_the_closed_form(robot, model):
    data = mujoco.MjData(model)
    worst = 0.0
    for X, Xdot, tau in _states(robot, N_STATES, seed=2):
        _set(model, data, robot, X, Xdot, tau)
        xdd = _closed_form(robot, X, Xdot, tau)
        err = np.max(np.abs(mj.task_acceleration(model, data) - xdd)) / np.max(np.abs(xdd))
        worst = max(worst, err)
    assert worst <= 1e-9, worst


def test_soft_acceleration_is_off_by_the_regulariser_alone(robot, model):
    """mj_forward's qacc is within 1e-3 (relative) of the closed form; the residual is the
    regulariser of MuJoCo's soft closures: it scales with 1 - d of solimp (0.9999 here)."""
    data = mujoco.MjData(model)
    worst = 0.0
    for X, Xdot, tau in _states(robot, N_STATES, seed=3):
        _set(model, data, robot, X, Xdot, tau)
        xdd = _closed_form(robot, X, Xdot, tau)
        err = mj.platform_task_acceleration(model, data) - xdd
        worst = max(worst, np.max(np.abs(err)) / np.max(np.abs(xdd)))
    assert worst <= 1e-3, worst
    X, Xdot, tau = _states(robot, 1, seed=4)[0]
    xdd = _closed_form(robot, X, Xdot, tau)
    errs = []
    for d in (0.99, 0.999, 0.9999):
        m = mj.build_model(robot, solimp=(d, d, 1e-3, 0.5, 2.0))
        dat = mujoco.MjData(m)
        _set(m, dat, robot, X, Xdot, tau)
        errs.append(np.max(np.abs(mj.platform_task_acceleration(m, dat) - xdd)))
        # and the exact solve does not depend on the softness at all
        assert np.max(np.abs(mj.task_acceleration(m, dat) - xdd)) <= 1e-9 * np.max(np.abs(xdd))
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    np.testing.assert_allclose(ratios, 10.0, rtol=0.05)


def test_rotor_inertia_and_viscous_friction_map_to_armature_and_damping(robot):
    J_m, lead, f_v = 2.77e-5, 0.01, 300.0
    m_r = J_m * (2 * np.pi / lead) ** 2  # 10.9 kg per limb (DESIGN.md §7)
    model = mj.build_model(robot, rotor_inertia=J_m, screw_lead=lead, friction_viscous=f_v)
    joint = mujoco.mjtObj.mjOBJ_JOINT
    slides = [mujoco.mj_name2id(model, joint, f"slide{n}") for n in (1, 2, 3, 4)]
    dofs = model.jnt_dofadr[slides]
    np.testing.assert_allclose(model.dof_armature[dofs], m_r, rtol=1e-15)
    np.testing.assert_array_equal(model.dof_damping[dofs], f_v)
    data = mujoco.MjData(model)
    for X, Xdot, tau in _states(robot, 50, seed=5):
        _set(model, data, robot, X, Xdot, tau)
        xdd = _closed_form(robot, X, Xdot, tau, m_r=m_r, f_v=f_v)
        err = np.max(np.abs(mj.task_acceleration(model, data) - xdd)) / np.max(np.abs(xdd))
        assert err <= 1e-9, err


def test_coulomb_friction_is_refused_with_the_reason(robot):
    with pytest.raises(ValueError, match="frictionloss.*soft constraint.*tanh"):
        mj.build_mjcf(robot, friction_coulomb=30.0)
    with pytest.raises(ValueError, match="screw_lead"):
        mj.build_mjcf(robot, rotor_inertia=1e-5, screw_lead=0.0)
    # the API's own checks (a timestep of 0, < 0 or NaN built a model; a lead of 1e-200
    # overflowed to an armature of inf)
    for step in (0.0, -1e-4, float("nan")):
        with pytest.raises(ValueError, match=r"^timestep = .*: must be finite and > 0 \(s\)$"):
            mj.build_mjcf(robot, timestep=step)
    with pytest.raises(ValueError, match="an infinite armature"):
        mj.build_mjcf(robot, rotor_inertia=1.0, screw_lead=1e-200)


def test_pkmctl_imports_without_mujoco_and_says_how_to_get_it():
    code = (
        "import sys; sys.modules['mujoco'] = None\n"
        "import pkmctl; pkmctl.simulate\n"
        "try:\n    import pkmctl.plants.mujoco\n"
        "except ImportError as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == (
        'pkmctl.plants.mujoco needs MuJoCo: pip install "mujoco>=3.1" (or, in a checkout of '
        'pkmctl, pip install ".[mujoco]")'
    )


def test_mujoco_model_command_writes_a_loadable_model(tmp_path):
    from typer.testing import CliRunner

    from pkmctl.cli import app

    runner = CliRunner()
    out = tmp_path / "m" / "pkm.xml"
    res = runner.invoke(app, ["mujoco-model", "--out", str(out), "--rotor-inertia", "2.77e-5",
                              "--friction-viscous", "300"])  # fmt: skip
    assert res.exit_code == 0, res.output
    model = mujoco.MjModel.from_xml_path(str(out))
    assert (model.nv, model.neq, model.nu) == (14, 4, 4)
    assert np.isclose(model.dof_armature.max(), 2.77e-5 * (2 * np.pi / 0.01) ** 2)
    assert [p.name for p in tmp_path.joinpath("m").iterdir()] == ["pkm.xml"]  # no temp left
    slow = tmp_path / "slow.toml"
    slow.write_text(
        pkmctl.Scenario.builtin("paper").replace(**{"timing.control_period": 1e-3}).to_toml()
    )
    for args, match in (
        (["--out", str(tmp_path)], "is a folder"),
        (["--out", "/proc/no/such/pkm.xml"], "'/proc' is not writable"),
        (["--out", str(out / "x.xml")], "pkm.xml': exists and is not a folder"),  # out: a file
        (["--out", str(out), "--friction-coulomb", "30"], "--friction-coulomb = 30.0: MuJoCo"),
        (["--out", str(out), "--rotor-inertia", "-1"], "--rotor-inertia = -1.0: must be"),
        (["--out", str(out), "--screw-lead", "inf"], "--screw-lead = inf: must be a finite"),
        # a floor: 1e-200 overflowed into a traceback, 1e-6 reflected 3.9e13 kg a limb
        (
            ["--out", str(out), "--screw-lead", "1e-200", "--rotor-inertia", "1"],
            "--screw-lead = 1e-200: must be a finite number in [0.0001, 1] (m)",
        ),
        # a name over 255 bytes: Path.is_dir raised, a traceback
        (["--out", str(tmp_path / ("a" * 300 + ".xml"))], "the name is too long"),
        # the scenario's ranges, not only build_mjcf's signs (it wrote armature = 3.9e28)
        (
            ["--out", str(out), "--rotor-inertia", "1e9"],
            "--rotor-inertia = 1000000000.0: must be a finite number in [0, 1] (kg m^2)",
        ),  # fmt: skip
        (
            ["--out", str(out), "--scenario", "prototype"],  # the scenario's 30 N
            "plant.friction_coulomb = 30.0: MuJoCo's dry friction (frictionloss)",
        ),
        (  # a 1 ms step: MuJoCo would raise the closures' 0.5 ms time constant to 2 ms
            ["--out", str(out), "--scenario", str(slow)],
            "timing.control_period / timing.substeps = 0.001: must be <= 0.00025 s, half",
        ),
    ):
        res = runner.invoke(app, ["mujoco-model", *args])
        assert res.exit_code == 2, res.output
        assert match in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_mujoco_model_takes_the_scenarios_plant_options(tmp_path):
    from typer.testing import CliRunner

    import pkmctl
    from pkmctl.cli import app

    out = tmp_path / "proto.xml"
    args = ["mujoco-model", "--out", str(out), "--scenario", "prototype", "--friction-coulomb", "0"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    plant = pkmctl.Scenario.builtin("prototype").plant_spec
    model = mujoco.MjModel.from_xml_path(str(out))
    m_r = plant.rotor_inertia * (2 * np.pi / plant.screw_lead) ** 2
    assert m_r > 0 and np.isclose(model.dof_armature.max(), m_r)
    assert np.isclose(model.dof_damping.max(), plant.friction_viscous)
    # the loop's RK4 sub-step, 1 ms / 10 (it wrote the paper's 5e-5 for every scenario)
    timing = pkmctl.Scenario.builtin("prototype").timing
    assert model.opt.timestep == timing.control_period / timing.substeps == 1e-4


def test_render_poses_draws_the_machine(robot):
    try:
        images = mj.render_poses(robot, [robot.home, robot.home + [0.0, 0.3, -0.3]], width=160,
                                 height=120)  # fmt: skip
    except RuntimeError as exc:
        pytest.skip(f"no offscreen GL backend here: {exc}")
    assert [im.shape for im in images] == [(120, 160, 3)] * 2
    assert images[0].std() > 10 and np.abs(images[0].astype(int) - images[1]).mean() > 1


def test_the_smaller_shadow_map_draws_the_default_picture(robot):
    """render_poses' shadow map (2048 for 640 x 480) against MuJoCo's default 4096: the
    same image but for a few pixels on the shadows' edges."""
    poses = [robot.home + [0.0, 0.25, -0.2]]
    try:
        ours = mj.render_poses(robot, poses)[0].astype(int)
        default = mj.render_poses(robot, poses, shadow_size=4096)[0].astype(int)
    except RuntimeError as exc:
        pytest.skip(f"no offscreen GL backend here: {exc}")
    differ = np.abs(ours - default).max(axis=2) > 8
    # measured: 63 of 307,200 pixels, mean 0.010 (a 1024 map: 119, 0.017; 256: 410, 0.063)
    assert differ.mean() < 3e-4, f"{differ.sum()} pixels differ"
    assert np.abs(ours - default).mean() < 0.014


def test_render_poses_draws_images_wider_than_800(robot):
    """build_mjcf's offscreen buffer is 800 x 600: width 1024 raised "MuJoCo cannot render
    here" in six lines (a code reader); render_poses raises the buffer to the image."""
    try:
        mj.render_poses(robot, [robot.home], width=32, height=24)
    except RuntimeError as exc:
        pytest.skip(f"no offscreen GL backend here: {exc}")
    images = mj.render_poses(robot, [robot.home], width=1024, height=700)
    assert images[0].shape == (700, 1024, 3) and images[0].std() > 10


def test_render_poses_refuses_a_shadow_map_out_of_range(robot):
    with pytest.raises(ValueError, match=r"shadow_size = 0: must be in \[64, 16384\]"):
        mj.render_poses(robot, [robot.home], shadow_size=0)


def test_every_option_mujoco_models_is_the_closed_form_plants(robot):
    """Rotor inertia, viscous friction and a payload off the platform's centre, all at once:
    MuJoCo's constrained acceleration against the rigid plant's own M, C v, G and friction
    (pkmctl.sim.plants.machine_dynamics, the code its derivative runs)."""
    from pkmctl.sim.plants import machine_dynamics, rigid_plant

    options = {"rotor_inertia": 2.77e-5, "screw_lead": 0.01, "friction_viscous": 300.0,
               "payload_mass": 5.0, "payload_offset": (0.06, -0.04, 0.03)}  # fmt: skip
    model = mj.build_model(robot, **options)
    plant = rigid_plant(robot, **options)
    assert plant.machine == 1.0 and plant.payload == 5.0
    assert np.isclose(model.body_mass.sum(), robot.theta[0::4].sum() + 5.0, rtol=1e-14)
    data = mujoco.MjData(model)
    for X, Xdot, tau in _states(robot, 50, seed=6):
        _set(model, data, robot, X, Xdot, tau)
        M, Cv, G, friction = machine_dynamics(plant, X, Xdot, Xdot)
        xdd = np.linalg.solve(M, robot.jacobian(X).T @ tau - Cv - G - friction)
        err = np.max(np.abs(mj.task_acceleration(model, data) - xdd)) / np.max(np.abs(xdd))
        assert err <= 1e-9, err
    with pytest.raises(ValueError, match=r"payload_offset = .*: must be 3 finite numbers"):
        mj.build_mjcf(robot, payload_mass=1.0, payload_offset=(0.0, np.nan, 0.0))


def test_each_limb_is_drawn_whole_over_the_workspace(robot, model):
    """The drawn rod was 2 l2 long and the tube 2 l1: a limb longer than their 0.877 m sum,
    as in half of the paper's run (up to 1.005 m), was drawn with a gap in it. Now the rod
    reaches from the tip to 5 cm short of the far joint at home: whole up to 1.1 m, and
    inside the limb at home."""
    home = robot.inverse_kinematics(robot.home)
    geoms = [model.geom(i) for i in range(model.ngeom)]
    size = {t: sorted(2 * float(g.size[1]) for g in geoms if g.type[0] == t and g.size[1] > 0.1)
            for t in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER)}  # fmt: skip
    rods, tubes = size[mujoco.mjtGeom.mjGEOM_CAPSULE], size[mujoco.mjtGeom.mjGEOM_CYLINDER]
    assert len(rods) == len(tubes) == 4
    for rod, tube, q in zip(rods, tubes, home, strict=True):
        assert rod + tube >= 1.1 and rod <= q - 0.049


def test_a_mujoco_plant_without_mujoco_is_refused_before_anything_compiles(tmp_path):
    """`reproduce` of a mujoco scenario without MuJoCo said "compiling 5 control loops" and
    compiled them for minutes (a cold cache) before its one-line refusal; a campaign ran
    every run as an error record, exit 1."""
    text = pkmctl.Scenario.builtin("paper").replace(**{"plant.kind": "mujoco"}).to_toml()
    (tmp_path / "mj.toml").write_text(text)
    code = (
        "import sys; sys.modules['mujoco'] = None\n"
        "from pkmctl.cli import main\n"
        "sys.argv = ['pkmctl', *sys.argv[1:]]\n"
        "main()\n"
    )
    hint = "plant 'mujoco': pkmctl.plants.mujoco needs MuJoCo: pip install \"mujoco>=3.1\""
    (tmp_path / "spec.toml").write_text(  # (a campaign made an error record of each run)
        'scenario = "mj.toml"\ncontrollers = ["pd"]\nseeds = [1]\nduration = 0.01\n'
        '[factors."plant.friction_viscous"]\nvalues = [0.0, 5.0]\n'
    )
    cache = seeded_cache(tmp_path / "cache")  # the kernels, no control loop
    for args in (
        ["reproduce", "--scenario", "mj.toml", "--out", "o", "--duration", "0.01"],
        ["simulate", "mj.toml", "--out", "o", "--duration", "0.01"],
        ["campaign", "run", "spec.toml", "--out", "o", "--workers", "1"],
    ):
        out = subprocess.run(
            [sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=tmp_path,
            env={**os.environ, "PKMCTL_CACHE_DIR": str(cache)},
        )  # fmt: skip
        assert out.returncode == 2, out.stderr
        # (the model's and the fuzzy engine's kernels, which check the scenario, compile
        # first where the machine's cache lacks them: seconds)
        lines = [ln for ln in out.stderr.splitlines()
                 if not ln.startswith(("compiling the ", "compiled the "))]  # fmt: skip
        assert len(lines) == 1 and hint in lines[0], out.stderr
        assert "control loop" not in out.stderr
        assert not (tmp_path / "o").exists()
