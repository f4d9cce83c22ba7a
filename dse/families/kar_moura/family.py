"""The gossip-kalman family (TEMPORARY: the old reproduction module seen through the contract)."""
from dse.families.legacy import legacy_family

GossipKalman = legacy_family("gossip-kalman", "dse.families.kar_moura", paper_id="kar-moura", example="scenarios/e1.toml")
