"""The paper's gains on a 1 kHz servo loop, as they are and with the beta-axis gains cut tenfold.

    python scripts/servo_1khz.py

For each controller: the fraction of periods after t = 1 s in which the increment of
F_beta flips sign (1.0 = a limit cycle at the Nyquist frequency), the chattering index
of actuator 2 (N/s), and the RMSE after 1 s of z (mm), alpha and beta (deg).
"""

from __future__ import annotations

import argparse

import numpy as np

import pkmctl
from pkmctl import metrics

VARIANTS = {
    "paper gains": {},
    "beta gains / 10": {
        "gains.K": [1000.0, 200.0, 20.0],
        "gains.Lam": [150.0, 40.0, 4.0],
        "gains.Ku": [50.0, 30.0, 3.0],
    },
}


def main() -> None:
    base = pkmctl.Scenario.builtin("paper-1khz")
    print(
        "| gains | controller | sign flips of dF_beta | chattering tau2 (N/s) "
        "| z mm (t>1s) | alpha deg (t>1s) | beta deg (t>1s) |"
    )
    print("|---|---|---|---|---|---|---|")
    for label, changes in VARIANTS.items():
        sc = base.replace(**changes) if changes else base
        for c in ("smc", "fsmc", "afsmc"):
            r = pkmctl.simulate(sc, controller=c)
            d = np.diff(r.F[r.t >= 1.0, 2])
            flips = float(np.mean(d[1:] * d[:-1] < 0))
            a = metrics.rmse(r, t_from=1.0)
            print(
                f"| {label} | {c} | {flips:.2f} | {metrics.chattering_index(r)[1]:,.0f} | "
                f"{a['z_mm']:.4f} | {a['alpha_deg']:.5f} | {a['beta_deg']:.5f} |"
            )


if __name__ == "__main__":
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()  # --help says what it measures; no option
    main()
