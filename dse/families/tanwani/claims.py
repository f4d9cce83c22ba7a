"""The claims and hypotheses of the random-communication filtering paper, in report order.

Claim ids: `<paper-id>.<where>.<what>.<scenario>`; hypothesis ids `<paper-id>.hyp.<scenario>.<name>`
(the scenario named only in a run of several: `<name>.hyp.alpha` in a user's run).
Every claim names the hypotheses its conclusion rests on; a claim whose hypotheses fail is
not checkable (the driver says which). Exact computations are compared with round-off
allowances derived from the sizes, operation counts and condition numbers of the computation;
Monte Carlo statements use tests that keep their level at the sample size used:

* exact laws where they are known: given a clock path the errors are Gaussian with a known
  covariance, so sums of squared (whitened) errors are exactly χ²; Poisson counts are exactly
  Poisson; sums of independent sign-symmetric differences obey Efron's self-normalised bound;
* for means over random clock paths of nonnegative per-path quantities (heavy right tails when
  nodes are unstable between rings): the variance over paths is computed exactly from the
  second-moment equation of the P-process, a sample mean too low is tested with Bernstein's
  inequality for variables bounded above (valid at any sample size), a sample mean too high
  only when both the Student statistic and the known-variance z statistic are significant
  (each errs on one side of the skewness, so requiring both keeps the level).

The checks are registered, with their ids, statements and hypotheses, in the modules the ClaimSet lists
(`claims_common`), in the order of the report (the run-level Lemma III.3 first, then every
scenario's claims, then the paper's topology sweep, the errata and what cannot be checked).
"""
from .claims_common import claims as _claims

claims = _claims.complete()

__all__ = ["claims"]
