"""Speed of the paper's FLC against scikit-fuzzy and simpful (same code as ``pkmctl bench``).

python -m benchmarks.bench_fuzzy [--quick]
"""

import argparse

from benchmarks.fuzzy_bench import run

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer evaluations")
    run(quick=parser.parse_args().quick, echo=True)
