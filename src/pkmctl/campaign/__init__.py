"""Robustness campaigns (DESIGN.md §8): many paired runs over factors of a scenario.

``spec`` reads and validates a campaign's TOML and expands it into runs and tasks;
``execute`` runs the tasks (local worker processes, or a Dask cluster by address);
``store`` keeps one Parquet file per task and reads the records back; ``stats``
computes the per-cell statistics and paired differences the report renders.
"""

from pkmctl.campaign.spec import CampaignSpec, SpecError

__all__ = ["CampaignSpec", "SpecError"]
