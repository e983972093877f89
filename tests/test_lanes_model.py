"""The model kernels in lane form (pkmctl.model.lanes) against the scalar kernels.

Every lane must equal the scalar kernel run on that lane's numbers (geometry, Theta,
options and state all differ between lanes), within 1e-12 relative; L in {1, 3, 8, 11}
exercises a block of 8 lanes and the remainder. Besides the scalar reference, each
group checks one property of its own (M symmetric positive definite, Y Theta = M a +
C v + G, J^T tau = F, the equation of motion), and the compiled code is read to see
that it is vectorised. Speed is measured in benchmarks/lanes_model.py, never here.
"""

import os
import re
from pathlib import Path

import numba
import numpy as np
import pytest

from pkmctl._jit import JIT_OPTIONS, NO_REFCOUNT
from pkmctl.model.dynamics import (
    JQ,
    Q,
    actuator_forces_kernel,
    dynamics_kernel,
    gravity_kernel,
    make_work,
    regressor_kernel,
)
from pkmctl.model.kinematics import limb_jacobian
from pkmctl.model.lanes import (
    LANE_JQ,
    LANE_Q,
    lane_actuator_forces,
    lane_dynamics,
    lane_gravity,
    lane_limb_jacobian,
    lane_regressor,
    lane_rigid_derivative,
    lane_rigid_plant,
    make_lane_work,
)
from pkmctl.sim.plants import RigidPlant, _rigid_work, rigid_derivative, rigid_plant
from tests.conftest import random_poses

LANES = (1, 3, 8, 11)
TOL = 1e-12


def rel(a, b) -> float:
    """max |a - b| / max |b| (the error of a relative to the size of the reference b)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def col(a: np.ndarray, l: int) -> np.ndarray:
    """Lane l of a lane array, as a contiguous scalar-kernel argument."""
    return np.ascontiguousarray(a[..., l])


def draw(robot, L: int, seed: int):
    """L lanes of different machines and states: geometry within 5 %, every entry of
    Theta within 20 %, g within 1 %; valid poses; velocities of order 1."""
    rng = np.random.default_rng(seed)
    geom = robot.geometry[:, None] * rng.uniform(0.95, 1.05, (11, L))
    geom[10] = robot.geometry[10] * rng.uniform(0.99, 1.01, L)
    theta = robot.theta[:, None] * rng.uniform(0.8, 1.2, (36, L))
    X = random_poses(rng, L).T.copy()
    Xd, v, a = (rng.normal(size=(3, L)) for _ in range(3))
    return rng, np.ascontiguousarray(geom), np.ascontiguousarray(theta), X, Xd, v, a


# ---------------------------------------------------------------- dynamics, gravity
@pytest.mark.parametrize("L", LANES)
def test_dynamics_agrees_with_the_scalar_kernel(robot, L):
    _, geom, theta, X, Xd, v, _ = draw(robot, L, 10 + L)
    M, Cv, G, work = np.empty((3, 3, L)), np.empty((3, L)), np.empty((3, L)), make_lane_work(L)
    lane_dynamics(geom, theta, X, Xd, v, work, M, Cv, G)
    w, m, c, g = make_work(), np.empty((3, 3)), np.empty(3), np.empty(3)
    for l in range(L):
        args = (col(geom, l), col(theta, l), col(X, l), col(Xd, l), col(v, l))
        dynamics_kernel(*args, w, m, c, g)
        assert rel(M[..., l], m) < TOL
        assert rel(Cv[:, l], c) < TOL
        assert rel(G[:, l], g) < TOL
        assert rel(work[LANE_JQ][..., l], w[JQ]) < TOL
        assert rel(work[LANE_Q][:, l], w[Q]) < TOL
        # a property of its own: M symmetric (exactly: mirrored) and positive definite
        assert np.array_equal(M[..., l], M[..., l].T)
        assert np.linalg.eigvalsh(M[..., l]).min() > 0.0


@pytest.mark.parametrize("L", LANES)
def test_gravity_agrees_with_the_scalar_kernel(robot, L):
    _, geom, theta, X, _, _, _ = draw(robot, L, 20 + L)
    G, work = np.empty((3, L)), make_lane_work(L)
    lane_gravity(geom, theta, X, work, G)
    w, g = make_work(), np.empty(3)
    M, Cv, G2 = np.empty((3, 3, L)), np.empty((3, L)), np.empty((3, L))
    zero = np.zeros((3, L))
    lane_dynamics(geom, theta, X, zero, zero, make_lane_work(L), M, Cv, G2)
    for l in range(L):
        gravity_kernel(col(geom, l), col(theta, l), col(X, l), w, g)
        assert rel(G[:, l], g) < TOL
        assert rel(work[LANE_JQ][..., l], w[JQ]) < TOL
        assert rel(work[LANE_Q][:, l], w[Q]) < TOL
    assert rel(G, G2) < 1e-14  # the G of the dynamics, summed another way
    assert np.array_equal(Cv, np.zeros((3, L)))  # at rest, no velocity terms


# ---------------------------------------------------------------- the regressor
@pytest.mark.parametrize("L", LANES)
def test_regressor_agrees_with_the_scalar_kernel(robot, L):
    rng, geom, theta, X, Xd, Xr_d, Xr_dd = draw(robot, L, 30 + L)
    Y, work = np.empty((3, 36, L)), make_lane_work(L)
    lane_regressor(geom, X, Xd, Xr_d, Xr_dd, work, Y)
    w, y = make_work(), np.empty((3, 36))
    for l in range(L):
        regressor_kernel(col(geom, l), col(X, l), col(Xd, l), col(Xr_d, l), col(Xr_dd, l), w, y)
        assert rel(Y[..., l], y) < TOL
        assert rel(work[LANE_JQ][..., l], w[JQ]) < TOL
    # a property of its own: Y Theta = M Xr_dd + C(X, Xd) Xr_d + G, lane by lane, with
    # the lane dynamics (C(X, Xd) Xr_d is the dynamics with v = Xr_d)
    M, Cv, G = np.empty((3, 3, L)), np.empty((3, L)), np.empty((3, L))
    lane_dynamics(geom, theta, X, Xd, Xr_d, make_lane_work(L), M, Cv, G)
    lhs = np.einsum("ikl,kl->il", Y, theta)
    rhs = np.einsum("ijl,jl->il", M, Xr_dd) + Cv + G
    for l in range(L):
        assert rel(lhs[:, l], rhs[:, l]) < 1e-12


# ---------------------------------------------------------------- limbs and forces
@pytest.mark.parametrize("L", LANES)
def test_limb_jacobian_and_actuator_forces_agree(robot, L):
    rng, geom, _, X, _, _, _ = draw(robot, L, 40 + L)
    Jq, q = np.empty((4, 3, L)), np.empty((4, L))
    lane_limb_jacobian(geom, X, make_lane_work(L), Jq, q)
    F = rng.normal(scale=100.0, size=(3, L))
    tau = np.empty((4, L))
    lane_actuator_forces(Jq, F, tau)
    R, j1, q1, t1 = np.empty((3, 3)), np.empty((4, 3)), np.empty(4), np.empty(4)
    for l in range(L):
        limb_jacobian(col(geom, l), col(X, l), R, j1, q1)
        assert rel(Jq[..., l], j1) < TOL
        assert rel(q[:, l], q1) < TOL
        actuator_forces_kernel(col(Jq, l), col(F, l), t1)
        assert rel(tau[:, l], t1) < TOL
        # a property of its own: J^T tau = F, and tau = J y (the minimum-norm solution)
        assert rel(Jq[..., l].T @ tau[:, l], F[:, l]) < 1e-12
        y = np.linalg.lstsq(Jq[..., l], tau[:, l], rcond=None)[0]
        assert rel(Jq[..., l] @ y, tau[:, l]) < 1e-12


# ---------------------------------------------------------------- the rigid plant
def plants(robot, L: int, rng) -> list[RigidPlant]:
    """L plants of different machines: lane l has options by l % 6 (none; rotor inertia;
    friction; a payload; all of them; and "machine" off with option values set, which
    must run the rigid model), each with its own numbers."""
    out = []
    for l in range(L):
        kind = l % 6
        kw = {}
        if kind in (1, 4):
            kw["rotor_inertia"] = rng.uniform(1e-5, 5e-5)
        if kind in (2, 4):
            kw["friction_coulomb"] = rng.uniform(5.0, 40.0)
            kw["friction_viscous"] = rng.uniform(50.0, 400.0)
            kw["friction_velocity"] = rng.uniform(5e-4, 5e-3)
        if kind in (3, 4):
            kw["payload_mass"] = rng.uniform(0.5, 3.0)
            kw["payload_offset"] = rng.uniform(-0.05, 0.05, 3)
        p = rigid_plant(robot, **kw)
        if kind == 5:  # option values present, the switch off: the rigid model
            p = rigid_plant(robot, rotor_inertia=3e-5, friction_coulomb=9.0, payload_mass=1.0)
            p = p._replace(machine=0.0)
        geom = robot.geometry * rng.uniform(0.95, 1.05, 11)
        geom[10] = robot.geometry[10]
        out.append(p._replace(geom=geom, theta=robot.theta * rng.uniform(0.8, 1.2, 36)))
    return out


def derivative_case(robot, L: int, seed: int):
    rng = np.random.default_rng(seed)
    ps = plants(robot, L, rng)
    x = np.ascontiguousarray(
        np.vstack([random_poses(rng, L).T, rng.normal(scale=0.5, size=(3, L))])
    )
    tau = rng.normal(scale=80.0, size=(4, L))
    dist = rng.normal(scale=5.0, size=(3, L))
    return ps, x, tau, dist


@pytest.mark.parametrize("L", LANES)
def test_rigid_derivative_agrees_with_the_scalar_plant(robot, L):
    ps, x, tau, dist = derivative_case(robot, L, 50 + L)
    p = lane_rigid_plant(ps)
    assert p.geom.shape == (11, L) and p.m_r.shape == (4, L) and p.v_s.shape == (L,)
    dx, work = np.empty((6, L)), make_lane_work(L)
    lane_rigid_derivative(p, x, tau, dist, work, dx)
    d1 = np.empty(6)
    for l in range(L):
        w = _rigid_work(ps[l])
        rigid_derivative(ps[l], col(x, l), col(tau, l), col(dist, l), w, d1)
        assert rel(dx[:, l], d1) < TOL, f"lane {l} (options {l % 6})"
        assert np.array_equal(dx[:3, l], x[3:, l])
        assert rel(work[LANE_JQ][..., l], w[0][JQ]) < TOL
        assert rel(work[LANE_Q][:, l], w[0][Q]) < TOL


def test_rigid_lanes_keep_the_rigid_result_bit_for_bit(robot):
    """A lane with the options off gives, in a block whose other lanes run them, exactly
    what it gives in a block of rigid lanes (a select, not a multiplication by zero)."""
    L = 11
    ps, x, tau, dist = derivative_case(robot, L, 60)
    dx_mixed, dx_rigid = np.empty((6, L)), np.empty((6, L))
    lane_rigid_derivative(lane_rigid_plant(ps), x, tau, dist, make_lane_work(L), dx_mixed)
    rigid = [p._replace(machine=0.0) for p in ps]
    lane_rigid_derivative(lane_rigid_plant(rigid), x, tau, dist, make_lane_work(L), dx_rigid)
    off = [l for l in range(L) if ps[l].machine == 0.0]
    assert len(off) >= 3
    assert np.array_equal(dx_mixed[:, off], dx_rigid[:, off])
    on = [l for l in range(L) if ps[l].machine > 0.0]
    assert np.all(np.abs(dx_mixed[3:, on] - dx_rigid[3:, on]) > 0.0)


def test_rigid_derivative_solves_the_equation_of_motion(robot):
    """For rigid lanes: M Xddot + C Xdot + G = J^T tau + tau_d', with the lane dynamics."""
    L = 8
    ps, x, tau, dist = derivative_case(robot, L, 70)
    ps = [p._replace(machine=0.0) for p in ps]
    p = lane_rigid_plant(ps)
    dx, work = np.empty((6, L)), make_lane_work(L)
    lane_rigid_derivative(p, x, tau, dist, work, dx)
    M, Cv, G = np.empty((3, 3, L)), np.empty((3, L)), np.empty((3, L))
    X, Xd = np.ascontiguousarray(x[:3]), np.ascontiguousarray(x[3:])
    lane_dynamics(p.geom, p.theta, X, Xd, Xd, make_lane_work(L), M, Cv, G)
    lhs = np.einsum("ijl,jl->il", M, dx[3:]) + Cv + G
    rhs = np.einsum("ril,rl->il", work[LANE_JQ], tau) + dist
    for l in range(L):
        assert rel(lhs[:, l], rhs[:, l]) < 1e-12


def test_lane_rigid_plant_stacks_the_bundles(robot):
    ps = plants(robot, 4, np.random.default_rng(1))
    p = lane_rigid_plant(ps)
    for name in RigidPlant._fields:
        for l, q in enumerate(ps):
            np.testing.assert_array_equal(getattr(p, name)[..., l], getattr(q, name))
        assert getattr(p, name).flags.c_contiguous
    with pytest.raises(ValueError, match="no plants"):
        lane_rigid_plant([])


# ---------------------------------------------------------------- it vectorises
def _has_cpu_flag(flag: str) -> bool:
    """Whether /proc/cpuinfo lists ``flag`` (e.g. avx2, avx512f); False elsewhere."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return bool(re.search(rf"^flags\s*:.*\b{flag}\b", text, flags=re.M))


def fma_counts(fn, args) -> tuple[int, int]:
    """(packed double FMAs on ymm/zmm registers, scalar double FMAs) in the machine code
    of ``fn`` compiled afresh with the project's options (cached code has no assembly)."""
    fresh = numba.njit(**(JIT_OPTIONS | NO_REFCOUNT))(fn.py_func)
    fresh(*args)
    asm = fresh.inspect_asm(fresh.signatures[0])
    packed = len(re.findall(r"\bvfn?m(?:add|sub)\w*pd\b[^\n]*%[yz]mm", asm))
    scalar = len(re.findall(r"\bvfn?m(?:add|sub)\w*sd\b", asm))
    return packed, scalar


def _derivative_args(robot, L):
    ps, x, tau, dist = derivative_case(robot, L, 80)
    return (lane_rigid_plant(ps), x, tau, dist, make_lane_work(L), np.empty((6, L)))


def _regressor_args(robot, L):
    _, geom, _, X, Xd, v, a = draw(robot, L, 81)
    return (geom, X, Xd, v, a, make_lane_work(L), np.empty((3, 36, L)))


_KERNELS = {
    "rigid_derivative": (lane_rigid_derivative, _derivative_args),
    "regressor": (lane_regressor, _regressor_args),
}


@pytest.mark.slow
@pytest.mark.skipif(not _has_cpu_flag("avx2"), reason="no AVX2 on this CPU")
@pytest.mark.parametrize("name", list(_KERNELS) if os.environ.get("PKMCTL_FULL") else ["regressor"])
def test_lane_kernels_are_vectorised(robot, name):
    """The heavy loops run on vector registers: every FMA of them is there in packed form
    (the scalar FMAs that remain are the copy of each loop for a last, partial block).
    CI: the controller's regressor (a fresh compile: 48 s on a busy 2-core Xeon, where the
    plant's derivative took 89 s); PKMCTL_FULL=1: the plant's derivative too."""
    fn, make_args = _KERNELS[name]
    packed, scalar = fma_counts(fn, make_args(robot, 8))
    assert packed >= 600 and packed >= scalar, (packed, scalar)


def test_wide_vectors_asks_llvm_for_512_bit_vectors():
    """wide_vectors() marks its function for 512-bit vectors: the attribute is in the IR,
    and on an AVX-512 CPU the loop runs on zmm registers (LLVM's tuning for some of them
    would choose ymm)."""
    from pkmctl.model.lanes import wide_vectors

    def axpy(a, x, y, n):
        wide_vectors()
        for i in range(n):
            y[i] += a * x[i]

    fn = numba.njit(**(JIT_OPTIONS | NO_REFCOUNT))(axpy)
    x = np.arange(8.0)
    y = np.ones(8)
    fn(2.0, x, y, 8)
    np.testing.assert_array_equal(y, 1.0 + 2.0 * np.arange(8.0))
    sig = fn.signatures[0]
    assert '"prefer-vector-width"="512"' in fn.inspect_llvm(sig)
    if _has_cpu_flag("avx512f"):
        assert re.search(r"\bv\w+pd\b[^\n]*%zmm", fn.inspect_asm(sig))


def test_disjoint_arrays_spares_llvm_its_overlap_checks():
    """disjoint_arrays() marks its function's array arguments noalias: the loop below is
    vectorised without the run-time overlap check LLVM otherwise puts before it (the check
    that sent the AFSMC lane step's adaptive update down its scalar path)."""
    from pkmctl.model.lanes import disjoint_arrays

    def plain(a, x, y):
        for i in range(x.shape[0]):
            y[i] += a * x[i]

    def promised(a, x, y):
        disjoint_arrays()
        for i in range(x.shape[0]):
            y[i] += a * x[i]

    for f, checked in ((plain, True), (promised, False)):
        fn = numba.njit(**(JIT_OPTIONS | NO_REFCOUNT))(f)
        y = np.ones(11)
        fn(2.0, np.arange(11.0), y)
        np.testing.assert_array_equal(y, 1.0 + 2.0 * np.arange(11.0))
        ir = fn.inspect_llvm(fn.signatures[0])
        assert "vector.body" in ir
        assert ("vector.memcheck" in ir) == checked


def test_flat_view_is_the_same_memory_without_the_reshape_helper():
    """flat_view(a) of a C-contiguous array is a 1-D view of its elements in order: a
    write through it lands in the array; 2-D and 3-D alike. Unlike ``a.reshape(a.size)``
    it makes no call into Numba's reshape helper (which the lane loop's profile showed);
    an array that is not C-contiguous is refused at compile time."""
    from pkmctl.model.simd import flat_view

    def bump(a):
        f = flat_view(a)
        for i in range(f.shape[0]):
            f[i] += i
        return f.shape[0]

    def reshaped(a):
        return a.reshape(a.size).shape[0]

    fn = numba.njit(**(JIT_OPTIONS | NO_REFCOUNT))(bump)
    for shape in ((3, 8), (2, 3, 4)):
        a = np.zeros(shape)
        assert fn(a) == a.size
        np.testing.assert_array_equal(a.ravel(), np.arange(a.size, dtype=float))
    assert "attempt_nocopy_reshape" not in fn.inspect_llvm(fn.signatures[0])
    ref = numba.njit(**(JIT_OPTIONS | NO_REFCOUNT))(reshaped)
    ref(np.zeros((3, 8)))
    assert "attempt_nocopy_reshape" in ref.inspect_llvm(ref.signatures[0])  # what it avoids
    with pytest.raises(numba.core.errors.TypingError):
        fn(np.zeros((8, 3)).T)


def test_sincos_lane_is_libm_within_one_ulp():
    """The lane kernels' cos and sin (no libm, so that they vectorise): within 1 ulp of
    libm over the workspace's angles and far beyond, NaN where libm gives NaN."""
    from pkmctl.model.lanes import sincos_lane

    @numba.njit(**(JIT_OPTIONS | NO_REFCOUNT))
    def both(x, c, s):
        for i in range(x.shape[0]):
            c[i], s[i] = sincos_lane(x[i])

    rng = np.random.default_rng(7)
    for half in (0.5 * np.pi, 1e2, 1e4):
        x = rng.uniform(-half, half, 100_000)
        c, s = np.empty_like(x), np.empty_like(x)
        both(x, c, s)
        for got, ref in ((c, np.cos(x)), (s, np.sin(x))):
            assert np.all(np.abs(got - ref) <= np.spacing(np.abs(ref))), half
    x = np.array([np.nan, np.inf, -np.inf])
    c, s = np.empty_like(x), np.empty_like(x)
    both(x, c, s)
    assert np.isnan(c).all() and np.isnan(s).all()
