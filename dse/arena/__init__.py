"""`dse arena`: a researcher's filter against every built-in estimator, over a standard suite of compare
scenarios (`suite`), with the same claims; a leaderboard, a frontier figure and a recording (`outputs`),
each scenario one task run in process or on a Dask cluster (`run`)."""
