"""The machine: mechanism data (Table 2), kinematics, dynamics and regressors (DESIGN §1-2)."""

from pkmctl.model.mechanism import BODY_NAMES, PAPER_TABLE2, Body, Mechanism

__all__ = ["BODY_NAMES", "PAPER_TABLE2", "Body", "Mechanism"]
