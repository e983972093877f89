"""Identification end to end on the prototype (docs/identification.md, the README's table):

1. design an exciting trajectory for the prototype (``pkmctl excite``);
2. run it on the ``prototype`` machine with PD, the encoders given 1 um of noise;
3. identify from the measured lengths and the drives' forces (``pkmctl identify``),
   validated on a second run along the paper's trajectory (eq. 54);
4. run the five controllers on ``prototype-tuned`` with three models: the paper's
   15 % light one (no rotor inertia, no friction), the identified one, the true one.

    PYTHONPATH=src python scripts/identify_prototype.py [--duration 10]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import pkmctl
from pkmctl.ident.excite import _machine, design_excitation
from pkmctl.ident.identify import Log, identify, predict
from pkmctl.sim.metrics import rmse

CONTROLLERS = ("smc", "fsmc", "afsmc", "pd", "ctc")
NOISE = 1e-6  # m, on each encoder length


def _log(r: pkmctl.Result, name: str) -> Log:
    return Log(r.t, r.q_measured, r.tau, name)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0, help="each controller run (s)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    proto = pkmctl.Scenario.builtin("prototype").replace(**{"sensor.noise": NOISE})
    e = design_excitation(proto)
    exc = e.scenario(proto)
    print(
        f"excitation: cond(W_b) {e.cond:.4g} (eq. 54: {e.cond_paper:.4g}), "
        f"{e.duration:g} s, peak force {e.peak_force:.0f} N, peak speed {e.peak_speed:.2f} m/s"
    )
    run = pkmctl.simulate(exc, controller="pd")
    check = pkmctl.simulate(proto, controller="pd")  # eq. 54: the validation log
    idn = identify(_log(run, "excite/pd"), exc, force_lead=None)
    val = predict(idn, _log(check, "eq54/pd"), proto)
    theta_true, _ = _machine(proto)
    true = idn.base.base(theta_true)
    print(
        f"identified in {idn.seconds:.2f} s: {idn.base.count} base parameters, cond "
        f"{idn.cond:.4g}, residual {100 * idn.wls.relative_error:.3g} %, validation "
        f"{100 * val['relative_error']:.3g} %, force lead {1e3 * idn.observation.force_lead:.3f} ms"
    )
    print()
    print("| base parameter | true | identified (WLS) | 95 % interval | error |")
    print("|---|---:|---:|---:|---:|")
    for k, name in enumerate(idn.base.names):
        if not (name.startswith(("m_platform", "m_r", "Fc", "Fv")) or k < 1):
            continue
        b, s = idn.wls.beta[k], idn.wls.std[k]
        print(
            f"| {idn.base.expressions[k]} [{idn.base.units[k]}] | {true[k]:.4g} | {b:.4g} | "
            f"± {1.96 * s:.3g} | {100 * (b - true[k]) / abs(true[k]):+.2f} % |"
        )
    base = pkmctl.Scenario.builtin("prototype-tuned").replace(**{"timing.duration": args.duration})
    models = {
        "15 % light, no rotors, no friction (the paper's)": {"theta_scale": 0.85},
        "identified": idn.controller_model(),
        "true": {"theta_ext": [float(v) for v in theta_true]},
    }
    print()
    print(
        f"RMSE after the first second on prototype-tuned ({args.duration:g} s, seed 0), "
        "z mm / α ° / β °:"
    )
    print()
    print("| controller | " + " | ".join(models) + " |")
    print("|---|" + "---|" * len(models))
    for ctrl in CONTROLLERS:
        cells = []
        for block in models.values():
            sc = base.replace(controller_model=block)
            try:
                r = rmse(pkmctl.simulate(sc, controller=ctrl), t_from=1.0)
                cells.append(f"{r['z_mm']:.3g} / {r['alpha_deg']:.3g} / {r['beta_deg']:.3g}")
            except pkmctl.SimulationDiverged as exc_:
                cells.append(f"diverged at {exc_.time:.3g} s")
        print(f"| {ctrl.upper()} | " + " | ".join(cells) + " |")
    print(f"\n({time.perf_counter() - t0:.0f} s in all)")
    np.set_printoptions(precision=4)


if __name__ == "__main__":
    main()
