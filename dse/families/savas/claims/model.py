"""Claims on the model (§II, §III-B) and the algebra of the proof of Theorem 1: Q and Q†, the
pathwise closed forms (17), (19), (20) and the unrolled covariance (23)."""
from __future__ import annotations

import numpy as np

import dse.estimators.consensus_covariance as cc
from dse.verify.rules import FAIL, PASS, Verdict, within

from .. import reference_values as ref
from ..design import filter_kwargs
from ..results import Results
from .common import DS, P, SUM_TOL, claims, input_deviation, stochastic_defects, table_rounds, tol


@claims.claim("savas.model.Q", "§II, §III-B", "Q is row stochastic with a simple unit eigenvalue and all others inside "
              "the unit disk", "identity")
def check_Q(res: Results) -> Verdict:
    """§II: Q is row stochastic with a simple unit eigenvalue, eigenvector 1/√N·1, others inside the disk."""
    Q = res.scenario.Q
    dev, neg = input_deviation(res), float(max(-Q.min(), 0.0))
    second = float(np.sort(np.abs(np.linalg.eigvals(Q)))[-2]) if len(Q) > 1 else 0.0
    ok = dev <= SUM_TOL and neg <= SUM_TOL and second < 1.0
    return Verdict(PASS if ok else FAIL, measured=second, reference=1.0, margin=1.0 - second, tolerance=SUM_TOL,
                   detail=(f"row/column sums off by {dev:.2e} (allowed {SUM_TOL:g}, the family's validation tolerance); "
                           f"min entry {Q.min():.3g}; second largest |λ| = {second:.6f} < 1"))


@claims.claim("savas.model.Q_example", "§III-B", "the example's Q = I − 0.4L on the 3-node line has eigenvalues "
              "{1, 0.6, −0.2}", "identity", scope=P)
def check_Q_example(res: Results) -> Verdict:
    lam = np.sort(np.linalg.eigvalsh(res.scenario.Q))
    return within(lam, ref.EIG_Q, tol(scale=1.0, operations=len(lam) ** 2),
                  detail="eigenvalues of Q = I − 0.4 L on the 3-node line")


@claims.claim("savas.model.Qdag", "§IV, proof of Thm 1", "Q† is row stochastic: Q†1 = 1 and ρ(Q†) = 1", "identity",
              hypotheses=(DS,))
def check_Qdag(res: Results) -> Verdict:
    """Q†1 = 1 and ρ(Q†) = 1 (proof of Thm 1), as 1 <= ρ(Q†) <= ‖Q†‖_∞ = 1 for nonnegative Q†, Q†1 = 1."""
    Q, n, delta = res.scenario.Q, res.scenario.n, input_deviation(res)
    vals, tols = [], []
    ms = table_rounds(res)
    for m in ms:
        t = tol(scale=1.0, operations=(m + 1) * (n + 1)) + (m + 1) * delta
        for zeta in np.linspace(0, 1, 11):
            vals.append(stochastic_defects(cc.reinjection_matrix(Q, m, zeta)))
            tols.append(np.full(3, t))
    return within(np.concatenate(vals), 0.0, np.concatenate(tols),
                  detail=(f"Q†1 = 1, ‖Q†‖_∞ = 1 and Q† >= 0 (so ρ(Q†) = 1) on {len(vals)} (m, ζ) pairs, m in "
                          f"{ms[0]}..{ms[-1]}; allowance (m+1)(N+1) operations plus (m+1)·δ, δ = {delta:.2e} the input's "
                          "deviation from double stochasticity"))


def _has_paths(res: Results) -> bool:
    return any("path_x" in res.mc[c.label] for c in res.cells)


def _path_errors(res: Results, cell, a) -> tuple[list, list]:
    """The three identities of one cell's sample paths: (17), then (19) or (9) unrolled, then (20)."""
    sc, delta = res.scenario, input_deviation(res)
    x, xp, xf, z, u, w, nz = (a[f"path_{k}"] for k in ("x", "xhat_pred", "xhat_filt", "z_rounds", "u", "w", "n"))
    ep, ef = x[..., None] - xp, x[..., None] - xf
    size = max(np.abs(x).max(), np.abs(xp).max(), np.abs(xf).max(), np.abs(nz).max(), 1e-300)
    errs = [np.abs(ef - ((1 - cell.ell) * ep - cell.ell * nz)).max()]  # (17)
    tols = [tol(scale=size, operations=6)]
    if cell.m == 0:
        return errs, tols
    powers = [np.linalg.matrix_power(sc.Q, i) for i in range(cell.m + 1)]
    noise = sum(np.einsum("ij,pkj->pki", powers[cell.m - h], u[:, :, h - 1]) for h in range(1, cell.m + 1))
    if cell.alg == "reinjection":
        closed = sum(np.einsum("ij,pkj->pki", Pw, xf) for Pw in powers) + cell.sigma_c * noise   # (19)
        beta = (1 - cell.zeta) / (cell.m + 1)
        Qd = cc.reinjection_matrix(sc.Q, cell.m, cell.zeta)
        nxt = np.einsum("ij,pkj->pki", Qd, ef) + w[..., None] - beta * cell.sigma_c * noise  # (20) with w(k)
    else:
        closed = np.einsum("ij,pkj->pki", powers[cell.m], xf) + cell.sigma_c * noise       # (9) unrolled
        nxt = np.einsum("ij,pkj->pki", powers[cell.m], ef) + w[..., None] - cell.sigma_c * noise
    ops = (cell.m + 1) * (sc.n + 2) * 2
    scale = (cell.m + 1) * max(size, cell.sigma_c * np.abs(u).max(), np.abs(w).max())
    errs += [np.abs(z[:, :, cell.m] - closed).max(), np.abs(ep[:, 1:] - nxt[:, :-1]).max()]
    tols += [tol(scale=scale, operations=ops), tol(scale=scale, operations=ops) + (cell.m + 1) * delta * np.abs(x).max()]
    return errs, tols


@claims.claim("savas.proof.pathwise", "eqs. (17), (19), (20)", "the error and consensus closed forms hold pathwise",
              "identity", hypotheses=(DS,),
              requires=[(_has_paths, "no sample paths were stored (monte_carlo.sample_paths = 0)")])
def check_pathwise(res: Results) -> Verdict:
    """(17), (19), (20) and the plain-consensus closed form on the stored sample paths."""
    errs, tols = [], []
    for cell in res.cells:
        if "path_x" in res.mc[cell.label]:
            e, t = _path_errors(res, cell, res.mc[cell.label])
            errs += e
            tols += t
    return within(errs, 0.0, tols, detail=(f"{len(errs)} path identities; (20) holds with w(k), not the printed w(k+1); "
                                           "allowances: (m+1)(N+2) operations on inputs of the paths' size"))


@claims.claim("savas.proof.eq23", "eq. (23)", "the unrolled finite-k covariance equals the iterated recursion (22)",
              "identity")
def check_unrolled(res: Results) -> Verdict:
    """(23) against the iterated (22) for k < 20 in every cell (pure algebra: no hypothesis); and the closed
    form at any step that the exact laws of the Monte Carlo checks use (modes, or jumps by squaring),
    against the same iterated (22) at the recorded steps below 20."""
    sc = res.scenario
    a, b, t = [], [], []
    steps = 20
    entries = 0
    for cell in res.cells:
        kw = {**filter_kwargs(sc, cell), "n_steps": steps}
        seq = cc.predictive_covariance_sequence(sc.Q, **kw)
        allowance = tol(scale=float(np.abs(seq).max()), operations=steps * (3 * sc.n + 4))
        ex = res.design.exact(cell)
        early = ex.steps < steps
        pairs = ((seq, cc.predictive_covariance_unrolled(sc.Q, **kw)),
                 (np.diagonal(seq[ex.steps[early]], axis1=1, axis2=2), ex.diag[early]))
        for x, y in pairs:   # the worst entry of each comparison (one allowance per cell): memory O(N²) per cell
            if x.size:
                w = np.unravel_index(int(np.argmax(np.abs(x - y))), x.shape)
                a.append(x[w]), b.append(y[w]), t.append(allowance)
                entries += x.size
    return within(a, b, t,
                  detail=(f"(23) vs (22) for k < {steps}, and the per-agent variances at the recorded steps (modal or "
                          f"squaring closed form, used by the exact laws) vs (22), every cell ({entries} entries; the worst "
                          "of each comparison is listed); allowance 20·(3N+4) operations on the entries' scale"))
