"""The oracle detector: the physical limit for a fault whose direction is known.

It knows which sensor fails, so it projects the whitened parity on that sensor's column,
r = u_iᵀz/|u_i| (N(0, 1) per sample for healthy white noise), and runs the monitor's
dyadic windows (1 ... 2^K samples, K = 12 by default: up to 41 s at 100 Hz) on this one
number: ``D_w = (Σ_w r)²/(w f_w)`` against ``chi2.isf(alpha_w, 1)·(1 + w·β/f_w + κ/f_w·Σ_w ρ)``,
and a two-sided CUSUM on r (allowance ν + 3·sqrt(κρ + β), ν = 0.1 by default); the
monitor's false-alarm budget is split over the windows and the CUSUM (Bonferroni), with the
monitor's calibration-uncertainty inflation. It alarms when either fires. Its delay on a
ramp is what any detector that must also find the direction is compared with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fdi.calfile import Calibration
from fdi.detector import chi2_threshold, cusum_threshold, default_thresholds
from fdi.monitor import Monitor

__all__ = ["OracleResult", "oracle_detect"]


@dataclass(frozen=True)
class OracleResult:
    """First alarm of the oracle.

    Attributes
    ----------
    t_alarm : float
        Time of the first alarm at or after ``onset`` (inf if none).
    delay_s : float
        ``t_alarm − onset``.
    false_alarms : int
        Alarm samples before ``onset``.
    scale : int or None
        Window that fired first (0: the CUSUM).
    """

    t_alarm: float
    delay_s: float
    false_alarms: int
    scale: int | None


def oracle_detect(cal: Calibration, t: np.ndarray, raw: np.ndarray, sensor: int,
                  onset: float, *, false_alarms_per_hour: float = 1e-3,
                  scales: int | tuple[int, ...] = 12, cusum_drift: float = 0.1,
                  kind: str = "gyro") -> OracleResult:
    """Run the oracle on a block of raw samples (all sensors healthy and present).

    Parameters
    ----------
    cal : Calibration
    t : ndarray, shape (N,)
    raw : ndarray, shape (N, n)
    sensor : int
        1-based sensor that fails.
    onset : float
        Fault onset (s).
    false_alarms_per_hour : float
        The same budget as the monitor's.
    scales : int or tuple of int
        K or the window lengths.
    cusum_drift : float
        CUSUM allowance ν (σ units).
    """
    thresholds = default_thresholds(cal, kind=kind, false_alarms_per_hour=false_alarms_per_hour,
                                    scales=scales, detector="both", cusum_drift=cusum_drift)
    mon = Monitor(cal, thresholds, kind=kind)
    mdl = mon.model
    t = np.asarray(t, float)
    raw = np.asarray(raw, float)
    _, z, _, rho = mdl.compensate(raw)
    k = mdl.idx.index(sensor - 1)
    u = mdl.U[:, k] / np.linalg.norm(mdl.U[:, k])
    r = sum(u[j] * z[j] for j in range(mdl.df))
    cr = np.concatenate([[0.0], np.cumsum(r)])
    cq = np.concatenate([[0.0], np.cumsum(rho)])
    N = t.shape[0]
    first = np.full(N, False)
    which = np.full(N, -1)
    for w, a, f in zip(thresholds.scales, thresholds.alpha, thresholds.variance_factor,
                       strict=True):
        if w > N:
            continue
        s = cr[w:] - cr[:-w]
        q = cq[w:] - cq[:-w]
        T = chi2_threshold(a, 1) * (1.0 + w * mdl.beta / f + mdl.kappa / f * q)
        al = np.zeros(N, bool)
        al[w - 1:] = s * s / (w * f) > T
        which = np.where(al & ~first, w, which)
        first |= al
    drift = cusum_drift + 3.0 * np.sqrt(mdl.kappa * rho + mdl.beta)
    h = cusum_threshold(thresholds.alpha[0], cusum_drift, 2)
    for sign in (1.0, -1.0):
        S = np.cumsum(sign * r - drift)
        g = S - np.minimum(np.minimum.accumulate(S), 0.0)
        al = g > h
        which = np.where(al & ~first, 0, which)
        first |= al
    pre = int(first[t < onset].sum())
    idx = np.flatnonzero(first & (t >= onset))
    if idx.size == 0:
        return OracleResult(float("inf"), float("inf"), pre, None)
    j = int(idx[0])
    return OracleResult(float(t[j]), float(t[j] - onset), pre, int(which[j]))
