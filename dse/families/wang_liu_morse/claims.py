"""The hybrid-observer paper's claims, checked on every scenario of the family (scope "family")
and, in the paper's reproduction, on the Section 6 example (scope "paper-example"); ids
`wang-liu-morse.<where>.<what>`. They are registered on their checks in four modules, each
importing the one before it so that the report keeps the paper's order: `claims_design` (the
design), `claims_simulation` (communication and error recursion), `claims_bounds` (Lemma 4 and
the theorems' bounds) and `claims_figures` (the centralized reference, Section 6's figures);
the hypotheses are in `hypotheses`, the shared cell logic in `checks`."""
from __future__ import annotations

from . import claims_figures  # noqa: F401 (registers every claim, in order)
from .hypotheses import claims

__all__ = ["claims"]
