"""Plug-in filters (`dse.plugin`) against the built-ins: the same numbers and verdicts for a filter algebraically
identical to a built-in, `fail` for a deliberately biased one, common random numbers, and generated scenarios.

The twins (tests/plugins/twins.py) are written against the public protocol only. `LocalTwin` does the built-in
local filter's arithmetic in the same order, so its Monte Carlo sums are the same bits. `DiffusionTwin` computes
the diffusion filter's estimates in another order (through messages, an information-form update and an explicit
inverse): its sums agree to the round-off bound `ROUNDOFF` derives below.
"""
from __future__ import annotations

import copy

import numpy as np
import pytest

import dse
from dse import registry
from dse.contract.context import StageContext
from dse.contract.options import RunOptions
from dse.engine.cache import MemoryCache
from dse.engine.driver import evaluate_claims
from dse.estimators.network_comparison import TRUE_STATE

from test_compare_family import tiny

TWINS = "tests.plugins.twins"
LINKS = {"reliable": {}, "failures": {}, "matchings": {}, "poisson": {"rate": 0.7, "rounds": 1}}
#: z-tested claims need 500 trials (claims.MIN_TRIALS_Z): the verdict tests run 600, the bit tests fewer
VERDICT_TRIALS = 600
BIT_TRIALS = 240
EPS = np.finfo(float).eps


def scenario(model: str = "reliable", noise: float = 0.3, plugins: dict[str, str] | None = None,
             include: list[str] | None = None) -> dict:
    """The tiny 4-node compare scenario on `model` links with `plugins` (name -> "module:Class")."""
    data = tiny(model=model, noise_std=noise, **LINKS[model])
    est: dict = {"include": include} if include else {}
    est.update({name: {"factory": f if ":" in f else f"{TWINS}:{f}"} for name, f in (plugins or {}).items()})
    if est:
        data["estimators"] = est
    return data


def compute(data: dict, trials: int, seed: int = 5, workers: int = 1):
    """(reproduction, computed) of a scenario dict, in memory."""
    repro = registry.from_dict(data)
    return repro, repro.compute(RunOptions(seed=seed, trials=trials, workers=workers), StageContext(MemoryCache()))


def stage_arrays(res, name: str) -> dict[str, np.ndarray]:
    """Every array of the monte_carlo and exact_moments stages that belongs to estimator `name`."""
    out = {f"mc.{k}": v for k, v in res.mc.get(name, {}).items()}
    out.update({f"exact.{k}": v for k, v in res.exact.get(name, {}).items()})
    if name in res.token:
        out["token"] = res.token[name]
    if name in res.paths:
        out["path"] = res.paths[name]
    return out


def assert_same_bits(a: dict, b: dict, what: str) -> None:
    assert set(a) == set(b), (what, sorted(set(a) ^ set(b)))
    for key in a:
        assert np.array_equal(a[key], b[key], equal_nan=True), (what, key)


# -- LocalTwin: the built-in local filter through the protocol ----------------------------------------------------

#: sums the twin has and the built-in has not (zero): exact-law NEES (the twin declares its matrices, so its
#: exact covariance is computed; the built-in local filter is checked through its own covariance)
TWIN_ONLY = {"xnees"}


@pytest.mark.parametrize("model", list(LINKS))
def test_local_twin_has_the_builtins_monte_carlo_sums_to_the_bit(model):
    _, comp = compute(scenario(model, plugins={"twin": "LocalTwin"}, include=["local"]), BIT_TRIALS)
    res = comp.results
    assert not res.faults
    local, twin = ({k: v for k, v in stage_arrays(res, name).items()
                    if not k.startswith("exact.") and k[3:] not in TWIN_ONLY} for name in ("local", "twin"))
    assert_same_bits(local, twin, model)
    assert res.mc["twin"]["msgs"].sum() == 0 and res.mc["twin"]["scalars"].sum() == 0


def joint_roundoff(res) -> float:
    """Relative round-off allowed between the twin's exact moments (the joint recursion of `dse.plugin.exact` on
    (N n)² matrices from its declared A, B) and the local filters' own Riccati recursions: each entry is, per
    step, a sum of N n + N m products (A Σ Aᵀ + B R Bᵀ) against n + m (the Riccati step), over K steps, each
    operation off by at most eps relative, amplified by at most cond(Σ_ii) when compared through Σ_ii⁻¹ (NEES)."""
    m = res.design.model
    K = res.scenario.simulation.steps
    cond = max(np.linalg.cond(b) for b in res.exact["local"]["blocks"].reshape(-1, m.n, m.n))
    return 10.0 * K * (m.N * m.n + m.N * m.m) * EPS * cond


def at_confidence(confidence: float, check, *args):
    """A claim's check run on the built-in, at the confidence the run gave each claim (its Bonferroni share)."""
    from dse.verify import rules

    token = rules._confidence.set(confidence)
    try:
        return check(*args)
    finally:
        rules._confidence.reset(token)


def test_local_twin_has_the_builtins_exact_moments_tables_and_verdicts():
    from dse.families.compare import claims as C

    run = dse.run(scenario("reliable", plugins={"twin": "LocalTwin"}, include=["local"]), trials=VERDICT_TRIALS,
                  seed=2, workers=1)
    res = run.results
    tol = joint_roundoff(res)
    assert 0 < tol < 1e-9
    for k, v in res.exact["local"].items():                    # blocks, mse, disagreement
        assert np.allclose(res.exact["twin"][k], v, rtol=tol, atol=0), k
    assert np.allclose(res.mc["twin"]["xnees"], res.mc["local"]["nees"], rtol=tol, atol=0)
    for table in ("estimators", "nodes", "series"):
        t = run.tables[table]
        a = t[t.estimator == "local"].drop(columns=["estimator", "label"], errors="ignore").reset_index(drop=True)
        b = t[t.estimator == "twin"].drop(columns=["estimator", "label"], errors="ignore").reset_index(drop=True)
        assert len(a) and a.shape == b.shape, table
        for col in a:
            x, y = a[col].to_numpy(), b[col].to_numpy()
            if x.dtype.kind == "f" and col.endswith("_exact") or col in ("network_mse", "excess", "disagreement"):
                assert np.allclose(x.astype(float), y.astype(float), rtol=tol, atol=0, equal_nan=True), (table, col)
            else:
                assert (x == y).all() or np.array_equal(x, y, equal_nan=True), (table, col, x, y)
    claims = {c["id"]: c for c in run.evaluation.claims}
    confidence = run.evaluation.statistics["groups"]["plugin:twin"]["per_claim_confidence"]
    for check, cid in ((C.plugin_orthogonality, "orthogonality"), (C.plugin_lower_bound, "lower_bound"),
                       (C.plugin_nees, "nees")):
        builtin, twin = at_confidence(confidence, check, res, "local"), claims[f"compare.plugin.twin.{cid}"]
        assert twin["verdict"] == builtin.status == "pass", (cid, twin["detail"])
        assert (twin["measured"], twin["margin"]) == (builtin.measured, builtin.margin), cid
    # its exact law is the local filters' own Kalman covariance: the same χ² test as their NEES, to round-off
    exact, nees = claims["compare.plugin.twin.exact_moments"], at_confidence(confidence, C.plugin_nees, res, "local")
    assert exact["verdict"] == nees.status == "pass", exact["detail"]
    assert abs(exact["margin"] - nees.margin) <= 1e-6 * abs(nees.margin)


# -- DiffusionTwin: the built-in diffusion filter through messages --------------------------------------------------

#: the sums of a quadratic (2) or quartic (4) function of the errors, and the sums the twin has not (it reports no
#: covariance and does not declare itself linear)
QUADRATIC = ("sq", "dist", "cross", "gap", "dis", "dis_node", "net")
QUARTIC = ("sq2", "dist2", "cross2", "gap2", "dis2", "net2")
NOT_COMPARED = ("nees", "nees2", "xnees")
#: operations per step behind one estimate of either implementation (an n × n inverse, n × n products, sums over at
#: most the largest degree of messages, the noise): far fewer than this on the tiny scenario (n = 2, degree 2)
OPS_PER_STEP = 100


def roundoff(res, power: int) -> float:
    """Relative bound on the difference of two round-offs of one sum: each estimate is off by at most
    OPS_PER_STEP · eps relative per step, accumulated over K steps (both filters are stable: a step does not
    amplify an earlier error); a sum of products of `power` errors moves by at most `power` times that relative to
    the sum of the `power`-th powers of ‖e_i‖ and ‖e_c‖ (which bound every term: |x̂_i − x̂_c| ≤ ‖e_i‖ + ‖e_c‖),
    times 2^power for the cross terms."""
    K = res.scenario.simulation.steps
    return power * 2.0 ** power * K * OPS_PER_STEP * EPS


def scale(res, name: str, key: str) -> np.ndarray:
    """The sum of the errors' powers that bounds every term of sum `key` (module doc of network_comparison)."""
    s, c = res.mc[name], res.mc["central"]
    power = "sq2" if key in QUARTIC else "sq"
    per_node = s[power] + c[power][..., :1]
    return per_node.sum(axis=-1) if key in ("dis", "dis2", "net", "net2") else per_node


@pytest.mark.parametrize("noise", [0.0, 0.3])
@pytest.mark.parametrize("model", list(LINKS))
def test_diffusion_twin_has_the_builtins_numbers_to_round_off(model, noise):
    _, comp = compute(scenario(model, noise, plugins={"dtwin": "DiffusionTwin"}, include=["diffusion"]), BIT_TRIALS)
    res = comp.results
    assert not res.faults
    a, b = res.mc["diffusion"], res.mc["dtwin"]
    assert set(a) == set(b)
    for key in ("msgs", "scalars"):                            # counted from what was sent: the same bits
        assert np.array_equal(a[key], b[key]), key
    assert a["scalars"].sum() > 0
    for key in QUADRATIC + QUARTIC:
        tol = roundoff(res, 4 if key in QUARTIC else 2) * scale(res, "diffusion", key)
        gap = np.abs(a[key] - b[key])
        assert (gap <= tol).all(), (key, float(np.max(gap / tol)))
    assert set(a) - set(QUADRATIC + QUARTIC + ("msgs", "scalars")) == set(NOT_COMPARED)


def test_the_round_off_bound_is_far_below_a_real_difference():
    """The bound above is not vacuous: the twin without its communication noise (a one-line change of the
    algorithm) differs from the built-in by orders of magnitude more than it allows."""
    _, comp = compute(scenario("failures", 0.3, plugins={"dtwin": "DiffusionTwin"}, include=["diffusion"]),
                      BIT_TRIALS)
    res = comp.results
    tol = roundoff(res, 2) * scale(res, "diffusion", "sq")
    _, comp2 = compute(scenario("failures", 0.3, plugins={"dtwin": f"{__name__}:NoiselessDiffusion"},
                                include=["diffusion"]), BIT_TRIALS)
    gap = np.abs(comp2.results.mc["dtwin"]["sq"] - res.mc["diffusion"]["sq"])
    assert gap.max() > 1e6 * tol.max()


from tests.plugins.twins import DiffusionTwin  # noqa: E402  (the variant's base)


class NoiselessDiffusion(DiffusionTwin):
    """The diffusion twin that forgets the communication noise of its fused estimates."""

    def step(self, k, y, network):
        real = network.exchange

        def exchange(payload):
            inbox = real(payload)
            return type(inbox)(inbox.values, inbox.delivered, inbox.heard, 0.0 * inbox.noise)
        network.exchange = exchange
        return super().step(k, y, network)


# -- a deliberately biased filter --------------------------------------------------------------------------------

def test_a_biased_filter_fails_orthogonality_and_the_lower_bound_with_a_margin_and_the_twins_pass():
    plugins = {"twin": "LocalTwin", "dtwin": "DiffusionTwin", "shrunk": "ShrunkLocal"}
    repro, comp = compute(scenario("reliable", plugins=plugins), VERDICT_TRIALS, seed=2)
    claims = {c["id"]: c for c in evaluate_claims(repro, comp).claims}
    orth, low = claims["compare.plugin.shrunk.orthogonality"], claims["compare.plugin.shrunk.lower_bound"]
    # halving the local estimate, declared equivariant: in error coordinates its error shrinks, so it seems to beat
    # the centralized filter (a negative mean gap), and its distance to it is not orthogonal to the central error
    assert orth["verdict"] == "fail" and low["verdict"] == "fail", (orth["detail"], low["detail"])
    assert low["measured"] < 0 and orth["measured"] < 0
    assert orth["margin"] < -10 and low["margin"] < -10, (orth["margin"], low["margin"])
    for name in ("twin", "dtwin"):
        for cid in ("orthogonality", "lower_bound"):
            c = claims[f"compare.plugin.{name}.{cid}"]
            assert c["verdict"] == "pass" and c["margin"] > 0, (name, cid, c["detail"])


# -- common random numbers -------------------------------------------------------------------------------------------

def builtin_claims(repro, comp) -> tuple[dict, dict, int]:
    """id -> (verdict, measured) and id -> margin of the built-ins' claims, and the number of statistical claims."""
    ev = evaluate_claims(repro, comp)
    rows = [c for c in ev.claims if ".plugin." not in c["id"]]
    return ({c["id"]: (c["verdict"], c["measured"]) for c in rows}, {c["id"]: c["margin"] for c in rows},
            ev.statistics["statistical_claims"])


@pytest.mark.parametrize("model", list(LINKS))
def test_adding_plugins_changes_no_other_number(model):
    """Every array of the monte_carlo and exact_moments stages of every built-in estimator, and every verdict of
    theirs, is the same with three plug-ins added (run on two workers: the split moves too)."""
    plugins = {"twin": "LocalTwin", "dtwin": "DiffusionTwin", "shrunk": "ShrunkLocal"}
    repro_a, a = compute(scenario(model), 500)
    repro_b, b = compute(scenario(model, plugins=plugins), 500, workers=2)
    assert not b.results.faults and set(plugins) <= set(b.results.mc)
    for name in a.results.design.running:
        assert_same_bits(stage_arrays(a.results, name), stage_arrays(b.results, name), f"{model}: {name}")
    assert np.array_equal(a.results.paths[TRUE_STATE], b.results.paths[TRUE_STATE])
    # every verdict, measured value and margin is the same: a plug-in's claims share a family-wise confidence of
    # their own, so the built-ins' Bonferroni share does not move
    (verdicts_a, margins_a, k_a), (verdicts_b, margins_b, k_b) = builtin_claims(repro_a, a), builtin_claims(repro_b, b)
    assert verdicts_a == verdicts_b and margins_a == margins_b and k_a == k_b


# -- generated scenarios ---------------------------------------------------------------------------------------------

def _generated():
    fam = registry.family("compare")
    return ([pytest.param(seed, edge, id=edge) for seed, edge in enumerate(fam.edges)]
            + [pytest.param(2000 + s, None, id=f"random{s}") for s in range(2)])


@pytest.mark.parametrize("seed,edge", _generated())
def test_generated_scenarios_with_twins_have_no_error_and_the_twins_never_fail(seed, edge):
    data = copy.deepcopy(registry.family("compare").generate(seed, edge))
    data.setdefault("estimators", {}).update({"twin": {"factory": f"{TWINS}:LocalTwin"},
                                              "dtwin": {"factory": f"{TWINS}:DiffusionTwin"}})
    repro = registry.from_dict(data)
    comp = repro.compute(RunOptions(seed=seed, quick=True, workers=1), StageContext(MemoryCache()))
    ev = evaluate_claims(repro, comp)
    assert not comp.results.faults
    bad = [f"{c['id']}: {c['verdict']}: {str(c.get('detail'))[:300]}" for c in ev.claims
           if c["verdict"] == "error" or (".plugin." in c["id"] and c["verdict"] == "fail")]
    bad += [f"hypothesis {h['id']}: {h['error'][:300]}" for h in ev.hypotheses if h["error"]]
    assert not bad, "\n".join(bad)
    assert any(c["id"] == "compare.plugin.twin.lower_bound" for c in ev.claims)


def test_the_overhead_benchmark_runs():
    """`make bench`'s `plugin` rows (a) and (b) exist and are positive (no timing is asserted)."""
    from benchmarks.bench_plugin import bench_protocol

    dispatch, messages = bench_protocol(steps=5, trials=100, repeats=1)
    for row in (dispatch, messages):
        assert np.isfinite(row["ratio"]) and row["ratio"] > 0 and row["plugin_ms_per_step"] > 0
    assert isinstance(dispatch["met"], bool) and messages["met"] == ""


def test_a_plugin_may_be_named_x():
    """The true state's sample paths used to be kept under "x": a plug-in named x overwrote them (and, on two
    workers, the run failed with a KeyError)."""
    _, comp = compute(scenario("reliable", plugins={"x": "LocalTwin"}, include=["local"]), BIT_TRIALS, workers=2)
    res = comp.results
    assert not res.faults
    assert np.array_equal(res.mc["x"]["sq"], res.mc["local"]["sq"])
    assert np.array_equal(res.paths["x"], res.paths["local"]) and TRUE_STATE in res.paths
