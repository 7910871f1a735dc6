"""Typed records of an in-flight calibration (``extra.inflight``): the time offsets with their
checks and the flight they belong to (:class:`InflightTiming`), and the alignment of each IMU
to the reference (:class:`InflightAlignment`). Times in s (``_ms`` in the file), angles in
rad, rates in rad/s (``_dph``, ``_dps`` in the file)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fdi.extras.read import floats, matrix, ms_field, plain, strings
from fdi.fileio import Fields
from fdi.units import DPH, DPS, MS

__all__ = ["ALIGNMENT_UNITS", "PARAMETER_STATUSES", "FlightIdentity", "FlightValues",
           "ImuAlignment", "ImuTiming", "InflightAlignment", "InflightTiming", "LeftOut",
           "OffsetCheck", "OffsetConsistency", "OffsetPiece", "ParameterRecord",
           "inflight_to_dict", "offset_check_from_dict", "read_inflight_alignment",
           "read_inflight_timing"]

PARAMETER_STATUSES = ("estimated", "held at prior")
"""``extra.inflight.imus.<imu>.parameters[k].status``: from the flight, or the prior's."""

ALIGNMENT_UNITS = {"rotation": "rad", "scale": "fraction", "nonorthogonality": "rad"}
"""``extra.inflight.units``: the units of the parts of the gain matrix."""


def _ms(x: float | None) -> float | None:
    """s to the file's ms, as the offset checks write them (``1e3 · x``)."""
    return None if x is None else 1e3 * x


def _rows(m: tuple[tuple[float, ...], ...]) -> list[list[float]]:
    return [list(r) for r in m]


def _per(v: tuple[float, ...], unit: float) -> list[float]:
    return (np.asarray(v, float) / unit).tolist()


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
    firmware : str
        The firmware the log names (:func:`replay.firmware.firmware_of`); ``""`` when it
        names none (the file then carries no ``firmware`` field).
    """

    source: str
    samples: int
    t0_s: float
    t1_s: float
    fingerprint: str
    firmware: str = ""

    def to_dict(self) -> dict[str, Any]:
        """The JSON record."""
        return {"source": self.source, "samples": self.samples, "t0_s": self.t0_s,
                "t1_s": self.t1_s, "fingerprint": self.fingerprint,
                **({"firmware": self.firmware} if self.firmware else {})}


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

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (ms): ``model`` when fitted, ``note`` when not."""
        tail = {"note": self.note} if self.offset_s is None else {"model": self.model}
        return {"t0_s": self.t0_s, "t1_s": self.t1_s, "offset_ms": _ms(self.offset_s),
                "sd_ms": _ms(self.sd_s), **tail}


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

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (ms)."""
        return {"mean_ms": _ms(self.mean_s), "sd_internal_ms": _ms(self.sd_internal_s),
                "sd_external_ms": _ms(self.sd_external_s), "chi2": self.chi2, "dof": self.dof,
                "chi2_dof": self.chi2_dof, "p_value": self.p_value, "alpha": self.alpha,
                "pieces_used": self.pieces_used}


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

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (``time_offset_check``; ms)."""
        return {"sd_ms": _ms(self.sd_s), "sd_hac_ms": _ms(self.sd_hac_s),
                "sd_bootstrap_ms": _ms(self.sd_bootstrap_s), "sd_pieces_ms": _ms(self.sd_pieces_s),
                "block_s": self.block_s, "pieces": [p.to_dict() for p in self.pieces],
                "consistency": None if self.consistency is None else self.consistency.to_dict(),
                "consistent": self.consistent, "widened": self.widened, "sign": self.sign}


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
                          fingerprint=f.string("fingerprint", "", nonempty=False),
                          firmware=f.string("firmware", "", nonempty=False))


def _piece(r: Fields) -> OffsetPiece:
    return OffsetPiece(t0_s=r.number("t0_s", finite=False), t1_s=r.number("t1_s", finite=False),
                       offset_s=ms_field(r, "offset_ms", None), sd_s=ms_field(r, "sd_ms", None),
                       model=r.string("model", "", nonempty=False),
                       note=r.string("note", "", nonempty=False))


def _consistency(r: Fields) -> OffsetConsistency | None:
    if "consistency" not in r:
        return None
    c = r.mapping("consistency")
    return OffsetConsistency(
        mean_s=ms_field(c, "mean_ms", np.nan), sd_internal_s=ms_field(c, "sd_internal_ms", np.nan),
        sd_external_s=ms_field(c, "sd_external_ms", np.nan),
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
        sd_s=ms_field(c, "sd_ms", np.nan), sd_hac_s=ms_field(c, "sd_hac_ms", np.nan),
        sd_bootstrap_s=ms_field(c, "sd_bootstrap_ms", np.nan),
        sd_pieces_s=ms_field(c, "sd_pieces_ms", 0.0),
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
    return _check(Fields({"time_offset_check": plain(rec)}, path))


def _imu_timing(r: Fields) -> ImuTiming:
    return ImuTiming(time_offset_s=ms_field(r, "time_offset_ms", None),
                     time_offset_sd_s=ms_field(r, "time_offset_ms_sd", 0.0),
                     timing_jitter_s=ms_field(r, "timing_jitter_ms", None),
                     timing_jitter_sd_s=ms_field(r, "timing_jitter_ms_sd", 0.0),
                     check=_check(r))


def read_inflight_timing(r: Fields) -> InflightTiming | None:
    """The timing part of ``extra.inflight`` (None when absent)."""
    if "inflight" not in r:
        return None
    f = r.mapping("inflight")
    imus = f.mapping("imus", {})
    return InflightTiming(
        reference=f.string("reference", "", nonempty=False),
        time_offset_sign=f.string("time_offset_sign", "", nonempty=False),
        flight=_flight(f), imus={g: _imu_timing(imus.mapping(g)) for g in imus.keys()})


# -- in-flight alignment ----------------------------------------------------------------
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

    def to_dict(self) -> dict[str, Any]:
        """The JSON record."""
        return {"t0_s": self.t0_s, "t1_s": self.t1_s, "reason": self.reason,
                "detail": self.detail}


@dataclass(frozen=True)
class ParameterRecord:
    """One parameter of an IMU's alignment (``extra.inflight.imus.<imu>.parameters[k]``).

    Attributes
    ----------
    name : str
        ``"rotation x"`` ... ``"nonorthogonality yz"``, ``"time offset"``.
    value, sd, prior_sd : float
        rad, fraction, or s for the time offset (file: ``value``, ``sd``, ``prior_sd``; the
        time offset in ms).
    status : str
        One of :data:`PARAMETER_STATUSES`.
    excitation : float or None
        RMS variation of its regressor over the reference noise (None: unbounded).
    """

    name: str
    value: float
    sd: float
    prior_sd: float
    status: str
    excitation: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (the time offset in ms)."""
        f = 1e3 if self.name == "time offset" else 1.0
        return {"name": self.name, "value": f * self.value, "sd": f * self.sd,
                "prior_sd": f * self.prior_sd, "status": self.status,
                "excitation": self.excitation}


_FLIGHT_KEYS = {"bias_dph": DPH, "bias_dph_sd": DPH, "time_offset_ms": MS,
                "time_offset_ms_sd": MS, "timing_jitter_ms": MS, "rotation": 1.0,
                "rotation_sd": 1.0, "scale": 1.0, "scale_sd": 1.0, "nonorthogonality": 1.0,
                "nonorthogonality_sd": 1.0}
"""Keys of ``extra.inflight.flights[k].imus.<imu>`` and their unit in SI."""


@dataclass(frozen=True)
class FlightValues:
    """What one flight of several calibrated together gave (``extra.inflight.flights[k]``).

    Attributes
    ----------
    source : str
        The flight folder.
    flight : FlightIdentity or None
    imus : dict of str to dict
        Per IMU group other than the reference: ``bias`` and ``bias_sd`` (rad/s, file
        ``bias_dph``), ``time_offset_s`` and its sd, ``timing_jitter_s`` (file ms),
        ``rotation``, ``scale`` and ``nonorthogonality`` with their sds (rad, fraction).
    """

    source: str
    flight: FlightIdentity | None = None
    imus: Mapping[str, Mapping[str, tuple[float, ...]]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The JSON record."""
        return {"source": self.source,
                **({} if self.flight is None else {"flight": self.flight.to_dict()}),
                "imus": {g: {k: _per(v[k], _FLIGHT_KEYS[k]) for k in _FLIGHT_KEYS if k in v}
                         for g, v in self.imus.items()}}


def _flight_values(r: Fields) -> FlightValues:
    imus = r.mapping("imus", {})
    out = {}
    for g in imus.keys():
        m = imus.mapping(g)
        out[g] = {k: floats(m, k, scale=u) for k, u in _FLIGHT_KEYS.items() if k in m}
        m.finish()
    fv = FlightValues(source=r.string("source", "", nonempty=False), flight=_flight(r),
                      imus=out)
    return fv


def _parameter(r: Fields) -> ParameterRecord:
    name = r.string("name")
    f = MS if name == "time offset" else 1.0
    status = r.string("status")
    if status not in PARAMETER_STATUSES:
        raise r.error("status", f"expected one of {', '.join(PARAMETER_STATUSES)}, "
                      f"got {status!r}")
    ex = r.number("excitation", None, nonnegative=True)
    return ParameterRecord(name=name, value=r.number("value") * f,
                           sd=r.number("sd", nonnegative=True) * f,
                           prior_sd=r.number("prior_sd", nonnegative=True) * f,
                           status=status, excitation=ex)


def _mounting(r: Fields) -> tuple[tuple[float, ...], ...]:
    """``mounting``: a signed permutation (rotation by multiples of 90°); () when absent."""
    m = matrix(r, "mounting")
    if not m:
        return ()
    M = np.asarray(m, float)
    ok = (M.shape == (3, 3) and np.all(np.isin(M, (-1.0, 0.0, 1.0)))
          and np.all(np.sum(np.abs(M), axis=0) == 1) and np.all(np.sum(np.abs(M), axis=1) == 1)
          and round(float(np.linalg.det(M))) == 1)
    if not ok:
        raise r.error("mounting", "expected a 3x3 rotation by multiples of 90 deg (one +1 or "
                      f"-1 per row and column, determinant +1), got {m!r}")
    return m


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
    mounting : tuple of tuple of float
        The nominal mounting R (a rotation by multiples of 90°, ``A = (I + E)·R``; the
        parts above are those of E; ``()``: identity, not recorded).
    parameters : tuple of ParameterRecord
        Each parameter estimated or held at the prior.
    axis_noise : tuple of float
        The IMU's own noise sd per axis in flight (rad/s; file ``axis_noise_dps``).
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
    excitation: Mapping[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    mounting: tuple[tuple[float, ...], ...] = ()
    parameters: tuple[ParameterRecord, ...] = ()
    axis_noise: tuple[float, ...] = ()


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
    findings : tuple of str
        IMU axes far noisier than their peers (``"imu1.x: 9.5 deg/s vibration against ..."``).
    reference_noise : tuple of float
        The reference's own noise sd per axis (rad/s; file ``reference_noise_dps``).
    prior : dict
        The prior's sds (``misalignment_mrad_sd``, ``scale_sd``, ``nonorthogonality_mrad_sd``,
        ``time_offset_ms_sd``).
    window_s : tuple of float
        ``(t0, t1)`` the part of the record used (s), ``()`` for all of it.
    flights : tuple of FlightValues
        With several flights calibrated together: each flight's own values.
    """

    imus: Mapping[str, ImuAlignment] = field(default_factory=dict)
    left_out: tuple[LeftOut, ...] = ()
    samples_used: int = 0
    samples: int = 0
    samples_nonfinite: int = 0
    findings: tuple[str, ...] = ()
    reference_noise: tuple[float, ...] = ()
    prior: Mapping[str, float] = field(default_factory=dict)
    window_s: tuple[float, ...] = ()
    flights: tuple[FlightValues, ...] = ()


def _imu_alignment(r: Fields) -> ImuAlignment:
    return ImuAlignment(
        model=r.string("model", "", nonempty=False), A=matrix(r, "A"), A_sd=matrix(r, "A_sd"),
        **{k: floats(r, k) for k in ("rotation", "rotation_sd", "scale", "scale_sd",
                                      "nonorthogonality", "nonorthogonality_sd",
                                      "residual_lag1_autocorrelation")},
        bias=floats(r, "bias_dph", scale=DPH), bias_sd=floats(r, "bias_dph_sd", scale=DPH),
        residual_rms=floats(r, "residual_rms_dps", scale=DPS),
        hac_lags=r.integer("hac_lags", 0, lo=0), samples=r.integer("samples", 0, lo=0),
        excitation=r.free("excitation", {}), notes=strings(r, "notes"),
        mounting=_mounting(r),
        parameters=tuple(_parameter(p) for p in r.tables("parameters", [], nonempty=False)),
        axis_noise=floats(r, "axis_noise_dps", scale=DPS))


def read_inflight_alignment(r: Fields) -> InflightAlignment | None:
    """The alignment part of ``extra.inflight`` (None when absent)."""
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
        samples_nonfinite=f.integer("samples_nonfinite", 0, lo=0),
        findings=strings(f, "findings"),
        reference_noise=floats(f, "reference_noise_dps", scale=DPS),
        prior={k: f.mapping("prior").number(k, nonnegative=True)
               for k in f.mapping("prior", {}).keys()} if "prior" in f else {},
        window_s=floats(f, "window_s"),
        flights=tuple(_flight_values(e) for e in f.tables("flights", [], nonempty=False)))



# -- writing ----------------------------------------------------------------------------
_PARTS = ("rotation", "scale", "nonorthogonality")


def _imu_to_dict(t: ImuTiming | None, a: ImuAlignment | None) -> dict[str, Any]:
    """One IMU's record: its alignment and timing, interleaved as the file lists them."""
    a = ImuAlignment() if a is None else a
    t = ImuTiming(None) if t is None else t
    jit = None if t.timing_jitter_s is None else t.timing_jitter_s / MS
    return {"model": a.model, "A": _rows(a.A), "A_sd": _rows(a.A_sd),
            **{k: list(getattr(a, k)) for k in _PARTS},
            **{f"{k}_sd": list(getattr(a, f"{k}_sd")) for k in _PARTS},
            "bias_dph": _per(a.bias, DPH), "bias_dph_sd": _per(a.bias_sd, DPH),
            "time_offset_ms": _ms(t.time_offset_s), "time_offset_ms_sd": _ms(t.time_offset_sd_s),
            "time_offset_check": {} if t.check is None else t.check.to_dict(),
            "timing_jitter_ms": jit, "timing_jitter_ms_sd": t.timing_jitter_sd_s / MS,
            "residual_rms_dps": _per(a.residual_rms, DPS),
            "residual_lag1_autocorrelation": list(a.residual_lag1_autocorrelation),
            "hac_lags": a.hac_lags, "samples": a.samples, "excitation": dict(a.excitation),
            "notes": list(a.notes),
            **({"mounting": _rows(a.mounting)} if a.mounting else {}),
            **({"parameters": [p.to_dict() for p in a.parameters]} if a.parameters else {}),
            **({"axis_noise_dps": _per(a.axis_noise, DPS)} if a.axis_noise else {})}


def inflight_to_dict(timing: InflightTiming | None,
                     alignment: InflightAlignment | None) -> dict[str, Any]:
    """The JSON record ``extra.inflight`` of the timing and alignment of an in-flight
    calibration (ms, deg/h, deg/s in the file; either part may be None)."""
    timing = InflightTiming() if timing is None else timing
    alignment = InflightAlignment() if alignment is None else alignment
    imus = dict.fromkeys([*alignment.imus, *timing.imus])
    flight = {} if timing.flight is None else {"flight": timing.flight.to_dict()}
    return {"reference": timing.reference, "units": dict(ALIGNMENT_UNITS),
            "time_offset_sign": timing.time_offset_sign, **flight,
            "imus": {g: _imu_to_dict(timing.imus.get(g), alignment.imus.get(g)) for g in imus},
            "left_out": [e.to_dict() for e in alignment.left_out],
            "samples_used": alignment.samples_used, "samples": alignment.samples,
            "samples_nonfinite": alignment.samples_nonfinite,
            **({"findings": list(alignment.findings)} if alignment.findings else {}),
            **({"reference_noise_dps": _per(alignment.reference_noise, DPS)}
               if alignment.reference_noise else {}),
            **({"prior": dict(alignment.prior)} if alignment.prior else {}),
            **({"window_s": list(alignment.window_s)} if alignment.window_s else {}),
            **({"flights": [v.to_dict() for v in alignment.flights]}
               if alignment.flights else {})}
