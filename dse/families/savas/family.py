"""The noisy-consensus-filter family (TEMPORARY: the old reproduction module seen through the contract)."""
from dse.families.legacy import legacy_family

NoisyConsensusFilter = legacy_family("noisy-consensus-filter", "dse.families.savas", paper_id="savas", example="paper.toml")
