"""The model kernels in lane form: L independent evaluations at once (SIMD lanes for campaigns).

Every array carries the lane dimension last: geom (11, L), theta (36, L), X (3, L),
M (3, 3, L), Y (3, 36, L), a plant's state x (6, L). Lane l of every output is what
the scalar kernel of :mod:`pkmctl.model.dynamics`, :mod:`~pkmctl.model.kinematics` or
:mod:`pkmctl.sim.plants` gives on lane l's numbers: the same formulas (the scalar
kernels' own per-limb functions ``limb_sums``, ``limb_columns`` and ``limb_gravity``, and
the platform's), summed in the same order, so that the values agree within a few ulps
where LLVM fuses a multiply-add differently (tests/test_lanes_model.py). Lanes may
differ in every number, not in the code that runs: where the scalar code tests a number
(``p.machine > 0``, ``p.payload > 0``), a block of lanes runs the option's terms if any
of its lanes needs them and each lane keeps, by a select, its own result.

How it vectorises (docs/performance.md). The lanes are processed in blocks of
:data:`LANE_BLOCK` (8 doubles, one AVX-512 register, two AVX2 ones); each stage of a
kernel is a loop over the block's lanes, innermost and branch-free, which LLVM's loop
vectoriser turns into packed FMAs. Three things decide whether it can:

- Aliasing. LLVM must know that a store of one lane does not feed a load of another.
  Between arrays it can only check that at run time, one check per pair of rows, and
  gives up beyond 8 checks (a kernel here touches hundreds of rows). So every stage
  writes only into a block of scratch on the stack (:func:`pkmctl.model.simd.stack_block`):
  memory LLVM knows no argument can point into, with rows LANE_BLOCK doubles apart (a
  distance it sees as a constant, where the rows of an (..., L) array are L apart,
  unknown). Inputs are read from the caller's arrays directly; results are copied out
  row by row, each copy a loop with one source and one destination.
- Loops within the lane loop. Only the innermost loop is vectorised, so where the scalar
  kernels loop over the four limbs (their own SIMD lanes), the lane kernels have one lane
  loop per limb: a helper called once per limb with a constant index, which also makes
  every row offset a constant. Each limb's terms are added to the block's sums there, as
  the scalar kernels add each limb's partial sums after their limb loop.
- Math calls. libm has no vector variants (nor has this Numba Intel's SVML). cos and
  sin of the two angles are computed here instead (:func:`sincos_lane`, within 1 ulp
  of libm), vectorised like the rest; tanh (friction, §7) stays a short scalar pass of
  libm calls per block whose results the vector stages read from the block. So a lane
  differs from its scalar kernel by rounding (tests: within 1e-12 relative).

The work tuple of :func:`make_lane_work` receives what the scalar kernels leave in
their work for later use, the limb Jacobian and lengths at X; the intermediate
kinematics live in the stack block. Every kernel allocates nothing (``refcount=False``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from pkmctl._jit import kernel
from pkmctl.model.dynamics import (
    cholesky_solve3,
    limb_columns,
    limb_gravity,
    limb_sums,
    platform_columns,
    platform_sums,
)
from pkmctl.model.kinematics import _SPR, _cx, _limb, _limb_row, platform_rates
from pkmctl.model.simd import disjoint_arrays, wide_vectors
from pkmctl.model.simd import stack_block as _stack_block

__all__ = [
    "LANE_BLOCK",
    "LANE_JQ",
    "LANE_Q",
    "LaneRigidPlant",
    "disjoint_arrays",
    "lane_actuator_forces",
    "lane_dynamics",
    "lane_gravity",
    "lane_limb_jacobian",
    "lane_regressor",
    "lane_rigid_derivative",
    "lane_rigid_plant",
    "make_lane_work",
    "sincos_lane",
    "wide_vectors",
]

#: Lanes per block: the stages' loops run over at most this many lanes at a time.
LANE_BLOCK = 8
_B = LANE_BLOCK

# Rows of the stack block (each row LANE_BLOCK doubles, lane l at row * _B + l).
_CA, _SA, _CB, _SB = 0, 1, 2, 3  # cos/sin of alpha and beta
_TA, _SEC2, _ZS, _AV01, _AW01, _AW02 = 4, 5, 6, 7, 8, 9  # platform values the limbs reuse
_RB = 10  # the platform's frame R (3, 3)
_JQ = _RB + 9  # limb Jacobian (4, 3)
_Q = _JQ + 12  # limb lengths (4,)
_KIN_END = _Q + 4
_MM = _KIN_END  # M's upper triangle m00, m01, m02, m11, m12, m22
_CV = _MM + 6  # C v (3,)
_GG = _CV + 3  # G (3,)
_FF = _GG + 3  # task force f (3,)
_JDV = _FF + 3  # Jdot Xdot (4,), for the options (from the limb loop, as the scalar plant)
_QD = _JDV + 4  # limb rates (4,)
_TH = _QD + 4  # tanh(qdot / v_s) (4,)
_XD = _TH + 4  # Xdot (3,), the first half of dx
_XDD = _XD + 3  # Xddot (3,)
_ROWS = _XDD + 3
_Y = _KIN_END  # the regressor's distinct columns: 9 mass + 5 x 3 inertia, 3 rows each
_ROWS_Y = _Y + 3 * 24
_SIZE = max(_ROWS, _ROWS_Y) * _B

#: Positions in the work tuple of :func:`make_lane_work`.
LANE_JQ, LANE_Q = 0, 1


def make_lane_work(L: int) -> tuple[np.ndarray, ...]:
    """The work tuple of the lane kernels for L lanes: the limb Jacobian (4, 3, L) and
    lengths (4, L) at X, which the dynamics, gravity, regressor and plant kernels leave
    there (at LANE_JQ, LANE_Q) as the scalar kernels leave them in theirs."""
    return np.empty((4, 3, L)), np.empty((4, L))


class LaneRigidPlant(NamedTuple):
    """L rigid plants (:class:`pkmctl.sim.plants.RigidPlant`), field by field with a
    trailing lane dimension: geom (11, L), theta (36, L), m_r, f_c, f_v (4, L), v_s (L,),
    payload (L,), payload_offset (3, L), machine (L,)."""

    geom: np.ndarray
    theta: np.ndarray
    m_r: np.ndarray
    f_c: np.ndarray
    f_v: np.ndarray
    v_s: np.ndarray
    payload: np.ndarray
    payload_offset: np.ndarray
    machine: np.ndarray


def lane_rigid_plant(plants) -> LaneRigidPlant:
    """One lane bundle from L scalar :class:`~pkmctl.sim.plants.RigidPlant` bundles (lane l
    is ``plants[l]``); every field a C-contiguous float64 array."""
    plants = list(plants)
    if not plants:
        raise ValueError("lane_rigid_plant: no plants")
    fields = []
    for name in LaneRigidPlant._fields:
        cols = [np.asarray(getattr(p, name), dtype=float) for p in plants]
        fields.append(np.ascontiguousarray(np.stack(cols, axis=-1)))
    return LaneRigidPlant(*fields)


# ---------------------------------------------------------------- the stack block
@intrinsic
def _ix(typingctx, row, l):
    """The index of lane l of a block row, ``np.uint64(row * _B + l)``, unsigned: Numba
    then emits no wraparound test for negative indices, which LLVM failed to remove in
    the larger loops and which made their loads and stores non-consecutive (not
    vectorised). An intrinsic, not a function Numba inlines: it is called at hundreds of
    places, and each inlining of a function copies and re-types its IR (most of these
    kernels' compile time when it was one)."""
    if not (isinstance(row, types.Integer) and isinstance(l, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        r = context.cast(builder, args[0], sig.args[0], types.int64)
        k = context.cast(builder, args[1], sig.args[1], types.int64)
        return builder.add(builder.mul(r, ir.Constant(ir.IntType(64), _B)), k)

    return types.uint64(row, l), codegen


@kernel(inline="always", refcount=False)
def _put9(W, row, l, a00, a01, a02, a10, a11, a12, a20, a21, a22):
    """Rows row..row+8 of lane l <- a (3, 3) row by row."""
    W[_ix(row, l)], W[_ix((row + 1), l)], W[_ix((row + 2), l)] = a00, a01, a02
    W[_ix((row + 3), l)], W[_ix((row + 4), l)], W[_ix((row + 5), l)] = a10, a11, a12
    W[_ix((row + 6), l)], W[_ix((row + 7), l)], W[_ix((row + 8), l)] = a20, a21, a22


@kernel(inline="always", refcount=False)
def _get9(W, row, l):
    """Rows row..row+8 of lane l, a (3, 3) row by row."""
    return (
        W[_ix(row, l)],
        W[_ix((row + 1), l)],
        W[_ix((row + 2), l)],
        W[_ix((row + 3), l)],
        W[_ix((row + 4), l)],
        W[_ix((row + 5), l)],
        W[_ix((row + 6), l)],
        W[_ix((row + 7), l)],
        W[_ix((row + 8), l)],
    )


@kernel(inline="always", refcount=False)
def _get3(W, row, l):
    return W[_ix(row, l)], W[_ix((row + 1), l)], W[_ix((row + 2), l)]


@kernel(inline="always", refcount=False)
def _put3(W, row, l, a0, a1, a2):
    W[_ix(row, l)], W[_ix((row + 1), l)], W[_ix((row + 2), l)] = a0, a1, a2


@kernel(inline="always", refcount=False)
def _row_out(W, row, out, l0, n):
    """out[l0:l0+n] <- row ``row`` of the block (out a 1-D view of one output row)."""
    if n == _B:  # a full block: a fixed-length copy, one vector load and store
        for l in range(_B):
            out[np.uint64(l0 + l)] = W[_ix(row, l)]
    else:  # (a copy of n elements becomes a call of memcpy: only for the last block)
        for l in range(n):
            out[np.uint64(l0 + l)] = W[_ix(row, l)]


@kernel(inline="always", refcount=False)
def _limbs_out(W, l0, n, Jq, q):
    """The limb Jacobian (4, 3, L) and lengths (4, L) of lanes l0..l0+n from the block."""
    for i in range(4):
        for a in range(3):
            _row_out(W, _JQ + 3 * i + a, Jq[i, a], l0, n)
        _row_out(W, _Q + i, q[i], l0, n)


# ---------------------------------------------------------------- kinematics
# cos and sin without libm, so that they vectorise across the lanes (Numba has no vector
# math library here): x = k pi/2 + r, |r| <= pi/4, by Cody and Waite with fdlibm's split of
# pi/2 (33 + 53 bits), then fdlibm's minimax polynomials for sin and cos on [-pi/4, pi/4]
# (__kernel_sin, __kernel_cos), and the quadrant k mod 4 by selects. Within 1 ulp of
# libm over the workspace and far beyond (tests/test_lanes_model.py).
_INV_PIO2 = 6.36619772367581382433e-01
_PIO2_1, _PIO2_1T = 1.57079632673412561417e00, 6.07710050650619224932e-11
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


@kernel(inline="always", refcount=False)
def sincos_lane(x):
    """(cos x, sin x), branch-free (see above); NaN for a non-finite x, as libm."""
    k = np.floor(x * _INV_PIO2 + 0.5)
    r = (x - k * _PIO2_1) - k * _PIO2_1T
    z = r * r
    sr = r + (z * r) * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    hz = 0.5 * z
    w = 1.0 - hz
    cr = w + (
        ((1.0 - w) - hz) + (z * z) * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    )
    q = k - 4.0 * np.floor(0.25 * k)  # 0, 1, 2 or 3
    odd = q == 1.0 or q == 3.0
    s = cr if odd else sr
    c = sr if odd else cr
    s = -s if q >= 2.0 else s
    c = -c if q == 1.0 or q == 2.0 else c
    return c, s


@kernel(inline="always", refcount=False)
def _trig(X, l0, n, W):
    """cos and sin of alpha and beta, vectorised across the lanes (:func:`sincos_lane`)."""
    for l in range(n):
        ca, sa = sincos_lane(X[1, np.uint64(l0 + l)])
        cb, sb = sincos_lane(X[2, np.uint64(l0 + l)])
        W[_ix(_CA, l)], W[_ix(_SA, l)] = ca, sa
        W[_ix(_CB, l)], W[_ix(_SB, l)] = cb, sb


@kernel(inline="always", refcount=False)
def _lane3(A, j):
    """Lane j of a (3, L) array as a tuple (Xd, v, ... of one lane)."""
    return A[0, j], A[1, j], A[2, j]


@kernel(inline="always", refcount=False)
def _pm(Xd, v, W, j, l):
    """Lane l's :func:`~pkmctl.model.kinematics.platform_motion` values, from the block
    (written by :func:`_platform`) and its Xd and v (the platform's omega and J_w v)."""
    ca, sa, cb, sb = W[_ix(_CA, l)], W[_ix(_SA, l)], W[_ix(_CB, l)], W[_ix(_SB, l)]
    ad, bd, v1, v2 = Xd[1, j], Xd[2, j], v[1, j], v[2, j]
    rates = (W[_ix(_TA, l)], W[_ix(_SEC2, l)], W[_ix(_ZS, l)], W[_ix(_AV01, l)],
             W[_ix(_AW01, l)], W[_ix(_AW02, l)])  # fmt: skip
    return (ca, sa, cb, sb) + rates + ((ad, ca * bd, sa * bd), (v1, ca * v2, sa * v2))


@kernel(inline="always", refcount=False)
def _limb_of(geom, X, pm, j, i):
    """Lane j's :func:`~pkmctl.model.kinematics._limb_at` of limb i (a constant)."""
    ca, sa, cb, sb, ta, _, zs = pm[0:7]
    return _limb(geom[0, j], geom[1, j], X[0, j], ta, zs, ca, sa, cb, sb, i)


@kernel(inline="always", refcount=False)
def _platform(X, Xd, v, l0, n, W):
    """The platform's values the limbs reuse (:func:`~pkmctl.model.kinematics.platform_rates`)
    and its frame R, into the block."""
    for l in range(n):
        j = np.uint64(l0 + l)
        ca, sa, cb, sb = W[_ix(_CA, l)], W[_ix(_SA, l)], W[_ix(_CB, l)], W[_ix(_SB, l)]
        rates = platform_rates(X[0, j], _lane3(Xd, j), _lane3(v, j), ca, sa)
        ta, sec2, zs, av01, aw01, aw02 = rates[0:6]
        W[_ix(_TA, l)], W[_ix(_SEC2, l)], W[_ix(_ZS, l)] = ta, sec2, zs
        W[_ix(_AV01, l)], W[_ix(_AW01, l)], W[_ix(_AW02, l)] = av01, aw01, aw02
        _put9(W, _RB, l, cb, 0.0, sb, sa * sb, ca, -sa * cb, -ca * sb, sa, ca * cb)


@kernel(inline="always", refcount=False)
def _platform_terms(theta, Xd, v, l0, n, W):
    """The platform's terms of M, C v and G (:func:`~pkmctl.model.dynamics.platform_sums`):
    the block's sums, to which the limbs' are added."""
    for l in range(n):
        j = np.uint64(l0 + l)
        th = (theta[0, j], theta[1, j], theta[2, j], theta[3, j])
        s = platform_sums(th, _lane3(Xd, j), _lane3(v, j), _pm(Xd, v, W, j, l))
        _put3(W, _MM, l, s[0], s[1], s[2])
        _put3(W, _MM + 3, l, s[3], s[4], s[5])
        _put3(W, _CV, l, s[6], s[7], s[8])
        _put3(W, _GG, l, s[9], s[10], s[11])


@kernel(inline="always", refcount=False)
def _add3(W, row, l, a0, a1, a2):
    """Rows row..row+2 of lane l += (a0, a1, a2)."""
    W[_ix(row, l)] += a0
    W[_ix((row + 1), l)] += a1
    W[_ix((row + 2), l)] += a2


@kernel(inline="always", refcount=False)
def _limb_terms(geom, theta, X, Xd, v, l0, n, W, i):
    """Limb i's terms of M, C v and G (:func:`~pkmctl.model.dynamics.limb_sums`) added to the
    block's sums (the scalar kernel's order: the platform's, then limb by limb); its length
    and row of J into the block."""
    lo, up = 4 * (1 + i), 4 * (5 + i)
    for l in range(n):
        j = np.uint64(l0 + l)
        pm = _pm(Xd, v, W, j, l)
        limb = _limb_of(geom, X, pm, j, i)
        masses = (theta[lo, j], theta[up, j])
        inertias = (theta[lo + 1, j] + theta[up + 1, j], theta[lo + 2, j] + theta[up + 2, j],
                    theta[lo + 3, j] + theta[up + 3, j])  # fmt: skip
        jr, jdv, s = limb_sums(geom[2 + i, j], geom[6 + i, j], masses, inertias, _lane3(Xd, j),
                            _lane3(v, j), pm, _SPR[i], limb)  # fmt: skip
        W[_ix((_JDV + i), l)] = jdv
        _add3(W, _MM, l, s[0], s[1], s[2])
        _add3(W, _MM + 3, l, s[3], s[4], s[5])
        _add3(W, _CV, l, s[6], s[7], s[8])
        _add3(W, _GG, l, s[9], s[10], s[11])
        W[_ix((_Q + i), l)] = limb[3]
        _put3(W, _JQ + 3 * i, l, jr[0], jr[1], jr[2])


@kernel(inline="always", refcount=False)
def _dynamics_block(geom, theta, X, Xd, v, l0, n, W):
    """M (upper triangle), C v and G of lanes l0..l0+n into the block, with the limb
    Jacobian and lengths: the scalar dynamics_kernel lane by lane, one lane loop per limb."""
    _trig(X, l0, n, W)
    _platform(X, Xd, v, l0, n, W)
    _platform_terms(theta, Xd, v, l0, n, W)
    _limb_terms(geom, theta, X, Xd, v, l0, n, W, 0)
    _limb_terms(geom, theta, X, Xd, v, l0, n, W, 1)
    _limb_terms(geom, theta, X, Xd, v, l0, n, W, 2)
    _limb_terms(geom, theta, X, Xd, v, l0, n, W, 3)
    for l in range(n):  # G = g sum m dz/dX
        g = geom[10, np.uint64(l0 + l)]
        W[_ix(_GG, l)] *= g
        W[_ix((_GG + 1), l)] *= g
        W[_ix((_GG + 2), l)] *= g


@kernel(inline="always", refcount=False)
def _mcg_out(W, l0, n, M, Cv, G):
    """M (3, 3, L) (mirrored from its upper triangle), C v and G (3, L) from the block."""
    for a in range(3):
        for b in range(3):
            r = min(a, b)
            c = max(a, b)
            _row_out(W, _MM + (5 * r - r * r) // 2 + c, M[a, b], l0, n)
        _row_out(W, _CV + a, Cv[a], l0, n)
        _row_out(W, _GG + a, G[a], l0, n)


@kernel(refcount=False, llvm_inline=True)
def lane_dynamics(geom, theta, X, Xd, v, work, M, Cv, G):
    """Per lane, M (3, 3, L), C(X, Xd) v (3, L) and G (3, L) of
    :func:`~pkmctl.model.dynamics.dynamics_kernel`; geom (11, L), theta (36, L), X, Xd,
    v (3, L); the limb Jacobian and lengths at X go to ``work`` (:func:`make_lane_work`)."""
    wide_vectors()
    W = _stack_block(_SIZE)
    L = X.shape[-1]
    for l0 in range(0, L, _B):
        n = min(_B, L - l0)
        _dynamics_block(geom, theta, X, Xd, v, l0, n, W)
        _mcg_out(W, l0, n, M, Cv, G)
        _limbs_out(W, l0, n, work[LANE_JQ], work[LANE_Q])


# ---------------------------------------------------------------- gravity
@kernel(inline="always", refcount=False)
def _limb_g(geom, theta, X, W, j, l, i, g):
    """Limb i's terms of G (:func:`~pkmctl.model.dynamics.limb_gravity`); its length and row
    of J into the block."""
    ca, sa, cb, sb = W[_ix(_CA, l)], W[_ix(_SA, l)], W[_ix(_CB, l)], W[_ix(_SB, l)]
    pm = (ca, sa, cb, sb, W[_ix(_TA, l)], 0.0, W[_ix(_ZS, l)])
    limb = _limb_of(geom, X, pm, j, i)
    jr, gl = limb_gravity(geom[2 + i, j], geom[6 + i, j], theta[4 * (1 + i), j] * g,
                          theta[4 * (5 + i), j] * g, limb)  # fmt: skip
    W[_ix((_Q + i), l)] = limb[3]
    _put3(W, _JQ + 3 * i, l, jr[0], jr[1], jr[2])
    return gl


@kernel(inline="always", refcount=False)
def _add_g(s, a):
    return s[0] + a[0], s[1] + a[1], s[2] + a[2]


@kernel(refcount=False, llvm_inline=True)
def lane_gravity(geom, theta, X, work, G):
    """Per lane, G (3, L) of :func:`~pkmctl.model.dynamics.gravity_kernel` at X (3, L);
    the limb Jacobian and lengths at X go to ``work``."""
    wide_vectors()
    W = _stack_block(_SIZE)
    L = X.shape[-1]
    for l0 in range(0, L, _B):
        n = min(_B, L - l0)
        _trig(X, l0, n, W)
        for l in range(n):
            j = np.uint64(l0 + l)
            ca, sa = W[_ix(_CA, l)], W[_ix(_SA, l)]
            W[_ix(_TA, l)], W[_ix(_ZS, l)] = sa / ca, X[0, j] * (1.0 / (ca * ca))
            g = geom[10, j]
            s = (theta[0, j] * g, 0.0, 0.0)  # the platform: dz/dX = e_z; then limb by limb
            s = _add_g(s, _limb_g(geom, theta, X, W, j, l, 0, g))
            s = _add_g(s, _limb_g(geom, theta, X, W, j, l, 1, g))
            s = _add_g(s, _limb_g(geom, theta, X, W, j, l, 2, g))
            s = _add_g(s, _limb_g(geom, theta, X, W, j, l, 3, g))
            _put3(W, _GG, l, s[0], s[1], s[2])
        for a in range(3):
            _row_out(W, _GG + a, G[a], l0, n)
        _limbs_out(W, l0, n, work[LANE_JQ], work[LANE_Q])


# ---------------------------------------------------------------- the regressor
@kernel(inline="always", refcount=False)
def _put_column(W, row, l, c):
    _put3(W, row, l, c[0], c[1], c[2])


@kernel(inline="always", refcount=False)
def _platform_columns(geom, Xd, Xr_d, Xr_dd, l0, n, W):
    """The platform's columns of Y (:func:`~pkmctl.model.dynamics.platform_columns`) into
    the block: the mass column at rows _Y + i, the inertia column nn at _Y + 27 + 3 nn + i."""
    for l in range(n):
        j = np.uint64(l0 + l)
        pm = _pm(Xd, Xr_d, W, j, l)
        m, cols = platform_columns(geom[10, j], _lane3(Xd, j), _lane3(Xr_d, j),
                                   _lane3(Xr_dd, j), pm)  # fmt: skip
        _put_column(W, _Y, l, m)
        _put_column(W, _Y + 27, l, cols[0])
        _put_column(W, _Y + 30, l, cols[1])
        _put_column(W, _Y + 33, l, cols[2])


@kernel(inline="always", refcount=False)
def _limb_columns(geom, X, Xd, Xr_d, Xr_dd, l0, n, W, i):
    """Limb i's columns of Y (:func:`~pkmctl.model.dynamics.limb_columns`) into the block
    (bodies 1 + i and 5 + i, frame 1 + i), its length and row of J."""
    b, f = 1 + i, 1 + i
    for l in range(n):
        j = np.uint64(l0 + l)
        pm = _pm(Xd, Xr_d, W, j, l)
        limb = _limb_of(geom, X, pm, j, i)
        jr, _, m_lo, m_up, cols = limb_columns(geom[2 + i, j], geom[6 + i, j], geom[10, j],
                                            _lane3(Xd, j), _lane3(Xr_d, j), _lane3(Xr_dd, j),
                                            pm, _SPR[i], limb)  # fmt: skip
        _put_column(W, _Y + 3 * b, l, m_lo)
        _put_column(W, _Y + 3 * (b + 4), l, m_up)
        _put_column(W, _Y + 27 + 9 * f, l, cols[0])
        _put_column(W, _Y + 27 + 9 * f + 3, l, cols[1])
        _put_column(W, _Y + 27 + 9 * f + 6, l, cols[2])
        W[_ix((_Q + i), l)] = limb[3]
        _put3(W, _JQ + 3 * i, l, jr[0], jr[1], jr[2])


@kernel(refcount=False, llvm_inline=True)
def lane_regressor(geom, X, Xd, Xr_d, Xr_dd, work, Y):
    """Per lane, Y (3, 36, L) of :func:`~pkmctl.model.dynamics.regressor_kernel`:
    Y Theta = M Xr_dd + C(X, Xd) Xr_d + G; geom (11, L), X, Xd, Xr_d, Xr_dd (3, L); the
    limb Jacobian and lengths at X go to ``work``."""
    wide_vectors()
    W = _stack_block(_SIZE)
    L = X.shape[-1]
    for l0 in range(0, L, _B):
        n = min(_B, L - l0)
        _trig(X, l0, n, W)
        _platform(X, Xd, Xr_d, l0, n, W)
        _platform_columns(geom, Xd, Xr_d, Xr_dd, l0, n, W)
        _limb_columns(geom, X, Xd, Xr_d, Xr_dd, l0, n, W, 0)
        _limb_columns(geom, X, Xd, Xr_d, Xr_dd, l0, n, W, 1)
        _limb_columns(geom, X, Xd, Xr_d, Xr_dd, l0, n, W, 2)
        _limb_columns(geom, X, Xd, Xr_d, Xr_dd, l0, n, W, 3)
        for i in range(3):
            for b in range(9):
                _row_out(W, _Y + 3 * b + i, Y[i, 4 * b], l0, n)
                f = b if b < 5 else b - 4  # the frame whose inertia columns body b shares
                for nn in range(3):
                    _row_out(W, _Y + 27 + 9 * f + 3 * nn + i, Y[i, 4 * b + 1 + nn], l0, n)
        _limbs_out(W, l0, n, work[LANE_JQ], work[LANE_Q])


# ---------------------------------------------------------------- limb Jacobian, forces
@kernel(inline="always", refcount=False)
def _limb_position(r_a, r_b, z, ta, zs, ca, sa, cb, sb, W, l, i):
    """Limb i's length and row of J into the block (the loop body of limb_jacobian)."""
    _, _, _, qi, _, u0, u1, u2, p02, p10, p11, p12, p21, p22 = _limb(
        r_a, r_b, z, ta, zs, ca, sa, cb, sb, i
    )
    W[_ix((_Q + i), l)] = qi
    j0, j1, j2 = _limb_row(u0, u1, u2, p02, p10, p11, p12, p21, p22)
    _put3(W, _JQ + 3 * i, l, j0, j1, j2)


@kernel(refcount=False, llvm_inline=True)
def lane_limb_jacobian(geom, X, work, Jq, q):
    """Per lane, the limb Jacobian Jq (4, 3, L) and lengths q (4, L) of
    :func:`~pkmctl.model.kinematics.limb_jacobian` at X (3, L). ``work`` is not written
    (the scalar kernel's R scratch lives in the stack block); it keeps the signature of
    the other lane kernels."""
    wide_vectors()
    W = _stack_block(_SIZE)
    L = X.shape[-1]
    for l0 in range(0, L, _B):
        n = min(_B, L - l0)
        _trig(X, l0, n, W)
        for l in range(n):
            j = np.uint64(l0 + l)
            r_a, r_b, z = geom[0, j], geom[1, j], X[0, j]
            ca, sa, cb, sb = W[_ix(_CA, l)], W[_ix(_SA, l)], W[_ix(_CB, l)], W[_ix(_SB, l)]
            ta = sa / ca
            zs = z * (1.0 / (ca * ca))
            _limb_position(r_a, r_b, z, ta, zs, ca, sa, cb, sb, W, l, 0)
            _limb_position(r_a, r_b, z, ta, zs, ca, sa, cb, sb, W, l, 1)
            _limb_position(r_a, r_b, z, ta, zs, ca, sa, cb, sb, W, l, 2)
            _limb_position(r_a, r_b, z, ta, zs, ca, sa, cb, sb, W, l, 3)
        _limbs_out(W, l0, n, Jq, q)


@kernel(inline="always", refcount=False)
def _gram(s, q0, q1, q2):
    """s += the upper triangle of q q^T, q a row of J: one term of J^T J."""
    a00, a01, a02, a11, a12, a22 = s
    a00 += q0 * q0
    a01 += q0 * q1
    a02 += q0 * q2
    a11 += q1 * q1
    a12 += q1 * q2
    a22 += q2 * q2
    return a00, a01, a02, a11, a12, a22


@kernel(refcount=False, llvm_inline=True)
def lane_actuator_forces(Jq, F, tau):
    """Per lane, the minimum-norm actuator forces tau (4, L) with J^T tau = F (3, L),
    J = Jq (4, 3, L): tau = J (J^T J)^-1 F, as
    :func:`~pkmctl.model.dynamics.actuator_forces_kernel`."""
    wide_vectors()
    W = _stack_block(_SIZE)
    L = F.shape[-1]
    for l0 in range(0, L, _B):
        n = min(_B, L - l0)
        for l in range(n):
            j = np.uint64(l0 + l)
            s = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            s = _gram(s, Jq[0, 0, j], Jq[0, 1, j], Jq[0, 2, j])
            s = _gram(s, Jq[1, 0, j], Jq[1, 1, j], Jq[1, 2, j])
            s = _gram(s, Jq[2, 0, j], Jq[2, 1, j], Jq[2, 2, j])
            s = _gram(s, Jq[3, 0, j], Jq[3, 1, j], Jq[3, 2, j])
            a00, a01, a02, a11, a12, a22 = s
            y0, y1, y2 = cholesky_solve3(a00, a01, a02, a11, a12, a22, F[0, j], F[1, j], F[2, j])
            W[_ix(0, l)] = Jq[0, 0, j] * y0 + Jq[0, 1, j] * y1 + Jq[0, 2, j] * y2
            W[_ix(1, l)] = Jq[1, 0, j] * y0 + Jq[1, 1, j] * y1 + Jq[1, 2, j] * y2
            W[_ix(2, l)] = Jq[2, 0, j] * y0 + Jq[2, 1, j] * y1 + Jq[2, 2, j] * y2
            W[_ix(3, l)] = Jq[3, 0, j] * y0 + Jq[3, 1, j] * y1 + Jq[3, 2, j] * y2
        for i in range(4):
            _row_out(W, i, tau[i], l0, n)


# ---------------------------------------------------------------- the rigid plant
@kernel(inline="always", refcount=False)
def _point(z, ta, zs, sec2, ca, sa, R, ox, oy, oz, zd, ad, bd, v0, v1, v2):
    """:func:`~pkmctl.model.kinematics.platform_point` on scalars: R a 9-tuple, Xd and v
    as (zd, ad, bd) and (v0, v1, v2)."""
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = R
    rx = R00 * ox + R01 * oy + R02 * oz
    ry = R10 * ox + R11 * oy + R12 * oz
    rz = R20 * ox + R21 * oy + R22 * oz
    p02 = ca * rz - sa * ry
    p10, p11, p12 = -ta, -zs - rz, sa * rx
    p21, p22 = ry, -ca * rx
    av1 = -sec2 * ad * v0 - (zd * sec2 + 2.0 * z * sec2 * ta * ad) * v1
    t0, t1, t2 = _cx(0.0, -sa * ad * v2, ca * ad * v2, rx, ry, rz)
    rdx, rdy, rdz = _cx(ad, ca * bd, sa * bd, rx, ry, rz)
    s0, s1, s2 = _cx(v1, ca * v2, sa * v2, rdx, rdy, rdz)
    return rx, ry, rz, p02, p10, p11, p12, p21, p22, t0 + s0, av1 + t1 + s1, t2 + s2


@kernel(inline="always", refcount=False)
def _limb_rate(Xd, W, j, l, i):
    """Limb i's rate qdot = J_i Xd for the friction law, from the row of J the limb loop
    left in the block (as plants._machine_terms)."""
    j0, j1, j2 = _get3(W, _JQ + 3 * i, l)
    W[_ix((_QD + i), l)] = j0 * Xd[0, j] + j1 * Xd[1, j] + j2 * Xd[2, j]


@kernel(inline="always", refcount=False)
def _rotor(m, W, l, i, s):
    """Limb i's reflected rotor inertia m added to s = (M's upper triangle, C v), as
    machine.add_rotor_inertia adds it: M += m J_i^T J_i, C v += m J_i^T (Jdot_i Xd)."""
    m00, m01, m02, m11, m12, m22, c0, c1, c2 = s
    j0, j1, j2 = _get3(W, _JQ + 3 * i, l)
    jdv = W[_ix((_JDV + i), l)]
    ma = m * j0
    c0 += ma * jdv
    m00 += ma * j0
    m01 += ma * j1
    m02 += ma * j2
    ma = m * j1
    c1 += ma * jdv
    m11 += ma * j1
    m12 += ma * j2
    ma = m * j2
    c2 += ma * jdv
    m22 += ma * j2
    return m00, m01, m02, m11, m12, m22, c0, c1, c2


@kernel(inline="always", refcount=False)
def _friction(p, j, W, l, i, r):
    """r -= J_i^T f_i with limb i's friction f_i = F_c tanh(qdot / v_s) + F_v qdot
    (machine.friction_law, its tanh from the block)."""
    j0, j1, j2 = _get3(W, _JQ + 3 * i, l)
    qd = W[_ix((_QD + i), l)]
    fr = p.f_c[i, j] * W[_ix((_TH + i), l)] + p.f_v[i, j] * qd
    return r[0] - j0 * fr, r[1] - j1 * fr, r[2] - j2 * fr


@kernel(inline="always", refcount=False)
def _options(p, X, Xd, l0, n, W):
    """The §7 terms of the lanes whose ``machine`` is on (plants._machine_terms): rotor
    inertia and payload into the block's M, C v and G, friction into its f. Lanes with it
    off keep their rigid values (a select, not a multiplication by 0)."""
    for l in range(n):
        j = np.uint64(l0 + l)
        _limb_rate(Xd, W, j, l, 0)
        _limb_rate(Xd, W, j, l, 1)
        _limb_rate(Xd, W, j, l, 2)
        _limb_rate(Xd, W, j, l, 3)
    for l in range(n):  # the scalar pass: tanh (libm)
        vs = p.v_s[np.uint64(l0 + l)]
        for i in range(4):
            W[_ix((_TH + i), l)] = math.tanh(W[_ix((_QD + i), l)] / vs)
    for l in range(n):
        j = np.uint64(l0 + l)
        on = p.machine[j] > 0.0
        m00, m01, m02 = _get3(W, _MM, l)
        m11, m12, m22 = _get3(W, _MM + 3, l)
        c0, c1, c2 = _get3(W, _CV, l)
        g0, g1, g2 = _get3(W, _GG, l)
        f0, f1, f2 = _get3(W, _FF, l)
        s = (m00, m01, m02, m11, m12, m22, c0, c1, c2)
        s = _rotor(p.m_r[0, j], W, l, 0, s)
        s = _rotor(p.m_r[1, j], W, l, 1, s)
        s = _rotor(p.m_r[2, j], W, l, 2, s)
        s = _rotor(p.m_r[3, j], W, l, 3, s)
        n00, n01, n02, n11, n12, n22, e0, e1, e2 = s
        # the payload (machine.add_payload), for the lanes that carry one
        mass = p.payload[j]
        with_payload = on & (mass > 0.0)
        z, zd, ad, bd = X[0, j], Xd[0, j], Xd[1, j], Xd[2, j]
        ca, sa = W[_ix(_CA, l)], W[_ix(_SA, l)]
        ta, sec2 = W[_ix(_TA, l)], W[_ix(_SEC2, l)]
        ox, oy, oz = p.payload_offset[0, j], p.payload_offset[1, j], p.payload_offset[2, j]
        _, _, _, p02, p10, p11, p12, p21, p22, a0, a1, a2 = _point(
            z, ta, z * sec2, sec2, ca, sa, _get9(W, _RB, l), ox, oy, oz, zd, ad, bd, zd, ad, bd
        )
        gg = p.geom[10, j]
        mm = mass
        q00 = n00 + mm * (p10 * p10 + 1.0)
        q01 = n01 + mm * (p10 * p11 + p21)
        q02 = n02 + mm * (p10 * p12 + p22)
        q11 = n11 + mm * (p11 * p11 + p21 * p21)
        q12 = n12 + mm * (p11 * p12 + p21 * p22)
        q22 = n22 + mm * (p02 * p02 + p12 * p12 + p22 * p22)
        h0 = e0 + mm * (p10 * a1 + a2)
        h1 = e1 + mm * (p11 * a1 + p21 * a2)
        h2 = e2 + mm * (p02 * a0 + p12 * a1 + p22 * a2)
        k0 = g0 + mm * gg
        k1 = g1 + mm * gg * p21
        k2 = g2 + mm * gg * p22
        if not with_payload:
            q00, q01, q02, q11, q12, q22 = n00, n01, n02, n11, n12, n22
            h0, h1, h2, k0, k1, k2 = e0, e1, e2, g0, g1, g2
        # friction: f -= J^T (F_c tanh(qdot / v_s) + F_v qdot)
        r = (f0, f1, f2)
        r = _friction(p, j, W, l, 0, r)
        r = _friction(p, j, W, l, 1, r)
        r = _friction(p, j, W, l, 2, r)
        r = _friction(p, j, W, l, 3, r)
        # every store unconditional, its value a select: the loop stays branch-free
        _put3(W, _MM, l, q00 if on else m00, q01 if on else m01, q02 if on else m02)
        _put3(W, _MM + 3, l, q11 if on else m11, q12 if on else m12, q22 if on else m22)
        _put3(W, _CV, l, h0 if on else c0, h1 if on else c1, h2 if on else c2)
        _put3(W, _GG, l, k0 if on else g0, k1 if on else g1, k2 if on else g2)
        _put3(W, _FF, l, r[0] if on else f0, r[1] if on else f1, r[2] if on else f2)


@kernel(refcount=False)
def lane_rigid_derivative(p, x, tau, dist, work, dx):
    """Per lane, dx (6, L) of :func:`pkmctl.sim.plants.rigid_derivative`:
    [Xdot, M^-1 (J^T tau + tau_d' - C Xdot - G)] with the §7 terms of the lanes whose
    ``machine`` is on. p a :class:`LaneRigidPlant`, x (6, L), tau (4, L), dist (3, L);
    the limb Jacobian and lengths at X go to ``work`` (:func:`make_lane_work`)."""
    wide_vectors()
    W = _stack_block(_SIZE)
    X, Xd = x[0:3], x[3:6]
    L = x.shape[-1]
    for l0 in range(0, L, _B):
        n = min(_B, L - l0)
        _dynamics_block(p.geom, p.theta, X, Xd, Xd, l0, n, W)
        for l in range(n):  # f = J^T tau + tau_d'
            j = np.uint64(l0 + l)
            J = _get9(W, _JQ, l) + _get3(W, _JQ + 9, l)
            t0, t1, t2, t3 = tau[0, j], tau[1, j], tau[2, j], tau[3, j]
            f0 = J[0] * t0 + J[3] * t1 + J[6] * t2 + J[9] * t3
            f1 = J[1] * t0 + J[4] * t1 + J[7] * t2 + J[10] * t3
            f2 = J[2] * t0 + J[5] * t1 + J[8] * t2 + J[11] * t3
            _put3(W, _FF, l, f0 + dist[0, j], f1 + dist[1, j], f2 + dist[2, j])
        any_on = False
        for l in range(n):
            any_on |= p.machine[np.uint64(l0 + l)] > 0.0
        if any_on:
            _options(p, X, Xd, l0, n, W)
        for l in range(n):  # forward dynamics: Xddot = M^-1 (f - C Xdot - G)
            m00, m01, m02 = _get3(W, _MM, l)
            m11, m12, m22 = _get3(W, _MM + 3, l)
            b0 = W[_ix(_FF, l)] - W[_ix(_CV, l)] - W[_ix(_GG, l)]
            b1 = W[_ix((_FF + 1), l)] - W[_ix((_CV + 1), l)] - W[_ix((_GG + 1), l)]
            b2 = W[_ix((_FF + 2), l)] - W[_ix((_CV + 2), l)] - W[_ix((_GG + 2), l)]
            a0, a1, a2 = cholesky_solve3(m00, m01, m02, m11, m12, m22, b0, b1, b2)
            _put3(W, _XDD, l, a0, a1, a2)
            j = np.uint64(l0 + l)
            _put3(W, _XD, l, x[3, j], x[4, j], x[5, j])  # dx[0:3] = Xdot, by way of the block
        for i in range(3):
            _row_out(W, _XD + i, dx[i], l0, n)
            _row_out(W, _XDD + i, dx[3 + i], l0, n)
        _limbs_out(W, l0, n, work[LANE_JQ], work[LANE_Q])
