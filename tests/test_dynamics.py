"""Dynamics: the regressor identity (Pinocchio-style), Mdot - 2C skew, batches.

The independent body-by-body oracle (kinetic energy from finite-differenced body
positions and frames) lives in test_dynamics_oracle.py.
"""

import numpy as np
from conftest import random_poses


def _states(seed, n):
    rng = np.random.default_rng(seed)
    return rng, random_poses(rng, n), *(rng.normal(size=(n, 3)) for _ in range(3))


def test_regressor_identity_paper_theta(robot):
    _, X, Xd, Xr, Xrr = _states(10, 30)
    Y = robot.regressor(X, Xd, Xr, Xrr)
    M, C, G = robot.mass_matrix(X), robot.coriolis_matrix(X, Xd), robot.gravity(X)
    rhs = np.einsum("nij,nj->ni", M, Xrr) + np.einsum("nij,nj->ni", C, Xr) + G
    np.testing.assert_allclose(Y @ robot.theta, rhs, rtol=1e-12, atol=1e-11)


def test_regressor_identity_random_theta(robot):
    rng, X, Xd, Xr, Xrr = _states(11, 30)
    for _ in range(5):
        theta = robot.theta * rng.uniform(0.2, 5.0, size=36)
        other = robot.with_theta(theta, physical=False)
        Y = robot.regressor(X, Xd, Xr, Xrr)  # Y does not depend on theta
        rhs = (
            np.einsum("nij,nj->ni", other.mass_matrix(X), Xrr)
            + np.einsum("nij,nj->ni", other.coriolis_matrix(X, Xd), Xr)
            + other.gravity(X)
        )
        np.testing.assert_allclose(Y @ theta, rhs, rtol=1e-12, atol=1e-10)


def test_mdot_minus_2c_skew(robot):
    _, X, Xd, _, _ = _states(12, 20)
    h = 1e-6  # central difference of M along Xdot: error ~1e-10 relative
    for x, xd in zip(X, Xd, strict=True):
        Mdot = (robot.mass_matrix(x + h * xd) - robot.mass_matrix(x - h * xd)) / (2 * h)
        S = Mdot - 2 * robot.coriolis_matrix(x, xd)
        np.testing.assert_allclose(S + S.T, 0, atol=1e-7)


def test_inverse_dynamics_equals_regressor_at_state(robot):
    _, X, Xd, _, Xdd = _states(13, 10)
    np.testing.assert_allclose(
        robot.inverse_dynamics(X, Xd, Xdd),
        robot.regressor(X, Xd, Xd, Xdd) @ robot.theta,
        rtol=1e-12,
    )


def test_work_shapes_describe_make_work():
    from pkmctl.model.dynamics import WORK_SHAPES, make_work

    assert tuple(a.shape for a in make_work()) == WORK_SHAPES


def test_spd_solve_agrees_with_lapack_and_rejects_indefinite_matrices():
    """cholesky_solve3 (L D L^T with the pivots' reciprocals) against numpy's LU solve on
    random SPD matrices over twelve orders of condition number, and NaN, not a number,
    for a matrix that is not positive definite (as the square-root Cholesky gave)."""
    import numba

    from pkmctl.model.dynamics import cholesky_solve3

    solve = numba.njit(lambda A, b: cholesky_solve3(
        A[0, 0], A[0, 1], A[0, 2], A[1, 1], A[1, 2], A[2, 2], b[0], b[1], b[2]
    ))  # fmt: skip
    rng = np.random.default_rng(7)
    for cond in (1.0, 1e3, 1e6, 1e9, 1e12):
        for _ in range(200):
            Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            A = Q @ np.diag(np.geomspace(1.0, cond, 3) * rng.uniform(0.1, 10.0)) @ Q.T
            A = 0.5 * (A + A.T)
            b = rng.normal(size=3)
            x = np.array(solve(A, b))
            ref = np.linalg.solve(A, b)
            # the backward error is what a stable solve bounds: |A x - b| ~ eps |A| |x|
            resid = np.linalg.norm(A @ x - b) / (np.linalg.norm(A, 2) * np.linalg.norm(x))
            assert resid < 1e-14, (cond, resid)
            assert np.linalg.norm(x - ref) <= 1e-14 * cond * np.linalg.norm(ref) + 1e-300
    for A in (np.diag([1.0, -1.0, 1.0]), np.diag([0.0, 1.0, 1.0]),
              np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
              np.diag([1.0, 1.0, np.nan])):  # fmt: skip
        assert np.all(np.isnan(solve(A, np.ones(3)))), A


def _packed_ymm_fmas(fn, args) -> tuple[int, str]:
    """Packed double FMAs on ymm registers in ``fn``'s machine code, compiled afresh with
    the project's options (cached code has no assembly), and its LLVM IR."""
    import re

    import numba

    from pkmctl._jit import JIT_OPTIONS, NO_REFCOUNT

    fresh = numba.njit(**(JIT_OPTIONS | NO_REFCOUNT))(fn.py_func)
    fresh(*args)
    sig = fresh.signatures[0]
    asm = fresh.inspect_asm(sig)
    return len(re.findall(r"\bvfn?m(?:add|sub)\w*pd\b[^\n]*%ymm", asm)), fresh.inspect_llvm(sig)


def test_the_limb_loops_run_as_simd_lanes(robot):
    """dynamics, gravity and regressor kernels run their four limbs as the lanes of 256-bit
    vectors (docs/performance.md): the attribute asking for them is in the IR and, on a
    CPU with AVX2, the limb formulas are packed FMAs (a scalar limb loop has none)."""
    from test_lanes_model import _has_cpu_flag

    from pkmctl.model.dynamics import (
        dynamics_kernel,
        gravity_kernel,
        make_work,
        regressor_kernel,
    )

    g, th, w = robot.geometry, robot.theta, make_work()
    X, v = np.array([0.7, 0.1, -0.2]), np.array([0.1, 0.2, -0.3])
    M, Cv, G = np.empty((3, 3)), np.empty(3), np.empty(3)
    cases = {
        "dynamics": (dynamics_kernel, (g, th, X, v, v, w, M, Cv, G), 100),
        "gravity": (gravity_kernel, (g, th, X, w, G), 8),
        "regressor": (regressor_kernel, (g, X, v, v, v, w, np.empty((3, 36))), 100),
    }
    for name, (fn, args, least) in cases.items():
        packed, ir = _packed_ymm_fmas(fn, args)
        assert '"prefer-vector-width"="256"' in ir, name
        if _has_cpu_flag("avx2"):
            assert packed >= least, (name, packed)
