"""The general engine's allocation-free kernel (issue 15, point 5): it compiles inside code
compiled without reference counting, so nothing on its path allocates, and gives the
Python evaluation's numbers bit for bit."""

from pathlib import Path

import numpy as np
import pytest

from pkmctl._jit import kernel
from pkmctl.fuzzy.fis import read_fis
from pkmctl.fuzzy.general import fis_eval2, new_work

CORPUS = Path(__file__).resolve().parents[2] / "shared" / "fis-corpus"
if not CORPUS.is_dir():
    CORPUS = Path("/work/shared/fis-corpus")
needs_corpus = pytest.mark.skipif(not CORPUS.is_dir(), reason="no .fis corpus")


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
