"""Scenario: built-ins, exact TOML round trip, one-line errors for bad input."""

import math
import re

import numpy as np
import pytest

import pkmctl
from pkmctl.sim.scenario import BUILTINS, Scenario, ScenarioError


def test_builtins_hold_the_paper_numbers():
    sc = Scenario.builtin("paper")
    assert sc.timing.control_period == 5e-5 and sc.timing.duration == 10.0
    assert sc.gains.lam == [50.0, 20.0, 20.0] and sc.gains.K == [1000.0, 200.0, 200.0]
    assert sc.gains.Lam == [150.0, 40.0, 40.0] and sc.gains.eps == 0.01
    assert sc.gains.Ku == [50.0, 30.0, 30.0] and sc.gains.Ksd == [0.5, 0.5, 0.5]
    assert sc.controller_model.theta_scale == 0.85
    assert sc.trajectory.amplitude == [0.02, math.pi / 6, math.pi / 6]
    assert sc.disturbance.amplitude == [2.0, 2.0, 2.0] and sc.disturbance.hold == 1e-3
    assert Scenario.builtin("paper-1khz").timing.control_period == 1e-3
    model = sc.controller_mechanism()
    assert (model.theta == 0.85 * sc.plant().theta).all()


@pytest.mark.parametrize("name", list(BUILTINS))
def test_builtin_with_a_duration_is_the_builtin_replaced(name):
    assert Scenario.builtin(name, 0.25) == Scenario.builtin(name).replace(
        **{"timing.duration": 0.25}
    )
    assert BUILTINS[name].get("timing", {}).get("duration") != 0.25  # the table unchanged
    with pytest.raises(ScenarioError, match="duration"):
        Scenario.builtin(name, -1.0)


@pytest.mark.parametrize("name", list(BUILTINS))
def test_toml_round_trip_exact(name):
    sc = Scenario.builtin(name)
    text = sc.to_toml()
    back = Scenario.from_toml(text)
    assert back == sc
    assert back.to_toml() == text


def test_an_identified_model_block_round_trips():
    """The [controller_model] block ``pkmctl identify`` writes (theta_ext) survives
    to_toml/from_toml, replace() and simulate_many's seeds: every one of them writes the
    block's other fields at their defaults, which the check against mixing them with
    theta_ext refused."""
    proto = Scenario.builtin("prototype")
    block = {"theta_ext": [*map(float, proto.plant().theta), *[10.9] * 4, *[30.0] * 4,
                           *[300.0] * 4]}  # fmt: skip
    sc = Scenario.builtin("prototype-tuned", 0.01).replace(controller_model=block)
    text = sc.to_toml()
    assert Scenario.from_toml(text) == sc and Scenario.from_toml(text).to_toml() == text
    assert sc.replace(**{"disturbance.seed": 3}).disturbance.seed == 3
    runs = pkmctl.simulate_many(sc, "pd", seeds=[0, 1])
    assert [r.info["steps"] for r in runs] == [10, 10]
    with pytest.raises(ScenarioError, match="theta_ext is given, so rotor_inertia"):
        sc.replace(**{"controller_model.rotor_inertia": 1e-5})


def test_replace_takes_numpy_values():
    """``replace`` with NumPy arrays and scalars (a loop over np.arange seeds, gains as an
    array): pydantic took neither ("Input should be a valid integer") until 2026-12-06."""
    sc = Scenario.builtin("paper")
    seeds = [sc.replace(**{"disturbance.seed": s}).disturbance.seed for s in np.arange(3)]
    assert seeds == [0, 1, 2] and all(type(s) is int for s in seeds)
    K = np.array([900.0, 150.0, 180.0])
    assert sc.replace(**{"gains.K": K}).gains.K == K.tolist()
    assert sc.replace(**{"initial.X": np.array([0.7, 0.0, 0.1])}).initial.X == [0.7, 0.0, 0.1]
    with pytest.raises(ScenarioError, match="disturbance.seed = True"):
        sc.replace(**{"disturbance.seed": np.bool_(True)})  # a flag is no seed
    with pytest.raises(ScenarioError, match=r"\[0, 2\^63 - 1\]$"):
        sc.replace(**{"disturbance.seed": np.bool_(True)})


def test_toml_file_round_trip(tmp_path):
    sc = Scenario.builtin("paper").replace(**{"disturbance.seed": 42, "timing.duration": 1.5})
    path = tmp_path / "s.toml"
    path.write_text(sc.to_toml())
    assert Scenario.from_toml(path) == sc


BAD = [
    (
        {"timing": {"control_period": -1.0}},
        "timing.control_period = -1.0: must be a finite number in [1e-06, 0.1] (s)",
    ),
    ({"timing": {"control_period": "fast"}}, "timing.control_period = 'fast'"),
    ({"timing": {"substeps": 0}}, "timing.substeps = 0"),
    ({"timing": {"duration": 0.0}}, "timing.duration = 0.0"),
    ({"timing": {"typo": 1}}, "timing.typo: unknown field (timing: control_period, substeps, "),
    ({"speed": 3}, "speed: unknown field (scenario: name, description, mechanism, "),
    ({"gains": {"lam": [50.0, 20.0]}}, "gains.lam"),
    ({"gains": {"K": [1000.0, -1.0, 200.0]}}, "gains.K[1] = -1.0: must be a finite number in [0, "),
    ({"gains": {"eps": 0.0}}, "gains.eps = 0.0"),
    ({"gains": {"theta_bounds": [2.0, 3.0]}}, "theta_bounds"),
    # the range each bound can take, not [0, 1e6] for both (0 then refused; a tester)
    (
        {"gains": {"theta_bounds": [-1.0, 10.0]}},
        "gains.theta_bounds[0] = -1.0: must be a finite number in (0, 1e+06] (multiples of "
        "Theta_0; lo in (0, 1], hi in [1, 1e+06])",
    ),
    (
        {"gains": {"theta_bounds": [5.0, 9.0]}},
        "gains.theta_bounds[0] = 5.0: must be a finite "
        "number in (0, 1] (multiples of Theta_0; lo in",
    ),
    ({"disturbance": {"seed": -1}}, "disturbance.seed = -1"),
    ({"disturbance": {"hold": 0.0}}, "disturbance.hold = 0.0"),
    # one value is held over each period: a shorter hold drew values no period read
    ({"disturbance": {"hold": 1e-300}}, "disturbance.hold = 1e-300: must be >= timing.contr"),
    # a control period typed in ms named only the hold, which the user had not changed; the
    # message offers both ways out (a tester)
    (
        {"timing": {"control_period": 0.05}},
        "disturbance.hold = 0.001: must be >= timing.control_period (0.05 s): the loop holds "
        "one value over each control period (or a timing.control_period <= 0.001 s)",
    ),
    ({"mechanism": {"r_a": 0.5}}, "need 0 < r_a < r_b"),
    # a long list's length, which the cut text hid (a tester)
    (
        {"mechanism": {"theta": [1.0] * 35}},
        "mechanism.theta = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, "
        "1.0, 1.0, 1.0, 1.0, 1.0, 1... (35 numbers): must be a list of 36 finite numbers",
    ),
    ({"controller_model": {"theta_scale": 0.0}}, "controller_model.theta_scale = 0.0"),
    ({"initial": {"X": [-0.1, 0.0, 0.0]}}, "initial.X"),
    ({"trajectory": {"offset": [0.7, 1.7, 0.0]}}, "trajectory: leaves the valid workspace"),
    ({"trajectory": {"offset": [0.7, 1.3, 0.0], "amplitude": [0.0, 0.0, 0.0]}}, "singularity"),
    ({"trajectory": {"kind": "spline"}}, "trajectory.kind = 'spline'"),
    ({"actuators": {"force_limit": -5.0}}, "actuators.force_limit = -5.0"),
    ({"name": "../x\n# heading"}, "name = '../x\\n# heading': must be one line of printable"),
    ({"name": "a\u2028b"}, "name = 'a\\u2028b': must be one line"),  # a line separator
    # a bidi override reorders what a report shows of the name (a fuzzer)
    ({"name": "\u202eevil"}, "name = '\\u202eevil': must be one line of printable text"),
]


@pytest.mark.parametrize(("data", "match"), BAD)
def test_bad_input_gives_one_line_error(data, match):
    with pytest.raises(ScenarioError) as info:
        Scenario.from_dict(data)
    msg = str(info.value)
    assert "\n" not in msg
    assert match in msg, msg


def test_bad_toml_and_unknown_builtin(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[timing\ncontrol_period = 1")
    with pytest.raises(ScenarioError, match="scenario TOML"):
        Scenario.from_toml(bad)
    with pytest.raises(ScenarioError, match="No such file"):
        Scenario.from_toml(tmp_path / "missing.toml")
    with pytest.raises(ScenarioError, match="unknown built-in"):
        Scenario.builtin("nope")
    with pytest.raises(ScenarioError, match="unknown field"):
        Scenario.builtin("paper").replace(**{"timing.nope": 1})
    assert isinstance(ScenarioError("x"), pkmctl.PkmctlError)


def _late_exit() -> dict:
    """A file whose beta reaches pi/2 at t = 5.93 s, valid over its first 5 s."""
    data = Scenario.builtin("paper").model_dump(by_alias=True, exclude_none=True)
    data["trajectory"].update(offset=[0.7, 0.0, 1.2], amplitude=[0.02, 0.5, 0.4],
                              omega=[2.0, 2.0, 0.2], phase=[0.0, 0.0, 0.0])  # fmt: skip
    return data


def test_changes_are_made_before_the_file_is_validated(tmp_path):
    """`simulate FILE --duration 0.5` checks the trajectory over 0.5 s, not the file's 10 s
    (it used to refuse a file whose trajectory leaves the workspace only after 5 s)."""
    import tomli_w

    path = tmp_path / "late.toml"
    path.write_text(tomli_w.dumps(_late_exit()))
    with pytest.raises(ScenarioError, match=r"leaves the valid workspace at t = 5\.93"):
        Scenario.from_toml(path)
    sc = Scenario.from_toml(path, {"timing.duration": 0.5, "disturbance.seed": 3})
    assert sc.timing.duration == 0.5 and sc.disturbance.seed == 3
    short = Scenario.builtin("paper", changes={"timing.duration": 0.5, "payload.mass": 1.0})
    assert short == Scenario.builtin("paper").replace(
        **{"timing.duration": 0.5, "payload.mass": 1.0}
    )
    with pytest.raises(ScenarioError, match=r"^nope\.x: unknown field \(sections: "):
        Scenario.from_toml(path, {"nope.x": 1})


def test_the_reference_is_checked_at_every_control_period():
    """beta grazing pi/2 between the scenario's 1 ms samples: refused as the trajectory's
    fault, naming the time, before the run (it used to run and end as "simulation diverged
    ... the pose left the valid set", as if the controller had failed)."""
    sc = Scenario.builtin("paper").replace(
        **{"trajectory.offset": [0.7, 0.0, 0.0], "trajectory.amplitude": [0.02, 0.0, 1.5707964268],
           "trajectory.omega": [2.0, 2.0, 2.0], "trajectory.phase": [0.0, 0.0, 0.0],
           "timing.duration": 1.0}
    )  # fmt: skip
    with pytest.raises(
        ScenarioError, match=r"^trajectory: leaves the valid workspace at t = 0\.785"
    ):
        pkmctl.simulate(sc, "pd")


# The tester's findings (pydantic's own words, one bound at best, no unit), as now worded.
REFUSALS = [
    ("gains.eps", 0.0, "gains.eps = 0.0: must be a finite number in (0, 1000]"),
    ("mechanism.r_a", math.nan, "mechanism.r_a = nan: must be a finite number in (0, 10] (m)"),
    (
        "timing.control_period",
        -1.0,
        "timing.control_period = -1.0: must be a finite number in [1e-06, 0.1] (s)",
    ),
    (
        "disturbance.amplitude",
        [5.0, 5.0],
        "disturbance.amplitude = [5.0, 5.0]: must be a list of 3 finite numbers in [0, 1e+06] "
        "(N, N m, N m for z, alpha, beta)",
    ),
    (
        "sensor.counts_per_rev",
        0,
        "sensor.counts_per_rev = 0: must be an integer in [1, 2^40] (counts per motor revolution)",
    ),
    (
        "actuators.force_limit",
        0,
        "actuators.force_limit = 0: must be a finite number in (0, 1e+09] (N), or left out",
    ),
    (
        "mechanism.l1",
        [0.1, math.nan, 0.1, 0.1],
        "mechanism.l1[1] = nan: must be a finite number in [0, 10] (m)",
    ),
    ("timing.duration", 0.0, "timing.duration = 0.0: must be a finite number in (0, 3600] (s)"),
    (
        "initial.Xdot",
        [0.0, 200.0, 0.0],
        "initial.Xdot[1] = 200.0: must be a finite number in [-100, 100] (rad/s)",
    ),
    ("sensor.seed", 1.5, "sensor.seed = 1.5: must be an integer in [0, 2^63 - 1]"),
]


@pytest.mark.parametrize(("field", "value", "message"), REFUSALS)
def test_refusal_gives_the_whole_range_and_the_unit(field, value, message):
    with pytest.raises(ScenarioError) as info:
        Scenario.builtin("paper", changes={field: value})
    assert str(info.value) == message


#: An allowed range as the messages write it: an interval "[0, 10]", "(0, 1e+06]",
#: "[0, 2^63 - 1]", or a choice.
RANGE = re.compile(r"[\[(][-+0-9.e^ ]+, [-+0-9.e^ ]+[\])]|one of ")


def _numeric(value) -> bool:
    if isinstance(value, list):
        return bool(value) and all(_numeric(v) for v in value)
    return isinstance(value, int | float) and not isinstance(value, bool)


def _numeric_fields(sc: Scenario) -> dict[str, object]:
    """Every numeric field of ``sc`` by dotted name: a number, a list of numbers (or of
    lists), or an optional one left out whose declared type holds a number."""
    out = {}
    for section, body in sc.model_dump(by_alias=True).items():
        if not isinstance(body, dict):
            continue
        model = type(getattr(sc, "plant_spec" if section == "plant" else section))
        for name, value in body.items():
            declared = str(model.model_fields[name].annotation)
            if _numeric(value) or (value is None and re.search(r"\b(float|int)\b", declared)):
                out[f"{section}.{name}"] = value
    return out


def _bad_values(value) -> list[tuple[object, str]]:
    """Out-of-range values for a field now at ``value``, each with the name the message
    must give (``field[i]`` for one element of a list)."""
    if not isinstance(value, list):
        return [(math.nan, ""), (-1, ""), (0, ""), (1e300, ""), ("x", "")]
    out: list[tuple[object, str]] = [(value + value[:1], ""), (value[:-1], ""), (3.0, "")]
    for i in (0, len(value) - 1):
        for bad in (math.nan, 1e300):
            row = list(value)
            row[i] = [bad] * len(row[i]) if isinstance(row[i], list) else bad
            out.append((row, f"[{i}]"))
    return out


def _fourier() -> Scenario:
    return Scenario.builtin("paper", 0.01).replace(
        trajectory={"kind": "fourier", "base_frequency": 0.5, "offset": [0.7, 0.0, 0.0],
                    "a": [[0.01, 0.0], [0.0, 0.1], [0.1, 0.0]],
                    "b": [[0.0, 0.0], [0.0, 0.0], [0.0, 0.1]]}
    )  # fmt: skip


@pytest.mark.parametrize("base", ["paper", "prototype", "fourier"])
def test_every_numeric_field_refuses_in_one_line_with_its_range(base):
    """Every numeric field of the built-ins (and of a Fourier trajectory), set out of its
    range (nan, -1, 0, 1e300, text, a list one too long or short, one bad element): the
    message is one line, names the field (an element as ``field[i]``) and gives the
    allowed range. A new field whose refusal gives only pydantic's words (one bound, no
    range) fails here."""
    sc = _fourier() if base == "fourier" else Scenario.builtin(base, 0.01)
    fields = _numeric_fields(sc)
    assert len(fields) > 40 and "logging.every" in fields and "fuzzy.samples" in fields
    bad = []
    for field, value in fields.items():
        ranged = 0
        for wrong, element in _bad_values(value):
            try:
                sc.replace(**{field: wrong})
            except ScenarioError as exc:
                msg = str(exc)
                named = re.match(re.escape(field + element) + r"(\[\d+\])* = ", msg)
                if "\n" in msg or not named:
                    bad.append(msg)
                elif RANGE.search(msg) and "should" not in msg:
                    ranged += 1
                elif "does not use it" not in msg:  # an in-range value on a kind without it
                    bad.append(msg)
        if not ranged:
            bad.append(f"{field}: no refusal with a range")
    assert not bad, "\n".join(bad)


def test_the_toml_names_every_field_left_unset_in_a_comment():
    """`pkmctl scenario paper` left out actuators.force_limit, fuzzy.fis, fuzzy.samples and
    controller_model.theta_ext (TOML has no null), though docs say it prints every field."""
    sc = pkmctl.Scenario.builtin("prototype")
    text = sc.to_toml()
    for section, key in (("actuators", "force_limit"), ("fuzzy", "fis"), ("fuzzy", "samples"),
                         ("controller_model", "theta_ext")):  # fmt: skip
        own = text.split(f"[{section}]\n", 1)[1].split("\n[", 1)[0]
        assert f"# {key} = (not set; optional)" in own
    assert pkmctl.Scenario.from_toml(text) == sc


def test_a_scenario_is_hashable_as_it_is_frozen():
    """pydantic's hash of a frozen model's values failed on its lists: a scenario could
    not be a dict key or in a set."""
    names = ("paper", "paper-1khz", "prototype", "prototype-model", "prototype-tuned")
    seen = {pkmctl.Scenario.builtin(n): n for n in names}
    assert len(seen) == len(names)
    for n in names:  # equal scenarios are the same key
        assert seen[pkmctl.Scenario.builtin(n)] == n
    paper = pkmctl.Scenario.builtin("paper")
    longer = paper.replace(**{"timing.duration": 1.0})
    assert longer != paper and longer not in seen
    assert pkmctl.Scenario.from_toml(paper.to_toml()) in seen  # read back: equal, same hash


def test_a_toml_error_quotes_the_line_it_points_at(tmp_path):
    """A key set twice said "Cannot overwrite a value (at line 84, column 11)", naming no
    key (a fuzzer); the line is quoted now, in a scenario and in a campaign spec."""
    from pkmctl.campaign.spec import CampaignSpec, SpecError

    text = pkmctl.Scenario.builtin("paper").to_toml()
    eps = next(line for line in text.splitlines() if line.startswith("eps = "))
    twice = text.replace(eps, f"{eps}\n{eps}", 1)
    with pytest.raises(pkmctl.ScenarioError) as info:
        pkmctl.Scenario.from_toml(twice)
    assert str(info.value).endswith(f"Cannot overwrite a value (at line "
                                    f"{twice.splitlines().index(eps) + 2}, column 11): "
                                    f"{eps!r}"), str(info.value)  # fmt: skip
    with pytest.raises(SpecError, match=r"\(at line 3, column \d+\): 'seeds = 2'$"):
        CampaignSpec.from_toml('scenario = "paper"\nseeds = 2\nseeds = 2\n')


def test_scenarios_share_no_section():
    """Every scenario without a [gains] section had one default GainsSpec (hashable, so
    pydantic did not copy it): `builtin("prototype").gains.lam[0] = 5` changed "paper"'s
    gains and the scenario of a finished run (a tester)."""
    a = pkmctl.Scenario.builtin("prototype")
    b = pkmctl.Scenario.builtin("paper")
    for name in pkmctl.Scenario.model_fields:
        x, y = getattr(a, name), getattr(b, name)
        assert x is not y or isinstance(x, str | int | float | type(None)), name
    a.gains.lam[0] = 5.0
    assert pkmctl.Scenario.builtin("paper").gains.lam[0] == 50.0 == pkmctl.Scenario().gains.lam[0]


def test_the_mujoco_step_limit_needs_no_mujoco(tmp_path):
    """The sub-step refusal read its limit from a module that needs MuJoCo: without it a
    1 ms step was accepted (a campaign client without MuJoCo, workers with it), and
    reading a scenario imported MuJoCo and set MUJOCO_GL (a review)."""
    import os
    import subprocess
    import sys

    code = (
        "import os, sys; sys.modules['mujoco'] = None\n"
        "import pkmctl\n"
        "sc = pkmctl.Scenario.builtin('paper')\n"
        "try:\n"
        "    sc.replace(**{'plant.kind': 'mujoco', 'timing.control_period': 1e-3})\n"
        "except pkmctl.ScenarioError as e:\n"
        "    print('refused:', e)\n"
        "sc.replace(**{'plant.kind': 'mujoco'})\n"
        "print('MUJOCO_GL' in os.environ)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("refused: timing.substeps = 1: with plant.kind = 'mujoco'"), lines
    assert lines[1] == "False"


def test_a_field_set_in_place_says_how_to_change_a_scenario():
    """Assigning a field gave pydantic's four-line error with a URL, no word of replace."""
    sc = pkmctl.Scenario.builtin("paper")
    with pytest.raises(
        TypeError,
        match=r"^GainsSpec\.lam = \[1, 2, 3\]: a scenario cannot be "
        r"changed in place; make a changed copy with scenario\.replace",
    ):
        sc.gains.lam = [1, 2, 3]  # fmt: skip
    assert sc.replace(name="x").name == "x"


def test_simulate_takes_a_toml_file_as_the_cli_does(tmp_path):
    """simulate("my.toml") said "unknown built-in", and a Path was a TypeError."""
    path = tmp_path / "my.toml"
    path.write_text(pkmctl.Scenario.builtin("paper").replace(name="mine").to_toml())
    for given in (path, str(path)):
        assert pkmctl.simulate(given, "pd", duration=0.01).scenario.name == "mine"
    with pytest.raises(pkmctl.ScenarioError, match="no.toml"):
        pkmctl.simulate(str(tmp_path / "no.toml"), "pd")
    from pkmctl.fuzzy.fis import FISError

    assert issubclass(FISError, pkmctl.PkmctlError)  # `except pkmctl.PkmctlError` catches it


def test_docs_field_reference_is_the_codes():
    """The fields' ranges were written nowhere but in the messages (a tester): the table
    in docs/architecture.md is field_reference()'s, and names every numeric field."""
    from pathlib import Path

    from pkmctl.sim.scenario import field_reference

    doc = (Path(__file__).resolve().parents[1] / "docs" / "architecture.md").read_text()
    begin, end = "<!-- field reference: begin -->\n", "<!-- field reference: end -->"
    table = doc[doc.index(begin) + len(begin) : doc.index(end)]
    assert table == field_reference()
    for base in ("paper", "prototype"):
        for field in _numeric_fields(Scenario.builtin(base)):
            assert f"| `{field}` |" in table or f"| `{field} (kind " in table, field
    assert "| `timing.duration` | a finite number in (0, 3600] | s |" in table
