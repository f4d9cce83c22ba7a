"""One BLAS thread in the test process and its children, as the `dse` command sets: the matrices
are small, and BLAS threads only contend with the worker processes (a small scipy call costs
100x more under load with threads on). Set before numpy is first imported."""
import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
