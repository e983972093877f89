"""The README's Python example runs as written (examples nothing tests go stale)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_blocks_run():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks
    for code in blocks:
        namespace: dict = {}
        exec(compile(code, str(README), "exec"), namespace)  # noqa: S102
    assert namespace["Y"].shape == (3, 36)
    assert set(namespace["result"].rmse()) >= {"z_mm", "alpha_deg", "beta_deg"}
    assert namespace["F"].shape == (3,)
    assert (namespace["again"].X == namespace["result"].X).all()
    assert namespace["baseline"].parts["controller"] == "ctc"


def test_readme_commands_match_ci():
    ci = (README.parent / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci in README.read_text()
