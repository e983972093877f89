"""Time the compiled model kernels from compiled code (issue 2, point 6).

    python -m benchmarks.bench_model

Prints microseconds per evaluation of M, C and G together, and of the regressor, each
called in an njit loop as the closed loop calls them. Same code as ``pkmctl bench``.
"""

import argparse

from benchmarks.bench import bench_model

if __name__ == "__main__":
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()  # --help says what it measures; no option
    r = bench_model()
    print(f"M, C, G together : {r['mcg_us']:.3f} us per evaluation (budget 3 us)")
    print(f"regressor Y      : {r['regressor_us']:.3f} us per evaluation (budget 5 us)")
