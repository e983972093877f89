"""Any loaded .fis system as the fuzzy term of FSMC/AFSMC (issue 15, point 5): the scenario's
``[fuzzy]`` section, the general engine's allocation-free kernel in the compiled loop, and
the one-line errors for files that cannot be the term."""

import dataclasses
import tomllib
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
import tomli_w
from conftest import CORPUS
from typer.testing import CliRunner

import pkmctl
from pkmctl._jit import kernel
from pkmctl.cli import app
from pkmctl.control.sliding import filter_sdot, sliding_surface
from pkmctl.fuzzy import FLC, FuzzySystem, MamdaniSystem, SystemTables
from pkmctl.fuzzy.fis import read_fis, to_fis_text
from pkmctl.fuzzy.general import fis_eval2, new_work
from pkmctl.fuzzy.term import term_eval, term_system, term_work
from pkmctl.model.dynamics import gravity_kernel, make_work
from pkmctl.parts import names
from pkmctl.sim.scenario import Scenario, ScenarioError

needs_corpus = pytest.mark.skipif(not CORPUS.is_dir(), reason="no .fis corpus")
PAPER_FIS = str(resources.files("pkmctl") / "fuzzy" / "data" / "paper_flc.fis")
# 2 inputs on [-1, 1], 1 output on [-1, 1], 25 rules, bisector: the general engine
TERM_FILE = "task4_bisector.fis"


def paper(duration: float) -> Scenario:
    return Scenario.builtin("paper").replace(**{"timing.duration": duration})


def scenario_toml(fis: str, duration: float = 0.01) -> str:
    """The paper's scenario as TOML with ``[fuzzy] fis = fis`` (written as given)."""
    data = tomllib.loads(paper(duration).to_toml())
    data["fuzzy"] = {"fis": fis}
    return tomli_w.dumps(data)


# ------------------------------------------------------------------ the kernel
@kernel(refcount=False)
def _eval_all(tables, work, X, out):
    """fis_eval2 from code compiled without reference counting: it compiles only if no
    kernel on its path allocates."""
    for n in range(X.shape[0]):
        out[n] = fis_eval2(tables, work, X[n, 0], X[n, 1])


@needs_corpus
@pytest.mark.parametrize(
    "name, options",
    [
        ("task4_bisector", {}),  # bisector
        ("bicopter_gbell", {}),  # gbellmf: panels and crossings
        ("matlab_tank", {"samples": 101}),  # prod/prod, MATLAB's sampled centroid
        ("sugeno_linear", {"input_range": "raw"}),  # Sugeno, linear terms
        ("plant_not", {}),  # NOT antecedents
    ],
)
def test_allocation_free_kernel_equals_the_python_evaluation(name, options):
    system = read_fis(CORPUS / f"{name}.fis", general=True, **options)
    lo = np.array([v.universe[0] for v in system.inputs])
    hi = np.array([v.universe[1] for v in system.inputs])
    X = np.random.default_rng(4).uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), (300, 2))
    out = np.empty(300)
    _eval_all(system.compiled(), new_work(system.compiled().ints), X, out)
    np.testing.assert_array_equal(out, system.evaluate(X)[:, 0])


def test_term_system_keeps_the_fast_path_and_refuses_other_shapes():
    flc = FLC()
    assert term_system(flc) is flc
    general = term_system(flc, engine="general")
    assert isinstance(general, FuzzySystem) and general.compiled().ints[0] == 2
    assert isinstance(term_system(flc, samples=101), FuzzySystem)
    g = FuzzySystem.from_mamdani(flc)
    three = g.replace(
        inputs=g.inputs + g.inputs[:1],
        rules=tuple(dataclasses.replace(r, antecedent=r.antecedent + (0,)) for r in g.rules),
    )
    with pytest.raises(ValueError, match=r"^x\.fis: 3 inputs and 1 output; the fuzzy term"):
        term_system(three, source="x.fis")
    with pytest.raises(ValueError, match="engine = 'fast'"):
        term_system(flc, engine="fast")
    assert isinstance(term_work(flc.compiled()), tuple)


# ------------------------------------------------------------------ (a) the paper's FLC as a file
def test_paper_flc_as_a_fis_file_is_the_builtin_bit_for_bit():
    """The file reads back as the same MamdaniSystem, compiled to the same tables: the
    loop is the built-in one (the same compiled code), hence identical numbers."""
    sc = paper(1.0)
    via_file = sc.replace(**{"fuzzy.fis": PAPER_FIS})
    assert isinstance(via_file.fuzzy_system(), MamdaniSystem)
    for c in ("fsmc", "afsmc"):
        ref = pkmctl.simulate(sc, controller=c)
        res = pkmctl.simulate(via_file, controller=c)
        for name in ("X", "Xdot", "F", "tau"):
            np.testing.assert_array_equal(getattr(res, name), getattr(ref, name))
        if c == "afsmc":
            np.testing.assert_array_equal(res.theta_hat, ref.theta_hat)


@pytest.mark.parametrize("controller", ["fsmc", "afsmc"])
def test_paper_flc_on_the_general_engine_agrees_to_rounding(controller):
    """The general engine integrates the same aggregate by another route (Gauss-Legendre
    between clip points and crossings found by bisection, against the fast kernel's closed
    form per cell): the FLC differs by <= 7e-16 (at two thirds of 1e5 random points), F by
    a few 1e-13 N, the pose not at all or by an ulp over a 10 s run (measured;
    docs/fuzzy.md). Checked here over 2 s."""
    sc = paper(2.0)
    general = sc.replace(**{"fuzzy.fis": PAPER_FIS, "fuzzy.engine": "general"})
    assert isinstance(general.fuzzy_system(), FuzzySystem)
    ref = pkmctl.simulate(sc, controller=controller)
    res = pkmctl.simulate(general, controller=controller)
    np.testing.assert_allclose(res.X, ref.X, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.F, ref.F, rtol=0, atol=1e-9)
    if controller == "afsmc":
        np.testing.assert_allclose(res.theta_hat, ref.theta_hat, rtol=1e-12, atol=0)


# ------------------------------------------------------------------ (b) a corpus file in the loop
class FuzzyProbe(NamedTuple):
    """PD plus the model's gravity plus a fuzzy term that logs its inputs and outputs."""

    geom: np.ndarray
    theta: np.ndarray
    lam: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    Ks: np.ndarray
    Ksd: np.ndarray
    Ku: np.ndarray
    Tc: float
    alpha_f: float
    flc: SystemTables

    @classmethod
    def from_context(cls, ctx):
        g = ctx.gains
        return cls(ctx.model.geometry, ctx.model.theta, g.lam, g.pd_kp, g.pd_kd, g.Ks, g.Ksd,
                   g.Ku, float(ctx.period), 1.0 / g.filter_periods,
                   term_system(ctx.flc, engine="general").compiled())  # fmt: skip


def _probe_work(p):
    return make_work(), np.empty(3), np.empty(3), np.empty(3), np.empty(3), term_work(p.flc)


def _probe_log(p, state, row):
    for k in range(9):
        row[k] = state[7 + k]  # the last step's (x1, x2, u) per axis


@pytest.fixture(scope="module")
def probe():
    if "fuzzy-probe" not in names("controller"):

        @pkmctl.register_controller("fuzzy-probe", params=FuzzyProbe, work=_probe_work,
                                    state_size=16, log=_probe_log, log_size=9,
                                    log_name="probe")  # fmt: skip
        def fuzzy_probe(p, state, work, y, ref, F):
            w, G, s, xr_d, xr_dd, fw = work
            sliding_surface(p.lam, y[0:3], y[3:6], ref[0:3], ref[3:6], ref[6:9], s, xr_d, xr_dd)
            filter_sdot(state, s, p.Tc, p.alpha_f)
            gravity_kernel(p.geom, p.theta, ref[0:3], w, G)
            for i in range(3):
                x1 = p.Ks[i] * s[i]
                x2 = p.Ksd[i] * state[3 + i]
                u = term_eval(p.flc, fw, x1, x2)  # the call of fsmc_step's fuzzy term
                state[7 + i], state[10 + i], state[13 + i] = x1, x2, u
                F[i] = p.kp[i] * (ref[i] - y[i]) + p.kd[i] * (ref[3 + i] - y[3 + i]) + G[i]
                F[i] -= p.Ku[i] * u

    return "fuzzy-probe"


@needs_corpus
def test_corpus_file_in_the_loop_equals_its_python_evaluation(probe):
    sc = paper(0.5).replace(**{"fuzzy.fis": str(CORPUS / TERM_FILE)})
    system = sc.fuzzy_system()
    assert isinstance(system, FuzzySystem) and system.defuzz_method == "bisector"
    res = pkmctl.simulate(sc, controller=probe)
    log = res.logs["probe"][1:]  # row k + 1 holds step k's values
    X1, X2, U = log[:, 0:3].reshape(-1), log[:, 3:6].reshape(-1), log[:, 6:9].reshape(-1)
    assert np.ptp(X1) > 0.5 and np.ptp(X2) > 0.5 and np.ptp(U) > 0.5  # the term worked
    np.testing.assert_array_equal(U, system.evaluate(np.stack([X1, X2], axis=1))[:, 0])
    # and FSMC and AFSMC run with it (the same kernel, the general engine's loops)
    for c in ("fsmc", "afsmc"):
        r = pkmctl.simulate(sc, controller=c)
        assert r.success and np.all(np.isfinite(r.X))


def test_a_controller_stepped_from_python_takes_a_fis_system():
    model = paper(0.01).controller_mechanism()
    X, Xd = np.array([0.7, 0.01, -0.02]), np.array([0.01, 0.05, -0.03])
    ref = (np.array([0.7005, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    forces = []
    for flc in (None, read_fis(PAPER_FIS, general=True)):
        ctrl = pkmctl.make_controller("fsmc", model, period=5e-5, flc=flc)
        forces.append([ctrl.step(X, Xd, *ref).copy() for _ in range(3)])
    assert isinstance(ctrl.flc, FuzzySystem)
    np.testing.assert_allclose(forces[1], forces[0], rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="3 inputs and 1 output"):
        g = FuzzySystem.from_mamdani(FLC())
        three = g.replace(
            inputs=g.inputs + g.inputs[:1],
            rules=tuple(dataclasses.replace(r, antecedent=r.antecedent + (0,)) for r in g.rules),
        )
        pkmctl.make_controller("fsmc", model, period=5e-5, flc=three)


# ------------------------------------------------------------------ the scenario option
def test_fis_path_is_relative_to_the_scenario_file_and_kept_absolute(tmp_path, monkeypatch):
    (tmp_path / "flc").mkdir()
    (tmp_path / "flc" / "mine.fis").write_text(to_fis_text(FLC()))
    toml = scenario_toml("flc/mine.fis")
    (tmp_path / "s.toml").write_text(toml)
    monkeypatch.chdir("/")
    sc = Scenario.from_toml(tmp_path / "s.toml")
    assert sc.fuzzy.fis == str(tmp_path / "flc" / "mine.fis")
    assert Scenario.from_toml(sc.to_toml()) == sc  # round trip
    assert sc.fuzzy_system() == FLC()
    monkeypatch.chdir(tmp_path)  # TOML text or a dict: relative to the working directory
    assert Scenario.from_toml(toml).fuzzy.fis == str(tmp_path / "flc" / "mine.fis")
    with pytest.raises(ScenarioError, match="fuzzy.engine"):
        sc.replace(**{"fuzzy.engine": "fastest"})
    raw = sc.replace(**{"fuzzy.input_range": "raw", "fuzzy.samples": 101}).fuzzy_system()
    assert (raw.input_range, raw.samples) == ("raw", 101)


def test_paper_flc_is_built_once_a_fis_file_read_each_time(tmp_path):
    sc = paper(0.01)
    assert sc.fuzzy_system() is sc.fuzzy_system()  # immutable: shared by every run
    raw = sc.replace(**{"fuzzy.input_range": "raw"})
    assert raw.fuzzy_system() is not sc.fuzzy_system() and raw.fuzzy_system().input_range == "raw"
    path = tmp_path / "mine.fis"
    path.write_text(Path(PAPER_FIS).read_text())
    via_file = sc.replace(**{"fuzzy.fis": str(path)})
    assert via_file.fuzzy_system() == FLC()
    changed = FLC()
    changed = dataclasses.replace(changed, rules=changed.rules[:-1])
    path.write_text(to_fis_text(changed))  # the same scenario now reads another system
    assert via_file.fuzzy_system() == changed


def _bad(tmp_path, name, text):
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def _error(path) -> str:
    with pytest.raises(ScenarioError) as info:
        paper(0.01).replace(**{"fuzzy.fis": str(path)})
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"fuzzy.fis: {path}")
    return msg


@needs_corpus
def test_files_that_cannot_be_the_term_are_refused_in_one_line(tmp_path):
    flc = to_fis_text(FLC())
    assert _error(CORPUS / "bank_choice4.fis").endswith(
        "bank_choice4.fis: 4 inputs and 1 output; the fuzzy term of FSMC/AFSMC takes 2 inputs "
        "(s*, sdot*) and 1 output"
    )
    assert "2 inputs and 2 outputs" in _error(CORPUS / "matlab_shower.fis")
    unsupported = flc.replace("'zmf'", "'custommf'", 1).replace("'centroid'", "'median'")
    msg = _error(_bad(tmp_path, "odd.fis", unsupported))
    assert "DefuzzMethod='median' is not supported" in msg and "(and 1 more problem)" in msg
    msg = _error(CORPUS / "frss_malformed.fis")
    assert "section names are case-sensitive" in msg and "(and 1 more problem)" in msg
    assert _error(tmp_path / "missing.fis").endswith("missing.fis: No such file or directory")
    assert "binary file" in _error(_bad(tmp_path, "b.fis", b"\x00\x01MATLAB 5.0 MAT-file"))


def test_cli_refuses_a_bad_fis_with_exit_2_before_running(tmp_path):
    fis = _bad(tmp_path, "odd.fis", to_fis_text(FLC()).replace("'zmf'", "'custommf'", 1))
    scenario = tmp_path / "s.toml"
    scenario.write_text(scenario_toml("odd.fis"))
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["simulate", str(scenario), "--controller", "fsmc",
                                   "--out", str(out)])  # fmt: skip
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and f"{fis}:" in lines[0] and "custommf" in lines[0], res.output
    assert not out.exists()


def test_each_kernel_refuses_the_other_engines_tables_at_compile_time():
    """FISTables and SystemTables differ in layout: flc_eval read a FuzzySystem's tables as
    a MamdaniSystem's and returned a wrong number (5.0 for the tipper at (3, 7), whose
    output is 12.2) without an error. Now each kernel refuses the other's tables."""
    from numba.core.errors import TypingError

    from pkmctl.fuzzy import flc_eval, mamdani_eval

    fast = FLC().compiled()
    general = FuzzySystem.from_mamdani(FLC()).compiled()
    assert isinstance(general, SystemTables)
    assert flc_eval(fast, 0.3, -2.0) == FLC()(0.3, -2.0)
    with pytest.raises(TypingError, match="these kernels take FISTables, not SystemTables"):
        flc_eval(general, 0.3, -2.0)
    with pytest.raises(TypingError, match="these kernels take FISTables, not SystemTables"):
        mamdani_eval(general, np.array([0.3, -2.0]))
    with pytest.raises(TypingError, match="these kernels take SystemTables, not FISTables"):
        fis_eval2(fast, new_work(general.ints), 0.3, -2.0)


# ------------------------------------------------------------------ (c) a term off 0 at rest
@needs_corpus
def test_a_fis_file_off_zero_at_rest_is_named_with_the_force_it_adds():
    """u_f = -Ku FLC(0, 0) when s = sdot = 0: a file whose output range is [0, 30] pushes
    even on the trajectory. The note gives FLC(0, 0) and that force; a file symmetric
    about 0, the paper's FLC and its .fis copy give none."""
    sc = paper(0.5).replace(**{"fuzzy.fis": str(CORPUS / "matlab_tipper.fis")})
    rest = float(sc.fuzzy_system()(0.0, 0.0))
    assert rest > 1.0  # tipper's output range is [0, 30]: its middle is far from 0
    note = sc.fuzzy_offset_note()
    assert note is not None and f"FLC(0, 0) = {rest:.4g}, not 0" in note
    push = [-k * rest for k in sc.gains.Ku]
    assert "[" + ", ".join(f"{f:.4g}" for f in push) + "]" in note, note
    assert paper(0.5).fuzzy_offset_note() is None
    for fis in (PAPER_FIS, str(CORPUS / "bicopter_trimf.fis")):
        s = paper(0.5).replace(**{"fuzzy.fis": fis})
        assert abs(float(s.fuzzy_system()(0.0, 0.0))) < 1e-12
        assert s.fuzzy_offset_note() is None


@needs_corpus
def test_cli_warns_of_an_offset_fis_for_fsmc_only(tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_text(scenario_toml(str(CORPUS / "matlab_tipper.fis")))
    for controller, warned in (("fsmc", True), ("afsmc-ext", True), ("smc", False)):
        res = CliRunner().invoke(app, ["simulate", str(scenario), "--controller", controller,
                                       "--out", str(tmp_path / controller)])  # fmt: skip
        assert res.exit_code == 0, res.output
        lines = [ln for ln in res.output.splitlines() if ln.startswith("warning: fuzzy.fis")]
        assert len(lines) == (1 if warned else 0), res.output


@needs_corpus
def test_the_fuzzy_controllers_are_those_whose_forces_the_fis_changes():
    """afsmc-ext ran the scenario's .fis with no offset warning: the warning asked
    ``controller in ("fsmc", "afsmc")``. FUZZY_CONTROLLERS, which the warning now asks,
    must be every built-in controller whose forces a .fis file changes, and only those."""
    from pkmctl import simulate
    from pkmctl.sim.scenario import FUZZY_CONTROLLERS

    base = paper(0.01)
    tipper = base.replace(**{"fuzzy.fis": str(CORPUS / "matlab_tipper.fis")})
    from pkmctl.parts import get_part

    builtin = [c for c in names("controller") if get_part("controller", c).builtin]
    changed = {
        c
        for c in builtin  # (not the parts other tests register in this process)
        if not np.array_equal(simulate(base, controller=c).tau, simulate(tipper, controller=c).tau)
    }
    assert changed == set(FUZZY_CONTROLLERS)
