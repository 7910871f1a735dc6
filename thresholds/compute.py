"""Detection thresholds from a calibration (``rimu.thresholds/2``).

``compute_thresholds`` sets, for a stated false-alarm rate, the threshold of each window
scale of the monitor (:mod:`fdi.detector` holds the arithmetic the runtime shares):

- per-sample false-alarm probability ``alpha = false_alarms_per_hour / (3600 · fs)``,
  split equally over the scales (and the CUSUM bank if used): Bonferroni. Running means
  are correlated in time, so a per-sample share is conservative for long windows.
- threshold of scale w: ``chi2.isf(alpha_w, m − 3)`` on ``D_w = |Σ_w z|²/(w f_w)``.
- ``f_w``: variance of a w-sample mean relative to white noise, from the Allan variance
  of the calibration residuals at τ = w/fs (the calibration file's table, or residuals
  given here, run through ``allantools.oadev``); where the calibration's residual tail
  model fails its normality check, the overbound of the measured tail when larger
  (:mod:`fdi.tails`).
"""

from __future__ import annotations

import allantools
import numpy as np

from fdi.calfile import AllanTable, Calibration
from fdi.detector import default_thresholds
from fdi.errors import ConfigError
from fdi.settings import Thresholds

__all__ = ["allan_from_residuals", "compute_thresholds"]


def allan_from_residuals(residuals: np.ndarray, sample_rate_hz: float) -> AllanTable:
    """Overlapping Allan deviation per sensor of residual rate data (N, n), octave τ.

    Uses ``allantools.oadev(..., data_type="freq", taus="octave")`` (rate data).
    """
    res = np.asarray(residuals, float)
    if res.ndim != 2 or res.shape[0] < 16:
        raise ConfigError("residuals must have shape (N >= 16, n)")
    taus = None
    cols = []
    for i in range(res.shape[1]):
        tau, adev, _, _ = allantools.oadev(res[:, i], rate=sample_rate_hz, data_type="freq",
                                           taus="octave")
        if taus is None:
            taus = tau
        cols.append(adev[:len(taus)])
    return AllanTable(np.asarray(taus, float), np.array(cols).T)


def compute_thresholds(cal: Calibration, *, false_alarms_per_hour: float = 1e-3,
                       kind: str = "gyro", scales: int | tuple[int, ...] = 7,
                       detector: str = "windows", cusum_drift: float = 0.5,
                       missed_detection: float = 1e-3, residuals: np.ndarray | None = None,
                       sample_rate_hz: float | None = None) -> Thresholds:
    """Thresholds for one sensor set of a calibration.

    Parameters
    ----------
    cal : Calibration
    false_alarms_per_hour : float
        Budget of false alarms per hour of healthy operation (default 1e-3).
    kind : str
    scales : int or tuple of int
        K (windows 1, 2, ..., 2^K samples) or explicit window lengths.
    detector : str
        ``"windows"``, ``"cusum"`` (single-sample test plus CUSUM) or ``"both"``.
    cusum_drift : float
        CUSUM allowance ν (whitened σ).
    missed_detection : float
        Missed-detection probability of the protection level.
    residuals : ndarray, shape (N, n), optional
        Healthy residual rate samples (SI) whose Allan variance replaces the calibration's
        table for the variance factors.
    sample_rate_hz : float, optional
        Defaults to the calibration's.

    Returns
    -------
    Thresholds
        Saved with ``.save(path)`` as ``"schema": "rimu.thresholds/2"``.
    """
    if residuals is not None:
        s = cal.kind(kind)
        fs = float(sample_rate_hz or cal.sample_rate_hz)
        table = allan_from_residuals(residuals, fs)
        if table.adev.shape[1] != s.n:
            raise ConfigError(f"residuals have {table.adev.shape[1]} columns for {s.n} sensors")
        from dataclasses import replace

        sets = dict(cal.sets)
        sets[kind] = replace(s, allan=table)
        cal = replace(cal, sets=sets)
    return default_thresholds(cal, kind=kind, false_alarms_per_hour=false_alarms_per_hour,
                              scales=scales, detector=detector, cusum_drift=cusum_drift,
                              missed_detection=missed_detection, sample_rate_hz=sample_rate_hz)
