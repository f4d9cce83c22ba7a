"""Gossip interactive Kalman filtering (Kar & Moura's GIKF), gathered from its three modules:

- `gikf_maps`: the signal model, the Riccati maps f_n (Joseph and square-root forms) with their
  round-off bounds, the covariance features and one GIKF slot;
- `gossip_protocols`: the laws of the matchings A(t) and their mean Ā;
- `gikf_monte_carlo`: batched runs, the accumulators of their statistics and how units combine.
"""
from .gikf_monte_carlo import (QUANTILES, RUN_AXIS, SUMS, MINS, Accumulator, FinalMoments, GikfRuns,  # noqa: F401
                               LoewnerMargins, Nees, OverRuns, RecordTimes, SamplePaths, TokenChain, decimated_slots,
                               finish_gikf, fold_gikf, gikf_units, simulate_gikf, standard_accumulators)
from .gikf_maps import *  # noqa: F401,F403
from .gikf_maps import (EPS, ENTRYWISE_MAX_M, FEATURES, GossipSystem, covariance_features,  # noqa: F401
                            eigvalsh, error_norm, factor_features, factor_psd, gikf_covariance_step, gikf_error_step,
                            lyapunov_roundoff, lyapunov_step, propagate_error, riccati_roundoff, riccati_sqrt_step,
                            riccati_step, riccati_textbook, swap)
from .gossip_protocols import (GreedyMatchingGossip, MatchingDistribution, MatchingSequence,  # noqa: F401
                               NodeInitiatedGossip, SingleEdgeGossip, matching_at)
