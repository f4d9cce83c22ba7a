"""One BLAS thread in the test process and its children, as the `dse` command sets: the matrices
are small, and BLAS threads only contend with the worker processes (a small scipy call costs
100x more under load with threads on). Set before numpy is first imported."""
import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

# Property tests: `make test` draws the same examples on every run (a CI verdict must not depend on the
# luck of the draw); DSE_HYPOTHESIS=explore draws new ones each run, to look for counterexamples.
from hypothesis import settings  # noqa: E402

settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("DSE_HYPOTHESIS", "repeatable"))
