"""The one place that says how pkmctl compiles its numerical kernels.

- ``cache=True``: compiled code is kept on disk, not recompiled per run.
- ``nogil=True``: kernels release the GIL, so runs can share a process's cores.
- ``error_model="numpy"``: a division by zero gives inf/nan (caught by the loop's
  finiteness check) instead of a Python exception, so no branch guards each division.
- ``fastmath={"contract"}``: lets LLVM fuse a*b + c into one FMA (one rounding instead
  of two). No other fast-math flag: NaN and inf keep their meaning, and no
  reassociation changes results.

``@kernel(refcount=False)`` is for the hot loops, which only work on arrays their
caller allocated: Numba then emits no reference counting. With it on, every array an
(inlined) kernel receives or slices costs an atomic increment and decrement; in the
closed loop that is about 40 atomic operations per plant evaluation, 40 % of its time
(docs/performance.md). Such a kernel must not allocate (no ``np.empty``, no copies)
and must not return arrays. The switch is Numba's ``_nrt`` option, which Numba's own
library uses; if a Numba version lacks it, the kernels compile with reference
counting, give the same numbers, and are only slower.

Every other kernel says ``_nrt=True`` explicitly: a function compiled while Numba is
compiling a refcount-free caller would otherwise inherit its flags and fail to compile
if it allocates (the general FLC path does). Without the explicit flag that only shows
on a cold cache, depending on which kernel compiles first.
"""

from numba import njit
from numba.core.cpu import CPUTargetOptions

_CAN_SWITCH = hasattr(CPUTargetOptions, "_nrt")
#: Reference counting on, said explicitly (see the module docstring).
REFCOUNT = {"_nrt": True} if _CAN_SWITCH else {}
#: The options of a kernel without reference counting (empty if Numba cannot do that).
NO_REFCOUNT = {"_nrt": False} if _CAN_SWITCH else {}
JIT_OPTIONS = {
    "cache": True,
    "nogil": True,
    "error_model": "numpy",
    "fastmath": {"contract"},
} | REFCOUNT


def kernel(fn=None, *, refcount: bool = True, **extra):
    """``@kernel`` = ``@numba.njit(**JIT_OPTIONS)``; keyword arguments add options.

    ``refcount=False``: compile without reference counting (see the module docstring).
    """
    options = JIT_OPTIONS | (REFCOUNT if refcount else NO_REFCOUNT) | extra
    if fn is None:
        return lambda f: njit(**options)(f)
    return njit(**options)(fn)
