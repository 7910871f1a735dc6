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
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fdi.errors import ConfigError
from fdi.fileio import Fields
from fdi.units import DEG, DPH, DPS, MS, input_unit_factor

__all__ = ["SD_FACTOR_KEYS", "CalibrationExtras", "DriftAttribution", "EarthRateRecord",
           "FerrarisRecord", "FlightIdentity", "GyroBias", "ImuAlignment", "ImuTiming",
           "InflightAlignment", "InflightTiming", "LeftOut", "Method", "NoiseFit", "NoiseModel",
           "OffsetCheck", "OffsetConsistency", "OffsetPiece", "OwnDrift", "RateTest",
           "ResidualStep", "StaticAlignment", "StaticImu", "extras_from_dict",
           "offset_check_from_dict"]

_PREFIX = "extra"
_TYPED = ("earth_rate_fit", "ferraris", "gyro_bias", "inflight", "method", "noise_model",
          "parity_accel_calibrated_sd", "parity_calibrated_sd", "rate_test", "residual_steps",
          "source", "static", "step_residual_chi2_dof", "warnings")
"""Keys of ``extra`` read into types (the others are kept as they are, unchecked)."""


def _plain(obj: Any) -> Any:
    """Numpy arrays and scalars, tuples and mappings to plain Python types (NaN kept), so that
    a record built in memory is checked as its JSON would be."""
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    return obj


def _ms(r: Fields, key: str, default: float | None) -> float | None:
    """A time in ms read as s (null or absent: ``default``, in s)."""
    v = r.number(key, None, finite=False)
    return default if v is None else v * MS


# -- in-flight timing -------------------------------------------------------------------
@dataclass(frozen=True)
class FlightIdentity:
    """The flight an in-flight calibration was fitted on (``extra.inflight.flight``).

    Attributes
    ----------
    source : str
        File name of the source log.
    samples : int
        Number of samples.
    t0_s, t1_s : float
        First and last sample time (s).
    fingerprint : str
        16 hex digits of a sha256 of the times and rates (rounded to 1e-9).
    """

    source: str
    samples: int
    t0_s: float
    t1_s: float
    fingerprint: str

    def to_dict(self) -> dict[str, Any]:
        """The JSON record."""
        return {"source": self.source, "samples": self.samples, "t0_s": self.t0_s,
                "t1_s": self.t1_s, "fingerprint": self.fingerprint}


@dataclass(frozen=True)
class OffsetPiece:
    """The time offset fitted on one piece of the flight alone.

    Attributes
    ----------
    t0_s, t1_s : float
        Span of the piece (s).
    offset_s, sd_s : float or None
        Its offset and sd (s); None when the piece could not be fitted (``note`` says why).
    model : str
        The alignment model used on the piece (``""`` when not fitted).
    note : str
        Why the piece was left out (``""`` when fitted).
    """

    t0_s: float
    t1_s: float
    offset_s: float | None
    sd_s: float | None
    model: str = ""
    note: str = ""


@dataclass(frozen=True)
class OffsetConsistency:
    """The χ² test that the pieces' offsets are one number.

    Attributes
    ----------
    mean_s, sd_internal_s, sd_external_s : float
        Weighted mean of the pieces' offsets, its sd from their sds and from their scatter (s).
    chi2, chi2_dof, p_value, alpha : float
        The statistic, per degree of freedom, its p-value and the level it is tested at.
    dof, pieces_used : int
    """

    mean_s: float
    sd_internal_s: float
    sd_external_s: float
    chi2: float
    dof: int
    chi2_dof: float
    p_value: float
    alpha: float
    pieces_used: int


@dataclass(frozen=True)
class OffsetCheck:
    """The sds and the piece-consistency test of one IMU's time offset
    (``extra.inflight.imus.<imu>.time_offset_check``, written by
    :func:`calibration.inflight.offset_check.check_offset`).

    Attributes
    ----------
    sd_s : float
        The sd reported (s): the largest of the three below.
    sd_hac_s, sd_bootstrap_s, sd_pieces_s : float
        HAC, block-bootstrap and piece-scatter sds (s).
    block_s : float
        Bootstrap block length (s).
    pieces : tuple of OffsetPiece
    consistency : OffsetConsistency or None
        None with fewer than two pieces fitted.
    consistent, widened : bool
        The pieces agree at ``alpha``; the sd is wider than the HAC sd.
    sign : str
        The sign convention of the offsets (one line).
    """

    sd_s: float
    sd_hac_s: float
    sd_bootstrap_s: float
    sd_pieces_s: float
    block_s: float
    pieces: tuple[OffsetPiece, ...]
    consistency: OffsetConsistency | None
    consistent: bool
    widened: bool
    sign: str = ""


@dataclass(frozen=True)
class ImuTiming:
    """The timing of one IMU of an in-flight calibration (``extra.inflight.imus.<imu>``).

    Attributes
    ----------
    time_offset_s : float or None
        The fitted offset τ (s; file: ``time_offset_ms``): the IMU's sample at t matches the
        reference's at ``t + τ``. None when the record has none.
    time_offset_sd_s : float
        Its sd (s; file: ``time_offset_ms_sd``; 0 when not recorded).
    timing_jitter_s : float or None
        sd of the sampling-time error relative to the reference (s; file:
        ``timing_jitter_ms``; None when not recorded).
    timing_jitter_sd_s : float
        Its uncertainty (s; file: ``timing_jitter_ms_sd``; 0 when not recorded).
    check : OffsetCheck or None
        The offset's checks (file: ``time_offset_check``; None when not recorded).
    """

    time_offset_s: float | None
    time_offset_sd_s: float = 0.0
    timing_jitter_s: float | None = None
    timing_jitter_sd_s: float = 0.0
    check: OffsetCheck | None = None


@dataclass(frozen=True)
class InflightTiming:
    """What an in-flight calibration records about timing (``extra.inflight``).

    Attributes
    ----------
    reference : str
        The IMU the others are aligned to (``""`` when not recorded).
    time_offset_sign : str
        The sign convention of the offsets, one line (``""`` when not recorded).
    flight : FlightIdentity or None
        The flight the offsets were fitted on (None when not recorded).
    imus : dict of str to ImuTiming
        Per IMU group other than the reference.
    """

    reference: str = ""
    time_offset_sign: str = ""
    flight: FlightIdentity | None = None
    imus: Mapping[str, ImuTiming] = field(default_factory=dict)

    def time_offsets_s(self) -> dict[str, float]:
        """``{group: τ (s)}`` of the IMUs with a fitted offset."""
        return {g: t.time_offset_s for g, t in self.imus.items()
                if t.time_offset_s is not None}


def _flight(r: Fields) -> FlightIdentity | None:
    if "flight" not in r:
        return None
    f = r.mapping("flight")
    return FlightIdentity(source=f.string("source", "", nonempty=False),
                          samples=f.integer("samples", 0, lo=0),
                          t0_s=f.number("t0_s", 0.0, finite=False),
                          t1_s=f.number("t1_s", 0.0, finite=False),
                          fingerprint=f.string("fingerprint", "", nonempty=False))


def _piece(r: Fields) -> OffsetPiece:
    return OffsetPiece(t0_s=r.number("t0_s", finite=False), t1_s=r.number("t1_s", finite=False),
                       offset_s=_ms(r, "offset_ms", None), sd_s=_ms(r, "sd_ms", None),
                       model=r.string("model", "", nonempty=False),
                       note=r.string("note", "", nonempty=False))


def _consistency(r: Fields) -> OffsetConsistency | None:
    if "consistency" not in r:
        return None
    c = r.mapping("consistency")
    return OffsetConsistency(
        mean_s=_ms(c, "mean_ms", np.nan), sd_internal_s=_ms(c, "sd_internal_ms", np.nan),
        sd_external_s=_ms(c, "sd_external_ms", np.nan),
        chi2=c.number("chi2", np.nan, finite=False), dof=c.integer("dof", 0, lo=0),
        chi2_dof=c.number("chi2_dof", np.nan, finite=False),
        p_value=c.number("p_value", np.nan, finite=False),
        alpha=c.number("alpha", np.nan, finite=False),
        pieces_used=c.integer("pieces_used", 0, lo=0))


def _check(r: Fields) -> OffsetCheck | None:
    if "time_offset_check" not in r or not r.get("time_offset_check"):
        return None
    c = r.mapping("time_offset_check")
    return OffsetCheck(
        sd_s=_ms(c, "sd_ms", np.nan), sd_hac_s=_ms(c, "sd_hac_ms", np.nan),
        sd_bootstrap_s=_ms(c, "sd_bootstrap_ms", np.nan),
        sd_pieces_s=_ms(c, "sd_pieces_ms", 0.0),
        block_s=c.number("block_s", np.nan, finite=False),
        pieces=tuple(_piece(p) for p in c.tables("pieces", [], nonempty=False)),
        consistency=_consistency(c), consistent=c.boolean("consistent", True),
        widened=c.boolean("widened", False), sign=c.string("sign", "", nonempty=False))


def offset_check_from_dict(rec: Mapping[str, Any], path: str = "<offset check>"
                           ) -> OffsetCheck | None:
    """An :class:`OffsetCheck` from its JSON record (what
    :func:`calibration.inflight.offset_check.check_offset` returns); None for an empty one.

    Raises
    ------
    FileFormatError
        A field of the wrong type, named.
    """
    return _check(Fields({"time_offset_check": _plain(rec)}, path))


def _imu_timing(r: Fields) -> ImuTiming:
    return ImuTiming(time_offset_s=_ms(r, "time_offset_ms", None),
                     time_offset_sd_s=_ms(r, "time_offset_ms_sd", 0.0),
                     timing_jitter_s=_ms(r, "timing_jitter_ms", None),
                     timing_jitter_sd_s=_ms(r, "timing_jitter_ms_sd", 0.0),
                     check=_check(r))


def _inflight(r: Fields) -> InflightTiming | None:
    if "inflight" not in r:
        return None
    f = r.mapping("inflight")
    imus = f.mapping("imus", {})
    return InflightTiming(
        reference=f.string("reference", "", nonempty=False),
        time_offset_sign=f.string("time_offset_sign", "", nonempty=False),
        flight=_flight(f), imus={g: _imu_timing(imus.mapping(g)) for g in imus.keys()})


@dataclass(frozen=True)
class LeftOut:
    """A stretch of the flight the in-flight fit left out (``extra.inflight.left_out[k]``).

    Attributes
    ----------
    t0_s, t1_s : float
        Its span (s).
    reason, detail : str
        Why (a short name and one line).
    """

    t0_s: float
    t1_s: float
    reason: str = ""
    detail: str = ""


@dataclass(frozen=True)
class ImuAlignment:
    """The fitted alignment of one IMU to the reference (``extra.inflight.imus.<imu>``).

    The model is ``y_j(t) = A_j · y_ref(t + τ_j) + c_j``; ``A_j ≈ I + [θ]× + scale and
    non-orthogonality`` (:func:`calibration.inflight.fit.decompose`). Vectors are x, y, z;
    empty when the file does not record them.

    Attributes
    ----------
    model : str
        ``"full"``, ``"rotation"``, ...: the alignment model fitted.
    A, A_sd : tuple of tuple of float
        The relative gain matrix (3×3, dimensionless) and its sds.
    rotation, rotation_sd : tuple of float
        Small-angle rotation θ onto the reference (rad).
    scale, scale_sd : tuple of float
        Diagonal of ``A − I`` (fraction).
    nonorthogonality, nonorthogonality_sd : tuple of float
        Off-diagonal symmetric part (rad).
    bias, bias_sd : tuple of float
        ``c_j`` (rad/s; file: ``bias_dph``, ``bias_dph_sd``).
    residual_rms : tuple of float
        RMS of the fit's residual (rad/s; file: ``residual_rms_dps``).
    residual_lag1_autocorrelation : tuple of float
    hac_lags : int
        Lags of the HAC covariance.
    samples : int
        Samples of the fit's residual.
    notes : tuple of str
    """

    model: str = ""
    A: tuple[tuple[float, ...], ...] = ()
    A_sd: tuple[tuple[float, ...], ...] = ()
    rotation: tuple[float, ...] = ()
    rotation_sd: tuple[float, ...] = ()
    scale: tuple[float, ...] = ()
    scale_sd: tuple[float, ...] = ()
    nonorthogonality: tuple[float, ...] = ()
    nonorthogonality_sd: tuple[float, ...] = ()
    bias: tuple[float, ...] = ()
    bias_sd: tuple[float, ...] = ()
    residual_rms: tuple[float, ...] = ()
    residual_lag1_autocorrelation: tuple[float, ...] = ()
    hac_lags: int = 0
    samples: int = 0
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class InflightAlignment:
    """What an in-flight calibration records about the alignment (``extra.inflight``; its
    timing is :class:`InflightTiming`).

    Attributes
    ----------
    imus : dict of str to ImuAlignment
        Per IMU group other than the reference.
    left_out : tuple of LeftOut
    samples_used, samples, samples_nonfinite : int
        Samples the fit used, of the flight, and left out for a non-finite rate.
    """

    imus: Mapping[str, ImuAlignment] = field(default_factory=dict)
    left_out: tuple[LeftOut, ...] = ()
    samples_used: int = 0
    samples: int = 0
    samples_nonfinite: int = 0


def _strings(r: Fields, key: str) -> tuple[str, ...]:
    v = r.get(key, [])
    if not isinstance(v, list):
        raise r.error(key, "expected a list of strings")
    bad = next((k for k, w in enumerate(v, start=1) if not isinstance(w, str)), None)
    if bad is not None:
        raise r.error(f"{key}[{bad}]", "expected a string")
    return tuple(v)


def _imu_alignment(r: Fields) -> ImuAlignment:
    return ImuAlignment(
        model=r.string("model", "", nonempty=False), A=_matrix(r, "A"), A_sd=_matrix(r, "A_sd"),
        **{k: _floats(r, k) for k in ("rotation", "rotation_sd", "scale", "scale_sd",
                                      "nonorthogonality", "nonorthogonality_sd",
                                      "residual_lag1_autocorrelation")},
        bias=_floats(r, "bias_dph", scale=DPH), bias_sd=_floats(r, "bias_dph_sd", scale=DPH),
        residual_rms=_floats(r, "residual_rms_dps", scale=DPS),
        hac_lags=r.integer("hac_lags", 0, lo=0), samples=r.integer("samples", 0, lo=0),
        notes=_strings(r, "notes"))


def _alignment(r: Fields) -> InflightAlignment | None:
    if "inflight" not in r:
        return None
    f = r.mapping("inflight")
    imus = f.mapping("imus", {})
    left = tuple(LeftOut(t0_s=e.number("t0_s", finite=False), t1_s=e.number("t1_s", finite=False),
                         reason=e.string("reason", "", nonempty=False),
                         detail=e.string("detail", "", nonempty=False))
                 for e in f.tables("left_out", [], nonempty=False))
    return InflightAlignment(
        imus={g: _imu_alignment(imus.mapping(g)) for g in imus.keys()}, left_out=left,
        samples_used=f.integer("samples_used", 0, lo=0), samples=f.integer("samples", 0, lo=0),
        samples_nonfinite=f.integer("samples_nonfinite", 0, lo=0))


# -- provenance, warnings ---------------------------------------------------------------
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


@dataclass(frozen=True)
class StaticImu:
    """One IMU of a static (at rest) calibration, relative to the reference
    (``extra.static.imus.<imu>``; degrees and deg/s in the file).

    Attributes
    ----------
    rotation, rotation_sd : tuple of float
        Rotation vector onto the reference and its sd (rad).
    relative_bias : tuple of float
        Bias relative to the reference (rad/s).
    relative_drift, relative_drift_sd : tuple of float
        Change of that bias over the record and its sd (rad/s).
    relative_drift_z, relative_drift_p : tuple of float
        Its z and p-value per axis.
    drift_block_s : float
        Block length of the drift's sd (s).
    drift_hac_lags : int
    """

    rotation: tuple[float, ...] = ()
    rotation_sd: tuple[float, ...] = ()
    relative_bias: tuple[float, ...] = ()
    relative_drift: tuple[float, ...] = ()
    relative_drift_sd: tuple[float, ...] = ()
    relative_drift_z: tuple[float, ...] = ()
    relative_drift_p: tuple[float, ...] = ()
    drift_block_s: float = float("nan")
    drift_hac_lags: int = 0


@dataclass(frozen=True)
class OwnDrift:
    """One IMU's drift relative to the reference (``extra.static.drift_attribution.own``).

    Attributes
    ----------
    drift : tuple of float
        Change over the record (rad/s, body frame of the reference).
    z : tuple of float
        Per axis, drift over its sd.
    p_value : float
        χ² test of the three together.
    """

    drift: tuple[float, ...] = ()
    z: tuple[float, ...] = ()
    p_value: float = float("nan")


@dataclass(frozen=True)
class DriftAttribution:
    """What of the IMUs' drifts relative to the reference is the reference's own
    (``extra.static.drift_attribution``, :func:`calibration.inflight.static.attribute_drift`).

    Attributes
    ----------
    common, common_sd : tuple of float
        The drift every IMU shares relative to the reference (minus the reference's own)
        and its sd (rad/s).
    common_p : float
        Its χ² p-value.
    consistent_chi2, consistent_p : float
        χ² and p-value of the IMUs differing from the common drift.
    consistent_dof : int
    own : dict of str to OwnDrift
    statement : str
        The conclusion, one line.
    """

    common: tuple[float, ...] = ()
    common_sd: tuple[float, ...] = ()
    common_p: float = float("nan")
    consistent_chi2: float = float("nan")
    consistent_dof: int = 0
    consistent_p: float = float("nan")
    own: Mapping[str, OwnDrift] = field(default_factory=dict)
    statement: str = ""


@dataclass(frozen=True)
class StaticAlignment:
    """A static (at rest) calibration's record (``extra.static``).

    Attributes
    ----------
    reference : str
        The IMU the others are aligned to.
    imus : dict of str to StaticImu
        Per IMU other than the reference.
    drift_attribution : DriftAttribution or None
    notes : tuple of str
    alpha : float
        Level of the drift tests.
    bias, bias_sd : tuple of float
        Per sensor (rad/s; file: ``bias_dps``, ``bias_dps_sd``).
    samples : int
    duration_s : float
        Length of the record at rest (s).
    alignment_full : bool
        The full rotation was observable (gravity alone leaves the rotation about it free).
    """

    reference: str = ""
    imus: Mapping[str, StaticImu] = field(default_factory=dict)
    drift_attribution: DriftAttribution | None = None
    notes: tuple[str, ...] = ()
    alpha: float = float("nan")
    bias: tuple[float, ...] = ()
    bias_sd: tuple[float, ...] = ()
    samples: int = 0
    duration_s: float = float("nan")
    alignment_full: bool = True


def _method(r: Fields) -> Method:
    v = r.get("method", "")
    if isinstance(v, str):
        return Method(text=v)
    m = r.mapping("method")
    return Method(parts={k: m.string(k, "", nonempty=False) for k in m.keys()})


def _static_imu(r: Fields) -> StaticImu:
    return StaticImu(
        rotation=_floats(r, "rotation_deg", scale=DEG),
        rotation_sd=_floats(r, "rotation_deg_sd", scale=DEG),
        relative_bias=_floats(r, "relative_bias_dps", scale=DPS),
        relative_drift=_floats(r, "relative_drift_dps", scale=DPS),
        relative_drift_sd=_floats(r, "relative_drift_dps_sd", scale=DPS),
        relative_drift_z=_floats(r, "relative_drift_z"),
        relative_drift_p=_floats(r, "relative_drift_p"),
        drift_block_s=r.number("drift_block_s", float("nan"), finite=False),
        drift_hac_lags=r.integer("drift_hac_lags", 0, lo=0))


def _attribution(r: Fields) -> DriftAttribution | None:
    if "drift_attribution" not in r:
        return None
    a = r.mapping("drift_attribution")
    own = a.mapping("own", {})
    nan = float("nan")

    def own_drift(o: Fields) -> OwnDrift:
        return OwnDrift(drift=_floats(o, "drift", scale=DPS), z=_floats(o, "z"),
                        p_value=o.number("p_value", nan, finite=False))

    return DriftAttribution(
        common=_floats(a, "common", scale=DPS), common_sd=_floats(a, "common_sd", scale=DPS),
        common_p=a.number("common_p", nan, finite=False),
        consistent_chi2=a.number("consistent_chi2", nan, finite=False),
        consistent_dof=a.integer("consistent_dof", 0, lo=0),
        consistent_p=a.number("consistent_p", nan, finite=False),
        own={g: own_drift(own.mapping(g)) for g in own.keys()},
        statement=a.string("statement", "", nonempty=False))


def _static(r: Fields) -> StaticAlignment | None:
    if "static" not in r:
        return None
    s = r.mapping("static")
    imus = s.mapping("imus", {})
    return StaticAlignment(
        reference=s.string("reference", "", nonempty=False),
        imus={g: _static_imu(imus.mapping(g)) for g in imus.keys()},
        drift_attribution=_attribution(s), notes=_strings(s, "notes"),
        alpha=s.number("alpha", float("nan"), finite=False),
        bias=_floats(s, "bias_dps", scale=DPS), bias_sd=_floats(s, "bias_dps_sd", scale=DPS),
        samples=s.integer("samples", 0, lo=0),
        duration_s=s.number("duration_s", float("nan"), finite=False),
        alignment_full=s.boolean("alignment_full", True))


# -- noise model -------------------------------------------------------------------------
SD_FACTOR_KEYS = ("bias", "scale_factor", "misalignment")
"""The estimates whose sd the coloured noise widens (``sd_factor`` keys)."""


@dataclass(frozen=True)
class NoiseFit:
    """What the noise model did to one sensor set (``extra.noise_model.<kind>``).

    Attributes
    ----------
    applied : bool
        The first-order Gauss-Markov bias was kept (else white noise).
    bias_instability : float
        σ_b of the fit (SI: rad/s or m/s²; 0 when not fitted).
    correlation_s : float or None
        Its correlation time (s).
    likelihood_ratio : float or None
        The likelihood-ratio statistic against white noise.
    sigma_bias_instability : float or None
        σ_b (SI) of the pair the estimates' sds were computed with (None: not applied).
    sigma_correlation_s : float or None
        The correlation time (s) of that pair.
    sigma_cut : bool
        The correlation time's profile interval was cut at a quarter of the record.
    record_s : float or None
        Length of the residual record the fit saw (s).
    sd_factor : dict of str to tuple of float
        Per :data:`SD_FACTOR_KEYS`, per sensor: sd with the model over the white-noise sd.
    """

    applied: bool = False
    bias_instability: float = 0.0
    correlation_s: float | None = None
    likelihood_ratio: float | None = None
    sigma_bias_instability: float | None = None
    sigma_correlation_s: float | None = None
    sigma_cut: bool = False
    record_s: float | None = None
    sd_factor: Mapping[str, tuple[float, ...]] = field(default_factory=dict)


@dataclass(frozen=True)
class NoiseModel:
    """The noise model of a turntable calibration (``extra.noise_model``).

    Attributes
    ----------
    method : str
        What was fitted and how (one line).
    sets : dict of str to NoiseFit
        Per sensor kind (``"gyro"``, ``"accel"``).
    """

    method: str = ""
    sets: Mapping[str, NoiseFit] = field(default_factory=dict)


def _opt(r: Fields, key: str) -> float | None:
    return r.number(key, None, finite=False)


def _noise_fit(r: Fields) -> NoiseFit:
    sdf = r.mapping("sd_factor", {})
    factors = {k: tuple(float(x) for x in sdf.array(k, (None,), finite=False))
               for k in sdf.keys()}
    return NoiseFit(applied=r.boolean("applied", False),
                    bias_instability=r.number("bias_instability", 0.0, finite=False),
                    correlation_s=_opt(r, "correlation_s"),
                    likelihood_ratio=_opt(r, "likelihood_ratio"),
                    sigma_bias_instability=_opt(r, "sigma_bias_instability"),
                    sigma_correlation_s=_opt(r, "sigma_correlation_s"),
                    sigma_cut=r.boolean("sigma_cut", False), record_s=_opt(r, "record_s"),
                    sd_factor=factors)


def _noise_model(r: Fields) -> NoiseModel | None:
    if "noise_model" not in r:
        return None
    m = r.mapping("noise_model")
    return NoiseModel(method=m.string("method", "", nonempty=False),
                      sets={k: _noise_fit(m.mapping(k)) for k in m.keys() if k != "method"})


# -- turntable fit checks -----------------------------------------------------------------
@dataclass(frozen=True)
class RateTest:
    """The rate-step pairs of a turntable calibration (``extra.rate_test``).

    Attributes
    ----------
    pairs : tuple of (int, int)
        1-based step numbers of each pair.
    rates : tuple of (float, float, float)
        The input rate of each pair (rad/s, MB frame; file: ``R_rad_s``).
    chi2_dof : tuple of float
        Per sensor, χ²/dof of the step differences about the fit.
    """

    pairs: tuple[tuple[int, int], ...] = ()
    rates: tuple[tuple[float, ...], ...] = ()
    chi2_dof: tuple[float, ...] = ()


@dataclass(frozen=True)
class ResidualStep:
    """Residual (compensated output − model) statistics of one step
    (``extra.residual_steps.<kind>[k]``).

    Attributes
    ----------
    step : int
        1-based step number.
    label, kind : str
        The step's label and kind (``"rate"``, ``"position"``).
    n : int
        Samples used.
    mean, rms : tuple of float
        Per sensor (SI: rad/s or m/s²).
    """

    step: int
    label: str
    kind: str
    n: int
    mean: tuple[float, ...]
    rms: tuple[float, ...]


@dataclass(frozen=True)
class EarthRateRecord:
    """The Earth rate recovered from the outer-axis modulation (``extra.earth_rate_fit``,
    :meth:`calibration.earth_rate.EarthRateFit.to_dict`; deg/h and deg in the file).

    Attributes
    ----------
    rate, rate_sd : float
        Magnitude and sd (rad/s).
    horizontal : float or None
        Horizontal component (rad/s); None when not recorded.
    horizontal_sd, scatter_sd : float
        Its sd and the per-step scatter sd (rad/s; 0 when not recorded).
    heading_offset, heading_offset_sd : float
        Heading of the table's zero and its sd (rad).
    steps : tuple of int
        1-based outer-axis steps used.
    per_step : tuple of float
        Rate per step (rad/s).
    n_samples : int
    denoised : bool
    """

    rate: float = float("nan")
    rate_sd: float = float("nan")
    horizontal: float | None = None
    horizontal_sd: float = 0.0
    heading_offset: float = float("nan")
    heading_offset_sd: float = float("nan")
    steps: tuple[int, ...] = ()
    per_step: tuple[float, ...] = ()
    scatter_sd: float = 0.0
    n_samples: int = 0
    denoised: bool = False


@dataclass(frozen=True)
class GyroBias:
    """The gyro biases by both methods of a turntable calibration (``extra.gyro_bias``).

    Attributes
    ----------
    unit : str
        The unit the file writes them in (the calibration file's bias unit).
    model, model_sd : tuple of float
        Per sensor, the bias of the Earth-rate model and its sd (rad/s).
    turns, turns_sd : tuple of float or None
        By seed 000's whole outer-axis turns (rad/s); None without whole turns.
    turns_steps, turns_per_step : tuple of int
        The steps with whole turns and their number of turns.
    vertical_correction : tuple of float or None
        The vertical Earth rate removed from the turns estimate (rad/s).
    """

    unit: str
    model: tuple[float, ...]
    model_sd: tuple[float, ...]
    turns: tuple[float, ...] | None = None
    turns_sd: tuple[float, ...] | None = None
    turns_steps: tuple[int, ...] = ()
    turns_per_step: tuple[int, ...] = ()
    vertical_correction: tuple[float, ...] | None = None


def _floats(r: Fields, key: str, default: Any = (), scale: float = 1.0) -> Any:
    """A list of numbers (null: NaN) as a tuple of float times ``scale``."""
    v = r.get(key, None)
    if v is None:
        return default
    if not isinstance(v, list) or any(x is not None and (isinstance(x, bool) or not
                                                         isinstance(x, int | float))
                                      for x in v):
        raise r.error(key, "expected a list of numbers")
    return tuple(float("nan") if x is None else float(x) * scale for x in v)


def _ints(r: Fields, key: str) -> tuple[int, ...]:
    v = r.get(key, [])
    if not isinstance(v, list) or any(isinstance(x, bool) or not isinstance(x, int)
                                      for x in v):
        raise r.error(key, "expected a list of integers")
    return tuple(v)


def _matrix(r: Fields, key: str) -> tuple[tuple[float, ...], ...]:
    """A list of rows of numbers (null: NaN); ``[]`` gives ``()``."""
    v = r.get(key, [])
    if not isinstance(v, list):
        raise r.error(key, "expected a list of rows of numbers")
    names = [f"{r.name(key)}[{k}]" for k in range(1, len(v) + 1)]
    rows = Fields(dict(zip(names, v, strict=True)), r.path)
    return tuple(_floats(rows, k) for k in names)


def _rate_test(r: Fields) -> RateTest | None:
    if "rate_test" not in r:
        return None
    t = r.mapping("rate_test")
    pairs = _matrix(t, "pairs")
    if any(len(p) != 2 or any(not float(x).is_integer() for x in p) for p in pairs):
        raise t.error("pairs", "expected pairs of step numbers")
    return RateTest(pairs=tuple((int(a), int(b)) for a, b in pairs), rates=_matrix(t, "R_rad_s"),
                    chi2_dof=_floats(t, "chi2_dof"))


def _residual_steps(r: Fields) -> dict[str, tuple[ResidualStep, ...]]:
    if "residual_steps" not in r:
        return {}
    m = r.mapping("residual_steps")
    m.accept("unit")
    return {k: tuple(ResidualStep(step=e.integer("step"), label=e.string("label", "",
                                                                         nonempty=False),
                                  kind=e.string("kind", "", nonempty=False),
                                  n=e.integer("n", 0, lo=0), mean=_floats(e, "mean"),
                                  rms=_floats(e, "rms"))
                     for e in m.tables(k, [], nonempty=False))
            for k in m.keys() if k != "unit"}


def _earth_rate(r: Fields) -> EarthRateRecord | None:
    if "earth_rate_fit" not in r:
        return None
    e = r.mapping("earth_rate_fit")
    nan = float("nan")

    def dph(key: str, default: float | None) -> float | None:
        v = e.number(key, None, finite=False)
        return default if v is None else v * DPH

    def deg(key: str) -> float:
        return e.number(key, nan, finite=False) * DEG

    return EarthRateRecord(
        rate=dph("rate_dph", nan), rate_sd=dph("rate_dph_sd", nan),
        horizontal=dph("horizontal_dph", None), horizontal_sd=dph("horizontal_dph_sd", 0.0),
        heading_offset=deg("heading_offset_deg"), heading_offset_sd=deg("heading_offset_deg_sd"),
        steps=_ints(e, "steps"), per_step=_floats(e, "per_step_dph", scale=DPH),
        scatter_sd=dph("scatter_sd_dph", 0.0), n_samples=e.integer("n_samples", 0, lo=0),
        denoised=e.boolean("denoised", False))


def _gyro_bias(r: Fields) -> GyroBias | None:
    if "gyro_bias" not in r:
        return None
    g = r.mapping("gyro_bias")
    unit = g.string("unit")
    try:
        f = input_unit_factor(unit)
    except ConfigError as exc:
        raise g.error("unit", str(exc)) from None
    turns = _floats(g, "turns", None, f)
    return GyroBias(unit=unit, model=_floats(g, "model", (), f),
                    model_sd=_floats(g, "model_sd", (), f), turns=turns,
                    turns_sd=_floats(g, "turns_sd", None, f),
                    turns_steps=_ints(g, "turns_steps"),
                    turns_per_step=_ints(g, "turns_per_step"),
                    vertical_correction=_floats(g, "vertical_correction", None, f))


def _parity_sd(r: Fields) -> dict[str, tuple[tuple[float, ...], ...]]:
    out = {}
    for kind, key in (("gyro", "parity_calibrated_sd"), ("accel", "parity_accel_calibrated_sd")):
        if key in r:
            out[kind] = _matrix(r, key)
    return out


# -- Ferraris ---------------------------------------------------------------------------
@dataclass(frozen=True)
class FerrarisRecord:
    """The settings and checks of a Ferraris calibration (``extra.ferraris``, degrees in the
    file).

    Attributes
    ----------
    rotation : float
        Nominal rotation about each axis (rad; imucal's −2π: clockwise seen from above).
    gravity : float
        Local gravity (m/s²).
    position_sd, angle_sd : float
        Stated sd of the static positions and of the rotation angles (rad).
    earth_rate_in_sd : bool
        The Earth rate is counted as an uncertainty of the gyro means.
    latitude : float or None
        Latitude (rad) whose vertical Earth rate was removed (None: not removed).
    g_sensitivity_raw_per_m_s2, g_sensitivity_raw_per_m_s2_sd : tuple of tuple of float
        Gyro g-sensitivity per sensor, raw units per m/s² (shape (n, 3)), and its sd.
    chi2_dof : dict of str to tuple of float
        Per sensor kind, χ²/dof of the static fits.
    chi2_dof_dof : int
        Their degrees of freedom per sensor.
    rotation_dof : int
        Spare degrees of freedom of the rotations.
    """

    rotation: float
    gravity: float
    position_sd: float
    angle_sd: float
    earth_rate_in_sd: bool = True
    latitude: float | None = None
    g_sensitivity_raw_per_m_s2: tuple[tuple[float, ...], ...] = ()
    g_sensitivity_raw_per_m_s2_sd: tuple[tuple[float, ...], ...] = ()
    chi2_dof: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    chi2_dof_dof: int = 0
    rotation_dof: int = 0


def _ferraris(r: Fields) -> FerrarisRecord | None:
    if "ferraris" not in r:
        return None
    f = r.mapping("ferraris")
    lat = f.number("latitude_deg", None)
    c = f.mapping("chi2_dof", {})
    return FerrarisRecord(
        rotation=f.number("rotation_deg") * DEG, gravity=f.number("gravity_m_s2", positive=True),
        position_sd=f.number("position_sd_deg", nonnegative=True) * DEG,
        angle_sd=f.number("angle_sd_deg", nonnegative=True) * DEG,
        earth_rate_in_sd=f.boolean("earth_rate_in_sd", True),
        latitude=None if lat is None else lat * DEG,
        g_sensitivity_raw_per_m_s2=_matrix(f, "g_sensitivity_raw_per_m_s2"),
        g_sensitivity_raw_per_m_s2_sd=_matrix(f, "g_sensitivity_raw_per_m_s2_sd"),
        chi2_dof={k: _floats(c, k) for k in c.keys() if k != "dof"},
        chi2_dof_dof=c.integer("dof", 0, lo=0), rotation_dof=f.integer("rotation_dof", 0, lo=0))


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
    r = Fields({k: _plain(extra[k]) for k in _TYPED if k in extra}, path, _PREFIX)
    return CalibrationExtras(inflight=_inflight(r), inflight_alignment=_alignment(r),
                             warnings=_strings(r, "warnings"),
                             source=r.string("source", "", nonempty=False),
                             method=_method(r), static=_static(r),
                             noise_model=_noise_model(r), rate_test=_rate_test(r),
                             step_residual_chi2_dof=_floats(r, "step_residual_chi2_dof"),
                             residual_steps=_residual_steps(r),
                             earth_rate_fit=_earth_rate(r), gyro_bias=_gyro_bias(r),
                             parity_sd=_parity_sd(r), ferraris=_ferraris(r))
