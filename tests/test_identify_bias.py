"""Identification of a closed-loop run is unbiased where the friction reverses.

The plant's Coulomb friction F_c tanh(qdot / v_s) (v_s = 1 mm/s) makes each velocity
reversal a kink: the limb decelerates into it faster than it accelerates out of it. The
pose filter (100 Hz at 1 kHz) rounds the kink, so a Coulomb column computed from the
filtered rate stepped 0.2-1.3 ms after the plant's friction did. Least squares put those
impulses into the mirror contrast of the rotor masses (m_r1 + m_r3 - m_r2 - m_r4) and into
the friction, and ``force_lead`` 'auto' traded them against the force timing (it found
-0.17 ms for a drive whose forces act (T/2 - tau_d) = 0.30 ms before they are logged).

A PD run of the prototype (drive: one period of delay, 0.2 ms torque lag, encoder
quantisation) on an exciting trajectory, with the random disturbance off so that the
intervals are narrow and any systematic error shows. Before the fix: lead -0.175 ms,
(m_r1 + m_r3 - m_r2 - m_r4) / 2 = -1.91 +- 0.35 kg; after: -0.300 ms, -0.03 +- 0.05 kg.
"""

from __future__ import annotations

import numpy as np
import pytest

import pkmctl
from pkmctl.ident.identify import Log, identify
from pkmctl.model.machine import reflected_inertia

#: An exciting trajectory of ``pkmctl excite`` (cond(W_b) 4,569; the one a bounds-checked
#: build designed), written out so the test does not depend on SLSQP's path.
TRAJECTORY = {
    "kind": "fourier",
    "base_frequency": 0.2,
    "offset": [0.7, 0.0, 0.0],
    "a": [
        [0.009457334290458058, 0.04048101856771833, 0.10027925419231773,
         0.2016660896980636, -0.35188369674855774],
        [0.4277445038501017, 0.07388935158126671, 0.3056009311613327,
         -0.5715226460012212, -0.23571214059148007],
        [-0.4992663939963153, 0.394038888898217, 0.11541144183400033,
         0.1621527554839964, -0.17233669221989828],
    ],
    "b": [
        [3.403256153207677e-06, -1.3598079093424531e-05, 2.370944466127748e-05,
         -2.9043861654595554e-05, 1.3768002933638232e-05],
        [0.07614294172375717, -0.27221848073188776, 0.41635674832225167,
         -0.5287581680314201, 0.26685128937978875],
        [0.13617607990649397, -0.23526046472655696, -0.002891655400593569,
         -0.3478083893291154, 0.3468506746129725],
    ],
}  # fmt: skip


@pytest.fixture(scope="module")
def run():
    sc = pkmctl.Scenario.builtin("prototype").replace(
        trajectory=TRAJECTORY,
        **{
            "initial.X": [0.7, 0.0, 0.0],
            "initial.Xdot": [0.0, 0.0, 0.0],
            "disturbance.amplitude": [0.0, 0.0, 0.0],
            "timing.duration": 10.0,
        },
    )
    r = pkmctl.simulate(sc, controller="pd")
    log = Log(r.t, r.q_measured, r.tau, "pd run", ())
    return sc, identify(log, sc, force_lead=None, physical=False)


def _estimate(ident, name):
    k = ident.base.expressions.index(name)
    return ident.wls.beta[k], ident.wls.std[k]


def test_force_lead_auto_finds_the_drives_timing(run):
    sc, ident = run
    # the torque logged at t_k is the one left from period k-1, whose command acted from
    # about t_k - T + tau_d: centred (T/2 - tau_d) before t_k
    expected = -(0.5 * sc.timing.control_period - sc.actuators.lag)
    assert ident.observation.force_lead == pytest.approx(expected, abs=0.03e-3)


def test_rotor_masses_and_friction_are_unbiased(run):
    sc, ident = run
    ps = sc.plant_spec
    m_r = reflected_inertia(ps.rotor_inertia, ps.screw_lead)
    ex = ident.base.expressions
    g = np.zeros(len(ex))
    for name, sign in (("m_r1", 0.5), ("m_r3", 0.5), ("m_r2", -0.5), ("m_r4", -0.5)):
        g[ex.index(name)] = sign
    contrast = g @ ident.wls.beta  # the mirror pairs' difference: 0 on this machine
    std = np.sqrt(g @ ident.wls.cov @ g)
    assert abs(contrast) < 0.3 and abs(contrast) < 3 * std + 0.05
    for i in range(1, 5):
        m, s = _estimate(ident, f"m_r{i}")
        assert abs(m - m_r) < 0.03 * m_r
        fc, _ = _estimate(ident, f"Fc{i}")
        fv, _ = _estimate(ident, f"Fv{i}")
        assert abs(fc - ps.friction_coulomb) < 1e-3 * ps.friction_coulomb
        assert abs(fv - ps.friction_viscous) < 1e-3 * ps.friction_viscous
