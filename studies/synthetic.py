"""Synthetic calibrations and raw samples from a true model (for tuning and tests).

:func:`synthetic_calibration` builds a plausible :class:`fdi.calfile.Calibration` in memory:
nominal axes of a built-in configuration slightly misaligned, scale factors and biases near
typical values, white noise, an input-error covariance and an Allan table of white noise.

:func:`draw_truth` draws the "real" sensors that such a calibration describes: each
sensor's true gain vector ``h̃_i + e_i`` with ``e_i ~ N(0, input_error_cov_i)`` (so the
calibration errs exactly as its covariance says), and :func:`raw_samples` produces raw
outputs ``u_i = ((h̃_i + e_i)·ω + b_i + η_i)/SF_i``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fdi.calfile import AllanTable, Calibration, SensorCal, SensorSet, tangent_basis
from fdi.geometry import load_configuration
from fdi.units import DPS

__all__ = ["SyntheticTruth", "draw_truth", "raw_samples", "synthetic_calibration"]


def synthetic_calibration(config_name: str = "cone6", *, noise_sd: float = 0.1 * DPS,
                          input_error_sd: float = 1e-4, seed: int = 0, raw_unit: str = "LSB",
                          sample_rate_hz: float = 100.0, misalignment_rad: float = 2e-3,
                          scale_factor: float = 0.0610 * DPS, bias_sd: float = 0.5 * DPS,
                          noise_sd_spread: float = 0.0, allan: bool = True,
                          bias_uncertainty: float = 0.1) -> Calibration:
    """An in-memory gyro calibration of a built-in (or file) configuration.

    Parameters
    ----------
    config_name : str
        ``"cone6"``, ``"tetrad"``, ``"triad"`` or a configuration file.
    noise_sd : float
        Per-sample white-noise standard deviation (rad/s).
    input_error_sd : float
        Standard deviation of each component of the gain-normalised calibration error
        e_i (dimensionless; 1e-4 = 100 ppm / 0.1 mrad): ``input_error_cov = sd²·I₃``.
    seed : int
    raw_unit : str
    sample_rate_hz : float
    misalignment_rad : float
        Standard deviation of the calibrated axes' misalignment from nominal.
    scale_factor : float
        Nominal SF in rad/s per raw unit (default 0.061 °/s per LSB); each sensor ±1 %.
    bias_sd : float
        Spread of the biases (rad/s).
    noise_sd_spread : float
        Relative spread of the per-sensor noise levels (0: all equal).
    allan : bool
        Attach an Allan table of white noise (τ = 2^k/fs, k = 0..14).
    bias_uncertainty : float
        ``bias_sd`` of each sensor as a fraction of its noise_sd.
    """
    rng = np.random.default_rng(seed)
    cfg = load_configuration(config_name)
    n = cfg.n
    sensors = []
    sds = noise_sd * (1.0 + noise_sd_spread * rng.uniform(-1, 1, n))
    for i in range(n):
        h0 = cfg.H[i]
        E = tangent_basis(h0)
        h = h0 + misalignment_rad * rng.standard_normal(2) @ E
        h /= np.linalg.norm(h)
        sf = scale_factor * (1.0 + 0.01 * rng.uniform(-1, 1))
        sensors.append(SensorCal(
            name=cfg.sensor_names[i], axis=h, axis_nominal=h0.copy(), scale_factor=sf,
            scale_factor_sd=sf * input_error_sd, bias=bias_sd * rng.standard_normal(),
            bias_sd=bias_uncertainty * float(sds[i]), input_error_cov=input_error_sd**2 * np.eye(3),
            misalignment_sd=np.full(2, input_error_sd), raw_unit=raw_unit,
            scale_factor_unit=f"(deg/s)/{raw_unit}", bias_unit="deg/s",
            residual_rms=float(sds[i])))
    table = None
    if allan:
        tau = 2.0 ** np.arange(15) / sample_rate_hz
        table = AllanTable(tau, sds[None, :] / np.sqrt(tau[:, None] * sample_rate_hz))
    gs = SensorSet("gyro", tuple(sensors), np.diag(sds**2), cfg.groups,
                   tuple(np.eye(len(g)) for g in cfg.groups), table)
    return Calibration(cfg.name, {"gyro": gs}, sample_rate_hz,
                       extra={"synthetic": {"seed": seed, "noise_sd": noise_sd,
                                            "input_error_sd": input_error_sd}})


@dataclass(frozen=True)
class SyntheticTruth:
    """The real sensors behind a calibration.

    Attributes
    ----------
    gains : ndarray, shape (n, 3)
        True gain vectors h̃_i + e_i (compensated output = gains·ω + noise).
    bias_error : ndarray, shape (n,)
        True bias minus calibrated bias (SI).
    noise_cov : ndarray, shape (n, n)
    """

    gains: np.ndarray
    bias_error: np.ndarray
    noise_cov: np.ndarray


def draw_truth(cal: Calibration, *, seed: int, kind: str = "gyro",
               calibration_error: bool = True) -> SyntheticTruth:
    """Draw the real sensors from the calibration's own uncertainty (or take it as exact)."""
    s = cal.kind(kind)
    rng = np.random.default_rng(seed)
    gains = s.H.copy()
    berr = np.zeros(s.n)
    if calibration_error:
        for i, c in enumerate(s.sensors):
            gains[i] += rng.multivariate_normal(np.zeros(3), np.asarray(c.input_error_cov))
            berr[i] = c.bias_sd * rng.standard_normal()
    return SyntheticTruth(gains, berr, np.asarray(s.noise_covariance, float).copy())


def raw_samples(cal: Calibration, omega: np.ndarray, *, seed: int,
                truth: SyntheticTruth | None = None, kind: str = "gyro",
                fault: np.ndarray | None = None) -> np.ndarray:
    """Raw outputs (N, n) for true body rates ``omega`` (N, 3), rad/s.

    Parameters
    ----------
    fault : ndarray, shape (N, n), optional
        Additive fault on the compensated outputs (SI).
    """
    s = cal.kind(kind)
    rng = np.random.default_rng(seed)
    omega = np.atleast_2d(np.asarray(omega, float))
    tr = truth or SyntheticTruth(s.H, np.zeros(s.n), np.asarray(s.noise_covariance, float))
    N = omega.shape[0]
    L = np.linalg.cholesky(tr.noise_cov)
    noise = rng.standard_normal((N, s.n)) @ L.T
    y = omega @ tr.gains.T + tr.bias_error + noise
    if fault is not None:
        y = y + fault
    return (y + s.biases) / s.scale_factors
