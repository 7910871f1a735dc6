"""Held-out check: does the model fitted without part of the session predict that part?

A model that absorbed an effect it lacks (a scale factor that took up a bias following the
rate sign, a warm-up and a drift that took up a late quadratic drift) can fit the samples
it saw with nothing left that a probe recognises, under a noise model that was itself
fitted to those samples. Before such a model is called adequate it must predict data it
did not see. Per sensor kind the session's steps are cut into :data:`HOLDOUT_FOLDS`
contiguous folds of whole steps (about equal sample counts); for each fold and sensor:

1. the sensor's model (the calibration's columns ``[1, x]`` plus the effect terms fitted,
   the same columns the selection's model holds) is fitted by generalised least squares
   on the block means of the *other* folds (each step cut into :data:`HOLDOUT_PIECES`
   pieces), under the noise the tests took as the null::

       cov(ȳ) = V = σ_w²·(diag(1/n_b) + ρ·K(τ))      (ρ = 0: white noise)

   ``K(τ)`` the exact covariance of interval means of a unit Gauss-Markov process
   (:func:`.coloured.block_corr`), ``σ_w²`` the within-block variance of the sensor's
   residual (the white part alone; it does not contain the block-to-block structure
   under test);
2. the held-out block means are predicted by the best linear unbiased predictor
   (universal kriging: the fitted columns plus, under Gauss-Markov noise, the part of
   the wander the training residual predicts, ``V_TR·V_RR⁻¹·(ȳ_R − X̄_R·β̂)``), with the
   prediction-error covariance ``V_TT − V_TR·V_RR⁻¹·V_RT + F·(X̄_Rᵀ·V_RR⁻¹·X̄_R)⁻¹·Fᵀ``,
   ``F = X̄_T − V_TR·V_RR⁻¹·X̄_R`` (every term of the stated σ: noise, wander and the
   parameters' uncertainty);
3. the prediction errors are averaged per held-out step (``m``, one value per step) and
   tested against that covariance: ``χ² = mᵀ·C_m⁻¹·m`` with the held-out steps as degrees
   of freedom (exact under the model's Gaussian noise with known ``(ρ, τ)``; ``σ_w²``
   comes from about N within-block degrees of freedom).

The Gauss-Markov ``(ρ, τ)`` of the check are not the set's fit: an effect on one sensor
inflates that fit (the colour of a set can come from the effect itself), and the check
would then forgive what the wander was fitted to. They come from the *other* sensors of
the set (``(ρ, τ)`` are common to identical sensors, the null's own assumption; a set of
one uses its own fit), and the check takes the least significant result over the
correlation times inside the :data:`NOISE_INTERVAL` profile-likelihood interval of that
fit (ρ at its maximum-likelihood value for each τ): a short record hardly fixes τ, and a
single plug-in value made the test liberal (on 40 clean coloured tetrad-paper sessions,
fold p-values below 0.01: 2.5 % with the point estimate, 1.6 % over the interval, 0.9 %
with the true noise).

The family is every (kind, sensor, fold) tested, at the verdict's own α with Bonferroni:
a session whose model is complete fails the held-out check with probability at most α
(so a verdict that combines the adequacy tests, also at α, and this check errs on a
complete model with probability at most 2α). A fold whose held-out steps need a column
the other folds do not determine (a bias step inside the last fold, a mounting seen in
one fold only) is not tested for that sensor and is listed.

A failing fold makes the verdict "effects suspected" (:func:`calibration.diagnose.adequacy.
decide`), whatever the other tests said. What it cannot see: structure faster than a step
(it reads step means), an effect the model absorbs alike in every fold, and, in a
set of one or where every sensor carries the effect, a Gauss-Markov fit inflated by it
(``docs/diagnose.md``, "The held-out check").
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from typing import Any

import numpy as np
import scipy.linalg
import scipy.stats

from calibration.diagnose.coloured import MAX_BLOCKS, GlsModel, block_corr
from calibration.diagnose.context import KindData
from calibration.diagnose.linmodel import LinModel

__all__ = ["HOLDOUT_FOLDS", "HOLDOUT_PIECES", "HOLDOUT_SCHEMA", "NOISE_INTERVAL", "folds",
           "holdout", "holdout_record"]

HOLDOUT_FOLDS = 4
"""Contiguous folds of whole steps. Four: each fold is a quarter of the session, so the
first and last folds test the model's extrapolation in time (what a slow term absorbed
shows there), the two inner ones its interpolation, and each training part keeps three
quarters of the steps (enough to determine bias and gain vector on the presets'
sequences)."""
HOLDOUT_PIECES = 8
"""Each step is cut into this many contiguous pieces (the blocks of the check; a block
never straddles a step). The test reads step means, which the pieces give exactly; the
pieces keep the within-step shape of the regressors for the fit (a warm-up, a line) while
the matrices stay small (8 per step)."""
NOISE_INTERVAL = 0.90
"""Coverage of the profile-likelihood interval of the correlation time over which the
check takes the least significant result (the same 90 % interval ``rimu calibrate`` takes
its pessimistic coloured-noise σ from, docs/model.md)."""
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


def _pieces(d: KindData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block starts, counts and step of each block: every run of one step cut into
    :data:`HOLDOUT_PIECES` contiguous pieces (fewer when the session has so many steps
    that the blocks would exceed :data:`.coloured.MAX_BLOCKS`: the check's cost grows as
    the cube of the blocks)."""
    runs = np.r_[0, np.flatnonzero(np.diff(d.step)) + 1, d.N]
    per = int(np.clip(MAX_BLOCKS // max(runs.size - 1, 1), 1, HOLDOUT_PIECES))
    starts = []
    for a, b in itertools.pairwise(runs):
        p = int(min(per, b - a))
        starts.extend(np.linspace(a, b, p + 1).astype(int)[:-1])
    st = np.unique(np.asarray(starts, int))
    counts = np.diff(np.r_[st, d.N]).astype(float)
    return st, counts, d.step[st]


def _noise_points(model: LinModel | GlsModel) -> list[tuple[float, float]]:
    """The ``(ρ, τ)`` the check tries (module docstring): white noise → ``[(0, 1)]``; white
    + Gauss-Markov → per correlation time inside the :data:`NOISE_INTERVAL` profile
    likelihood interval of the *other* sensors of the set (its own fit for a set of
    one), the ρ that maximises the likelihood there."""
    if not isinstance(model, GlsModel):
        return [(0.0, 1.0)]
    g = model.group
    tot = g.others(model.sensor) if any(j != model.sensor for j in g.grids) \
        else g.others(-1)
    prof = tot.min(axis=1)
    lim = float(scipy.stats.chi2.ppf(NOISE_INTERVAL, 1))
    out = []
    for t in np.flatnonzero(prof - prof.min() <= lim):
        r = int(np.argmin(tot[t]))
        out.append((float(g.noise.rho[r]), float(g.noise.taus[t])))
    return out


def _within_var(e: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> float:
    """Within-block variance of ``e`` (the white part of the noise)."""
    means = np.add.reduceat(e, starts) / counts
    dev = e - np.repeat(means, counts.astype(int))
    return float(dev @ dev) / max(e.size - starts.size, 1)


class _Fold:
    """One fold under one noise ``V0 = diag(1/n_b) + ρ·K(τ)`` (σ_w² factored out):
    the Cholesky factor of the training part and what the prediction needs."""

    def __init__(self, V0: np.ndarray, train: np.ndarray, test: np.ndarray) -> None:
        self.R, self.T = np.flatnonzero(train), np.flatnonzero(test)
        self.cho = scipy.linalg.cho_factor(V0[np.ix_(self.R, self.R)], lower=True)
        self.VTR = V0[np.ix_(self.T, self.R)]
        self.Kc = V0[np.ix_(self.T, self.T)] - self.VTR @ scipy.linalg.cho_solve(
            self.cho, self.VTR.T)                         # conditional covariance

    def chi2(self, ybar: np.ndarray, Xbar: np.ndarray, sw2: float, A: np.ndarray
             ) -> float:
        """χ² of the held-out step means (module docstring)."""
        XR, XT = Xbar[self.R], Xbar[self.T]
        WX = scipy.linalg.cho_solve(self.cho, XR)            # V_RR⁻¹·X_R
        Gi = np.linalg.pinv(XR.T @ WX)
        beta = Gi @ (WX.T @ ybar[self.R])
        resid = ybar[self.R] - XR @ beta
        pred = XT @ beta + self.VTR @ scipy.linalg.cho_solve(self.cho, resid)
        F = XT - self.VTR @ WX
        m = A @ (ybar[self.T] - pred)
        Cm = sw2 * (A @ (self.Kc + F @ Gi @ F.T) @ A.T)
        Cm = 0.5 * (Cm + Cm.T)
        return float(m @ np.linalg.lstsq(Cm, m, rcond=None)[0])


def _determined(Xbar: np.ndarray, train: np.ndarray) -> bool:
    """True when the training blocks determine every column direction of ``Xbar``."""
    sc = np.linalg.norm(Xbar, axis=0)
    sc[sc == 0] = 1.0
    X = Xbar / sc
    tol = _RANK_TOL * np.sqrt(X.shape[0])
    return bool(np.linalg.matrix_rank(X[train], tol=tol) >= np.linalg.matrix_rank(X, tol=tol))


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
        "chi2", "dof", "p_value", "log10_p_value", "noise", "rho", "tau_s"}`` (``rho``,
        ``tau_s``: the noise of the least significant result, ρ = σ_b²/σ_w²).
    """
    recs: list[dict[str, Any]] = []
    not_tested: list[dict[str, Any]] = []
    for kind, d in datas.items():
        fl = folds(d)
        if len(fl) < 2:
            not_tested.append({"kind": kind, "reason": "the session has one step"})
            continue
        starts, counts, bstep = _pieces(d)
        t0, L = starts / d.sample_rate_hz, counts / d.sample_rate_hz
        tests = [np.isin(bstep, fs) for fs in fl]
        aggs = []
        for fs, test in zip(fl, tests, strict=True):
            Tb = np.flatnonzero(test)
            A = np.array([counts[Tb] * (bstep[Tb] == s) for s in fs])
            A = A[A.sum(axis=1) > 0]
            aggs.append(A / A.sum(axis=1, keepdims=True))
        cache: dict[tuple[float, float, int], _Fold] = {}
        for i in range(d.n):
            model = models.get((kind, i))
            if model is None:
                continue
            sw2 = _within_var(np.asarray(model.e, float), starts, counts)
            if not sw2 > 0:
                not_tested.append({"kind": kind, "sensor": i + 1,
                                   "reason": "no within-block noise"})
                continue
            ybar = np.add.reduceat(np.asarray(model.y, float), starts) / counts
            Xbar = np.add.reduceat(np.asarray(model.Q, float), starts, axis=0) \
                / counts[:, None]
            points = _noise_points(model)
            for j, (fs, test) in enumerate(zip(fl, tests, strict=True)):
                if not _determined(Xbar, ~test):
                    not_tested.append({"kind": kind, "sensor": i + 1, "fold": j + 1,
                                       "steps": list(fs),
                                       "reason": "the other folds do not determine the "
                                                 "model's columns on these steps"})
                    continue
                best = None
                for rho, tau in points:
                    key = (rho, tau, j)
                    if key not in cache:
                        V0 = np.diag(1.0 / counts)
                        if rho > 0:
                            V0 = V0 + rho * block_corr(t0, L, tau)
                        cache[key] = _Fold(V0, ~test, test)
                    c2 = cache[key].chi2(ybar, Xbar, sw2, aggs[j])
                    if best is None or c2 < best[0]:
                        best = (c2, rho, tau)
                chi2, rho, tau = best
                dof = int(aggs[j].shape[0])
                recs.append({"kind": kind, "sensor": i + 1, "sensor_name": d.names[i],
                             "fold": j + 1, "steps": [int(s) for s in fs],
                             "chi2": chi2, "dof": dof,
                             "p_value": float(scipy.stats.chi2.sf(chi2, dof)),
                             "log10_p_value": float(scipy.stats.chi2.logsf(chi2, dof)
                                                    / np.log(10)),
                             "noise": "white + Gauss-Markov" if rho > 0 else "white",
                             "rho": rho, "tau_s": tau if rho > 0 else None})
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
