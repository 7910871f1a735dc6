"""Wavelet denoising of sensor outputs (seed 000, "Wavelet transform").

Seed 000 decomposes the gyro outputs with Daubechies db4 over eight levels at 100 Hz: the
approximation A8 keeps 0 … fs/2⁹ ≈ 0.2 Hz, which holds the Earth-rate modulation of the
outer-axis steps (at the table rate, 10 °/s → 0.028 Hz) and the long-term components, and
drops the high-frequency noise. Built on PyWavelets (``pywt.wavedec`` / ``pywt.waverec``).

Two modes:

- ``"approx"`` (seed 000): keep the approximation only, zero every detail.
- ``"soft"``: keep the approximation and soft-threshold the details with the universal
  threshold ``σ·√(2 ln N)``, ``σ = median(|D1|)/0.6745`` (Donoho-Johnstone).
"""

from __future__ import annotations

import numpy as np
import pywt

__all__ = ["cutoff_hz", "denoise", "denoise_columns"]


def cutoff_hz(sample_rate_hz: float, level: int) -> float:
    """Upper edge of the approximation band at ``level``: ``fs / 2^(level+1)`` (Hz)."""
    return sample_rate_hz / 2.0 ** (level + 1)


def denoise(x: np.ndarray, *, wavelet: str = "db4", level: int = 8,
            mode: str = "approx") -> np.ndarray:
    """Denoise a signal, or each column of a block of signals.

    Parameters
    ----------
    x : ndarray, shape (N,) or (N, m)
        Denoised along axis 0.
    wavelet : str
        PyWavelets name (db4 as seed 000).
    level : int
        Decomposition depth; reduced to ``pywt.dwt_max_level`` for short signals (level 8
        with db4 needs N ≥ 1792).
    mode : {"approx", "soft"}

    Returns
    -------
    ndarray, same shape as ``x``
    """
    x = np.asarray(x, float)
    if mode not in ("approx", "soft"):
        raise ValueError(f"unknown denoising mode {mode!r}; expected 'approx' or 'soft'")
    n = x.shape[0]
    lev = min(level, pywt.dwt_max_level(n, pywt.Wavelet(wavelet).dec_len))
    if lev < 1:
        return x.copy()
    coeffs = pywt.wavedec(x, wavelet, level=lev, axis=0)
    if mode == "approx":
        coeffs = [coeffs[0]] + [np.zeros_like(d) for d in coeffs[1:]]
    else:
        sigma = np.median(np.abs(coeffs[-1]), axis=0) / 0.6745
        thr = sigma * np.sqrt(2.0 * np.log(n))
        coeffs = [coeffs[0]] + [np.sign(d) * np.maximum(np.abs(d) - thr, 0.0)
                                for d in coeffs[1:]]          # pywt.threshold(.., "soft")
    return pywt.waverec(coeffs, wavelet, axis=0)[:n]


def denoise_columns(X: np.ndarray, **kwargs) -> np.ndarray:
    """Alias of :func:`denoise` for (N, m) blocks (kept for readability at call sites)."""
    return denoise(X, **kwargs)
