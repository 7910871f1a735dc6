"""All typed entries of a calibration's ``extra`` block (:class:`CalibrationExtras`) and the
one function that reads them (:func:`extras_from_dict`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fdi.extras.ferraris import FerrarisRecord, read_ferraris
from fdi.extras.inflight import (
    InflightAlignment,
    InflightTiming,
    read_inflight_alignment,
    read_inflight_timing,
)
from fdi.extras.read import floats, plain, strings
from fdi.extras.static import StaticAlignment, read_static
from fdi.extras.turntable import (
    EarthRateRecord,
    GyroBias,
    NoiseModel,
    RateTest,
    ResidualStep,
    read_earth_rate,
    read_gyro_bias,
    read_noise_model,
    read_parity_sd,
    read_rate_test,
    read_residual_steps,
)
from fdi.fileio import Fields

__all__ = ["TYPED_KEYS", "CalibrationExtras", "Method", "extras_from_dict"]

_PREFIX = "extra"
TYPED_KEYS = ("earth_rate_fit", "ferraris", "gyro_bias", "inflight", "method", "noise_model",
              "parity_accel_calibrated_sd", "parity_calibrated_sd", "rate_test",
              "residual_steps", "source", "static", "step_residual_chi2_dof", "warnings")
"""Keys of ``extra`` read into types (the others are kept as they are, unchecked)."""


@dataclass(frozen=True)
class Method:
    """How the calibration was made (``extra.method``): one line, or one line per part.

    Attributes
    ----------
    text : str
        The file's ``method`` when it is a string (in-flight, static calibrations).
    parts : dict of str to str
        The file's ``method`` when it is an object (turntable: ``gyro``, ``bias``,
        ``denoise``; Ferraris: ``gyro``, ``accel``).
    """

    text: str = ""
    parts: Mapping[str, str] = field(default_factory=dict)

    def part(self, key: str, default: str = "") -> str:
        """The line of one part (``default`` when the file has none)."""
        return self.parts.get(key, default)


def read_method(r: Fields) -> Method:
    v = r.get("method", "")
    if isinstance(v, str):
        return Method(text=v)
    m = r.mapping("method")
    return Method(parts={k: m.string(k, "", nonempty=False) for k in m.keys()})


# -- all of them ------------------------------------------------------------------------
@dataclass(frozen=True)
class CalibrationExtras:
    """The typed entries of ``Calibration.extra`` (see the module docstring).

    Attributes
    ----------
    inflight : InflightTiming or None
        In-flight calibrations only: the time offsets.
    inflight_alignment : InflightAlignment or None
        In-flight calibrations only: the alignment estimates.
    warnings : tuple of str
        What the calibration warns about, one line each.
    source : str
        The session or flight it was made from (``""`` when not recorded).
    method : Method
    static : StaticAlignment or None
        Static (at rest) calibrations only.
    noise_model : NoiseModel or None
        Turntable calibrations only.
    rate_test : RateTest or None
    step_residual_chi2_dof : tuple of float
        Per gyro, χ²/dof of the per-step residual means (expectation 1 under white noise).
    residual_steps : dict of str to tuple of ResidualStep
        Per sensor kind.
    earth_rate_fit : EarthRateRecord or None
    gyro_bias : GyroBias or None
    parity_sd : dict of str to tuple of tuple of float
        Per sensor kind, the first-order sd of the calibrated parity matrix, shape (n-3, n)
        (dimensionless; ``()`` for a set of three).
    ferraris : FerrarisRecord or None
        Ferraris calibrations only.
    """

    inflight: InflightTiming | None = None
    inflight_alignment: InflightAlignment | None = None
    warnings: tuple[str, ...] = ()
    source: str = ""
    method: Method = field(default_factory=Method)
    static: StaticAlignment | None = None
    noise_model: NoiseModel | None = None
    rate_test: RateTest | None = None
    step_residual_chi2_dof: tuple[float, ...] = ()
    residual_steps: Mapping[str, tuple[ResidualStep, ...]] = field(default_factory=dict)
    earth_rate_fit: EarthRateRecord | None = None
    gyro_bias: GyroBias | None = None
    parity_sd: Mapping[str, tuple[tuple[float, ...], ...]] = field(default_factory=dict)
    ferraris: FerrarisRecord | None = None

    def time_offsets_s(self) -> dict[str, float]:
        """``{IMU group: τ (s)}`` of an in-flight calibration (empty for any other)."""
        return {} if self.inflight is None else self.inflight.time_offsets_s()


def extras_from_dict(extra: Mapping[str, Any], path: str = "<calibration>"
                     ) -> CalibrationExtras:
    """Read the typed entries of an ``extra`` block (a calibration file's or one in memory).

    Parameters
    ----------
    extra : mapping
        The block; numpy values are read as their JSON would be.
    path : str
        The file, for the messages.

    Raises
    ------
    FileFormatError
        A typed entry of the wrong type; the message names the file and the field
        (``extra.inflight.imus.imu2.time_offset_ms``).
    """
    r = Fields({k: plain(extra[k]) for k in TYPED_KEYS if k in extra}, path, _PREFIX)
    return CalibrationExtras(
        inflight=read_inflight_timing(r), inflight_alignment=read_inflight_alignment(r),
        warnings=strings(r, "warnings"), source=r.string("source", "", nonempty=False),
        method=read_method(r), static=read_static(r), noise_model=read_noise_model(r),
        rate_test=read_rate_test(r),
        step_residual_chi2_dof=floats(r, "step_residual_chi2_dof"),
        residual_steps=read_residual_steps(r), earth_rate_fit=read_earth_rate(r),
        gyro_bias=read_gyro_bias(r), parity_sd=read_parity_sd(r), ferraris=read_ferraris(r))
