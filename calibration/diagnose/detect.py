"""Detectability: could this session have seen an effect that moves a parameter by 5 σ?

"Adequate" must mean more than "the tests found nothing": it means *this session could
have seen any library effect large enough to move a calibration parameter by*
:data:`SHIFT_SIGMA` *σ, and saw none*. Under coloured noise (a Gauss-Markov bias
instability) a slow effect near the wander's size is barely identifiable from one
session, so the tests can pass with a parameter far off. This module computes, for every
testable (candidate, sensor) pair and the candidate's nuisance grid (change-point times,
line frequencies, mountings), under the session's fitted null noise:

- the **shift** of the calibration parameters per unit of the effect: the least-squares
  projection of the regressor ``z`` onto the calibration model ``[1, x]`` of the sensor
  (the calibration's estimates are least squares; the same projection
  :mod:`calibration.diagnose.refit` solves jointly)::

      [Δb, Δg] = ([1, x]ᵀ[1, x])⁻¹ [1, x]ᵀ z        (Δg: change of the gain vector h̃)
      Δbias = Δb,  ΔSF = −SF·(h̃·Δg),  Δθ_misalignment = E·Δg    (E ⟂ h̃, fdi.calfile)

  each divided by the σ the calibration reports for it;
- the **size** ``a5`` that moves some parameter by 5 σ, in the direction of the effect's
  coefficients that is hardest to detect (for an effect of p columns with Fisher matrix
  ``F`` and shift row ``s_j`` of parameter j: ``λ_j = 25/(s_j·F⁻¹·s_jᵀ)`` at
  ``β = 5·F⁻¹s_jᵀ/(s_j·F⁻¹·s_jᵀ)``; the smallest ``λ_j`` over the parameters);
- the **power** of the actual test at ``a5``: the test's first Holm threshold ``(α/2)/m``
  (m the candidates × sensors tested) divided by the scan multiplicity, on χ²_r; the
  noncentrality is

  - white noise: ``λ = a5²·‖(I − P)z‖²/σ_w²`` (the F-test's, exact);
  - white + Gauss-Markov noise (:mod:`.coloured`): the likelihood-ratio statistic the
    profiled test would give on the session *with the effect added and its cross-term
    with the noise at its expectation, zero* (an "Asimov" data set): the session's
    restricted residual grid under ``[X, z]`` plus ``a5²·⟨z⊥, z⊥⟩_V`` on every (τ, ρ) of
    the grid, minimised over (τ, ρ) as the test does. This charges the test for what the
    re-fitted Gauss-Markov term absorbs of a slow effect (a warm-up near the wander's size
    is read partly as a wander with a long τ), which the known-noise noncentrality
    ``a5²·⟨z⊥, z⊥⟩_V/σ_w²`` at the fitted (ρ, τ) does not.

A pair whose power is below :data:`POWER` is a *limit* of the session: the verdict cannot
be "adequate" (``"effects not ruled out"``, :func:`calibration.diagnose.adequacy.decide`).
Each limit names the effect, the sensor, the size that could hide (``a5``, in the effect's
unit), the parameter it would move by 5 σ, the power there, and the size from which the
test finds it with probability :data:`POWER`.

The reference of a bias step: a step changes the bias the calibration should report; the
shift is counted against the bias that holds over the longer part of the session (a step
near an end moves the calibration little from it). Other effects keep the reference of
their regressor (a warm-up against the settled bias, a drift against the bias at the
start).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import scipy.stats

from calibration.diagnose.coloured import DetectGrids, GlsModel, grid_min
from calibration.diagnose.context import KindData
from calibration.diagnose.library import (
    LINE_MIN_CYCLES,
    Candidate,
    candidates,
    line_search,
    mount_search,
    step_grid,
    step_range,
    step_search,
    testable,
)
from calibration.diagnose.linmodel import LinModel
from fdi.calfile import Calibration, tangent_basis

__all__ = ["LINE_CYCLES", "PARAMETERS", "POWER", "PROFILE_MARGIN", "SHIFT_SIGMA", "STEP_TIMES",
           "asimov_lr", "limits", "nuisance_grid", "parameter_shift", "power_at",
           "size_for_power"]

POWER = 0.99
"""Power the test must have against an effect that moves a parameter by SHIFT_SIGMA σ for
the session to rule it out."""
SHIFT_SIGMA = 5.0
"""Parameter shift (in the calibration's σ) an adequate session must be able to see."""
STEP_TIMES = 15
"""Change-point times tried for the detectability of a bias step (equally spaced within
the scanned range)."""
LINE_CYCLES = (4, 6, 8, 12, 16, 24, 32, 48, 64)
"""Line frequencies tried (cycles per session; higher ones average out of the parameters
over a step)."""
PROFILE_MARGIN = 8.0
"""Under white + Gauss-Markov noise the full profiled computation is skipped for a point
whose known-noise noncentrality is so large that even this fraction of it gives POWER
(re-fitting the noise cost at most a factor 3.8 in the measured sessions)."""
PARAMETERS = ("bias", "scale_factor", "misalignment_1", "misalignment_2")


def parameter_shift(d: KindData, i: int, Z: np.ndarray, cal: Calibration,
                    proj: np.ndarray | None = None) -> np.ndarray:
    """Shift of sensor ``i``'s calibration parameters per unit of each column of ``Z``,
    in units of the calibration's σ (module docstring).

    ``proj``: :func:`_shift_projector` of ``d`` (computed when not given).

    Returns
    -------
    ndarray, shape (4, p)
        Rows :data:`PARAMETERS`; a row whose σ is not positive and finite is 0.
    """
    D = (_shift_projector(d) if proj is None else proj) @ Z
    c = cal.sets[d.kind].sensors[i]
    h = np.asarray(c.axis, float) / np.linalg.norm(c.axis)
    E = tangent_basis(c.axis_nominal)
    rows = np.vstack([D[0], -c.scale_factor * (h @ D[1:]), E @ D[1:]])
    sd = np.r_[c.bias_sd, c.scale_factor_sd, np.asarray(c.misalignment_sd, float)]
    ok = np.isfinite(sd) & (sd > 0)
    out = np.zeros_like(rows)
    out[ok] = rows[ok] / sd[ok, None]
    return out


def _step_points(d: KindData) -> tuple[list[dict[str, Any]], int]:
    """Bias-step times checked (:data:`STEP_TIMES`, equally spaced in the scanned range)
    and the scan's multiplicity (:func:`.library.step_grid`, as the test counts it)."""
    lo, hi = step_range(d.N)
    idx = np.linspace(lo, hi, STEP_TIMES + 2).astype(int)[1:-1]
    return [{"time_s": float(d.t[k])} for k in idx], int(step_grid(d).size)


def _line_points(d: KindData) -> tuple[list[dict[str, Any]], int]:
    """Line frequencies checked (:data:`LINE_CYCLES` below Nyquist) and the Fourier
    frequencies :func:`.library.line_search` scans."""
    spec_bins = d.N // 2 + 1
    mult = max(spec_bins - 1 - int(np.ceil(LINE_MIN_CYCLES)), 1)
    T = d.duration_s
    return [{"frequency_hz": k / T} for k in LINE_CYCLES if k / T < d.sample_rate_hz / 2], mult


def _mount_points(d: KindData) -> tuple[list[dict[str, Any]], int]:
    """Every mounting after the first (:func:`.library.mount_search` tries each)."""
    n = int(d.mount.max())
    return [{"mount": m} for m in range(1, n + 1)], max(n, 1)


_SEARCH_POINTS = {step_search: _step_points, line_search: _line_points,
                  mount_search: _mount_points}
"""The parameter values checked for each library search (any candidate that uses it),
with the search's multiplicity."""


def nuisance_grid(c: Candidate, d: KindData, i: int,
                  model: LinModel | GlsModel) -> tuple[list[dict[str, Any]], int]:
    """The parameter values of ``c`` to check and the test's scan multiplicity: a grid
    for a library search (:data:`_SEARCH_POINTS`), a user search's own best point, or the
    candidate's fixed parameters."""
    if c.search in _SEARCH_POINTS:
        return _SEARCH_POINTS[c.search](d)
    if c.search is not None:                        # a user search: its own best point
        params, mult = c.search(d, i, model.Q, model.e)
        return [params], int(mult)
    return [c.fixed_params(d, i) if c.fixed_params else {}], 1


def _reference(c: Candidate, d: KindData, Z: np.ndarray, params: Mapping[str, Any]
               ) -> np.ndarray:
    """``Z`` shifted to its reference for the parameter shift (module docstring)."""
    if c.search is step_search and "time_s" in params:
        after = float(np.mean(d.t >= float(params["time_s"])))
        if after > 0.5:                             # the later bias holds longer
            return Z - Z[-1:]
    return Z


def power_at(lam: float, crit: float, r: int) -> float:
    """P(χ²_r(λ) > crit).

    scipy's noncentral χ² returns NaN for a noncentrality beyond about 1e15 (a regressor
    that barely touches a parameter needs an absurd size to move it by 5 σ and is then
    trivially detectable); there the normal approximation of χ²_r(λ) (mean r + λ,
    variance 2(r + 2λ)) is used, which is exact to far below the printed digits."""
    lam = max(float(lam), 1e-12)
    p = float(scipy.stats.ncx2.sf(crit, r, lam))
    if np.isfinite(p):
        return p
    if not np.isfinite(lam):
        return 1.0
    return float(scipy.stats.norm.sf((crit - r - lam) / np.sqrt(2.0 * (r + 2.0 * lam))))


def _worst_direction(S: np.ndarray, F: np.ndarray) -> tuple[float, np.ndarray, int]:
    """Over the parameters j (rows of S, in σ per unit coefficient): the smallest
    known-noise noncentrality of a shift of SHIFT_SIGMA σ in j, its coefficients β and j."""
    Fi = np.linalg.pinv(F)
    best = (np.inf, np.zeros(F.shape[0]), -1)
    for j in range(S.shape[0]):
        s = S[j]
        q = float(s @ Fi @ s)
        if not q > 0:
            continue
        lam = SHIFT_SIGMA**2 / q
        if lam < best[0]:
            best = (lam, SHIFT_SIGMA * (Fi @ s) / q, j)
    return best


def asimov_lr(g: DetectGrids, b: np.ndarray, a: float) -> float:
    """Profiled likelihood-ratio statistic on the Asimov session (module docstring) for
    the effect ``a·Z·b``."""
    s = np.einsum("i,...ij,j->...", b, g.gram, b)
    extra = a**2 * np.maximum(s, 0.0)
    return max(grid_min(g.v(extra), g.noise) - grid_min(g.v(), g.noise), 0.0)


def size_for_power(lam_of: Any, crit: float, r: int, a5: float) -> float:
    """The smallest multiple of ``a5`` at which the power reaches POWER (bisection on a
    monotone noncentrality)."""
    lo, hi = 1.0, 2.0
    while power_at(lam_of(hi), crit, r) < POWER and hi < 1e4:
        lo, hi = hi, hi * 2
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if power_at(lam_of(mid), crit, r) < POWER:
            lo = mid
        else:
            hi = mid
        if hi / lo < 1.01:
            break
    return hi * a5


def _shift_projector(d: KindData) -> np.ndarray:
    """``([1, x]ᵀ[1, x])⁻¹[1, x]ᵀ`` (4, N): the least-squares map of a regressor onto the
    calibration's bias and gain vector (the same for every sensor of a kind)."""
    X = np.column_stack([np.ones(d.N), d.x])
    sc = np.linalg.norm(X, axis=0)
    sc[sc == 0] = 1.0
    return np.linalg.pinv(X / sc) / sc[:, None]


def _pair(c: Candidate, d: KindData, i: int, model: LinModel | GlsModel,
          cal: Calibration, thr: float, proj: np.ndarray) -> list[dict[str, Any]]:
    """The least detectable point of (c, sensor i) of each class (``"session"``: hidden by
    this session's noise; ``"sequence"``: hidden even under white noise of the session's
    level, a limit of the sequence), if any point's power is below POWER."""
    grid, mult = nuisance_grid(c, d, i, model)
    worst: dict[str, dict[str, Any]] = {}
    gls = isinstance(model, GlsModel)
    sw2_white = model.rss / max(model.y.size - model.k, 1)
    for params in grid:
        Z = c.columns(d, i, params)
        S = parameter_shift(d, i, _reference(c, d, Z, params), cal, proj)
        if not np.any(S):
            continue
        Zp = model.project_out(Z)
        if gls:
            gram_k, sw2 = model.known_noise(Z)
        else:
            gram_k, sw2 = Zp.T @ Zp, sw2_white
        F = gram_k / sw2
        lam_k, beta, j = _worst_direction(S, F)
        if j < 0:
            continue
        rank = int(np.linalg.matrix_rank(F, tol=1e-9 * max(np.abs(F).max(), 1e-300)))
        if rank == 0:
            continue
        crit = float(scipy.stats.chi2.isf(thr / mult, rank))
        a5 = float(np.linalg.norm(beta))
        b = beta / a5
        lam_d = float(b @ (Zp.T @ Zp) @ b) * a5**2 / sw2      # white noise of level σ_w²
        pd = power_at(lam_d, crit, rank)
        if gls:
            if pd >= POWER and power_at(lam_k / PROFILE_MARGIN, crit, rank) >= POWER:
                continue
            g = model.detect_grids(Z)

            def lam_of(m: float, g: DetectGrids = g, b: np.ndarray = b,
                       a5: float = a5) -> float:
                return asimov_lr(g, b, m * a5)
        else:
            def lam_of(m: float, lam_k: float = lam_k) -> float:
                return m**2 * lam_k
        lam = lam_of(1.0)
        pw = power_at(lam, crit, rank)
        if pw >= POWER:
            continue
        cls = "session" if pd >= POWER else "sequence"
        if cls not in worst or pw < worst[cls]["power"]:
            worst[cls] = {"name": c.name, "kind": d.kind, "sensor": i + 1,
                          "sensor_name": d.names[i], "limit": cls, "size": a5,
                          "unit": c.unit_for(d.kind), "parameter": PARAMETERS[j],
                          "shift_sigma": SHIFT_SIGMA, "power": pw, "power_white": pd,
                          "noncentrality": lam, "noncentrality_known_noise": lam_k,
                          "params": dict(params), "_lam_of": lam_of, "_crit": crit,
                          "_rank": rank}
    out = []
    for rec in worst.values():
        size = size_for_power(rec.pop("_lam_of"), rec.pop("_crit"), rec.pop("_rank"),
                               rec["size"])
        rec["size_for_power"] = size
        rec["shift_sigma_for_power"] = SHIFT_SIGMA * size / rec["size"]
        out.append(rec)
    return out


def limits(datas: Mapping[str, KindData], models: Mapping[tuple[str, int], Any],
           cal: Calibration, alpha: float, family_size: int, *,
           cands: Iterable[Candidate] | None = None,
           skip: Iterable[tuple[str, int, str]] = ()) -> list[dict[str, Any]]:
    """Every (candidate, sensor) this session cannot rule out (module docstring).

    Parameters
    ----------
    datas : mapping of kind to KindData
    models : mapping of (kind, sensor) to LinModel or GlsModel
        Each sensor's current model (the selection's), its noise the null's.
    cal : Calibration
        Whose σ define "5 σ" (the calibration as it will be reported).
    alpha : float
        Family-wise level of the selection (its first Holm threshold is ``(α/2)/m``).
    family_size : int
        ``m``: the (candidate, sensor) pairs the selection tested.
    cands : candidates, optional
        Default: every registered candidate.
    skip : (kind, sensor, name) triples
        Pairs already fitted (0-based sensors).

    Returns
    -------
    list of dict
        ``{"name", "kind", "sensor" (1-based), "sensor_name", "limit", "size", "unit",
        "parameter", "shift_sigma", "power", "power_white", "noncentrality",
        "noncentrality_known_noise", "params", "size_for_power",
        "shift_sigma_for_power"}``, least detectable first. ``limit`` is
        ``"session"`` when white noise of the session's level would have found the effect
        (this session's noise hides it) and ``"sequence"`` when not even that would
        (the sequence cannot tell it from the calibration parameters at this size).
    """
    thr = (alpha / 2) / max(int(family_size), 1)
    skip = set(skip)
    cands = list(candidates() if cands is None else cands)
    out = []
    for kind, d in datas.items():
        proj = _shift_projector(d)
        for c in cands:
            if testable(c, d) is not None:
                continue
            for i in range(d.n):
                if (kind, i, c.name) in skip or (kind, i) not in models:
                    continue
                out += _pair(c, d, i, models[(kind, i)], cal, thr, proj)
    return sorted(out, key=lambda r: r["power"])
