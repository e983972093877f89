"""The compile options of the hot loops (pkmctl._jit)."""

import numpy as np
from numba import njit

import pkmctl
from pkmctl._jit import JIT_OPTIONS, NO_REFCOUNT
from pkmctl.controllers import control_step
from pkmctl.dynamics import dynamics_kernel, make_work
from pkmctl.simulation import _run_loop

_OPTS = JIT_OPTIONS | {"cache": False}


def _inner(geom, theta, X, Xd, n, work, M, Cv, G):
    acc = 0.0
    for k in range(n):
        X[2] = 0.1 * k
        dynamics_kernel(geom, theta, X, Xd, Xd, work, M, Cv, G)
        acc += M[0, 0] + Cv[0] + G[2]
    return acc


def _counted(geom, theta, X, Xd, n):
    """The loop as it was written before: arrays allocated in the same function."""
    work, M, Cv, G = make_work(), np.empty((3, 3)), np.empty(3), np.empty(3)
    acc = 0.0
    for k in range(n):
        X[2] = 0.1 * k
        dynamics_kernel(geom, theta, X, Xd, Xd, work, M, Cv, G)
        acc += M[0, 0] + Cv[0] + G[2]
    return acc


def test_this_numba_can_drop_reference_counting():
    assert NO_REFCOUNT == {"_nrt": False}


def test_hot_loops_are_compiled_without_reference_counting():
    assert _run_loop.targetoptions.get("_nrt") is False
    assert control_step.targetoptions.get("_nrt") is False


def test_no_refcount_removes_every_atomic_and_keeps_the_numbers():
    robot = pkmctl.Mechanism.paper()
    args = (robot.geometry, robot.theta, np.array([0.7, 0.1, -0.1]), np.array([0.1, 0.2, 0.3]), 3)
    counted = njit(**_OPTS)(_counted)
    fast = njit(**(_OPTS | NO_REFCOUNT))(_inner)
    plain = counted(*args)
    out = fast(*args, make_work(), np.empty((3, 3)), np.empty(3), np.empty(3))
    ir_counted = next(iter(counted.inspect_llvm().values()))
    ir_fast = next(iter(fast.inspect_llvm().values()))
    assert "call void @NRT_incref" in ir_counted  # the cost being removed exists ...
    assert "@NRT_incref" not in ir_fast and "@NRT_decref" not in ir_fast  # ... and is gone
    assert out == plain


def _all_kernels():
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher

    for mod in pkgutil.iter_modules(pkmctl.__path__):
        if mod.name == "__main__":
            continue
        m = importlib.import_module(f"pkmctl.{mod.name}")
        for name, obj in vars(m).items():
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == m.__name__:
                yield f"{m.__name__}.{name}", obj


def test_every_kernel_states_its_reference_counting():
    # A kernel first compiled from inside a refcount-free caller inherits the caller's
    # flags unless it states _nrt itself; if it allocates, it then fails to compile,
    # but only on a cold cache (this bit us once). So every kernel states it.
    kernels = dict(_all_kernels())
    assert len(kernels) > 30
    unstated = [name for name, k in kernels.items() if "_nrt" not in k.targetoptions]
    assert unstated == []
