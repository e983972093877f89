"""The ranges `pkmctl excite` and `pkmctl identify` state for their options, at their
bounds: one line naming the option, its value and the range, exit 2, nothing written."""

import pytest
from typer.testing import CliRunner

from pkmctl.cli import app

runner = CliRunner()


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["excite", "--periods", "101"], "error: --periods = 101: must be in [1, 100]"),
        (["excite", "--harmonics", "21"], "error: --harmonics = 21: must be in [3, 20]"),
        (["identify", "ok.csv", "--force-lead", "1"],
         "error: --force-lead = 1: must be 'auto' or a time in (-1, 1) s"),
        (["identify", "ok.csv", "--force-lead=-1"],
         "error: --force-lead = -1: must be 'auto' or a time in (-1, 1) s"),
    ],
    ids=["periods-101", "harmonics-21", "force-lead-1", "force-lead-minus-1"],
)  # fmt: skip
def test_an_option_just_outside_its_range_is_one_line_exit_2(tmp_path, monkeypatch, args, line):
    header = "t,q1,q2,q3,q4,tau1,tau2,tau3,tau4\n"
    rows = "\n".join(f"{k * 1e-3},0.7,0.7,0.7,0.7,1,1,1,1" for k in range(30))
    (tmp_path / "ok.csv").write_text(header + rows + "\n")
    monkeypatch.chdir(tmp_path)
    out = "o" if args[0] == "identify" else "o.toml"
    res = runner.invoke(app, [*args, "--out", out])
    assert res.exit_code == 2, res.output
    assert res.stderr.strip().splitlines() == [line]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.csv"]
