"""Numba kernels of the Mamdani engine of :mod:`pkmctl.fuzzy` (evaluation and exact centroid).

Kept apart from the Python-level classes so that each file stays readable; the public
entry points :func:`flc_eval` and :func:`mamdani_eval` are re-exported by
:mod:`pkmctl.fuzzy`. The table layout they read is documented in
:class:`pkmctl.fuzzy.FISTables`.
"""

from __future__ import annotations

import math

import numpy as np
from numba.core.errors import TypingError
from numba.extending import overload

from pkmctl._jit import JIT_OPTIONS, NO_REFCOUNT, kernel
from pkmctl.model.simd import unsigned as _u  # table offsets: ten reads per output cell

__all__ = ["flc_eval", "mamdani_eval"]

_TRI, _TRAP, _GAUSS, _ZMF, _SMF = 0, 1, 2, 3, 4
# Divisions by a number the inputs do not change are multiplications by its reciprocal
# (one rounding more, the same in every kernel): a division is the slowest arithmetic
# instruction and gains the least from SIMD lanes. In pkmctl.fuzzy.lanes the reciprocal
# is computed once per term or output cell, and the lanes divide only in the centroid.
_THIRD = 1.0 / 3.0

# No FMA contraction here (unlike pkmctl._jit.kernel); reference counting said explicitly,
# as pkmctl._jit explains, since flc_eval is called from the refcount-free loop.
_jit = kernel(fastmath=False)
# The scalar path the control loop takes (flc_eval -> _grid_eval2) never allocates: it is
# compiled without reference counting, which saves ~4 atomic operations per call.
_jit_free = kernel(fastmath=False, refcount=False)
_jit_inl = kernel(fastmath=False, refcount=False, llvm_inline=True)

# FISTables layout: two flat arrays. ints[:HEADER] = [n_in, K, R, T, fast] followed by
# the offsets of the sections INT_SECTIONS in ints and REAL_SECTIONS in reals.
INT_SECTIONS = ("in_nterms", "in_kind", "out_kind", "rule_ant", "rule_cons", "grid_cons")
REAL_SECTIONS = (
    "in_range",
    "grid_inv_step",
    "in_params",
    "out_range",
    "out_params",
    "rule_weight",
    "grid_weight",
    "cells",
)
_N_IN, _K, _R, _T, _FAST = range(5)
#: Where ``ints`` says whether a system qualifies for the fast (grid) kernel (1) or not.
FAST_SLOT = _FAST
O_NT, _O_KIN, _O_KOUT, _O_ANT, _O_CONS, _O_GCONS = range(5, 11)
O_RIN, _O_INV, _O_PIN, _O_ROUT, _O_POUT, _O_W, _O_GW, _O_CELLS = range(11, 19)
HEADER = 19
#: Numbers per output cell in the ``cells`` section (pkmctl.fuzzy.FISTables).
CELL_SIZE = 12

# ---------------------------------------------------------------------------------------
# Scalar kernels and the general exact centroid. One formula per membership function:
# `mf_piece` serves evaluation (its value) and the exact centroid (its local polynomial).
# ---------------------------------------------------------------------------------------


@_jit_inl
def mf_piece(kind, a, b, c, d, y):
    """Local polynomial of μ at y: μ(y + u) = v0 + v1 u + v2 u² on the piece holding y.

    For Gaussians only v0 is meaningful (they are not piecewise polynomial).
    """
    if kind == _TRI:  # a <= b <= c; MATLAB's trimf
        if y == b:
            return 1.0, 0.0, 0.0
        if a < y < b:
            up = 1.0 / (b - a)
            return (y - a) * up, up, 0.0
        if b < y < c:
            down = 1.0 / (c - b)
            return (c - y) * down, -down, 0.0
        return 0.0, 0.0, 0.0
    if kind == _TRAP:  # a <= b <= c <= d; MATLAB's trapmf
        if y < a or y > d:
            return 0.0, 0.0, 0.0
        if y < b:
            up = 1.0 / (b - a)
            return (y - a) * up, up, 0.0
        if y <= c:
            return 1.0, 0.0, 0.0
        down = 1.0 / (d - c)
        return (d - y) * down, -down, 0.0
    if kind == _GAUSS:  # a = mean, b = sigma
        return math.exp(-((y - a) ** 2) / (2.0 * b * b)), 0.0, 0.0
    if kind == _ZMF:  # quadratic Z spline from a (1) to b (0); a == b is a step
        if y <= a:
            return 1.0, 0.0, 0.0
        if y >= b:
            return 0.0, 0.0, 0.0
        w2 = (b - a) * (b - a)
        if y <= 0.5 * (a + b):
            t = y - a
            return 1.0 - 2.0 * t * t / w2, -4.0 * t / w2, -2.0 / w2
        t = y - b
        return 2.0 * t * t / w2, 4.0 * t / w2, 2.0 / w2
    # _SMF: quadratic S spline from a (0) to b (1); a == b is a step (1 at a, as MATLAB)
    if y >= b:
        return 1.0, 0.0, 0.0
    if y <= a:
        return 0.0, 0.0, 0.0
    w2 = (b - a) * (b - a)
    if y <= 0.5 * (a + b):
        t = y - a
        return 2.0 * t * t / w2, 4.0 * t / w2, 2.0 / w2
    t = y - b
    return 1.0 - 2.0 * t * t / w2, -4.0 * t / w2, -2.0 / w2


@_jit
def _clipped_piece(kind, a, b, c, d, h, y):
    """Local polynomial of min(h, μ) at y (the implication of a rule firing at h)."""
    v0, v1, v2 = mf_piece(kind, a, b, c, d, y)
    if v0 >= h:
        return h, 0.0, 0.0
    return v0, v1, v2


@_jit
def _above(best, t, y):
    return t if y < t < best else best


@_jit
def _next_break(kind, a, b, c, d, h, y):
    """Smallest breakpoint of min(h, μ) strictly greater than y (inf if none).

    Breakpoints are the feet, peaks and spline midpoints of μ and the points where
    μ = h; between two consecutive ones min(h, μ) is a single polynomial (or smooth).
    """
    best = np.inf
    if kind == _TRI:
        best = _above(_above(_above(best, a, y), b, y), c, y)
        best = _above(_above(best, a + h * (b - a), y), c - h * (c - b), y)
    elif kind == _TRAP:
        best = _above(_above(_above(_above(best, a, y), b, y), c, y), d, y)
        best = _above(_above(best, a + h * (b - a), y), d - h * (d - c), y)
    elif kind == _GAUSS:
        best = _above(best, a, y)
        if 0.0 < h < 1.0:
            r = b * math.sqrt(-2.0 * math.log(h))
            best = _above(_above(best, a - r, y), a + r, y)
    else:
        best = _above(_above(_above(best, a, y), 0.5 * (a + b), y), b, y)
        if h < 1.0:
            up = h if kind == _SMF else 1.0 - h  # solve the rising S spline for `up`
            t = math.sqrt(0.5 * up) if up <= 0.5 else 1.0 - math.sqrt(0.5 * (1.0 - up))
            best = _above(best, a + t * (b - a), y)
    return best


@_jit
def _next_break_any(kind, prm, levels, act, na, cur, hi):
    """The first breakpoint after ``cur`` of any active clipped output term (or ``hi``)."""
    nxt = hi
    for i in range(na):
        k = act[i]
        p = prm[k]
        nxt = min(nxt, _next_break(kind[k], p[0], p[1], p[2], p[3], levels[k], cur))
    return nxt


@_jit
def _roots_in(d0, d1, d2, lo, hi):
    """Real roots of d0 + d1 u + d2 u² strictly inside (lo, hi): (count, r1, r2), r1 <= r2."""
    r1 = np.inf
    r2 = np.inf
    if d2 == 0.0:
        if d1 != 0.0:
            r1 = -d0 / d1
    else:
        disc = d1 * d1 - 4.0 * d2 * d0
        if disc >= 0.0:
            q = -0.5 * (d1 + math.copysign(math.sqrt(disc), d1))  # stable form
            r1 = q / d2
            if q != 0.0:
                r2 = d0 / q
            if r2 < r1:
                r1, r2 = r2, r1
    n = 0
    out1 = np.inf
    out2 = np.inf
    if lo < r1 < hi:
        out1 = r1
        n = 1
    if lo < r2 < hi and r2 != r1:
        if n == 0:
            out1 = r2
        else:
            out2 = r2
        n += 1
    return n, out1, out2


@_jit
def _poly_moments(v0, v1, v2, y0, u0, u1):
    """∫ p and ∫ y p over y in [y0 + u0, y0 + u1] for p = v0 + v1 u + v2 u², u = y - y0."""
    e1 = u1 - u0
    e2 = (u1 * u1 - u0 * u0) / 2.0
    e3 = (u1**3 - u0**3) / 3.0
    e4 = (u1**4 - u0**4) / 4.0
    m0 = v0 * e1 + v1 * e2 + v2 * e3
    return m0, y0 * m0 + v0 * e2 + v1 * e3 + v2 * e4


@_jit
def _cog_poly(kind, prm, lo, hi, levels, act, na):
    """Exact (∫ μ, ∫ y μ) of the aggregate over [lo, hi]; piecewise-polynomial terms only.

    ``act[:na]`` lists the output terms with a positive level. Between consecutive
    breakpoints of all clipped terms each is one polynomial; the pairwise crossings split
    that piece further so that the maximum is one polynomial, integrated in closed form.
    """
    coef = np.empty((na, 3))
    roots = np.empty(na * (na - 1) + 1)
    m0 = 0.0
    m1 = 0.0
    cur = lo
    while cur < hi:
        nxt = _next_break_any(kind, prm, levels, act, na, cur, hi)
        y0 = 0.5 * (cur + nxt)
        r = 0.5 * (nxt - cur)
        for i in range(na):
            k = act[i]
            p = prm[k]
            coef[i, 0], coef[i, 1], coef[i, 2] = _clipped_piece(
                kind[k], p[0], p[1], p[2], p[3], levels[k], y0
            )
        nr = 0
        for i in range(na):
            for j in range(i + 1, na):
                n, r1, r2 = _roots_in(
                    coef[i, 0] - coef[j, 0], coef[i, 1] - coef[j, 1], coef[i, 2] - coef[j, 2], -r, r
                )
                if n > 0:
                    roots[nr] = r1
                    nr += 1
                if n > 1:
                    roots[nr] = r2
                    nr += 1
        roots[:nr].sort()
        u0 = -r
        for s in range(nr + 1):
            u1 = r if s == nr else roots[s]
            if u1 > u0:
                um = 0.5 * (u0 + u1)
                best = 0
                vbest = -1.0
                for i in range(na):
                    v = coef[i, 0] + um * (coef[i, 1] + um * coef[i, 2])
                    if v > vbest:
                        vbest = v
                        best = i
                i0, i1 = _poly_moments(coef[best, 0], coef[best, 1], coef[best, 2], y0, u0, u1)
                m0 += i0
                m1 += i1
            u0 = u1
        cur = nxt
    return m0, m1


# 5-point Gauss-Legendre on [-1, 1]
_GL_X = np.array(
    [-0.9061798459386640, -0.5384693101056831, 0.0, 0.5384693101056831, 0.9061798459386640]
)
_GL_W = np.array(
    [
        0.2369268850561891,
        0.4786286704993665,
        0.5688888888888889,
        0.4786286704993665,
        0.2369268850561891,
    ]
)
_QUAD_PANELS = 512  # panels per universe width for Gaussian output terms


@_jit
def _envelope(kind, prm, levels, act, na, y):
    """(max_k min(h_k, μ_k(y)), argmax k) over the active output terms."""
    best = -1.0
    kbest = act[0]
    for i in range(na):
        k = act[i]
        p = prm[k]
        v = min(levels[k], mf_piece(kind[k], p[0], p[1], p[2], p[3], y)[0])
        if v > best:
            best = v
            kbest = k
    return best, kbest


@_jit
def _next_resolution(kind, prm, act, na, cur, hmax):
    """The first node after ``cur`` that resolves a Gaussian narrower than two panels
    (sigma < 2 hmax): its mean +- sigma/2, sigma, ... 8 sigma, as
    :func:`pkmctl.fuzzy.mf.resolution_nodes` gives the general engine (inf if none)."""
    best = np.inf
    for i in range(na):
        k = act[i]
        if kind[k] == _GAUSS and prm[k, 1] < 2.0 * hmax:
            m = prm[k, 0]
            s = prm[k, 1]
            for j in range(1, 17):
                best = _above(_above(best, m - 0.5 * j * s, cur), m + 0.5 * j * s, cur)
    return best


@_jit
def _gl_moments(kind, prm, levels, act, na, a, b):
    m0 = 0.0
    m1 = 0.0
    c = 0.5 * (a + b)
    r = 0.5 * (b - a)
    for g in range(5):
        y = c + r * _GL_X[g]
        v = _envelope(kind, prm, levels, act, na, y)[0]
        m0 += _GL_W[g] * r * v
        m1 += _GL_W[g] * r * v * y
    return m0, m1


@_jit
def _cog_quad(kind, prm, lo, hi, levels, act, na):
    """(∫ μ, ∫ y μ) of the aggregate when some active output term is Gaussian.

    Pieces between the breakpoints of the clipped terms (including the Gaussians' clip
    points, and around a Gaussian narrower than two panels the nodes of
    :func:`_next_resolution`) are cut into panels of width <= (hi - lo) / 512. Where the
    top term changes inside a panel, the crossing is found by bisection and each side is
    integrated with 5-point Gauss-Legendre, so the integrand is smooth on every
    sub-panel; the error is far below 1e-6 (tests check it against a very fine reference
    integral).
    """
    m0 = 0.0
    m1 = 0.0
    hmax = (hi - lo) / _QUAD_PANELS
    cur = lo
    while cur < hi:
        nxt = min(_next_break_any(kind, prm, levels, act, na, cur, hi),
                  _next_resolution(kind, prm, act, na, cur, hmax))  # fmt: skip
        npan = max(1, int(math.ceil((nxt - cur) / hmax)))
        for j in range(npan):
            a = cur + (nxt - cur) * j / npan
            b = nxt if j == npan - 1 else cur + (nxt - cur) * (j + 1) / npan
            ka = _envelope(kind, prm, levels, act, na, a + (b - a) * 1e-9)[1]
            kb = _envelope(kind, prm, levels, act, na, b - (b - a) * 1e-9)[1]
            split = b
            if ka != kb:
                pa = prm[ka]
                pb = prm[kb]
                lo_s = a
                hi_s = b
                for _ in range(60):
                    mid = 0.5 * (lo_s + hi_s)
                    va = min(levels[ka], mf_piece(kind[ka], pa[0], pa[1], pa[2], pa[3], mid)[0])
                    vb = min(levels[kb], mf_piece(kind[kb], pb[0], pb[1], pb[2], pb[3], mid)[0])
                    if va >= vb:
                        lo_s = mid
                    else:
                        hi_s = mid
                split = 0.5 * (lo_s + hi_s)
            i0, i1 = _gl_moments(kind, prm, levels, act, na, a, split)
            m0 += i0
            m1 += i1
            if split < b:
                i0, i1 = _gl_moments(kind, prm, levels, act, na, split, b)
                m0 += i0
                m1 += i1
        cur = nxt
    return m0, m1


@_jit
def _point_masses(kind, prm, lo, hi, levels, act, na):
    """Centroid of a zero-area aggregate whose rules fire (singletons such as trimf
    [c c c]): the mean of the points where the aggregate is positive, weighted by its
    value there, the limit of MATLAB's sampled centroid when they are samples."""
    pts = np.empty(4 * na)
    n = 0
    for i in range(na):
        for j in range(4):
            y = prm[act[i], j]
            if lo <= y <= hi:
                pts[n] = y
                n += 1
    pts[:n].sort()
    m0 = 0.0
    m1 = 0.0
    for j in range(n):
        if j == 0 or pts[j] != pts[j - 1]:
            v = _envelope(kind, prm, levels, act, na, pts[j])[0]
            m0 += v
            m1 += v * pts[j]
    if m0 <= 0.0:
        return 0.5 * (lo + hi)
    return min(max(m1 / m0, lo), hi)


@_jit
def _centroid_flag(kind, prm, lo, hi, levels):
    """(centroid, 1 if the aggregate had zero area although rules fired, else 0)."""
    K = kind.shape[0]
    act = np.empty(K, dtype=np.int64)
    na = 0
    gauss = False
    for k in range(K):
        if levels[k] > 0.0:
            act[na] = k
            na += 1
            gauss = gauss or kind[k] == _GAUSS
    if na == 0:
        return 0.5 * (lo + hi), 0
    if gauss:
        m0, m1 = _cog_quad(kind, prm, lo, hi, levels, act, na)
    else:
        m0, m1 = _cog_poly(kind, prm, lo, hi, levels, act, na)
    if m0 <= 0.0:
        return _point_masses(kind, prm, lo, hi, levels, act, na), 1
    return min(max(m1 / m0, lo), hi), 0


@_jit
def _centroid(kind, prm, lo, hi, levels):
    """Centre of gravity of max_k min(levels[k], μ_k) over [lo, hi]; midpoint if empty,
    the point-mass centroid if the aggregate has zero area (singleton terms)."""
    return _centroid_flag(kind, prm, lo, hi, levels)[0]


# ---------------------------------------------------------------------------------------
# Fast exact kernel for the common structure (the paper's FLC): closed form per output cell
# ---------------------------------------------------------------------------------------


@_jit_inl
def _ramp_int(shape, t):
    """(∫_0^t ψ, ∫_0^t τ ψ) for the rising unit ramp ψ (0 for t < 0, 1 for t > 1).

    shape 0: ψ = t (a triangle's or trapezoid's side); shape 1: the quadratic S spline
    ψ = 2t² (t <= 1/2), 1 - 2(1 - t)² (t > 1/2) of smf/zmf.
    """
    if t <= 0.0:
        return 0.0, 0.0
    if t >= 1.0:
        return 0.5 + (t - 1.0), (1.0 / 3.0 if shape == 0 else 17.0 / 48.0) + 0.5 * (t * t - 1.0)
    if shape == 0:
        return 0.5 * t * t, t * t * t * _THIRD
    if t <= 0.5:
        return 2.0 * t**3 * _THIRD, 0.5 * t**4
    s = 1.0 - t
    return t - 0.5 + 2.0 * s**3 * _THIRD, t * t * (-0.5 + t * (4.0 / 3.0 - 0.5 * t)) + 1.0 / 48.0


@_jit_inl
def _ramp_inv(shape, h):
    """t in [0, 1] where the rising unit ramp equals h (h clamped to [0, 1])."""
    h = min(max(h, 0.0), 1.0)
    if shape == 0:
        return h
    return math.sqrt(0.5 * h) if h <= 0.5 else 1.0 - math.sqrt(0.5 * (1.0 - h))


@_jit_inl
def _ramp_moments(shape, p, w, iw, u, v):
    """(∫ ψ, ∫ z ψ) over z in [u, v] of the ramp ψ((z - p) / w) rising from p to p + w;
    iw = 1 / w (from the tables: no division here)."""
    f0, f1 = _ramp_int(shape, (u - p) * iw)
    F0, F1 = _ramp_int(shape, (v - p) * iw)
    return w * (F0 - f0), w * (p * (F0 - f0) + w * (F1 - f1))


@_jit_inl
def _cell_moments(g0, g1, sa, qa, wa, sb, pb, wb, yc, vc, iwa, iwb, ha, hb):
    """Exact (∫ μ, ∫ y μ) over the cell [g0, g1] of μ = max(min(ha, A), min(hb, B)).

    A(y) = ψ_sa((qa - y) / wa) falls to 0 at qa, B(y) = ψ_sb((y - pb) / wb) rises from 0 at
    pb, and they cross at yc with value vc. So min(ha, A) - min(hb, B) is non-increasing:
    μ is min(ha, A) left of their crossing y* and min(hb, B) right of it. A is integrated
    as a rising ramp in z = -y, so that small values never come from a cancellation.
    """
    if vc <= min(ha, hb):
        ys = yc
    elif ha < hb:
        ys = pb + wb * _ramp_inv(sb, ha)  # B = ha while A > vc > ha
    else:
        ys = qa - wa * _ramp_inv(sa, hb)  # A = hb while B > vc > hb
    ys = min(max(ys, g0), g1)
    # [g0, ys]: ha up to where A = ha, then A
    e = min(max(qa - wa * _ramp_inv(sa, ha), g0), ys)
    m0 = ha * (e - g0)
    m1 = ha * 0.5 * (e * e - g0 * g0)
    if ys > e:
        i0, i1 = _ramp_moments(sa, -qa, wa, iwa, -ys, -e)
        m0 += i0
        m1 -= i1
    # [ys, g1]: B up to where B = hb, then hb
    e = max(min(pb + wb * _ramp_inv(sb, hb), g1), ys)
    m0 += hb * (g1 - e)
    m1 += hb * 0.5 * (g1 * g1 - e * e)
    if e > ys:
        i0, i1 = _ramp_moments(sb, pb, wb, iwb, ys, e)
        m0 += i0
        m1 += i1
    return m0, m1


@_jit_inl
def _locate(lo, hi, inv_step, n, x):
    """Clip x to [lo, hi]; index j of its cell [g_j, g_j+1] on a uniform grid of n points."""
    x = min(max(x, lo), hi)
    return min(max(int((x - lo) * inv_step), 0), n - 2), x


@_jit_inl
def _level(k, k0, h0, k1, h1, k2, h2, k3, h3):
    """Clip level of output term k: the largest strength of the four rules aimed at it."""
    h = 0.0
    if k0 == k:
        h = h0
    if k1 == k:
        h = max(h, h1)
    if k2 == k:
        h = max(h, h2)
    if k3 == k:
        h = max(h, h3)
    return h


@_jit_free
def _grid_eval2(ints, reals, x1, x2):
    """Fast exact kernel: inputs on uniform grids (<= 2 terms of each non-zero, so <= 4
    rules fire) and output terms on a uniform grid (<= 2 non-zero per cell), so the
    centroid is a sum of _cell_moments. No allocation; only scalars cross calls (an array
    passed to a call costs atomic reference counting)."""
    if x1 != x1 or x2 != x2:
        return np.nan
    T = ints[_T]
    K = ints[_K]
    r = ints[O_RIN]
    inv = ints[_O_INV]
    nt = ints[O_NT]
    j1, x1 = _locate(reals[_u(r)], reals[_u(r + 1)], reals[_u(inv)], ints[_u(nt)], x1)
    j2, x2 = _locate(reals[_u(r + 2)], reals[_u(r + 3)], reals[_u(inv + 1)], ints[_u(nt + 1)], x2)
    kin = ints[_O_KIN]
    q = ints[_O_PIN] + 4 * j1
    k = kin + j1
    u1a = mf_piece(ints[_u(k)], reals[_u(q)], reals[_u(q + 1)], reals[_u(q + 2)],
                   reals[_u(q + 3)], x1)[0]  # fmt: skip
    q += 4
    u1b = mf_piece(ints[_u(k + 1)], reals[_u(q)], reals[_u(q + 1)], reals[_u(q + 2)],
                   reals[_u(q + 3)], x1)[0]  # fmt: skip
    q = ints[_O_PIN] + 4 * (T + j2)
    k = kin + T + j2
    u2a = mf_piece(ints[_u(k)], reals[_u(q)], reals[_u(q + 1)], reals[_u(q + 2)],
                   reals[_u(q + 3)], x2)[0]  # fmt: skip
    q += 4
    u2b = mf_piece(ints[_u(k + 1)], reals[_u(q)], reals[_u(q + 1)], reals[_u(q + 2)],
                   reals[_u(q + 3)], x2)[0]  # fmt: skip
    c = ints[_O_GCONS] + j1 * T + j2
    w = ints[_O_GW] + j1 * T + j2
    k0, k1, k2, k3 = ints[_u(c)], ints[_u(c + 1)], ints[_u(c + T)], ints[_u(c + T + 1)]
    h0 = min(u1a, u2a) * reals[_u(w)]
    h1 = min(u1a, u2b) * reals[_u(w + 1)]
    h2 = min(u1b, u2a) * reals[_u(w + T)]
    h3 = min(u1b, u2b) * reals[_u(w + T + 1)]
    kmin = K
    kmax = -1
    for k, h in ((k0, h0), (k1, h1), (k2, h2), (k3, h3)):
        if k >= 0 and h > 0.0:
            kmin = min(kmin, k)
            kmax = max(kmax, k)
    lo = reals[_u(ints[_O_ROUT])]
    hi = reals[_u(ints[_O_ROUT] + 1)]
    m0 = 0.0
    m1 = 0.0
    hb = _level(max(kmin - 1, 0), k0, h0, k1, h1, k2, h2, k3, h3)
    for m in range(max(kmin - 1, 0), min(kmax, K - 2) + 1):
        ha = hb
        hb = _level(m + 1, k0, h0, k1, h1, k2, h2, k3, h3)
        if ha > 0.0 or hb > 0.0:
            q = ints[_O_CELLS] + CELL_SIZE * m
            i0, i1 = _cell_moments(
                reals[_u(q)],
                reals[_u(q + 1)],
                reals[_u(q + 2)],
                reals[_u(q + 3)],
                reals[_u(q + 4)],
                reals[_u(q + 5)],
                reals[_u(q + 6)],
                reals[_u(q + 7)],
                reals[_u(q + 8)],
                reals[_u(q + 9)],
                reals[_u(q + 10)],
                reals[_u(q + 11)],
                ha,
                hb,
            )
            m0 += i0
            m1 += i1
    if m0 <= 0.0:
        return 0.5 * (lo + hi)
    return min(max(m1 / m0, lo), hi)


# ---------------------------------------------------------------------------------------
# General kernel and entry points
# ---------------------------------------------------------------------------------------


@_jit
def _unpack(ints, reals):
    """Views of the sections of a compiled system (see FISTables)."""
    n_in, K, R, T = ints[_N_IN], ints[_K], ints[_R], ints[_T]
    o = ints
    return (
        ints[o[O_NT] : o[O_NT] + n_in],
        ints[o[_O_KIN] : o[_O_KIN] + n_in * T].reshape((n_in, T)),
        ints[o[_O_KOUT] : o[_O_KOUT] + K],
        ints[o[_O_ANT] : o[_O_ANT] + R * n_in].reshape((R, n_in)),
        ints[o[_O_CONS] : o[_O_CONS] + R],
        reals[o[O_RIN] : o[O_RIN] + 2 * n_in].reshape((n_in, 2)),
        reals[o[_O_PIN] : o[_O_PIN] + 4 * n_in * T].reshape((n_in, T, 4)),
        reals[o[_O_ROUT] : o[_O_ROUT] + 2],
        reals[o[_O_POUT] : o[_O_POUT] + 4 * K].reshape((K, 4)),
        reals[o[_O_W] : o[_O_W] + R],
    )


@_jit
def _fire(ints, reals, x, mu, levels):
    """Clip level of every output term: max over its rules of weight · min over inputs."""
    nt, kin, _, ant, cons, rin, pin, _, _, weight = _unpack(ints, reals)
    for i in range(x.shape[0]):
        xi = min(max(x[i], rin[i, 0]), rin[i, 1])
        for j in range(nt[i]):
            p = pin[i, j]
            mu[i, j] = mf_piece(kin[i, j], p[0], p[1], p[2], p[3], xi)[0]
    levels[:] = 0.0
    for r in range(cons.shape[0]):
        s = 1.0
        for i in range(x.shape[0]):
            if ant[r, i] >= 0:
                s = min(s, mu[i, ant[r, i]])
        s *= weight[r]
        if s > levels[cons[r]]:
            levels[cons[r]] = s


@_jit
def _general_eval_flag(ints, reals, x):
    """(output, zero-area flag) of any compiled system at one point x (n_in,): the general
    (allocating) kernel."""
    for i in range(x.shape[0]):
        if x[i] != x[i]:
            return np.nan, 0
    mu = np.empty((ints[_N_IN], ints[_T]))
    levels = np.empty(ints[_K])
    _fire(ints, reals, x, mu, levels)
    _, _, kout, _, _, _, _, rout, pout, _ = _unpack(ints, reals)
    return _centroid_flag(kout, pout, rout[0], rout[1], levels)


@_jit
def _general_eval(ints, reals, x):
    """Any compiled system at one point x (n_in,): the general (allocating) kernel."""
    return _general_eval_flag(ints, reals, x)[0]


def _tables_check(name: str):
    """A function of ``tables`` that does nothing at run time and, in compiled code,
    refuses at compile time a named tuple of another class than ``name``: FISTables and
    SystemTables have different layouts, and one read as the other gives wrong numbers,
    not an error."""

    def check(tables) -> None:
        pass

    @overload(check, jit_options=JIT_OPTIONS | NO_REFCOUNT, strict=False, inline="always")
    def _typed(tables):
        cls = getattr(tables, "instance_class", None)
        if cls is not None and cls.__name__ != name:
            use = {"FISTables": "flc_eval or mamdani_eval (a MamdaniSystem's)",
                   "SystemTables": "pkmctl.fuzzy.general.fis_eval2 or fis_eval_into (a "
                                   "FuzzySystem's)"}  # fmt: skip
            raise TypingError(
                f"these kernels take {name}, not {cls.__name__}: {cls.__name__} go to "
                f"{use.get(cls.__name__, 'their own kernels')}; pkmctl.fuzzy.term.term_eval "
                "takes either"
            )

        def nothing(tables):
            return None

        return nothing

    check.__name__ = check.__qualname__ = f"{name.lower()}_only"
    return check


#: Compile-time checks of the tables the kernels of this module and of
#: :mod:`pkmctl.fuzzy.general` are given (no run-time cost).
fistables_only = _tables_check("FISTables")
systemtables_only = _tables_check("SystemTables")


@_jit_free
def flc_eval(tables, s, sdot):
    """Evaluate a compiled two-input Mamdani system at one point, from compiled code.

    Parameters
    ----------
    tables : FISTables
        ``system.compiled()`` of a two-input :class:`MamdaniSystem`, e.g. ``FLC().compiled()``.
    s, sdot : float
        The two inputs (s*, ṡ* for the paper's FLC); clipped to their universes.

    Returns
    -------
    float
        The centroid output, equal to ``system(s, sdot)``; NaN if an input is NaN.
    """
    fistables_only(tables)
    ints, reals = tables
    if ints[_FAST] == 1:
        return _grid_eval2(ints, reals, s, sdot)
    return _general_eval2(ints, reals, s, sdot)


@_jit_free
def flc_grid_eval(tables, s, sdot):
    """:func:`flc_eval` for tables on the fast kernel only, NaN for any other (the fuzzy
    term's path: :func:`pkmctl.fuzzy.term.term_system` sends every other system to the
    general engine). A loop then compiles without the allocating general path, which is
    most of the fuzzy kernels' compile time."""
    ints, reals = tables
    if ints[_FAST] != 1:
        return np.nan
    return _grid_eval2(ints, reals, s, sdot)


@_jit
def _general_eval2(ints, reals, s, sdot):
    """The general path of flc_eval (it allocates, so it keeps reference counting)."""
    return _general_eval(ints, reals, np.array((float(s), float(sdot))))


@_jit
def mamdani_eval(tables, x):
    """Evaluate a compiled Mamdani system with any number of inputs at one point.

    Parameters
    ----------
    tables : FISTables
        ``system.compiled()``.
    x : ndarray, shape (n_inputs,)
        Crisp inputs, clipped to their universes.

    Returns
    -------
    float
        The centroid output; NaN if an input is NaN.
    """
    fistables_only(tables)
    ints, reals = tables
    if ints[_FAST] == 1:
        return _grid_eval2(ints, reals, x[0], x[1])
    return _general_eval(ints, reals, x)


@_jit_free
def grid_eval_batch(ints, reals, X, out):
    """out[n] = system(X[n, 0], X[n, 1]) for a system on the fast kernel (the caller
    checks): :func:`eval_batch` without the general path, so that evaluating the paper's
    FLC does not compile the general engine."""
    for n in range(X.shape[0]):
        out[n] = _grid_eval2(ints, reals, X[n, 0], X[n, 1])


@_jit
def eval_batch(ints, reals, X, out, fast):
    """out[n] = system(X[n]); returns how many points had a zero-area aggregate."""
    flags = 0
    for n in range(X.shape[0]):
        if fast and ints[_FAST] == 1:
            out[n] = _grid_eval2(ints, reals, X[n, 0], X[n, 1])
        else:
            out[n], f = _general_eval_flag(ints, reals, X[n])
            flags += f
    return flags


@_jit
def levels_batch(ints, reals, X, out):
    mu = np.empty((ints[_N_IN], ints[_T]))
    for n in range(X.shape[0]):
        _fire(ints, reals, X[n], mu, out[n])


@_jit
def centroid_batch(kind, prm, lo, hi, L, out):
    for n in range(L.shape[0]):
        out[n] = _centroid(kind, prm, lo, hi, L[n])


@_jit
def _mf_fill(kind, a, b, c, d, x, out):
    for n in range(x.shape[0]):
        out[n] = mf_piece(kind, a, b, c, d, x[n])[0] if x[n] == x[n] else np.nan


# ---------------------------------------------------------------------------------------
# Membership functions: pure, vectorised functions of x (shape in = shape out).
# ---------------------------------------------------------------------------------------
