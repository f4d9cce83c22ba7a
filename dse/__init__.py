"""dse: distributed state estimation, reproduced. The Python entry point (see `pipeline.api`).

    import dse
    run = dse.run("my_scenario.toml", trials=5000)      # or a dict, or dse.paper("savas")
    run.counts, run.hypotheses, run.claims, run.tables["nodes"]
    run.write("out/run/mine")                          # files only when asked
    dse.check("my_scenario.toml").estimate             # validate and estimate, no simulation
"""
from pipeline.api import Check, Run, check, execute, load, paper, run
from pipeline.errors import ScenarioError
from pipeline.reproduction import RunOptions

__all__ = ["Check", "Run", "RunOptions", "ScenarioError", "check", "execute", "load", "paper", "run"]
