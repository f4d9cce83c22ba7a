"""The prefetcher of a multi-paper `dse reproduce` (dse.engine.prefetch): it computes the last papers ahead, never
one the run has reached, and the run waits for the paper it is computing; a failure there is the run's to meet."""
import json
import os
import time

import pytest

from dse.engine.prefetch import prefetching, worth_prefetching
from dse.contract.options import RunOptions


def _log(path, text):
    with open(path, "a") as f:
        f.write(text + "\n")


def _lines(path):
    return path.read_text().split() if path.exists() else []


@pytest.mark.parametrize("cost_s", [0.0, 0.3])
def test_the_run_and_the_prefetcher_share_the_papers_without_overlap(tmp_path, cost_s):
    """Paper i costs `cost_s` wherever it runs; every paper is computed once, the run's papers from the first on
    and the prefetcher's from the last one back, and a paper the prefetcher computes is done before the run uses it."""
    n, ahead, ran = 5, tmp_path / "ahead", tmp_path / "ran"

    def compute(i):
        time.sleep(cost_s)
        _log(ahead, str(i))

    with prefetching(n, compute, True) as reach:
        for i in range(n):
            reach(i)
            if str(i) not in _lines(ahead):
                time.sleep(cost_s)          # the run computes paper i itself
                _log(ran, str(i))
    done, own = [int(x) for x in _lines(ahead)], [int(x) for x in _lines(ran)]
    assert sorted(done + own) == list(range(n))
    assert own == list(range(len(own))) and done == list(range(n - 1, n - 1 - len(done), -1))
    assert 0 in own


def test_a_failure_ahead_leaves_the_paper_to_the_run(tmp_path):
    """The prefetcher stops at a paper it cannot compute (its exception goes nowhere): the run computes it."""
    ahead = tmp_path / "ahead"

    def compute(i):
        if i == 2:
            raise RuntimeError("refused")
        _log(ahead, str(i))

    with prefetching(3, compute, True) as reach:
        time.sleep(0.3)
        for i in range(3):
            reach(i)
    assert _lines(ahead) == []


def test_the_prefetcher_is_stopped_when_the_run_fails():
    """A run that fails ends the prefetcher before anything else happens (the lock's undo comes after)."""
    with pytest.raises(KeyError):
        with prefetching(3, lambda i: time.sleep(30), True) as reach:
            pid = reach.__self__.proc.pid
            raise KeyError("the run failed")
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_the_prefetcher_runs_at_the_lowest_priority(tmp_path):
    """It takes the cores the run leaves idle, and hardly any other."""
    nice = tmp_path / "nice"
    with prefetching(2, lambda i: _log(nice, str(os.getpriority(os.PRIO_PROCESS, 0))), True):
        deadline = time.time() + 20
        while not _lines(nice) and time.time() < deadline:
            time.sleep(0.05)
    assert int(_lines(nice)[0]) == min(19, os.getpriority(os.PRIO_PROCESS, 0) + 19)


def test_only_where_it_pays(monkeypatch):
    opts = RunOptions(quick=True, workers=2)
    assert worth_prefetching(["a", "b"], opts, fresh=False)
    assert not worth_prefetching(["a"], opts, fresh=False)
    assert not worth_prefetching(["a", "a"], opts, fresh=False)           # one cache: the same paper twice
    assert not worth_prefetching(["a", "b"], opts, fresh=True)            # --fresh recomputes what it did not write
    assert not worth_prefetching(["a", "b"], RunOptions(quick=True, workers=1), fresh=False)
    assert not worth_prefetching(["a", "b"], RunOptions(quick=True, workers=2, scheduler="inline"), fresh=False)
    monkeypatch.setenv("DSE_PREFETCH", "0")
    assert not worth_prefetching(["a", "b"], opts, fresh=False)


def test_what_the_prefetcher_computes_is_what_the_run_reads(tmp_path):
    """A paper's stages computed ahead (`paper_stages`, with its own share of the memory) are the run's very cache
    entries: the run computes none, and writes the same report and tables as a run without them."""
    from dse import registry
    from dse.engine.driver import cache_for, run
    from dse.engine.prefetch import paper_stages

    opts = RunOptions(quick=True, trials=4000, workers=2)
    paper_stages(registry.paper("savas"), opts, cache_for(tmp_path / "a", "savas").root)
    run(registry.paper("savas"), tmp_path / "a", opts, figures=False)
    run(registry.paper("savas"), tmp_path / "b", opts, figures=False)
    report = {k: json.loads((tmp_path / k / "savas" / "report.json").read_text()) for k in "ab"}
    assert all(s["cached"] for s in report["a"]["provenance"]["stages"])
    assert not any(s["cached"] for s in report["b"]["provenance"]["stages"])
    assert report["a"]["claims"] == report["b"]["claims"]
    tables = sorted(p.name for p in (tmp_path / "a" / "savas" / "tables").iterdir())
    assert tables and all((tmp_path / "a" / "savas" / "tables" / t).read_bytes()
                          == (tmp_path / "b" / "savas" / "tables" / t).read_bytes() for t in tables if t.endswith(".csv"))


def test_a_prefetcher_killed_holding_its_lock_does_not_block_the_run():
    """Killed from outside (SIGKILL) at the worst moment: the run goes on and computes the papers itself."""
    with prefetching(4, lambda i: time.sleep(30), True) as reach:
        pre = reach.__self__
        pre.lock.acquire()                      # as if the prefetcher held it when it was killed
        os.kill(pre.proc.pid, 9)
        started = time.time()
        for i in range(4):
            reach(i)
        assert time.time() - started < 10 and pre.stopped
