"""The one place that says how pkmctl compiles its numerical kernels.

- ``cache=True``: compiled code is kept on disk, not recompiled per run.
- ``nogil=True``: kernels release the GIL, so runs can share a process's cores.
- ``error_model="numpy"``: a division by zero gives inf/nan (caught by the loop's
  finiteness check) instead of a Python exception, so no branch guards each division.
- ``fastmath={"contract"}``: lets LLVM fuse a*b + c into one FMA (one rounding instead
  of two). No other fast-math flag: NaN and inf keep their meaning, and no
  reassociation changes results.
"""

from numba import njit

JIT_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy", "fastmath": {"contract"}}


def kernel(fn=None, **extra):
    """``@kernel`` = ``@numba.njit(**JIT_OPTIONS)``; keyword arguments add options."""
    options = JIT_OPTIONS | extra
    if fn is None:
        return lambda f: njit(**options)(f)
    return njit(**options)(fn)
