"""The public interface's type hints, as a user's type checker reads them.

pkmctl shipped no ``py.typed``: ``mypy --strict`` on any script that imports it stopped at
"missing library stubs or py.typed marker", every pkmctl name an ``Any``; read anyway,
some hints were wrong (a tester): ``save_result`` refused the README's ``str`` folder,
``q_measured`` was optional, ``register_controller`` made a typed step function untyped,
``simulate_many`` returned a bare ``list``, ``FLC()(s, sdot)`` no ``float``.
"""

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mypy")

ROOT = Path(__file__).resolve().parents[1]

USER = """
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

import pkmctl
from pkmctl.fuzzy import FLC

A = npt.NDArray[np.float64]
scenario = pkmctl.Scenario.builtin("paper")
result = pkmctl.simulate(scenario, controller="pd", duration=0.01)
table, meta = pkmctl.save_result(result, "folder")
again: pkmctl.Result = pkmctl.load_result(str(meta))
q_seen: A = result.q_measured
ends: dict[str, npt.NDArray[Any]] = result.final_state
runs: list[pkmctl.Result] = pkmctl.simulate_many(scenario, "pd", seeds=range(2))
rows: list[dict[str, Any]] = pkmctl.simulate_many(scenario, "pd", seeds=[1], keep="metrics")
u: float = FLC()(0.3, -2.0)
F: npt.NDArray[Any] = pkmctl.Controller.from_scenario("paper", "pd").step(
    np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
)


class MyLaw(NamedTuple):
    kp: A

    @classmethod
    def from_context(cls, ctx: pkmctl.PartContext) -> "MyLaw":
        return cls(ctx.gains.pd_kp)


@pkmctl.register_controller("my-typed-law", params=MyLaw)
def my_law(p: MyLaw, state: A, work: A, y: A, ref: A, F: A) -> None:
    for i in range(3):
        F[i] = p.kp[i] * (ref[i] - y[i])


step: Callable[[MyLaw, A, A, A, A, A], None] = my_law  # still the typed function
q = pkmctl.Mechanism.paper().inverse_kinematics([0.7, 0.0, 0.0])  # lists, as they run
X = pkmctl.Mechanism.paper().forward_kinematics(list(q), least_squares=True)


def forward(keep: str) -> list[pkmctl.Result] | list[dict[str, Any]]:
    return pkmctl.simulate_many(scenario, "pd", seeds=[1], keep=keep)  # a str passed on
"""


def _mypy(tmp_path: Path, name: str, text: str) -> subprocess.CompletedProcess:
    path = tmp_path / name
    path.write_text(text)
    return subprocess.run(
        [sys.executable, "-m", "mypy", "--strict", "--cache-dir", str(tmp_path / ".mypy"),
         str(path)],
        capture_output=True, text=True, cwd=tmp_path,
    )  # fmt: skip


def test_the_readme_and_a_typed_user_script_pass_mypy_strict(tmp_path):
    readme = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert readme, "README has no python block"
    for name, text in (("readme_block.py", readme[0]), ("user.py", USER)):
        res = _mypy(tmp_path, name, text)
        assert res.returncode == 0, f"{name}:\n{res.stdout}{res.stderr}"


def test_a_result_given_no_measured_arrays_has_the_true_ones():
    """``q_measured`` and the rest are arrays (DESIGN.md §11), hinted so: a Result made
    without them gets the truth, as ``load_result`` reads a file that did not save them."""
    import dataclasses

    import pkmctl

    r = pkmctl.simulate("paper", controller="pd", duration=0.01)
    bare = dataclasses.replace(r, X_measured=None, Xdot_measured=None, q_measured=None)
    assert bare.X_measured is r.X and bare.Xdot_measured is r.Xdot and bare.q_measured is r.q


def test_the_reprs_a_notebook_shows_are_short():
    """The dataclass reprs showed every array: an Identification was 108,480 characters,
    an Excitation wrote np.float64(...) for each number; a controller said only
    '<... AFSMC object at 0x...>' (a tester)."""
    import pkmctl
    from pkmctl.ident.excite import design_excitation
    from pkmctl.ident.identify import identify
    from pkmctl.ident.synthetic import synthetic_log

    sc = pkmctl.Scenario.builtin("prototype")
    exc = design_excitation(sc, harmonics=3, base_frequency=0.125, periods=1, restarts=1)
    text = repr(exc)
    assert text.startswith("Excitation(3 harmonics of 0.125 Hz") and "np.float64" not in text
    log = synthetic_log(exc.scenario(sc), tau_noise=1.0)  # 8 s
    idn = identify(log, sc)
    text = repr(idn)
    assert len(text) < 400 and "base parameters" in text and "cond" in text, text
    c = pkmctl.Controller.from_scenario("paper", "pd")
    assert repr(c) == "PD(name='pd', period=5e-05 s, 0 steps taken)"
