"""The hybrid-observer family (TEMPORARY: the old reproduction module seen through the contract)."""
from dse.families.legacy import legacy_family

HybridObserver = legacy_family("hybrid-observer", "dse.families.wang_liu_morse", paper_id="wang-liu-morse", example="generic.toml")
