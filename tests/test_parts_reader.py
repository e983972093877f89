"""A code reader's findings on the user-part machinery (pkmctl.parts): each lane keeps its
run's numbers; a registration that cannot run, or whose options or log name are wrong,
is refused in one line."""

from typing import NamedTuple

import numpy as np
import pytest

import pkmctl
from pkmctl.parts import get_part, stack_lanes


class _Mix(NamedTuple):
    kp: float


def _mix_step(p, state, work, y, ref, F):
    for i in range(3):
        F[i] = p.kp * 1e-3


def _mix_lanes(p, state, work, y, ref, F):
    for i in range(3):
        for lane in range(F.shape[1]):
            F[i, lane] = p.kp[lane] * 1e-3


pkmctl.register_controller("x-reader-mix", params=_Mix, build=lambda c: _Mix(1.0),
                           lanes={"step": _mix_lanes},
                           lane_work=lambda p, L: (np.empty((3, L)),))(_mix_step)  # fmt: skip


@pytest.mark.parametrize("kps", [[1000, 1000.75, 2.5], [1000.75, 1000, True], [3, 4, 5]])
def test_each_lane_of_a_stack_computes_what_its_run_computes_alone(kps):
    """A bundle's int in the first run (a TOML integer, say) made the stacked field int64
    for every lane: the other runs' 1000.75 ran as 1000."""
    part = get_part("controller", "x-reader-mix")
    lp, _, work = stack_lanes(part, [(_Mix(k), np.zeros(0), (np.empty(3),)) for k in kps])
    F = np.zeros((3, len(kps)))
    part.lanes["step"](lp, np.zeros((0, len(kps))), work, None, None, F)  # as Python
    for lane, kp in enumerate(kps):
        alone = np.zeros(3)
        part.functions["step"](_Mix(kp), np.zeros(0), (np.empty(3),), None, None, alone)
        assert np.array_equal(F[:, lane], alone), (lane, kp)
    if all(isinstance(k, int) for k in kps):  # integers stay integers
        assert lp.kp.dtype == np.int64


class _Counted(NamedTuple):
    kp: float


def _count_log(p, state, row):
    row[0] = state[0]


def _count_step(p, state, work, y, ref, F):
    state[0] += 1.0
    for i in range(3):
        F[i] = 0.0


def _count_log_lanes(p, state, row):
    for lane in range(row.shape[1]):
        row[0, lane] = state[0, lane]


def _count_lanes(p, state, work, y, ref, F):
    for lane in range(F.shape[1]):
        state[0, lane] += 1.0
        for i in range(3):
            F[i, lane] = 0.0


def test_a_lane_form_missing_for_one_of_the_parts_functions_is_refused_at_registration():
    """A lane step beside a scalar log registered and ran alone, then every simulate_many
    and campaign failed: "does not compile: no implementation of controller_log"."""
    from pkmctl.parts import PartError, names

    def register(**lanes):
        pkmctl.register_controller("x-reader-count", params=_Counted,
                                   build=lambda c: _Counted(1.0), state_size=1, log=_count_log,
                                   log_size=1, log_name="count",
                                   lane_work=lambda p, L: (np.empty((3, L)),),
                                   **lanes)(_count_step)  # fmt: skip

    with pytest.raises(PartError, match=r"^controller 'x-reader-count': lanes = \{'step'\}: "
                                        r"must give a lane form of every function the part "
                                        r"has \(here also: log\)$"):  # fmt: skip
        register(lanes={"step": _count_lanes})
    assert "x-reader-count" not in names("controller")
    register(lanes={"step": _count_lanes, "log": _count_log_lanes})  # both: taken
    assert set(get_part("controller", "x-reader-count").lanes) == {"step", "log"}


class _Opt(NamedTuple):
    k: float


def _opt_step(p, state, work, y, ref, F):
    for i in range(3):
        F[i] = 0.0


@pytest.mark.parametrize(
    ("option", "message"),
    [
        # listed among the options, then a TypeError naming _register
        ({"module": "my_module"}, r"unknown option 'module'; the options are adaptive, build, "),
        ({"builtin": True}, r"unknown option 'builtin'"),  # taken: a user part as pkmctl's own
        # replaced the decorated function without a word
        ({"step": lambda p, s, w, y, r, F: None}, r"step= is not an option: the decorated "
         r"function is its step; the options give its other functions \(log\)$"),
    ],
)  # fmt: skip
def test_options_pkmctl_sets_and_the_decorated_role_are_refused_in_one_line(option, message):
    from pkmctl.parts import PartError, names

    with pytest.raises(PartError, match=r"^controller 'x-reader-opt': " + message) as info:
        pkmctl.register_controller("x-reader-opt", params=_Opt, build=lambda c: _Opt(1.0),
                                   **option)(_opt_step)  # fmt: skip
    assert "\n" not in str(info.value)
    assert "x-reader-opt" not in names("controller")
    with pytest.raises(PartError, match=r"the options are (?!.*\bmodule\b)(?!.*\bbuiltin\b)"):
        pkmctl.register_controller("x-reader-opt", params=_Opt, stat_size=3)(_opt_step)


class _Logged(NamedTuple):
    k: float


def _logged_log(p, state, row):
    row[0] = 1.0


@pytest.mark.parametrize("log_name", ["x,y", "a b", "x" * 65, 3, "q\n"])
def test_a_log_name_is_checked_as_a_part_name(log_name):
    """A comma in log_name made a CSV whose header had more fields than its rows (pyarrow:
    "Expected 39 columns, got 37")."""
    from pkmctl.parts import PartError, names

    message = (
        r"^controller 'x-reader-log': log_name = .{1,60}: must be 1-64 letters, digits, "
        r"'_', '.' or '-', starting with a letter or digit \(or '': the part's name\)$"
    )
    with pytest.raises(PartError, match=message):
        pkmctl.register_controller(
            "x-reader-log",
            params=_Logged,
            build=lambda c: _Logged(1.0),
            log=_logged_log,
            log_size=1,
            log_name=log_name,
        )(_opt_step)
    assert "x-reader-log" not in names("controller")


def test_an_empty_log_name_is_the_parts_name():
    class _Default(NamedTuple):
        k: float

    pkmctl.register_controller(
        "x-reader-log-default",
        params=_Default,
        log=_logged_log,
        build=lambda c: _Default(1.0),
        log_size=1,
    )(_opt_step)
    assert get_part("controller", "x-reader-log-default").log_name == ""
