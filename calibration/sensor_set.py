"""The one builder of a calibrated :class:`fdi.calfile.SensorSet`, gyros and accelerometers.

From the per-sensor estimates of :mod:`calibration.uncertainty`, the residuals and the
noise covariance, :func:`build_sensor_set` makes the :class:`fdi.calfile.SensorCal` of every
sensor (with the units files print), checks that the calibrated axes span 3-D space and adds
the misalignment matrices per subsystem and the Allan deviation of the residuals.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calibration.rate_test import group_misalignment_matrices
from calibration.residuals import allan_table
from calibration.uncertainty import SensorEstimate
from fdi.calfile import SensorCal, SensorSet
from fdi.errors import CalibrationError
from fdi.geometry import Configuration
from fdi.units import RAW_UNITS, input_unit_factor

__all__ = ["build_sensor_set", "check_axes", "check_gains", "display_units"]

_ANALOG = {"mV", "V", "uA"}


def display_units(kind: str, raw_unit: str, biases: np.ndarray | None = None) -> tuple[str, str]:
    """(scale_factor_unit, bias_unit) files print for a sensor kind and raw unit.

    Analog outputs print raw per input as datasheets and seed 000 Table 2 do
    (``mV/(deg/s)``); digital ones input per raw as seed 001 Table 3 (``(deg/s)/LSB``).
    Gyro biases in °/h (°/s when one exceeds 1 °/s, MEMS raw offsets), accelerometer biases
    in mg (g when one exceeds 1 g). ``biases`` in SI.
    """
    raw = raw_unit if raw_unit in RAW_UNITS else "raw"
    inp = "deg/s" if kind == "gyro" else "g"
    sfu = f"{raw}/({inp})" if raw in _ANALOG else f"({inp})/{raw}"
    big = biases is not None and np.size(biases) and float(np.max(np.abs(biases))) > (
        input_unit_factor("deg/s") if kind == "gyro" else input_unit_factor("g"))
    if kind == "gyro":
        return sfu, "deg/s" if big else "deg/h"
    return sfu, "g" if big else "mg"


def check_gains(source: str, kind: str, a: np.ndarray, names: Sequence[str]) -> None:
    """Refuse gains a = h̃/SF that cannot be split (zero or non-finite |a|).

    A sensor that does not respond to the known input (stuck, or swamped by a corrupt
    sample such as 1e300) gives |a| ≈ 0 or inf: no scale factor exists.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        na = np.linalg.norm(a, axis=1)
    bad = ~np.isfinite(na) | (na <= 0) | ~np.all(np.isfinite(a), axis=1)
    big = np.isfinite(na) & (na > 0)
    if big.any():
        bad |= na < 1e-9 * np.median(na[big])
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise CalibrationError(
            f"{source}: {kind} sensor {i + 1} ({names[i]}): estimated gain |h/SF| = {na[i]:.3g} "
            "cannot give a scale factor; expected a sensor that follows the table input "
            "(look for stuck or corrupt samples)")


def check_axes(source: str, kind: str, Ht: np.ndarray) -> None:
    """Refuse calibrated axes that do not span 3-D space."""
    rank = int(np.linalg.matrix_rank(Ht, tol=1e-6))
    if rank < 3:
        raise CalibrationError(f"{source}: the calibrated {kind} axes span only {rank} "
                               "dimension(s); expected 3 (look for stuck or corrupt samples)")


def build_sensor_set(kind: str, config: Configuration, raw_unit: str,
                     parts: Sequence[SensorEstimate], resid_si: np.ndarray,
                     noise_cov_si: np.ndarray, sample_rate_hz: float, *, allan: bool,
                     source: str,
                     bias_parts: Sequence[SensorEstimate] | None = None) -> SensorSet:
    """A calibrated sensor set (gyros or accelerometers).

    Parameters
    ----------
    kind : {"gyro", "accel"}
    config : Configuration
        Nominal axes, names and groups.
    raw_unit : str
    parts : sequence of SensorEstimate
        Scale factor, axis and (unless ``bias_parts``) bias of each sensor.
    resid_si : ndarray, shape (N_used, n)
        Residuals in input units (residual RMS, Allan deviation).
    noise_cov_si : ndarray, shape (n, n)
        Per-sample noise covariance of the compensated outputs (SI²).
    sample_rate_hz : float
    allan : bool
        Compute the Allan deviation of the residuals.
    source : str
        For error messages.
    bias_parts : sequence of SensorEstimate, optional
        Where the biases come from when not ``parts`` (seed 000's whole-turn offsets).

    Raises
    ------
    CalibrationError
        Calibrated axes that do not span 3-D space.
    """
    chosen = parts if bias_parts is None else bias_parts
    sfu, bu = display_units(kind, raw_unit, np.array([p.bias for p in chosen]))
    H0 = config.H
    cals = []
    for i, (p, b) in enumerate(zip(parts, chosen, strict=True)):
        g = p.split
        cals.append(SensorCal(
            name=config.sensor_names[i], axis=g.axis, axis_nominal=H0[i].copy(),
            scale_factor=g.scale_factor, scale_factor_sd=g.scale_factor_sd,
            bias=float(b.bias), bias_sd=float(b.bias_sd),
            input_error_cov=p.input_error_cov, misalignment_sd=g.misalignment_sd,
            raw_unit=raw_unit, scale_factor_unit=sfu, bias_unit=bu,
            residual_rms=float(np.sqrt(np.mean(resid_si[:, i] ** 2)))))
    Ht = np.array([cc.axis for cc in cals])
    check_axes(source, kind, Ht)
    groups = config.groups
    return SensorSet(kind, tuple(cals), noise_cov_si, groups,
                     group_misalignment_matrices(H0, Ht, groups),
                     allan_table(resid_si, sample_rate_hz) if allan else None)
