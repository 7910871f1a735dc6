"""Per-segment means and what is left over after the calibration model.

A *segment* is a set of samples whose mean enters the estimators: a whole step, or part of
one (the whole-turn window of an outer-axis step, seed 000 Eq. 20). Means are computed in
one vectorised pass (``np.add.reduceat`` on contiguous runs).

Residuals are the compensated outputs minus the fitted model,
``e_i = SF_i·u_i − b_i − h̃_i·x`` (SI, per sample). From them: the per-sample noise
covariance (n×n), residual statistics per step and the overlapping Allan deviation
(``allantools.oadev``) that the monitor's multi-scale thresholds use.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import allantools
import numpy as np

from fdi.calfile import AllanTable

__all__ = [
    "allan_table",
    "noise_covariance",
    "residual_step_stats",
    "segment_means",
]


def segment_means(seg: np.ndarray, n_seg: int,
                  *columns: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Sample counts and means of several arrays over segments.

    Parameters
    ----------
    seg : ndarray of int, shape (N,)
        Segment id (0..n_seg-1) of each sample; negative ids are ignored.
    n_seg : int
    *columns : ndarray, shape (N,) or (N, m)

    Returns
    -------
    counts : ndarray of int, shape (n_seg,)
    means : list of ndarray, each (n_seg,) or (n_seg, m); NaN for empty segments.
    """
    seg = np.asarray(seg)
    use = seg >= 0
    order = None
    s = seg[use]
    if s.size > 1 and np.any(np.diff(s) < 0):
        order = np.argsort(s, kind="stable")
        s = s[order]
    counts = np.bincount(s, minlength=n_seg)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    nonempty = counts > 0
    means = []
    for col in columns:
        v = np.asarray(col, float)[use]
        if order is not None:
            v = v[order]
        out = np.full((n_seg, *v.shape[1:]), np.nan)
        if v.shape[0]:
            sums = np.add.reduceat(v, starts[nonempty], axis=0)
            out[nonempty] = sums / counts[nonempty].reshape((-1,) + (1,) * (v.ndim - 1))
        means.append(out)
    return counts, means


def noise_covariance(residuals: np.ndarray, dof_used: int = 0) -> np.ndarray:
    """Per-sample noise covariance (n, n) of residuals (N, n), SI².

    ``dof_used`` is the number of fitted parameters per sensor, removed from the divisor.
    """
    r = np.asarray(residuals, float)
    r = r - r.mean(axis=0)
    return (r.T @ r) / max(r.shape[0] - 1 - dof_used, 1)


def residual_step_stats(residuals: np.ndarray, step: np.ndarray,
                        step_numbers: Sequence[int], labels: Sequence[str] = (),
                        kinds: Sequence[str] = ()) -> list[dict[str, Any]]:
    """Mean, RMS and sample count of the residuals of each step.

    Parameters
    ----------
    residuals : ndarray, shape (N, n)
        SI.
    step : ndarray of int, shape (N,)
        1-based step number per sample (0 or negative: not used).
    step_numbers : sequence of int
        Steps to report, in order.

    Returns
    -------
    list of dict
        ``{"step", "label", "kind", "n", "mean": [n], "rms": [n]}`` per step.
    """
    nums = list(step_numbers)
    lookup = {k: j for j, k in enumerate(nums)}
    uniq, inv = np.unique(step, return_inverse=True)
    seg = np.array([lookup.get(int(k), -1) for k in uniq])
    ids = seg[inv]
    r = np.asarray(residuals, float)
    counts, (m, m2) = segment_means(ids, len(nums), r, r**2)
    out = []
    for j, k in enumerate(nums):
        out.append({"step": int(k),
                    "label": labels[j] if j < len(labels) else "",
                    "kind": kinds[j] if j < len(kinds) else "",
                    "n": int(counts[j]),
                    "mean": m[j].tolist(),
                    "rms": np.sqrt(m2[j]).tolist()})
    return out


def allan_table(residuals: np.ndarray, rate_hz: float) -> AllanTable | None:
    """Overlapping Allan deviation of each residual column at octave-spaced τ.

    Uses ``allantools.oadev(x, rate=fs, data_type="freq", taus="octave")`` (rate data).
    Returns None when there are too few samples (< 16).
    """
    r = np.asarray(residuals, float)
    if r.shape[0] < 16:
        return None
    taus, cols = None, []
    for i in range(r.shape[1]):
        t, ad, _, _ = allantools.oadev(r[:, i], rate=rate_hz, data_type="freq", taus="octave")
        if taus is None:
            taus = np.asarray(t, float)
        cols.append(np.asarray(ad, float)[: len(taus)])
    k = min(len(c) for c in cols)
    return AllanTable(tau_s=taus[:k], adev=np.column_stack([c[:k] for c in cols]))
