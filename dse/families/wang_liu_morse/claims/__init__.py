"""The hybrid-observer paper's hypotheses and claims, each registered on its check: the claims are
checked on every scenario of the family (scope "family") and, in the paper's reproduction, on
the Section 6 example (scope "paper-example"); ids `wang-liu-morse.<where>.<what>`. The modules
register into one `ClaimSet` (made in `hypotheses`), imported here in the order of the report:
the hypotheses, the claims on the design (`designs`), on the communication and the error
recursion (`iterations`), on Lemma 4 and the theorems' bounds (`bounds`), and on the centralized
reference and Section 6's figures (`figures`); `common` holds what the checks share."""
from .hypotheses import claims as _claims

claims = _claims.complete()

__all__ = ["claims"]
