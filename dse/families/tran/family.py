"""The coestimation family (TEMPORARY: the old reproduction module seen through the contract)."""
from dse.families.legacy import legacy_family

Coestimation = legacy_family("coestimation", "dse.families.tran", paper_id="tran", example="paper.toml")
