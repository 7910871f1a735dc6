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
import itertools
import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import ndimage
from scipy.interpolate import CubicSpline

from calibration.inflight.jitter import JitterFit, fit_timing_jitter
from calibration.inflight.offset_check import check_offset
from calibration.inflight.prior import PARAMETERS, Prior, mounting_text, nearest_mounting
from calibration.inflight.regression import StackedFit, stacked_lstsq, stacked_ridge
from calibration.inflight.segments import Segment, find_segments, keep_mask
from fdi.errors import CalibrationError, ConfigError
from fdi.extras import OffsetCheck
from replay.flight_data import Flight

__all__ = ["ESTIMATED", "EXCITATION_MIN", "FINDING_RATIO", "HELD", "INFORMED", "MODELS",
           "TAU_EXCITATION_MIN", "VIF_MAX", "AxisFinding", "Excitation", "ImuAlignmentFit",
           "InflightFit",
           "ParameterStatus", "axis_noise", "decompose", "fit_inflight", "fit_pair",
           "fit_pair_prior", "imu_rates"]

VIF_MAX = 1e3
"""Largest variance inflation factor of a parameter that is still separable."""
EXCITATION_MIN = 10.0
"""Smallest ratio of a regressor's RMS variation to the noise it carries."""
MODELS = ("auto", "full", "rotation")
TAU_EXCITATION_MIN = 3.0
"""Smallest ratio for the time offset (with the prior): the errors-in-variables bias of a
coefficient is a fraction ``1/(1 + ratio²)`` of the coefficient itself; a gain is near 1,
so 1 % of it (ratio 10) is a 10,000 ppm scale error, while the time offset is small
itself, and 10 % of it (ratio 3) lies within its sd before the first-order correction."""
FINDING_RATIO = 3.0
"""An IMU axis whose own noise exceeds this many times the median of the same body axis on
the other IMUs is a finding (vibration, a loose mount, a failing sensor)."""
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


ESTIMATED = "estimated"
HELD = "held at prior"
INFORMED = 0.5
"""A parameter counts as estimated when its posterior sd is at most this fraction of its
prior sd (the data carry at least three times the prior's information)."""


@dataclass(frozen=True)
class ParameterStatus:
    """One parameter of an alignment: its value, sd, prior sd and whether the flight
    estimated it or it stays at the prior.

    Attributes
    ----------
    name : str
        :data:`calibration.inflight.prior.PARAMETERS` or ``"time offset"``.
    value, sd, prior_sd : float
        rad, fraction or s.
    status : str
        :data:`ESTIMATED` or :data:`HELD`.
    excitation : float
        RMS variation of its regressor over the reference noise on that axis (the
        largest over the reference axes it involves).
    """

    name: str
    value: float
    sd: float
    prior_sd: float
    status: str
    excitation: float


@dataclass(frozen=True, eq=False)
class ImuAlignmentFit:
    """In-flight calibration of one IMU against the reference (SI): the fit (the
    calibration file's record of it is :class:`fdi.extras.ImuAlignment`).

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
    mounting: np.ndarray = field(default_factory=lambda: np.eye(3))
    parameters: tuple[ParameterStatus, ...] = ()

    @property
    def small(self) -> tuple[np.ndarray, np.ndarray]:
        """``E = A·Rᵀ − I`` (the part beyond the mounting R) and the covariance of vec(E)."""
        R = np.asarray(self.mounting, float)
        B = np.kron(np.eye(3), R)                   # vec(E) = B·vec(A) − vec(I)
        return self.A @ R.T - np.eye(3), B @ self.A_cov @ B.T

    @property
    def offset_check(self) -> dict[str, object]:
        """:attr:`check` as the file writes it (ms; empty when τ is not fitted)."""
        return {} if self.check is None else self.check.to_dict()

    def parts(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Rotation, scale and non-orthogonality beyond the mounting with their sds (rad,
        fraction): the parts of ``I + E``, ``A = (I + E)·R``."""
        E, C = self.small
        return decompose(np.eye(3) + E, C)

    def held(self) -> list[str]:
        """Names of the parameters held at the prior (not excited by the motion)."""
        return [p.name for p in self.parameters if p.status == HELD]


@dataclass(frozen=True, eq=False)
class InflightFit:
    """Alignment of every IMU of a flight to the reference.

    Attributes
    ----------
    reference : str
    imus : tuple of str
        All IMU groups in flight order.
    alignments : dict of str to ImuAlignmentFit
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
    alignments: dict[str, ImuAlignmentFit]
    used: np.ndarray
    left_out: tuple[Segment, ...]
    sample_rate_hz: float
    source: str = ""
    extra: dict[str, object] = field(default_factory=dict)
    nonfinite: int = 0
    findings: tuple[AxisFinding, ...] = ()
    axis_noise: dict[str, np.ndarray] = field(default_factory=dict)
    prior: Prior | None = None
    window: tuple[float, float] | None = None


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
             gain: np.ndarray | None = None, jitter: bool = True) -> ImuAlignmentFit:
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
    return ImuAlignmentFit(imu=label, model=model, A=A, A_cov=A_cov, c=beta[ci],
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


@dataclass(frozen=True)
class AxisFinding:
    """An IMU axis far noisier than the same body axis on the other IMUs.

    Attributes
    ----------
    imu : str
    axis : str
        The IMU's own axis (``"x"``, ...).
    noise_sd : float
        Its own noise sd in flight (rad/s; the three-cornered hat of the residuals).
    others_sd : float
        Median of the other IMUs' noise sd on the same body axis (rad/s).
    """

    imu: str
    axis: str
    noise_sd: float
    others_sd: float

    def text(self) -> str:
        """``"imu1.x: 9.5 deg/s vibration against 1.5 deg/s on the others"``."""
        return (f"{self.imu}.{self.axis}: {np.degrees(self.noise_sd):.3g} deg/s vibration "
                f"against {np.degrees(self.others_sd):.3g} deg/s on the others (kept: its "
                "channel is weighted by its own noise)")


def axis_noise(alignments: dict[str, ImuAlignmentFit], reference: str
               ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Noise covariance of the reference (its frame) and of each IMU (its own frame).

    The residual of IMU j is ``r_j = n_j − A_j·n_ref``; in the reference frame
    (``r̃_j = R_jᵀ·r_j``) the three-cornered hat gives
    ``Σ_ref = (Cov r̃_i + Cov r̃_j − Cov(r̃_i − r̃_j))/2`` averaged over pairs, and
    ``Σ_j = Cov r_j − R_j·Σ_ref·R_jᵀ`` (per axis the median over pairs, bounded by the
    smallest residual variance on that axis). With one IMU besides the reference the two share
    the residual equally (the data cannot split it).

    Returns
    -------
    Sr : ndarray, shape (3, 3)
    own : dict of str to ndarray (3, 3)
        Including the reference; rad²/s².
    """
    res = {g: a.residual for g, a in alignments.items()}
    rot = {g: res[g] @ np.asarray(a.mounting, float) for g, a in alignments.items()}
    fin = {g: np.all(np.isfinite(r), axis=1) for g, r in res.items()}
    covs = {g: np.cov(res[g][fin[g]].T) for g in res}
    names = list(res)
    if len(names) >= 2:
        est = []
        for i, j in itertools.combinations(names, 2):
            both = fin[i] & fin[j]
            ci, cj = np.cov(rot[i][both].T), np.cov(rot[j][both].T)
            d = np.cov((rot[i][both] - rot[j][both]).T)
            est.append((ci + cj - d) / 2)
        Sr = np.mean(est, axis=0)
        # robust per axis: the median over pairs (two IMUs sharing an error inflate their
        # pair's estimate), at most the smallest residual variance on that axis (the
        # reference's noise is in every residual); the correlations of the mean estimate
        var = np.clip(np.median([np.diag(e) for e in est], axis=0), 0, None)
        var = np.minimum(var, np.min([np.var(rot[g][fin[g]], axis=0) for g in names],
                                     axis=0))
        d0 = np.sqrt(np.clip(np.diag(Sr), 1e-30, None))
        corr = np.clip(Sr / np.outer(d0, d0), -1, 1)
        np.fill_diagonal(corr, 1.0)
        Sr = corr * np.sqrt(np.outer(var, var))
    else:
        R = np.asarray(alignments[names[0]].mounting, float)
        Sr = R.T @ covs[names[0]] @ R / 2
    floor = 1e-3 * float(np.mean([np.trace(c) / 3 for c in covs.values()]))
    Sr = _psd(Sr, floor)
    own = {reference: Sr}
    for g, a in alignments.items():
        R = np.asarray(a.mounting, float)
        own[g] = _psd(covs[g] - R @ Sr @ R.T, floor)
    return Sr, own


def _psd(C: np.ndarray, floor: float) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    return (V * np.maximum(w, floor)) @ V.T


def _findings(alignments: dict[str, ImuAlignmentFit], reference: str,
              own: dict[str, np.ndarray]) -> tuple[AxisFinding, ...]:
    """Axes whose own noise exceeds :data:`FINDING_RATIO` × the others' on that body axis
    (needs three IMUs or more: with two the residual cannot be split)."""
    if len(own) < 3:
        return ()
    mount = {reference: np.eye(3), **{g: np.asarray(a.mounting, float)
                                      for g, a in alignments.items()}}
    body = {g: np.sqrt(np.clip(np.diag(mount[g].T @ own[g] @ mount[g]), 0, None))
            for g in own}
    out = []
    for g in own:
        for k in range(3):
            m = int(np.argmax(np.abs(mount[g][k])))      # body axis of the IMU's axis k
            others = float(np.median([body[h][m] for h in own if h != g]))
            mine = float(np.sqrt(max(own[g][k, k], 0.0)))
            if others > 0 and mine > FINDING_RATIO * others:
                out.append(AxisFinding(g, _AXES[k], mine, others))
    return tuple(out)


def fit_inflight(flight: Flight, *, reference: str | None = None, model: str = "auto",
                 time_offset: bool = True, prior: Prior | None = None,
                 window: tuple[float, float] | None = None,
                 mountings: dict[str, np.ndarray] | None = None,
                 check: bool = True) -> InflightFit:
    """Align every IMU of a flight to the reference IMU.

    Each IMU's mounting is found first (the nearest rotation by multiples of 90°,
    :func:`calibration.inflight.prior.nearest_mounting`, unless ``mountings`` declares it),
    then its small misalignment, scale, non-orthogonality, bias and time offset are fitted
    with the prior (:func:`fit_pair_prior`) in two passes: the first gives the residuals
    from which each IMU's own noise per axis is split (:func:`axis_noise`), the second
    judges excitation against the reference's own noise per axis.

    Parameters
    ----------
    flight : Flight
        Gyro flight with IMU groups of three axes.
    reference : str, optional
        IMU group of the reference (default: the first).
    model : str
        ``"auto"`` (= ``"full"``), ``"full"`` or ``"rotation"``.
    time_offset : bool
    prior : Prior, optional
        Default :class:`~calibration.inflight.prior.Prior`.
    window : (float, float), optional
        Only samples with ``t0 <= t <= t1`` (s).
    mountings : dict of str to ndarray (3, 3), optional
        Declared mountings (signed permutations) of some IMUs.
    check : bool
        Check the time offsets' sds (:mod:`.offset_check`).

    Raises
    ------
    ConfigError
        Unknown reference or model, fewer than two IMUs, an empty window.
    CalibrationError
        Too few usable samples (the message names the IMU and what to do).
    """
    if model not in MODELS:
        raise ConfigError(f"model {model!r} is not one of {MODELS}")
    prior = Prior() if prior is None else prior
    rates = imu_rates(flight)
    ref = reference or next(iter(rates))
    if ref not in rates:
        raise ConfigError(f"reference {ref!r} is not an IMU of {flight.source} "
                          f"(IMUs: {', '.join(rates)})")
    segs = find_segments(flight)
    kept = keep_mask(flight.t, segs)
    if window is not None:
        t0, t1 = window
        inw = (flight.t >= t0) & (flight.t <= t1)
        if not inw.any():
            raise ConfigError(f"{flight.source}: the window {t0:g}:{t1:g} s holds no sample "
                              f"(the record spans {flight.t[0]:.3f}-{flight.t[-1]:.3f} s)")
        kept = kept & inw
    finite = np.all([np.all(np.isfinite(r), axis=1) for r in rates.values()], axis=0)
    used = kept & finite
    fitm = "rotation" if model == "rotation" else "full"
    mount = {}
    for g, y in rates.items():
        if g == ref:
            continue
        if mountings and g in mountings:
            mount[g] = np.asarray(mountings[g], float)
        else:
            u = used & np.all(np.isfinite(y), axis=1)
            mount[g] = nearest_mounting(rates[ref][u], y[u])[0] if u.sum() >= 50 \
                else np.eye(3)
    kw = dict(prior=prior, model=fitm, time_offset=time_offset,
              sample_rate_hz=flight.sample_rate_hz)
    try:
        first = {g: fit_pair_prior(flight.t, rates[ref], y, used, mounting=mount[g], label=g,
                                   check=False, jitter=False, gate=False, **kw)
                 for g, y in rates.items() if g != ref}
        Sr, _ = axis_noise(first, ref)
        out = {g: fit_pair_prior(flight.t, rates[ref], y, used, mounting=mount[g], label=g,
                                 ref_noise=Sr, check=check, **kw)
               for g, y in rates.items() if g != ref}
    except CalibrationError as exc:
        raise CalibrationError(f"{flight.source}: {exc}") from None
    _, own = axis_noise(out, ref)
    return InflightFit(reference=ref, imus=tuple(rates), alignments=out, used=used,
                       left_out=tuple(segs), sample_rate_hz=flight.sample_rate_hz,
                       source=flight.source, nonfinite=int((kept & ~finite).sum()),
                       findings=_findings(out, ref, own),
                       axis_noise={g: np.sqrt(np.clip(np.diag(c), 0, None))
                                   for g, c in own.items()},
                       prior=prior, window=window)


# -- with a prior: every IMU calibrated, what the motion does not excite held ------------
def _rotation_basis() -> np.ndarray:
    """(9, 3): vec([θ]×) = T·θ (row-major)."""
    T = np.zeros((9, 3))
    T[7, 0], T[5, 0] = 1.0, -1.0
    T[2, 1], T[6, 1] = 1.0, -1.0
    T[3, 2], T[1, 2] = 1.0, -1.0
    return T


def _columns_of(basis: np.ndarray) -> list[list[int]]:
    """For each parameter (column of ``basis``), the columns m of E it involves."""
    return [sorted({i % 3 for i in np.flatnonzero(np.abs(basis[:, j]) > 0)})
            for j in range(basis.shape[1])]


def fit_pair_prior(t: np.ndarray, y_ref: np.ndarray, y: np.ndarray, used: np.ndarray, *,
                   prior: Prior, mounting: np.ndarray | None = None, model: str = "full",
                   time_offset: bool = True, label: str = "imu",
                   sample_rate_hz: float | None = None, ref_noise: np.ndarray | None = None,
                   check: bool = True, jitter: bool = True, gate: bool = True
                   ) -> ImuAlignmentFit:
    """Fit ``y = (I + E)·R·y_ref(t+τ) + c`` with a prior on E and τ (:mod:`.prior`).

    Every reference axis whose rate varies by at least :data:`EXCITATION_MIN` times the
    reference's own noise on that axis informs the columns of E it multiplies; the columns
    of an axis that does not stay at the prior (their regressors reduced to their mean:
    the data cannot tell their variation from the noise, its errors-in-variables bias would
    be large, and the mean keeps the prior's uncertainty of ``E·z̄`` in the bias). τ is
    fitted when the angular acceleration varies by :data:`TAU_EXCITATION_MIN` times the
    noise of the differentiated reference, and held at 0 ± the prior's sd otherwise. The
    estimate is the posterior mode with the HAC sandwich covariance
    (:func:`calibration.inflight.regression.stacked_ridge`), channels weighted by the
    inverse variance of their own residual (one IMU's vibrating axis weighs only its own
    channel), corrected for the reference noise in the regressors (:func:`_debias`).

    Parameters
    ----------
    t : ndarray, shape (N,)
    y_ref, y : ndarray, shape (N, 3)
        Reference and IMU gyro outputs (rad/s).
    used : ndarray of bool, shape (N,)
    prior : Prior
    mounting : ndarray, shape (3, 3), optional
        R (a signed permutation); identity when None.
    model : str
        ``"full"`` (E free: rotation, scale, non-orthogonality) or ``"rotation"`` (E = [θ]×).
    time_offset : bool
    label : str
    sample_rate_hz : float, optional
    ref_noise : ndarray, shape (3, 3), optional
        Noise covariance of the reference (rad²/s², its own frame); when None, half the
        pair's residual covariance (two IMUs of equal noise).
    check, jitter : bool
        As :func:`fit_pair`.
    gate : bool
        Judge excitation (default). Without it every parameter is fitted with its prior
        (the first pass, whose residual gives the noise the excitation is judged against:
        a lag left in the residual would inflate it). With it and no ``ref_noise``, that
        first pass is run here.

    Raises
    ------
    CalibrationError
        Too few usable samples (the message names the IMU and what to do).
    """
    fs = float(sample_rate_hz or (1.0 / np.median(np.diff(t))))
    tau0 = 0.0
    if gate and ref_noise is None:
        ref_noise, tau0 = _prior_first_pass(t, y_ref, y, used, prior=prior, mounting=mounting,
                                            model=model, time_offset=time_offset,
                                            label=label, fs=fs)
    R = np.eye(3) if mounting is None else np.asarray(mounting, float)
    ok, core = _prior_samples(used, y_ref, y, label)
    pm = _PriorModel.of(model, prior, fs)
    tt = t[ok]
    spline = CubicSpline(tt, y_ref[ok], axis=0)
    Sr_given = None if ref_noise is None else R @ np.asarray(ref_noise, float) @ R.T
    s = _solve_prior(tt, y[ok], spline, core[ok], R, pm, tau0=tau0, Sr_given=Sr_given,
                     fs=fs, time_offset=time_offset, gate=gate)
    fit, E, tau, fit_tau = s.fit, s.E, s.tau, s.fit_tau
    q = pm.basis.shape[1]
    A = (np.eye(3) + E) @ R
    cov = fit.cov
    Ecov = pm.basis @ cov[:q, :q] @ pm.basis.T
    K = np.kron(np.eye(3), R.T)                      # vec(A) = K·vec(I + E)
    A_cov = K @ Ecov @ K.T
    ci = slice(q, q + 3)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    params = _prior_parameters(fit.beta, sd, pm, s.col_ratio)
    sd_tau = float(sd[-1]) if fit_tau else pm.tau_sd
    if time_offset:
        params.append(_tau_status(tau, sd_tau, pm.tau_sd, s.tau_ratio, fit_tau))
    residual = np.full(y.shape, np.nan)
    rows = np.flatnonzero(ok)[s.inside]
    residual[rows] = fit.residual
    exc = _prior_excitation(s.X, pm, params, s.tau_ratio, fit_tau)
    notes = _prior_notes(params, R)
    chk: OffsetCheck | None = None
    if fit_tau and check:
        chk, sd_tau, note = _prior_offset_check(t, y_ref, y, rows, s, q, sd_tau, fs=fs,
                                                label=label, A=A)
        if note:
            notes.append(note)
        params[-1] = replace(params[-1], sd=sd_tau)
    jit = (fit_timing_jitter(fit.residual, s.dz[s.inside] @ (np.eye(3) + E).T,
                             lags=fit.lags)
           if jitter else JitterFit(0.0, 0.0, 0.0, 0.0, np.zeros((3, 3)), 0))
    return ImuAlignmentFit(imu=label, model=model, A=A, A_cov=A_cov, c=fit.beta[ci],
                        c_cov=cov[ci, ci], time_offset_s=tau if fit_tau else 0.0,
                        time_offset_sd_s=sd_tau if time_offset else 0.0,
                        residual=residual, lags=fit.lags, excitation=exc, notes=tuple(notes),
                        check=chk, timing_jitter_s=jit.tau_s,
                        timing_jitter_sd_s=jit.tau_sd_s, mounting=R,
                        parameters=tuple(params))


def _prior_first_pass(t: np.ndarray, y_ref: np.ndarray, y: np.ndarray, used: np.ndarray, *,
                      prior: Prior, mounting: np.ndarray | None, model: str,
                      time_offset: bool, label: str, fs: float) -> tuple[np.ndarray, float]:
    """The ungated first pass of :func:`fit_pair_prior`: the reference noise it implies
    (half the residual covariance, in the reference's frame) and its time offset.

    Parameters
    ----------
    t, y_ref, y, used, prior, mounting, model, time_offset, label
        As :func:`fit_pair_prior`.
    fs : float
        Sample rate (Hz).

    Returns
    -------
    ref_noise : ndarray, shape (3, 3)
    tau0 : float
        Time offset of the first pass (s), where the gated fit starts.
    """
    a0 = fit_pair_prior(t, y_ref, y, used, prior=prior, mounting=mounting, model=model,
                        time_offset=time_offset, label=label, sample_rate_hz=fs,
                        check=False, jitter=False, gate=False)
    r0 = a0.residual[np.all(np.isfinite(a0.residual), axis=1)]
    R0 = np.eye(3) if mounting is None else np.asarray(mounting, float)
    return R0.T @ np.cov(r0.T) @ R0 / 2, a0.time_offset_s


def _prior_samples(used: np.ndarray, y_ref: np.ndarray, y: np.ndarray, label: str
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Samples :func:`fit_pair_prior` fits: used with both rates finite, and the core of
    those (:data:`_EDGE` samples off each side of a dropped block).

    Parameters
    ----------
    used : ndarray of bool, shape (N,)
    y_ref, y : ndarray, shape (N, 3)
    label : str
        The IMU, for the message.

    Returns
    -------
    ok, core : ndarray of bool, shape (N,)

    Raises
    ------
    CalibrationError
        Fewer than 50 such samples.
    """
    ok = used & np.all(np.isfinite(y_ref), axis=1) & np.all(np.isfinite(y), axis=1)
    if ok.sum() < 50:
        raise CalibrationError(
            f"{label}: only {int(ok.sum())} samples where it and the reference both have "
            "finite rates (need 50): choose a longer part of the record (--window)")
    core = ok & ndimage.binary_erosion(ok, structure=np.ones(2 * _EDGE + 1, bool),
                                       border_value=True)
    return ok, core


@dataclass(frozen=True)
class _PriorModel:
    """The parametrisation of E a :func:`fit_pair_prior` model uses.

    Attributes
    ----------
    basis : ndarray, shape (9, q)
        vec(E) = basis·β.
    sds : ndarray, shape (q,)
        Prior sds of β.
    names : list of str
    involves : list of list of int
        For each parameter, the columns of E it involves.
    tau_sd : float
        Prior sd of the time offset (s).
    """

    basis: np.ndarray
    sds: np.ndarray
    names: list[str]
    involves: list[list[int]]
    tau_sd: float

    @classmethod
    def of(cls, model: str, prior: Prior, fs: float) -> _PriorModel:
        """``"full"`` (the nine parameters of :data:`PARAMETERS`) or ``"rotation"``.

        Parameters
        ----------
        model : str
        prior : Prior
        fs : float
            Sample rate (Hz).

        Returns
        -------
        _PriorModel
        """
        full = model == "full"
        basis = np.linalg.inv(_decomposition_matrix()) if full else _rotation_basis()
        sds = prior.sds() if full else prior.sds()[:3]
        names = list(PARAMETERS) if full else list(PARAMETERS[:3])
        return cls(basis, sds, names, _columns_of(basis), prior.tau_sd(fs))


@dataclass(frozen=True, eq=False)
class _PriorSolution:
    """Where the Gauss–Newton iteration of :func:`_solve_prior` ends.

    Attributes
    ----------
    fit : StackedFit
    X : ndarray, shape (n, 3, p)
        The last design.
    inside : ndarray of bool
        Fitted samples (of the usable ones) whose shifted time lies in the record.
    dz : ndarray, shape (n_ok, 3)
        Derivative of the mounted reference at the shifted times.
    E : ndarray, shape (3, 3)
    tau : float
    fit_tau : bool
    col_ratio : ndarray, shape (3,)
        Excitation of each reference axis.
    tau_ratio : float
        Excitation of the time offset.
    w : ndarray, shape (3,)
        Channel weights (inverse residual variance).
    """

    fit: StackedFit
    X: np.ndarray
    inside: np.ndarray
    dz: np.ndarray
    E: np.ndarray
    tau: float
    fit_tau: bool
    col_ratio: np.ndarray
    tau_ratio: float
    w: np.ndarray


def _solve_prior(tt: np.ndarray, y_ok: np.ndarray, spline: CubicSpline, core_ok: np.ndarray,
                 R: np.ndarray, pm: _PriorModel, *, tau0: float, Sr_given: np.ndarray | None,
                 fs: float, time_offset: bool, gate: bool) -> _PriorSolution:
    """The Gauss–Newton iteration in τ of :func:`fit_pair_prior`.

    Parameters
    ----------
    tt : ndarray, shape (n_ok,)
        Times of the usable samples.
    y_ok : ndarray, shape (n_ok, 3)
        The IMU's rates there.
    spline : CubicSpline
        The reference through those samples.
    core_ok : ndarray of bool, shape (n_ok,)
        Usable samples away from a dropped block.
    R : ndarray, shape (3, 3)
        Mounting.
    pm : _PriorModel
    tau0 : float
        Starting time offset (s).
    Sr_given : ndarray, shape (3, 3), optional
        Reference noise covariance in the IMU's frame; None to take it from the residual.
    fs : float
    time_offset, gate : bool
        As :func:`fit_pair_prior`.

    Returns
    -------
    _PriorSolution
    """
    tau = tau0
    E = np.zeros((3, 3))
    fit_tau = time_offset
    w = None
    col_ratio = np.full(3, np.inf)
    tau_ratio = np.inf
    fit = X = inside = dz = None
    for it in range(_GN_ITER if time_offset else 2):
        inside = (tt + tau >= tt[0]) & (tt + tau <= tt[-1]) & core_ok
        z = spline(tt + tau) @ R.T
        dz = spline(tt + tau, 1) @ R.T
        zi, dzi = z[inside], dz[inside]
        Y = y_ok[inside] - zi
        if w is None:
            w = 1.0 / np.maximum(np.var(Y, axis=0), 1e-30)
            Sr = Sr_given if Sr_given is not None else np.diag(0.5 / w)
        sig_r = np.sqrt(np.clip(np.diag(Sr), 1e-30, None))
        if it == 0 or Sr_given is None:
            col_ratio, tau_ratio, fit_tau = _prior_gate(zi, dzi, E, sig_r, fs,
                                                        time_offset=time_offset, gate=gate)
            if not fit_tau:
                tau = 0.0
        excited = (col_ratio >= EXCITATION_MIN) | (not gate)
        X, Xc = _prior_design(zi, dzi, excited, pm.basis, E, fit_tau)
        mu, Lam, mom = _prior_system(X.shape[0], pm, E, Sr, w, excited, tau=tau, fs=fs,
                                     fit_tau=fit_tau)
        fit = stacked_ridge(X, Y, w, mu, Lam, moment=mom,
                            consider=Xc if np.any(~excited) else None)
        E = (pm.basis @ fit.beta[:pm.basis.shape[1]]).reshape(3, 3)
        w = 1.0 / np.maximum(np.var(fit.residual, axis=0), 1e-30)
        if Sr_given is None:
            Sr = np.cov(fit.residual.T) / 2
        if fit_tau:
            step = float(fit.beta[-1])
            tau += step
            if abs(step) < 1e-3 * max(fit.sd[-1], 1e-9):
                break
    return _PriorSolution(fit, X, inside, dz, E, tau, fit_tau, col_ratio, tau_ratio, w)


def _prior_gate(zi: np.ndarray, dzi: np.ndarray, E: np.ndarray, sig_r: np.ndarray,
                fs: float, *, time_offset: bool, gate: bool
                ) -> tuple[np.ndarray, float, bool]:
    """Excitation of each reference axis and of the time offset, and whether τ is fitted.

    Parameters
    ----------
    zi, dzi : ndarray, shape (n, 3)
        Mounted reference rate and its derivative on the fitted samples.
    E : ndarray, shape (3, 3)
        Current gain beyond the mounting.
    sig_r : ndarray, shape (3,)
        Reference noise sd per axis (rad/s).
    fs : float
    time_offset, gate : bool
        As :func:`fit_pair_prior`.

    Returns
    -------
    col_ratio : ndarray, shape (3,)
    tau_ratio : float
    fit_tau : bool
    """
    col_ratio = np.std(zi, axis=0) / sig_r
    A_now = np.eye(3) + E
    tau_ratio = float(np.max(np.std(dzi @ A_now.T, axis=0) / (fs * sig_r)))
    fit_tau = time_offset and (tau_ratio >= TAU_EXCITATION_MIN or not gate)
    return col_ratio, tau_ratio, fit_tau


def _prior_design(zi: np.ndarray, dzi: np.ndarray, excited: np.ndarray, basis: np.ndarray,
                  E: np.ndarray, fit_tau: bool) -> tuple[np.ndarray, np.ndarray]:
    """The design of one Gauss–Newton step and the considered part left out of it.

    An axis not excited keeps only its mean in the regressors: the data then say nothing
    of its columns beyond their product with the mean rate (the reference's bias,
    confounded with c), so c carries the prior's uncertainty of E·z̄ (the variation left
    out is "considered": its effect through the prior's spread of E goes into the
    covariance of what is estimated, :func:`~calibration.inflight.regression.stacked_ridge`).

    Parameters
    ----------
    zi, dzi : ndarray, shape (n, 3)
        Mounted reference rate and its derivative on the fitted samples.
    excited : ndarray of bool, shape (3,)
        Reference axes whose variation is used.
    basis : ndarray, shape (9, q)
    E : ndarray, shape (3, 3)
    fit_tau : bool

    Returns
    -------
    X, Xc : ndarray, shape (n, 3, q + 3 + fit_tau)
        The design (E parameters, three biases, τ last when fitted) and the considered
        regressors (zero but for the E columns).
    """
    n = zi.shape[0]
    q = basis.shape[1]
    zx = np.where(excited[None, :], zi, zi.mean(axis=0, keepdims=True))
    XE = np.zeros((n, 3, 9))
    XC = np.zeros((n, 3, 9))
    for k in range(3):
        XE[:, k, 3 * k:3 * k + 3] = zx
        XC[:, k, 3 * k:3 * k + 3] = zi - zx
    p = q + 3 + fit_tau
    X = np.zeros((n, 3, p))
    X[:, :, :q] = XE @ basis
    for k in range(3):
        X[:, k, q + k] = 1.0
    A_now = np.eye(3) + E
    if fit_tau:
        X[:, :, -1] = dzi @ A_now.T
    Xc = np.zeros_like(X)
    Xc[:, :, :q] = XC @ basis
    return X, Xc


def _prior_system(n: int, pm: _PriorModel, E: np.ndarray, Sr: np.ndarray, w: np.ndarray,
                  excited: np.ndarray, *, tau: float, fs: float, fit_tau: bool
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prior mean and precision of one step, and the moment bias of the reference noise.

    Parameters
    ----------
    n : int
        Fitted samples.
    pm : _PriorModel
    E : ndarray, shape (3, 3)
    Sr : ndarray, shape (3, 3)
        Reference noise covariance (the IMU's frame).
    w : ndarray, shape (3,)
        Channel weights.
    excited : ndarray of bool, shape (3,)
    tau : float
        Current time offset (s); the prior holds the step at ``-tau``.
    fs : float
    fit_tau : bool

    Returns
    -------
    mu : ndarray, shape (p,)
    Lam : ndarray, shape (p, p)
    mom : ndarray, shape (p,)
        As :func:`_debias` (first order), the unexcited axes left out.
    """
    q = pm.basis.shape[1]
    p = q + 3 + fit_tau
    A_now = np.eye(3) + E
    Lam = np.zeros((p, p))
    Lam[:q, :q] = np.diag(1.0 / pm.sds**2)
    mu = np.zeros(p)
    if fit_tau:
        Lam[-1, -1] = 1.0 / pm.tau_sd**2
        mu[-1] = -tau
    v, kappa = _spline_noise(round(float((tau * fs) % 1.0), 3))
    mE = -n * v * ((A_now @ Sr) * excited[None, :] * w[:, None]).ravel()
    mom = np.zeros(p)
    mom[:q] = pm.basis.T @ mE
    if fit_tau:
        mom[-1] = -n * kappa * fs * float(np.sum(w * np.diag(A_now @ Sr @ A_now.T)))
    return mu, Lam, mom


def _prior_parameters(beta: np.ndarray, sd: np.ndarray, pm: _PriorModel,
                      col_ratio: np.ndarray) -> list[ParameterStatus]:
    """Status of each parameter of E: estimated when its sd is at most :data:`INFORMED`
    times its prior sd, held otherwise; its excitation the largest of the axes it involves.

    Parameters
    ----------
    beta, sd : ndarray
        Estimate and sd (E parameters first).
    pm : _PriorModel
    col_ratio : ndarray, shape (3,)

    Returns
    -------
    list of ParameterStatus
    """
    params = []
    for j in range(pm.basis.shape[1]):
        r = float(max(col_ratio[m] for m in pm.involves[j]))
        st = ESTIMATED if sd[j] <= INFORMED * pm.sds[j] else HELD
        params.append(ParameterStatus(pm.names[j], float(beta[j]), float(sd[j]),
                                      float(pm.sds[j]), st, r))
    return params


def _tau_status(tau: float, sd_tau: float, tau_sd: float, tau_ratio: float, fit_tau: bool
                ) -> ParameterStatus:
    """Status of the time offset (held at 0 when not fitted).

    Parameters
    ----------
    tau, sd_tau : float
        Estimate and sd (s).
    tau_sd : float
        Prior sd (s).
    tau_ratio : float
    fit_tau : bool

    Returns
    -------
    ParameterStatus
    """
    status = ESTIMATED if fit_tau and sd_tau <= INFORMED * tau_sd else HELD
    return ParameterStatus("time offset", tau if fit_tau else 0.0, sd_tau, tau_sd, status,
                           tau_ratio)


def _prior_excitation(X: np.ndarray, pm: _PriorModel, params: list[ParameterStatus],
                      tau_ratio: float, fit_tau: bool) -> Excitation:
    """Excitation of the last design, with the ratios the gate judged.

    Parameters
    ----------
    X : ndarray, shape (n, 3, p)
    pm : _PriorModel
    params : list of ParameterStatus
        E parameters first.
    tau_ratio : float
    fit_tau : bool

    Returns
    -------
    Excitation
    """
    q = pm.basis.shape[1]
    p = X.shape[2]
    tau_names = ["time offset"] if fit_tau else []
    ex_names = [*pm.names, "bias x", "bias y", "bias z", *tau_names]
    exc = _excitation(X, ex_names, list(range(q, q + 3)), np.ones(p))
    ratio = np.array([pp.excitation for pp in params[:q]]
                     + ([tau_ratio] if fit_tau else []))
    return replace(exc, ratio=ratio)


def _prior_notes(params: list[ParameterStatus], R: np.ndarray) -> list[str]:
    """Notes of a :func:`fit_pair_prior` alignment: the method, what is held, the mounting.

    Parameters
    ----------
    params : list of ParameterStatus
    R : ndarray, shape (3, 3)

    Returns
    -------
    list of str
    """
    notes = ["posterior mode with the prior as pseudo-observations; channels weighted by "
             "their own residual variance; corrected for the reference noise in the "
             "regressors (first order)"]
    held = [pp.name for pp in params if pp.status == HELD]
    if held:
        notes.append("held at the prior (the flight does not excite them): "
                     + ", ".join(held))
    if not np.allclose(R, np.eye(3)):
        notes.append(f"mounting {mounting_text(R)}")
    return notes


def _prior_offset_check(t: np.ndarray, y_ref: np.ndarray, y: np.ndarray, rows: np.ndarray,
                        s: _PriorSolution, q: int, sd_tau: float, *, fs: float, label: str,
                        A: np.ndarray) -> tuple[OffsetCheck | None, float, str]:
    """The piece and bootstrap checks of a fitted time offset
    (:func:`calibration.inflight.offset_check.check_offset`).

    Parameters
    ----------
    t, y_ref, y : ndarray
        As :func:`fit_pair_prior`.
    rows : ndarray of int
        Samples fitted.
    s : _PriorSolution
    q : int
        Parameters of E.
    sd_tau : float
        HAC sd of τ (s).
    fs : float
    label : str
    A : ndarray, shape (3, 3)
        The fitted gain (the pieces are fitted with it fixed).

    Returns
    -------
    chk : OffsetCheck or None
        None when the checks could not be computed.
    sd_tau : float
        The largest of the sds (through the file's ms), or the HAC sd.
    note : str
        Empty, or why the checks are missing.
    """
    p = s.X.shape[2]
    fitted = np.zeros(t.shape[0], bool)
    fitted[rows] = True
    data_cols = [j for j in range(q) if np.any(np.std(s.X[:, :, j], axis=0) > 0)]
    data_cols += list(range(q, p))
    sw = np.sqrt(s.w)

    def piece(mask: np.ndarray) -> tuple[float, float, str]:
        kw = dict(time_offset=True, label=label, sample_rate_hz=fs, check=False,
                  jitter=False)
        a = fit_pair(t, y_ref, y, mask, model="fixed", gain=A, **kw)
        return a.time_offset_s, a.time_offset_sd_s, a.model

    try:
        chk = check_offset(t, fitted, s.X[:, :, data_cols] * sw[None, :, None],
                           s.fit.residual * sw, sd_tau, fs, piece)
    except np.linalg.LinAlgError:
        return None, sd_tau, ("time offset: the piece and bootstrap checks could not be "
                              "computed (singular design); HAC sd reported")
    return chk, max(sd_tau, 1e-3 * (1e3 * chk.sd_s)), ""
