"""Per healthy set: parity, whitening, reconstruction, thresholds, and the compiled kernel.

Isolating a sensor zeroes its row of H̃ (seed 001 Eq. 21); V, the whitening and the
reconstruction matrix of the remaining set are computed once, the first time that set
occurs, and cached by the bitmask of healthy sensors (:class:`SetCache`). The step path
never does an SVD.

The per-sample arithmetic of a set (compensation, parity, whitening, reconstruction and the
calibration-uncertainty ratio ρ) is *generated* as straight-line Python source with the
set's constants embedded, and compiled once. The same function object runs on Python
floats (the step path) and on numpy columns of a block (the block path): one expression
tree, elementwise IEEE operations in one order, hence bit-identical results.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fdi.detector import chi2_threshold, cusum_threshold
from fdi.integrity import ProtectionLevel, protection_level_constants
from fdi.parity import isolability, parity_matrix, reconstruction_matrix
from fdi.settings import Thresholds

__all__ = ["SetCache", "SetModel", "build_set_model"]


def _c(x: float) -> str:
    """Exact source literal of a float."""
    return f"({float(x)!r})"


def _lincomb(coefs: list[float], names: list[str]) -> str:
    """``((c0*x0 + c1*x1) + c2*x2) ...`` left to right."""
    expr = f"{_c(coefs[0])} * {names[0]}"
    for c, nm in zip(coefs[1:], names[1:], strict=True):
        expr = f"({expr}) + {_c(c)} * {nm}"
    return expr


def _vmax(*args: Any) -> Any:
    """Elementwise maximum of arrays (exact, order-free)."""
    out = args[0]
    for a in args[1:]:
        out = np.maximum(out, a)
    return out


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
    thr, invwf, kof, one_bw : tuple of float, shape (K,)
        Per scale: χ² threshold for df, 1/(w·f_w), κ/f_w and 1 + w·β/f_w.
    cusum_h : float
    pl : ProtectionLevel
    kernel : callable
        ``kernel(u_0, ..., u_{n-1}) -> (p, z, omega, rho)`` on floats or numpy columns.
    proj : callable or None
        ``proj(z_0, ...) -> r`` unit whitened projections per healthy sensor (CUSUM).
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
    invwf: tuple[float, ...]
    kof: tuple[float, ...]
    beta: float
    one_bw: tuple[float, ...]
    cusum_h: float
    pl: ProtectionLevel
    kernel: Any = field(repr=False)
    kernel_vec: Any = field(repr=False)
    proj: Any = field(repr=False, default=None)
    source: str = field(repr=False, default="")

    @property
    def m(self) -> int:
        """Number of healthy sensors."""
        return len(self.idx)


def _generate(n: int, idx: tuple[int, ...], sf: np.ndarray, b: np.ndarray, V: np.ndarray,
              A: np.ndarray, G: np.ndarray, cal_coef: np.ndarray, with_omega: bool) -> str:
    args = ", ".join(f"u{i}" for i in range(n))
    lines = [f"def kernel({args}):"]
    for i in idx:                                          # compensation y = SF·u − b
        lines.append(f"    y{i} = {_c(sf[i])} * u{i} - {_c(b[i])}")
    ys = [f"y{i}" for i in idx]
    df = V.shape[0]
    for j in range(df):                                    # parity p = V·y
        lines.append(f"    p{j} = {_lincomb([V[j, i] for i in idx], ys)}")
    for j in range(df):                                    # whitening z = A·p
        ps = [f"p{k}" for k in range(j + 1)]
        lines.append(f"    z{j} = {_lincomb([A[j, k] for k in range(j + 1)], ps)}")
    if with_omega:
        for a in range(3):                                 # reconstruction ω̂ = G·y
            lines.append(f"    w{a} = {_lincomb([G[a, i] for i in idx], ys)}")
        lines += ["    q0 = w0 * w0", "    q1 = w1 * w1", "    q2 = w2 * w2",
                  "    q3 = w0 * w1", "    q4 = w0 * w2", "    q5 = w1 * w2"]
        qs = [f"q{k}" for k in range(6)]
        for k, i in enumerate(idx):                        # ρ_i = ω̂ᵀ C_i ω̂ / Σ_ii
            lines.append(f"    s{k} = {_lincomb(list(cal_coef[i]), qs)}")
        lines.append(f"    rho = MAX({', '.join(f's{k}' for k in range(len(idx)))}, 0.0)")
        lines.append("    return (" + "".join(f"p{j}, " for j in range(df)) + "), ("
                     + "".join(f"z{j}, " for j in range(df)) + "), (w0, w1, w2), rho")
    else:
        lines.append("    return (" + "".join(f"p{j}, " for j in range(df)) + "), ("
                     + "".join(f"z{j}, " for j in range(df)) + "), None, 0.0")
    return "\n".join(lines) + "\n"


def _generate_proj(U: np.ndarray) -> str:
    df, m = U.shape
    zs = [f"z{j}" for j in range(df)]
    lines = [f"def proj({', '.join(zs)}):"]
    norms = np.linalg.norm(U, axis=0)
    for k in range(m):
        un = U[:, k] / norms[k] if norms[k] > 0 else np.zeros(df)
        lines.append(f"    r{k} = {_lincomb(list(un), zs)}")
    lines.append("    return (" + "".join(f"r{k}, " for k in range(m)) + ")")
    return "\n".join(lines) + "\n"


def _compile(src: str, name: str, vec: bool) -> Any:
    # _c() writes non-finite constants as inf / nan (repr): give those names their values
    ns: dict[str, Any] = {"MAX": _vmax if vec else max, "inf": float("inf"),
                          "nan": float("nan")}
    exec(compile(src, f"<rimu {name}>", "exec"), ns)
    return ns[name]


def build_set_model(H: np.ndarray, sf: np.ndarray, bias: np.ndarray, noise_cov: np.ndarray,
                    input_error_cov: np.ndarray, mask: int, thresholds: Thresholds,
                    missed_detection: float, bias_sd: np.ndarray | None = None) -> SetModel:
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
    if df > 0:
        S = V @ Sig @ V.T
        R = np.linalg.cholesky(S)
        A = np.linalg.solve(R, np.eye(df))
        A = np.tril(A)
        U = (A @ V)[:, list(idx)]
        Dg = V @ np.diag(np.diag(Sig)) @ V.T
        kappa = float(np.linalg.eigvalsh(A @ Dg @ A.T).max())
        Bg = V @ np.diag(np.asarray(bias_sd, float) ** 2) @ V.T
        beta = float(max(np.linalg.eigvalsh(A @ Bg @ A.T).max(), 0.0))
    else:
        beta = 0.0
        A = np.zeros((0, 0))
        U = np.zeros((0, m))
        kappa = 1.0
    if full:
        Wu = np.zeros((n, n))
        Wu[np.ix_(list(idx), list(idx))] = np.linalg.inv(Sig[np.ix_(list(idx), list(idx))])
        G = reconstruction_matrix(H, healthy, Wu)
        cov = G @ Sig @ G.T
        osd = np.sqrt(np.diag(cov))
    else:
        G = np.zeros((3, n))
        cov = np.full((3, 3), np.nan)
        osd = np.full(3, np.nan)
    if not full:
        cap = "none"
    elif df == 0:
        cap = "reconstruct"
    elif df == 1:
        cap = "detect"
    else:
        iso = isolability(V[:, list(idx)], Sig[np.ix_(list(idx), list(idx))])
        cap = "isolate" if iso["can_isolate"] else "detect"
    # calibration uncertainty: ρ_i = ω̂ᵀ C_i ω̂ / Σ_ii on (ω0², ω1², ω2², ω0ω1, ω0ω2, ω1ω2)
    C = np.asarray(input_error_cov, float) / np.diag(Sig)[:, None, None]
    coef = np.stack([C[:, 0, 0], C[:, 1, 1], C[:, 2, 2], 2 * C[:, 0, 1], 2 * C[:, 0, 2],
                     2 * C[:, 1, 2]], axis=1)
    scales = thresholds.scales
    vf = thresholds.variance_factor
    thr = tuple(chi2_threshold(a, df) if df > 0 else float("inf") for a in thresholds.alpha)
    invwf = tuple(1.0 / (w * f) for w, f in zip(scales, vf, strict=True))
    kof = tuple(kappa / f for f in vf)
    one_bw = tuple(1.0 + w * beta / f for w, f in zip(scales, vf, strict=True))
    h = float("nan")
    if df > 0 and thresholds.detector != "windows":
        h = cusum_threshold(thresholds.alpha[0], thresholds.cusum_drift, 2 * m)
    pl = protection_level_constants(U, G[:, list(idx)], Sig[np.ix_(list(idx), list(idx))],
                                    thr[0] if scales[0] == 1 else float("inf"), vf[0], kappa,
                                    missed_detection)
    src = _generate(n, idx, sf, bias, V, A, G, coef, full)
    kern = _compile(src, "kernel", vec=False)
    kern_vec = _compile(src, "kernel", vec=True)
    proj = None
    psrc = ""
    if df > 0:
        psrc = _generate_proj(U)
        proj = _compile(psrc, "proj", vec=False)
    for a in (V, A, U, G, cov, osd):
        a.setflags(write=False)
    return SetModel(mask=mask, idx=idx, df=df, capability=cap, V=V, A=A, U=U, G=G, cov=cov,
                    omega_sd=osd, kappa=kappa, thr=thr, invwf=invwf, kof=kof, beta=beta,
                    one_bw=one_bw, cusum_h=h,
                    pl=pl, kernel=kern, kernel_vec=kern_vec, proj=proj, source=src + psrc)


class SetCache:
    """Lazily built :class:`SetModel` per bitmask of healthy sensors."""

    def __init__(self, H: np.ndarray, sf: np.ndarray, bias: np.ndarray,
                 noise_cov: np.ndarray, input_error_cov: np.ndarray, thresholds: Thresholds,
                 missed_detection: float, bias_sd: np.ndarray | None = None) -> None:
        self.H = np.asarray(H, float)
        self.n = self.H.shape[0]
        self.sf = np.asarray(sf, float)
        self.bias = np.asarray(bias, float)
        self.noise_cov = np.asarray(noise_cov, float)
        self.input_error_cov = np.asarray(input_error_cov, float)
        self.thresholds = thresholds
        self.missed_detection = float(missed_detection)
        self.bias_sd = np.zeros(self.n) if bias_sd is None else np.asarray(bias_sd, float)
        self._models: dict[int, SetModel] = {}

    def get(self, mask: int) -> SetModel:
        """The model of a set (built the first time it is asked for)."""
        mdl = self._models.get(mask)
        if mdl is None:
            mdl = build_set_model(self.H, self.sf, self.bias, self.noise_cov,
                                  self.input_error_cov, mask, self.thresholds,
                                  self.missed_detection, self.bias_sd)
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

