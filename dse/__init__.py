"""dse: distributed state estimation, reproduced. The Python entry point (see `pipeline.api`).

    import dse
    run = dse.run("my_scenario.toml", trials=5000)
    run.claims, run.hypotheses, run.tables["claims"], run.write("out/run/mine")
"""
from pipeline.api import Run, execute, load, paper, run
from pipeline.errors import ScenarioError

__all__ = ["Run", "ScenarioError", "execute", "load", "paper", "run"]
