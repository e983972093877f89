"""Numba kernels of the general fuzzy engine (:class:`pkmctl.fuzzy.system.FuzzySystem`).

Mamdani and Sugeno systems with any number of inputs and outputs, every method of the
Fuzzy Logic Toolbox. The table layout (two flat read-only arrays, ``ints`` and
``reals``, as :class:`pkmctl.fuzzy.FISTables`) is written by
:func:`pkmctl.fuzzy.system._compile`; the header slots are named below.

Continuous defuzzification of a Mamdani output walks the output universe between
*nodes*: the breakpoints of its terms (feet, peaks, spline midpoints, extrema), the
points where a term reaches its clip level (min implication, found by bisection on
intervals where the term is monotone) and the crossings of the implied sets (max
aggregation: polynomial kinds, every change of the top set, from the roots of the pieces'
differences, and for mom/som/lom the aggregate's interior extrema; other kinds, one
bisection per panel). Between nodes the aggregate is one polynomial of degree
<= 8 for the polynomial kinds (trimf, trapmf, zmf, smf, pimf, linzmf, linsmf; not with
probor aggregation), which 5-point Gauss-Legendre integrates exactly; other kinds are
cut into panels of width <= range/256 as well, with nodes at half-scale steps around a
term narrower than two panels (:func:`pkmctl.fuzzy.mf.resolution_nodes`), and there
mom/som/lom refine each smooth interior maximum by golden-section search.

No kernel here allocates except the three entry points that say so (:func:`fis_eval`,
:func:`eval_batch`, :func:`new_work`): every buffer comes from a *work* tuple made once by
:func:`new_work` (layout: the ``_W_*`` names below; sizes from the header), so
:func:`fis_eval_into` and :func:`fis_eval2` run in the control loop without allocating
and are compiled without reference counting (``pkmctl._jit``: an array view taken in a
function compiled with it costs two atomic operations).
"""

from __future__ import annotations

import math

import numpy as np

from pkmctl._jit import kernel
from pkmctl.fuzzy.kernels import systemtables_only
from pkmctl.fuzzy.mf import mf_value

__all__ = ["eval_batch", "fis_eval", "fis_eval2", "fis_eval_into", "new_work"]

# No FMA contraction (the same numbers as Python's float arithmetic); the kernels that
# allocate keep reference counting, the rest are compiled without it.
_jit_alloc = kernel(fastmath=False)
_jit = kernel(fastmath=False, refcount=False)

# header of ints
(_NIN, _NOUT, _R, _T, _KO, _P, _B, _SUGENO, _AND, _OR, _IMP, _AGG, _DEFUZZ, _CLIP,
 _SAMPLES) = range(15)  # fmt: skip
(_O_INNT, _O_INKIND, _O_OUTNT, _O_OUTKIND, _O_ANT, _O_CONS, _O_ISOR, _O_NBP, _O_POLY,
 _O_INRANGE, _O_INPAR, _O_OUTRANGE, _O_OUTPAR, _O_W, _O_BP) = range(15, 30)  # fmt: skip
_BM = 30  # the most breakpoints of one output term (resolution nodes not counted)
HEADER = 31
#: codes of the methods, in header slots _AND ... _DEFUZZ
AND_CODES = {"min": 0, "prod": 1}
OR_CODES = {"max": 0, "probor": 1}
IMP_CODES = {"min": 0, "prod": 1}
AGG_CODES = {"max": 0, "sum": 1, "probor": 2}
DEFUZZ_CODES = {
    "centroid": 0,
    "bisector": 1,
    "mom": 2,
    "som": 3,
    "lom": 4,
    "wtaver": 5,
    "wtsum": 6,
}
CONSTANT, LINEAR = 100, 101  # kinds of Sugeno output terms
#: Quadrature panels per output universe for the non-polynomial kinds (pkmctl.fuzzy.mf
#: resolution_nodes adds nodes where a term is narrower than a panel).
PANELS = 256
# the work tuple (new_work): float64 arrays, then int64 arrays
(_W_X, _W_OUT, _W_XS, _W_MU_IN, _W_W, _W_PH, _W_MU, _W_NODES, _W_SA, _W_SB, _W_SM, _W_VE,
 _W_YE, _W_VM, _W_VALS, _W_YS, _W_CF, _W_RS, _W_PK, _W_PNEG, _W_DG) = range(21)  # fmt: skip

_GL_X = np.array(
    [-0.9061798459386640, -0.5384693101056831, 0.0, 0.5384693101056831, 0.9061798459386640]
)
_GL_W = np.array(
    [0.2369268850561891, 0.4786286704993665, 0.5688888888888889, 0.4786286704993665,
     0.2369268850561891]
)  # fmt: skip


@_jit
def _views(ints, reals):
    n_in, n_out, R, T, KO, P, B = (
        ints[_NIN],
        ints[_NOUT],
        ints[_R],
        ints[_T],
        ints[_KO],
        ints[_P],
        ints[_B],
    )  # noqa: E501
    o = ints
    return (
        ints[o[_O_INNT] : o[_O_INNT] + n_in],
        ints[o[_O_INKIND] : o[_O_INKIND] + n_in * T].reshape((n_in, T)),
        ints[o[_O_OUTNT] : o[_O_OUTNT] + n_out],
        ints[o[_O_OUTKIND] : o[_O_OUTKIND] + n_out * KO].reshape((n_out, KO)),
        ints[o[_O_ANT] : o[_O_ANT] + R * n_in].reshape((R, n_in)),
        ints[o[_O_CONS] : o[_O_CONS] + R * n_out].reshape((R, n_out)),
        ints[o[_O_ISOR] : o[_O_ISOR] + R],
        ints[o[_O_NBP] : o[_O_NBP] + n_out],
        ints[o[_O_POLY] : o[_O_POLY] + n_out],
        reals[o[_O_INRANGE] : o[_O_INRANGE] + 2 * n_in].reshape((n_in, 2)),
        reals[o[_O_INPAR] : o[_O_INPAR] + 4 * n_in * T].reshape((n_in, T, 4)),
        reals[o[_O_OUTRANGE] : o[_O_OUTRANGE] + 2 * n_out].reshape((n_out, 2)),
        reals[o[_O_OUTPAR] : o[_O_OUTPAR] + P * n_out * KO].reshape((n_out, KO, P)),
        reals[o[_O_W] : o[_O_W] + R],
        reals[o[_O_BP] : o[_O_BP] + B * n_out].reshape((n_out, B)),
    )


@_jit
def _term(kind, par, k, neg, y):
    """μ_k(y) of an output term, or 1 - μ_k(y) for a negated consequent."""
    p = par[k]
    m = mf_value(kind[k], p[0], p[1], p[2], p[3], y)
    return 1.0 - m if neg else m


@_jit
def _aggregate(kind, par, nt, pk, pneg, ph, na, imp, agg, y, mu):
    """(aggregate at y, index of the top piece for max aggregation, else -1).

    Piece i is the implied set imp(ph[i], μ_pk[i]) (negated if pneg[i]).
    """
    for k in range(nt):
        p = par[k]
        mu[k] = mf_value(kind[k], p[0], p[1], p[2], p[3], y)
    v = 0.0
    arg = -1
    for i in range(na):
        m = mu[pk[i]]
        if pneg[i]:
            m = 1.0 - m
        z = min(ph[i], m) if imp == 0 else ph[i] * m
        if agg == 0:
            if z > v:
                v = z
                arg = i
        elif agg == 1:
            v += z
        else:
            v = v + z - v * z
    return v, arg


@_jit
def _gl(kind, par, nt, pk, pneg, ph, na, imp, agg, a, b, mu):
    """(∫ agg, ∫ y agg) over [a, b] by 5-point Gauss-Legendre."""
    c = 0.5 * (a + b)
    r = 0.5 * (b - a)
    m0 = 0.0
    m1 = 0.0
    for g in range(5):
        y = c + r * _GL_X[g]
        v = _aggregate(kind, par, nt, pk, pneg, ph, na, imp, agg, y, mu)[0]
        m0 += _GL_W[g] * r * v
        m1 += _GL_W[g] * r * v * y
    return m0, m1


@_jit
def _sampled(kind, par, nt, pk, pneg, ph, na, imp, agg, lo, hi, n, method, mu, vals, ys):
    """MATLAB's defuzzification on n evenly spaced points (linspace(lo, hi, n)); vals and
    ys (n,) are scratch.

    Returns (value, zero-area flag)."""
    total = 0.0
    vmax = 0.0
    for i in range(n):
        y = lo + i * (hi - lo) / (n - 1) if i < n - 1 else hi
        v = _aggregate(kind, par, nt, pk, pneg, ph, na, imp, agg, y, mu)[0]
        ys[i] = y
        vals[i] = v
        total += v
        vmax = max(vmax, v)
    if total <= 0.0:
        return 0.5 * (lo + hi), 1
    if method == 0:
        s = 0.0
        for i in range(n):
            s += ys[i] * vals[i]
        return s / total, 0
    if method == 1:  # MATLAB's defuzz.m: first sample where the running sum reaches half
        s = 0.0
        for i in range(n):
            s += vals[i]
            if s >= 0.5 * total:
                return ys[i], 0
        return hi, 0
    cnt = 0
    s = 0.0
    first = hi
    last = lo
    for i in range(n):
        if vals[i] == vmax:
            cnt += 1
            s += ys[i]
            first = min(first, ys[i])
            last = max(last, ys[i])
    if method == 2:
        return s / cnt, 0
    return (first, 0) if method == 3 else (last, 0)


@_jit
def _sort(a, n):
    """Sort a[:n] in place (insertion sort: a[:n] is mostly sorted here, and Numba's
    ``sort`` needs reference counting)."""
    for i in range(1, n):
        v = a[i]
        j = i - 1
        while j >= 0 and a[j] > v:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = v


# 5 interpolation points inside [-1, 1] (Chebyshev roots: no end, where a step term would
# jump) and the inverse of their Vandermonde matrix: degree-4 coefficients from values
_CH_T = np.cos((2 * np.arange(5) + 1) * np.pi / 10)
_CH_INV = np.linalg.inv(np.vander(_CH_T, 5, increasing=True))


@_jit
def _implied(kind, par, pk, pneg, ph, i, imp, y):
    """Piece i (an implied set) at y."""
    m = _term(kind, par, pk[i], pneg[i], y)
    return min(ph[i], m) if imp == 0 else ph[i] * m


@_jit
def _coefs(kind, par, pk, pneg, ph, na, imp, c, r, cf, dg):
    """Coefficients in t of each piece on the node interval y = c + r t, t in [-1, 1]
    (polynomial kinds): cf[5 i + m] of t^m, dg[i] its degree (-1: zero on the interval,
    0: clipped at its level)."""
    for i in range(na):
        o = 5 * i
        for m in range(5):
            cf[o + m] = 0.0
        k = pk[i]
        if imp == 0 and _term(kind, par, k, pneg[i], c) >= ph[i]:
            cf[o] = ph[i]
            dg[i] = 0 if ph[i] != 0.0 else -1
            continue
        kk = kind[k]
        if kk == 10:
            for g in range(5):
                v = _implied(kind, par, pk, pneg, ph, i, imp, c + r * _CH_T[g])
                for m in range(5):
                    cf[o + m] += _CH_INV[m, g] * v
            d = 4
        elif kk == 3 or kk == 4:
            va = _implied(kind, par, pk, pneg, ph, i, imp, c - 0.5 * r)
            vm = _implied(kind, par, pk, pneg, ph, i, imp, c)
            vb = _implied(kind, par, pk, pneg, ph, i, imp, c + 0.5 * r)
            cf[o] = vm
            cf[o + 1] = vb - va
            cf[o + 2] = 2.0 * (va + vb - 2.0 * vm)
            d = 2
        else:
            va = _implied(kind, par, pk, pneg, ph, i, imp, c - 0.5 * r)
            vb = _implied(kind, par, pk, pneg, ph, i, imp, c + 0.5 * r)
            cf[o] = 0.5 * (va + vb)
            cf[o + 1] = vb - va
            d = 1
        while d >= 0 and cf[o + d] == 0.0:
            d -= 1
        dg[i] = d


@_jit
def _horner(q, o, d, t):
    v = 0.0
    for m in range(d, -1, -1):
        v = v * t + q[o + m]
    return v


@_jit
def _roots(rs, d, ta, tb):
    """Real roots in (ta, tb) of the polynomial rs[0] + rs[1] t + ... + rs[d] t^d, found
    level by level from its (d-1)-th derivative down: between two roots of the derivative
    the polynomial is monotone, so a sign change there is one root (bisection). Returns
    their count; the roots are rs[40:40 + count], ascending. rs[5:25], rs[32:40] scratch."""
    while d > 0 and rs[d] == 0.0:
        d -= 1
    if d <= 0:
        return 0
    for lev in range(1, d):  # lev-th derivative at rs[5 lev:]
        for m in range(d - lev + 1):
            rs[5 * lev + m] = rs[5 * (lev - 1) + m + 1] * (m + 1)
    n = 0
    for lev in range(d - 1, -1, -1):
        o = 5 * lev
        dd = d - lev
        rs[32] = ta
        for i in range(n):
            rs[33 + i] = rs[40 + i]
        rs[33 + n] = tb
        ms = n + 2
        n = 0
        if dd == 1:
            if rs[o + 1] != 0.0:
                t = -rs[o] / rs[o + 1]
                if ta < t < tb:
                    rs[40] = t
                    n = 1
            continue
        for i in range(ms - 1):
            a = rs[32 + i]
            b = rs[33 + i]
            if not b > a:
                continue
            fa = _horner(rs, o, dd, a)
            fb = _horner(rs, o, dd, b)
            if fa == 0.0 and i > 0:
                rs[40 + n] = a
                n += 1
            elif fa * fb < 0.0:
                for _ in range(80):
                    m = 0.5 * (a + b)
                    if not a < m < b:
                        break
                    fm = _horner(rs, o, dd, m)
                    if (fm < 0.0) == (fa < 0.0):
                        a = m
                    else:
                        b = m
                rs[40 + n] = 0.5 * (a + b)
                n += 1
    return n


@_jit
def _cmp(cf, dg, j, i, u, rs):
    """Sign of p_j - p_i just right of t = u: of the first non-zero of its value and
    derivatives at u."""
    d = max(dg[i], dg[j], 0)
    for m in range(5):
        rs[48 + m] = (cf[5 * j + m] if m <= dg[j] else 0.0) - (cf[5 * i + m] if m <= dg[i] else 0.0)
    for k in range(d + 1):
        v = 0.0  # k-th derivative / k! at u
        for m in range(d, k - 1, -1):
            cmk = 1.0
            for q in range(k):
                cmk = cmk * (m - q) / (q + 1)
            v += rs[48 + m] * cmk * u ** (m - k)
        if v > 0.0:
            return 1
        if v < 0.0:
            return -1
    return 0


@_jit
def _emit(kind, par, nt, pk, pneg, ph, na, imp, agg, u, w, mu, sa, sb, sm, nseg, m0, m1):
    if w > u:
        i0, i1 = _gl(kind, par, nt, pk, pneg, ph, na, imp, agg, u, w, mu)
        sa[nseg] = u
        sb[nseg] = w
        sm[nseg] = i0
        nseg += 1
        m0 += i0
        m1 += i1
    return nseg, m0, m1


@_jit
def _emit_ext(kind, par, nt, pk, pneg, ph, na, imp, agg, a0, b0, c, r, tu, tw, rs, d, ext, mu,
              sa, sb, sm, nseg, m0, m1):  # fmt: skip
    """Segments of [tu, tw] (t coordinates of the node interval [a0, b0]), cut where
    the polynomial in rs[0:d + 1] (the aggregate there) has an extremum if ext."""
    u = a0 if tu == -1.0 else (b0 if tu == 1.0 else c + r * tu)
    w = b0 if tw == 1.0 else (a0 if tw == -1.0 else c + r * tw)
    if ext and d >= 2 and nseg + 8 < sa.shape[0]:
        for m in range(d):
            rs[m] = rs[m + 1] * (m + 1)
        n = _roots(rs, d - 1, tu, tw)
        for k in range(n):
            y = min(max(c + r * rs[40 + k], u), w)
            nseg, m0, m1 = _emit(kind, par, nt, pk, pneg, ph, na, imp, agg, u, y, mu, sa, sb, sm,
                                 nseg, m0, m1)  # fmt: skip
            u = y
    return _emit(kind, par, nt, pk, pneg, ph, na, imp, agg, u, w, mu, sa, sb, sm, nseg, m0, m1)


@_jit
def _poly_interval(kind, par, nt, pk, pneg, ph, na, imp, agg, a0, b0, ext, mu, cf, dg, rs, sa, sb,
                   sm, nseg, m0, m1):  # fmt: skip
    """Segments of one node interval with polynomial pieces: for max aggregation cut at
    every change of the top piece (walking its upper envelope: from t = u, the first root
    of p_j - p_top where p_j rises above it), and at the aggregate's extrema if ext."""
    c = 0.5 * (a0 + b0)
    r = 0.5 * (b0 - a0)
    _coefs(kind, par, pk, pneg, ph, na, imp, c, r, cf, dg)
    if agg != 0:
        d = 0
        for m in range(5):
            rs[m] = 0.0
        for i in range(na):
            for m in range(dg[i] + 1):
                rs[m] += cf[5 * i + m]
            d = max(d, dg[i])
        return _emit_ext(kind, par, nt, pk, pneg, ph, na, imp, agg, a0, b0, c, r, -1.0, 1.0, rs, d,
                         ext, mu, sa, sb, sm, nseg, m0, m1)  # fmt: skip
    u = -1.0
    top = -1
    for i in range(na):
        if dg[i] >= 0 and (top < 0 or _cmp(cf, dg, i, top, u, rs) > 0):
            top = i
    if top < 0:
        return _emit(kind, par, nt, pk, pneg, ph, na, imp, agg, a0, b0, mu, sa, sb, sm, nseg, m0,
                     m1)  # fmt: skip
    for _ in range(4 * na + 4):
        tn = 1.0
        jn = -1
        if nseg + 16 < sa.shape[0]:
            for j in range(na):
                if j == top or dg[j] < 0:
                    continue
                d = max(dg[j], dg[top])
                for m in range(5):
                    rs[m] = (cf[5 * j + m] if m <= dg[j] else 0.0) - (
                        cf[5 * top + m] if m <= dg[top] else 0.0
                    )
                n = _roots(rs, d, u, tn)
                for k in range(n):
                    rk = rs[40 + k]
                    nx = rs[41 + k] if k + 1 < n else tn
                    if _horner(rs, 0, d, 0.5 * (rk + nx)) > 0.0:
                        tn = rk  # < tn: the roots are in (u, tn)
                        jn = j
                        break
        for m in range(5):
            rs[m] = cf[5 * top + m] if m <= dg[top] else 0.0
        nseg, m0, m1 = _emit_ext(kind, par, nt, pk, pneg, ph, na, imp, agg, a0, b0, c, r, u, tn,
                                 rs, dg[top], ext, mu, sa, sb, sm, nseg, m0, m1)  # fmt: skip
        if jn < 0:
            return nseg, m0, m1
        u = tn
        top = jn
    return _emit(kind, par, nt, pk, pneg, ph, na, imp, agg, c + r * u, b0, mu, sa, sb, sm, nseg,
                 m0, m1)  # fmt: skip


@_jit
def _panels(kind, par, nt, pk, pneg, ph, na, imp, agg, nodes, nn, hmax, mu, sa, sb, sm):
    """Segments of the non-polynomial case: node intervals cut into panels of width <=
    hmax, each split once where the top implied set changes (max aggregation)."""
    nseg = 0
    m0 = 0.0
    m1 = 0.0
    for j in range(nn - 1):
        a0 = nodes[j]
        b0 = nodes[j + 1]
        if not b0 > a0:
            continue
        nsub = max(1, int(math.ceil((b0 - a0) / hmax)))
        for q in range(nsub):
            a = a0 + (b0 - a0) * q / nsub
            b = b0 if q == nsub - 1 else a0 + (b0 - a0) * (q + 1) / nsub
            split = b
            if agg == 0:
                d = (b - a) * 1e-9
                ia = _aggregate(kind, par, nt, pk, pneg, ph, na, imp, agg, a + d, mu)[1]
                ib = _aggregate(kind, par, nt, pk, pneg, ph, na, imp, agg, b - d, mu)[1]
                if ia != ib and ia >= 0 and ib >= 0:
                    lo_s = a
                    hi_s = b
                    for _ in range(64):
                        mid = 0.5 * (lo_s + hi_s)
                        if not lo_s < mid < hi_s:
                            break
                        za = _implied(kind, par, pk, pneg, ph, ia, imp, mid)
                        zb = _implied(kind, par, pk, pneg, ph, ib, imp, mid)
                        if za >= zb:
                            lo_s = mid
                        else:
                            hi_s = mid
                    split = 0.5 * (lo_s + hi_s)
            for u, w in ((a, split), (split, b)):
                nseg, m0, m1 = _emit(kind, par, nt, pk, pneg, ph, na, imp, agg, u, w, mu, sa, sb,
                                     sm, nseg, m0, m1)  # fmt: skip
    return nseg, m0, m1


@_jit
def _continuous(kind, par, nt, pk, pneg, ph, na, imp, agg, lo, hi, bp, nbp, poly, method, mu, wk):
    """Defuzzification of the continuous aggregate (see the module docstring); scratch
    from the work tuple wk.

    Returns (value, zero-area flag)."""
    # nodes: static breakpoints inside (lo, hi) (sorted by _compile), the ends, and the
    # clip points
    nodes = wk[_W_NODES]
    nn = 0
    nodes[nn] = lo
    nn += 1
    for j in range(nbp):
        if lo < bp[j] < hi:
            nodes[nn] = bp[j]
            nn += 1
    nodes[nn] = hi
    nn += 1
    _sort(nodes, nn)
    ns = nn
    if imp == 0:
        for i in range(na):
            h = ph[i]
            if not 0.0 < h < 1.0:
                continue
            for j in range(ns - 1):
                a = nodes[j]
                b = nodes[j + 1]
                ga = _term(kind, par, pk[i], pneg[i], a) - h
                gb = _term(kind, par, pk[i], pneg[i], b) - h
                if ga * gb < 0.0 and nn < nodes.shape[0]:
                    for _ in range(64):
                        m = 0.5 * (a + b)
                        if not a < m < b:
                            break
                        gm = _term(kind, par, pk[i], pneg[i], m) - h
                        if (gm < 0.0) == (ga < 0.0):
                            a = m
                        else:
                            b = m
                    nodes[nn] = 0.5 * (a + b)
                    nn += 1
        _sort(nodes, nn)
    hmax = (hi - lo) / PANELS
    smooth = poly == 1 and agg != 2
    sa = wk[_W_SA]
    sb = wk[_W_SB]
    sm = wk[_W_SM]
    nseg = 0
    m0 = 0.0
    m1 = 0.0
    if smooth:
        cf = wk[_W_CF]
        dg = wk[_W_DG]
        rs = wk[_W_RS]
        for j in range(nn - 1):
            if nodes[j + 1] > nodes[j]:
                nseg, m0, m1 = _poly_interval(kind, par, nt, pk, pneg, ph, na, imp, agg, nodes[j],
                                              nodes[j + 1], method >= 2, mu, cf, dg, rs, sa, sb,
                                              sm, nseg, m0, m1)  # fmt: skip
    if not smooth:
        nseg, m0, m1 = _panels(kind, par, nt, pk, pneg, ph, na, imp, agg, nodes, nn, hmax, mu, sa,
                               sb, sm)  # fmt: skip
    if method >= 2 or m0 <= 0.0:
        return _points(kind, par, nt, pk, pneg, ph, na, imp, agg, lo, hi, sa, sb, sm, nseg,
                       method, not smooth, mu, wk[_W_VE], wk[_W_YE], wk[_W_VM])  # fmt: skip
    if method == 0:
        return min(max(m1 / m0, lo), hi), 0
    # bisector: the segment where the running area reaches half, then bisection inside it
    half = 0.5 * m0
    acc = 0.0
    for s in range(nseg):
        if acc + sm[s] >= half or s == nseg - 1:
            a = sa[s]
            b = sb[s]
            for _ in range(64):
                mid = 0.5 * (a + b)
                if not a < mid < b:
                    break
                part = _gl(kind, par, nt, pk, pneg, ph, na, imp, agg, sa[s], mid, mu)[0]
                if acc + part < half:
                    a = mid
                else:
                    b = mid
            return 0.5 * (a + b), 0
        acc += sm[s]
    return 0.5 * (lo + hi), 0


@_jit
def _golden(kind, par, nt, pk, pneg, ph, na, imp, agg, a, m, b, vm, mu):
    """(y, aggregate(y)) of the maximum of the aggregate in [a, b], given an inner point m
    where it is vm and higher than at a and b: golden-section search down to rounding. m
    moves only to a higher point, so it is always the best seen (never below vm)."""
    for _ in range(200):
        right = b - m > m - a  # probe the longer side
        t = m + 0.3819660112501051 * ((b - m) if right else (a - m))
        if not (a < t < b and t != m):
            break
        vt = _aggregate(kind, par, nt, pk, pneg, ph, na, imp, agg, t, mu)[0]
        if vt > vm:  # t is the new inner point; m bounds the side it came from
            if right:
                a = m
            else:
                b = m
            m, vm = t, vt
        elif right:
            b = t
        else:
            a = t
    return m, vm


@_jit
def _points(kind, par, nt, pk, pneg, ph, na, imp, agg, lo, hi, sa, sb, sm, nseg, method, refine,
            mu, ve, ye, vm):  # fmt: skip
    """Maximum-based methods (mom, som, lom) and the zero-area fallback of centroid and
    bisector, from the aggregate at the segment ends and midpoints.

    mom is the mean of the maximum set (by length if it has intervals, else of its
    points; MATLAB's sampled mom in the limit); som/lom its smallest/largest point. A
    zero-area aggregate with firing rules is a set of point masses (singletons): the
    centroid is their weighted mean, the bisector their weighted median (flag 1). ve, ye
    (>= nseg + 1) and vm (>= nseg) are scratch, and so is sm (the segments' areas, not
    read after this) for mom/som/lom. With ``refine`` (the non-polynomial segments, whose
    ends need not hold the aggregate's extrema) a sample higher than both its neighbours
    moves to the maximum between them (:func:`_golden`).
    """
    vmax = 0.0
    for s in range(nseg + 1):
        ye[s] = sa[s] if s < nseg else sb[nseg - 1]
        ve[s] = _aggregate(kind, par, nt, pk, pneg, ph, na, imp, agg, ye[s], mu)[0]
        vmax = max(vmax, ve[s])
    for s in range(nseg):
        vm[s] = _aggregate(kind, par, nt, pk, pneg, ph, na, imp, agg, 0.5 * (sa[s] + sb[s]), mu)[0]
        vmax = max(vmax, vm[s])
    if method >= 2:
        for s in range(nseg):  # where each segment's sample inside it lies
            sm[s] = 0.5 * (sa[s] + sb[s])
    if method >= 2 and refine and vmax > 0.0:
        for s in range(nseg):
            if vm[s] > ve[s] and vm[s] > ve[s + 1]:
                sm[s], vm[s] = _golden(kind, par, nt, pk, pneg, ph, na, imp, agg, sa[s], sm[s],
                                       sb[s], vm[s], mu)  # fmt: skip
                vmax = max(vmax, vm[s])
        for s in range(nseg + 1):
            left = vm[s - 1] if s > 0 else -1.0
            right = vm[s] if s < nseg else -1.0
            if ve[s] > left and ve[s] > right and 0 < s < nseg:
                ye[s], ve[s] = _golden(kind, par, nt, pk, pneg, ph, na, imp, agg, sm[s - 1], ye[s],
                                       sm[s], ve[s], mu)  # fmt: skip
                vmax = max(vmax, ve[s])
    if vmax <= 0.0:
        return 0.5 * (lo + hi), 1
    if method <= 1:  # zero area: point masses
        total = 0.0
        for s in range(nseg + 1):
            total += ve[s]
        if method == 0:
            acc = 0.0
            for s in range(nseg + 1):
                acc += ye[s] * ve[s]
            return min(max(acc / total, lo), hi), 1
        acc = 0.0
        for s in range(nseg + 1):
            acc += ve[s]
            if acc >= 0.5 * total:
                return ye[s], 1
        return hi, 1
    tol = vmax * (1.0 - 1e-12)
    length = 0.0
    moment = 0.0
    npts = 0
    psum = 0.0
    first = hi
    last = lo
    for s in range(nseg):
        if ve[s] >= tol and vm[s] >= tol and ve[s + 1] >= tol:
            length += sb[s] - sa[s]
            moment += (sb[s] - sa[s]) * 0.5 * (sa[s] + sb[s])
            first = min(first, sa[s])
            last = max(last, sb[s])
        elif vm[s] >= tol:  # an interior peak between ends (smooth terms)
            npts += 1
            psum += sm[s]
            first = min(first, sm[s])
            last = max(last, sm[s])
    for s in range(nseg + 1):
        if ve[s] >= tol:
            npts += 1
            psum += ye[s]
            first = min(first, ye[s])
            last = max(last, ye[s])
    if method == 3:
        return first, 0
    if method == 4:
        return last, 0
    return (moment / length if length > 0.0 else psum / npts), 0


@_jit
def _eval_point(ints, reals, x, out, wk):
    """Evaluate a compiled system at x (n_in,) into out (n_out,) with the scratch of the
    work tuple wk (:func:`new_work`); return the number of outputs that took the zero-area
    fallback."""
    (in_nt, in_kind, out_nt, out_kind, ant, cons, is_or, nbp, poly, in_range, in_par,
     out_range, out_par, weight, bp) = _views(ints, reals)  # fmt: skip
    n_in = ints[_NIN]
    n_out = ints[_NOUT]
    R = ints[_R]
    for i in range(n_in):
        if x[i] != x[i]:
            out[:] = np.nan
            return 0
    xs = wk[_W_XS]
    for i in range(n_in):
        xs[i] = min(max(x[i], in_range[i, 0]), in_range[i, 1]) if ints[_CLIP] == 1 else x[i]
    T = ints[_T]
    mu_in = wk[_W_MU_IN]  # (n_in, T) row by row
    for i in range(n_in):
        for j in range(in_nt[i]):
            p = in_par[i, j]
            mu_in[i * T + j] = mf_value(in_kind[i, j], p[0], p[1], p[2], p[3], xs[i])
    w = wk[_W_W]
    and_prod = ints[_AND] == 1
    or_prob = ints[_OR] == 1
    for r in range(R):
        orr = is_or[r] == 1
        acc = 0.0 if orr else 1.0
        for i in range(n_in):
            a = ant[r, i]
            if a == 0:
                continue
            m = mu_in[i * T + abs(a) - 1]
            if a < 0:
                m = 1.0 - m
            if orr:
                acc = acc + m - acc * m if or_prob else max(acc, m)
            else:
                acc = acc * m if and_prod else min(acc, m)
        w[r] = acc * weight[r]
    flags = 0
    KO = ints[_KO]
    pk = wk[_W_PK]
    pneg = wk[_W_PNEG]
    ph = wk[_W_PH]
    mu = wk[_W_MU]
    imp = ints[_IMP]
    agg = ints[_AGG]
    method = ints[_DEFUZZ]
    for o in range(n_out):
        lo = out_range[o, 0]
        hi = out_range[o, 1]
        if ints[_SUGENO] == 1:
            num = 0.0
            den = 0.0
            for r in range(R):
                c = cons[r, o]
                if c == 0:
                    continue
                p = out_par[o, c - 1]
                if out_kind[o, c - 1] == CONSTANT:
                    z = p[0]
                else:
                    z = p[n_in]
                    for i in range(n_in):
                        z += p[i] * xs[i]
                num += w[r] * z
                den += w[r]
            if den <= 0.0:
                out[o] = 0.5 * (lo + hi)
            else:
                out[o] = num / den if method == 5 else num
            continue
        # Mamdani: the implied sets ("pieces"); with max aggregation one per signed term
        na = 0
        if agg == 0:
            ph[: 2 * KO] = 0.0
            for r in range(R):
                c = cons[r, o]
                if c != 0:
                    slot = c - 1 if c > 0 else KO - c - 1
                    ph[slot] = max(ph[slot], w[r])
            for slot in range(2 * KO):
                if ph[slot] > 0.0:
                    pk[na] = slot if slot < KO else slot - KO
                    pneg[na] = slot >= KO
                    ph[na] = ph[slot]
                    na += 1
        else:
            for r in range(R):
                c = cons[r, o]
                if c != 0 and w[r] > 0.0:
                    pk[na] = abs(c) - 1
                    pneg[na] = c < 0
                    ph[na] = w[r]
                    na += 1
        if na == 0:
            out[o] = 0.5 * (lo + hi)
            continue
        kind = out_kind[o]
        par = out_par[o]
        nt = out_nt[o]
        if ints[_SAMPLES] > 1:
            v, f = _sampled(kind, par, nt, pk, pneg, ph, na, imp, agg, lo, hi, ints[_SAMPLES],
                            method, mu, wk[_W_VALS], wk[_W_YS])  # fmt: skip
        else:
            v, f = _continuous(kind, par, nt, pk, pneg, ph, na, imp, agg, lo, hi, bp[o], nbp[o],
                               poly[o], method, mu, wk)  # fmt: skip
        out[o] = v
        flags += f
    return flags


@_jit_alloc
def new_work(ints):
    """The work tuple of a compiled system (it allocates; once per run or batch).

    Float64 arrays ``x`` (n_in,) and ``out`` (n_out,) for :func:`fis_eval2`, the clipped
    inputs (n_in,), input memberships (n_in T,), rule strengths (R,), piece levels (P,),
    output memberships (K,), the defuzzifier's nodes (N,), segments (3 of S,), their ends
    and midpoints (S + 1, S + 1, S), samples (2 of n_samples), then int64 piece terms and
    negations (P,). P = max(R, 2 K) pieces (max aggregation merges the rules of each signed
    term), N = B + 2 + P (BM + 1) nodes (B breakpoints and resolution nodes, the ends, and
    the clip points: a piece crosses its level at most once in each of the BM + 1 runs
    where its term is monotone, BM the most breakpoints of one term) and S = 2 (N + 257)
    + 8 N segments (each node interval cut into panels of width <= range / 256, each panel
    split once at a crossing; polynomial terms: node intervals split at every crossing
    and, for mom/som/lom, extremum; past that room an interval is not split further).
    Then the polynomial pieces' coefficients (5 P,), root-finding scratch (64,) and int64
    piece degrees (P,).
    """
    n_in, n_out, R, KO, B = ints[_NIN], ints[_NOUT], ints[_R], ints[_KO], ints[_B]
    P = max(R, 2 * KO, 1)
    N = B + 2 + P * (ints[_BM] + 1)
    S = 2 * (N + PANELS + 1) + 8 * N
    ns = max(ints[_SAMPLES], 1)
    e = np.empty
    return (e(n_in), e(n_out), e(n_in), e(n_in * ints[_T]), e(max(R, 1)), e(P), e(max(KO, 1)),
            e(N), e(S), e(S), e(S), e(S + 1), e(S + 1), e(S), e(ns), e(ns), e(5 * P), e(64),
            np.empty(P, np.int64), np.empty(P, np.int64), np.empty(P, np.int64))  # fmt: skip


@_jit
def fis_eval_into(tables, work, x, out):
    """Evaluate a compiled system at one point without allocating (compiled code).

    Parameters
    ----------
    tables : SystemTables
        ``system.compiled()``.
    work : tuple of arrays
        ``new_work(tables.ints)``, made once; scratch, overwritten.
    x : ndarray, shape (n_inputs,)
    out : ndarray, shape (n_outputs,)
        Receives the crisp outputs (NaN if an input is NaN).

    Returns
    -------
    int
        Number of outputs whose aggregate had zero area although rules fired.
    """
    systemtables_only(tables)
    return _eval_point(tables[0], tables[1], x, out, work)


@_jit
def fis_eval2(tables, work, x1, x2):
    """The first output of a compiled system with two inputs, at (x1, x2), without
    allocating (the fuzzy term of FSMC/AFSMC; ``work`` from :func:`new_work`)."""
    systemtables_only(tables)
    x = work[_W_X]
    out = work[_W_OUT]
    x[0] = x1
    x[1] = x2
    _eval_point(tables[0], tables[1], x, out, work)
    return out[0]


@_jit_alloc
def fis_eval(tables, x, out):
    """Evaluate a compiled :class:`~pkmctl.fuzzy.system.FuzzySystem` at one point.

    Allocates its work arrays on every call; compiled code that calls it often should make
    them once with :func:`new_work` and call :func:`fis_eval_into`.

    Parameters
    ----------
    tables : SystemTables
        ``system.compiled()``.
    x : ndarray, shape (n_inputs,)
    out : ndarray, shape (n_outputs,)
        Receives the crisp outputs (NaN if an input is NaN).

    Returns
    -------
    int
        Number of outputs whose aggregate had zero area although rules fired.
    """
    systemtables_only(tables)
    return _eval_point(tables[0], tables[1], x, out, new_work(tables[0]))


@_jit_alloc
def eval_batch(ints, reals, X, out):
    """out[n] = system(X[n]) for X (N, n_in), out (N, n_out); returns the zero-area count."""
    wk = new_work(ints)
    flags = 0
    for n in range(X.shape[0]):
        flags += _eval_point(ints, reals, X[n], out[n], wk)
    return flags
