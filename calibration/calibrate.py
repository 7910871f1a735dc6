"""Calibrate a redundant IMU from a turntable session (seed 000, seed 001).

``calibrate(session)`` runs, in order:

1. per-segment means of the raw outputs and of the exact body-frame inputs (table rate,
   Earth rate, specific force from :meth:`calibration.session.Session.inputs`);
2. the gyro rate test over the paired ±ω steps (:mod:`calibration.rate_test`,
   seed 000 Eqs. 16-19), with the Earth rate as modelled included in the inputs;
3. the gyro offsets, both ways (:mod:`calibration.bias`): the explicit model over every step
   and seed 000's average over whole outer-axis turns (Eq. 20); ``bias_method`` says which
   one goes into the file;
4. residuals ``SF·u − b − h̃·x`` per sample → per-sample noise covariance, per-step
   statistics, Allan deviation (:mod:`calibration.residuals`);
5. covariances: every estimate is linear in segment means, so
   ``cov(θ_i, θ_j) = Σ_ij·P·diag(1/N)·Pᵀ`` with ``Σ`` the per-sample raw noise covariance,
   then first-order propagation through the unit-norm split (seed 000 Eq. 19);
6. the Earth rate from the (wavelet-denoised) outer-axis modulation
   (:mod:`calibration.earth_rate`);
7. the accelerometer multi-position test over the position steps
   (:mod:`calibration.multiposition`, seed 001 Eqs. 5-10), when the session has
   accelerometers and at least 4 positions.

Coloured noise (``noise_model="auto"``, the default): the covariances above are exact for
white noise only. With a bias instability the step means are correlated over several steps
and the bias σ is several times too small (tetrad-paper, 1 °/h, τc 100 s: sd(error/σ) ≈ 3.5
for the biases, 1.2 for the scale factors). Per sensor set a white + first-order
Gauss-Markov model, the bias process common to the set, is fitted to the residual spectrum
(:func:`calibration.residuals.fit_gauss_markov`, Whittle likelihood); when the
likelihood-ratio test keeps it, its exact covariance over the segment means
``(σ_b/SF_i)²·P·K(τc)·Pᵀ`` is added to the white one for a, SF, h̃, angles, both biases, v_c
and ``input_error_cov`` (it only adds: never below the white covariance). The estimates do
not change. ``extra["noise_model"]`` records the fit and the sd factor over white noise per
sensor. Measured over 100 seeds (tetrad-paper, sd(z) per parameter): white noise: the
test keeps white in 87-90 of 100 sessions, spreads unchanged within the MC tolerance;
1 °/h, τc 100 s: biases 3.3-3.8 → 0.90-1.05, SF 1.10-1.25 → 0.92-1.04; τc 30 s: biases
2.2 → 1.0; 0.5 °/h: biases ≈ 2.0 → 1.05-1.42 (the test misses the process in about one
session in five); τc 300 s (half the record): biases 5.0 → 1.7 and random walk: 4.6 → 1.8
(a session of a few correlation times cannot tell how much of the slow noise is bias).
cone-paper accelerometers, 0.1 mg, τc 100 s (pooled over sensors): 2.6-3.5 → 1.09-1.15.
The Earth-rate fit still uses the white per-sample covariance.

Two further checks test whiteness against the data and add a line to ``extra["warnings"]``
(printed by ``rimu calibrate``) when it fails at the 0.1 % level: the scatter of the
rate-step differences about the fit (``extra["rate_test"]["chi2_dof"]``) and the scatter of
the per-step residual means (``extra["step_residual_chi2_dof"]``, exact expectation 1 under
white noise).

Keys of ``Calibration.extra`` written here::

    source                     session path
    method                     {"gyro", "bias", "denoise"}
    rate_test                  {"pairs": [[k, p], ...] (1-based), "R_rad_s": (P, 3),
                                "chi2_dof": (n,)}
    step_residual_chi2_dof     (n,)
    warnings                   [str, ...]
    noise_model                {"method": str, "gyro"/"accel": {"applied", "bias_instability"
                                (SI), "correlation_s", "likelihood_ratio", "sd_factor":
                                {"bias", "scale_factor", "misalignment": (n,)}}}
                               (sd_factor: sd with the model / white sd; misalignment: the
                               larger of the two angles' factors)
    gyro_bias                  {"unit", "model", "model_sd", and when there are whole outer
                                turns "turns", "turns_sd", "turns_steps", "turns_per_step",
                                "vertical_correction"}   (values in "unit")
    parity_calibrated_sd       (n-3, n) first-order sd of V_c (gyros)
    parity_accel_calibrated_sd (n-3, n) (accelerometers)
    residual_steps             {"unit": {...}, "gyro": [{"step", "label", "kind", "n",
                                "mean": [n], "rms": [n]}, ...], "accel": [...]}  (SI)
    earth_rate_fit             see :meth:`calibration.earth_rate.EarthRateFit.to_dict`
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.stats

from calibration.bias import is_outer_step, offset_operator, turn_windows
from calibration.earth_rate import EarthRateFit, fit_earth_rate
from calibration.multiposition import multiposition
from calibration.rate_test import group_misalignment_matrices, rate_test, split_gain
from calibration.residuals import (
    GM_LR_THRESHOLD,
    allan_table,
    fit_gauss_markov,
    gauss_markov_segment_corr,
    noise_covariance,
    residual_step_stats,
    segment_means,
)
from calibration.session import Session
from calibration.turntable import mat_nb
from fdi.calfile import Calibration, SensorCal, SensorSet
from fdi.errors import CalibrationError
from fdi.parity import parity_matrix
from fdi.units import EARTH_RATE, RAW_UNITS, input_unit_factor

__all__ = ["BIAS_METHODS", "MIN_STEP_SAMPLES", "calibrate", "display_units", "outer_axis_fit"]

BIAS_METHODS = ("model", "turns")
NOISE_MODELS = ("auto", "white")
MIN_STEP_SAMPLES = 10
"""Fewest samples a step used by an estimator may have."""

_ANALOG = {"mV", "V", "uA"}


def display_units(kind: str, raw_unit: str, biases: np.ndarray | None = None) -> tuple[str, str]:
    """(scale_factor_unit, bias_unit) files print for a sensor kind and raw unit.

    Analog outputs print raw per input as datasheets and seed 000 Table 2 do
    (``mV/(deg/s)``); digital ones input per raw as seed 001 Table 3 (``(deg/s)/LSB``).
    Gyro biases in °/h (°/s when one exceeds 1 °/s, MEMS raw offsets), accelerometer biases
    in mg (g when one exceeds 1 g). ``biases`` in SI.
    """
    raw = raw_unit if raw_unit in RAW_UNITS else "raw"
    inp = "deg/s" if kind == "gyro" else "g"
    sfu = f"{raw}/({inp})" if raw in _ANALOG else f"({inp})/{raw}"
    big = biases is not None and np.size(biases) and float(np.max(np.abs(biases))) > (
        input_unit_factor("deg/s") if kind == "gyro" else input_unit_factor("g"))
    if kind == "gyro":
        return sfu, "deg/s" if big else "deg/h"
    return sfu, "g" if big else "mg"


def _fail_steps(source: str, kind: str, steps: list[tuple[int, int]]) -> CalibrationError:
    k, n = steps[0]
    what = "no samples" if n == 0 else f"only {n} sample(s)"
    return CalibrationError(f"{source}, step {k}: {what} of the {kind} outputs; expected at "
                            f"least {MIN_STEP_SAMPLES} per step used by the calibration")


def _check_finite(source: str, kind: str, raw: np.ndarray, step: np.ndarray) -> None:
    bad = ~np.all(np.isfinite(raw), axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        col = int(np.flatnonzero(~np.isfinite(raw[i]))[0])
        raise CalibrationError(f"{source}, step {int(step[i])}: non-finite {kind} sample "
                               f"(sensor {col + 1}, sample {i + 1}); expected finite numbers")


def _check_gains(source: str, kind: str, a: np.ndarray, names: tuple[str, ...]) -> None:
    """Refuse gains a = h̃/SF that cannot be split (zero or non-finite |a|).

    A sensor that does not respond to the known input (stuck, or swamped by a corrupt
    sample such as 1e300) gives |a| ≈ 0 or inf: no scale factor exists.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        na = np.linalg.norm(a, axis=1)
    bad = ~np.isfinite(na) | (na <= 0) | ~np.all(np.isfinite(a), axis=1)
    big = np.isfinite(na) & (na > 0)
    if big.any():
        bad |= na < 1e-9 * np.median(na[big])
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise CalibrationError(
            f"{source}: {kind} sensor {i + 1} ({names[i]}): estimated gain |h/SF| = {na[i]:.3g} "
            "cannot give a scale factor; expected a sensor that follows the table input "
            "(look for stuck or corrupt samples)")


def _check_axes(source: str, kind: str, Ht: np.ndarray) -> None:
    """Refuse calibrated axes that do not span 3-D space."""
    rank = int(np.linalg.matrix_rank(Ht, tol=1e-6))
    if rank < 3:
        raise CalibrationError(f"{source}: the calibrated {kind} axes span only {rank} "
                               "dimension(s); expected 3 (look for stuck or corrupt samples)")


def _pairs(session: Session, pos: dict[int, int]) -> list[tuple[int, int]]:
    """Rate-step pairs as step positions (first occurrence minus its partner)."""
    rate = [s for s in session.steps if s.kind == "rate"]
    out, seen = [], set()
    if any(s.pair is not None for s in rate):
        for s in rate:
            if s.pair is None or s.pair not in pos:
                continue
            key = tuple(sorted((s.index, s.pair)))
            if key in seen:
                continue
            seen.add(key)
            out.append((pos[s.index], pos[s.pair]))
    else:                                  # seed 000 Eq. 18 / seed 001 Eq. 15: in order
        for s1, s2 in zip(rate[0::2], rate[1::2], strict=False):
            out.append((pos[s1.index], pos[s2.index]))
    return out


def _split_all(a: np.ndarray, c: np.ndarray, Q: np.ndarray, Sigma_raw: np.ndarray,
               H0: np.ndarray, extra_cov: np.ndarray | None = None) -> list[dict[str, Any]]:
    """Per sensor: SF, h̃, angles, bias and their sds from (a, c) and cov factor Q (4×4).

    ``extra_cov`` (n, 4, 4): the coloured-noise part of each sensor's (a, c) covariance,
    added to the white ``Σ_ii·Q`` (None: white noise only).
    """
    out = []
    for i in range(a.shape[0]):
        Ci = Sigma_raw[i, i] * Q
        if extra_cov is not None:
            Ci = Ci + extra_cov[i]
        g = split_gain(a[i], Ci[:3, :3], H0[i])
        sf = g.scale_factor
        jb = np.concatenate([c[i] * g.jac[0], [sf]])                # b = c/|a|
        out.append({"split": g, "bias": c[i] * sf,
                    "bias_sd": float(np.sqrt(max(jb @ Ci @ jb, 0.0))),
                    "input_error_cov": Ci[:3, :3] * sf**2})
    return out


def _coloured(resid_si: np.ndarray, sf: np.ndarray, fs: float, seg_start: np.ndarray,
              seg_len: np.ndarray,
              ops: list[np.ndarray]) -> tuple[list[np.ndarray | None], dict[str, Any]]:
    """Coloured-noise part of the covariance of linear estimates ``θ = op @ ū_seg``.

    A white + Gauss-Markov model common to the set is fitted to the residual spectrum
    (:func:`calibration.residuals.fit_gauss_markov`). When the likelihood-ratio test keeps
    the bias process, its covariance over the segment means (exact for that model,
    inter-step correlation included, :func:`calibration.residuals.gauss_markov_segment_corr`)
    is propagated through each operator: ``(σ_b/SF_i)²·op·K(τc)·opᵀ`` in raw units.

    Returns
    -------
    list of (n, k, k) arrays or None (one per operator; None: white noise kept)
    dict
        ``{"bias_instability", "correlation_s", "likelihood_ratio", "applied"}`` (SI).
    """
    fit = fit_gauss_markov(resid_si, fs)
    rec = {"bias_instability": float(np.sqrt(fit.bias_var)),
           "correlation_s": float(fit.tau_c) if np.isfinite(fit.tau_c) else None,
           "likelihood_ratio": float(fit.lr), "applied": fit.bias_var > 0}
    if fit.bias_var <= 0:
        return [None] * len(ops), rec
    K = gauss_markov_segment_corr(seg_start, seg_len, fit.tau_c)
    var_raw = fit.bias_var / np.asarray(sf, float) ** 2
    outs: list[np.ndarray | None] = []
    for op in ops:
        G = op @ K @ op.T
        outs.append(var_raw[:, None, None] * G[None, :, :])
    return outs, rec


_NOISE_METHOD = {
    "white": "white: covariances sigma^2 op diag(1/N) op^T from the per-sample residual "
             "variance",
    "auto": "auto: white + first-order Gauss-Markov bias common to the set, Whittle "
            "maximum-likelihood fit to the residual spectrum, kept when its likelihood-ratio "
            f"statistic exceeds {GM_LR_THRESHOLD}; its exact covariance over the segment "
            "means is added",
}


def _noise_record(crec: dict[str, Any], parts: list[dict[str, Any]], a: np.ndarray,
                  c: np.ndarray, Q: np.ndarray, Sigma_raw: np.ndarray, H0: np.ndarray,
                  extra_cov: np.ndarray | None) -> dict[str, Any]:
    """What the noise model did to one set: fit, and sd factors (auto/white) per sensor."""
    n = a.shape[0]
    rec = dict(crec) if crec else {"applied": False}
    if extra_cov is None:
        rec["sd_factor"] = {"bias": [1.0] * n, "scale_factor": [1.0] * n,
                            "misalignment": [1.0] * n}
        return rec
    white = _split_all(a, c, Q, Sigma_raw, H0)
    rec["sd_factor"] = {
        "bias": [p["bias_sd"] / max(w["bias_sd"], 1e-300) for p, w in zip(parts, white,
                                                                          strict=True)],
        "scale_factor": [p["split"].scale_factor_sd / max(w["split"].scale_factor_sd, 1e-300)
                         for p, w in zip(parts, white, strict=True)],
        "misalignment": [float(np.max(p["split"].misalignment_sd
                                      / np.maximum(w["split"].misalignment_sd, 1e-300)))
                         for p, w in zip(parts, white, strict=True)]}
    return rec


def _segment_times(t: np.ndarray, seg: np.ndarray, cnt_seg: np.ndarray,
                   fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Start time (s) and duration (N/fs) of each segment; duration 0 when empty."""
    start = np.zeros(cnt_seg.size)
    use = seg >= 0
    if use.any():
        tt = np.asarray(t, float)[use]
        first = np.full(cnt_seg.size, np.inf)
        np.minimum.at(first, seg[use], tt)
        start = np.where(np.isfinite(first), first, 0.0)
    return start, cnt_seg / fs


def _parity_sd(H: np.ndarray, axis_jac: list[np.ndarray], Sigma_raw: np.ndarray,
               Qa: np.ndarray, extra_cov: np.ndarray | None = None) -> np.ndarray:
    """First-order sd of the calibrated parity matrix V(H̃), shape (n-3, n)."""
    n = H.shape[0]
    V0 = parity_matrix(H)
    eps = 1e-7
    J = np.zeros((V0.size, 3 * n))
    for i in range(n):
        for k in range(3):
            Hp = H.copy()
            Hp[i, k] += eps
            J[:, 3 * i + k] = (parity_matrix(Hp) - V0).ravel() / eps
    C = np.zeros((3 * n, 3 * n))
    for i in range(n):
        for j in range(n):
            Cij = Sigma_raw[i, j] * Qa
            if i == j and extra_cov is not None:
                Cij = Cij + extra_cov[i][:3, :3]
            C[3 * i:3 * i + 3, 3 * j:3 * j + 3] = axis_jac[i] @ Cij @ axis_jac[j].T
    return np.sqrt(np.clip(np.diag(J @ C @ J.T), 0, None)).reshape(V0.shape)


def calibrate(session: Session, *, bias_method: str = "model", denoise: bool = True,
              allan: bool = True, earth_rate: bool = True,
              noise_model: str = "auto") -> Calibration:
    """Calibrate the gyros (rate test) and accelerometers (multi-position) of a session.

    Parameters
    ----------
    session : Session
    bias_method : {"model", "turns"}
        Gyro bias written to the file: explicit Earth-rate model or seed 000's average over
        whole outer-axis turns (both are computed and kept in ``extra["gyro_bias"]``).
    denoise : bool
        Wavelet-denoise (db4, level 8) the outer-axis outputs before the Earth-rate fit.
    allan : bool
        Compute the Allan deviation of the residuals.
    earth_rate : bool
        Estimate the Earth rate from the outer-axis modulation.
    noise_model : {"auto", "white"}
        Uncertainties: ``"auto"`` adds a fitted Gauss-Markov bias process per sensor set when
        the residuals show one (see the module docstring); ``"white"`` assumes white noise.

    Returns
    -------
    Calibration

    Raises
    ------
    CalibrationError
        Rank-deficient rate pairs or positions, a used step with too few samples,
        non-finite samples, no whole outer turn for ``bias_method="turns"``.
    """
    if bias_method not in BIAS_METHODS:
        raise CalibrationError(f"unknown bias method {bias_method!r}; expected one of "
                               f"{', '.join(BIAS_METHODS)}")
    if noise_model not in NOISE_MODELS:
        raise CalibrationError(f"unknown noise model {noise_model!r}; expected one of "
                               f"{', '.join(NOISE_MODELS)}")
    src = session.source
    steps = list(session.steps)
    nums = [s.index for s in steps]
    pos = {k: j for j, k in enumerate(nums)}
    S = len(steps)
    fs = float(session.sample_rate_hz)
    lat = np.deg2rad(session.latitude_deg)
    raw = np.asarray(session.raw_gyro, float)
    _check_finite(src, "gyro", raw, session.step)

    wt, we, fb = session.inputs()
    up = fb / np.maximum(np.linalg.norm(fb, axis=1, keepdims=True), 1e-300)
    xt = wt + we

    # -- segments: (step, in whole-turn window) --------------------------------------------
    tw = turn_windows(session.step, session.outer, session.inner_rate, session.outer_rate,
                      nums)
    step_pos = np.array([pos.get(int(k), -1) for k in np.unique(session.step)])
    _, inv = np.unique(session.step, return_inverse=True)
    spos = step_pos[inv]
    seg = np.where(spos >= 0, 2 * spos + tw.in_window, -1)
    xturn = wt + EARTH_RATE * np.sin(lat) * up            # vertical Earth rate only
    cnt_seg, (u_seg, xt_seg, xturn_seg) = segment_means(seg, 2 * S, raw, xt, xturn)
    cnt = cnt_seg[0::2] + cnt_seg[1::2]
    frac = np.zeros((S, 2 * S))
    for j in range(S):
        if cnt[j]:
            frac[j, 2 * j] = cnt_seg[2 * j] / cnt[j]
            frac[j, 2 * j + 1] = cnt_seg[2 * j + 1] / cnt[j]
    u_step = frac @ np.nan_to_num(u_seg)
    xt_step = frac @ np.nan_to_num(xt_seg)

    # -- rate test -------------------------------------------------------------------------
    pairs = _pairs(session, pos)
    used = sorted({j for p in pairs for j in p})
    few = [(nums[j], int(cnt[j])) for j in used if cnt[j] < MIN_STEP_SAMPLES]
    if few:
        raise _fail_steps(src, "gyro", few)
    rt = rate_test(u_step, np.maximum(cnt, 1), xt_step, pairs, step_numbers=nums, source=src)
    op_a = rt.op @ frac                                    # (3, 2S) over segments

    # -- offsets ---------------------------------------------------------------------------
    bias_steps = [j for j in range(S) if cnt[j] >= MIN_STEP_SAMPLES]
    w_model = np.zeros(2 * S)
    for j in bias_steps:
        w_model[2 * j:2 * j + 2] = cnt_seg[2 * j:2 * j + 2]
    w_model /= w_model.sum()
    P_model = np.vstack([op_a, offset_operator(w_model, xt_seg, op_a)])
    P_turns = None
    if tw.steps:
        w_t = np.zeros(2 * S)
        w_t[1::2] = cnt_seg[1::2]
        w_t /= w_t.sum()
        P_turns = np.vstack([op_a, offset_operator(w_t, xturn_seg, op_a)])
    elif bias_method == "turns":
        raise CalibrationError(f"{src}: bias method 'turns' needs outer-axis rate steps of "
                               "at least one whole turn; the session has none"
                               + (f" (steps {', '.join(map(str, tw.short_steps))} are shorter)"
                                  if tw.short_steps else ""))
    u0 = np.nan_to_num(u_seg)
    theta = P_model @ u0                                   # (4, n)
    a, c = theta[:3].T, theta[3]
    _check_gains(src, "gyro", a, session.gyro_config.sensor_names)
    inv_cnt = np.where(cnt_seg > 0, 1.0 / np.maximum(cnt_seg, 1), 0.0)
    Q_model = (P_model * inv_cnt) @ P_model.T

    # -- residuals and noise ---------------------------------------------------------------
    mask = (spos >= 0) & np.isin(spos, bias_steps)
    r_raw = raw[mask] - xt[mask] @ a.T - c                 # raw units
    Sigma_raw = noise_covariance(r_raw, dof_used=4)
    chi2 = rt.chi2(np.sqrt(np.diag(Sigma_raw)), np.maximum(cnt, 1))
    # scatter of the per-step residual means against white noise: r = B·ū_seg exactly,
    # E[Σ_k N_k r_k²] = σ²·tr(D·B·diag(1/N_seg)·Bᵀ) (D = diag N_k over the bias steps)
    bs = np.array(bias_steps)
    B = frac[bs] - xt_step[bs] @ op_a - P_model[3][None, :]
    r_step = B @ u0                                                   # (S_b, n) raw
    expect = float(np.trace((cnt[bs][:, None] * B * inv_cnt) @ B.T))
    step_chi2 = (cnt[bs] @ r_step**2) / (np.diag(Sigma_raw) * max(expect, 1e-300))
    sdof = max(len(bs) - 4, 1)
    ex_model = ex_turns = None
    crec: dict[str, Any] = {}
    if noise_model == "auto":
        seg_start, seg_len = _segment_times(session.t, seg, cnt_seg, fs)
        ops = [P_model] + ([P_turns] if P_turns is not None else [])
        sf0 = 1.0 / np.linalg.norm(a, axis=1)
        exs, crec = _coloured(r_raw * sf0, sf0, fs, seg_start, seg_len, ops)
        ex_model = exs[0]
        ex_turns = exs[1] if P_turns is not None else None
    parts = _split_all(a, c, Q_model, Sigma_raw, session.gyro_config.H, ex_model)
    noise_rec = {"method": _NOISE_METHOD[noise_model],
                 "gyro": _noise_record(crec, parts, a, c, Q_model, Sigma_raw,
                                       session.gyro_config.H, ex_model)}
    if P_turns is not None:
        th_t = P_turns @ u0
        Q_t = (P_turns * inv_cnt) @ P_turns.T
        parts_t = _split_all(th_t[:3].T, th_t[3], Q_t, Sigma_raw, session.gyro_config.H,
                             ex_turns)
    sf = np.array([p["split"].scale_factor for p in parts])
    Sigma = Sigma_raw * np.outer(sf, sf)                   # compensated outputs, SI²
    resid = r_raw * sf
    chosen = parts_t if bias_method == "turns" else parts

    gyro_sfu, gyro_bu = display_units("gyro", session.gyro_raw_unit,
                                      np.array([p["bias"] for p in chosen]))
    cals = []
    for i, p in enumerate(parts):
        g = p["split"]
        cals.append(SensorCal(
            name=session.gyro_config.sensor_names[i], axis=g.axis,
            axis_nominal=session.gyro_config.H[i].copy(), scale_factor=g.scale_factor,
            scale_factor_sd=g.scale_factor_sd, bias=float(chosen[i]["bias"]),
            bias_sd=float(chosen[i]["bias_sd"]), input_error_cov=p["input_error_cov"],
            misalignment_sd=g.misalignment_sd, raw_unit=session.gyro_raw_unit,
            scale_factor_unit=gyro_sfu, bias_unit=gyro_bu,
            residual_rms=float(np.sqrt(np.mean(resid[:, i] ** 2)))))
    Ht = np.array([cc.axis for cc in cals])
    _check_axes(src, "gyro", Ht)
    groups = session.gyro_config.groups
    gyro_set = SensorSet("gyro", tuple(cals), Sigma, groups,
                         group_misalignment_matrices(session.gyro_config.H, Ht, groups),
                         allan_table(resid, fs) if allan else None)

    bfac = input_unit_factor(gyro_bu)
    dof = rt.R.shape[0] - 3
    warnings = []
    widened = bool(crec.get("applied"))
    consequence = ("the Gauss-Markov noise model (extra['noise_model']) widens the "
                   "uncertainties for correlated noise; an unmodelled effect would not be "
                   "covered") if widened else None
    if dof > 0:
        lim = float(scipy.stats.chi2.isf(1e-3, dof)) / dof
        for i in np.flatnonzero(chi2 > lim):
            warnings.append(
                f"gyro {session.gyro_config.sensor_names[i]}: the rate-step differences "
                f"scatter more than white noise explains (chi2/dof {chi2[i]:.2f}, 0.1 % limit "
                f"{lim:.2f}); correlated noise or an unmodelled effect: "
                + (consequence or "the uncertainties are too small"))
    slim = float(scipy.stats.chi2.isf(1e-3, sdof)) / sdof
    for i in np.flatnonzero(step_chi2 > slim):
        warnings.append(
            f"gyro {session.gyro_config.sensor_names[i]}: the step means of the residuals "
            f"scatter more than white noise explains (chi2/dof {step_chi2[i]:.2f}, 0.1 % limit "
            f"{slim:.2f}); correlated noise (bias instability) or an unmodelled effect: "
            + (consequence or "the bias uncertainty is too small"))
    extra: dict[str, Any] = {
        "source": src,
        "method": {"gyro": "rate test, seed 000 Eqs. 16-19 / seed 001 Eqs. 11-15, inputs "
                           "from the turntable model with the Earth rate",
                   "bias": bias_method, "denoise": "db4 level 8 (approximation)"
                   if denoise else "none"},
        "rate_test": {"pairs": [[nums[k], nums[p]] for k, p in rt.pairs],
                      "R_rad_s": rt.R, "chi2_dof": chi2},
        "step_residual_chi2_dof": step_chi2,
        "warnings": warnings,
        "noise_model": noise_rec,
        "gyro_bias": {"unit": gyro_bu,
                      "model": [p["bias"] / bfac for p in parts],
                      "model_sd": [p["bias_sd"] / bfac for p in parts]},
        "parity_calibrated_sd": _parity_sd(Ht, [p["split"].jac[1:4] for p in parts],
                                           Sigma_raw, Q_model[:3, :3], ex_model),
        "residual_steps": {"unit": {"gyro": "rad/s", "accel": "m/s^2"},
                           "gyro": residual_step_stats(
                               resid, session.step[mask], [nums[j] for j in bias_steps],
                               [steps[j].label for j in bias_steps],
                               [steps[j].kind for j in bias_steps])},
    }
    if P_turns is not None:
        vert = Ht @ (EARTH_RATE * np.sin(lat) * up[tw.in_window].mean(axis=0))
        extra["gyro_bias"].update({
            "turns": [p["bias"] / bfac for p in parts_t],
            "turns_sd": [p["bias_sd"] / bfac for p in parts_t],
            "turns_steps": list(tw.steps), "turns_per_step": list(tw.turns),
            "vertical_correction": (vert / bfac).tolist()})

    er: EarthRateFit | None = None
    if earth_rate:
        er = _earth_rate(session, Ht, sf, wt, Sigma, lat, denoise)
        if er is not None:
            extra["earth_rate_fit"] = er.to_dict()

    sets = {"gyro": gyro_set}
    if session.raw_accel is not None and session.accel_config is not None:
        acc = _accelerometers(session, fb, nums, pos, steps, fs, allan, extra, noise_model)
        if acc is not None:
            sets["accel"] = acc
    return Calibration(
        configuration=session.gyro_config.name, sets=sets, sample_rate_hz=fs,
        earth_rate_dph=None if er is None else er.rate_dph,
        earth_rate_dph_sd=None if er is None else er.rate_dph_sd,
        latitude_deg=float(session.latitude_deg), extra=extra)


def outer_axis_fit(session: Session, cal: Calibration, *,
                   denoise: bool = True) -> EarthRateFit | None:
    """The Earth-rate fit of a session with a calibration's gyro parameters (for plots).

    Same computation as inside :func:`calibrate`; the result keeps the (denoised)
    compensated outputs and the fitted curves. None without outer-axis steps.
    """
    g = cal.gyro
    wt, _, _ = session.inputs()
    return _earth_rate(session, g.H, g.scale_factors, wt, g.noise_covariance,
                       np.deg2rad(session.latitude_deg), denoise)


def _earth_rate(session: Session, Ht: np.ndarray, sf: np.ndarray, wt: np.ndarray,
                Sigma: np.ndarray, lat: float, denoise: bool) -> EarthRateFit | None:
    """Earth rate from the outer-axis steps (None when there are none)."""
    idx_all, ups = [], []
    for s in session.steps:
        idx = np.flatnonzero(session.step == s.index)
        if idx.size < MIN_STEP_SAMPLES or not is_outer_step(session.inner_rate[idx],
                                                            session.outer_rate[idx]):
            continue
        # inner angle fixed: C_nb = Rz(a_o)·[Ry(a_i)·P], rotate the fixed part about Up
        q = mat_nb(np.median(session.inner[idx]), 0.0, s.mat_pb)[0] @ Ht.T    # (3, n)
        co, so = np.cos(session.outer[idx])[:, None], np.sin(session.outer[idx])[:, None]
        ups.append(np.stack([co * q[0] - so * q[1], so * q[0] + co * q[1],
                             np.broadcast_to(q[2], co.shape[:1] + q[2].shape)], axis=1))
        idx_all.append(idx)
    if not idx_all:
        return None
    idx = np.concatenate(idx_all)
    y = np.asarray(session.raw_gyro, float)[idx] * sf - wt[idx] @ Ht.T
    return fit_earth_rate(y, np.concatenate(ups), session.step[idx], Sigma, lat,
                          denoise_outputs=denoise)


def _accelerometers(session: Session, fb: np.ndarray, nums: list[int], pos: dict[int, int],
                    steps: list, fs: float, allan: bool, extra: dict[str, Any],
                    noise_model: str = "auto") -> SensorSet | None:
    """Multi-position calibration of the accelerometers (None without ≥ 4 positions)."""
    src = session.source
    raw = np.asarray(session.raw_accel, float)
    pos_steps = [s.index for s in steps if s.kind == "position"]
    if len(pos_steps) < 4:
        return None
    _check_finite(src, "accelerometer", raw, session.step)
    lookup = {k: j for j, k in enumerate(pos_steps)}
    uniq, inv = np.unique(session.step, return_inverse=True)
    seg = np.array([lookup.get(int(k), -1) for k in uniq])[inv]
    cnt, (u_m, f_m) = segment_means(seg, len(pos_steps), raw, fb)
    few = [(k, int(cnt[j])) for j, k in enumerate(pos_steps) if cnt[j] < MIN_STEP_SAMPLES]
    if few:
        raise _fail_steps(src, "accelerometer", few)
    mp = multiposition(u_m, cnt, f_m, step_numbers=pos_steps, source=src)
    m = seg >= 0
    r_raw = raw[m] - fb[m] @ mp.a.T - mp.c
    Sigma_raw = noise_covariance(r_raw, dof_used=4)
    Q = (mp.op / cnt) @ mp.op.T
    H0 = session.accel_config.H
    _check_gains(src, "accel", mp.a, session.accel_config.sensor_names)
    ex, crec = None, {}
    if noise_model == "auto":
        seg_start, seg_len = _segment_times(session.t, seg, cnt, fs)
        sf0 = 1.0 / np.linalg.norm(mp.a, axis=1)
        (ex,), crec = _coloured(r_raw * sf0, sf0, fs, seg_start, seg_len, [mp.op])
    parts = _split_all(mp.a, mp.c, Q, Sigma_raw, H0, ex)
    extra["noise_model"]["accel"] = _noise_record(crec, parts, mp.a, mp.c, Q, Sigma_raw, H0, ex)
    sf = np.array([p["split"].scale_factor for p in parts])
    resid = r_raw * sf
    sfu, bu = display_units("accel", session.accel_raw_unit,
                            np.array([p["bias"] for p in parts]))
    cals = []
    for i, p in enumerate(parts):
        g = p["split"]
        cals.append(SensorCal(
            name=session.accel_config.sensor_names[i], axis=g.axis, axis_nominal=H0[i].copy(),
            scale_factor=g.scale_factor, scale_factor_sd=g.scale_factor_sd,
            bias=float(p["bias"]), bias_sd=float(p["bias_sd"]),
            input_error_cov=p["input_error_cov"], misalignment_sd=g.misalignment_sd,
            raw_unit=session.accel_raw_unit, scale_factor_unit=sfu, bias_unit=bu,
            residual_rms=float(np.sqrt(np.mean(resid[:, i] ** 2)))))
    Ht = np.array([cc.axis for cc in cals])
    _check_axes(src, "accel", Ht)
    groups = session.accel_config.groups
    extra["residual_steps"]["accel"] = residual_step_stats(
        resid, session.step[m], pos_steps, [steps[pos[k]].label for k in pos_steps],
        ["position"] * len(pos_steps))
    extra["parity_accel_calibrated_sd"] = _parity_sd(
        Ht, [p["split"].jac[1:4] for p in parts], Sigma_raw, Q[:3, :3], ex) \
        if Ht.shape[0] > 3 else []
    return SensorSet("accel", tuple(cals), Sigma_raw * np.outer(sf, sf), groups,
                     group_misalignment_matrices(H0, Ht, groups),
                     allan_table(resid, fs) if allan else None)
