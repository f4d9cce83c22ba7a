"""Dask clients: a local cluster of worker processes, or a connection to a running scheduler
(``tcp://HOST:PORT``). What `dse sweep` runs its points on and what a run's Monte Carlo units go to
(`dse run --scheduler`, `dse.simulate.executor`)."""
from __future__ import annotations

import contextlib
import logging
from typing import Callable, Iterator

from dse.errors import ScenarioError

#: environment of every worker: one BLAS thread (the tasks are the parallelism), no inner bars
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "DSE_PROGRESS": "0"}
#: Dask settings of a local cluster (its scheduler, nannies and workers): the periodic housekeeping that serves the
#: dashboard's profile and event-loop-health pages, sampled less often (the defaults cost each idle worker 4-5 % of a
#: core, and the client as much: on 2 cores, a fifth of one taken from the workers' tasks); work stealing, memory
#: limits and heartbeats keep their defaults
QUIET_CONFIG = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "500ms",
                "distributed.admin.system-monitor.interval": "2s"}
#: the names `--scheduler` accepts besides a scheduler's address
SCHEDULERS = ("auto", "inline", "local")
SCHEDULER_HELP = "auto, inline, local or an address such as tcp://HOST:8786"


def check_scheduler(scheduler: object, field: str = "--scheduler", error: type[ScenarioError] = ScenarioError) -> str:
    """`scheduler` if it is one of SCHEDULERS or an address (``tcp://HOST:PORT``); else `error` naming `field`."""
    if not isinstance(scheduler, str) or (scheduler not in SCHEDULERS and "://" not in scheduler):
        raise error(field, f"must be {SCHEDULER_HELP}, got {scheduler!r}")
    return scheduler


def start_local(workers: int):
    """(cluster, client): a local cluster of `workers` single-thread worker processes on loopback."""
    import dask
    from dask.distributed import Client, LocalCluster

    from distributed.gc import disable_gc_diagnosis

    # the settings are read when the scheduler and the nannies are made; a nanny hands its own to its worker
    with dask.config.set(QUIET_CONFIG):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address="127.0.0.1:0", silence_logs=logging.CRITICAL, env=WORKER_ENV)
    # the cluster's scheduler runs in this process and hooks a diagnosis into every garbage collection: a Ctrl-C
    # that lands in that hook is swallowed (the run goes on) and prints two tracebacks; it only measures GC time
    disable_gc_diagnosis(force=True)
    return cluster, Client(cluster)


def connect(scheduler: str):
    """A client of the scheduler at the address `scheduler`; ScenarioError naming --scheduler if it cannot be reached."""
    from dask.distributed import Client

    try:
        return Client(scheduler, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise ScenarioError("--scheduler", f"cannot reach the Dask scheduler at {scheduler} ({exc})") from None


def wait_for_a_worker(client, scheduler: str, where: str, log: Callable[[str], None], worker_timeout: float) -> int:
    """The number of workers of `client`'s cluster, after waiting up to `worker_timeout` seconds for a first one
    (ScenarioError naming --scheduler if none joins); says where it runs with `log`."""
    n_workers = len(client.scheduler_info().get("workers", {}))
    if n_workers == 0:
        log(f"dask: {where} has no worker yet; waiting up to {worker_timeout:g} s for one")
        try:
            client.wait_for_workers(1, timeout=worker_timeout)
        except (TimeoutError, OSError):
            raise ScenarioError("--scheduler", f"no worker joined the Dask scheduler at {scheduler} within "
                                               f"{worker_timeout:g} s (start workers with `dask worker {scheduler}`)") from None
        n_workers = len(client.scheduler_info().get("workers", {}))
    log(f"dask: {where} with {n_workers} worker(s); dashboard {client.dashboard_link}")
    return n_workers


@contextlib.contextmanager
def dask_client(scheduler: str, workers: int, *, log: Callable[[str], None] = print,
                worker_timeout: float = 60.0) -> Iterator:
    """A client on a local cluster of `workers` processes (`scheduler` is "local") or on the scheduler at the
    address `scheduler`, with at least one worker; closed (and the local cluster stopped) on exit."""
    cluster, client = start_local(workers) if scheduler == "local" else (None, connect(scheduler))
    try:
        wait_for_a_worker(client, scheduler, "local cluster" if cluster else scheduler, log, worker_timeout)
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
