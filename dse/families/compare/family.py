"""The compare family (TEMPORARY: the old reproduction module seen through the contract)."""
from dse.families.legacy import legacy_family

Compare = legacy_family("compare", "dse.families.compare", paper_id=None, example="scenarios/tracking.toml")
