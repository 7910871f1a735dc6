"""Held-out check: does the model fitted without part of the session predict that part?

A model that absorbed an effect it lacks (a scale factor that took up a bias following the
rate sign, a warm-up and a drift that took up a late quadratic drift) can fit the samples
it saw with nothing left that a probe recognises, under a noise model that was itself
fitted to those samples. Before such a model is called adequate it must predict data it
did not see. Per sensor kind the session's steps are cut into :data:`HOLDOUT_FOLDS`
contiguous folds of whole steps (about equal sample counts); for each fold and sensor:

1. the sensor's model (the calibration's columns ``[1, x]`` plus the effect terms fitted,
   the same columns the selection's model holds) is fitted by generalised least squares
   on the block means (≈ 1 s, :func:`.coloured.block_noise`) of the *other* folds, under
   the noise the tests took as the null: white, or white + Gauss-Markov at the set's
   fitted ``(ρ, τ)`` (:mod:`.coloured`)::

       cov(ȳ) = V = σ_w²·(diag(1/n_b) + ρ·K(τ))

   ``σ_w²`` the within-block variance of the sensor's residual (the white part alone;
   it does not contain the block-to-block structure under test);
2. the held-out block means are predicted by the best linear unbiased predictor
   (universal kriging: the fitted columns plus, under Gauss-Markov noise, the part of
   the wander the training residual predicts, ``V_TR·V_RR⁻¹·(ȳ_R − X̄_R·β̂)``), with the
   prediction-error covariance ``V_TT − V_TR·V_RR⁻¹·V_RT + F·(X̄_Rᵀ·V_RR⁻¹·X̄_R)⁻¹·Fᵀ``,
   ``F = X̄_T − V_TR·V_RR⁻¹·X̄_R`` (every term of the stated σ: noise, wander and the
   parameters' uncertainty);
3. the prediction errors are averaged per held-out step (``m``, one value per step) and
   tested against that covariance: ``χ² = mᵀ·C_m⁻¹·m`` with the held-out steps as degrees
   of freedom (exact under the model's Gaussian noise, ``σ_w²`` estimated from about N
   within-block degrees of freedom).

The family is every (kind, sensor, fold) tested, at the verdict's own α with Bonferroni:
a session whose model is complete fails the held-out check with probability at most α
(so a verdict that combines the adequacy tests, also at α, and this check errs on a
complete model with probability at most 2α). A fold whose held-out steps need a column
the other folds do not determine (a bias step inside the last fold, a mounting seen in
one fold only) is not tested for that sensor and is listed.

A failing fold makes the verdict "effects suspected" (:func:`calibration.diagnose.run.
with_holdout`), whatever the other tests said. The check reads what the noise model was
fitted to as well as the data it predicts, so a Gauss-Markov term inflated by an effect
still weakens it (``docs/diagnose.md``, "Held-out check").
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from typing import Any

import numpy as np
import scipy.linalg
import scipy.stats

from calibration.diagnose.coloured import GlsModel, block_corr, block_noise
from calibration.diagnose.context import KindData
from calibration.diagnose.linmodel import LinModel

__all__ = ["HOLDOUT_FOLDS", "HOLDOUT_SCHEMA", "folds", "holdout", "holdout_record"]

HOLDOUT_FOLDS = 4
"""Contiguous folds of whole steps. Four: each fold is a quarter of the session, so the
first and last folds test the model's extrapolation in time (what a slow term absorbed
shows there), the two inner ones its interpolation, and each training part keeps three
quarters of the steps (enough to determine bias and gain vector on the presets'
sequences)."""
HOLDOUT_SCHEMA = "rimu.holdout/1"
_RANK_TOL = 1e-9


def folds(d: KindData, k: int = HOLDOUT_FOLDS) -> list[tuple[int, ...]]:
    """The steps of each fold: ``k`` contiguous groups of whole steps in session order,
    the cuts placed where the cumulative sample count is nearest to ``j/k`` of the total
    (fewer folds when the session has fewer steps)."""
    steps = list(d.steps)
    if len(steps) < 2:
        return [tuple(steps)]
    k = min(k, len(steps))
    counts = np.array([np.count_nonzero(d.step == s) for s in steps], float)
    cum = np.cumsum(counts) / counts.sum()
    cuts = sorted({int(np.argmin(np.abs(cum - j / k))) + 1 for j in range(1, k)})
    cuts = [c for c in cuts if 0 < c < len(steps)]
    edges = [0, *cuts, len(steps)]
    return [tuple(steps[a:b]) for a, b in itertools.pairwise(edges) if b > a]


def _noise_of(model: LinModel | GlsModel) -> tuple[float, float]:
    """``(ρ, τ)`` of the model's null noise (ρ = 0: white), fitted on the *other*
    sensors of the set (module docstring); a set of one: its own fit."""
    if not isinstance(model, GlsModel):
        return 0.0, 1.0
    g = model.group
    if not any(j != model.sensor for j in g.grids):
        return g.fitted()
    tot = g.others(model.sensor)
    t, r = np.unravel_index(int(np.argmin(tot)), tot.shape)
    return float(g.noise.rho[r]), float(g.noise.taus[t])


def _block_layout(d: KindData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block starts, counts and step of each block (its first sample's)."""
    nz = block_noise(d.N, d.sample_rate_hz)
    return nz.starts, nz.counts, d.step[nz.starts]


def _within_var(e: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> float:
    """Within-block variance of ``e`` (the white part of the noise)."""
    means = np.add.reduceat(e, starts) / counts
    dev = e - np.repeat(means, counts.astype(int))
    return float(dev @ dev) / max(e.size - starts.size, 1)


def _fold_test(ybar: np.ndarray, Xbar: np.ndarray, V: np.ndarray, train: np.ndarray,
               test: np.ndarray, A: np.ndarray) -> tuple[float, int] | None:
    """χ² and dof of the held-out step means (module docstring), None when the training
    blocks do not determine what the held-out ones need."""
    R, T = np.flatnonzero(train), np.flatnonzero(test)
    XR, XT = Xbar[R], Xbar[T]
    sc = np.linalg.norm(Xbar, axis=0)
    sc[sc == 0] = 1.0
    rank_all = np.linalg.matrix_rank(Xbar / sc, tol=_RANK_TOL * np.sqrt(Xbar.shape[0]))
    if np.linalg.matrix_rank(XR / sc, tol=_RANK_TOL * np.sqrt(R.size)) < rank_all:
        return None
    cho = scipy.linalg.cho_factor(V[np.ix_(R, R)], lower=True)
    VTR = V[np.ix_(T, R)]
    WX = scipy.linalg.cho_solve(cho, XR)                        # V_RR⁻¹·X_R
    Wy = scipy.linalg.cho_solve(cho, ybar[R])
    G = XR.T @ WX
    Gi = np.linalg.pinv(G)
    beta = Gi @ (XR.T @ Wy)
    resid = ybar[R] - XR @ beta
    pred = XT @ beta + VTR @ scipy.linalg.cho_solve(cho, resid)
    err = ybar[T] - pred
    F = XT - VTR @ WX
    cov = V[np.ix_(T, T)] - VTR @ scipy.linalg.cho_solve(cho, VTR.T) + F @ Gi @ F.T
    m = A @ err
    Cm = A @ cov @ A.T
    Cm = 0.5 * (Cm + Cm.T)
    try:
        chi2 = float(m @ np.linalg.solve(Cm, m))
    except np.linalg.LinAlgError:
        return None
    return chi2, int(A.shape[0])


def holdout(datas: Mapping[str, KindData], models: Mapping[tuple[str, int], Any],
            alpha: float) -> dict[str, Any]:
    """The held-out check of every sensor's model (module docstring).

    Parameters
    ----------
    datas : mapping of kind to KindData
    models : mapping of (kind, 0-based sensor) to LinModel or GlsModel
        Each sensor's final model (:attr:`.selection.Selection.models`: the calibration's
        columns and the effect terms accepted or fitted), its noise the null's.
    alpha : float
        Family-wise level (Bonferroni over the (kind, sensor, fold) tested).

    Returns
    -------
    dict
        :func:`holdout_record`'s layout: ``{"schema", "passed", "alpha", "threshold",
        "folds", "failed", "not_tested", "worst"}``; each fold record
        ``{"kind", "sensor" (1-based), "sensor_name", "fold" (1-based), "steps",
        "chi2", "dof", "p_value", "noise"}``.
    """
    recs: list[dict[str, Any]] = []
    not_tested: list[dict[str, Any]] = []
    for kind, d in datas.items():
        fl = folds(d)
        if len(fl) < 2:
            not_tested.append({"kind": kind, "reason": "the session has one step"})
            continue
        starts, counts, bstep = _block_layout(d)
        t0 = starts / d.sample_rate_hz
        L = counts / d.sample_rate_hz
        K_cache: dict[float, np.ndarray] = {}
        for i in range(d.n):
            model = models.get((kind, i))
            if model is None:
                continue
            rho, tau = _noise_of(model)
            e = np.asarray(model.e, float)
            sw2 = _within_var(e, starts, counts)
            if not sw2 > 0:
                not_tested.append({"kind": kind, "sensor": i + 1,
                                   "reason": "no within-block noise"})
                continue
            V = np.diag(1.0 / counts)
            if rho > 0:
                if tau not in K_cache:
                    K_cache[tau] = block_corr(t0, L, tau)
                V = V + rho * K_cache[tau]
            V = sw2 * V
            ybar = np.add.reduceat(np.asarray(model.y, float), starts) / counts
            Xbar = np.add.reduceat(np.asarray(model.Q, float), starts, axis=0) \
                / counts[:, None]
            for j, fs in enumerate(fl):
                test = np.isin(bstep, fs)
                if not test.any() or test.all():
                    continue
                Tb = np.flatnonzero(test)
                A = np.zeros((len(fs), Tb.size))
                for r, s in enumerate(fs):
                    w = counts[Tb] * (bstep[Tb] == s)
                    if w.sum() > 0:
                        A[r] = w / w.sum()
                A = A[A.sum(axis=1) > 0]
                res = _fold_test(ybar, Xbar, V, ~test, test, A)
                if res is None:
                    not_tested.append({"kind": kind, "sensor": i + 1, "fold": j + 1,
                                       "steps": list(fs),
                                       "reason": "the other folds do not determine the "
                                                 "model's columns on these steps"})
                    continue
                chi2, dof = res
                recs.append({"kind": kind, "sensor": i + 1, "sensor_name": d.names[i],
                             "fold": j + 1, "steps": [int(s) for s in fs],
                             "chi2": chi2, "dof": dof,
                             "p_value": float(scipy.stats.chi2.sf(chi2, dof)),
                             "log10_p_value": float(scipy.stats.chi2.logsf(chi2, dof)
                                                    / np.log(10)),
                             "noise": "white + Gauss-Markov" if rho > 0 else "white"})
    return holdout_record(recs, not_tested, alpha)


def holdout_record(recs: list[dict[str, Any]], not_tested: list[dict[str, Any]],
                   alpha: float) -> dict[str, Any]:
    """The record of a held-out check: passed when no fold's p is below α / (folds
    tested)."""
    thr = alpha / max(len(recs), 1)
    failed = [r for r in recs if r["p_value"] < thr]
    worst = min(recs, key=lambda r: r["log10_p_value"]) if recs else None
    return {"schema": HOLDOUT_SCHEMA, "passed": not failed, "alpha": alpha,
            "threshold": thr, "folds": recs, "failed": failed, "not_tested": not_tested,
            "worst": worst}
