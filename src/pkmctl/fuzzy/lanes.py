"""The fast kernel of :mod:`pkmctl.fuzzy.kernels` for L points at once (SIMD lanes).

The scalar kernel ``_grid_eval2`` finds each input's cell, evaluates the two terms that
can be non-zero there, fires the cell's four rules and integrates the output cells those
rules touch: table lookups and branches that depend on the input, so a loop around it
runs lane by lane (and, on a closed loop's noisy inputs, mispredicts its branches). Here
the lanes of a block (8) run the same instructions on the same table entries, so no
lane's cell index is ever used to index (gathers, which LLVM's cost model scalarises):

1. each input clipped, its cell found, per lane; the block's range of cells;
2. every term of that range, masked per lane to the two terms of the lane's own cell
   (so exactly the scalar kernel's memberships, zero elsewhere);
3. every rule among those terms, max-aggregated into the clip levels (the rules the
   scalar kernel skips have strength 0 in that lane);
4. every output cell those rules' consequents touch, each branch of the scalar cell
   integral computed and one chosen by a select, added where that lane's levels touch
   the cell (elsewhere + 0.0, which leaves the sum unchanged);
5. the centroid, or the midpoint where no rule fired, or NaN for a NaN input.

Every loop over the lanes is innermost and branch-free, on scratch in stack blocks, and
LLVM vectorises it. Lane l's result is the scalar kernel's at (x1[l], x2[l]) bit for bit:
the same operations on the same operands in the same order (tests/test_fuzzy_lanes.py
checks it over grid points and their neighbouring floats, random points in and beyond
the universes, NaN and infinities, on the paper's FLC, other grids and the .fis corpus).
A system with more than :data:`MAX_TERMS` terms on a variable runs lane by lane on the
scalar kernel.
"""

from __future__ import annotations

import math

import numpy as np

from pkmctl._jit import kernel
from pkmctl.fuzzy.kernels import (
    _K,
    _O_CELLS,
    _O_GCONS,
    _O_GW,
    _O_INV,
    _O_KIN,
    _O_PIN,
    _O_ROUT,
    _SMF,
    _T,
    _THIRD,
    _TRAP,
    _TRI,
    _ZMF,
    CELL_SIZE,
    O_NT,
    O_RIN,
    _grid_eval2,
    mf_piece,
)
from pkmctl.model.lanes import LANE_BLOCK as _B
from pkmctl.model.lanes import _ix, _stack_block, wide_vectors

__all__ = ["MAX_TERMS", "grid_eval_lanes"]

# As the scalar kernels: no FMA contraction (bit-identical results), no reference counting.
_jit_inl = kernel(fastmath=False, refcount=False, llvm_inline=True)

#: The largest number of terms per input (T) and output terms (K) the lane kernel
#: holds in its stack block; a larger system runs lane by lane on the scalar kernel.
MAX_TERMS = 16
# The stack blocks (rows of one block of lanes each; separate blocks, so that LLVM sees
# that a loop writing one row cannot feed its reads of another at a run-time row):
# WX the clipped inputs (rows 0, 1) and their cells as floats (rows 2, 3); WMU the
# memberships (input i, term j at row i MAX_TERMS + j); WLEV the clip levels (row k);
# WM the moments (rows 0, 1).
_C = 2
_SIZE_X = 4 * _B
_SIZE_MU = 2 * MAX_TERMS * _B
_SIZE_LEV = MAX_TERMS * _B
_SIZE_M = 2 * _B


@kernel(inline="always", fastmath=False, refcount=False)
def _memberships(kind, a, b, c, d, WX, rx, rc, j, WMU, row, n):
    """Row ``row`` of WMU <- μ_j (mf_piece's value) at the inputs of row ``rx`` of WX
    where term j is one of the two of the lane's cell (row ``rc``), else 0; one
    branch-free loop over the lanes per kind."""
    fj = float(j)
    if kind == _TRI:
        iup, idown = 1.0 / (b - a), 1.0 / (c - b)
        for l in range(n):
            y = WX[_ix(rx, l)]
            up = (y - a) * iup
            down = (c - y) * idown
            v = down if b < y and y < c else 0.0
            v = up if a < y and y < b else v
            v = 1.0 if y == b else v
            cl = WX[_ix(rc, l)]
            WMU[_ix(row, l)] = v if cl == fj or cl + 1.0 == fj else 0.0
    elif kind == _TRAP:
        iup, idown = 1.0 / (b - a), 1.0 / (d - c)
        for l in range(n):
            y = WX[_ix(rx, l)]
            up = (y - a) * iup
            down = (d - y) * idown
            v = 1.0 if y <= c else down
            v = up if y < b else v
            v = 0.0 if y < a or y > d else v
            cl = WX[_ix(rc, l)]
            WMU[_ix(row, l)] = v if cl == fj or cl + 1.0 == fj else 0.0
    elif kind == _ZMF:
        w2 = (b - a) * (b - a)
        for l in range(n):
            y = WX[_ix(rx, l)]
            t = y - a
            lo = 1.0 - 2.0 * t * t / w2
            t = y - b
            v = lo if y <= 0.5 * (a + b) else 2.0 * t * t / w2
            v = 0.0 if y >= b else v
            v = 1.0 if y <= a else v
            cl = WX[_ix(rc, l)]
            WMU[_ix(row, l)] = v if cl == fj or cl + 1.0 == fj else 0.0
    elif kind == _SMF:
        w2 = (b - a) * (b - a)
        for l in range(n):
            y = WX[_ix(rx, l)]
            t = y - a
            lo = 2.0 * t * t / w2
            t = y - b
            v = lo if y <= 0.5 * (a + b) else 1.0 - 2.0 * t * t / w2
            v = 0.0 if y <= a else v
            v = 1.0 if y >= b else v
            cl = WX[_ix(rc, l)]
            WMU[_ix(row, l)] = v if cl == fj or cl + 1.0 == fj else 0.0
    else:  # not on a grid (a Gaussian is nowhere zero): the scalar function, per lane
        for l in range(n):
            v = mf_piece(kind, a, b, c, d, WX[_ix(rx, l)])[0]
            cl = WX[_ix(rc, l)]
            WMU[_ix(row, l)] = v if cl == fj or cl + 1.0 == fj else 0.0


@_jit_inl
def _ramp_int(shape, t):
    """pkmctl.fuzzy.kernels._ramp_int with every branch computed and one chosen."""
    full0 = 0.5 + (t - 1.0)
    full1 = (1.0 / 3.0 if shape == 0 else 17.0 / 48.0) + 0.5 * (t * t - 1.0)
    lin0 = 0.5 * t * t
    lin1 = t * t * t * _THIRD
    low0 = 2.0 * t**3 * _THIRD
    low1 = 0.5 * t**4
    s = 1.0 - t
    high0 = t - 0.5 + 2.0 * s**3 * _THIRD
    high1 = t * t * (-0.5 + t * (4.0 / 3.0 - 0.5 * t)) + 1.0 / 48.0
    r0 = low0 if t <= 0.5 else high0
    r1 = low1 if t <= 0.5 else high1
    r0 = lin0 if shape == 0 else r0
    r1 = lin1 if shape == 0 else r1
    r0 = full0 if t >= 1.0 else r0
    r1 = full1 if t >= 1.0 else r1
    r0 = 0.0 if t <= 0.0 else r0
    r1 = 0.0 if t <= 0.0 else r1
    return r0, r1


@_jit_inl
def _ramp_inv(shape, h):
    h = min(max(h, 0.0), 1.0)
    lo = math.sqrt(0.5 * h)
    hi = 1.0 - math.sqrt(0.5 * (1.0 - h))
    v = lo if h <= 0.5 else hi
    return h if shape == 0 else v


@_jit_inl
def _ramp_moments(shape, p, w, iw, u, v):
    f0, f1 = _ramp_int(shape, (u - p) * iw)
    F0, F1 = _ramp_int(shape, (v - p) * iw)
    return w * (F0 - f0), w * (p * (F0 - f0) + w * (F1 - f1))


@kernel(inline="always", fastmath=False, refcount=False)
def _cell_loop(q, reals, WLEV, WM, m, sa, sb, n):
    """Rows 0, 1 of WM += the moments of output cell m in every lane where a rule touching
    it fired (pkmctl.fuzzy.kernels._cell_moments, branch-free); sa, sb the shapes of its
    two ramps, constants where :func:`_cell_lanes` calls it."""
    g0, g1, qa, wa = reals[q], reals[q + 1], reals[q + 3], reals[q + 4]
    pb, wb, yc, vc = reals[q + 6], reals[q + 7], reals[q + 8], reals[q + 9]
    iwa, iwb = reals[q + 10], reals[q + 11]
    for l in range(n):
        ha = WLEV[_ix(m, l)]
        hb = WLEV[_ix(m + 1, l)]
        ys_b = pb + wb * _ramp_inv(sb, ha)
        ys_a = qa - wa * _ramp_inv(sa, hb)
        ys = ys_b if ha < hb else ys_a
        ys = yc if vc <= min(ha, hb) else ys
        ys = min(max(ys, g0), g1)
        e = min(max(qa - wa * _ramp_inv(sa, ha), g0), ys)
        m0 = ha * (e - g0)
        m1 = ha * 0.5 * (e * e - g0 * g0)
        i0, i1 = _ramp_moments(sa, -qa, wa, iwa, -ys, -e)
        m0 = m0 + i0 if ys > e else m0
        m1 = m1 - i1 if ys > e else m1
        e = max(min(pb + wb * _ramp_inv(sb, hb), g1), ys)
        m0 += hb * (g1 - e)
        m1 += hb * 0.5 * (g1 * g1 - e * e)
        i0, i1 = _ramp_moments(sb, pb, wb, iwb, ys, e)
        m0 = m0 + i0 if e > ys else m0
        m1 = m1 + i1 if e > ys else m1
        on = ha > 0.0 or hb > 0.0
        # The scalar kernel adds only where on. Adding 0.0 elsewhere is the same: a sum
        # that starts at +0.0 is never -0.0. (A store of "a0 + m0 if on else a0" would
        # compile to a masked scatter.)
        WM[_ix(0, l)] = WM[_ix(0, l)] + (m0 if on else 0.0)
        WM[_ix(1, l)] = WM[_ix(1, l)] + (m1 if on else 0.0)


@kernel(inline="always", fastmath=False, refcount=False)
def _cell_lanes(q, reals, WLEV, WM, m, n):
    """:func:`_cell_loop` compiled for the shapes of the cell's ramps (only the branches
    of that shape are computed)."""
    sa, sb = reals[q + 2], reals[q + 5]
    if sa == 0.0 and sb == 0.0:
        _cell_loop(q, reals, WLEV, WM, m, 0, 0, n)
    elif sa == 0.0:
        _cell_loop(q, reals, WLEV, WM, m, 0, 1, n)
    elif sb == 0.0:
        _cell_loop(q, reals, WLEV, WM, m, 1, 0, n)
    else:
        _cell_loop(q, reals, WLEV, WM, m, 1, 1, n)


@kernel(inline="always", fastmath=False, refcount=False)
def _block(ints, reals, x1, x2, out, l0, n, WX, WMU, WLEV, WM):
    """Lanes l0 .. l0 + n - 1 (n <= _B) through the stack blocks. Every loop over the
    lanes runs to n, not to the constant _B: LLVM would unroll a constant 8 into scalar
    code before its loop vectoriser sees it."""
    T = ints[_T]
    K = ints[_K]
    r = ints[O_RIN]
    kin = ints[_O_KIN]
    c0 = 0
    c1 = 0
    d0 = 0
    d1 = 0
    for i in range(2):  # clip each input; its cell on the uniform grid (_locate)
        x = x1 if i == 0 else x2
        lo, hi = reals[r + 2 * i], reals[r + 2 * i + 1]
        inv = reals[ints[_O_INV] + i]
        nt = ints[ints[O_NT] + i]
        cmin = nt
        cmax = 0
        for l in range(n):
            v = x[np.uint64(l0 + l)]
            v = min(max(v, lo), hi)
            v = lo if v != v else v  # a NaN lane's output is NaN (below); keep its cell valid
            WX[_ix(i, l)] = v
            c = min(max(int((v - lo) * inv), 0), nt - 2)
            WX[_ix(_C + i, l)] = float(c)
            cmin = min(cmin, c)
            cmax = max(cmax, c)
        for j in range(cmin, cmax + 2):  # the terms of the lanes' cells (and between them)
            q = ints[_O_PIN] + 4 * (i * T + j)
            _memberships(ints[kin + i * T + j], reals[q], reals[q + 1], reals[q + 2],
                         reals[q + 3], WX, i, _C + i, j, WMU, i * MAX_TERMS + j, n)  # fmt: skip
        if i == 0:
            c0, c1 = cmin, cmax + 2
        else:
            d0, d1 = cmin, cmax + 2
    for k in range(K):
        for l in range(n):
            WLEV[_ix(k, l)] = 0.0
    kmin = K
    kmax = -1
    for j1 in range(c0, c1):  # the rules of those terms; each lane's other terms are 0
        for j2 in range(d0, d1):
            k = ints[ints[_O_GCONS] + j1 * T + j2]
            if k < 0:
                continue
            kmin = min(kmin, k)
            kmax = max(kmax, k)
            w = reals[ints[_O_GW] + j1 * T + j2]
            rb = MAX_TERMS + j2
            for l in range(n):
                WLEV[_ix(k, l)] = max(WLEV[_ix(k, l)], min(WMU[_ix(j1, l)], WMU[_ix(rb, l)]) * w)
    for l in range(n):
        WM[_ix(0, l)] = 0.0
        WM[_ix(1, l)] = 0.0
    for m in range(max(kmin - 1, 0), min(kmax, K - 2) + 1):  # the output cells they touch
        touched = 0
        for l in range(n):
            touched += (WLEV[_ix(m, l)] > 0.0) | (WLEV[_ix(m + 1, l)] > 0.0)
        if touched > 0:
            _cell_lanes(ints[_O_CELLS] + CELL_SIZE * m, reals, WLEV, WM, m, n)
    lo = reals[ints[_O_ROUT]]
    hi = reals[ints[_O_ROUT] + 1]
    mid = 0.5 * (lo + hi)
    for l in range(n):
        m0 = WM[_ix(0, l)]
        v = min(max(WM[_ix(1, l)] / m0, lo), hi)
        v = mid if m0 <= 0.0 else v
        j = np.uint64(l0 + l)
        out[j] = np.nan if x1[j] != x1[j] or x2[j] != x2[j] else v


@_jit_inl
def grid_eval_lanes(ints, reals, x1, x2, out):
    """out[l] = the fast kernel at (x1[l], x2[l]) for every lane l, bit for bit.

    Parameters
    ----------
    ints, reals : arrays
        A compiled system on the fast kernel (``FISTables``; the caller checks).
    x1, x2, out : ndarray, shape (L,)
    """
    wide_vectors()
    L = out.shape[0]
    if ints[_T] > MAX_TERMS or ints[_K] > MAX_TERMS:
        for l in range(L):
            out[l] = _grid_eval2(ints, reals, x1[l], x2[l])
        return
    WX, WMU = _stack_block(_SIZE_X), _stack_block(_SIZE_MU)
    WLEV, WM = _stack_block(_SIZE_LEV), _stack_block(_SIZE_M)
    for l0 in range(0, L, _B):
        _block(ints, reals, x1, x2, out, l0, min(_B, L - l0), WX, WMU, WLEV, WM)
