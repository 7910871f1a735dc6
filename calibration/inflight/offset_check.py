"""How far the time offset of an in-flight fit holds: beyond one calm stretch, or not.

The HAC sd of the fitted offset τ (:mod:`.regression`) holds when the residual's
correlation dies out within the Newey–West lag and the offset is one number for the whole
flight. A flight breaks both: manoeuvres, vibration and shocks change the residual's
colour from one stretch to the next, and the lag between two IMUs' samples can move
(scheduling, buffering). Two checks that do not rest on those assumptions:

- **Block bootstrap** (moving blocks of :data:`BLOCK_S` seconds of the fit's scores
  ``s_t = Σ_c X[t, c, :]·e[t, c]``; the fit is linear at convergence, so
  ``β̂* − β̂ = M⁻¹·Σ s*_t``): the sd of τ when the residual is correlated over seconds.
- **Independent pieces**: the used samples are cut into :data:`PIECES` contiguous pieces
  of equal size (fewer when a piece would be shorter than :data:`PIECE_MIN_S`), each
  fitted on its own (same model, its own HAC sd; a piece whose motion does not excite the
  gain matrix on its own is fitted with the whole flight's gain held and its own bias
  and τ). Their weighted mean
  ``τ̄`` and ``χ² = Σ (τ_k − τ̄)²/σ_k²`` on ``K − 1`` degrees of freedom test whether one
  offset explains every piece; the external sd of the mean
  ``σ_ext = σ_int·sqrt(χ²/dof)`` (``σ_int = (Σ 1/σ_k²)^(-1/2)``) is the scatter of the
  pieces, and is larger than σ_int exactly when the pieces disagree.

The offset's reported sd is the largest of the HAC, bootstrap and piece-scatter sds; when
the consistency test fails (p < :data:`CONSISTENCY_ALPHA`) the output says the offset varies
within the flight, and the sd carries that variation (σ_ext). Either way the offset belongs
to the flight it was fitted on.

Sign convention (the in-flight model ``y_j(t) = A_j·y_ref(t + τ_j) + c_j``): IMU j's sample
at time t matches the reference's at ``t + τ_j``; ``τ_j < 0`` means IMU j sees the motion
``|τ_j|`` later than the reference (it lags).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from scipy import stats

from fdi.extras import OffsetCheck, OffsetConsistency, OffsetPiece, offset_check_from_dict
from fdi.units import MS

__all__ = ["BLOCK_S", "CONSISTENCY_ALPHA", "PIECES", "PIECE_MIN_S", "SIGN_CONVENTION",
           "block_bootstrap_sd", "check_lines", "check_offset", "consistency"]

BLOCK_S = 4.0
"""Length (s) of the moving blocks of the bootstrap (several manoeuvres long)."""
PIECES = 6
"""Number of contiguous pieces the used samples are cut into for the consistency test."""
PIECE_MIN_S = 5.0
"""Shortest piece (s of used samples): fewer pieces when the flight is short (the HAC sd of
a shorter piece rests on too few lags to be trusted)."""
CONSISTENCY_ALPHA = 0.01
"""Level of the piece-consistency χ² test."""
_N_BOOT = 400
SIGN_CONVENTION = ("time offset τ: IMU j's sample at t matches the reference's at t + τ; "
                   "τ < 0 means IMU j sees the motion |τ| later than the reference")
"""One line stating the sign of every time offset rimu prints."""


def block_bootstrap_sd(X: np.ndarray, e: np.ndarray, block: int, *, n_boot: int = _N_BOOT,
                       seed: int = 0) -> np.ndarray:
    """Moving-block bootstrap sd of linear least-squares parameters.

    Parameters
    ----------
    X : ndarray, shape (N, m, p)
        Design of the fit (times, channels, parameters).
    e : ndarray, shape (N, m)
        Residual at the estimate.
    block : int
        Block length (samples).
    n_boot : int
    seed : int

    Returns
    -------
    ndarray, shape (p,)
        Standard deviation of each parameter over the bootstrap replicates.
    """
    N, _, p = X.shape
    s = np.einsum("tcp,tc->tp", X, e, optimize=True)
    s = s - s.mean(axis=0)
    b = int(min(max(block, 1), N))
    nb = max(1, math.ceil(N / b))
    c = np.vstack([np.zeros((1, p)), np.cumsum(s, axis=0)])
    sums = c[b:] - c[:-b]                                   # (N - b + 1, p) block sums
    rng = np.random.default_rng(seed)
    starts = rng.integers(0, sums.shape[0], size=(n_boot, nb))
    S = sums[starts].sum(axis=1) * (N / (nb * b))           # (n_boot, p)
    Xf = X.reshape(-1, p)
    Minv = np.linalg.pinv(Xf.T @ Xf)
    d = S @ Minv.T
    return np.std(d, axis=0, ddof=1)


def consistency(tau: np.ndarray, sd: np.ndarray) -> dict[str, float]:
    """Weighted mean of piece offsets and the χ² test that they are one number.

    Parameters
    ----------
    tau, sd : ndarray, shape (K,)
        Offsets (s) and their sds.

    Returns
    -------
    dict
        ``mean_s``, ``sd_internal_s``, ``sd_external_s``, ``chi2``, ``dof``,
        ``chi2_dof``, ``p_value``.
    """
    tau = np.asarray(tau, float)
    sd = np.asarray(sd, float)
    w = 1.0 / sd**2
    m = float(np.sum(w * tau) / np.sum(w))
    chi2 = float(np.sum(w * (tau - m) ** 2))
    dof = max(tau.size - 1, 1)
    s_int = float(1.0 / math.sqrt(np.sum(w)))
    return {"mean_s": m, "sd_internal_s": s_int,
            "sd_external_s": s_int * math.sqrt(chi2 / dof), "chi2": chi2, "dof": dof,
            "chi2_dof": chi2 / dof, "p_value": float(stats.chi2.sf(chi2, dof))}


def check_offset(t: np.ndarray, used: np.ndarray, X: np.ndarray, e: np.ndarray,
                 sd_hac_s: float, fs: float,
                 fit_piece: Callable[[np.ndarray], tuple[float, float]], *,
                 pieces: int = PIECES) -> OffsetCheck:
    """The sds of a fitted offset and the piece-consistency test (module docstring).

    Parameters
    ----------
    t : ndarray, shape (N,)
    used : ndarray of bool, shape (N,)
        Rows the whole-flight fit used.
    X, e : ndarray
        Design (n_used, m, p) with τ in the last column, and residual (n_used, m), of the
        whole-flight fit at convergence.
    sd_hac_s : float
        HAC sd of τ.
    fs : float
        Sample rate (Hz).
    fit_piece : callable
        ``fit_piece(mask (N,) bool) -> (τ, sd, model)`` fits the model on a piece (the
        whole flight's gain held fixed, model ``"fixed"``, where the piece alone does not
        excite it); may raise :class:`~fdi.errors.CalibrationError` (the piece is then
        left out, with the reason).
    pieces : int

    Returns
    -------
    OffsetCheck
        ``sd_s`` (the one to report), the HAC, bootstrap and piece sds, the block length,
        the pieces, ``consistency`` (χ² test, or None with fewer than two pieces),
        ``consistent``, ``widened``, ``sign`` (:class:`fdi.extras.OffsetCheck`; its
        ``to_dict()`` is the file's ``time_offset_check``, in ms).
    """
    from fdi.errors import CalibrationError

    block = max(1, round(BLOCK_S * fs))
    sd_boot = float(block_bootstrap_sd(X, e, block)[-1])
    rows = np.flatnonzero(used)
    k = min(pieces, int(rows.size // max(PIECE_MIN_S * fs, 1)))
    out_p = []
    for chunk in np.array_split(rows, k) if k >= 2 else []:
        m = np.zeros(t.shape[0], bool)
        m[chunk] = True
        m &= used
        t0, t1 = float(t[chunk[0]]), float(t[chunk[-1]])
        try:
            tau_k, sd_k, model_k = fit_piece(m)
        except CalibrationError as exc:
            out_p.append(OffsetPiece(t0, t1, None, None, note=str(exc)))
            continue
        out_p.append(OffsetPiece(t0, t1, tau_k, sd_k, model=model_k))
    good = [q for q in out_p if q.offset_s is not None and q.sd_s > 0]
    cons = None
    sd_piece = 0.0
    ok = True
    if len(good) >= 2:
        # from the pieces' offsets in ms, as the file holds them (1e3·τ, then back)
        c = consistency(np.array([1e3 * q.offset_s for q in good]) * 1e-3,
                        np.array([1e3 * q.sd_s for q in good]) * 1e-3)
        cons = OffsetConsistency(
            mean_s=c["mean_s"], sd_internal_s=c["sd_internal_s"],
            sd_external_s=c["sd_external_s"], chi2=c["chi2"], dof=c["dof"],
            chi2_dof=c["chi2_dof"], p_value=c["p_value"], alpha=CONSISTENCY_ALPHA,
            pieces_used=len(good))
        sd_piece = c["sd_external_s"]
        ok = c["p_value"] >= CONSISTENCY_ALPHA
    sd = max(sd_hac_s, sd_boot, sd_piece)
    return OffsetCheck(sd_s=sd, sd_hac_s=sd_hac_s, sd_bootstrap_s=sd_boot, sd_pieces_s=sd_piece,
                       block_s=block / fs, pieces=tuple(out_p), consistency=cons, consistent=ok,
                       widened=sd > sd_hac_s, sign=SIGN_CONVENTION)


def check_lines(chk: OffsetCheck | Mapping[str, Any] | None) -> list[str]:
    """Readable lines of an offset's checks: :func:`check_offset`'s result, or the same as
    the calibration file keeps it (:attr:`fdi.extras.ImuTiming.check`)."""
    if isinstance(chk, Mapping):
        chk = offset_check_from_dict(chk)
    if chk is None:
        return []
    lines = [f"offset sd {chk.sd_s / MS:.3f} ms = max(HAC {chk.sd_hac_s / MS:.3f}, block "
             f"bootstrap {chk.sd_bootstrap_s / MS:.3f} ({chk.block_s:g}-s blocks), piece "
             f"scatter {chk.sd_pieces_s / MS:.3f})"]
    c = chk.consistency
    good = [q.offset_s / MS for q in chk.pieces if q.offset_s is not None]
    if c is not None and good:
        lo, hi = min(good), max(good)
        if chk.consistent:
            lines.append(f"the offset is consistent over {c.pieces_used} pieces of the "
                         f"flight: {lo:+.2f} to {hi:+.2f} ms, chi2/dof {c.chi2_dof:.2f} "
                         f"(p={c.p_value:.2g})")
        else:
            lines.append(f"the offset varies within this flight: {lo:+.2f} to {hi:+.2f} ms "
                         f"over {c.pieces_used} pieces, chi2/dof {c.chi2_dof:.2f} "
                         f"(p={c.p_value:.2g}); the sd carries that scatter"
                         + (" (widened)" if chk.sd_s > chk.sd_hac_s else ""))
    else:
        lines.append("piece-consistency test not possible (fewer than two pieces fitted)")
    lines.append("the offset belongs to this flight: another flight of the same airframe "
                 "may lag differently")
    return lines

