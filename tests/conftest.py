import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen, before anything imports MuJoCo

import numpy as np
import pytest

import pkmctl

#: The 30 real .fis files (../shared/fis-corpus; test data, not in the repository).
CORPUS = Path(__file__).resolve().parents[2] / "shared" / "fis-corpus"
if not CORPUS.is_dir():
    CORPUS = Path("/work/shared/fis-corpus")


@pytest.fixture(scope="session", autouse=True)
def _validation_kernels_compiled() -> None:
    """Loading a scenario checks its poses with compiled kinematics; on an empty cache that
    compiles first, and the CLI says so on stderr. The one-line error tests of every file
    are about the error, on a machine that has compiled them (as after any first run)."""
    pkmctl.Scenario.builtin("paper")


@pytest.fixture(scope="session")
def robot() -> pkmctl.Mechanism:
    return pkmctl.Mechanism.paper()


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    """Valid poses spanning the paper's workspace (z 0.55-0.85 m, |angles| <= 0.6 rad)."""
    return np.column_stack(
        [rng.uniform(0.55, 0.85, n), rng.uniform(-0.6, 0.6, n), rng.uniform(-0.6, 0.6, n)]
    )
