"""The claims and hypotheses of the noisy-communication paper, each registered on its check.

Every check compares our computation with an independent one (another formula, a solver,
Monte Carlo under an exact law) or, for claims of scope "paper-example", with reference
numbers computed independently for our reconstruction of the paper's example. Claim ids
follow `savas.<where>.<what>`; each claim names the hypotheses its conclusion rests on.
The modules register into one `ClaimSet`, imported here in the order of the report:
hypotheses, the model and the proof's algebra, Theorem 1, the Monte Carlo against the exact
laws, the optimal gains and references, §IV, Carli's filter, the figures.
"""
from .common import claims as _claims

claims = _claims.complete()

__all__ = ["claims"]
