"""The model kernels in lane form: L independent evaluations at once (SIMD lanes for campaigns).

Every array carries the lane dimension last: geom (11, L), theta (36, L), X (3, L),
M (3, 3, L), Y (3, 36, L), a plant's state x (6, L). Lane l of every output is what
the scalar kernel of :mod:`pkmctl.model.dynamics`, :mod:`~pkmctl.model.kinematics` or
:mod:`pkmctl.sim.plants` gives on lane l's numbers: the same formulas, written in the
same order, so that the values agree bit for bit or within an ulp where LLVM fuses a
multiply-add differently (tests/test_lanes_model.py). Lanes may differ in every number,
not in the code that runs: where the scalar code tests a number (``p.machine > 0``,
``p.payload > 0``), a block of lanes runs the option's terms if any of its lanes needs
them and each lane keeps, by a select, its own result.

How it vectorises (docs/performance.md). The lanes are processed in blocks of
:data:`LANE_BLOCK` (8 doubles, one AVX-512 register, two AVX2 ones); each stage of a
kernel is a loop over the block's lanes, innermost and branch-free, which LLVM's loop
vectoriser turns into packed FMAs. Three things decide whether it can:

- Aliasing. LLVM must know that a store of one lane does not feed a load of another.
  Between arrays it can only check that at run time, one check per pair of rows, and
  gives up beyond 8 checks (a kernel here touches hundreds of rows). So every stage
  writes only into a block of scratch on the stack (:func:`_stack_block`): memory LLVM
  knows no argument can point into, with rows LANE_BLOCK doubles apart (a distance it
  sees as a constant, where the rows of an (..., L) array are L apart, unknown). Inputs
  are read from the caller's arrays directly; results are copied out row by row, each
  copy a loop with one source and one destination.
- Loops within the lane loop. Only the innermost loop is vectorised, so the scalar
  code's loops over limbs and bodies are unrolled by hand: a helper called once per
  limb or body with a constant index, which also makes every row offset a constant.
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
from pkmctl.model.dynamics import cholesky_solve3
from pkmctl.model.kinematics import _LIMB_DIR, _SPR, _cx, _limb, _limb_row
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
_RB = 10  # body frames, 5 x (3, 3) (as the scalar work: rows 0-4 only)
_JV = _RB + 45  # linear velocity Jacobians, 9 x (3, 3)
_JW = _JV + 81  # angular velocity Jacobians, 5 x (3, 3)
_AV = _JW + 45  # dJ_v v, 9 x 3
_AW = _AV + 27  # dJ_w v, 5 x 3
_JQ = _AW + 15  # limb Jacobian (4, 3)
_Q = _JQ + 12  # limb lengths (4,)
_KIN_END = _Q + 4
_MM = _KIN_END  # M's upper triangle m00, m01, m02, m11, m12, m22
_CV = _MM + 6  # C v (3,)
_GG = _CV + 3  # G (3,)
_FF = _GG + 3  # task force f (3,)
_JQR = _FF + 3  # the limb Jacobian of limb_jacobian_rate (4, 3), for the options
_JDV = _JQR + 12  # Jdot Xdot (4,)
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
def _platform(X, Xd, v, l0, n, W):
    """Body 0 of :func:`~pkmctl.model.kinematics.body_jacobians`, and the values its limbs
    reuse (tan alpha, sec^2 alpha, z sec^2 alpha, dJ_v v and dJ_w v of the platform)."""
    for l in range(n):
        j = np.uint64(l0 + l)
        z, zd, ad = X[0, j], Xd[0, j], Xd[1, j]
        v0, v1, v2 = v[0, j], v[1, j], v[2, j]
        ca, sa, cb, sb = W[_ix(_CA, l)], W[_ix(_SA, l)], W[_ix(_CB, l)], W[_ix(_SB, l)]
        ta = sa / ca
        sec2 = 1.0 / (ca * ca)
        _put9(W, _RB, l, cb, 0.0, sb, sa * sb, ca, -sa * cb, -ca * sb, sa, ca * cb)
        _put9(W, _JV, l, 0.0, 0.0, 0.0, -ta, -z * sec2, 0.0, 1.0, 0.0, 0.0)
        _put9(W, _JW, l, 0.0, 1.0, 0.0, 0.0, 0.0, ca, 0.0, 0.0, sa)
        av01 = -sec2 * ad * v0 - (zd * sec2 + 2.0 * z * sec2 * ta * ad) * v1
        aw01, aw02 = -sa * ad * v2, ca * ad * v2
        _put3(W, _AV, l, 0.0, av01, 0.0)
        _put3(W, _AW, l, 0.0, aw01, aw02)
        W[_ix(_TA, l)], W[_ix(_SEC2, l)], W[_ix(_ZS, l)] = ta, sec2, z * sec2
        W[_ix(_AV01, l)], W[_ix(_AW01, l)], W[_ix(_AW02, l)] = av01, aw01, aw02


@kernel(inline="always", refcount=False)
def _limb_body(geom, X, Xd, v, l0, n, W, i):
    """Limb i (a constant) of :func:`~pkmctl.model.kinematics.body_jacobians`: its two
    bodies' Jacobians and dJ/dt v, its frame, and its row of the limb Jacobian."""
    lo, up = 1 + i, 5 + i
    spr = _SPR[i]
    for l in range(n):
        j = np.uint64(l0 + l)
        r_a, r_b = geom[0, j], geom[1, j]
        l1, l2 = geom[2 + i, j], geom[6 + i, j]
        z, zd, ad, bd = X[0, j], Xd[0, j], Xd[1, j], Xd[2, j]
        v0, v1, v2 = v[0, j], v[1, j], v[2, j]
        ca, sa, cb, sb = W[_ix(_CA, l)], W[_ix(_SA, l)], W[_ix(_CB, l)], W[_ix(_SB, l)]
        ta, zs = W[_ix(_TA, l)], W[_ix(_ZS, l)]
        av01, aw01, aw02 = W[_ix(_AV01, l)], W[_ix(_AW01, l)], W[_ix(_AW02, l)]
        w0x, w0y, w0z = ad, ca * bd, sa * bd
        wv0x, wv0y, wv0z = v1, ca * v2, sa * v2
        # from here on the loop body of body_jacobians, line by line
        rx, ry, rz, qi, iq, u0, u1, u2, p02, p10, p11, p12, p21, p22 = _limb(
            r_a, r_b, z, ta, zs, ca, sa, cb, sb, i
        )
        rdx, rdy, rdz = _cx(w0x, w0y, w0z, rx, ry, rz)
        t0, t1, t2 = _cx(0.0, aw01, aw02, rx, ry, rz)
        s0, s1, s2 = _cx(wv0x, wv0y, wv0z, rdx, rdy, rdz)
        aP0, aP1, aP2 = t0 + s0, av01 + t1 + s1, t2 + s2
        Pd0 = p02 * bd
        Pd1 = p10 * zd + p11 * ad + p12 * bd
        Pd2 = zd + p21 * ad + p22 * bd
        Pv0 = p02 * v2
        Pv1 = p10 * v0 + p11 * v1 + p12 * v2
        Pv2 = v0 + p21 * v1 + p22 * v2
        qd = u0 * Pd0 + u1 * Pd1 + u2 * Pd2
        ud0, ud1, ud2 = (Pd0 - u0 * qd) * iq, (Pd1 - u1 * qd) * iq, (Pd2 - u2 * qd) * iq
        j0, j1, j2 = _limb_row(u0, u1, u2, p02, p10, p11, p12, p21, p22)
        k00, k01, k02 = -u0 * j0 * iq, -u0 * j1 * iq, (p02 - u0 * j2) * iq
        k10, k11, k12 = (p10 - u1 * j0) * iq, (p11 - u1 * j1) * iq, (p12 - u1 * j2) * iq
        k20, k21, k22 = (1.0 - u2 * j0) * iq, (p21 - u2 * j1) * iq, (p22 - u2 * j2) * iq
        uPv = u0 * Pv0 + u1 * Pv1 + u2 * Pv2
        udPv = ud0 * Pv0 + ud1 * Pv1 + ud2 * Pv2
        uaP = u0 * aP0 + u1 * aP1 + u2 * aP2
        Juv0, Juv1, Juv2 = (Pv0 - u0 * uPv) * iq, (Pv1 - u1 * uPv) * iq, (Pv2 - u2 * uPv) * iq
        cc = uaP + udPv
        au0 = (aP0 - u0 * cc - ud0 * uPv - Juv0 * qd) * iq
        au1 = (aP1 - u1 * cc - ud1 * uPv - Juv1 * qd) * iq
        au2 = (aP2 - u2 * cc - ud2 * uPv - Juv2 * qd) * iq
        W[_ix((_Q + i), l)] = qi
        _put3(W, _JQ + 3 * i, l, j0, j1, j2)
        _put9(W, _JV + 9 * lo, l, l1 * k00, l1 * k01, l1 * k02, l1 * k10, l1 * k11, l1 * k12,
              l1 * k20, l1 * k21, l1 * k22)  # fmt: skip
        _put9(W, _JV + 9 * up, l, -l2 * k00, -l2 * k01, p02 - l2 * k02,
              p10 - l2 * k10, p11 - l2 * k11, p12 - l2 * k12,
              1.0 - l2 * k20, p21 - l2 * k21, p22 - l2 * k22)  # fmt: skip
        _put3(W, _AV + 3 * lo, l, l1 * au0, l1 * au1, l1 * au2)
        _put3(W, _AV + 3 * up, l, aP0 - l2 * au0, aP1 - l2 * au1, aP2 - l2 * au2)
        if spr:  # a constant: the branch is gone once i is known
            x0, x1, x2 = 0.0, ca, sa
        else:
            x0, x1, x2 = 1.0, 0.0, 0.0
        y0, y1, y2 = _cx(u0, u1, u2, x0, x1, x2)
        w00, w10, w20 = _cx(u0, u1, u2, k00, k10, k20)
        w01, w11, w21 = _cx(u0, u1, u2, k01, k11, k21)
        w02, w12, w22 = _cx(u0, u1, u2, k02, k12, k22)
        t0, t1, t2 = _cx(ud0, ud1, ud2, Juv0, Juv1, Juv2)
        s0, s1, s2 = _cx(u0, u1, u2, au0, au1, au2)
        e0, e1, e2 = t0 + s0, t1 + s1, t2 + s2
        if spr:
            w01 += u0 * u0
            w11 += u0 * u1
            w21 += u0 * u2
            e0 += v1 * (ud0 * u0 + u0 * ud0)
            e1 += v1 * (ud0 * u1 + u0 * ud1)
            e2 += v1 * (ud0 * u2 + u0 * ud2)
        _put9(W, _RB + 9 * lo, l, x0, y0, u0, x1, y1, u1, x2, y2, u2)
        _put9(W, _JW + 9 * lo, l, w00, w01, w02, w10, w11, w12, w20, w21, w22)
        _put3(W, _AW + 3 * lo, l, e0, e1, e2)


@kernel(inline="always", refcount=False)
def _body_kinematics(geom, X, Xd, v, l0, n, W):
    """:func:`~pkmctl.model.kinematics.body_jacobians` of lanes l0..l0+n into the block."""
    _trig(X, l0, n, W)
    _platform(X, Xd, v, l0, n, W)
    _limb_body(geom, X, Xd, v, l0, n, W, 0)
    _limb_body(geom, X, Xd, v, l0, n, W, 1)
    _limb_body(geom, X, Xd, v, l0, n, W, 2)
    _limb_body(geom, X, Xd, v, l0, n, W, 3)


# ---------------------------------------------------------------- M, C v, G
@kernel(inline="always", refcount=False)
def _translation(theta, W, j, l, b, s):
    """Body b's terms m J_v^T J_v, m J_v^T (dJ_v v), m dz/dX added to the sums s (as
    dynamics._assemble's first loop)."""
    m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2 = s
    m = theta[4 * b, j]
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = _get9(W, _JV + 9 * b, l)
    av0, av1, av2 = _get3(W, _AV + 3 * b, l)
    m00 += m * (a00 * a00 + a10 * a10 + a20 * a20)
    m01 += m * (a00 * a01 + a10 * a11 + a20 * a21)
    m02 += m * (a00 * a02 + a10 * a12 + a20 * a22)
    m11 += m * (a01 * a01 + a11 * a11 + a21 * a21)
    m12 += m * (a01 * a02 + a11 * a12 + a21 * a22)
    m22 += m * (a02 * a02 + a12 * a12 + a22 * a22)
    x0, x1, x2 = m * av0, m * av1, m * av2
    c0 += a00 * x0 + a10 * x1 + a20 * x2
    c1 += a01 * x0 + a11 * x1 + a21 * x2
    c2 += a02 * x0 + a12 * x1 + a22 * x2
    g0 += m * a20
    g1 += m * a21
    g2 += m * a22
    return m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2


@kernel(inline="always", refcount=False)
def _rotation(theta, Xd, v, W, j, l, f, s):
    """Frame f's rotational terms added to the sums s (as dynamics._assemble's second
    loop; the two bodies of a limb turn together, their inertias add)."""
    m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2 = s
    i0, i1, i2 = theta[4 * f + 1, j], theta[4 * f + 2, j], theta[4 * f + 3, j]
    if f > 0:  # a constant
        i0 += theta[4 * (f + 4) + 1, j]
        i1 += theta[4 * (f + 4) + 2, j]
        i2 += theta[4 * (f + 4) + 3, j]
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = _get9(W, _RB + 9 * f, l)
    J00, J01, J02, J10, J11, J12, J20, J21, J22 = _get9(W, _JW + 9 * f, l)
    aw0, aw1, aw2 = _get3(W, _AW + 3 * f, l)
    d0, d1, d2 = Xd[0, j], Xd[1, j], Xd[2, j]
    v0, v1, v2 = v[0, j], v[1, j], v[2, j]
    b00 = R00 * J00 + R10 * J10 + R20 * J20
    b01 = R00 * J01 + R10 * J11 + R20 * J21
    b02 = R00 * J02 + R10 * J12 + R20 * J22
    b10 = R01 * J00 + R11 * J10 + R21 * J20
    b11 = R01 * J01 + R11 * J11 + R21 * J21
    b12 = R01 * J02 + R11 * J12 + R21 * J22
    b20 = R02 * J00 + R12 * J10 + R22 * J20
    b21 = R02 * J01 + R12 * J11 + R22 * J21
    b22 = R02 * J02 + R12 * J12 + R22 * J22
    m00 += i0 * b00 * b00 + i1 * b10 * b10 + i2 * b20 * b20
    m01 += i0 * b00 * b01 + i1 * b10 * b11 + i2 * b20 * b21
    m02 += i0 * b00 * b02 + i1 * b10 * b12 + i2 * b20 * b22
    m11 += i0 * b01 * b01 + i1 * b11 * b11 + i2 * b21 * b21
    m12 += i0 * b01 * b02 + i1 * b11 * b12 + i2 * b21 * b22
    m22 += i0 * b02 * b02 + i1 * b12 * b12 + i2 * b22 * b22
    w0 = b00 * d0 + b01 * d1 + b02 * d2
    w1 = b10 * d0 + b11 * d1 + b12 * d2
    w2 = b20 * d0 + b21 * d1 + b22 * d2
    h0 = i0 * (b00 * v0 + b01 * v1 + b02 * v2)
    h1 = i1 * (b10 * v0 + b11 * v1 + b12 * v2)
    h2 = i2 * (b20 * v0 + b21 * v1 + b22 * v2)
    e0 = R00 * aw0 + R10 * aw1 + R20 * aw2
    e1 = R01 * aw0 + R11 * aw1 + R21 * aw2
    e2 = R02 * aw0 + R12 * aw1 + R22 * aw2
    t0 = i0 * e0 + w1 * h2 - w2 * h1
    t1 = i1 * e1 + w2 * h0 - w0 * h2
    t2 = i2 * e2 + w0 * h1 - w1 * h0
    c0 += b00 * t0 + b10 * t1 + b20 * t2
    c1 += b01 * t0 + b11 * t1 + b21 * t2
    c2 += b02 * t0 + b12 * t1 + b22 * t2
    return m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2


@kernel(inline="always", refcount=False)
def _assemble(geom, theta, Xd, v, l0, n, W):
    """M (upper triangle), C v and G of lanes l0..l0+n into the block, from its body
    kinematics: dynamics._assemble, its loops over bodies unrolled, the same sums in the
    same order. Two lane loops, translation then rotation, each under LLVM's limit of
    pointers per loop (see the module docstring)."""
    for l in range(n):
        j = np.uint64(l0 + l)
        s = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        s = _translation(theta, W, j, l, 0, s)
        s = _translation(theta, W, j, l, 1, s)
        s = _translation(theta, W, j, l, 2, s)
        s = _translation(theta, W, j, l, 3, s)
        s = _translation(theta, W, j, l, 4, s)
        s = _translation(theta, W, j, l, 5, s)
        s = _translation(theta, W, j, l, 6, s)
        s = _translation(theta, W, j, l, 7, s)
        s = _translation(theta, W, j, l, 8, s)
        m00, m01, m02, m11, m12, m22, c0, c1, c2, g0, g1, g2 = s
        g = geom[10, j]
        _put3(W, _MM, l, m00, m01, m02)
        _put3(W, _MM + 3, l, m11, m12, m22)
        _put3(W, _CV, l, c0, c1, c2)
        _put3(W, _GG, l, g * g0, g * g1, g * g2)
    for l in range(n):
        j = np.uint64(l0 + l)
        s = _get3(W, _MM, l) + _get3(W, _MM + 3, l) + _get3(W, _CV, l) + (0.0, 0.0, 0.0)
        s = _rotation(theta, Xd, v, W, j, l, 0, s)
        s = _rotation(theta, Xd, v, W, j, l, 1, s)
        s = _rotation(theta, Xd, v, W, j, l, 2, s)
        s = _rotation(theta, Xd, v, W, j, l, 3, s)
        s = _rotation(theta, Xd, v, W, j, l, 4, s)
        m00, m01, m02, m11, m12, m22, c0, c1, c2, _, _, _ = s
        _put3(W, _MM, l, m00, m01, m02)
        _put3(W, _MM + 3, l, m11, m12, m22)
        _put3(W, _CV, l, c0, c1, c2)


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
        _body_kinematics(geom, X, Xd, v, l0, n, W)
        _assemble(geom, theta, Xd, v, l0, n, W)
        _mcg_out(W, l0, n, M, Cv, G)
        _limbs_out(W, l0, n, work[LANE_JQ], work[LANE_Q])


# ---------------------------------------------------------------- gravity
@kernel(inline="always", refcount=False)
def _limb_z_rows(geom, X, W, j, l, i):
    """Limb i's q and J row, and row 2 (dz/dX) of its lower and upper bodies' J_v, as
    body_jacobians computes them (they do not depend on the velocities)."""
    r_a, r_b = geom[0, j], geom[1, j]
    l1, l2 = geom[2 + i, j], geom[6 + i, j]
    z = X[0, j]
    ca, sa, cb, sb = W[_ix(_CA, l)], W[_ix(_SA, l)], W[_ix(_CB, l)], W[_ix(_SB, l)]
    ta, zs = W[_ix(_TA, l)], W[_ix(_ZS, l)]
    _, _, _, qi, iq, u0, u1, u2, p02, p10, p11, p12, p21, p22 = _limb(
        r_a, r_b, z, ta, zs, ca, sa, cb, sb, i
    )
    j0, j1, j2 = _limb_row(u0, u1, u2, p02, p10, p11, p12, p21, p22)
    k20, k21, k22 = (1.0 - u2 * j0) * iq, (p21 - u2 * j1) * iq, (p22 - u2 * j2) * iq
    W[_ix((_Q + i), l)] = qi
    _put3(W, _JQ + 3 * i, l, j0, j1, j2)
    lower = (l1 * k20, l1 * k21, l1 * k22)
    upper = (1.0 - l2 * k20, p21 - l2 * k21, p22 - l2 * k22)
    return lower, upper


@kernel(inline="always", refcount=False)
def _add_mg(theta, j, b, g, row, s):
    """s += m_b g J_v[b, 2, :], as gravity_kernel sums it."""
    mg = theta[4 * b, j] * g
    return s[0] + mg * row[0], s[1] + mg * row[1], s[2] + mg * row[2]


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
            z = X[0, j]
            ca, sa = W[_ix(_CA, l)], W[_ix(_SA, l)]
            ta = sa / ca
            sec2 = 1.0 / (ca * ca)
            W[_ix(_TA, l)], W[_ix(_ZS, l)] = ta, z * sec2
            lo0, up0 = _limb_z_rows(geom, X, W, j, l, 0)
            lo1, up1 = _limb_z_rows(geom, X, W, j, l, 1)
            lo2, up2 = _limb_z_rows(geom, X, W, j, l, 2)
            lo3, up3 = _limb_z_rows(geom, X, W, j, l, 3)
            g = geom[10, j]
            s = (0.0, 0.0, 0.0)
            s = _add_mg(theta, j, 0, g, (1.0, 0.0, 0.0), s)  # the platform: dz/dX = e_z
            s = _add_mg(theta, j, 1, g, lo0, s)
            s = _add_mg(theta, j, 2, g, lo1, s)
            s = _add_mg(theta, j, 3, g, lo2, s)
            s = _add_mg(theta, j, 4, g, lo3, s)
            s = _add_mg(theta, j, 5, g, up0, s)
            s = _add_mg(theta, j, 6, g, up1, s)
            s = _add_mg(theta, j, 7, g, up2, s)
            s = _add_mg(theta, j, 8, g, up3, s)
            _put3(W, _GG, l, s[0], s[1], s[2])
        for a in range(3):
            _row_out(W, _GG + a, G[a], l0, n)
        _limbs_out(W, l0, n, work[LANE_JQ], work[LANE_Q])


# ---------------------------------------------------------------- the regressor
@kernel(inline="always", refcount=False)
def _inertia_column(W, l, b, nn, x0, x1, x2, c0, c1, c2, e0, e1, e2, o0, o1, o2,
                    w00, w01, w02, w10, w11, w12, w20, w21, w22):  # fmt: skip
    """Y[:, 4 b + 1 + nn] = J_w^T (x a_n + b_n omega x x), x = R[:, nn] (into the block)."""
    a_n = x0 * c0 + x1 * c1 + x2 * c2
    b_n = x0 * e0 + x1 * e1 + x2 * e2
    u0 = x0 * a_n + b_n * (o1 * x2 - o2 * x1)
    u1 = x1 * a_n + b_n * (o2 * x0 - o0 * x2)
    u2 = x2 * a_n + b_n * (o0 * x1 - o1 * x0)
    _put3(W, _Y + 27 + 9 * b + 3 * nn, l,  # block row _Y + 27 + 9 b + 3 nn + i: Y[i, 4 b + 1 + nn]
          w00 * u0 + w10 * u1 + w20 * u2,
          w01 * u0 + w11 * u1 + w21 * u2,
          w02 * u0 + w12 * u1 + w22 * u2)  # fmt: skip


@kernel(inline="always", refcount=False)
def _regressor_body(geom, Xd, Xr_d, Xr_dd, W, j, l, b):
    """Body b's columns of Y (dynamics._regressor_from_work's loop body): the mass column,
    and for b < 5 the three inertia columns, into the block (an upper limb's inertia
    columns are its lower limb's, copied out from there)."""
    g = geom[10, j]
    d0, d1, d2 = Xd[0, j], Xd[1, j], Xd[2, j]
    r0d, r1d, r2d = Xr_d[0, j], Xr_d[1, j], Xr_d[2, j]
    r0dd, r1dd, r2dd = Xr_dd[0, j], Xr_dd[1, j], Xr_dd[2, j]
    v00, v01, v02, v10, v11, v12, v20, v21, v22 = _get9(W, _JV + 9 * b, l)
    av0, av1, av2 = _get3(W, _AV + 3 * b, l)
    a0 = v00 * r0dd + v01 * r1dd + v02 * r2dd + av0
    a1 = v10 * r0dd + v11 * r1dd + v12 * r2dd + av1
    a2 = v20 * r0dd + v21 * r1dd + v22 * r2dd + av2
    m0 = v00 * a0 + v10 * a1 + v20 * a2 + g * v20
    m1 = v01 * a0 + v11 * a1 + v21 * a2 + g * v21
    m2 = v02 * a0 + v12 * a1 + v22 * a2 + g * v22
    _put3(W, _Y + 3 * b, l, m0, m1, m2)  # block row _Y + 3 b + i: Y[i, 4 b]
    if b >= 5:  # a constant
        return
    w00, w01, w02, w10, w11, w12, w20, w21, w22 = _get9(W, _JW + 9 * b, l)
    aw0, aw1, aw2 = _get3(W, _AW + 3 * b, l)
    c0 = aw0 + w00 * r0dd + w01 * r1dd + w02 * r2dd
    c1 = aw1 + w10 * r0dd + w11 * r1dd + w12 * r2dd
    c2 = aw2 + w20 * r0dd + w21 * r1dd + w22 * r2dd
    e0 = w00 * r0d + w01 * r1d + w02 * r2d
    e1 = w10 * r0d + w11 * r1d + w12 * r2d
    e2 = w20 * r0d + w21 * r1d + w22 * r2d
    o0 = w00 * d0 + w01 * d1 + w02 * d2
    o1 = w10 * d0 + w11 * d1 + w12 * d2
    o2 = w20 * d0 + w21 * d1 + w22 * d2
    R00, R01, R02, R10, R11, R12, R20, R21, R22 = _get9(W, _RB + 9 * b, l)
    # the scalar code's loop over the columns x = R[:, n], unrolled
    _inertia_column(W, l, b, 0, R00, R10, R20, c0, c1, c2, e0, e1, e2, o0, o1, o2, w00, w01, w02,
                    w10, w11, w12, w20, w21, w22)  # fmt: skip
    _inertia_column(W, l, b, 1, R01, R11, R21, c0, c1, c2, e0, e1, e2, o0, o1, o2, w00, w01, w02,
                    w10, w11, w12, w20, w21, w22)  # fmt: skip
    _inertia_column(W, l, b, 2, R02, R12, R22, c0, c1, c2, e0, e1, e2, o0, o1, o2, w00, w01, w02,
                    w10, w11, w12, w20, w21, w22)  # fmt: skip


@kernel(inline="always", refcount=False)
def _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, b):
    """Body b's columns of Y for lanes l0..l0+n: one lane loop per body, as all nine in
    one loop would pass LLVM's limit of pointers per loop."""
    for l in range(n):
        _regressor_body(geom, Xd, Xr_d, Xr_dd, W, np.uint64(l0 + l), l, b)


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
        _body_kinematics(geom, X, Xd, Xr_d, l0, n, W)
        _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, 0)
        _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, 1)
        _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, 2)
        _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, 3)
        _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, 4)
        _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, 5)
        _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, 6)
        _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, 7)
        _regressor_lanes(geom, Xd, Xr_d, Xr_dd, W, l0, n, 8)
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
def _limb_rate(geom, X, Xd, W, j, l, i):
    """Limb i of :func:`~pkmctl.model.kinematics.limb_jacobian_rate` with v = Xd: its
    row of J (to block rows _JQR), Jdot Xd and the limb rate qdot = J Xd."""
    r_a, r_b, z = geom[0, j], geom[1, j], X[0, j]
    zd, ad, bd = Xd[0, j], Xd[1, j], Xd[2, j]
    ca, sa = W[_ix(_CA, l)], W[_ix(_SA, l)]
    ta, sec2, zs = W[_ix(_TA, l)], W[_ix(_SEC2, l)], W[_ix(_ZS, l)]
    R = _get9(W, _RB, l)
    ox, oy = r_a * _LIMB_DIR[i, 0], r_a * _LIMB_DIR[i, 1]
    rx, ry, rz, p02, p10, p11, p12, p21, p22, a0, a1, a2 = _point(
        z, ta, zs, sec2, ca, sa, R, ox, oy, 0.0, zd, ad, bd, zd, ad, bd
    )
    d0, d1, d2 = rx - r_b * _LIMB_DIR[i, 0], -z * ta + ry - r_b * _LIMB_DIR[i, 1], z + rz
    qi = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    iq = 1.0 / qi
    u0, u1, u2 = d0 * iq, d1 * iq, d2 * iq
    j0, j1, j2 = _limb_row(u0, u1, u2, p02, p10, p11, p12, p21, p22)
    Pd0 = p02 * bd
    Pd1 = p10 * zd + p11 * ad + p12 * bd
    Pd2 = zd + p21 * ad + p22 * bd
    Pv0 = p02 * bd
    Pv1 = p10 * zd + p11 * ad + p12 * bd
    Pv2 = zd + p21 * ad + p22 * bd
    qd = u0 * Pd0 + u1 * Pd1 + u2 * Pd2
    qv = u0 * Pv0 + u1 * Pv1 + u2 * Pv2
    jdv = (Pd0 * Pv0 + Pd1 * Pv1 + Pd2 * Pv2 - qd * qv) * iq + (u0 * a0 + u1 * a1 + u2 * a2)
    _put3(W, _JQR + 3 * i, l, j0, j1, j2)
    W[_ix((_JDV + i), l)] = jdv
    # the limb rate of the friction law, from this Jacobian (as plants._machine_terms)
    W[_ix((_QD + i), l)] = j0 * zd + j1 * ad + j2 * bd


@kernel(inline="always", refcount=False)
def _rotor(m, W, l, i, s):
    """Limb i's reflected rotor inertia m added to s = (M's upper triangle, C v), as
    machine.add_rotor_inertia adds it: M += m J_i^T J_i, C v += m J_i^T (Jdot_i Xd)."""
    m00, m01, m02, m11, m12, m22, c0, c1, c2 = s
    j0, j1, j2 = _get3(W, _JQR + 3 * i, l)
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
    j0, j1, j2 = _get3(W, _JQR + 3 * i, l)
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
        _limb_rate(p.geom, X, Xd, W, j, l, 0)
        _limb_rate(p.geom, X, Xd, W, j, l, 1)
        _limb_rate(p.geom, X, Xd, W, j, l, 2)
        _limb_rate(p.geom, X, Xd, W, j, l, 3)
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
        _body_kinematics(p.geom, X, Xd, Xd, l0, n, W)
        _assemble(p.geom, p.theta, Xd, Xd, l0, n, W)
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
