"""One BLAS thread in the test process and its children, as the `dse` command sets: the matrices
are small, and BLAS threads only contend with the worker processes (a small scipy call costs
100x more under load with threads on). Set before numpy is first imported."""
import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import gc  # noqa: E402

import pytest  # noqa: E402

# Property tests: `make test` draws the same examples on every run (a CI verdict must not depend on the
# luck of the draw); DSE_HYPOTHESIS=explore draws new ones each run, to look for counterexamples.
from hypothesis import settings  # noqa: E402

settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("DSE_HYPOTHESIS", "repeatable"))


# The longest test files first. `make test` hands whole files to its workers (`--dist loadfile`) in the order
# collected (`--no-loadscope-reorder`; pytest-xdist's own order is by number of tests, which put the longest file,
# with a handful of tests, at the end, where it ran alone on one core while the other workers had finished). Longest
# first is the classic greedy balance: the short files fill the gaps at the end. The list is the twenty longest, longest
# first, ranked by twice a file's CPU time (its share of 2 cores among `make test`'s 4 workers) plus the time it only
# waits (sleeps, timeouts: test_faults.py about 9 s, test_scheduler_run.py about 7 s). The CPU times are per test, the
# test's own and that of the processes it started, summed per file over a run of the whole suite (the load of a shared
# machine moves durations, not CPU times). A file missing from the list only starts later, and the order of tests
# inside a file is kept.
LONGEST_FILES = (
    "test_kar_moura_reproduction.py", "test_sweep.py", "test_faults.py", "test_generated_scenarios.py",
    "test_tanwani_cli.py", "test_generated_gossip_coestimation.py", "test_generated_random_comm.py",
    "test_tran_reproduction.py", "test_scheduler_run.py", "test_cli.py", "test_wang_liu_morse_repro.py",
    "test_tanwani_pipeline.py", "test_scheduler_families.py", "test_tran_pipeline.py", "test_arena.py",
    "test_plugin_protocol.py", "test_kar_moura_pipeline.py", "test_readme_examples.py", "test_plugin_faults.py",
    "test_output_truth.py",
)


def pytest_collection_modifyitems(config, items):
    """Orders the collected tests by LONGEST_FILES (a stable sort: every other order is kept)."""
    rank = {name: i for i, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONGEST_FILES)))


_module_of_last_setup = [None]


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """At the first test of each module, before its fixtures: the cyclic garbage of the modules before it is collected
    and what is still alive (the collected tests, the libraries imported so far, session fixtures) is exempted from the
    garbage collector's later passes (`gc.freeze`), which otherwise walk those millions of objects again and again in
    every worker and in the processes a run forks from it (0.80 -> 0.45 s of GC in a process running 35 s of tests).
    A frozen object is still freed when its last reference goes; only a reference cycle among objects that were alive
    when a module started waits for the end of the session."""
    if item.path != _module_of_last_setup[0]:
        _module_of_last_setup[0] = item.path
        gc.collect()
        gc.freeze()
