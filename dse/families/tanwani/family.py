"""The random-comm-filter family (TEMPORARY: the old reproduction module seen through the contract)."""
from dse.families.legacy import legacy_family

RandomCommFilter = legacy_family("random-comm-filter", "dse.families.tanwani", paper_id="tanwani", example="example.toml")
