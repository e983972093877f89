"""Identification (DESIGN.md §9, issue 12): base parameters, the exciting trajectory, the
estimate on noise-free and noisy data, honest intervals, bad logs, the two commands."""

from __future__ import annotations

import json
import os
import tomllib

import numpy as np
import pytest

import pkmctl
from pkmctl.ident.base import base_parameters, random_states
from pkmctl.ident.excite import MAX_ANGLE, Z_RANGE, _machine, design_excitation
from pkmctl.ident.identify import IdentificationError, Log, identify, predict, read_log
from pkmctl.ident.synthetic import limb_accelerations, synthetic_log
from tests.conftest import run_pkmctl

FULL = os.environ.get("PKMCTL_FULL") == "1"


@pytest.fixture(scope="module")
def proto() -> pkmctl.Scenario:
    return pkmctl.Scenario.builtin("prototype")


@pytest.fixture(scope="module")
def exciting(proto):
    """The designed trajectory (the defaults of pkmctl excite: ~20 s) and the prototype on it."""
    said: list[tuple[int, int]] = []
    e = design_excitation(proto, progress=lambda *a: said.append(a))
    assert said == [(1, 4), (2, 4), (3, 4), (4, 4)]  # each random start, as it ends
    return e, e.scenario(proto)


# ------------------------------------------------------------------ base parameters
def test_base_parameters_reproduce_the_full_regressor(robot):
    bp = base_parameters(robot)
    assert bp.count == 30  # the paper's geometry: 30 of the 48 combine identifiably
    rng = np.random.default_rng(11)  # other states than the ones the QR saw
    X, Xd, Xdd = random_states(robot, 80, rng)
    W = robot.extended_regressor(X, Xd, Xd, Xdd, 1e-3)
    Wb = bp.reduce(W).reshape(-1, bp.count)
    assert np.linalg.matrix_rank(Wb) == bp.count  # full column rank
    for _ in range(5):
        theta = rng.uniform(-2.0, 2.0, 48)
        full = W.reshape(-1, 48) @ theta
        np.testing.assert_allclose(
            Wb @ bp.base(theta), full, rtol=0, atol=1e-10 * np.abs(full).max()
        )


def test_base_parameters_are_named_combinations(robot):
    bp = base_parameters(robot)
    assert bp.expressions[0] == "m_platform"
    assert any(" + " in e for e in bp.expressions)  # some are combinations
    for k in range(bp.count):  # each starts with its own standard parameter, coefficient 1
        assert bp.expressions[k].split(" ")[0] == bp.names[k]
        assert bp.K[k, bp.independent[k]] == 1.0
    assert "Fv4" in bp.table() and bp.rank_gap < 1e-6  # a clean rank decision


# ------------------------------------------------------------------ the trajectory
def test_fourier_derivatives_and_rest_at_the_ends(exciting):
    e, sc = exciting
    tr = e.trajectory
    t = np.linspace(0.3, 4.7, 50)
    h = 1e-5
    X, Xd, Xdd = tr.evaluate(t)
    Xp, Xdp, _ = tr.evaluate(t + h)
    Xm, Xdm, _ = tr.evaluate(t - h)
    np.testing.assert_allclose((Xp - Xm) / (2 * h), Xd, atol=1e-8)
    np.testing.assert_allclose((Xdp - Xdm) / (2 * h), Xdd, atol=1e-7)
    for t_end in (0.0, e.duration):
        X0, Xd0, Xdd0 = tr.evaluate(np.array([t_end]))
        np.testing.assert_allclose(X0[0], sc.initial.X, atol=1e-12)
        np.testing.assert_allclose(Xd0[0], 0.0, atol=1e-12)
        np.testing.assert_allclose(Xdd0[0], 0.0, atol=1e-10)


def test_excitation_beats_the_papers_trajectory_inside_the_limits(exciting, proto):
    e, sc = exciting
    assert e.cond < e.cond_paper / 10
    # the constraints, checked here on a fine grid with the public API
    t = np.linspace(0.0, e.duration, 4001)
    X, Xd, Xdd = sc.trajectory.build().evaluate(t)
    assert np.abs(X[:, 1:]).max() <= MAX_ANGLE + 1e-6
    assert Z_RANGE[0] - 1e-6 <= X[:, 0].min() and X[:, 0].max() <= Z_RANGE[1] + 1e-6
    robot = sc.plant()
    J = robot.jacobian(X)
    assert np.linalg.cond(J).max() <= 50.0 + 1e-6
    qd = np.einsum("nij,nj->ni", J, Xd)
    assert np.abs(qd).max() <= 0.8 * 0.8334
    theta_ext, vs = _machine(sc)
    F = robot.extended_regressor(X, Xd, Xd, Xdd, vs) @ theta_ext
    tau = np.array([robot.actuator_forces(X[k], F[k]) for k in range(0, t.size, 10)])
    assert np.abs(tau).max() <= 0.5 * 2160.2
    # the scenario is a valid one, and TOML round-trips it
    again = pkmctl.Scenario.from_toml(sc.to_toml())
    assert again == sc and again.trajectory.kind == "fourier"


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"base_frequency": -1.0}, "trajectory.base_frequency"),
        ({"a": [[0.1, 0.2], [0.1], [0.0, 0.0]]}, "same number of harmonics"),
        ({"a": [[float("nan")], [0.0], [0.0]]}, "trajectory.a"),
        ({"a": [[9.0], [0.0], [0.0]]}, "trajectory"),  # z leaves the workspace
    ],
)
def test_bad_fourier_trajectory_is_one_line(change, words):
    data = {"trajectory": {"kind": "fourier", "base_frequency": 0.2} | change}
    with pytest.raises(pkmctl.ScenarioError, match=words) as info:
        pkmctl.Scenario.from_dict(data)
    assert "\n" not in str(info.value)


# ------------------------------------------------------------------ estimation
def test_synthetic_limb_accelerations_are_the_lengths_second_derivative(exciting):
    """J Xddot + Jdot Xdot against five-point central differences of the exact limb
    lengths along the designed trajectory (their error: ~2e-9 m/s^2 at a 1 ms step)."""
    _, sc = exciting
    traj, mech = sc.trajectory.build(), sc.plant()
    t = np.linspace(0.5, sc.timing.duration - 0.5, 400)
    X, Xd, Xdd = traj.evaluate(t)
    qdd = limb_accelerations(mech.geometry, X, Xd, Xdd)
    d = 1e-3
    q = [mech.inverse_kinematics(traj.evaluate(t + k * d)[0]) for k in (-2, -1, 0, 1, 2)]
    fd = (-q[0] + 16.0 * q[1] - 30.0 * q[2] + 16.0 * q[3] - q[4]) / (12.0 * d * d)
    assert np.abs(qdd).max() > 1.0  # the trajectory accelerates the limbs
    np.testing.assert_allclose(qdd, fd, rtol=0, atol=1e-7)


def test_noise_free_data_recover_the_base_parameters(exciting):
    _, sc = exciting
    log = synthetic_log(sc, internal=50.0)  # internal forces must change nothing
    idn = identify(log, sc)
    true = idn.base.base(_machine(sc)[0])
    for fit in (idn.ols, idn.wls):
        rel = np.abs(fit.beta - true) / np.abs(true)
        assert rel.max() <= 1e-6, dict(zip(idn.base.names, rel, strict=True))
    assert idn.wls.relative_error < 1e-8
    # the physically consistent estimate also fits (a bound is never active here)
    np.testing.assert_allclose(idn.physical_fit.beta, idn.wls.beta, rtol=1e-4, atol=1e-6)


def test_intervals_are_honest_over_noise_draws(exciting):
    """BIRDy's set-up: one trajectory, >= 20 draws of encoder quantisation, 0.5 um of noise
    on q and 1 N on tau; the true base parameter inside its 95 % interval 90-99 % of the time."""
    _, sc = exciting
    true = None
    inside = []
    seeds = range(40 if FULL else 20)
    for seed in seeds:
        log = synthetic_log(sc, quantise=True, q_noise=5e-7, tau_noise=1.0, seed=seed)
        idn = identify(log, sc, physical=False)
        if true is None:
            true = idn.base.base(_machine(sc)[0])
            friction = [k for k, n in enumerate(idn.base.names) if n[:2] in ("Fc", "Fv")]
        inside.append(np.abs(idn.wls.beta - true) <= 1.96 * idn.wls.std)
    inside = np.array(inside)
    assert 0.90 <= inside.mean() <= 0.99, inside.mean()
    assert inside[:, friction].mean() >= 0.85, inside[:, friction].mean(axis=0)


def test_validation_on_another_trajectory(exciting, proto):
    _, sc = exciting
    idn = identify(synthetic_log(sc, tau_noise=1.0, seed=1), sc)
    other = synthetic_log(proto, duration=6.0, tau_noise=1.0, seed=2)  # eq. 54
    val = predict(idn, other, proto)
    assert val["relative_error"] < 0.01
    assert val["predicted"].shape == val["observation"].y.shape


def test_the_estimate_is_a_controller_model(exciting, proto):
    _, sc = exciting
    idn = identify(synthetic_log(sc, tau_noise=1.0, seed=3), sc)
    block = idn.controller_model()
    model = proto.replace(controller_model=block)
    # the controllers' model now carries the identified rotor masses and friction
    np.testing.assert_allclose(model.controller_mechanism().theta, block["theta_ext"][:36])
    m_r, fc, fv = model.controller_model.machine_terms(0.01)
    np.testing.assert_allclose(fc, block["theta_ext"][40:44])
    assert np.all(fc > 25) and np.all(fv > 290)  # the truth: 30 N, 300 N s/m


def test_theta_ext_equal_to_theta_scale_gives_the_same_run():
    sc = pkmctl.Scenario.builtin("paper").replace(**{"timing.duration": 0.02})
    th = list(0.85 * sc.plant().theta) + [0.0] * 12
    same = sc.replace(controller_model={"theta_ext": th})
    for ctrl in ("afsmc", "ctc"):
        a, b = pkmctl.simulate(sc, controller=ctrl), pkmctl.simulate(same, controller=ctrl)
        np.testing.assert_array_equal(a.F, b.F)


def test_theta_ext_conflicts_are_one_line():
    with pytest.raises(pkmctl.ScenarioError, match="theta_ext is given, so theta_scale"):
        pkmctl.Scenario.from_dict(
            {"controller_model": {"theta_ext": [1.0] * 48, "theta_scale": 0.9}}
        )
    with pytest.raises(pkmctl.ScenarioError, match=r"theta_ext\[3\]"):
        pkmctl.Scenario.from_dict({"controller_model": {"theta_ext": [1.0] * 3 + [0.0] * 45}})


# ------------------------------------------------------------------ bad logs
def _clean(sc) -> Log:
    return synthetic_log(sc, duration=10.0)


def _with(log: Log, **changes) -> Log:
    d = {"t": log.t.copy(), "q": log.q.copy(), "tau": log.tau.copy()}
    for k, fn in changes.items():
        d[k] = fn(d[k])
    return Log(d["t"], d["q"], d["tau"], "bad.csv")


def _set(a, idx, v):
    a[idx] = v
    return a


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"t": lambda t: _set(t, 500, t[499])}, "time is not increasing at data row 501"),
        ({"t": lambda t: np.concatenate([t[:300], t[300:] + 0.05])}, "uneven sampling at t"),
        ({"t": lambda t: t[:15], "q": lambda q: q[:15], "tau": lambda x: x[:15]}, "too few"),
        (
            {"q": lambda q: _set(q, (50, 1), -0.1)},
            r"column q2 at data row 51 \(t = 0.05 s\) is -0.1: limb lengths must be > 0 m",
        ),
        ({"tau": lambda x: 0.0 * x}, "tau1..tau4 are all zero: the forces carry no information"),
        ({"q": lambda q: q * 3.0}, "forward kinematics failed"),
    ],
)
def test_bad_logs_are_one_line(exciting, changes, words):
    _, sc = exciting
    log = _with(_clean(sc), **changes)
    with pytest.raises(IdentificationError, match=words) as info:
        identify(log, sc)
    assert "\n" not in str(info.value)


def test_short_and_unexciting_logs_are_refused(exciting, proto):
    _, sc = exciting
    short = synthetic_log(sc, duration=1.0)
    with pytest.raises(IdentificationError, match="leave none|too short|too few"):
        identify(short, sc)
    # at rest at home for 10 s: nothing is excited
    still = pkmctl.Scenario.from_dict(
        {"trajectory": {"kind": "fourier", "base_frequency": 0.2}, "plant": {"kind": "rigid"}}
    )
    # rank <= 3, one pose's three rows (it said 5: columns of rounding alone counted)
    with pytest.raises(IdentificationError, match=r"no excitation: the observation matrix has "
                       r"rank [0-3] of 30 "):  # fmt: skip
        identify(synthetic_log(still, duration=10.0), still)
    # the force lead searched on a log that moves nothing: the misfit is flat, and the
    # search said "smallest at the edge ... give the lead in seconds" instead
    with pytest.raises(IdentificationError, match="no excitation: the observation matrix has rank"):
        identify(synthetic_log(still, duration=10.0), still, force_lead=None)


def test_lengths_that_fit_no_pose_of_the_geometry_are_refused(exciting):
    """Forward kinematics is least squares: swapped q columns or another machine's lengths
    still give poses, with residuals far above what quantisation and noise leave (3e-8 m,
    2.4 x the noise's std). Refused, naming the row, the residual and the scenario; the
    validation log too. Genuine noisy encoder logs pass."""
    from pkmctl.ident.identify import MAX_FK_RESIDUAL

    _, sc = exciting
    swapped = _with(_clean(sc), q=lambda q: q[:, [1, 0, 2, 3]])
    with pytest.raises(IdentificationError, match="do not fit the geometry of scenario") as info:
        identify(swapped, sc)
    msg = str(info.value)
    assert "the worst 0." in msg and "from data row" in msg and "\n" not in msg
    # where it starts, not the worst row: an encoder wrap at 6.000 s was named at 6.772 s
    log = _clean(sc)
    k = log.t.size // 2
    wrap = _with(log, q=lambda q: np.vstack([q[:k], q[k:] + [0.0, -0.01, 0.0, 0.0]]))
    with pytest.raises(
        IdentificationError,
        match=rf"from data row {k + 1} \(t = "
        rf"{log.t[k]:.6g} s\): \d+ rows, the worst .* m, most on q2 ",
    ):
        identify(wrap, sc)  # fmt: skip
    mm = _with(log, q=lambda q: 1e3 * q)
    with pytest.raises(IdentificationError, match=r"in millimetres\? \(q must be in metres\)"):
        identify(mm, sc)
    # centimetres (71 m limbs) had no hint, the 100 x bound being mm's (a code reader)
    for factor, unit in ((100.0, "centimetres"), (39.37, "inches"), (1e-3, "kilometres")):
        other = _with(log, q=lambda q, f=factor: f * q)
        with pytest.raises(IdentificationError, match=rf"m: in {unit}\? \(q must be in metres"):
            identify(other, sc)
    other = sc.replace(**{"mechanism.r_b": sc.mechanism.r_b + 0.01})  # another machine
    with pytest.raises(IdentificationError, match="do not fit the geometry"):
        identify(_clean(other), sc)
    for noise in (1e-6, 5e-6):  # genuine: quantised and noisy (worst 2.4 x noise)
        noisy = synthetic_log(sc, duration=10.0, quantise=True, q_noise=noise, seed=4)
        idn = identify(noisy, sc, physical=False)
        assert 2.0 * noise < idn.observation.fk_residual < MAX_FK_RESIDUAL
    with pytest.raises(IdentificationError, match="^--validate 'bad.csv': the lengths do not"):
        predict(idn, Log(swapped.t, swapped.q, swapped.tau, "bad.csv", what="--validate"), sc)


def test_sample_rate_cutoff_and_length_are_checked_first(exciting):
    _, sc = exciting
    log = _clean(sc)
    with pytest.raises(IdentificationError, match=r"cutoff = 150 Hz, which must be in \(0, 20\]"):
        identify(log, sc, cutoff=150.0)
    slow = synthetic_log(sc, rate=200.0, duration=10.0)  # pose filter at 20 Hz: biased
    with pytest.raises(IdentificationError, match="sampled at 200 Hz, too slowly") as info:
        identify(slow, sc)
    assert "sampled at >= 500 Hz" in str(info.value)
    # a tiny cutoff is a huge FIR: the log's length is checked before it is built
    with pytest.raises(IdentificationError, match="too short for cutoff = 0.001 Hz"):
        identify(log, sc, cutoff=1e-3)
    with pytest.raises(IdentificationError, match="too short for cutoff = 1e-308 Hz"):
        identify(log, sc, cutoff=1e-308)  # (an OverflowError: an internal error, a fuzzer)
    with pytest.raises(IdentificationError, match="too short for cutoff = 10 Hz: it needs >= 6"):
        identify(synthetic_log(sc, duration=5.0), sc)
    # a median interval a hair over 1 ms is 1 kHz: decimation by 40 at 10 Hz, not 39
    late = _with(log, t=lambda t: t * (1 + 1e-7))
    obs = identify(late, sc, physical=False).observation
    assert obs.sample_rate == 1000.0 and obs.decimation == 40
    # epoch times (t ~ 1.7e9 s): float64 intervals of 0.99993 or 1.00017 ms, whose median
    # made 1000.07 Hz, 'decimation by 40 (to 25.0018 Hz)' and moved the estimate by up to
    # 0.22 std (a code reader); the mean interval is the span's
    ref = identify(log, sc, physical=False)
    epoch = identify(_with(log, t=lambda t: t + 1.7e9), sc, physical=False)
    assert epoch.observation.sample_rate == 1000.0 and epoch.observation.decimation == 40
    assert np.abs((epoch.wls.beta - ref.wls.beta) / ref.wls.std).max() < 0.05


def test_a_log_of_just_the_minimum_length_is_identified(exciting, noisy):
    """6727 samples of 6.726 s at 10 Hz are the minimum: cut from t = 1 s, the median
    interval is a rounding under 1 ms, and the log was refused as 6.726 s too short for
    6.726 s (a code reader); one sample less is refused."""
    _, sc = exciting
    cut = Log(noisy.t[1000:7727], noisy.q[1000:7727], noisy.tau[1000:7727], "bad.csv")
    assert np.median(np.diff(cut.t)) < 1e-3
    assert identify(cut, sc, physical=False).observation.t.size > 0
    with pytest.raises(IdentificationError, match=r"6726 samples \(6.725 s\), too short"):
        identify(Log(cut.t[:-1], cut.q[:-1], cut.tau[:-1], "bad.csv"), sc, physical=False)


def test_force_lead_auto_finds_several_samples_and_refuses_the_edge(exciting):
    _, sc = exciting
    log = _clean(sc)
    late = _with(log, tau=lambda x: np.vstack([np.repeat(x[:1], 5, 0), x[:-5]]))  # 5 ms late
    idn = identify(late, sc, force_lead=None, physical=False)
    assert abs(idn.observation.force_lead + 0.005) < 5e-5, idn.observation.force_lead
    later = _with(log, tau=lambda x: np.vstack([np.repeat(x[:1], 15, 0), x[:-15]]))
    with pytest.raises(IdentificationError, match="at the edge of the searched"):
        identify(later, sc, force_lead=None, physical=False)


def test_notes_name_base_parameters_in_full_and_bounds_only_where_active(exciting):
    """Coulomb friction of -30 N (the log's forces minus twice the true 30 N): the bound
    F_c >= 0 is active, and the note says so for those parameters and no others."""
    _, sc = exciting
    log = _clean(sc)
    X, Xd, _ = sc.trajectory.build().evaluate(log.t)
    qd = np.einsum("nij,nj->ni", sc.plant().jacobian(X), Xd)
    vs = sc.plant_spec.friction_velocity
    bad = _with(log, tau=lambda x: x - 60.0 * np.tanh(qd / vs))
    # the physical fit leaves 12 % of this unphysical log: past the fit-quality gate
    idn = identify(bad, sc, max_residual=None)
    assert len(idn.notes) == 1 and "Fc1 = 0" in idn.active_bounds
    note = idn.notes[0]
    k = idn.base.names.index("Fc1")
    assert f"#{k + 1} Fc1 (at a bound: Fc1 = 0)" in note
    assert "a bound is active there" not in note
    for part in note.split("; #")[1:]:  # each parameter's claim is its own
        if "(at a bound:" in part:
            j = int(part.split(" ")[0]) - 1
            held = part.split("(at a bound: ")[1].split(")")[0].split(", ")
            assert set(held) <= set(idn.active_bounds), (idn.base.expressions[j], held)


def test_csv_quirks_are_read_or_refused_in_one_printable_line(tmp_path, exciting):
    _, sc = exciting
    log = synthetic_log(sc, duration=0.05)
    rows = np.column_stack([log.t, log.q, log.tau])
    body = "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n"
    header = "t,q1,q2,q3,q4,tau1,tau2,tau3,tau4"
    # duplicated columns that are not needed are ignored
    extra = "\n".join(line + ",a,b,," for line in body.splitlines()) + "\n"
    (tmp_path / "extra.csv").write_text(header + ",note,note,,\n" + extra)
    np.testing.assert_array_equal(read_log(tmp_path / "extra.csv").q, log.q)
    cases = {
        "dup.csv": (header.replace("tau4", "tau1") + "\n" + body,
                    "column tau1 occurs 2 times (columns 6, 9)"),
        "nohdr.csv": (body, "the header is missing (the first line is numbers"),
        "semi.csv": (header.replace(",", ";") + "\n" + body.replace(",", ";"),
                     "the header read: 't;q1;q2;q3;q4;tau1;tau2;tau3;tau4', 1 column(s)"),
    }  # fmt: skip
    for name, (text, words) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(IdentificationError) as info:
            read_log(tmp_path / name)
        assert words in str(info.value), str(info.value)
    (tmp_path / "bin.csv").write_bytes(
        b"\x7fELF\x02\x01,\x00\x03\n\x00\x1b[2J,\x05,\x06,\x07\n" * 3
    )
    with pytest.raises(IdentificationError, match="binary data, neither a Parquet") as info:
        read_log(tmp_path / "bin.csv")
    assert str(info.value).isprintable(), repr(str(info.value))
    with pytest.raises(IdentificationError, match="is a folder, not a file"):
        read_log(tmp_path)
    # pyarrow's own messages quoted a Parquet file's bytes, or counted columns
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({"t": log.t}), tmp_path / "table.csv")
    (tmp_path / "table.parquet").write_text(header + "\n" + body)
    (tmp_path / "comment.csv").write_text("# run 7, by hand\n" + header + "\n" + body)
    sniffed = {
        "table.csv": "a Parquet file under another name (name it .parquet)",
        "table.parquet": "text, not a Parquet file (a CSV table? name it .csv)",
        "comment.csv": "the first line is a comment ('#...'): remove it",
    }
    for name, words in sniffed.items():
        with pytest.raises(IdentificationError) as info:
            read_log(tmp_path / name)
        assert f"log '{tmp_path / name}': {words}" in str(info.value), str(info.value)


def test_excitation_refuses_an_initial_pose_outside_its_limits(proto):
    with pytest.raises(ValueError, match=r"initial.X = \[0.6, 0.0, 0.0\].*z >= 0.62 m"):
        design_excitation(proto.replace(**{"initial.X": [0.6, 0.0, 0.0]}))


# ------------------------------------------------------------------ the commands
def _run(*args, cwd):
    return run_pkmctl(*args, cwd=cwd)


def _write_csv(path, log: Log):
    data = np.column_stack([log.t, log.q, log.tau])
    header = "t,q1,q2,q3,q4,tau1,tau2,tau3,tau4"
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.17g")


def test_excite_and_identify_commands(tmp_path, exciting, proto):
    r = _run("excite", "--out", "ex.toml", "--harmonics", "4", "--periods", "1", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "cond(W_b)" in r.stdout and "eq. 54" in r.stdout
    assert "1080 (50 % of 2160)" in r.stdout  # the design's limit, and the drive's rating
    assert "too short for pkmctl identify" in r.stderr and "--periods >= 2" in r.stderr
    assert "Warning" not in r.stderr, r.stderr
    sc = pkmctl.Scenario.from_toml(tmp_path / "ex.toml")
    assert sc.trajectory.kind == "fourier" and len(sc.trajectory.a[0]) == 4
    # what SLSQP's path depends on beyond the command (its threads changed the design)
    second = (tmp_path / "ex.toml").read_text().splitlines()[1]
    assert second.startswith("# designed with pkmctl ") and " thread" in second, second
    _, exc_sc = exciting
    _write_csv(tmp_path / "run.csv", synthetic_log(exc_sc, tau_noise=1.0, quantise=True))
    _write_csv(tmp_path / "val.csv", synthetic_log(proto, duration=6.0, tau_noise=1.0))
    r = _run("identify", "run.csv", "--out", "id", "--validate", "val.csv", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "validation on val.csv" in " ".join(r.stdout.split())
    out = tmp_path / "id"
    names = {p.name for p in out.iterdir()}
    assert {"report.md", "estimate.json", "controller_model.toml", "fit.png",
            "residuals.png", "parameters.png", "validation.png"} <= names  # fmt: skip
    report = (out / "report.md").read_text()
    assert "30 base parameters" in report and "discarded" in report
    block = tomllib.loads((out / "controller_model.toml").read_text())["controller_model"]
    pkmctl.Scenario.builtin("prototype").replace(controller_model=block)  # ready to use


def test_identify_output_is_one_runs_and_names_its_log_and_machine(tmp_path, exciting, proto):
    """A second run into the same folder, without --validate and --no-physical, leaves no
    controller_model.toml or validation.png of the first; other files stay. The files
    name the log and the scenario assumed (and where it came from)."""
    _, exc_sc = exciting
    _write_csv(tmp_path / "run.csv", synthetic_log(exc_sc, tau_noise=1.0, quantise=True))
    _write_csv(tmp_path / "val.csv", synthetic_log(proto, duration=6.0, tau_noise=1.0))
    out = tmp_path / "id"
    r = _run("identify", "run.csv", "--out", "id", "--validate", "val.csv", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (
        "# The identified model (pkmctl identify) from run.csv"
        in (out / "controller_model.toml").read_text()
    )
    (out / "mine.txt").write_text("a user's file")
    r = _run("identify", "run.csv", "--out", "id", "--no-physical", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert {p.name for p in out.iterdir()} == {
        "report.md", "estimate.json", "fit.png", "residuals.png", "parameters.png", "mine.txt"
    }  # fmt: skip
    assert "removed controller_model.toml, validation.png" in " ".join(r.stdout.split())
    assert " used; " in r.stderr  # the summary's separators
    default = "scenario 'prototype' (the default: no --scenario and no pkmctl .json"
    report = " ".join((out / "report.md").read_text().split())
    assert "`run.csv`" in report and default in report
    assert "Butterworth low-pass, order 4, at 100 Hz" in report
    assert "FIR low-pass (Hamming window, 401 taps) at 10 Hz" in report
    est = json.loads((out / "estimate.json").read_text())
    assert est["log"] == "run.csv" and est["scenario"].startswith(default)
    assert est["validation_log"] is None and est["theta_ext_physical"] is None
    from pkmctl import __version__

    assert est["software"]["pkmctl"] == __version__ and "Made by pkmctl " in report


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["identify", "missing.csv"], "no such file"),
        (["identify", "cols.csv"], "missing column(s) tau1"),
        (["identify", "nan.csv"], "column q2 holds 1 non-finite value(s), the first at data row 3"),
        (["identify", "cols.csv", "--force-lead", "x"], "--force-lead = 'x'"),
        (["excite", "--harmonics", "2"], "--harmonics = 2: must be in [3, 20]"),
        (["excite", "--seed", "-1"], "--seed = -1: must be >= 0"),
        # (1e-100 Hz was "Singular matrix"; 1e-3 Hz a hint to try another --seed)
        (["excite", "--base-frequency", "1e-100"],
         "--base-frequency = 1e-100: a run of --periods = 2 would last 2e+100 s, over "
         "timing.duration's 3600 s: must be >= 0.000555556 Hz"),
        # the bound rounded up: ">= 0.001944" refused 0.001944 (a review)
        (["excite", "--periods", "7", "--base-frequency", "0.001944"],
         "would last 3601 s, over timing.duration's 3600 s: must be >= 0.00194445 Hz"),
        (["identify", "dup.csv"], "column tau1 occurs 2 times (columns 6, 9)"),
        (["identify", "nohdr.csv"], "the header is missing"),
        (["identify", "zero.csv"], "tau1..tau4 are all zero"),
        (["identify", "ok.csv", "--cutoff", "150"], "--cutoff = 150 Hz, which must be in (0, 20]"),
        (["identify", "ok.csv", "--validate", "nope.csv"], "--validate 'nope.csv': no such file"),
        (["identify", "."], "log '.': is a folder, not a file"),
        (["identify", "/dev/null"], "log '/dev/null': not a regular file"),
        (["identify", "ok.csv", "--validate", "/dev/null"], "--validate '/dev/null': not a"),
        # 30 Hz harmonics: a 1 kHz log's filter (at most 20 Hz) would remove them
        (["excite", "--base-frequency", "10", "--harmonics", "3"],
         "--base-frequency x --harmonics = 30 Hz: pkmctl identify would filter the top harmonic "
         "away (a 1000 Hz log allows --cutoff <= 20 Hz, which keeps 90 % of a harmonic up to "
         "15.5 Hz)"),
    ],
)  # fmt: skip
def test_command_errors_are_one_line_exit_2(tmp_path, args, words):
    (tmp_path / "cols.csv").write_text("t,q1,q2,q3,q4\n0,1,1,1,1\n")
    header = "t,q1,q2,q3,q4,tau1,tau2,tau3,tau4\n"

    def rows(q2="0.7", tau="1,1,1,1"):
        return "\n".join(f"{k * 1e-3},0.7,{q2 if k == 2 else 0.7},0.7,0.7,{tau}" for k in range(30))

    (tmp_path / "nan.csv").write_text(header + rows(q2="nan") + "\n")
    (tmp_path / "ok.csv").write_text(header + rows() + "\n")
    (tmp_path / "zero.csv").write_text(header + rows(tau="0,0,0,0") + "\n")
    (tmp_path / "dup.csv").write_text(header.replace("tau4", "tau1") + rows() + "\n")
    (tmp_path / "nohdr.csv").write_text(rows() + "\n")
    r = _run(*args, "--out", "o" if args[0] == "identify" else "o.toml", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert words in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.toml").exists()


def test_a_run_on_the_mujoco_plant_gives_back_its_armature_and_damping(exciting, tmp_path):
    """MuJoCo as the oracle of the whole chain: the exciting trajectory run by PD on the
    MuJoCo plant (its slides' armature and damping are the prototype's rotor inertia and
    viscous friction; Coulomb friction 0, which MuJoCo cannot model as §7 does), the
    encoder's log saved and identified. The reflected rotor masses (10.94 kg), the viscous
    friction (300 N s/m) and the absent dry friction come back."""
    pytest.importorskip("mujoco", reason="MuJoCo is not installed (pkmctl[mujoco])")
    from pkmctl.ident.identify import read_log
    from pkmctl.io.results import save_result

    _, sc = exciting
    sc = sc.replace(**{"plant.kind": "mujoco", "plant.friction_coulomb": 0.0})
    run = pkmctl.simulate(sc, controller="pd")
    assert run.parts["plant"] == "mujoco"
    table, _ = save_result(run, tmp_path)
    idn = identify(read_log(table), sc)
    est = dict(zip(idn.base.names, idn.wls.beta, strict=True))
    m_r = sc.plant_spec.rotor_inertia * (2 * np.pi / sc.plant_spec.screw_lead) ** 2
    for i in range(1, 5):
        assert abs(est[f"m_r{i}"] / m_r - 1) <= 0.05, (i, est[f"m_r{i}"], m_r)
        assert abs(est[f"Fv{i}"] / 300.0 - 1) <= 0.005, (i, est[f"Fv{i}"])
        assert abs(est[f"Fc{i}"]) <= 0.2, (i, est[f"Fc{i}"])  # the prototype's is 30 N
    assert idn.wls.relative_error < 1e-3


def test_pkmctl_time_series_carry_the_measured_lengths(tmp_path, proto):
    from pkmctl.ident.identify import read_log
    from pkmctl.io.results import load_result, save_result

    r = pkmctl.simulate(proto.replace(**{"sensor.noise": 1e-6}), controller="pd", duration=0.05)
    table, meta = save_result(r, tmp_path)
    back = load_result(meta)
    np.testing.assert_array_equal(back.q_measured, r.q_measured)
    log = read_log(table)
    assert log.columns[1:5] == ("q1_m", "q2_m", "q3_m", "q4_m")
    np.testing.assert_array_equal(log.q, r.q_measured)
    assert not np.array_equal(log.q, r.q)  # the encoder's, not the truth


# ------------------------------------------------------------------ fit-quality gates
@pytest.fixture(scope="module")
def noisy(exciting):
    """A genuine log: quantised encoders, 1 N of force noise (relative residual ~0.06 %)."""
    _, sc = exciting
    return synthetic_log(sc, duration=10.0, quantise=True, tau_noise=1.0, seed=5)


def _refused(log: Log, sc, words: str, **kw) -> str:
    with pytest.raises(IdentificationError, match=words) as info:
        identify(log, sc, **kw)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("log 'bad.csv': "), msg
    return msg


def test_forces_of_the_wrong_sign_are_refused(exciting, noisy):
    """Every force negated: WLS fits as well as before (0.06 %) with every mass negative
    (m_platform ~40 std below 0), and the physical fit explains 0.2 % of the data; one
    limb's force negated: the physical fit leaves ~23 %. Refused, naming the value, the
    allowed range and the likely causes; the genuine log passes."""
    _, sc = exciting
    idn = identify(noisy, sc)
    assert idn.physical_fit.relative_error < 0.01
    for physical in (True, False):
        msg = _refused(
            _with(noisy, tau=lambda x: -x), sc, "WLS gives m_platform = -1", physical=physical
        )
        assert "std below 0" in msg and "at most 5 std below" in msg
        assert "forces of the wrong sign" in msg
    one = _with(noisy, tau=lambda x: x * [1.0, -1.0, 1.0, 1.0])
    msg = _refused(one, sc, r"the physically consistent fit leaves [12]\d\.\d+ % of J\^T tau")
    assert "allowed <= max_residual = 5 %" in msg and "swapped q or tau columns" in msg
    # without the physical fit, WLS (2.5 %) has m_platform < 0: refused too
    _refused(one, sc, r"m_platform = -[\d.]+ kg \(WLS\) is -[\d.]+ x", physical=False)


def test_forces_in_other_units_are_refused(exciting, noisy):
    """kN, or motor torques in N m: the same small residual, every mass scaled (1e-3 x,
    lead / (2 pi eta) = 0.0018 x); m_platform against the scenario's prior (10.84 kg)."""
    _, sc = exciting
    eta, lead = 0.9, sc.plant_spec.screw_lead
    for scale in (1e-3, lead / (2 * np.pi * eta)):
        msg = _refused(
            _with(noisy, tau=lambda x, s=scale: s * x), sc, r"m_platform = 0\.0[12]\d+ kg \(WLS\)"
        )
        assert "x the scenario's prior 10.84 kg (allowed 0.1-10 x)" in msg
        assert "kN instead of N" in msg and "motor torques" in msg
    # further off, the physical fit (masses >= 1 g) fits no more, and the residual it left
    # (70 %) was blamed on negative masses, the units unnamed (a code reader)
    for scale in (1e-4, 1e-6):
        msg = _refused(_with(noisy, tau=lambda x, s=scale: s * x), sc, r"m_platform = [\d.e-]+ kg "
                       r"\(WLS\) is [\d.e-]+ x the scenario's prior")  # fmt: skip
        assert "kN instead of N" in msg and "negative masses" not in msg


@pytest.mark.parametrize(
    ("change", "physical"),
    [
        ({"q": lambda q: q[:, [0, 3, 2, 1]]}, True),  # q2 <-> q4: mirror images
        ({"q": lambda q: q[:, [0, 3, 2, 1]]}, False),
        ({"tau": lambda x: x[:, [0, 3, 2, 1]]}, True),
        ({"tau": lambda x: x[:, [1, 0, 2, 3]]}, True),  # Fv1 161 instead of 300 before
    ],
)
def test_mirror_swapped_columns_are_refused_by_the_fit(exciting, noisy, change, physical):
    """Limbs 2 and 4 (1 and 3) mirror each other: swapped, their lengths still fit the
    geometry (the forward-kinematics check passes), but 12-14 % of the data is left."""
    _, sc = exciting
    which = "the physically consistent fit" if physical else "WLS"
    msg = _refused(
        _with(noisy, **change),
        sc,
        rf"^log 'bad.csv': {which} leaves 1\d\.\d+ % of J\^T tau",
        physical=physical,
    )
    assert "q1<->q3 and q2<->q4 are mirror images" in msg and "raise max_residual" in msg


def test_swapped_columns_with_force_lead_auto_are_not_called_a_timing_problem(exciting, noisy):
    _, sc = exciting
    msg = _refused(_with(noisy, q=lambda q: q[:, [2, 1, 0, 3]]), sc, "not a timing problem",
                   force_lead=None)  # fmt: skip
    assert "swapped q or tau columns" in msg and "max_residual = 5 %" in msg


def test_max_residual_is_the_limit_for_a_machine_with_unmodelled_effects(exciting, noisy):
    """A 15 N vibration at 7.3 Hz on every limb (not in the model): ~9 % left over, the
    masses still sound. Refused at the default 5 %, accepted with max_residual 0.2."""
    _, sc = exciting
    shaken = _with(noisy, tau=lambda x: x + 15.0 * np.sin(2 * np.pi * 7.3 * noisy.t)[:, None])
    msg = _refused(shaken, sc, r"the physically consistent fit leaves [5-9]\.\d+ %")
    idn = identify(shaken, sc, max_residual=0.2)
    assert 0.05 < idn.physical_fit.relative_error < 0.2
    assert "raise max_residual" in msg


def test_a_given_lead_far_worse_than_the_best_near_0_is_noted(exciting, noisy):
    """A tester's -20 ms lead passed every gate (3.1 % misfit, m_platform 5 x its true
    value) without a word; the best lead within +-10 samples left 0.06 %."""
    _, sc = exciting
    idn = identify(noisy, sc, force_lead=0.0, physical=False)
    assert not [n for n in idn.notes if "force lead given" in n]
    h = 1.0 / idn.observation.sample_rate
    idn = identify(noisy, sc, force_lead=3 * h, physical=False)
    (note,) = [n for n in idn.notes if "force lead given" in n]
    assert note.startswith("the force lead given, +3 ms, leaves ") and "+0 ms, the best" in note
    best, at_best, at_given = idn.observation.lead_check
    assert best == 0.0 and at_given > 2 * at_best


def test_late_forces_at_lead_0_name_the_lead_first_among_the_causes(exciting, noisy):
    """A tester's drive log with forces 5 ms late, at the default lead 0, was refused as
    forces of the wrong sign, other units or swapped columns, though the lead search had
    found lead 0 fitting ten times worse than -5 ms. A refusal now names the lead first
    (here the forces are also negated, so that a gate refuses the log)."""
    _, sc = exciting
    late = _with(noisy, tau=lambda x: -np.vstack([np.repeat(x[:1], 5, 0), x[:-5]]))
    msg = _refused(late, sc, "std below 0", force_lead=0.0, physical=False)
    assert ("the force lead given, +0 ms, leaves " in msg and "-5 ms, the best of the +-10 "
            "samples around 0" in msg and "let --force-lead auto estimate it; else forces of "
            "the wrong sign" in msg), msg  # fmt: skip
    assert "wrong force_lead" not in msg  # (said once)
    # on time, the same refusal names no lead
    msg = _refused(_with(noisy, tau=lambda x: -x), sc, "std below 0", force_lead=0.0)
    assert "force lead" not in msg and "forces of the wrong sign" in msg, msg


def test_notes_are_printed_and_noisy_lengths_get_one(tmp_path, exciting, noisy):
    """identify printed none of its notes (the report held them): a 5 % gain error on one
    force passed with a note in report.md only. And 5 um of encoder noise, which the docs
    say identification does not survive, passed without a word."""
    _, sc = exciting
    log = synthetic_log(sc, duration=10.0, quantise=True, q_noise=5e-6, tau_noise=1.0, seed=11)
    (note,) = identify(log, sc, physical=False).notes
    assert note.startswith("the lengths' noise, <= 4.") and "is over 2 um" in note, note
    assert not identify(noisy, sc, physical=False).notes
    _write_csv(tmp_path / "run.csv", log)
    r = _run("identify", "run.csv", "--out", "o", "--no-physical", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert f"warning: {note}" in " ".join(r.stderr.split()), r.stderr


def test_a_force_lead_reads_no_force_from_beyond_the_log(exciting):
    """Forces logged 0.2 s early (lead -0.2 s): the samples whose filter would need forces
    after the log's end are dropped (np.interp would repeat the last one), and the fit is
    exact; a lead that leaves too little of a 7 s log is refused, naming the range."""
    _, sc = exciting
    long = synthetic_log(sc, duration=12.0)  # the trajectory moves at 1 s and 11 s
    n, k = 10001, 1000
    early = Log(long.t[:n], long.q[k : k + n], long.tau[k - 200 : k - 200 + n], "early.csv")
    idn = identify(early, sc, force_lead=-0.2)
    obs = idn.observation
    half = obs.fir_taps // 2 / obs.sample_rate
    assert obs.t[-1] + half - (-0.2) <= early.t[-1] + 1e-9
    assert idn.wls.relative_error < 1e-8, idn.wls.relative_error
    lost = [v for why, v in obs.discarded.items() if why.startswith("force lead -0.2 s")]
    assert lost and lost[0] > 0 and sum(obs.discarded.values()) + obs.t.size == n
    short = synthetic_log(sc, duration=7.0)
    with pytest.raises(
        IdentificationError, match=r"force_lead = \+0.9 s shifts the forces"
    ) as info:
        identify(short, sc, force_lead=0.9)
    assert "allows |force_lead| <= 0." in str(info.value)


def _error_lines(r) -> list[str]:
    """stderr without the kernels' compile messages (another change to the model's source
    recompiles them)."""
    return [x for x in r.stderr.strip().splitlines() if not x.startswith("compil")]


def test_max_residual_option_and_refusals_write_nothing(tmp_path, exciting, noisy):
    _, sc = exciting
    # the library's is a fraction, checked before the fit (nan and -1 were refused after
    # it, 5.0 turned the gate off)
    for bad in (float("nan"), -1.0, 0.0, 5.0):
        with pytest.raises(IdentificationError, match=r"must be in \(0, 1\], a fraction"):
            identify(Log(noisy.t[:10], noisy.q[:10], noisy.tau[:10], "x"), sc, max_residual=bad)
    shaken = _with(noisy, tau=lambda x: x + 15.0 * np.sin(2 * np.pi * 7.3 * noisy.t)[:, None])
    _write_csv(tmp_path / "run.csv", shaken)
    r = _run("identify", "run.csv", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2 and len(_error_lines(r)) == 1, r.stderr
    assert "allowed <= --max-residual = 5 %" in r.stderr and "raise --max-residual" in r.stderr
    # the lead was the default 0, not searched: out-of-step forces are named too, with the
    # option that searches (a pkmctl log copied without its .json needed -0.25 ms, and the
    # message named only signs, units, columns and machines: a tester)
    assert "forces out of step with the lengths by a fraction of a sample" in r.stderr
    assert "try --force-lead auto;" in r.stderr, r.stderr
    assert not (tmp_path / "o").exists()
    for bad in ("0", "150", "nan"):
        r = _run("identify", "run.csv", "--out", "o", "--max-residual", bad, cwd=tmp_path)
        assert r.returncode == 2 and "must be in (0, 100] %" in r.stderr, r.stderr
    r = _run("identify", "run.csv", "--out", "o", "--max-residual", "20", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "o" / "controller_model.toml").is_file()


def test_a_json_beside_the_log_is_used_refused_or_said_to_be_foreign(tmp_path, exciting, noisy):
    """pkmctl's metadata whose scenario cannot be read: refused (falling back to prototype
    and saying there was no .json was false); a .json of something else: the default, and
    the report says why."""
    _write_csv(tmp_path / "run.csv", noisy)
    bad = "[controller_model]\ntheta_ext = [1.0, 2.0]\n"
    (tmp_path / "run.json").write_text(json.dumps({"scenario_toml": bad, "table": "run.csv"}))
    r = _run("identify", "run.csv", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2 and len(_error_lines(r)) == 1, r.stderr
    assert "'run.json', holds a scenario that cannot be read (controller_model.theta_ext" in (
        r.stderr
    )
    assert "--scenario" in r.stderr and not (tmp_path / "o").exists()
    # one line of TOML is TOML too (it was read as a file's name: "No such file")
    (tmp_path / "run.json").write_text(json.dumps({"scenario_toml": "garbage = [",
                                                   "table": "run.csv"}))  # fmt: skip
    r = _run("identify", "run.csv", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2 and len(_error_lines(r)) == 1, r.stderr
    assert "holds a scenario that cannot be read (" in r.stderr
    assert "No such file" not in r.stderr and "garbage" not in r.stderr.split("(", 1)[1], r.stderr
    (tmp_path / "run.json").write_text(json.dumps({"operator": "someone"}))
    r = _run("identify", "run.csv", "--out", "o", "--no-physical", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    said = "the default: no --scenario and 'run.json' beside the log is not pkmctl's metadata"
    assert said in " ".join((tmp_path / "o" / "report.md").read_text().split())
    # pkmctl's metadata of another table (run.parquet's, saved after run.csv): not this
    # log's machine (it labelled the log with that run's scenario, or refused the log
    # blaming its data); the default, and the report says why
    (tmp_path / "run.json").write_text(json.dumps({"scenario_toml": bad, "table": "run.parquet"}))
    r = _run("identify", "run.csv", "--out", "o2", "--no-physical", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    said = "no --scenario and 'run.json' beside the log describes 'run.parquet', not this log"
    assert said in " ".join((tmp_path / "o2" / "report.md").read_text().split())


def test_a_pkmctl_log_gets_the_force_lead_searched_by_default(tmp_path, exciting, noisy):
    """A pkmctl log's forces are commands held over a control period: the default lead 0
    biased the friction by several std (the next step ``excite`` printed). With pkmctl's
    .json beside the log the lead is now searched; a log without one keeps 0."""
    _, sc = exciting
    _write_csv(tmp_path / "run.csv", noisy)
    r = _run("identify", "run.csv", "--out", "o", "--no-physical", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "force lead" not in r.stderr
    assert json.loads((tmp_path / "o" / "estimate.json").read_text())["force_lead"] == 0.0
    meta = {"scenario_toml": sc.to_toml(), "table": "run.csv"}
    (tmp_path / "run.json").write_text(json.dumps(meta))
    r = _run("identify", "run.csv", "--out", "o", "--no-physical", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "force lead (auto, the default for a pkmctl log): " in r.stderr
    r = _run("identify", "run.csv", "--out", "o", "--no-physical", "--force-lead", "0",
             cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0 and "force lead" not in r.stderr, r.stderr
    # the .json given as the log (read_log follows its table): the .json "beside" it was
    # itself, naming run.csv, so it was called another table's, the lead was 0 and the
    # machine the default (a code reader)
    r = _run("identify", "run.json", "--out", "o", "--no-physical", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "force lead (auto, the default for a pkmctl log): " in r.stderr, r.stderr
    report = " ".join((tmp_path / "o" / "report.md").read_text().split())
    assert f"scenario {sc.name!r} (from 'run.json', beside the log)" in report, report


def test_a_validation_log_of_another_machine_is_said_so(tmp_path, exciting, noisy):
    """A tester validated on a log of another scenario (no rotors, no friction): 250 %,
    and nothing said that its .json named another machine."""
    _, sc = exciting
    _write_csv(tmp_path / "run.csv", noisy)
    _write_csv(tmp_path / "val.csv", noisy)
    for name, scenario in (("run", sc), ("val", sc.replace(**{"payload.mass": 5.0}))):
        meta = {"scenario_toml": scenario.to_toml(), "table": f"{name}.csv"}
        (tmp_path / f"{name}.json").write_text(json.dumps(meta))
    args = ["identify", "run.csv", "--out", "o", "--no-physical", "--validate", "val.csv"]
    r = _run(*args, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    said = (
        f"warning: --validate 'val.csv': its .json is of scenario {sc.name!r}, whose payload "
        "differs from"
    )
    assert said in " ".join(r.stderr.split()), r.stderr
    # the .json given as --validate: its own scenario, not "another table's" (a code reader)
    r = _run(*args[:-1], "val.json", cwd=tmp_path)
    assert r.returncode == 0 and said in " ".join(r.stderr.split()), r.stderr
    (tmp_path / "val.json").write_text((tmp_path / "run.json").read_text())
    r = _run(*args, cwd=tmp_path)
    assert r.returncode == 0 and "--validate" not in r.stderr, r.stderr
    # a validation log in kN: 9.99e+04 % without a word (the same machine's .json)
    _write_csv(tmp_path / "val.csv", _with(noisy, tau=lambda x: x / 1000.0))
    r = _run(*args, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    said = "warning: --validate 'val.csv': the estimate leaves 9.99e+04 % of its J^T tau"
    assert said in " ".join(r.stderr.split()), r.stderr


def test_excite_names_the_cutoff_its_harmonics_need(tmp_path):
    """Harmonics up to 12 Hz pass the parallel filter at 10 Hz at half their amplitude or
    less: excite says which --cutoff keeps 90 % of them, and times the log for it."""
    from pkmctl.ident.identify import MIN_HARMONIC_GAIN, cutoff_for, filter_gain

    cut = cutoff_for(12.0, 1000.0)
    assert filter_gain(10.0, 1000.0, 12.0) < 0.2  # the default cutoff removes most of it
    assert (
        filter_gain(cut, 1000.0, 12.0) >= MIN_HARMONIC_GAIN > filter_gain(cut - 0.1, 1000.0, 12.0)
    )
    assert cutoff_for(1.0, 1000.0) == 10.0  # the default, when it keeps them
    r = _run("excite", "--out", "e x.toml", "--harmonics", "3", "--base-frequency", "4",
             "--periods", "4", cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert f"identify DIR/pd.parquet --cutoff {cut:g}" in " ".join(r.stdout.split())
    # the file's name quoted, to paste (it ran "simulate e" for "e x.toml": a tester)
    assert "pkmctl simulate 'e x.toml' --controller pd" in " ".join(r.stdout.split())


def test_excite_on_a_slow_log_names_the_cutoff_identify_allows(tmp_path):
    """A 100 Hz log (prototype, logging.every = 10) allows --cutoff <= 2 Hz: excite printed
    plain `identify` (its 10 Hz default, refused) and timed the run for 10 Hz, so identify
    refused again for a run too short (a tester). It names the cutoff and the periods now."""
    import inspect

    from pkmctl import cli_identify
    from pkmctl.ident.identify import DEFAULT_CUTOFF, cutoff_for, max_cutoff

    assert inspect.signature(cli_identify.identify).parameters["cutoff"].default == DEFAULT_CUTOFF
    assert cutoff_for(1.0, 100.0) == max_cutoff(100.0) == 2.0
    slow = pkmctl.Scenario.builtin("prototype").replace(**{"logging.every": 10})
    (tmp_path / "slow.toml").write_text(slow.to_toml())
    r = _run("excite", "--scenario", "slow.toml", "--out", "ex.toml", "--harmonics", "3",
             "--base-frequency", "0.5", cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "identify DIR/pd.parquet --cutoff 2" in " ".join(r.stdout.split())
    said = " ".join(r.stderr.split())
    assert "too short for pkmctl identify at --cutoff 2 Hz" in said, said
    # a log (not a terminal) gets a line a random start: 20-30 s went unsaid (a tester)
    assert "(4 of 4 random starts done)" in said, said


def test_excite_says_which_limits_it_assumed_and_refuses_an_empty_scenario(tmp_path):
    """On the paper's ideal actuators (no limits) excite showed the prototype drive's
    limits as the scenario's; `--scenario ''` was the prototype, unsaid (a tester)."""
    from pkmctl.ident.excite import assumed_limits

    assert assumed_limits(pkmctl.Scenario.builtin("prototype")) is None
    note = assumed_limits(pkmctl.Scenario.builtin("paper"))
    assert note == (
        "the scenario's 'ideal' actuators state no force or speed limit: the design kept to "
        "the prototype drive's (force 2160 N, speed 0.833 m/s, before the margins)"
    )
    r = _run("excite", "--scenario", "", "--out", "ex.toml", cwd=tmp_path)
    assert r.returncode == 2 and not (tmp_path / "ex.toml").exists()
    assert r.stderr.strip().startswith("error: --scenario = '': must name a built-in"), r.stderr


def test_identify_leaves_a_first_compilation_out_of_its_time():
    """The report's "Identification took" counted a first compilation of the kernels."""
    import dataclasses
    import time

    import numba

    from pkmctl.ident import identify as m

    @dataclasses.dataclass(frozen=True)
    class Timed:
        seconds: float
        compile_seconds: float = 0.0

    def work(log, scenario, **options):
        t0 = time.perf_counter()
        numba.njit(lambda x: x + 1.5)(1.0)  # a compilation, as a cold cache would do
        time.sleep(0.05)  # and the identification's own work
        return Timed(time.perf_counter() - t0)

    t0 = time.perf_counter()
    out = m._compile_time_apart(work)(None, None)  # as identify is wrapped
    wall = time.perf_counter() - t0
    assert out.compile_seconds > 0.01 and 0.05 <= out.seconds < 0.05 + out.compile_seconds
    assert out.seconds + out.compile_seconds == pytest.approx(wall, abs=0.02)


def test_the_compile_clock_counts_overlapping_compilations_once():
    import time

    from pkmctl.ident.identify import _CompileClock

    clock = _CompileClock()
    clock("start", "a", 0.0)
    time.sleep(0.05)
    clock("start", "b", 0.0)  # another thread's, overlapping
    clock("end", "a", 0.05)
    time.sleep(0.05)
    clock("end", "b", 0.05)
    assert clock.seconds == pytest.approx(0.1, abs=0.02)


@pytest.mark.parametrize("q_noise", [0.0, 2e-6, 5e-6])
def test_the_lengths_noise_and_the_rate_cutoff_it_allows_are_reported(exciting, q_noise):
    """What the pose filter removes from smooth lengths is their noise: the white noise put
    in, and the quantisation's step/sqrt(12). The Coulomb columns' rates are filtered as
    high as 0.4 fs with quantisation alone, lower with 2 um of noise, and no lower than the
    pose filter with 5 um (docs/identification.md, step 2)."""
    from pkmctl.ident.identify import observe

    _, sc = exciting
    log = synthetic_log(sc, duration=10.0, quantise=True, q_noise=q_noise, seed=11)
    obs = observe(log, sc.plant())
    step = sc.plant_spec.screw_lead / sc.sensor.counts_per_rev
    assert obs.length_noise == pytest.approx(np.hypot(q_noise, step / np.sqrt(12)), rel=0.05)
    fs, fd = obs.sample_rate, obs.diff_cutoff
    expected = {0.0: 0.4 * fs, 5e-6: fd}.get(q_noise)
    if expected is None:
        assert fd < obs.rate_cutoff < 0.4 * fs
    else:
        assert obs.rate_cutoff == pytest.approx(expected, rel=1e-12)


def test_excite_predicts_the_forces_of_the_payload_too(proto):
    """excite predicted limb forces with Theta's machine alone: with 300 kg on the platform it
    reported 282 N (as with none) for a trajectory needing 3633 N, and the written run
    diverged (a tester). The payload's weight alone, at the pose the design starts from at
    rest, now bounds the peak it reports from below; the payload's forces themselves are
    checked against a point mass in tests/test_machine.py."""
    from pkmctl.ident.excite import _split

    loaded = proto.replace(**{"payload.mass": 60.0, "payload.offset": [0.02, 0.0, 0.05]})
    e = design_excitation(loaded, harmonics=3, restarts=1, max_iter=15)
    X0 = np.array([loaded.initial.X])
    plant = loaded.plant()
    at_rest = _split(plant.jacobian(X0), plant.gravity(X0[0])[None] + loaded.payload_forces(X0))
    bare = _split(plant.jacobian(X0), plant.gravity(X0[0])[None])
    assert np.abs(at_rest).max() > np.abs(bare).max() + 100.0  # 60 kg: ~150 N a limb more
    assert e.peak_force >= np.abs(at_rest).max()
    assert e.peak_force <= 0.5 * e.force_limit


def test_csv_files_as_other_tools_write_them_are_named(tmp_path):
    """A European CSV (';' and decimal commas), a log cut in its last line and t in ms
    got pyarrow's bare parse error or a rate message with no word of units (a tester)."""
    from pkmctl.ident.identify import read_log

    head = "t;q1;q2;q3;q4;tau1;tau2;tau3;tau4\n"
    (tmp_path / "eu.csv").write_text(head + "0;0,7;0,7;0,7;0,7;1,0;1,0;1,0;1,0\n" * 3)
    with pytest.raises(IdentificationError, match=r"separated by ';' \(the header: 't;q1;"):
        read_log(tmp_path / "eu.csv")
    rows = "".join(f"{k / 1000},0.7,0.7,0.7,0.7,1,1,1,1\n" for k in range(20))
    (tmp_path / "cut.csv").write_text("t,q1,q2,q3,q4,tau1,tau2,tau3,tau4\n" + rows + "0.02,0.7,0.")
    with pytest.raises(
        IdentificationError,
        match=r"the last line \(data row 21\) is incomplete, "
        r"3 of 9 columns: the file was cut short",
    ):
        read_log(tmp_path / "cut.csv")  # fmt: skip


def test_forces_clipped_by_the_logger_are_noted(exciting):
    """Forces clipped at +-280 N in 1-9 % of the samples passed every check and gave a
    platform of 1.2 kg for 12.75 (a tester). No check can tell them from the machine, but
    a column sitting exactly at its extremes is said; a clean log says nothing of it."""
    from pkmctl.ident.identify import _clipped

    _, sc = exciting
    log = _clean(sc)
    assert _clipped(log.tau) == ""
    top = np.quantile(np.abs(log.tau[:, 2]), 0.97)
    clipped = _with(log, tau=lambda tau: np.column_stack(
        [tau[:, :2], np.clip(tau[:, 2], -top, top), tau[:, 3:]]))  # fmt: skip
    said = _clipped(clipped.tau)
    assert said.startswith("tau3 is exactly ") and " % of the samples" in said, said
    # forces the logger quantised (0.1 % of the 2160 N rating, or 5 N) sit at their extremes
    # as often as at the levels next to them: they were called clipped (a code reader); so
    # quantised and then clipped, they are
    for step in (2.16, 5.0):
        quantised = step * np.round(log.tau / step)
        assert _clipped(quantised) == "", (step, _clipped(quantised))
        top = np.quantile(quantised[:, 2], 0.97)
        quantised[:, 2] = np.minimum(quantised[:, 2], top)
        assert _clipped(quantised).startswith(f"tau3 is exactly {top:g} N in 3"), step
    notes = identify(clipped, sc, force_lead=None).notes
    assert any(n.startswith("tau3 is exactly") and "clips the force" in n for n in notes), notes
