"""A user part's Python hooks (``limits``, ``memory``, ``report``): what they raise or
return is named as that part's, in one line (a code reader: "ZeroDivisionError ... (an
internal error)", int()'s words for "lots", 100 % of a run "at the force limit" for
negative limits, and a controller's ``memory`` not counted at all)."""

import math
from typing import NamedTuple

import pytest

import pkmctl
from pkmctl.parts import PartError


def _cmd(p, state, work, y, F, cmd):
    for i in range(4):
        cmd[i] = 0.0


def _force(p, state, cmd, tau):
    for i in range(4):
        tau[i] = cmd[i]


def _actuator(name: str, **hooks) -> pkmctl.Scenario:
    class params(NamedTuple):  # a class of its own: one per part
        a: float

    pkmctl.register_actuator(name, params=params, build=lambda c: params(1.0), force=_force,
                             **hooks)(_cmd)  # fmt: skip
    return pkmctl.Scenario.builtin("paper").replace(**{"actuators.kind": name})


_NAMES: list[str] = []


@pytest.mark.parametrize(
    ("hook", "value", "said"),
    [
        ("limits", lambda p: 1 / 0, "limits failed: ZeroDivisionError: division by zero"),
        ("limits", lambda p: (-1.0, -1.0), "limits gave (-1.0, -1.0): must be two numbers > 0"),
        ("limits", lambda p: (math.nan, 1.0), "limits gave (nan, 1.0): must be two numbers > 0"),
        ("memory", lambda sc: 1 / 0, "memory failed: ZeroDivisionError: division by zero"),
        ("memory", lambda sc: "lots", "memory gave 'lots': must be a whole number of doubles"),
        ("memory", lambda sc: math.nan, "memory gave nan: must be a whole number of doubles"),
        ("memory", lambda sc: -5, "memory gave -5: must be a whole number of doubles"),
    ],
)
def test_a_hook_that_raises_or_gives_nonsense_is_named_before_the_run(hook, value, said):
    name = f"x-hook-{hook}-{len(_NAMES)}"
    _NAMES.append(name)
    sc = _actuator(name, **{hook: value})
    with pytest.raises(PartError) as info:
        pkmctl.simulate(sc, "pd", duration=0.001)
    assert str(info.value).startswith(f"actuator {name!r}: {said}"), str(info.value)


def test_a_controllers_memory_is_counted_by_the_memory_check():
    """``memory=`` on a controller was accepted and ignored: 8 GB a period ran."""

    class _C(NamedTuple):
        a: float

    hungry = pkmctl.register_controller(
        "x-hungry", params=_C, build=lambda c: _C(1.0), memory=lambda sc: 10**9
    )
    hungry(lambda p, state, work, y, ref, F: None)
    with pytest.raises(pkmctl.errors.InsufficientMemory, match=r"needs \d[\d.,]* [GT]iB"):
        pkmctl.simulate("paper", "x-hungry", duration=0.01)
    from pkmctl.sim.simulate import part_memory

    assert part_memory(pkmctl.Scenario.builtin("paper"), "x-hungry") == 10**9


def test_a_report_that_raises_or_is_not_a_dict_is_named_after_the_run():
    sc = _actuator("x-hook-report", report=lambda p, final: 5)
    with pytest.raises(
        PartError, match=r"^actuator 'x-hook-report': report gave 5: must be a dict"
    ):
        pkmctl.simulate(sc, "pd", duration=0.001)
