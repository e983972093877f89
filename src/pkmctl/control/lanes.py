"""The built-in controllers in lane form (:mod:`pkmctl.sim.lanes`): smc, fsmc, afsmc, pd,
ctc for L runs at once, every array with a trailing lane dimension.

Lane l computes what the scalar step computes on lane l's numbers: the model terms come
from the lane kernels of :mod:`pkmctl.model.lanes` (within 1e-12 relative of the scalar
ones, tests/test_lanes_model.py), the rest is written here, in the scalar step's order,
as loops over the lanes, innermost, which LLVM vectorises. The fuzzy term evaluates the
lanes of each axis at once (:func:`pkmctl.fuzzy.term.term_eval_lanes`: on the fast
kernel, branch-free and bit for bit the scalar result). A run whose controller
has the machine model of DESIGN.md §7 switched on (``mach_on``) runs its controller lane
by lane instead (``lane_ok``).
"""

from __future__ import annotations

import numpy as np

from pkmctl._jit import kernel
from pkmctl.control import adaptive, baselines  # noqa: F401  (the parts extended here)
from pkmctl.control.sliding import SLIDING_STATE
from pkmctl.fuzzy.term import term_eval_lanes, term_work
from pkmctl.model.lanes import (
    LANE_JQ,
    disjoint_arrays,
    lane_dynamics,
    lane_gravity,
    lane_regressor,
    make_lane_work,
    wide_vectors,
)
from pkmctl.model.simd import flat_view
from pkmctl.parts import attach_lanes

__all__ = ["lane_controller_work"]

#: Where the lane work holds the limb Jacobian at y[:3] after a step (as MODEL_JACOBIAN).
LANE_JACOBIAN = (0, LANE_JQ)
_FLC = 9  # the fuzzy system's (scalar) work in the lane work tuple
_FLC_IO = 10  # the fuzzy term's inputs and output (3, L)


def lane_controller_work(p, L: int, n_theta: int = 0) -> tuple:
    """Lane work: (model work, M (3, 3, L), C v, G, G(X_d) (3, L), Y (3, n_theta, L),
    s, Xr_dot, Xr_ddot (3, L), and with a fuzzy system its work and its inputs and
    output (3, L))."""
    e = np.empty
    work = (make_lane_work(L), e((3, 3, L)), e((3, L)), e((3, L)), e((3, L)),
            e((3, n_theta, L)), e((3, L)), e((3, L)), e((3, L)))  # fmt: skip
    flc = getattr(p, "flc", None)
    return work + ((term_work(flc), e((3, L))) if flc is not None else ())


def _no_machine(p) -> bool:
    return not float(p.mach_on) > 0.0


def _afsmc_lane_ok(p) -> bool:
    """AFSMC's lane step updates Θ^ four parameters at a time: without the machine model
    it has 36 (9 bodies x 4); any other count runs one run at a time."""
    return _no_machine(p) and p.theta0.shape[0] % 4 == 0


@kernel(inline="always", refcount=False)
def _surface(lam, y, ref, s, xr_d, xr_dd):
    """s, Xr_dot, Xr_ddot (3, L) as :func:`pkmctl.control.sliding.sliding_surface`."""
    n = s.shape[0] * s.shape[1]  # the 3 rows x L lanes as one flat loop (flat_view)
    rf, yf, lf = flat_view(ref), flat_view(y), flat_view(lam)
    sf, df, ddf = flat_view(s), flat_view(xr_d), flat_view(xr_dd)
    for m in range(n):
        e = rf[m] - yf[m]
        ed = rf[n + m] - yf[n + m]
        sf[m] = ed + lf[m] * e
        df[m] = rf[n + m] + lf[m] * e
        ddf[m] = rf[2 * n + m] + lf[m] * ed


@kernel(inline="always", refcount=False)
def _filter(state, s, Tc, alpha_f):
    """The sdot filter of :func:`pkmctl.control.sliding.filter_sdot`, per lane."""
    L = s.shape[1]
    for i in range(3):
        for l in range(L):
            raw = (s[i, l] - state[i, l]) / Tc[l] if state[6, l] > 0.0 else 0.0
            state[3 + i, l] += alpha_f[l] * (raw - state[3 + i, l])
            state[i, l] = s[i, l]
    for l in range(L):
        state[6, l] = 1.0


@kernel(inline="always", refcount=False)
def _inverse(M, Cv, G, a, F):
    """F = M a + C v + G per lane (:func:`pkmctl.model.dynamics.inverse_dynamics`)."""
    L = F.shape[1]
    for i in range(3):
        for l in range(L):
            F[i, l] = G[i, l] + (
                M[i, 0, l] * a[0, l] + M[i, 1, l] * a[1, l] + M[i, 2, l] * a[2, l] + Cv[i, l]
            )


@kernel(inline="always", refcount=False)
def _model_force(p, y, ref, work, F):
    w, M, Cv, G, Gd, xr_d, xr_dd = work[0], work[1], work[2], work[3], work[4], work[7], work[8]
    lane_gravity(p.geom, p.theta, ref[0:3], w, Gd)
    lane_dynamics(p.geom, p.theta, y[0:3], y[3:6], xr_d, w, M, Cv, G)  # Cv: C^ Xr_dot
    _inverse(M, Cv, Gd, xr_dd, F)


@kernel(inline="always", refcount=False)
def _add_ks(K, s, F):
    Ff, Kf, sf = flat_view(F), flat_view(K), flat_view(s)
    for m in range(Ff.shape[0]):
        Ff[m] += Kf[m] * sf[m]


@kernel(inline="always", refcount=False)
def _fuzzy(p, fwork, io, s, state, F):
    """F -= K_u FLC(K_s s, K_sdot sdot), the lanes of each axis in one evaluation."""
    L = F.shape[1]
    x1, x2, u = io[0], io[1], io[2]
    for i in range(3):
        for l in range(L):
            x1[l] = p.Ks[i, l] * s[i, l]
            x2[l] = p.Ksd[i, l] * state[3 + i, l]
        term_eval_lanes(p.flc, fwork, x1, x2, u)
        for l in range(L):
            F[i, l] -= p.Ku[i, l] * u[l]


@kernel(refcount=False)
def lane_smc_step(p, state, work, y, ref, F):
    """:func:`pkmctl.control.sliding.smc_step` per lane."""
    wide_vectors()
    disjoint_arrays()
    s = work[6]
    _surface(p.lam, y, ref, s, work[7], work[8])
    _filter(state, s, p.Tc, p.alpha_f)
    _model_force(p, y, ref, work, F)
    L = F.shape[1]
    for i in range(3):
        for l in range(L):
            F[i, l] += p.K[i, l] * s[i, l]
            F[i, l] += p.Lam[i, l] * min(1.0, max(-1.0, s[i, l] / p.eps[l]))


@kernel(refcount=False)
def lane_fsmc_step(p, state, work, y, ref, F):
    """:func:`pkmctl.control.sliding.fsmc_step` per lane."""
    wide_vectors()
    disjoint_arrays()
    s = work[6]
    _surface(p.lam, y, ref, s, work[7], work[8])
    _filter(state, s, p.Tc, p.alpha_f)
    _model_force(p, y, ref, work, F)
    _add_ks(p.K, s, F)
    _fuzzy(p, work[_FLC], work[_FLC_IO], s, state, F)


@kernel(refcount=False)
def lane_afsmc_step(p, state, work, y, ref, F):
    """:func:`pkmctl.control.adaptive.afsmc_step` per lane."""
    wide_vectors()
    disjoint_arrays()
    n = p.theta0.shape[0]
    L = F.shape[1]
    w, Y, s, xr_d, xr_dd = work[0], work[5], work[6], work[7], work[8]
    th = state[SLIDING_STATE : SLIDING_STATE + n]
    _surface(p.lam, y, ref, s, xr_d, xr_dd)
    _filter(state, s, p.Tc, p.alpha_f)
    lane_regressor(p.geom, y[0:3], y[3:6], xr_d, xr_dd, w, Y)
    Ff = flat_view(F)
    for m in range(Ff.shape[0]):
        Ff[m] = 0.0
    # F = Y Theta^ and the projected adaptive law (pkmctl.control.adaptive.adapt) in one
    # pass over the parameters: the same sums in the same order as the scalar step's two
    # loops (the law reads neither F nor the terms added below), four parameters per
    # loop over the lanes, so that F stays in registers between them (a loop per
    # parameter stored and reloaded it 36 times: 329 -> 251 ns per 8 lanes alone).
    k0 = 0
    while k0 + 4 <= n:  # n is a multiple of 4 (_afsmc_lane_ok)
        for l in range(L):
            f0, f1, f2 = F[0, l], F[1, l], F[2, l]
            s0, s1, s2 = s[0, l], s[1, l], s[2, l]
            for k in range(k0, k0 + 4):
                t = th[k, l]
                y0, y1, y2 = Y[0, k, l], Y[1, k, l], Y[2, k, l]
                f0 += y0 * t
                f1 += y1 * t
                f2 += y2 * t
                upd = 0.0
                upd += y0 * s0
                upd += y1 * s1
                upd += y2 * s2
                v = t + p.Tc[l] * p.gamma_vec[k, l] * upd
                th[k, l] = min(p.theta_max[k, l], max(p.theta_min[k, l], v))
            F[0, l], F[1, l], F[2, l] = f0, f1, f2
        k0 += 4
    _add_ks(p.K, s, F)
    _fuzzy(p, work[_FLC], work[_FLC_IO], s, state, F)


@kernel(refcount=False)
def lane_afsmc_log(p, state, row):
    """Theta^ per lane (:func:`pkmctl.control.adaptive.afsmc_log`)."""
    for k in range(row.shape[0]):
        for l in range(row.shape[1]):
            row[k, l] = state[SLIDING_STATE + k, l]


@kernel(refcount=False)
def lane_pd_step(p, state, work, y, ref, F):
    """:func:`pkmctl.control.baselines.pd_step` per lane."""
    wide_vectors()
    disjoint_arrays()
    G = work[3]
    lane_gravity(p.geom, p.theta, y[0:3], work[0], G)
    n = F.shape[0] * F.shape[1]
    Ff, rf, yf = flat_view(F), flat_view(ref), flat_view(y)
    kp, kd, Gf = flat_view(p.kp), flat_view(p.kd), flat_view(G)
    for m in range(n):
        Ff[m] = kp[m] * (rf[m] - yf[m]) + kd[m] * (rf[n + m] - yf[n + m]) + Gf[m]


@kernel(refcount=False)
def lane_ctc_step(p, state, work, y, ref, F):
    """:func:`pkmctl.control.baselines.ctc_step` per lane."""
    wide_vectors()
    disjoint_arrays()
    M, Cv, G, a = work[1], work[2], work[3], work[8]
    lane_dynamics(p.geom, p.theta, y[0:3], y[3:6], y[3:6], work[0], M, Cv, G)
    n = F.shape[0] * F.shape[1]
    af, rf, yf = flat_view(a), flat_view(ref), flat_view(y)
    kp, kd = flat_view(p.kp), flat_view(p.kd)
    for m in range(n):
        af[m] = rf[2 * n + m] + kd[m] * (rf[n + m] - yf[n + m]) + kp[m] * (rf[m] - yf[m])
    _inverse(M, Cv, G, a, F)


def _attach() -> None:
    common = {"lane_ok": _no_machine, "lane_limb_jacobian": LANE_JACOBIAN}
    for name, step in (("smc", lane_smc_step), ("fsmc", lane_fsmc_step),
                       ("pd", lane_pd_step), ("ctc", lane_ctc_step)):  # fmt: skip
        attach_lanes("controller", name, {"step": step}, lane_work=lane_controller_work, **common)
    attach_lanes(
        "controller", "afsmc", {"step": lane_afsmc_step, "log": lane_afsmc_log},
        lane_work=lambda p, L: lane_controller_work(p, L, p.theta0.shape[0]),
        **{**common, "lane_ok": _afsmc_lane_ok},
    )  # fmt: skip


_attach()
