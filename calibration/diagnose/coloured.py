"""Nested-model tests against white noise plus a Gauss-Markov bias (profile likelihood).

Why. The white-noise F-tests of :mod:`.linmodel` are exact only when the noise left after
the model is white. A genuine bias instability (first-order Gauss-Markov, correlation time
τ, variance σ_b²) leaves slow structure that every slow regressor (per-step means, a
Legendre trend, a change point, a warm-up) partly explains, so clean sessions are flagged
(9 of 10 tetrad-paper sessions at 1 °/h, τ 100 s). Here the null hypothesis includes the
Gauss-Markov term with its parameters *re-estimated* under the null and under the
alternative: a likelihood-ratio test with the noise parameters profiled out. An effect is
then credited only with what a Gauss-Markov wander of the best-fitting size and τ cannot
explain as well; an effect tied to the session's inputs, or far larger than the fitted
wander, still gives a large ratio.

Model. One sensor's residual ``y`` (N samples) under the design ``X`` (the calibration's
free columns and the effects accepted so far)::

    y = X·β + w + g,    w ~ N(0, σ_w²·I),    g a Gauss-Markov process (σ_b², τ)

Block decomposition. The samples are cut into M contiguous blocks of ``n_b`` samples
(about :data:`BLOCK_S` each, at most :data:`MAX_BLOCKS`). Every vector ``a`` splits
exactly into its block means ``ā`` (M) and its within-block deviations ``a_w``. For
τ ≫ a block the Gauss-Markov process is constant within a block, so (the only
approximation: its within-block variance, ≈ σ_b²·n_b/(3·f_s·τ), is left out)::

    cov(a_w) = σ_w²·(I − P_blocks)
    cov(D·ā) = σ_w²·(I + ρ·S),   D = diag(√n_b),  S = D·K(τ)·D,  ρ = σ_b²/σ_w²

with ``K(τ)_jk = (1/(L_j·L_k))·∫∫ exp(−|t − s|/τ) ds dt`` over blocks j and k (closed
form, :func:`calibration.residuals.gauss_markov_segment_corr`) and the two parts
uncorrelated. With ``S = U·diag(λ)·Uᵀ`` the generalised inner product is::

    ⟨a, b⟩_V = aᵀb − ãᵀ·diag(h)·b̃,    ã = Uᵀ·D·ā,   h_m = ρλ_m / (1 + ρλ_m)

so the GLS Gram matrix of any set of columns is its ordinary Gram minus a correction
from M block means only, and the profile log-likelihood (σ_w² and β maximised out) is::

    −2·ℓ(ρ, τ) = N·log(RSS_V(ρ, τ)/N) + Σ_m log(1 + ρ·λ_m) + const
    RSS_V = ⟨e, e⟩_V − g_Xᵀ·G_X⁻¹·g_X     (G_X, g_X: ⟨·,·⟩_V Gram of X and its cross with e)

Restricted likelihood. With σ_w² and β profiled out, the restricted (REML) −2·log
likelihood of the design ``X`` (p columns) is, up to a constant::

    −2·ℓ_R(ρ, τ) = (N − p)·log(RSS_V/(N − p)) + Σ_m log(1 + ρ·λ_m) + log det G_X
    RSS_V = ⟨e, e⟩_V − g_Xᵀ·G_X⁻¹·g_X     (G_X, g_X: ⟨·,·⟩_V Gram of X and its cross with e)

The plain (maximum-likelihood) profile forgets that β was estimated from the same data and
under-estimates the slow noise; over simulated white + Gauss-Markov sets its ratio for a
warm-up or a trend averaged 1.7-1.9 per degree of freedom instead of 1 (too many false
claims). The restricted one averages 0.9-1.1.

Test. Restricted likelihoods of different designs cannot be compared directly; the
Welham-Thompson (1997) ratio evaluates both models' residuals under the *alternative's*
restricted terms (``p``, ``log det G_X`` of the larger design ``X₁ = [X₀, Z]``)::

    LR = min_{ρ,τ} [(N − p₁)·log RSS₀ + D(ρ, τ)] − min_{ρ,τ} [(N − p₁)·log RSS₁ + D(ρ, τ)]
    D = Σ log(1 + ρλ) + log det G_X₁ ,       p = upper tail of χ²_r at LR  (r = rank of Z)

``(ρ, τ)`` are common to the sensors of a set (identical sensors; the calibration's
noise model makes the same assumption): each sensor's −2ℓ_R grid is summed over the set
before the minimum, so an effect on one sensor cannot buy itself a large Gauss-Markov term
that the other sensors contradict. The minimum is over a grid (12 τ log-spaced from 3
blocks to 4 session lengths × 73 ρ plus ρ = 0, white noise) with a parabolic refinement in
log ρ and then log τ. The eigen-decompositions depend only on the block layout and τ, so
they are computed once per layout (cached) and shared by every sensor and test; one test
costs O(T·M·(k + r)²) for T correlation times, independent of N beyond one pass of block
means.

When. :func:`needs_coloured` applies the calibration's own noise-model selection
(:func:`calibration.residuals.fit_gauss_markov`, the Gauss-Markov likelihood-ratio test
on the residual of the set): where it keeps white noise the exact white-noise F-tests of
:mod:`.linmodel` run unchanged.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.special
import scipy.stats
from threadpoolctl import threadpool_limits

from calibration.diagnose.linmodel import FTest, LinModel, projected_whitener
from calibration.residuals import fit_gauss_markov

__all__ = ["BLOCK_S", "MAX_BLOCKS", "BlockNoise", "DetectGrids", "GlsModel", "NoiseSet",
           "block_corr", "block_noise", "grid_min", "needs_coloured"]

BLOCK_S = 1.0
"""Nominal block length (s) of the block-mean decomposition."""
MAX_BLOCKS = 600
"""At most this many blocks (longer sessions get longer blocks)."""
TAU_GRID = 12
"""Correlation times tried (log-spaced, 3 blocks to 4 session lengths)."""
RHO_PER_DECADE = 8
"""Grid density of ρ·n_b (Gauss-Markov variance over the white variance of a block mean),
from 1e-4 to 1e5, plus ρ = 0."""


def _without_best_step(e: np.ndarray) -> np.ndarray:
    """``e`` (N,) with its mean and its best-fitting single step removed (least squares
    over the step time, cumulative sums: the step at ``k`` explains ``S_k²·N/(k·(N−k))``,
    ``S`` the cumulative sum of the centred samples)."""
    e = e - e.mean()
    N = e.size
    if N < 3:
        return e
    k = np.arange(1, N)
    S = np.cumsum(e)[:-1]
    best = int(k[np.argmax(S**2 * N / (k * (N - k)))])
    z = (np.arange(N) >= best) - (N - best) / N
    return e - z * (z @ e) / (z @ z)


def needs_coloured(y: np.ndarray, fs: float) -> bool:
    """True when the calibration's noise-model selection keeps a Gauss-Markov term for
    these residuals (N, n) of one sensor set, and keeps it once the sensor that reads most
    coloured on its own has its best single step removed (sets of two or more).

    The Gauss-Markov term is a property of the set (identical sensors, common σ_b² and
    τ): a bias instability shows in every sensor and survives removing one step from one
    of them. A bias step in one sensor (an effect, the library's ``bias_step``) otherwise
    makes the whole set's null white + Gauss-Markov, and that null absorbs the step it
    came from: a 3 °/h step at 55 % of a tetrad-paper session on one gyro (white-noise
    p ≈ 1e-19) fell to p ≈ 4e-4 and was missed in 3 of 10 seeds
    (``tests/calibration/test_closure_injected.py``).
    """
    y = np.asarray(y, float).reshape(np.shape(y)[0], -1)
    if not fit_gauss_markov(y, fs).bias_var > 0:
        return False
    n = y.shape[1]
    if n < 2:
        return True
    worst = int(np.argmax([fit_gauss_markov(y[:, i], fs).lr for i in range(n)]))
    y = y.copy()
    y[:, worst] = _without_best_step(y[:, worst])
    return fit_gauss_markov(y, fs).bias_var > 0


@dataclass(frozen=True)
class BlockNoise:
    """Block layout and the eigen-decompositions of ``S(τ)`` for the τ grid.

    Attributes
    ----------
    starts : ndarray of int, shape (M,)
        First sample of each block.
    counts : ndarray, shape (M,)
        Samples per block.
    taus : ndarray, shape (T,)
        Correlation times (s).
    lam : ndarray, shape (T, M)
        Eigenvalues of ``S(τ)``.
    Ut : ndarray, shape (T, M, M)
        Transposed eigenvectors (``Ut[t] @ D·ā`` rotates block means).
    rho : ndarray, shape (R,)
        ρ grid (first entry 0).
    h : ndarray, shape (T, R, M)
        ``ρλ/(1 + ρλ)``.
    logdet : ndarray, shape (T, R)
        ``Σ log(1 + ρλ)``.
    """

    starts: np.ndarray
    counts: np.ndarray
    taus: np.ndarray
    lam: np.ndarray
    Ut: np.ndarray
    rho: np.ndarray
    h: np.ndarray
    logdet: np.ndarray

    @property
    def M(self) -> int:
        """Number of blocks."""
        return self.starts.size

    def means(self, Z: np.ndarray) -> np.ndarray:
        """Block means of ``Z`` (N, p) → (M, p)."""
        return np.add.reduceat(Z, self.starts, axis=0) / self.counts[:, None]

    def rotate(self, Zbar: np.ndarray) -> np.ndarray:
        """``Uᵀ·D·Z̄`` for every τ: (M, p) → (T, M, p)."""
        return np.matmul(self.Ut, np.sqrt(self.counts)[:, None] * Zbar)


def block_corr(start_s: np.ndarray, length_s: np.ndarray, tau_c: float) -> np.ndarray:
    """``K(τ)`` of contiguous, time-ordered, non-overlapping blocks (vectorised form of
    :func:`calibration.residuals.gauss_markov_segment_corr`): for block j before k,
    ``K_jk = τ²·exp(−(a_k − b_j)/τ)·(1 − e^{−L_j/τ})·(1 − e^{−L_k/τ})/(L_j·L_k)``
    (``a`` starts, ``b`` ends), and ``K_jj = 2·(x − 1 + e^{−x})/x²``, ``x = L_j/τ``."""
    a = np.asarray(start_s, float)
    L = np.asarray(length_s, float)
    x = L / tau_c
    f = -np.expm1(-x) * tau_c / L                               # (1 − e^{−L/τ})·τ/L
    gap = np.maximum(a[None, :] - (a + L)[:, None], 0.0)        # a_k − b_j for j < k
    K = np.exp(-gap / tau_c) * f[:, None] * f[None, :]
    K = np.triu(K, 1)
    K = K + K.T
    K[np.diag_indices_from(K)] = 2.0 * (x - 1.0 + np.exp(-x)) / x**2
    return K


@functools.lru_cache(maxsize=8)
def _block_noise(N: int, B: int, fs: float) -> BlockNoise:
    with threadpool_limits(limits=1, user_api="blas"):        # M×M, one thread is faster
        return _make_block_noise(N, B, fs)


def _make_block_noise(N: int, B: int, fs: float) -> BlockNoise:
    starts = np.arange(0, N, B)
    counts = np.diff(np.r_[starts, N]).astype(float)
    if counts.size > 1 and counts[-1] < B / 2:           # fold a short tail into the last
        starts, counts = starts[:-1], np.r_[counts[:-2], counts[-2] + counts[-1]]
    t0, L = starts / fs, counts / fs
    T = N / fs
    taus = np.geomspace(3 * B / fs, 4 * T, TAU_GRID)
    sq = np.sqrt(counts)
    lam, Ut = [], []
    for tc in taus:
        K = block_corr(t0, L, tc)
        w, V = np.linalg.eigh(sq[:, None] * K * sq[None, :])
        lam.append(np.maximum(w, 0.0))
        Ut.append(V.T)
    lam_a = np.array(lam)
    nb = float(np.mean(counts))
    rho = np.r_[0.0, np.logspace(-4, 5, 9 * RHO_PER_DECADE + 1) / nb]
    rl = rho[None, :, None] * lam_a[:, None, :]
    return BlockNoise(starts=starts, counts=counts, taus=taus, lam=lam_a, Ut=np.array(Ut),
                      rho=rho, h=rl / (1 + rl), logdet=np.log1p(rl).sum(axis=2))


def block_noise(N: int, fs: float) -> BlockNoise:
    """The (cached) block layout for N samples at ``fs`` Hz."""
    B = max(round(BLOCK_S * fs), -(-N // MAX_BLOCKS), 1)
    return _block_noise(int(N), int(B), float(fs))


def _parabola_min(x: np.ndarray, v: np.ndarray, j: int) -> float:
    """Minimum of the parabola through (x, v) at j-1, j, j+1 (v[j] at an edge)."""
    if j == 0 or j == v.size - 1:
        return float(v[j])
    x0, x1, x2 = x[j - 1:j + 2]
    y0, y1, y2 = v[j - 1:j + 2]
    d = (x0 - x1) * (x0 - x2) * (x1 - x2)
    a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / d
    if not a > 0:
        return float(y1)
    b = (x2**2 * (y0 - y1) + x1**2 * (y2 - y0) + x0**2 * (y1 - y2)) / d
    c = y1 - a * x1**2 - b * x1
    xm = float(np.clip(-b / (2 * a), x0, x2))
    return float(min(y1, a * xm**2 + b * xm + c))


def grid_min(v: np.ndarray, noise: BlockNoise) -> float:
    """Minimum over (τ, ρ) of a −2ℓ grid (T, R): per τ a parabola in log ρ through the
    best grid point and its neighbours, then one in log τ over those profiles; never
    above the best grid value."""
    lr = np.log(np.maximum(noise.rho, noise.rho[1] * 1e-3))
    prof = np.array([_parabola_min(lr, v[t], int(np.argmin(v[t])))
                     for t in range(v.shape[0])])
    return min(_parabola_min(np.log(noise.taus), prof, int(np.argmin(prof))),
               float(v.min()))


def _solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A⁻¹·B`` for stacked symmetric ``A``; least squares where one is singular."""
    try:
        return np.linalg.solve(A, B)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(A) @ B


def _log_chi2_sf(x: float, r: int) -> float:
    v = float(scipy.stats.chi2.logsf(x, r))
    if np.isfinite(v):
        return v
    return float(-x / 2 + (r / 2 - 1) * np.log(x / 2) - scipy.special.gammaln(r / 2))


class NoiseSet:
    """The sensors of one set share ``(ρ, τ)``: the −2ℓ grid of each sensor's current
    model, summed over the set, is the set's profile likelihood.

    Parameters
    ----------
    noise : BlockNoise
    """

    def __init__(self, noise: BlockNoise) -> None:
        self.noise = noise
        self.grids: dict[int, np.ndarray] = {}

    def fitted(self) -> tuple[float, float]:
        """``(ρ, τ)`` at the grid minimum of the set's summed −2ℓ_R (ρ = 0: white)."""
        tot = self.others(-1)
        t, r = np.unravel_index(int(np.argmin(tot)), tot.shape)
        return float(self.noise.rho[r]), float(self.noise.taus[t])

    def gm_cov(self, X: np.ndarray) -> np.ndarray:
        """``ρ·(D·X̄)ᵀ·S(τ)·(D·X̄)`` at the fitted ``(ρ, τ)``: the Gauss-Markov part of
        ``Xᵀ·V·X/σ_w²`` for columns ``X`` (N, p) (the white part is ``XᵀX``)."""
        tot = self.others(-1)
        t, r = np.unravel_index(int(np.argmin(tot)), tot.shape)
        nz = self.noise
        A = nz.rotate(nz.means(np.asarray(X, float)))[t]
        return nz.rho[r] * (A.T * nz.lam[t]) @ A

    def others(self, sensor: int) -> np.ndarray:
        """Sum of the grids of every sensor but ``sensor`` (T, R)."""
        tot = np.zeros_like(self.noise.logdet)
        for j, v in self.grids.items():
            if j != sensor:
                tot = tot + v
        return tot


@dataclass(frozen=True)
class DetectGrids:
    """What the detectability of an effect ``Z`` under the profiled null needs
    (:mod:`calibration.diagnose.detect`), on the (τ, ρ) grid.

    Attributes
    ----------
    rss1 : ndarray, shape (T, R)
        Restricted residual sum of squares of the session under the design ``[X, Z]``.
    base : ndarray, shape (T, R)
        Its restricted terms ``Σ log(1 + ρλ) + log det G_[X,Z]``.
    dof : int
        ``N − k − p``.
    gram : ndarray, shape (T, R, p, p)
        ``⟨Z⊥, Z⊥⟩_V``: the V-metric Gram of ``Z`` made orthogonal (V-metric) to ``X``.
    others : ndarray, shape (T, R)
        The other sensors' −2ℓ_R grids.
    fitted : tuple of int
        Grid index (τ, ρ) of the set's fitted noise.
    noise : BlockNoise
    """

    rss1: np.ndarray
    base: np.ndarray
    dof: int
    gram: np.ndarray
    others: np.ndarray
    fitted: tuple[int, int]
    noise: BlockNoise

    def v(self, extra: np.ndarray | float = 0.0) -> np.ndarray:
        """−2ℓ_R grid of the set (others included) with ``extra`` added to ``rss1``."""
        rss = np.maximum(self.rss1 + extra, 1e-300)
        return self.others + self.dof * np.log(rss / self.dof) + self.base


class GlsModel:
    """A :class:`LinModel` whose tests are profile-likelihood ratios under white +
    Gauss-Markov noise (module docstring), ``(ρ, τ)`` common to the sensors of ``group``.
    ``Q``, ``e``, ``basis`` and ``project_out`` are the ordinary least-squares ones (the
    searches and the alias check use them).

    Parameters
    ----------
    y : ndarray, shape (N,)
    X : ndarray, shape (N, k)
        Initial model columns.
    group : NoiseSet or BlockNoise
        The set's shared noise (a BlockNoise alone: a set of one).
    sensor : int
        This sensor's key in the set.
    """

    def __init__(self, y: np.ndarray, X: np.ndarray, group: NoiseSet | BlockNoise,
                 sensor: int = 0) -> None:
        self.group = group if isinstance(group, NoiseSet) else NoiseSet(group)
        self.sensor = sensor
        noise = self.noise = self.group.noise
        self.lm = LinModel(y, np.zeros((np.asarray(y).size, 0)))
        self.y = self.lm.y
        self._Qbar = np.zeros((noise.M, 0))
        self._Qrot = np.zeros((noise.taus.size, noise.M, 0))
        self._refresh_e()
        self.add(X)

    # -- the LinModel interface --------------------------------------------------------
    @property
    def Q(self) -> np.ndarray:
        """Ordinary orthonormal basis (N, k) of the model."""
        return self.lm.Q

    @property
    def e(self) -> np.ndarray:
        """Ordinary least-squares residual (N,)."""
        return self.lm.e

    @property
    def k(self) -> int:
        """Number of independent model columns."""
        return self.lm.k

    @property
    def rss(self) -> float:
        """Ordinary residual sum of squares."""
        return self.lm.rss

    def basis(self, Z: np.ndarray) -> np.ndarray:
        """Orthonormal (ordinary inner product) basis of ``Z`` projected off the model."""
        return self.lm.basis(Z)

    def project_out(self, Z: np.ndarray) -> np.ndarray:
        """``Z`` minus its ordinary projection on the model."""
        return self.lm.project_out(Z)

    def add(self, Z: np.ndarray) -> int:
        """Add the columns of ``Z`` to the model; returns the rank added."""
        k0 = self.lm.k
        r = self.lm.add(Z)
        if r:
            Ubar = self.noise.means(self.lm.Q[:, k0:])
            self._Qbar = np.hstack([self._Qbar, Ubar])
            self._Qrot = np.concatenate([self._Qrot, self.noise.rotate(Ubar)], axis=2)
            self._refresh_e()
        return r

    def _refresh_e(self) -> None:
        self._erot = self.noise.rotate(self.noise.means(self.lm.e[:, None]))
        k = self.lm.k
        G = np.zeros((k + 1, k + 1))
        G[:k, :k] = np.eye(k)
        G[k, k] = self.lm.rss
        self.group.grids[self.sensor] = self._nll(
            np.concatenate([self._Qrot, self._erot], axis=2), G)[0]

    # -- the likelihood ----------------------------------------------------------------
    def _nll(self, A: np.ndarray, G: np.ndarray,
             k0: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """Restricted −2ℓ on the (τ, ρ) grid, shape (T, R), for the design whose rotated
        block means are ``A[..., :-1]`` (T, M, p) and whose ordinary Gram is ``G`` (the
        last column is the residual ``e``). With ``k0``: also the Welham-Thompson null
        grid, the residual of the first ``k0`` columns under the same restricted terms."""
        nz = self.noise
        T, M, p = A.shape
        P = (A[:, :, :, None] * A[:, :, None, :]).reshape(T, M, p * p)
        C = np.matmul(nz.h, P).reshape(T, -1, p, p)             # (T, R, p, p)
        Gv = G[None, None] - C
        ee = Gv[..., -1, -1]
        dof = self.y.size - (p - 1)

        def rss(k: int) -> np.ndarray:
            if k == 0:
                return ee
            Gx, gx = Gv[..., :k, :k], Gv[..., :k, -1]
            try:
                sol = np.linalg.solve(Gx, gx[..., None])[..., 0]
            except np.linalg.LinAlgError:       # numerically singular: least squares
                sol = np.einsum("...ij,...j->...i", np.linalg.pinv(Gx), gx)
            return ee - np.einsum("...i,...i->...", gx, sol)

        ld = np.linalg.slogdet(Gv[..., :-1, :-1])[1] if p > 1 else 0.0
        ld = np.where(np.isfinite(ld), ld, np.inf)  # a singular Gram: that (ρ, τ) is out
        base = nz.logdet + ld
        v1 = dof * np.log(np.maximum(rss(p - 1), 1e-300) / dof) + base
        v0 = None if k0 is None else \
            dof * np.log(np.maximum(rss(k0), 1e-300) / dof) + base
        return v1, v0

    def _vgram(self, Zrot: np.ndarray, Z: np.ndarray, sel: tuple[int, int] | None = None
               ) -> np.ndarray:
        """``⟨Z⊥, Z⊥⟩_V`` (Gram of ``Z`` (N, p) made V-orthogonal to the model) on the
        (τ, ρ) grid, (T, R, p, p), or at one grid point ``sel`` (p, p). ``Zrot``: the
        rotated block means of ``Z`` (T, M, p)."""
        nz = self.noise
        k, p = self.lm.k, Z.shape[1]
        QZ = self.lm.Q.T @ Z
        G = np.zeros((k + p, k + p))
        G[:k, :k] = np.eye(k)
        G[:k, k:] = QZ
        G[k:, :k] = QZ.T
        G[k:, k:] = Z.T @ Z
        if sel is not None:
            t, r = sel
            At = np.concatenate([self._Qrot[t], Zrot], axis=1)
            Gv = G - (At.T * nz.h[t, r]) @ At
        else:
            A = np.concatenate([self._Qrot, Zrot], axis=2)
            T, M, q = A.shape
            P = (A[:, :, :, None] * A[:, :, None, :]).reshape(T, M, q * q)
            Gv = G[None, None] - np.matmul(nz.h, P).reshape(T, -1, q, q)
        if not k:
            return Gv
        return Gv[..., k:, k:] - np.swapaxes(Gv[..., :k, k:], -1, -2) @ _solve(
            Gv[..., :k, :k], Gv[..., :k, k:])

    def fitted_index(self) -> tuple[int, int]:
        """Grid index (τ, ρ) of the set's fitted noise (minimum of the summed −2ℓ_R)."""
        tot = self.group.others(-1)
        t, r = np.unravel_index(int(np.argmin(tot)), tot.shape)
        return int(t), int(r)

    def known_noise(self, Z: np.ndarray) -> tuple[np.ndarray, float]:
        """``⟨Z⊥, Z⊥⟩_V`` (p, p) at the set's fitted (ρ, τ) and the white variance σ_w²
        there: the Fisher information of ``Z``'s coefficients is their ratio."""
        Z = np.asarray(Z, float).reshape(self.y.size, -1)
        nz = self.noise
        t, r = self.fitted_index()
        Zrot = nz.Ut[t] @ (np.sqrt(nz.counts)[:, None] * nz.means(Z))
        k = self.lm.k
        # σ_w² at the fitted point from the current model's residual
        Ae = np.concatenate([self._Qrot[t], self._erot[t]], axis=1)
        Ge = np.zeros((k + 1, k + 1))
        Ge[:k, :k] = np.eye(k)
        Ge[k, k] = self.lm.rss
        Gv = Ge - (Ae.T * nz.h[t, r]) @ Ae
        rss = Gv[k, k] - Gv[k, :k] @ _solve(Gv[:k, :k], Gv[:k, k])
        sw2 = float(rss) / max(self.y.size - k, 1)
        gram = self._vgram(Zrot, Z, (t, r))
        return gram, sw2

    def detect_grids(self, Z: np.ndarray) -> DetectGrids:
        """The grids :mod:`calibration.diagnose.detect` needs for adding ``Z`` (N, p)
        (see :class:`DetectGrids`): the session's residual under ``[X, Z]`` and the
        V-metric Gram of ``Z`` off ``X``, at every (τ, ρ) of the grid."""
        Z = np.asarray(Z, float).reshape(self.y.size, -1)
        nz = self.noise
        k = self.lm.k
        Zrot = nz.rotate(nz.means(Z))
        gram = self._vgram(Zrot, Z)
        # the session's residual under [Q, Z] (the test's own alternative grid)
        Zs, scale, Aw, W = projected_whitener(Z, self.lm.Q)
        r = W.shape[1]
        c = W.T @ ((Zs.T @ self.lm.e) / scale)
        Urot = (Zrot / scale - self._Qrot @ Aw) @ W          # rotation is linear
        Gf = np.zeros((k + r + 1, k + r + 1))
        Gf[:k + r, :k + r] = np.eye(k + r)
        Gf[k:k + r, -1] = Gf[-1, k:k + r] = c
        Gf[-1, -1] = self.lm.rss
        Arot = np.concatenate([self._Qrot, Urot, self._erot], axis=2)
        T, M, q = Arot.shape
        Gv1 = Gf[None, None] - np.matmul(
            nz.h, (Arot[..., :, None] * Arot[..., None, :]).reshape(T, M, q * q)
        ).reshape(T, -1, q, q)
        Gx, gx = Gv1[..., :-1, :-1], Gv1[..., :-1, -1:]
        rss1 = Gv1[..., -1, -1] - (np.swapaxes(gx, -1, -2) @ _solve(Gx, gx))[..., 0, 0]
        ld = np.linalg.slogdet(Gx)[1]
        base = nz.logdet + np.where(np.isfinite(ld), ld, np.inf)
        dof = self.y.size - (k + r)
        return DetectGrids(rss1=np.maximum(rss1, 1e-300), base=base,
                           dof=dof, gram=gram, others=self.group.others(self.sensor),
                           fitted=self.fitted_index(), noise=nz)

    def test(self, Z: np.ndarray, gram: np.ndarray | None = None) -> FTest:
        """Profile-likelihood-ratio test of adding ``Z`` (N, p) to the model.

        Returns an :class:`FTest` with ``F = LR/r`` and ``ss = LR`` (the statistic), p
        from χ²_r.
        """
        Z = np.asarray(Z, float).reshape(self.y.size, -1)
        Z, scale, A, W = projected_whitener(Z, self.lm.Q, gram)   # W: (p, r)
        r = W.shape[1]
        if r == 0:
            return FTest(0, 0.0, 0.0, 1.0, 0.0, np.zeros((self.y.size, 0)))
        c = W.T @ ((Z.T @ self.lm.e) / scale)                     # Uᵀe
        Ubar = (self.noise.means(Z) / scale - self._Qbar @ A) @ W  # block means of U
        k = self.lm.k
        Gf = np.zeros((k + r + 1, k + r + 1))
        Gf[:k + r, :k + r] = np.eye(k + r)
        Gf[k:k + r, -1] = Gf[-1, k:k + r] = c
        Gf[-1, -1] = self.lm.rss
        Arot = np.concatenate([self._Qrot, self.noise.rotate(Ubar), self._erot], axis=2)
        others = self.group.others(self.sensor)
        v1, v0 = self._nll(Arot, Gf, k)
        lr = max(grid_min(others + v0, self.noise) - grid_min(others + v1, self.noise), 0.0)
        return FTest(r, lr, lr / r, float(scipy.stats.chi2.sf(lr, r)), _log_chi2_sf(lr, r),
                     Z)
