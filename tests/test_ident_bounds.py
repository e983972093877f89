"""Identification's checks at their bounds: rounding of the printed cutoffs, what is
refused (max_residual, excitation, negative masses, the mass ratio), the clipping note,
the lead note, the minimum duration, the base parameters' table, the report folder's
stale files (a tester's mutation round)."""

import re
from types import SimpleNamespace

import numpy as np
import pytest

from pkmctl.ident import identify as ident
from pkmctl.ident.base import PARAMETER_NAMES, BaseParameters
from pkmctl.ident.identify import IdentificationError, Log


def test_floor_g_keeps_a_value_already_at_its_digits_and_rounds_down_otherwise():
    assert ident.floor_g(10.0) == 10.0
    assert ident.floor_g(20.0) == 20.0
    assert ident.floor_g(6.6666667) == 6.66666
    assert ident.ceil_g(6.6666661) == 6.66667
    assert ident.ceil_g(10.0) == 10.0


def test_max_residual_zero_is_refused_before_any_work():
    log = Log(np.zeros(3), np.zeros((3, 4)), np.zeros((3, 4)), "run.csv")
    for bad in (0.0, -0.1, 1.5, float("nan")):
        with pytest.raises(IdentificationError) as exc:
            ident.identify(log, scenario=None, scenario_label="x", max_residual=bad)
        assert str(exc.value) == (
            f"max_residual = {bad!r}: must be in (0, 1], a fraction (the command's "
            "--max-residual is in %), or None for no gate"
        )


def test_a_force_column_clipped_in_4_percent_of_the_samples_is_named():
    rng = np.random.default_rng(0)
    tau = rng.normal(0, 100, (1000, 4))
    tau[:30, 2], tau[30:40, 2] = 280.0, -280.0
    tau = np.clip(tau, -280, 280)
    assert ident._clipped(tau) == "tau3 is exactly -280 or 280 N in 4.5 % of the samples"
    tau[:, 2] = np.clip(rng.normal(0, 50, 1000), -270, 270)
    tau[:5, 2] = 280.0  # 0.5 %: at most CLIPPED_SHARE, not said
    assert ident._clipped(tau) == ""


def _base(names, expressions=None):
    r = len(names)
    return BaseParameters(np.arange(r), np.eye(r, 48), tuple(names),
                          tuple(expressions or names), ("kg",) * r, 0.0)  # fmt: skip


def test_an_observation_matrix_one_rank_short_is_refused_naming_the_weakest():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(60, 5))
    A[:, 3] = 0.5 * A[:, 0]
    base = _base(["p1", "p2", "p3", "p4", "p5"])
    with pytest.raises(IdentificationError) as exc:
        ident.check_excitation("log 'x.csv'", base, A)
    assert re.fullmatch(
        r"log 'x.csv': no excitation: the observation matrix has rank 4 of 5 \(cond \S+\); "
        r"the trajectory does not move p4 \(use pkmctl excite\)",
        str(exc.value),
    )
    A[:, 3] = rng.normal(size=60)
    assert ident.check_excitation("log 'x.csv'", base, A) > 0


def test_minimum_duration_counts_parameters_plus_one_jackknife_blocks():
    # support: 2 (200 + 60 + 3) samples at 1 kHz; blocks: 31 of 2 / 10 s
    assert ident.minimum_duration(10.0, 30, 1000.0) == pytest.approx(0.526 + 31 * 0.2)


def test_a_lead_one_sample_from_the_best_gets_no_note():
    obs = SimpleNamespace(lead_check=(0.0, 0.001, 0.5), sample_rate=1000.0, force_lead=0.001)
    assert ident.lead_note(obs) == ""
    obs.force_lead = 0.002
    assert ident.lead_note(obs).startswith("the force lead given, +2 ms, leaves 50 % ")


def _fit(beta, std, rel=1e-3):
    beta, std = np.asarray(beta, float), np.asarray(std, float)
    return ident.Fit(beta, np.diag(std**2), std, np.ones(3), rel)


def _prior(m0=1.0):
    p = np.zeros(48)
    p[PARAMETER_NAMES.index("m_platform")] = m0
    return p


def test_a_mass_six_std_below_zero_is_refused():
    base = _base(["m_platform", "m_lower1"])
    ok = _fit([1.0, -4.9], [0.1, 1.0])
    ident._check_fit("log 'x.csv'", base, ok, None, _prior(), 0.05, (0.1, 10.0))
    bad = _fit([1.0, -6.0], [0.1, 1.0])
    with pytest.raises(IdentificationError) as exc:
        ident._check_fit("log 'x.csv'", base, bad, None, _prior(), 0.05, (0.1, 10.0))
    assert str(exc.value).startswith(
        "log 'x.csv': WLS gives m_lower1 = -6 kg, 6 std below 0 (a mass must be >= 0; "
        "allowed: at most 5 std below): forces of the wrong sign"
    )


def test_an_m_platform_at_the_mass_ratios_bounds_is_accepted():
    base = _base(["m_platform"])
    for ratio in (0.1, 10.0):
        ident._check_fit("log 'x.csv'", base, _fit([ratio], [0.01]), None, _prior(), 0.05,
                         (0.1, 10.0))  # fmt: skip
    with pytest.raises(IdentificationError) as exc:
        ident._check_fit("log 'x.csv'", base, _fit([0.09], [0.01]), None, _prior(), 0.05,
                         (0.1, 10.0))  # fmt: skip
    assert str(exc.value).startswith(
        "log 'x.csv': m_platform = 0.09 kg (WLS) is 0.09 x the scenario's prior 1 kg "
        "(allowed 0.1-10 x): forces in other units"
    )


def test_mass_ratio_none_turns_the_check_off():
    """``identify(..., mass_ratio=None)``, documented as no mass-ratio check, raised
    "cannot unpack non-iterable NoneType object" after the whole fit (a tester's
    mutation round found it)."""
    base = _base(["m_platform"])
    ident._check_fit("log 'x.csv'", base, _fit([0.01], [0.001]), None, _prior(), 0.05, None)


@pytest.mark.parametrize(
    "bad",
    [
        (2.0, 1.0),
        (float("nan"), 3.0),
        (1.0, float("nan")),
        (-1.0, 2.0),
        0.5,
        (1, 2, 3),
        (0.1, "10"),
        "19",
        (False, True),
    ],
)
def test_a_bad_mass_ratio_is_refused_before_any_work(bad):
    """A pair out of order or with a NaN passed every mass, or failed after the fit with
    a TypeError; it is refused first, in one line naming it."""
    log = Log(np.zeros(3), np.zeros((3, 4)), np.zeros((3, 4)), "run.csv")
    with pytest.raises(IdentificationError) as exc:
        ident.identify(log, scenario=None, scenario_label="x", mass_ratio=bad)
    assert str(exc.value) == (
        f"mass_ratio = {bad!r}: must be None (no check) or (low, high) with 0 <= low <= "
        "high, the identified m_platform's bounds as a multiple of the prior's (default "
        "(0.1, 10))"
    )


def test_the_base_parameters_table_numbers_from_1_and_writes_no_unit_coefficient():
    names, exprs = ("m_platform", "Ixx_upper1"), ("m_platform", "Ixx_upper1 + Ixx_lower1")
    b = BaseParameters(np.array([0, 1]), np.eye(2, 48), names, exprs, ("kg", "kg m^2"), 0.0)
    assert b.table().splitlines() == [
        "  1  m_platform  [kg]  m_platform",
        "  2  Ixx_upper1  [kg m^2]  Ixx_upper1 + Ixx_lower1",
    ]


def test_the_papers_base_parameters_write_unit_coefficients_as_plain_sums(robot):
    from pkmctl.ident.base import base_parameters

    b = base_parameters(robot)
    assert b.count == 30
    assert "Ixx_lower2 + Ixx_upper2" in b.expressions
    assert "Izz_lower4 - Iyy_lower4 - Iyy_upper4 + Izz_upper4" in b.expressions


def test_a_stale_output_that_is_a_dangling_symlink_is_removed_too(tmp_path):
    from pkmctl.ident.report import remove_stale

    (tmp_path / "target.md").write_text("x")
    (tmp_path / "report.md").symlink_to(tmp_path / "gone.md")  # points nowhere
    (tmp_path / "fit.png").write_text("old")
    (tmp_path / "estimate.json").write_text("new")
    gone = remove_stale(tmp_path, [tmp_path / "estimate.json"])
    assert sorted(p.name for p in gone) == ["fit.png", "report.md"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["estimate.json", "target.md"]
