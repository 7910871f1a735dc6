"""In-flight alignment of each IMU to a reference IMU, with bias and time offset.

For IMU j and the reference IMU r (gyro outputs ``y_j``, ``y_r``, shape (N, 3), rad/s)::

    y_j(t) = A_j·y_r(t + τ_j) + c_j + e_j(t)

``A_j`` (3×3) is the relative gain matrix: with ``A = I + E`` its antisymmetric part is the
misalignment rotation θ (``A ≈ I + [θ]×``), its diagonal the scale-factor differences and its
symmetric off-diagonal part the non-orthogonality; ``c_j`` the relative bias (``b_j − A·b_r``)
and ``τ_j`` the time offset of IMU j against the reference. The reference is read between
its samples through a cubic spline and the fit is Gauss–Newton in τ (each step is linear
least squares with the regressor ``A·ẏ_r``, the angular acceleration seen by IMU j), with the
HAC covariance of :mod:`calibration.inflight.regression`.

Models: ``full`` (A free: 9 parameters), ``rotation`` (A = I + [θ]×: scale and
non-orthogonality taken equal to the reference's). ``auto`` fits ``full`` when the motion
excites it and falls back to ``rotation`` otherwise.

Excitation check (before any number is trusted): for every parameter, the variance
inflation factor of its centred regressor (from the rank and condition of the design)
must stay below :data:`VIF_MAX`, and its regressor must vary by at least
:data:`EXCITATION_MIN` times the noise it carries (rates against the reference noise,
angular acceleration against the noise of the differentiated reference); otherwise the
parameter is not separable and :class:`~fdi.errors.CalibrationError` names it.

Errors in the reference (its noise enters the regressors) bias A towards zero by
``Σ_r·S_zz⁻¹``; the fit corrects that to first order with ``Σ_r`` taken as half the
residual covariance (two IMUs of equal noise).
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import ndimage
from scipy.interpolate import CubicSpline

from calibration.inflight.jitter import JitterFit, fit_timing_jitter
from calibration.inflight.offset_check import check_offset
from calibration.inflight.regression import StackedFit, stacked_lstsq
from calibration.inflight.segments import Segment, find_segments, keep_mask
from fdi.errors import CalibrationError, ConfigError
from fdi.extras import OffsetCheck
from replay.flight_data import Flight

__all__ = ["EXCITATION_MIN", "MODELS", "VIF_MAX", "Excitation", "ImuAlignment",
           "InflightFit", "decompose", "fit_inflight", "fit_pair", "imu_rates"]

VIF_MAX = 1e3
"""Largest variance inflation factor of a parameter that is still separable."""
EXCITATION_MIN = 10.0
"""Smallest ratio of a regressor's RMS variation to the noise it carries."""
MODELS = ("auto", "full", "rotation")
_GN_ITER = 6
_EDGE = 3
"""Samples left out on each side of a dropped block (the spline bridges it)."""
_AXES = "xyz"


@dataclass(frozen=True)
class Excitation:
    """How well the flight excites each parameter of one fit.

    Attributes
    ----------
    names : tuple of str
    ratio : ndarray
        RMS variation of each regressor over the noise it carries.
    vif : ndarray
        Variance inflation factor of each parameter.
    condition : float
        Condition number of the standardised design (centred, unit-norm columns).
    rank : int
        Numerical rank of that design.
    """

    names: tuple[str, ...]
    ratio: np.ndarray
    vif: np.ndarray
    condition: float
    rank: int

    def failures(self) -> list[str]:
        """One reason per parameter that is not separable."""
        out = []
        for n, r, v in zip(self.names, self.ratio, self.vif, strict=True):
            if not r >= EXCITATION_MIN:
                out.append(f"{n}: its regressor varies by {r:.3g}x its noise "
                           f"(need >= {EXCITATION_MIN:g}x)")
            elif not v <= VIF_MAX:
                out.append(f"{n}: not separable from the other parameters (variance "
                           f"inflation {v:.3g} > {VIF_MAX:g}, design condition "
                           f"{self.condition:.3g}, rank {self.rank} of {len(self.names)})")
        return out

    def to_dict(self) -> dict[str, object]:
        """JSON-ready."""
        return {"parameters": list(self.names), "ratio": self.ratio.tolist(),
                "variance_inflation": self.vif.tolist(), "condition": self.condition,
                "rank": self.rank, "ratio_min": EXCITATION_MIN, "vif_max": VIF_MAX}


@dataclass(frozen=True, eq=False)
class ImuAlignment:
    """In-flight calibration of one IMU against the reference (SI).

    Attributes
    ----------
    imu : str
    model : str
        ``"full"`` or ``"rotation"``.
    A : ndarray, shape (3, 3)
    A_cov : ndarray, shape (9, 9)
        Covariance of ``A.ravel()`` (row-major).
    c : ndarray, shape (3,)
        Relative bias (rad/s).
    c_cov : ndarray, shape (3, 3)
    time_offset_s, time_offset_sd_s : float
        τ (NaN and 0 when not fitted).
    timing_jitter_s, timing_jitter_sd_s : float
        Sd of the random sampling-time error against the reference and its sd (s), from the
        residual's growth with the angular acceleration (:mod:`calibration.inflight.jitter`).
    residual : ndarray, shape (N, 3)
        ``y_j − A·y_r(t+τ) − c`` on the samples used, NaN elsewhere (rad/s).
    lags : int
        Newey–West lag of the covariance.
    excitation : Excitation
    notes : tuple of str
    check : OffsetCheck or None
        How far the offset's sd holds (:func:`calibration.inflight.offset_check.check_offset`):
        HAC, block-bootstrap and piece sds, the piece-consistency test; None when τ is
        not fitted. ``time_offset_sd_s`` is the largest of those sds.
    """

    imu: str
    model: str
    A: np.ndarray
    A_cov: np.ndarray
    c: np.ndarray
    c_cov: np.ndarray
    time_offset_s: float
    time_offset_sd_s: float
    residual: np.ndarray
    lags: int
    excitation: Excitation
    notes: tuple[str, ...] = ()
    check: OffsetCheck | None = None
    timing_jitter_s: float = 0.0
    timing_jitter_sd_s: float = 0.0

    @property
    def offset_check(self) -> dict[str, object]:
        """:attr:`check` as the file writes it (ms; empty when τ is not fitted)."""
        return {} if self.check is None else self.check.to_dict()

    def parts(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Rotation, scale and non-orthogonality of A with their sds (rad, fraction)."""
        return decompose(self.A, self.A_cov)


@dataclass(frozen=True, eq=False)
class InflightFit:
    """Alignment of every IMU of a flight to the reference.

    Attributes
    ----------
    reference : str
    imus : tuple of str
        All IMU groups in flight order.
    alignments : dict of str to ImuAlignment
        One per IMU other than the reference.
    used : ndarray of bool, shape (N,)
        Samples the fit used.
    nonfinite : int
        Samples outside the left-out segments left out for a non-finite rate in some IMU.
    left_out : tuple of Segment
    sample_rate_hz : float
    source : str
    """

    reference: str
    imus: tuple[str, ...]
    alignments: dict[str, ImuAlignment]
    used: np.ndarray
    left_out: tuple[Segment, ...]
    sample_rate_hz: float
    source: str = ""
    extra: dict[str, object] = field(default_factory=dict)
    nonfinite: int = 0


def _decomposition_matrix() -> np.ndarray:
    """T (9×9): (θx, θy, θz, sx, sy, sz, nxy, nxz, nyz) = T·vec(A − I)."""
    T = np.zeros((9, 9))

    def ix(i: int, j: int) -> int:
        return 3 * i + j

    T[0, ix(2, 1)], T[0, ix(1, 2)] = 0.5, -0.5
    T[1, ix(0, 2)], T[1, ix(2, 0)] = 0.5, -0.5
    T[2, ix(1, 0)], T[2, ix(0, 1)] = 0.5, -0.5
    T[3, ix(0, 0)] = T[4, ix(1, 1)] = T[5, ix(2, 2)] = 1.0
    T[6, ix(0, 1)] = T[6, ix(1, 0)] = 0.5
    T[7, ix(0, 2)] = T[7, ix(2, 0)] = 0.5
    T[8, ix(1, 2)] = T[8, ix(2, 1)] = 0.5
    return T


def decompose(A: np.ndarray, A_cov: np.ndarray | None = None
              ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Small-angle parts of a relative gain matrix and their sds.

    Returns
    -------
    dict
        ``"rotation"`` (θ, rad), ``"scale"`` (diagonal of A − I), ``"nonorthogonality"``
        (xy, xz, yz); each ``(value (3,), sd (3,))``.
    """
    T = _decomposition_matrix()
    v = T @ (np.asarray(A, float) - np.eye(3)).ravel()
    C = np.zeros((9, 9)) if A_cov is None else T @ A_cov @ T.T
    sd = np.sqrt(np.clip(np.diag(C), 0, None))
    return {"rotation": (v[0:3], sd[0:3]), "scale": (v[3:6], sd[3:6]),
            "nonorthogonality": (v[6:9], sd[6:9])}


IMPLAUSIBLE_RAW = 1e12
"""A raw gyro value beyond this magnitude is no measurement (no sensor counts to 10¹² in
any unit; squared, 1e308 overflows): it is left out of the fit like a missing one."""


def imu_rates(flight: Flight) -> dict[str, np.ndarray]:
    """The gyro samples of each IMU group, shape (N, 3) each, in x, y, z order; values
    beyond :data:`IMPLAUSIBLE_RAW` become NaN (counted in one warning)."""
    if flight.kind != "gyro":
        raise ConfigError(f"{flight.source}: in-flight calibration needs gyros, the flight "
                          f"monitors {flight.kind}")
    groups = flight.imu_groups()
    if len(groups) < 2:
        raise ConfigError(f"{flight.source}: in-flight calibration needs at least two IMU "
                          f"groups (manifest 'imu'), found {len(groups)}")
    out = {}
    for g, idx in groups.items():
        if len(idx) != 3:
            raise ConfigError(f"{flight.source}: IMU {g} has {len(idx)} gyro axes, "
                              f"expected 3")
        r = np.asarray(flight.raw[:, idx], float)
        huge = np.isfinite(r) & (np.abs(r) > IMPLAUSIBLE_RAW)
        if huge.any():
            rows = int(np.count_nonzero(huge.any(axis=1)))
            logging.getLogger("rimu.inflight").warning(
                f"{flight.source}: IMU {g}: {rows} row{'s' * (rows != 1)} with values beyond "
                f"{IMPLAUSIBLE_RAW:g} (no measurement) left out of the fit")
            r = np.where(huge, np.nan, r)
        out[g] = r
    return out


def _centred_ratio(col: np.ndarray, noise: float) -> float:
    v = float(np.std(col))
    return v / noise if noise > 0 else math.inf


def _excitation(X: np.ndarray, names: list[str], const: list[int], noise: np.ndarray
                ) -> Excitation:
    """Excitation of the non-constant parameters of a stacked design (N, m, p)."""
    keep = [i for i in range(X.shape[2]) if i not in const]
    Z = X[:, :, keep] - X[:, :, keep].mean(axis=0, keepdims=True)
    Zf = Z.reshape(-1, len(keep))
    norm = np.linalg.norm(Zf, axis=0)
    ratio = np.array([_centred_ratio(Z[:, int(np.argmax(np.std(Z[:, :, k], axis=0))), k],
                                     float(noise[k])) for k in range(len(keep))])
    with np.errstate(invalid="ignore", divide="ignore"):
        S = Zf / np.where(norm > 0, norm, 1.0)
    sv = np.linalg.svd(S, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    rank = int(np.sum(sv > sv[0] * 1e-10)) if sv[0] > 0 else 0
    try:
        vif = np.diag(np.linalg.inv(S.T @ S)) if rank == len(keep) else \
            np.full(len(keep), math.inf)
    except np.linalg.LinAlgError:
        vif = np.full(len(keep), math.inf)
    vif = np.where(norm > 0, vif, math.inf)
    return Excitation(tuple(names[i] for i in keep), ratio, np.abs(vif), cond, rank)


def _design(model: str, z: np.ndarray, dz: np.ndarray, A: np.ndarray, with_tau: bool
            ) -> tuple[np.ndarray, list[str], list[int]]:
    """Stacked design (N, 3, p), parameter names and the constant columns."""
    N = z.shape[0]
    if model == "full":
        p = 12 + with_tau
        X = np.zeros((N, 3, p))
        for k in range(3):
            X[:, k, 3 * k:3 * k + 3] = z
            X[:, k, 9 + k] = 1.0
        names = [f"A[{_AXES[k]},{_AXES[m]}]" for k in range(3) for m in range(3)]
        const = [9, 10, 11]
    elif model == "fixed":                           # gain held: bias (and τ) only
        p = 3 + with_tau
        X = np.zeros((N, 3, p))
        for k in range(3):
            X[:, k, k] = 1.0
        names, const = [], [0, 1, 2]
    else:
        p = 6 + with_tau
        X = np.zeros((N, 3, p))
        # A = I + [θ]×:  [θ]× z = −[z]× θ
        X[:, 0, 1], X[:, 0, 2] = z[:, 2], -z[:, 1]
        X[:, 1, 0], X[:, 1, 2] = -z[:, 2], z[:, 0]
        X[:, 2, 0], X[:, 2, 1] = z[:, 1], -z[:, 0]
        for k in range(3):
            X[:, k, 3 + k] = 1.0
        names = [f"rotation about {a}" for a in _AXES]
        const = [3, 4, 5]
    names += [f"bias {a}" for a in _AXES]
    if with_tau:
        X[:, :, -1] = dz @ A.T
        names.append("time offset")
    return X, names, const


def fit_pair(t: np.ndarray, y_ref: np.ndarray, y: np.ndarray, used: np.ndarray, *,
             model: str = "full", time_offset: bool = True, label: str = "imu",
             sample_rate_hz: float | None = None, check: bool = True,
             gain: np.ndarray | None = None, jitter: bool = True) -> ImuAlignment:
    """Fit ``y = A·y_ref(t+τ) + c`` on the samples ``used`` (module docstring).

    Parameters
    ----------
    t : ndarray, shape (N,)
    y_ref, y : ndarray, shape (N, 3)
        Reference and IMU gyro outputs (rad/s).
    used : ndarray of bool, shape (N,)
    model : str
        ``"full"`` or ``"rotation"``.
    time_offset : bool
        Fit τ (otherwise τ = 0).
    label : str
        IMU name for messages.
    check : bool
        With ``time_offset``: check how far τ's sd holds (block bootstrap, independently
        fitted pieces, :mod:`calibration.inflight.offset_check`) and report the largest sd.
    gain : ndarray, shape (3, 3), optional
        With ``model="fixed"``: the gain A held fixed (only c and τ are fitted; used for
        the pieces of the consistency check that do not excite A on their own).
    jitter : bool
        Estimate the timing jitter from the residual (:mod:`calibration.inflight.jitter`;
        the pieces of the consistency check skip it: 0).

    Raises
    ------
    CalibrationError
        Naming the first parameter the motion does not excite.
    """
    fs = float(sample_rate_hz or (1.0 / np.median(np.diff(t))))
    ok = used & np.all(np.isfinite(y_ref), axis=1) & np.all(np.isfinite(y), axis=1)
    if ok.sum() < 50:
        raise CalibrationError(f"{label}: only {int(ok.sum())} usable samples (need 50)")
    # rows next to a dropped block read a spline that bridges it: leave them out too
    core = ok & ndimage.binary_erosion(ok, structure=np.ones(2 * _EDGE + 1, bool),
                                       border_value=True)
    tau = 0.0
    A = np.eye(3) if gain is None else np.asarray(gain, float)
    fit = None
    tt = t[ok]
    spline = CubicSpline(tt, y_ref[ok], axis=0)
    Sr = np.zeros((3, 3))
    for _ in range(_GN_ITER if time_offset else 2):
        inside = (tt + tau >= tt[0]) & (tt + tau <= tt[-1]) & core[ok]
        z = spline(tt + tau)
        dz = spline(tt + tau, 1)
        X, names, const = _design(model, z, dz, A, time_offset)
        Y = y[ok] - (z if model == "rotation" else z @ A.T if model == "fixed" else 0.0)
        fit = stacked_lstsq(X[inside], Y[inside])
        fit = _debias(fit, X[inside], model, A, Sr, (tau * fs) % 1.0, fs, time_offset)
        Sr = np.cov(fit.residual.T) / 2              # reference noise: half the residual
        A = A if model == "fixed" else _gain(model, fit.beta)
        if time_offset:
            step = float(fit.beta[-1])
            tau += step
            if abs(step) < 1e-3 * max(fit.sd[-1], 1e-9):
                break
    res_sd = np.std(fit.residual, axis=0)
    noise = float(np.sqrt(np.mean(res_sd**2) / 2))
    zn = np.full(X.shape[2], noise)
    if time_offset:
        zn[-1] = noise * fs                          # noise of the differentiated reference
    exc = _excitation(X[inside], names, const, zn)
    bad = exc.failures()
    if bad:
        raise CalibrationError(f"{label}: the flight does not excite {bad[0]}")
    notes = []
    beta, cov = fit.beta.copy(), fit.cov.copy()
    notes.append("corrected for the reference noise in the regressors (first order, "
                 "reference noise taken as half the residual covariance)")
    if model == "full":
        A_cov = cov[:9, :9]
        ci = slice(9, 12)
    elif model == "fixed":
        A_cov = np.zeros((9, 9))
        ci = slice(0, 3)
    else:
        T = np.zeros((9, 3))                         # vec([θ]×) = T·θ
        T[7, 0], T[5, 0] = 1.0, -1.0
        T[2, 1], T[6, 1] = 1.0, -1.0
        T[3, 2], T[1, 2] = 1.0, -1.0
        A_cov = T @ cov[:3, :3] @ T.T
        ci = slice(3, 6)
    residual = np.full(y.shape, np.nan)
    rows = np.flatnonzero(ok)[inside]
    residual[rows] = fit.residual
    sd_tau = float(fit.sd[-1]) if time_offset else 0.0
    chk: OffsetCheck | None = None
    if time_offset and check:
        fitted = np.zeros(t.shape[0], bool)
        fitted[rows] = True

        def piece(mask: np.ndarray) -> tuple[float, float, str]:
            kw = dict(time_offset=True, label=label, sample_rate_hz=fs, check=False,
                      jitter=False)
            try:
                a = fit_pair(t, y_ref, y, mask, model=model, **kw)
            except CalibrationError as exc:
                if "time offset" in str(exc) or "bias" in str(exc) or model == "fixed":
                    raise
                a = fit_pair(t, y_ref, y, mask, model="fixed", gain=A, **kw)
            return a.time_offset_s, a.time_offset_sd_s, a.model

        chk = check_offset(t, fitted, X[inside], fit.residual, sd_tau, fs, piece)
        sd_tau = 1e-3 * (1e3 * chk.sd_s)        # through the file's ms, as written
    # timing jitter: the residual against the angular acceleration IMU j sees, A·ω̇_ref
    jit = (fit_timing_jitter(fit.residual, dz[inside] @ A.T, lags=fit.lags) if jitter
           else JitterFit(0.0, 0.0, 0.0, 0.0, np.zeros((3, 3)), 0))
    return ImuAlignment(imu=label, model=model, A=A, A_cov=A_cov, c=beta[ci],
                        c_cov=cov[ci, ci],
                        time_offset_s=tau if time_offset else 0.0,
                        time_offset_sd_s=sd_tau,
                        residual=residual, lags=fit.lags, excitation=exc, notes=tuple(notes),
                        check=chk, timing_jitter_s=jit.tau_s,
                        timing_jitter_sd_s=jit.tau_sd_s)


@functools.lru_cache(maxsize=64)
def _spline_noise(frac: float) -> tuple[float, float]:
    """(v, κ) of cubic-spline-interpolated white noise at fractional position ``frac``.

    ``Var ñ = v·σ²`` and ``E[ñ·dñ/dk] = κ·σ²`` (per sample) for unit white noise σ.
    """
    n = 201
    k = n // 2
    sp = CubicSpline(np.arange(n, dtype=float), np.eye(n), axis=0)
    v = sp(k + frac)
    d = sp(k + frac, 1)
    return float(v @ v), float(v @ d)


def _debias(fit: StackedFit, X: np.ndarray, model: str, A: np.ndarray, Sr: np.ndarray,
            frac: float, fs: float, with_tau: bool) -> StackedFit:
    """Remove the first-order bias of the reference noise in the regressors.

    The reference's noise ñ enters both the regressors (ẑ = z + ñ, its derivative) and the
    error (−A·ñ), so ``E[Xᵀe] = m ≠ 0``: for the gain columns ``−N·v·(A Σ_r)_kl``
    (attenuation), for the time column ``−N·κ·fs·tr(A Σ_r Aᵀ)`` (the interpolated noise
    and its derivative are correlated between samples). β̂ − M⁻¹·m removes it.
    """
    if not np.any(Sr):
        return fit
    v, kappa = _spline_noise(round(float(frac), 3))
    N = X.shape[0]
    p = X.shape[2]
    mom = np.zeros(p)
    if model == "full":
        mom[:9] = -N * v * (A @ Sr).ravel()
    if with_tau:
        mom[-1] = -N * kappa * fs * float(np.trace(A @ Sr @ A.T))
    Xf = X.reshape(-1, p)
    corr = np.linalg.solve(Xf.T @ Xf, mom)
    return StackedFit(fit.beta - corr, fit.cov, fit.residual, fit.lags, fit.cov_white)


def _gain(model: str, beta: np.ndarray) -> np.ndarray:
    if model == "full":
        return beta[:9].reshape(3, 3)
    th = beta[:3]
    return np.eye(3) + np.array([[0.0, -th[2], th[1]], [th[2], 0.0, -th[0]],
                                 [-th[1], th[0], 0.0]])


def fit_inflight(flight: Flight, *, reference: str | None = None, model: str = "auto",
                 time_offset: bool = True) -> InflightFit:
    """Align every IMU of a flight to the reference IMU.

    Parameters
    ----------
    flight : Flight
        Gyro flight with IMU groups of three axes.
    reference : str, optional
        IMU group of the reference (default: the first).
    model : str
        ``"auto"``, ``"full"`` or ``"rotation"``.
    time_offset : bool

    Raises
    ------
    ConfigError
        Unknown reference or model, fewer than two IMUs.
    CalibrationError
        The flight does not excite a parameter (the message names it).
    """
    if model not in MODELS:
        raise ConfigError(f"model {model!r} is not one of {MODELS}")
    rates = imu_rates(flight)
    ref = reference or next(iter(rates))
    if ref not in rates:
        raise ConfigError(f"reference {ref!r} is not an IMU of {flight.source} "
                          f"(IMUs: {', '.join(rates)})")
    segs = find_segments(flight)
    kept = keep_mask(flight.t, segs)
    # a sample with a non-finite rate in any IMU is left out of every pair, and counted
    finite = np.all([np.all(np.isfinite(r), axis=1) for r in rates.values()], axis=0)
    used = kept & finite
    try:
        out = _fit_all(flight, rates, ref, used, model, time_offset)
    except CalibrationError as exc:
        raise CalibrationError(f"{flight.source}: {exc}") from None
    return InflightFit(reference=ref, imus=tuple(rates), alignments=out, used=used,
                       left_out=tuple(segs), sample_rate_hz=flight.sample_rate_hz,
                       source=flight.source, nonfinite=int((kept & ~finite).sum()))


def _fit_all(flight: Flight, rates: dict[str, np.ndarray], ref: str, used: np.ndarray,
             model: str, time_offset: bool) -> dict[str, ImuAlignment]:
    out = {}
    for g, y in rates.items():
        if g == ref:
            continue
        kw = dict(time_offset=time_offset, label=g, sample_rate_hz=flight.sample_rate_hz)
        if model == "auto":
            try:
                out[g] = fit_pair(flight.t, rates[ref], y, used, model="full", **kw)
            except CalibrationError as exc:
                if "time offset" in str(exc) or "bias" in str(exc):
                    raise
                a = fit_pair(flight.t, rates[ref], y, used, model="rotation", **kw)
                out[g] = replace(a, notes=(*a.notes, (
                    f"scale factors and non-orthogonality not fitted ({exc}); taken equal "
                    f"to the reference's")))
        else:
            out[g] = fit_pair(flight.t, rates[ref], y, used, model=model, **kw)
    return out
