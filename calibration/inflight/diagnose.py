"""Trace the parity residual of a flight to its causes.

Residual: the calibration compensates every gyro (``y = SF·u − b``); the reference IMU's
three axes give the body rate ``ω̂ = H_r⁻¹·y_r`` and every other IMU's axes the residual
``r_j = y_j − H_j·ω̂(t + τ_j)`` (3 channels per IMU, together a basis of the parity space:
``r = 0`` for a perfect model), with ``τ_j`` the calibration's time offset of IMU j applied
exactly as the in-flight fit reads it (:func:`shifted_residual`: cubic spline of the
reference). The samples are the fit's: segments to leave out (:mod:`.segments`), invalid
samples and the rows next to a dropped block are dropped. So the diagnosis reports what
the calibration left, not a second estimate of what it fitted: ``time_skew`` is the skew
left after the calibration's offset, and every IMU gets a ``timing`` record comparing the
two (the skew left, its sd, the combined sd). A calibration fitted on another flight is
named in ``warnings`` (an offset belongs to its flight).

Functions of time chosen together (``warm_up`` and ``bias_drift``, nearly collinear over one
flight) are reported as one ``slow_bias_change`` with their combined effect (the change of
the fitted slow bias over the flight); matrices (``g_sensitivity``, ``bias_drift``) carry
row and column labels and their unit (``matrix``).

Candidate effects, per IMU j: the in-flight forms of the effect specifications
(:class:`fdi.effect_specs.FlightForm`; :mod:`fdi.effect_specs.builtin` lists them with
their regressors on the IMU's three channels, units and time constants). A constant per
channel is always in the model. Selection is forward with Holm's step-down over all M
candidates of all IMUs (the multiplicity procedure of the session diagnosis,
:mod:`calibration.diagnose.selection`): at each round the candidate with the smallest
p-value (HAC Wald test of its parameters in its IMU's model with those already chosen,
:mod:`.regression`) enters if ``p < α/(M − k)``, k the effects accepted so far; effects
that are functions of time only (warm-up, drift) enter only when no candidate built from a
measured signal (angular acceleration, specific force, temperature, a spectral line)
passes, since a slow temperature change and a warm-up curve explain the same residual and
the measured one is the physical explanation. The vibration-noise candidates continue the
step-down after the mean model. The reported p-values are those of the final model (each
effect removed from it). Spectral lines: bins of the Welch spectrum of a channel more than
:data:`LINE_FACTOR` times its running median (41 bins), local maxima, up to
:data:`MAX_LINES`.

Vibration noise (a variance effect, tested after the mean model): the squared residual of
each channel regressed on the IMU's accelerometer vibration power (1-s mean of the squared
deviation from the 1-s mean acceleration); one candidate per IMU with accelerometers.

Unexplained: after the final model, a channel whose 1-s block means vary more than its
short-lag (AR(1)) correlation explains (χ² test at α/M, Bonferroni as the session's
probes), or that still shows a line. The timing record's ``left`` is tested at α/M too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage, signal, stats
from scipy.interpolate import CubicSpline

from calibration.inflight.offset_check import SIGN_CONVENTION
from calibration.inflight.regression import stacked_lstsq, wald_test
from calibration.inflight.segments import find_segments, keep_mask
from calibration.inflight.timing import other_flight_warning
from fdi.calfile import Calibration
from fdi.effect_specs import WARMUP_FLIGHT_TAU_S, FlightForm, FlightInputs, effect_specs
from fdi.errors import ConfigError
from fdi.extras import ImuTiming
from fdi.units import DPS, G0, MS
from replay.flight_data import Flight

__all__ = ["DIAGNOSE_SCHEMA", "DRIFT_EFFECT", "FORMS", "GENERIC", "LINE_FACTOR", "MAX_LINES",
           "RATE_LIMIT", "WARM_UP_S", "diagnose_flight", "flight_residual", "shifted_residual"]

DIAGNOSE_SCHEMA = "rimu.diagnose-flight/1"
LINE_FACTOR = 10.0
"""A spectral bin this many times the local median spectrum is a line."""
_LOCAL_BINS = 41
"""Width (bins) of the running median a line is compared with."""
MAX_LINES = 3
FORMS: tuple[FlightForm, ...] = tuple(sorted(
    (sp.flight for sp in effect_specs() if sp.flight is not None), key=lambda f: f.order))
"""The in-flight candidates, in their order (the specs' ``flight`` forms)."""
GENERIC = tuple(f.label for f in FORMS if f.time_only)
"""Effects that are functions of time only; they enter after the measured regressors."""
WARM_UP_S = WARMUP_FLIGHT_TAU_S
"""Time constant of the warm-up regressor (s; :data:`fdi.effect_specs.WARMUP_FLIGHT_TAU_S`)."""
_ROLE = {f.role: f.label for f in FORMS if f.role}
"""The label of the skew and of the drift candidate."""
DRIFT_EFFECT = _ROLE["drift"]
"""The label of the drift candidate (the drift attribution is printed with it)."""
RATE_LIMIT = 1e5 * DPS
"""A rate beyond this (rad/s; 100 000 deg/s, far beyond any gyro's range) is not a
measurement: such samples are left out like non-finite ones."""


@dataclass(frozen=True)
class _Cand:
    name: str
    imu: str
    X: np.ndarray           # (N, 3, p)
    unit: str
    scale: float            # SI parameter → reported unit
    form: FlightForm | None = None


def flight_residual(flight: Flight, cal: Calibration, reference: str | None = None
                    ) -> tuple[str, dict[str, np.ndarray], dict[str, list[int]], np.ndarray,
                               np.ndarray]:
    """Compensated residual of every non-reference IMU.

    Returns
    -------
    reference : str
    residual : dict of str to ndarray (N, 3)
        ``r_j`` (rad/s).
    index : dict of str to list of int
        0-based sensor indices of each IMU.
    omega : ndarray, shape (N, 3)
        ``ω̂`` from the reference (rad/s).
    H : ndarray, shape (n, 3)
        Calibrated axes.
    """
    s = cal.kind("gyro")
    if flight.kind != "gyro" or s.n != flight.n:
        raise ConfigError(f"{flight.source}: {flight.n} {flight.kind} sensors, the "
                          f"calibration has {s.n} gyros")
    groups = flight.imu_triads("diagnose of a flight")
    typed = cal.extras
    ref = reference or (typed.inflight.reference if typed.inflight is not None else "") \
        or (typed.static.reference if typed.static is not None else "") \
        or next(iter(groups))
    if ref not in groups:
        ref = next(iter(groups))
    y = flight.raw * s.scale_factors - s.biases
    H = s.H
    ri = groups[ref]
    omega = np.linalg.solve(H[ri], y[:, ri].T).T
    res = {g: y[:, idx] - omega @ H[idx].T for g, idx in groups.items() if g != ref}
    return ref, res, groups, omega, H


def shifted_residual(flight: Flight, cal: Calibration, keep: np.ndarray,
                     reference: str | None = None
                     ) -> tuple[str, dict[str, np.ndarray], dict[str, list[int]],
                                dict[str, np.ndarray], np.ndarray, np.ndarray, dict[str, float]]:
    """The residual the in-flight calibration leaves, on the samples it used.

    As the fit (:func:`calibration.inflight.fit.fit_pair`) reads it: the reference's rate
    ``ω̂`` through a cubic spline of its samples in ``keep``, read at ``t + τ_j`` for IMU j
    (τ_j its calibration's offset, exact, not to first order), and the rows next to a
    dropped block (the spline bridges it) or whose shifted time leaves the record left
    out.

    Returns
    -------
    reference : str
    residual : dict of str to ndarray (N, 3)
        ``r_j = y_j − H_j·ω̂(t + τ_j)`` (rad/s), NaN on rows not used.
    index : dict of str to list of int
    omega_dot : dict of str to ndarray (N, 3)
        ``dω̂/dt`` at ``t + τ_j`` (rad/s²), the regressor of a time skew left over.
    H : ndarray, shape (n, 3)
    used : ndarray of bool, shape (N,)
        Rows used for every IMU.
    offsets : dict of str to float
        τ_j applied (s; 0 for an IMU the calibration gives none).
    """
    from calibration.inflight.fit import _EDGE
    from calibration.inflight.timing import time_offsets_s

    ref, _, groups, omega, H = flight_residual(flight, cal, reference)
    s = cal.kind("gyro")
    y = flight.raw * s.scale_factors - s.biases
    t = np.asarray(flight.t, float)
    known = time_offsets_s(cal)
    res, dots, offsets = {}, {}, {}
    used = np.asarray(keep, bool).copy()
    # a rate beyond any gyro's range (1e308 in a damaged file) is left out like a NaN
    fin_ref = np.all(np.abs(omega) < RATE_LIMIT, axis=1)
    for g, idx in groups.items():
        if g == ref:
            continue
        tau = float(known.get(g, 0.0))
        ok = keep & fin_ref & np.all(np.abs(y[:, idx]) < RATE_LIMIT, axis=1)
        if ok.sum() < 4:
            raise ConfigError(f"{flight.source}: only {int(ok.sum())} usable samples of {g}")
        core = ok & ndimage.binary_erosion(ok, structure=np.ones(2 * _EDGE + 1, bool),
                                           border_value=True)
        tt = t[ok]
        core &= (t + tau >= tt[0]) & (t + tau <= tt[-1])
        sp = CubicSpline(tt, omega[ok], axis=0)
        w = sp(t + tau)
        r = y[:, idx] - w @ H[idx].T
        r[~core] = np.nan
        res[g] = r
        dots[g] = sp(t + tau, 1)
        offsets[g] = tau
        used &= core
    return ref, res, groups, dots, H, used, offsets


def _aux(flight: Flight, kind: str, imu: str) -> np.ndarray | None:
    if flight.aux is None:
        return None
    a = flight.aux.select(kind)
    cols = [k for k, g in enumerate(a.imu) if g == imu]
    if not cols:
        return None
    return a.values[:, cols]


def _lines(r: np.ndarray, fs: float) -> list[float]:
    """Frequencies (Hz) of the strongest spectral lines of the residual channels."""
    nper = int(min(r.shape[0], 8192, max(256, 2 ** int(math.log2(max(r.shape[0] / 4, 2))))))
    found: dict[float, float] = {}
    for k in range(r.shape[1]):
        f, p = signal.welch(r[:, k] - r[:, k].mean(), fs=fs, nperseg=nper)
        med = ndimage.median_filter(p, size=_LOCAL_BINS, mode="nearest")
        if not np.all(med > 0):
            continue
        ratio = p / med
        pk, _ = signal.find_peaks(ratio, height=LINE_FACTOR)
        for i in pk:
            if f[i] > 0.2:                  # slower than 0.2 Hz is drift, not a line
                key = round(float(f[i]), 2)
                found[key] = max(found.get(key, 0.0), float(ratio[i]))
    best = sorted(found, key=lambda x: -found[x])
    out: list[float] = []
    for fr in best:
        if all(abs(fr - o) > 2 * fs / nper for o in out):
            out.append(fr)
        if len(out) == MAX_LINES:
            break
    return out


def _refine(r: np.ndarray, t: np.ndarray, f0: float, fs: float) -> float:
    """Frequency of a line to a fraction of a Welch bin (grid search of the periodogram)."""
    grid = f0 + np.linspace(-fs / 256, fs / 256, 41)
    pw = [float(np.sum(np.abs(np.exp(-2j * np.pi * g * t) @ (r - r.mean(axis=0))) ** 2))
          for g in grid]
    return float(grid[int(np.argmax(pw))])


def _candidates(flight: Flight, imu: str, idx: list[int], H: np.ndarray, omega_dot: np.ndarray,
                r: np.ndarray, t: np.ndarray, keep: np.ndarray
                ) -> tuple[list[_Cand], list[dict[str, str]]]:
    """The candidates of one IMU from the specs' flight forms, and those not testable."""
    cands: list[_Cand] = []
    untestable: list[dict[str, str]] = []
    fi = FlightInputs(t=t, keep=keep, rate_dot=omega_dot @ H[idx].T,
                      force=_aux(flight, "accel", imu),
                      temperature=_aux(flight, "temperature", imu))
    fs = flight.sample_rate_hz
    for form in FORMS:
        if form.searched:
            for f0 in _lines(r[keep], fs):
                f1 = _refine(r[keep], t[keep], f0, fs)
                cands.append(_Cand(f"{form.label}_{f1:.2f}Hz", imu,
                                   form.columns(fi, {"frequency_hz": f1}), form.unit,
                                   form.scale, form))
            continue
        X = form.columns(fi, {})
        if isinstance(X, str):
            untestable.append({"name": form.label, "imu": imu, "reason": X})
        else:
            cands.append(_Cand(form.label, imu, X, form.unit, form.scale, form))
    return cands, untestable


def _vibration_level(flight: Flight, imu: str) -> np.ndarray | None:
    """Accelerometer vibration power of an IMU: 1-s mean of |a − 1-s mean of a|², (m/s²)²."""
    a = _aux(flight, "accel", imu)
    if a is None or a.shape[1] != 3 or not np.isfinite(a).all():
        return None
    q = max(3, round(flight.sample_rate_hz))
    hp = np.sum((a - ndimage.uniform_filter1d(a, q, axis=0, mode="nearest")) ** 2, axis=1)
    return ndimage.uniform_filter1d(hp, q, mode="nearest")


def _vibration_noise(e: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, float,
                                                             list[float]]:
    """Does the residual power follow the vibration level?  ``e_k² = c_k + s_k·(v − v̄)``.

    Returns the slopes (rad²/s² per (m/s²)²), their HAC sds, the Wald p-value and the
    residual RMS per axis in the calmest and the roughest quarter of the samples (rad/s).
    """
    N = e.shape[0]
    X = np.zeros((N, 3, 6))
    vc = v - v.mean()
    for k in range(3):
        X[:, k, k] = 1.0
        X[:, k, 3 + k] = vc
    fit = stacked_lstsq(X, e**2)
    p = wald_test(fit, [3, 4, 5])[2]
    lo, hi = np.quantile(v, [0.25, 0.75])
    calm = float(np.sqrt(np.mean(e[v <= lo] ** 2)))
    rough = float(np.sqrt(np.mean(e[v >= hi] ** 2)))
    return fit.beta[3:], fit.sd[3:], p, [calm, rough]


def _design(base: np.ndarray, chosen: list[_Cand]) -> tuple[np.ndarray, list[slice]]:
    blocks = [base] + [c.X for c in chosen]
    sl, a = [], base.shape[2]
    for c in chosen:
        sl.append(slice(a, a + c.X.shape[2]))
        a += c.X.shape[2]
    return np.concatenate(blocks, axis=2), sl


def _base(N: int) -> np.ndarray:
    """The constant of each channel, (N, 3, 3)."""
    base = np.zeros((N, 3, 3))
    for k in range(3):
        base[:, k, k] = 1.0
    return base


def _pvalues(r: np.ndarray, chosen: list[_Cand], left: list[_Cand], keep: np.ndarray
             ) -> list[float]:
    """The p-value of each candidate in ``left`` added to the model with ``chosen``."""
    base, Y = _base(r.shape[0]), r[keep]
    ps = []
    for c in left:
        X, sl = _design(base, [*chosen, c])
        fit = stacked_lstsq(X[keep], Y)
        ps.append(wald_test(fit, np.arange(sl[-1].start, sl[-1].stop))[2])
    return ps


def _select(res: dict[str, np.ndarray], cands: dict[str, list[_Cand]], keep: np.ndarray,
            alpha: float, M: int) -> tuple[dict[str, tuple[list[_Cand], Any, list[slice]]],
                                            int]:
    """Forward selection over every IMU with Holm's step-down: the k-th effect accepted
    passed ``α/(M − k)`` (k from 0), measured regressors before functions of time.
    Returns each IMU's (chosen, final fit, slices) and the number accepted."""
    chosen: dict[str, list[_Cand]] = {g: [] for g in cands}
    left = {g: list(c) for g, c in cands.items()}
    ps = {g: _pvalues(res[g], [], left[g], keep) for g in cands}
    k = 0
    while True:
        thr = alpha / max(M - k, 1)
        ok = [(c.name in GENERIC, p, gi, i) for gi, g in enumerate(cands)
              for i, (c, p) in enumerate(zip(left[g], ps[g], strict=True)) if p < thr]
        if not ok:
            break
        _, _, gi, i = min(ok)                   # measured regressors before generic ones
        g = list(cands)[gi]
        chosen[g].append(left[g].pop(i))
        ps[g] = _pvalues(res[g], chosen[g], left[g], keep)
        k += 1
    out = {}
    for g in cands:
        X, sl = _design(_base(res[g].shape[0]), chosen[g])
        out[g] = (chosen[g], stacked_lstsq(X[keep], res[g][keep]), sl)
    return out, k


def _structure(e: np.ndarray, fs: float, alpha_each: float, names: list[str]) -> list[str]:
    """Channels whose 1-s block means vary more than AR(1) noise allows."""
    out = []
    q = max(2, round(fs))
    nb = e.shape[0] // q
    if nb < 10:
        return out
    for k in range(e.shape[1]):
        x = e[:, k] - e[:, k].mean()
        rho = float(np.clip(np.corrcoef(x[1:], x[:-1])[0, 1], -0.9, 0.9))
        vr_ar = (1 + rho) / (1 - rho) - 2 * rho * (1 - rho**q) / (q * (1 - rho) ** 2)
        bm = x[:nb * q].reshape(nb, q).mean(axis=1)
        vr = float(np.var(bm, ddof=1) * q / np.var(x))
        stat = (nb - 1) * vr / max(vr_ar, 1e-9)
        p = float(stats.chi2.sf(stat, nb - 1))
        if p < alpha_each:
            out.append(f"{names[k]}: 1-s block means vary {vr / vr_ar:.3g}x more than "
                       f"short-lag noise explains (p={p:.2g})")
    return out


def _imu_timing(cal: Calibration, g: str) -> ImuTiming:
    """The calibration's timing of IMU ``g`` (no offset when it records none)."""
    inflight = cal.extras.inflight
    none = ImuTiming(time_offset_s=None)
    return none if inflight is None else inflight.imus.get(g, none)


def _effect_record(c: Any, s: slice, fit: Any, g: str, sensors: list[int],
                   cal: Calibration) -> dict[str, Any]:
    """The JSON record of a selected effect (estimate and sd in the candidate's unit)."""
    est = fit.beta[s] * c.scale
    sd = fit.sd[s] * c.scale
    rec = {"name": c.name, "imu": g, "sensors": sensors,
           "estimate": float(est[0]) if est.size == 1 else est.tolist(),
           "estimate_sd": float(sd[0]) if sd.size == 1 else sd.tolist(),
           "unit": c.unit, "p_value": wald_test(fit, np.arange(s.start, s.stop))[2]}
    known = _imu_timing(cal, g)
    if c.name == _ROLE["skew"]:
        cal_txt = (f"the calibration's {known.time_offset_s / MS:+.3f} ± "
                   f"{known.time_offset_sd_s / MS:.3f} ms" if known.time_offset_s is not None
                   else "no calibrated offset")
        rec["detail"] = (f"time skew left after {cal_txt} for {g} (applied exactly, as the "
                         f"calibration reads it; rimu monitor-file moves {g}'s samples by "
                         f"the same offset); {SIGN_CONVENTION}")
    if c.form is not None and c.form.matrix is not None:
        cols, term_major = c.form.matrix
        vals, sds = est.reshape(3, len(cols)), sd.reshape(3, len(cols))
        if term_major:                          # parameters P1x P1y P1z P2x ...
            vals, sds = est.reshape(len(cols), 3).T, sd.reshape(len(cols), 3).T
        rec["matrix"] = {"rows": [f"{g}.{a} gyro" for a in "xyz"], "cols": list(cols),
                         "values": vals.tolist(), "sd": sds.tolist(),
                         "unit": "deg/s" if term_major else c.unit}
    return rec


def _slow_group(chosen: list[_Cand], sl: list[slice], fit: Any, t: np.ndarray,
                keep: np.ndarray, g: str, sensors: list[int]) -> dict[str, Any] | None:
    """One record for the functions of time (warm-up, drift) chosen together: they are
    nearly collinear over one flight, so only their combined effect is a claim.

    The combined effect is the change of the fitted slow bias between the first and the
    last used sample, per axis (deg/s), with its sd from the joint HAC covariance.
    """
    idx = [k for k, c in enumerate(chosen) if c.name in GENERIC]
    if len(idx) < 2:
        return None
    cols = np.concatenate([np.arange(sl[k].start, sl[k].stop) for k in idx])
    rows = np.flatnonzero(keep)
    first, last = rows[0], rows[-1]
    L = np.zeros((3, fit.beta.shape[0]))
    for k in idx:
        X = chosen[k].X
        L[:, sl[k]] = X[last] - X[first]          # (3 channels, its parameters)
    eff = L @ fit.beta / DPS
    C = L @ fit.cov @ L.T / DPS**2
    p = wald_test(fit, cols)[2]
    ta, tb = chosen[idx[0]].X[keep].reshape(-1, chosen[idx[0]].X.shape[2]), \
        chosen[idx[1]].X[keep].reshape(-1, chosen[idx[1]].X.shape[2])
    q1, _ = np.linalg.qr(ta - ta.mean(axis=0))
    q2, _ = np.linalg.qr(tb - tb.mean(axis=0))
    rho = float(np.linalg.svd(q1.T @ q2, compute_uv=False)[0])
    names = " + ".join(chosen[k].name for k in idx)
    return {"name": "slow_bias_change", "imu": g, "sensors": sensors,
            "members": [chosen[k].name for k in idx],
            "estimate": eff.tolist(), "estimate_sd": np.sqrt(np.clip(np.diag(C), 0, None)).tolist(),
            "unit": "deg/s (change of the slow bias from the first to the last used sample)",
            "p_value": p,
            "detail": f"{names} are nearly collinear over this flight (largest canonical "
                      f"correlation {rho:.4f}): reported as one slow bias change, not as "
                      f"separate physical effects"}


def _timing_record(g: str, chosen: list[_Cand], sl: list[slice], fit: Any,
                   cands: list[_Cand], r0: np.ndarray, keep: np.ndarray, cal: Calibration,
                   tau_s: float, alpha_each: float) -> dict[str, Any]:
    """What the calibration's time offset of IMU ``g`` leaves: the skew δτ in the final
    model (with the skew added when it was not chosen), against the calibrated offset."""
    names = [c.name for c in chosen]
    if _ROLE["skew"] in names:
        k = names.index(_ROLE["skew"])
        f, s = fit, sl[k]
    else:
        skew = next((c for c in cands if c.name == _ROLE["skew"]), None)
        X, sls = _design(_base(r0.shape[0]), [*chosen, skew])
        f, s = stacked_lstsq(X[keep], r0[keep]), sls[-1]
    d, dsd = 1e3 * float(f.beta[s][0]), 1e3 * float(f.sd[s][0])
    p = wald_test(f, np.arange(s.start, s.stop))[2]
    timing = _imu_timing(cal, g)
    known = timing.time_offset_s is not None
    csd = timing.time_offset_sd_s / MS if known else 0.0
    comb = math.hypot(csd, dsd)
    return {"imu": g, "calibration_ms": 1e3 * tau_s if known else None,
            "calibration_sd_ms": csd,
            "left_ms": d, "left_sd_ms": dsd, "p_value": p, "left": bool(p < alpha_each),
            "total_ms": 1e3 * tau_s + d, "combined_sd_ms": comb,
            "apart_in_combined_sd": abs(d) / comb if comb > 0 else math.inf}


def _drift_p1(chosen: list[_Cand], sl: list[slice], fit: Any, cands: list[_Cand],
              r0: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The change of the slow bias of the three channels from the first to the last used
    sample (rad/s) and its HAC covariance: from the functions of time in the final model
    (warm-up and drift together when both were chosen: their sum is what is identified),
    or with ``bias_drift`` added when none was chosen."""
    idx = [k for k, c in enumerate(chosen) if c.name in GENERIC]
    f, cs, sls = fit, chosen, sl
    if not idx:
        cand = next((c for c in cands if c.name == _ROLE["drift"]), None)
        if cand is None:
            return None
        X, sls = _design(_base(r0.shape[0]), [*chosen, cand])
        f, cs = stacked_lstsq(X[keep], r0[keep]), [*chosen, cand]
        idx = [len(cs) - 1]
    rows = np.flatnonzero(keep)
    L = np.zeros((3, f.beta.shape[0]))
    for k in idx:
        L[:, sls[k]] = cs[k].X[rows[-1]] - cs[k].X[rows[0]]
    return L @ f.beta, L @ f.cov @ L.T


def _attribution(p1: dict[str, tuple[np.ndarray, np.ndarray]], groups: dict[str, list[int]],
                 H: np.ndarray, ref: str, alpha: float) -> dict[str, Any] | None:
    """Which drift is the reference's: the P1 drifts of the residuals in the body frame
    (``r_j = D_j − H_j·D_ref``, so ``H_j⁻¹·r_j`` shares ``−D_ref``), through
    :func:`calibration.inflight.static.attribute_drift`; deg/s."""
    from calibration.inflight.static import attribute_drift

    if not p1:
        return None
    rel, cov = {}, {}
    for g, (b, C) in p1.items():
        Hi = np.linalg.pinv(H[groups[g]])
        rel[g] = Hi @ b
        cov[g] = Hi @ C @ Hi.T
    a = attribute_drift(rel, cov, ref, alpha=alpha)
    return {**a, "common": (np.asarray(a["common"]) / DPS).tolist(),
            "common_sd": (np.asarray(a["common_sd"]) / DPS).tolist(),
            "own": {g: {**v, "drift": (np.asarray(v["drift"]) / DPS).tolist()}
                    for g, v in a["own"].items()},
            "unit": "deg/s, change of the slow bias over the record (body frame of the "
                    "reference)"}


def _vibration_record(test: tuple[np.ndarray, np.ndarray, float, list[float]], g: str,
                      sensors: list[int]) -> dict[str, Any]:
    """The ``vibration_noise`` record of a test :func:`_vibration_noise` accepted."""
    sl_, sd_, p, (calm, rough) = test
    f2 = (G0 / DPS) ** 2                  # rad²/s² per (m/s²)² → (deg/s)² per g²
    return {"name": "vibration_noise", "imu": g, "sensors": sensors,
            "estimate": (sl_ * f2).tolist(), "estimate_sd": (sd_ * f2).tolist(),
            "unit": "(deg/s)^2 of residual variance per g^2 of accelerometer "
                    "vibration power", "p_value": p,
            "detail": f"residual rms {calm / DPS:.3g} deg/s in the calmest quarter, "
                      f"{rough / DPS:.3g} deg/s in the roughest (a variance effect: "
                      f"not removed from the residual)"}


def _holm_rest(ps: dict[str, float], alpha: float, M: int, k: int) -> set[str]:
    """The members of ``ps`` Holm's step-down accepts after ``k`` acceptances of M."""
    out: set[str] = set()
    for g in sorted(ps, key=lambda g: ps[g]):
        if not ps[g] < alpha / max(M - k - len(out), 1):
            break
        out.add(g)
    return out


def _imu_records(flight: Flight, cal: Calibration, r0s: dict[str, np.ndarray],
                 selected: dict[str, Any], per_imu: dict[str, Any],
                 groups: dict[str, list[int]], keep: np.ndarray, offsets: dict[str, float],
                 alpha_each: float, vib_on: Any, vib_tests: dict[str, Any]) -> tuple:
    """Per IMU the records :func:`diagnose_flight` returns: (effects, detail, timing, the
    drift's first-order parts, channels, RMS before, RMS after, not testable)."""
    t = flight.t
    not_testable: list[dict[str, str]] = []
    effects, detail, timing = [], [], []
    p1: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    chans, before, after = [], [], []
    for g in r0s:
        r0 = r0s[g]
        chosen, fit, sl = selected[g]
        names = [flight.sensor_names[i] for i in groups[g]]
        chans += names
        before += list(np.sqrt(np.mean(r0[keep] ** 2, axis=0)) / DPS)
        after += list(np.sqrt(np.mean(fit.residual**2, axis=0)) / DPS)
        sensors = [i + 1 for i in groups[g]]
        grp = _slow_group(chosen, sl, fit, t, keep, g, sensors)
        effects += [_effect_record(c, s, fit, g, sensors, cal)
                    for c, s in zip(chosen, sl, strict=True)
                    if grp is None or c.name not in grp["members"]]
        effects += [grp] if grp is not None else []
        timing.append(_timing_record(g, chosen, sl, fit, per_imu[g], r0, keep, cal,
                                     offsets[g], alpha_each))
        d1 = _drift_p1(chosen, sl, fit, per_imu[g], r0, keep)
        if d1 is not None:
            p1[g] = d1
        if g in vib_on:
            effects.append(_vibration_record(vib_tests[g], g, sensors))
        elif g not in vib_tests:
            not_testable.append({"name": "vibration_noise", "imu": g,
                                 "reason": "no accelerometer logged beside the gyros"})
        detail += _structure(fit.residual, flight.sample_rate_hz, alpha_each, names)
        for f0 in _lines(fit.residual, flight.sample_rate_hz):
            detail.append(f"{g}: a spectral line at {f0:.2f} Hz remains")
    return effects, detail, timing, p1, chans, before, after, not_testable


def diagnose_flight(flight: Flight, cal: Calibration, *, alpha: float = 0.01,
                    reference: str | None = None) -> dict[str, Any]:
    """Diagnose the parity residual of a flight (module docstring).

    Parameters
    ----------
    flight : Flight
        Gyro flight with IMU groups.
    cal : Calibration
    alpha : float
        Family-wise significance level.
    reference : str, optional

    Returns
    -------
    dict
        JSON-ready: ``effects``, ``unexplained``, ``unexplained_detail``, ``not_testable``,
        ``error_before``, ``error_after``, ``left_out``, ...
    """
    if not 0 < alpha < 1:
        raise ConfigError(f"alpha must be in (0, 1), got {alpha}")
    t = flight.t
    segs = find_segments(flight)
    ref, res, groups, omega_dot, H, keep, offsets = shifted_residual(
        flight, cal, keep_mask(t, segs), reference)
    if keep.sum() < 100:
        raise ConfigError(f"{flight.source}: only {int(keep.sum())} usable samples")
    other = other_flight_warning(cal, flight)
    warnings = [other] if other else []
    # every parameter of the calibration against this flight's own fit (issue 27)
    from calibration.inflight.fits_flight import flight_mismatch

    checks, misfit = flight_mismatch(cal, flight, alpha=alpha)
    warnings += misfit
    per_imu = {}
    not_testable: list[dict[str, str]] = []
    for g, r in res.items():
        c, u = _candidates(flight, g, groups[g], H, omega_dot[g], np.nan_to_num(r), t, keep)
        per_imu[g] = c
        not_testable += u
    vib = {g: _vibration_level(flight, g) for g in res}
    M = sum(len(c) for c in per_imu.values()) + sum(v is not None for v in vib.values())
    alpha_each = alpha / max(M, 1)                   # the after-checks (Bonferroni)
    r0s = {g: np.nan_to_num(r) for g, r in res.items()}
    selected, k = _select(r0s, per_imu, keep, alpha, M)
    vib_tests = {g: _vibration_noise(selected[g][1].residual, v[keep])
                 for g, v in vib.items() if v is not None}
    vib_on = _holm_rest({g: v[2] for g, v in vib_tests.items()}, alpha, M, k)
    rec = _imu_records(flight, cal, r0s, selected, per_imu, groups, keep, offsets,
                       alpha_each, vib_on, vib_tests)
    effects, detail, timing, p1, chans, before, after = rec[:7]
    not_testable += rec[7]
    return {"schema": DIAGNOSE_SCHEMA, "source": flight.source, "reference": ref,
            "alpha": alpha, "candidates": M,
            "correction": "Holm over all candidates (the after-checks at alpha/M)",
            "effects": effects, "unexplained": bool(detail), "unexplained_detail": detail,
            "not_testable": not_testable,
            "timing": timing, "time_offset_sign": SIGN_CONVENTION, "warnings": warnings,
            "parameter_checks": [c.to_dict() for c in checks],
            "drift_attribution": _attribution(p1, groups, H, ref, alpha),
            "calibration_kind": ("in-flight" if cal.extras.inflight is not None else
                                 "static" if cal.extras.static is not None else "turntable"),
            "error_before": {"unit": "deg/s", "channels": chans, "rms": before},
            "error_after": {"unit": "deg/s", "channels": chans, "rms": after},
            "left_out": [s.to_dict() for s in segs],
            "samples_used": int(keep.sum()), "samples": int(t.shape[0])}
