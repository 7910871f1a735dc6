"""Typed records of a calibration's ``extra`` block: the entries rimu's code reads.

``Calibration.extra`` keeps what each calibration stage records (JSON under ``"extra"`` in
``rimu.calibration/3`` and ``/4``, layout in ``docs/formats.md``). The entries code acts on
are read here into frozen dataclasses, SI inside (names carry the unit where it is not SI),
and :attr:`fdi.calfile.Calibration.extras` gives them:

- :class:`InflightTiming` (``extra.inflight``): the reference IMU, the time offset of every
  IMU with its sd, its checks and its timing jitter, the sign convention and the flight the
  offsets were fitted on; :class:`InflightAlignment` (the same block): each IMU's fitted
  gain matrix, its parts, bias and residual, and the stretches left out;
- ``warnings`` (``extra.warnings``), ``source`` (``extra.source``), :class:`Method`
  (``extra.method``);
- :class:`StaticAlignment` (``extra.static``): a calibration at rest, each IMU's rotation,
  bias and drift relative to the reference and what of the drift is whose;
- :class:`NoiseModel` (``extra.noise_model``): the coloured-noise fit per sensor set;
- the turntable fit's checks: :class:`RateTest` (``extra.rate_test``), the per-step residual
  χ²/dof (``extra.step_residual_chi2_dof``), :class:`ResidualStep` per set
  (``extra.residual_steps``), :class:`EarthRateRecord` (``extra.earth_rate_fit``),
  :class:`GyroBias` (``extra.gyro_bias``) and the first-order sd of the calibrated parity
  matrix per set (``extra.parity_calibrated_sd``, ``extra.parity_accel_calibrated_sd``);
- :class:`FerrarisRecord` (``extra.ferraris``): a Ferraris calibration's settings and fits.

The JSON layout is unchanged (the file keeps its keys and units: ``time_offset_ms`` in the
file is :attr:`ImuTiming.time_offset_s` here), so every file written before these types
existed loads as it did and keeps its fingerprint; :func:`extras_from_dict` checks the types
and names the bad field (``extra.inflight.imus.imu2.time_offset_ms``). Keys the types do not
cover stay in ``Calibration.extra`` and are not checked.

The writers build the same types: every record's ``to_dict()`` is its JSON in the file's
units (``1e3·τ`` as ``time_offset_ms``, ...), :meth:`CalibrationExtras.to_dict` writes the
block with the keys in the order of a calibration kind (:data:`TURNTABLE_LAYOUT`,
:data:`FERRARIS_LAYOUT`, :data:`STATIC_LAYOUT`, :data:`INFLIGHT_LAYOUT`) and
:func:`replace_extras` rewrites entries of a written block, so the keys are spelled here only.

Modules: :mod:`fdi.extras.record` (:class:`CalibrationExtras`, :func:`extras_from_dict`),
:mod:`fdi.extras.inflight`, :mod:`fdi.extras.static`, :mod:`fdi.extras.turntable`,
:mod:`fdi.extras.ferraris`, and the shared readers :mod:`fdi.extras.read`.
"""

from fdi.extras.ferraris import (
    FerrarisRecord,
)
from fdi.extras.inflight import (
    ALIGNMENT_UNITS,
    PARAMETER_STATUSES,
    FlightIdentity,
    FlightValues,
    ImuAlignment,
    ImuTiming,
    InflightAlignment,
    InflightTiming,
    LeftOut,
    OffsetCheck,
    OffsetConsistency,
    OffsetPiece,
    ParameterRecord,
    inflight_to_dict,
    offset_check_from_dict,
)
from fdi.extras.record import (
    FERRARIS_LAYOUT,
    INFLIGHT_LAYOUT,
    STATIC_LAYOUT,
    TURNTABLE_LAYOUT,
    TYPED_KEYS,
    CalibrationExtras,
    Method,
    extras_from_dict,
    replace_extras,
)
from fdi.extras.static import (
    ATTRIBUTION_UNIT,
    DriftAttribution,
    OwnDrift,
    StaticAlignment,
    StaticImu,
)
from fdi.extras.turntable import (
    PARITY_SD_KEYS,
    RESIDUAL_UNITS,
    SD_FACTOR_KEYS,
    EarthRateRecord,
    GyroBias,
    NoiseFit,
    NoiseModel,
    RateTest,
    ResidualStep,
)

__all__ = [
    "ALIGNMENT_UNITS",
    "ATTRIBUTION_UNIT",
    "FERRARIS_LAYOUT",
    "INFLIGHT_LAYOUT",
    "PARAMETER_STATUSES",
    "PARITY_SD_KEYS",
    "RESIDUAL_UNITS",
    "SD_FACTOR_KEYS",
    "STATIC_LAYOUT",
    "TURNTABLE_LAYOUT",
    "TYPED_KEYS",
    "CalibrationExtras",
    "DriftAttribution",
    "EarthRateRecord",
    "FerrarisRecord",
    "FlightIdentity",
    "FlightValues",
    "GyroBias",
    "ImuAlignment",
    "ImuTiming",
    "InflightAlignment",
    "InflightTiming",
    "LeftOut",
    "Method",
    "NoiseFit",
    "NoiseModel",
    "OffsetCheck",
    "OffsetConsistency",
    "OffsetPiece",
    "OwnDrift",
    "ParameterRecord",
    "RateTest",
    "ResidualStep",
    "StaticAlignment",
    "StaticImu",
    "extras_from_dict",
    "inflight_to_dict",
    "offset_check_from_dict",
    "replace_extras",
]
