"""What `dse arena` writes into OUT/arena/<name>/: the leaderboard (per scenario and estimator) and its
summary per estimator as documented tables (tables/), summary.md, the frontier figure (frontier.png: error
against communication per scenario, the filter highlighted, the frontier drawn), a recording (arena.rrd) and
every suite scenario as a TOML file (scenarios/<scenario>.toml: `dse run` it for the full compare outputs).

Verdict columns: a plug-in filter's own claims (`compare.plugin.<name>.*`); a built-in estimator's are the
run's claims that cover the built-ins jointly (orthogonality and the lower bound: every built-in; NEES: the
built-ins whose covariance is conditional; exact moments: those with exact moments), so a built-in row shows
whether that joint claim held on the scenario.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from dse.outputs.tables import Tables, read_arrow_file, spec

#: the verdict columns and, per column, the plug-in's claim and the built-ins' joint claim
CHECKS = {"orthogonality": ("orthogonality", "compare.central.orthogonality"),
          "lower_bound": ("lower_bound", "compare.central.lower_bound"),
          "nees": ("nees", "compare.kalman.conditional_covariance"),
          "exact_moments": ("exact_moments", "compare.exact.monte_carlo")}
#: a filter whose MSE is this many times the centralized filter's, or not finite, has diverged
DIVERGED_RATIO = 1e6

_S = ("scenario", "", "suite scenario (scenarios/<scenario>.toml)")
_E = ("estimator", "", "estimator id (a built-in's, or the filter's name)")

LEADERBOARD = spec("leaderboard", "estimator on a suite scenario, at its evaluation step", [
    _S, _E, ("label", "", "what the estimator is"), ("plugin", "", "true for the filter under test"),
    ("mse_ratio", "1", "Monte Carlo network MSE over the centralized filter's, on the same trials (≥ 1 in "
                       "expectation by optimality)"),
    ("network_mse", "state²", "Monte Carlo node average of ‖x − x̂_i‖² (mean over trials)"),
    ("scalars_per_step", "1", "real numbers sent per node and step"),
    ("messages_per_step", "1", "messages sent per node and step"),
    ("nees", "1", "mean NEES with the estimator's own covariance (n when consistent; empty without one)"),
    ("diverged", "", f"network MSE not finite or above {DIVERGED_RATIO:g} times the centralized filter's"),
    ("frontier", "", "no network estimator of the scenario has both a smaller MSE and sends no more (the "
                     "centralized filter, which gathers every measurement, is the reference, not a competitor)"),
    *[(f"verdict_{c}", "", f"verdict of the {c.replace('_', ' ')} claim (module doc)") for c in CHECKS],
    ("ran", "", "true when it ran on the scenario (false: left out for breaking the protocol; its numbers empty)"),
    ("fault", "", "what the filter did wrong (left out, or its exact moments left out when only its matrices were "
                  "wrong)")],
    "Every estimator on every suite scenario: error against communication, consistency and verdicts.")

SUMMARY = spec("summary", "estimator over the suite", [
    _E, ("label", "", "what the estimator is"), ("plugin", "", "true for the filter under test"),
    ("scenarios", "", "suite scenarios it ran on"),
    ("mse_ratio_geomean", "1", "geometric mean of mse_ratio over the scenarios it ran on without diverging"),
    ("scalars_per_step_mean", "1", "mean over those scenarios of the numbers sent per node and step"),
    ("on_frontier", "", "scenarios where it is on the error-communication frontier"),
    ("diverged", "", "scenarios where it diverged"),
    ("fails", "", "its verdict cells that are fail"),
    ("faults", "", "scenarios where it broke the protocol (the leaderboard's fault column)")],
    "The leaderboard, one row per estimator, the filter under test first.")


def _claims(result: dict[str, Any]) -> dict[str, str]:
    return {c["id"]: c["verdict"] for c in result.get("claims", [])}


def _verdicts(name: str, est: str, plugin: bool, claims: dict[str, str]) -> dict[str, str]:
    out = {}
    for col, (own, joint) in CHECKS.items():
        out[f"verdict_{col}"] = claims.get(f"compare.plugin.{name}.{own}" if plugin else joint, "") \
            if est != "central" else ""
    return out


def frontier(mse: np.ndarray, scalars: np.ndarray) -> np.ndarray:
    """Which points (MSE, scalars) no other point dominates (smaller or equal in both, smaller in one)."""
    ok = np.isfinite(mse)
    out = np.zeros(len(mse), bool)
    for i in np.flatnonzero(ok):
        dominated = ok & (mse <= mse[i]) & (scalars <= scalars[i]) & ((mse < mse[i]) | (scalars < scalars[i]))
        out[i] = not dominated.any()
    return out


def scenario_rows(name: str, scenario: str, result: dict[str, Any]) -> list[dict[str, Any]]:
    """The leaderboard's rows of one scenario's run."""
    files = result.get("table_files", {})
    est = read_arrow_file(files["estimators"]).to_pandas() if "estimators" in files else pd.DataFrame()
    faults = read_arrow_file(files["faults"]).to_pandas() if "faults" in files else pd.DataFrame(columns=["estimator"])
    claims = _claims(result)
    central = est.loc[est["estimator"] == "central", "network_mse_mc"]
    c = float(central.iloc[0]) if len(central) else np.nan
    rows = []
    what = dict(zip(faults["estimator"], faults["what"])) if len(faults) else {}
    for r in est.itertuples():
        plugin = r.estimator == name
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = float(r.network_mse_mc) / c
        rows.append({"scenario": scenario, "estimator": r.estimator, "label": r.label, "plugin": plugin,
                     "mse_ratio": ratio, "network_mse": float(r.network_mse_mc),
                     "scalars_per_step": float(r.scalars_per_step), "messages_per_step": float(r.messages_per_step),
                     "nees": float(r.nees), "diverged": bool(not np.isfinite(ratio) or ratio > DIVERGED_RATIO),
                     **_verdicts(name, r.estimator, plugin, claims), "ran": True, "fault": what.pop(r.estimator, "")})
    for estimator, fault in what.items():             # left out of the simulation: no numbers
        rows.append({"scenario": scenario, "estimator": estimator, "label": estimator, "plugin": True,
                     "mse_ratio": np.nan, "network_mse": np.nan, "scalars_per_step": np.nan,
                     "messages_per_step": np.nan, "nees": np.nan, "diverged": False,
                     **_verdicts(name, estimator, True, claims), "ran": False, "fault": fault})
    mse = np.array([r["mse_ratio"] for r in rows])
    out = np.array([r["diverged"] or r["estimator"] == "central" for r in rows])
    on = frontier(np.where(out, np.nan, mse), np.array([r["scalars_per_step"] for r in rows]))
    for r, f in zip(rows, on):
        r["frontier"] = bool(f)
    return rows


def summary_rows(board: pd.DataFrame, name: str) -> list[dict[str, Any]]:
    rows = []
    for est, g in board.groupby("estimator", sort=False):
        ran = g[g["ran"]]
        ok = ran[~ran["diverged"]]
        verdicts = g[[f"verdict_{c}" for c in CHECKS]].to_numpy().ravel()
        rows.append({"estimator": est, "label": g["label"].iloc[0], "plugin": est == name, "scenarios": len(ran),
                     "mse_ratio_geomean": float(np.exp(np.log(ok["mse_ratio"]).mean())) if len(ok) else np.nan,
                     "scalars_per_step_mean": float(ok["scalars_per_step"].mean()) if len(ok) else np.nan,
                     "on_frontier": int(ran["frontier"].sum()), "diverged": int(ran["diverged"].sum()),
                     "fails": int((verdicts == "fail").sum()), "faults": int((g["fault"] != "").sum())})
    rows.sort(key=lambda r: (not r["plugin"], r["mse_ratio_geomean"] if np.isfinite(r["mse_ratio_geomean"]) else np.inf))
    return rows


def write_arena(name: str, table: dict[str, Any], tasks: list, results: dict[str, dict[str, Any]],
                failures: dict[str, str], out_dir: Path, *, quick: bool, seed: int) -> dict[str, Any]:
    """Every output of the arena into `out_dir` (module doc); returns the filter's summary counts."""
    from dse.scenario.fields import toml_text

    rows = []
    (out_dir / "scenarios").mkdir(parents=True, exist_ok=True)
    for t in tasks:
        scenario = t.point.values["scenario"]
        (out_dir / "scenarios" / f"{scenario}.toml").write_text(toml_text(t.scenario))
        if t.key in results and results[t.key].get("status") == "ok":
            rows += scenario_rows(name, scenario, results[t.key])
    board = pd.DataFrame(rows, columns=LEADERBOARD.column_names)
    summary = pd.DataFrame(summary_rows(board, name), columns=SUMMARY.column_names)
    tables = Tables()
    tables.add(LEADERBOARD, board)
    tables.add(SUMMARY, summary)
    tables.write(out_dir / "tables")
    from .views import frontier_figure, markdown, recording

    text = markdown(name, table, board, summary, failures, quick=quick, seed=seed)
    (out_dir / "summary.md").write_text(text)
    if len(board):
        frontier_figure(name, board, out_dir / "frontier.png")
        recording(name, board, text, out_dir / "arena.rrd", seed=seed)
    mine = board[board["estimator"] == name]
    return {"filter": name, "rows": len(board), "fails": int((mine[[f"verdict_{c}" for c in CHECKS]] == "fail").sum().sum()),
            "faults": [f"{r.scenario}: {r.fault}" for r in mine.itertuples() if r.fault],
            "on_frontier": int(mine["frontier"].sum()), "ran": int(mine["ran"].sum())}
