"""Per healthy set: parity, whitening, reconstruction, thresholds, and the compiled kernel.

Isolating a sensor zeroes its row of H̃ (seed 001 Eq. 21); V, the whitening and the
reconstruction matrix of the remaining set are computed once, the first time that set
occurs, and cached by the bitmask of healthy sensors (:class:`SetCache`). The step path
never does an SVD.

The per-sample arithmetic (compensation, parity, whitening, reconstruction and the
calibration-uncertainty ratio ρ) runs in the compiled monitor kernel (:mod:`fdi.kernel`),
which reads these matrices; :meth:`SetModel.compensate` is the same arithmetic in numpy
for whole blocks (analysis code, not the monitor). ρ holds the calibration uncertainty at
the current rate and, with a timing jitter τ_i per sensor, the error ``h_iᵀω̇·δt`` of a
sampling-time error δt at the current angular acceleration (:meth:`SetModel.rho`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fdi.detector import chi2_threshold, cusum_threshold, minimum_detectable_noncentrality
from fdi.integrity import ProtectionLevel, protection_level_constants
from fdi.isolation import pair_sines, rejection_level
from fdi.parity import parity_matrix, reconstruction_matrix
from fdi.settings import Thresholds

__all__ = ["SetCache", "SetModel", "build_set_model", "inflation_terms", "isolation_sizes",
           "jitter_coefficients", "rho_series"]


@dataclass(frozen=True, eq=False)
class SetModel:
    """Everything the monitor needs for one set of healthy sensors.

    Attributes
    ----------
    mask : int
        Bitmask of healthy sensors (bit i: sensor i, 0-based).
    idx : tuple of int
        Healthy sensors (0-based, ascending); m = len(idx).
    df : int
        Parity dimension m − 3 (0 without redundancy).
    capability : str
    V : ndarray, shape (df, n)
        Parity matrix (zero columns for excluded sensors).
    A : ndarray, shape (df, df)
        Lower-triangular whitening: z = A·p has unit covariance for white noise.
    U : ndarray, shape (df, m)
        Whitened parity columns u_i = A·v_i of the healthy sensors.
    G : ndarray, shape (3, n)
        Reconstruction matrix ω̂ = G·y.
    cov : ndarray, shape (3, 3)
        G Σ Gᵀ (white noise), rad²/s² per sample.
    omega_sd : ndarray, shape (3,)
    kappa : float
        Calibration-uncertainty constant: V diag(Σ_ii) Vᵀ ≼ κ·VΣVᵀ.
    beta : float
        Bias-uncertainty constant: A·V·diag(bias_sd²)·Vᵀ·Aᵀ ≼ β·I (a constant parity offset
        that no window averages down).
    thr, chi2_scale, rho_gain, offset_gain : tuple of float, shape (K,)
        Per window scale w with variance factor f_w: the χ² threshold T_w for df, the
        statistic's scale 1/(w·f_w), the gain κ/f_w of the window's summed ρ and the
        constant-offset inflation 1 + w·β/f_w (threshold ``T_w·(offset_gain + rho_gain·Σρ)``).
    cusum_h : float
        CUSUM decision threshold h (NaN without a CUSUM bank).
    sines : ndarray, shape (m, m)
        sin θ_ij between the whitened parity columns of healthy sensors i and j (how well
        their fault hypotheses can be told apart; :func:`fdi.isolation.pair_sines`).
    detectable : ndarray, shape (m,)
        Bias (SI) on each healthy sensor detected with probability 1 − P_md by the longest
        window at rest.
    isolable_from : ndarray, shape (m, m)
        Bias (SI) on sensor i (row) from which the longest window rejects the hypothesis of
        sensor j (column) with probability 1 − P_md at the risk of wrong exclusion
        (:func:`isolation_sizes`); inf where the two cannot be told apart.
    pl : ProtectionLevel
    sf, bias : ndarray, shape (n,)
        Scale factors (SI per raw unit) and biases (SI): y = sf·u − bias.
    cal_coef : ndarray, shape (n, 6)
        ρ_i = ω̂ᵀC_iω̂/Σ_ii as coefficients of (ω0², ω1², ω2², ω0ω1, ω0ω2, ω1ω2).
    jit_coef : ndarray, shape (n,)
        τ_i²·fs²/Σ_ii: the timing-jitter share of ρ_i is ``jit_coef_i·(h_iᵀΔω̂)²`` with
        Δω̂ = ω̂_t − ω̂_{t−1} (so h_iᵀω̇̂·τ_i with ω̇̂ = Δω̂·fs); zero without jitter.
    axes : ndarray, shape (n, 3)
        Calibrated axes h_i (for the jitter term).
    """

    mask: int
    idx: tuple[int, ...]
    df: int
    capability: str
    V: np.ndarray
    A: np.ndarray
    U: np.ndarray
    G: np.ndarray
    cov: np.ndarray
    omega_sd: np.ndarray
    kappa: float
    thr: tuple[float, ...]
    chi2_scale: tuple[float, ...]
    rho_gain: tuple[float, ...]
    beta: float
    offset_gain: tuple[float, ...]
    cusum_h: float
    sines: np.ndarray
    detectable: np.ndarray
    isolable_from: np.ndarray
    pl: ProtectionLevel
    sf: np.ndarray = field(repr=False)
    bias: np.ndarray = field(repr=False)
    cal_coef: np.ndarray = field(repr=False)
    jit_coef: np.ndarray | None = field(default=None, repr=False)
    axes: np.ndarray | None = field(default=None, repr=False)

    @property
    def m(self) -> int:
        """Number of healthy sensors."""
        return len(self.idx)

    def compensate(self, raw: np.ndarray, omega_prev: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Parity, whitened parity, reconstruction and ρ of a block, in numpy.

        Parameters
        ----------
        raw : ndarray, shape (N, n)
            Raw outputs, every healthy sensor present.
        omega_prev : ndarray, shape (3,), optional
            ω̂ of the sample before the block (rad/s; the jitter term of the first row is 0
            without it).

        Returns
        -------
        p, z : ndarray, shape (df, N)
        omega : ndarray, shape (3, N)
            rad/s (NaN without three independent sensors).
        rho : ndarray, shape (N,)
        """
        y = (np.asarray(raw, float) * self.sf - self.bias).T
        y = np.where(self.healthy_mask()[:, None], y, 0.0)
        p = self.V @ y
        z = self.A @ p
        if self.capability == "none":
            return p, z, np.full((3, y.shape[1]), np.nan), np.zeros(y.shape[1])
        w = self.G @ y
        return p, z, w, self.rho(w, omega_prev)

    def rho(self, w: np.ndarray, omega_prev: np.ndarray | None = None) -> np.ndarray:
        """ρ_t = max_i [ω̂ᵀC_iω̂ + τ_i²·(h_iᵀω̇̂)²]/Σ_ii of a block of ω̂ (the kernel's
        definition, :mod:`fdi.kernel`).

        Parameters
        ----------
        w : ndarray, shape (3, N)
            ω̂ (rad/s).
        omega_prev : ndarray, shape (3,), optional
            ω̂ before the block; ω̇̂ of the first row counts as 0 without it.

        Returns
        -------
        ndarray, shape (N,)
        """
        return rho_series(w, self.cal_coef, self.jit_coef, self.axes, self.idx, omega_prev)

    def healthy_mask(self) -> np.ndarray:
        """Boolean mask of the healthy sensors, shape (n,)."""
        return np.array([(self.mask >> i) & 1 == 1 for i in range(self.V.shape[1])])


def rho_series(w: np.ndarray, cal_coef: np.ndarray, jit_coef: np.ndarray | None,
               axes: np.ndarray | None, idx: tuple[int, ...],
               omega_prev: np.ndarray | None = None) -> np.ndarray:
    """ρ_t = max_i [ω̂ᵀC_iω̂ + τ_i²·(h_iᵀω̇̂)²]/Σ_ii over the sensors ``idx`` (≥ 0).

    Parameters
    ----------
    w : ndarray, shape (3, N)
        ω̂ (rad/s).
    cal_coef : ndarray, shape (n, 6)
    jit_coef : ndarray, shape (n,), or None
        τ_i²·fs²/Σ_ii (:func:`jitter_coefficients`).
    axes : ndarray, shape (n, 3), or None
    idx : tuple of int
    omega_prev : ndarray, shape (3,), optional
        ω̂ before the block; a non-finite Δω̂ counts as 0.

    Returns
    -------
    ndarray, shape (N,)
    """
    w = np.asarray(w, float)
    q = np.stack([w[0] * w[0], w[1] * w[1], w[2] * w[2], w[0] * w[1], w[0] * w[2],
                  w[1] * w[2]])
    idx = list(idx)
    terms = cal_coef[idx] @ q
    if jit_coef is not None and axes is not None and np.any(jit_coef[idx]):
        prev = np.full((3, 1), np.nan) if omega_prev is None else \
            np.asarray(omega_prev, float).reshape(3, 1)
        with np.errstate(invalid="ignore", over="ignore"):
            d = np.diff(np.hstack([prev, w]), axis=1)
            d = np.where(np.all(np.isfinite(d), axis=0), d, 0.0)
            jc = jit_coef[idx, None]
            terms = terms + np.where(jc != 0, jc * (axes[idx] @ d) ** 2, 0.0)
    return np.maximum(terms.max(axis=0), 0.0)


def inflation_terms(H: np.ndarray, sf: np.ndarray, bias: np.ndarray, noise_cov: np.ndarray,
                    input_error_cov: np.ndarray, bias_sd: np.ndarray,
                    timing_jitter: np.ndarray, sample_rate_hz: float, raw: np.ndarray
                    ) -> tuple[np.ndarray, float, float]:
    """What the monitor's thresholds of the full set do with a recording: ρ_t, κ and β.

    The monitor's threshold at scale w is ``thr_w·(1 + w·β/f_w + κ/f_w·Σ_w ρ)``
    (:mod:`fdi.windows`); a tail model measured relative to it (:mod:`calibration.tails`)
    needs these three.

    Parameters
    ----------
    H : ndarray, shape (n, 3)
    sf, bias : ndarray, shape (n,)
    noise_cov : ndarray, shape (n, n)
    input_error_cov : ndarray, shape (n, 3, 3)
    bias_sd, timing_jitter : ndarray, shape (n,)
        SI and s.
    sample_rate_hz : float
    raw : ndarray, shape (N, n)
        Raw outputs; ρ of a row with a non-finite value is 0.

    Returns
    -------
    rho : ndarray, shape (N,)
    kappa, beta : float
    """
    H = np.asarray(H, float)
    n = H.shape[0]
    healthy = np.ones(n, bool)
    idx = tuple(range(n))
    Sig = np.asarray(noise_cov, float)
    V = parity_matrix(H, healthy)
    _, _, kappa, beta = _whitening(V[:max(n - 3, 0)], Sig, idx, np.asarray(bias_sd, float))
    G, _, _ = _reconstruction(H, healthy, Sig, idx, int(np.linalg.matrix_rank(H)) == 3)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        C = np.asarray(input_error_cov, float) / np.diag(Sig)[:, None, None]
    coef = np.stack([C[:, 0, 0], C[:, 1, 1], C[:, 2, 2], 2 * C[:, 0, 1], 2 * C[:, 0, 2],
                     2 * C[:, 1, 2]], axis=1)
    jit = jitter_coefficients(timing_jitter, np.diag(Sig), sample_rate_hz, n)
    y = np.asarray(raw, float) * np.asarray(sf, float) - np.asarray(bias, float)
    w = G @ y.T
    rho = rho_series(w, coef, jit, H, idx)
    return np.where(np.isfinite(rho), rho, 0.0), kappa, beta


def _whitening(V: np.ndarray, Sig: np.ndarray, idx: tuple[int, ...], bias_sd: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Whitening A (lower triangular, A·VΣVᵀ·Aᵀ = I), whitened parity columns U and the
    calibration (κ) and bias (β) uncertainty constants of the set."""
    df = V.shape[0]
    if df == 0:
        return np.zeros((0, 0)), np.zeros((0, len(idx))), 1.0, 0.0
    R = np.linalg.cholesky(V @ Sig @ V.T)
    A = np.tril(np.linalg.solve(R, np.eye(df)))
    U = (A @ V)[:, list(idx)]
    Dg = V @ np.diag(np.diag(Sig)) @ V.T
    kappa = float(np.linalg.eigvalsh(A @ Dg @ A.T).max())
    Bg = V @ np.diag(np.asarray(bias_sd, float) ** 2) @ V.T
    beta = float(max(np.linalg.eigvalsh(A @ Bg @ A.T).max(), 0.0))
    return A, U, kappa, beta


def _reconstruction(H: np.ndarray, healthy: np.ndarray, Sig: np.ndarray,
                    idx: tuple[int, ...], full: bool
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted least-squares G, its white-noise covariance GΣGᵀ and the sd per axis."""
    n = H.shape[0]
    if not full:
        return np.zeros((3, n)), np.full((3, 3), np.nan), np.full(3, np.nan)
    Wu = np.zeros((n, n))
    Wu[np.ix_(list(idx), list(idx))] = np.linalg.inv(Sig[np.ix_(list(idx), list(idx))])
    G = reconstruction_matrix(H, healthy, Wu)
    cov = G @ Sig @ G.T
    return G, cov, np.sqrt(np.diag(cov))


def isolation_sizes(U: np.ndarray, thresholds: Thresholds, missed_detection: float,
                    wrong_exclusion: float) -> tuple[np.ndarray, np.ndarray]:
    """Detectable and reliably isolable bias sizes (SI) at the longest window, at rest.

    A bias b on sensor i over a full window of w samples gives the detection statistic the
    noncentrality λ = w·b²·|u_i|²/f_w (χ²(df) against T_w) and the residual of the
    hypothesis of sensor j the noncentrality λ·sin²θ_ij (χ²(df − 1) against the rejection
    level c of :func:`fdi.isolation.rejection_level`). The sizes solve
    ``ncx2.cdf(level, dof, λ) = P_md`` (:func:`fdi.detector.minimum_detectable_noncentrality`).

    Returns
    -------
    detectable : ndarray, shape (m,)
    isolable_from : ndarray, shape (m, m)
        Row i, column j: the bias on i from which j's hypothesis is rejected (inf on the
        diagonal and where sin θ_ij = 0).
    """
    df, m = U.shape
    if df < 1 or m == 0:
        return np.full(m, np.inf), np.full((m, m), np.inf)
    k = int(np.argmax(thresholds.scales))
    w, f = float(thresholds.scales[k]), float(thresholds.variance_factor[k])
    un = np.linalg.norm(U, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam_det = minimum_detectable_noncentrality(chi2_threshold(thresholds.alpha[k], df), df,
                                                   missed_detection)
        det = np.where(un > 0, np.sqrt(lam_det * f / w) / un, np.inf)
        c = rejection_level(df, m, wrong_exclusion)
        lam_iso = minimum_detectable_noncentrality(c, df - 1, missed_detection) if df > 1 \
            else float("inf")
        sn = pair_sines(U)
        iso = np.where(sn > 0, np.sqrt(lam_iso * f / w) / (un[:, None] * sn), np.inf)
    np.fill_diagonal(iso, np.inf)
    return det, iso


def _capability(full: bool, df: int, detectable: np.ndarray, isolable_from: np.ndarray,
                isolation_ratio: float) -> str:
    """What the set can do: isolate, detect, reconstruct or none.

    "isolate" needs every pair of healthy sensors to be told apart, statistically, from a
    bias at most ``isolation_ratio`` times the largest detectable one: two nearly aligned
    triads detect but do not isolate (their columns are a degree or two apart), however
    different their axes are on paper.
    """
    if not full:
        return "none"
    if df == 0:
        return "reconstruct"
    if df == 1 or isolable_from.size == 0:
        return "detect"
    worst = float(np.max(isolable_from[~np.eye(isolable_from.shape[0], dtype=bool)]))
    return "isolate" if worst <= isolation_ratio * float(np.max(detectable)) else "detect"


def build_set_model(H: np.ndarray, sf: np.ndarray, bias: np.ndarray, noise_cov: np.ndarray,
                    input_error_cov: np.ndarray, mask: int, thresholds: Thresholds,
                    missed_detection: float, bias_sd: np.ndarray | None = None, *,
                    wrong_exclusion: float = 1e-7, isolation_ratio: float = 10.0,
                    timing_jitter: np.ndarray | None = None) -> SetModel:
    """Compute (once) the model of one healthy set. See :class:`SetModel`.

    Parameters
    ----------
    H : ndarray, shape (n, 3)
        Calibrated axes H̃.
    sf, bias : ndarray, shape (n,)
        Scale factors (SI per raw unit) and biases (SI).
    noise_cov : ndarray, shape (n, n)
    input_error_cov : ndarray, shape (n, 3, 3)
    mask : int
        Bitmask of healthy sensors.
    thresholds : Thresholds
    missed_detection : float
    bias_sd : ndarray, shape (n,), optional
        Standard deviation of the calibrated biases (SI); zero when omitted.
    wrong_exclusion : float
        Risk of excluding a healthy sensor per isolation decision
        (:attr:`fdi.settings.MonitorSettings.wrong_exclusion`).
    isolation_ratio : float
        Capability rule (:func:`_capability`).
    timing_jitter : ndarray, shape (n,), optional
        Per sensor the sd τ_i of the sampling-time error against the reference (s); the
        jitter term of ρ uses the thresholds' sample rate (zero when omitted).
    """
    n = H.shape[0]
    if bias_sd is None:
        bias_sd = np.zeros(n)
    healthy = np.array([(mask >> i) & 1 == 1 for i in range(n)])
    idx = tuple(int(i) for i in np.flatnonzero(healthy))
    m = len(idx)
    Hu = H[list(idx)]
    rank = int(np.linalg.matrix_rank(Hu)) if m else 0
    full = rank == 3
    df = m - 3 if full else 0
    V = parity_matrix(H, healthy) if df > 0 else np.zeros((0, n))
    V = V[:df] if V.shape[0] > df else V
    Sig = np.asarray(noise_cov, float)
    A, U, kappa, beta = _whitening(V, Sig, idx, bias_sd)
    G, cov, osd = _reconstruction(H, healthy, Sig, idx, full)
    det, iso = isolation_sizes(U, thresholds, missed_detection, wrong_exclusion)
    cap = _capability(full, df, det, iso, isolation_ratio)
    sines = pair_sines(U)
    # calibration uncertainty: ρ_i = ω̂ᵀ C_i ω̂ / Σ_ii on (ω0², ω1², ω2², ω0ω1, ω0ω2, ω1ω2)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):   # huge/0: inf, nan
        C = np.asarray(input_error_cov, float) / np.diag(Sig)[:, None, None]
    coef = np.stack([C[:, 0, 0], C[:, 1, 1], C[:, 2, 2], 2 * C[:, 0, 1], 2 * C[:, 0, 2],
                     2 * C[:, 1, 2]], axis=1)
    jit = jitter_coefficients(timing_jitter, np.diag(Sig), thresholds.sample_rate_hz, n)
    scales = thresholds.scales
    vf = thresholds.variance_factor
    thr = tuple(chi2_threshold(a, df) if df > 0 else float("inf") for a in thresholds.alpha)
    chi2_scale = tuple(1.0 / (w * f) for w, f in zip(scales, vf, strict=True))
    # q ≥ 1 (Thresholds.rate_error_factor): the rate term held for a calibration error up
    # to a quantile of its covariance, not only the average one (thresholds.per_draw)
    q = float(thresholds.rate_error_factor)
    rho_gain = tuple(q * kappa / f for f in vf)
    offset_gain = tuple(1.0 + w * beta / f for w, f in zip(scales, vf, strict=True))
    h = float("nan")
    if df > 0 and thresholds.detector != "windows":
        h = cusum_threshold(thresholds.alpha[0], thresholds.cusum_drift, 2 * m)
    pl = protection_level_constants(U, G[:, list(idx)], Sig[np.ix_(list(idx), list(idx))],
                                    thr[0] if scales[0] == 1 else float("inf"), vf[0], q * kappa,
                                    missed_detection)
    sf = np.array(sf, float)
    bias = np.array(bias, float)
    axes = np.array(H, float)
    for a in (V, A, U, G, cov, osd, sf, bias, coef, sines, det, iso, jit, axes):
        a.setflags(write=False)
    return SetModel(mask=mask, idx=idx, df=df, capability=cap, V=V, A=A, U=U, G=G, cov=cov,
                    omega_sd=osd, kappa=kappa, thr=thr, chi2_scale=chi2_scale,
                    rho_gain=rho_gain, beta=beta, offset_gain=offset_gain, cusum_h=h,
                    sines=sines, detectable=det, isolable_from=iso, pl=pl,
                    sf=sf, bias=bias, cal_coef=coef, jit_coef=jit, axes=axes)


def jitter_coefficients(timing_jitter: np.ndarray | None, sigma_diag: np.ndarray,
                        sample_rate_hz: float, n: int) -> np.ndarray:
    """τ_i²·fs²/Σ_ii per sensor (0 where τ, fs or Σ_ii do not give a finite number).

    Parameters
    ----------
    timing_jitter : ndarray, shape (n,), or None
        τ_i (s).
    sigma_diag : ndarray, shape (n,)
        Σ_ii (SI²).
    sample_rate_hz : float
    n : int

    Returns
    -------
    ndarray, shape (n,)
    """
    if timing_jitter is None:
        return np.zeros(n)
    tau = np.asarray(timing_jitter, float).reshape(n)
    with np.errstate(all="ignore"):
        c = tau**2 * float(sample_rate_hz) ** 2 / np.asarray(sigma_diag, float)
    return np.where(np.isfinite(c) & (c > 0), c, 0.0)


class SetCache:
    """Lazily built :class:`SetModel` per bitmask of healthy sensors."""

    def __init__(self, H: np.ndarray, sf: np.ndarray, bias: np.ndarray,
                 noise_cov: np.ndarray, input_error_cov: np.ndarray, thresholds: Thresholds,
                 missed_detection: float, bias_sd: np.ndarray | None = None, *,
                 wrong_exclusion: float = 1e-7, isolation_ratio: float = 10.0,
                 timing_jitter: np.ndarray | None = None) -> None:
        self.H = np.asarray(H, float)
        self.wrong_exclusion = float(wrong_exclusion)
        self.isolation_ratio = float(isolation_ratio)
        self.n = self.H.shape[0]
        self.sf = np.asarray(sf, float)
        self.bias = np.asarray(bias, float)
        self.noise_cov = np.asarray(noise_cov, float)
        self.input_error_cov = np.asarray(input_error_cov, float)
        self.thresholds = thresholds
        self.missed_detection = float(missed_detection)
        self.bias_sd = np.zeros(self.n) if bias_sd is None else np.asarray(bias_sd, float)
        self.timing_jitter = (np.zeros(self.n) if timing_jitter is None
                              else np.asarray(timing_jitter, float))
        self._models: dict[int, SetModel] = {}

    def get(self, mask: int) -> SetModel:
        """The model of a set (built the first time it is asked for)."""
        mdl = self._models.get(mask)
        if mdl is None:
            mdl = build_set_model(self.H, self.sf, self.bias, self.noise_cov,
                                  self.input_error_cov, mask, self.thresholds,
                                  self.missed_detection, self.bias_sd,
                                  wrong_exclusion=self.wrong_exclusion,
                                  isolation_ratio=self.isolation_ratio,
                                  timing_jitter=self.timing_jitter)
            self._models[mask] = mdl
        return mdl

    def precompute(self, min_sensors: int) -> None:
        """Build every set with at least ``min_sensors`` healthy sensors now."""
        full = (1 << self.n) - 1
        for mask in range(full, -1, -1):
            if bin(mask).count("1") >= min_sensors:
                self.get(mask)

    def __len__(self) -> int:
        return len(self._models)

    def masks(self) -> list[int]:
        """Bitmasks built so far."""
        return sorted(self._models)

