"""The calibration file ``rimu.calibration/3``: what the calibration produces and the runtime reads.

Model per sensor (seed 000 Eq. 13, seed 001 Eq. 1), internally in SI::

    SF_i · u_i = h̃_i · x + b_i + η_i

``u_i`` the raw output (mV, LSB, ...), ``x`` the input (body rate in rad/s for gyros,
specific force in m/s² for accelerometers, MB frame), ``SF_i`` the scale factor in *input
per raw unit*, ``h̃_i`` the calibrated unit input axis, ``b_i`` the bias in input units.
The compensated output the runtime uses is ``y_i = SF_i·u_i − b_i``.

In the JSON file each value carries its unit (``scale_factor_unit``, ``bias_unit``); arrays
are nested lists. Keys other tools read (keep them stable)::

    {"schema": "rimu.calibration/3",
     "sensors": {"gyro": [{"name", "axis", "axis_nominal", "misalignment_mrad",
                           "misalignment_mrad_sd", "scale_factor", "scale_factor_sd",
                           "scale_factor_unit", "bias", "bias_sd", "bias_unit",
                           "input_error_cov", "raw_unit", "residual_rms"}, ...],
                 "accel": [...]},
     "noise_covariance": {"gyro": [[...]], "accel": [[...]], "unit": {...},
                          "sample_rate_hz": 100.0},
     "parity": {"nominal": V, "calibrated": V_c},   # gyros; accelerometers: "parity_accel"
     "misalignment_matrices": {"gyro": [{"sensors": [1, 2, 3], "M": [[...]]}], ...},
     "allan": {"gyro": {"tau_s": [...], "adev": [[...] per tau]}, ...},
     "earth_rate_dph": 15.04, "earth_rate_dph_sd": 0.3, ...}

Version 2 adds two optional top-level keys (a ``/1`` file loads as a calibration with no
effects and no adequacy record; it is migrated on the next save)::

     "effects": [{"name": "bias_drift", "kind": "gyro", "sensor": 2,      # 1-based in files
                  "estimate": 3.1, "estimate_sd": 0.4, "unit": "deg/h",
                  "inputs": ["time"], "params": {...}}, ...],
     "adequacy": {"verdict": one of fdi.adequacy.VERDICTS, ...details}

Version 3 adds one optional top-level key, the residual's tail per window scale (a ``/2``
file loads without it; :mod:`fdi.tails`, ``docs/noise-tails.md``)::

     "residual_tails": {"gyro": {"method": "rimu.tails/1", "df": 3, "samples": 6431,
                                 "scales": [{"scale": 1, "probability": [...],
                                             "quantile_upper": [...], "gpd": {...}}, ...]}}

Version 4 adds one optional top-level key, the slow drift of the residual's whitened
parity (:mod:`fdi.drift`, ``docs/drift.md``); a calibration without it is still written as
``/3``, so files without a drift model read as before::

     "parity_drift": {"gyro": {"method": "rimu.drift/1", "df": 9, "samples": 20835,
                               "sample_rate_hz": 43.0, "span_s": 484.0,
                               "tau_s": [...], "blocks": [...], "excess": [...], ...}}

Each effect term adds ``estimate · g(inputs; params)`` to the sensor's output in the
model (see :mod:`calibration.diagnose.library` for the regressors ``g``).
The runtime monitor compensates the terms whose inputs it has at run time (rate sign,
rate squared, specific force when accelerometers are present, temperature when the
stream carries it) and lists the others with the reason (:mod:`fdi.effects`,
``docs/effects-runtime.md``).

``input_error_cov`` (3×3, dimensionless) is the covariance of the error of the estimated
``h̃_i/SF_i`` scaled to unit gain: the compensated output errs by ``e_iᵀ·x`` with
``e_i ~ N(0, input_error_cov)``; it holds both the scale-factor and the misalignment
uncertainty and is what makes the parity residual grow with the rate.

Optional in ``/3`` (a file without it states no range): the body rate per body axis and the
specific force up to which the calibration's samples went (its error model and residual
tails hold there; the monitor's envelope marks what lies beyond,
:data:`fdi.envelope.RANGE`)::

     "validated_range": {"gyro": {"rate_abs_max": [wx, wy, wz], "rate_unit": "rad/s",
                                  "specific_force_max": f, "specific_force_unit": "m/s^2",
                                  "jolt_max": j, "jolt_unit": "m/s^2 per sample"}}

(``jolt_max`` optional: the largest change of specific force from one sample to the next
that every IMU felt, :func:`fdi.envelope.covered_jolt`.)

Optional per sensor (a ``/3`` file without them loads with 0): ``timing_jitter_ms`` and
``timing_jitter_ms_sd``, the standard deviation of the sensor's sampling-time error
relative to the reference IMU (0 for the reference and for turntable calibrations) and its
uncertainty. A timing error δt makes the output err by ``h_iᵀω̇·δt``, so the monitor widens
its thresholds with ``τ_i²·(h_iᵀω̇)²`` while the body accelerates (:mod:`fdi.kernel`).

Optional per sensor (a ``/3`` file without it loads with None, "not measured"):
``bias_turn_on_sd``, in ``bias_unit``: the run-to-run standard deviation of the sensor's
turn-on bias, measured over several flights calibrated together (``rimu calibrate
in-flight F1 F2 ...``, :mod:`calibration.inflight.multi`). ``bias`` is what holds on the
flights it was fitted on; on the next power-up the bias may lie anywhere within about
this spread.

``extra`` keeps what each calibration stage recorded. The entries rimu's code reads (the
in-flight timing, the warnings, the noise model, the turntable fit's checks, ...) are typed
in :mod:`fdi.extras` and read through :attr:`Calibration.extras`; the loader checks them and
names the bad field. Their JSON keys are those written before the types existed (no version
change; ``docs/formats.md`` lists them).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fdi.adequacy import VERDICTS
from fdi.drift import DriftModel, drift_model_from_fields
from fdi.errors import ConfigError
from fdi.extras import CalibrationExtras, extras_from_dict
from fdi.fileio import Fields, NumberRule, check_numbers, read_json_object, to_jsonable
from fdi.tails import TailModel, tail_model_from_fields
from fdi.units import (
    MS,
    input_unit_factor,
    scale_factor_from_si,
    scale_factor_sd_from_si,
    scale_factor_sd_to_si,
    scale_factor_to_si,
)

__all__ = [
    "CALIBRATION_NUMBER_RULES",
    "CALIBRATION_SCHEMA",
    "CALIBRATION_SCHEMAS",
    "CALIBRATION_SCHEMA_DRIFT",
    "FINGERPRINT_VOLATILE",
    "FINGERPRINT_VOLATILE_EXTRA",
    "KINDS",
    "AllanTable",
    "Calibration",
    "EffectTerm",
    "SensorCal",
    "SensorSet",
    "calibration_from_dict",
    "load_calibration",
    "misalignment_angles",
    "tangent_basis",
]

CALIBRATION_SCHEMA = "rimu.calibration/3"
CALIBRATION_SCHEMA_DRIFT = "rimu.calibration/4"
"""Written instead of :data:`CALIBRATION_SCHEMA` when a set carries a drift model."""
CALIBRATION_SCHEMAS = (CALIBRATION_SCHEMA, "rimu.calibration/1", "rimu.calibration/2",
                       CALIBRATION_SCHEMA_DRIFT)
"""Versions the loader reads, the one written first (what an error message asks for);
``/1``: no effects, no adequacy record; ``/2``: no residual tail model; ``/3``: no drift
model; ``/4``: with the drift model (``parity_drift``)."""
FINGERPRINT_VOLATILE = ("schema", "parity")
"""Top-level keys left out of :meth:`Calibration.fingerprint`: the schema (a migrated file
keeps it) and the parity matrices, which are derived from the axes (their near-zero entries,
1e-16, change with the last bit of an axis and no rounding of significant digits can
hold them)."""
FINGERPRINT_VOLATILE_EXTRA = ("created", "source", "written")
"""Keys of ``extra`` left out of the fingerprint (when and from which path, not what)."""
KINDS = ("gyro", "accel")
_INPUT_SI = {"gyro": "rad/s", "accel": "m/s^2"}


def tangent_basis(axis_nominal: np.ndarray) -> np.ndarray:
    """Two unit vectors (rows, shape (2, 3)) perpendicular to a nominal axis.

    ``e1`` is the MB axis least aligned with the nominal one, made perpendicular;
    ``e2 = h₀ × e1``. Misalignment angles are measured along e1 and e2.
    """
    h0 = np.asarray(axis_nominal, float)
    h0 = h0 / np.linalg.norm(h0)
    k = int(np.argmin(np.abs(h0)))
    e = np.zeros(3)
    e[k] = 1.0
    e1 = e - (e @ h0) * h0
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(h0, e1)
    return np.vstack([e1, e2])


def misalignment_angles(axis_nominal: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Two misalignment angles (rad) of ``axis`` about the nominal one, along e1 and e2."""
    h = np.asarray(axis, float)
    h = h / np.linalg.norm(h)
    E = tangent_basis(axis_nominal)
    c = float(np.dot(h, np.asarray(axis_nominal, float) / np.linalg.norm(axis_nominal)))
    return np.arctan2(E @ h, c)


@dataclass(frozen=True)
class SensorCal:
    """Calibration of one sensor, in SI.

    Attributes
    ----------
    name : str
    axis : ndarray, shape (3,)
        Calibrated unit input axis h̃ (MB frame).
    axis_nominal : ndarray, shape (3,)
        Nominal axis (row of H).
    scale_factor : float
        SF in input per raw unit (rad/s or m/s² per raw unit).
    scale_factor_sd : float
    bias : float
        b in rad/s or m/s².
    bias_sd : float
    input_error_cov : ndarray, shape (3, 3)
        Covariance of the gain-normalised error of h̃/SF (see module docstring).
    misalignment_sd : ndarray, shape (2,)
        Standard deviations of the two misalignment angles (rad).
    raw_unit : str
        Unit of the raw output (``"mV"``, ``"LSB"``, ...).
    scale_factor_unit : str
        Unit in which files print the scale factor (``"mV/(deg/s)"``, ``"(deg/s)/LSB"``).
    bias_unit : str
        Unit in which files print the bias (``"deg/h"``, ``"mg"``, ...).
    residual_rms : float
        RMS of the calibration residual (input units, SI).
    timing_jitter, timing_jitter_sd : float
        Standard deviation τ of the sampling-time error relative to the reference IMU (s)
        and its uncertainty (s); 0 for the reference and for turntable calibrations.
    bias_turn_on_sd : float or None
        Run-to-run standard deviation of the turn-on bias over several power-ups (rad/s or
        m/s², as ``bias``); None when not measured.
    """

    name: str
    axis: np.ndarray
    axis_nominal: np.ndarray
    scale_factor: float
    scale_factor_sd: float
    bias: float
    bias_sd: float
    input_error_cov: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    misalignment_sd: np.ndarray = field(default_factory=lambda: np.zeros(2))
    raw_unit: str = "raw"
    scale_factor_unit: str = "(rad/s)/raw"
    bias_unit: str = "rad/s"
    residual_rms: float = float("nan")
    timing_jitter: float = 0.0
    timing_jitter_sd: float = 0.0
    bias_turn_on_sd: float | None = None

    @property
    def misalignment(self) -> np.ndarray:
        """The two misalignment angles (rad) of the calibrated axis about the nominal one."""
        return misalignment_angles(self.axis_nominal, self.axis)


@dataclass(frozen=True)
class AllanTable:
    """Overlapping Allan deviation of the calibration residuals.

    Attributes
    ----------
    tau_s : ndarray, shape (K,)
        Averaging times (s).
    adev : ndarray, shape (K, n)
        Allan deviation per sensor (input units, SI).
    """

    tau_s: np.ndarray
    adev: np.ndarray


@dataclass(frozen=True)
class EffectTerm:
    """One effect of the extended sensor model (``rimu.calibration/2``).

    Attributes
    ----------
    name : str
        Effect name (the simulator's knob name where one matches: ``bias_drift``).
    kind : str
        ``"gyro"`` or ``"accel"``.
    sensor : int
        0-based sensor index within its kind (1-based in files).
    estimate, estimate_sd : float
        Value and standard deviation, in ``unit``.
    unit : str
    inputs : tuple of str
        Inputs the term needs (``"time"``, ``"temperature"``, ``"specific_force"``, ...).
    params : dict
        Fixed parameters of its regressor (a step time, a frequency, a reference
        temperature), JSON-ready.
    """

    name: str
    kind: str
    sensor: int
    estimate: float
    estimate_sd: float
    unit: str
    inputs: tuple[str, ...] = ()
    params: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (sensor 1-based)."""
        return {"name": self.name, "kind": self.kind, "sensor": self.sensor + 1,
                "estimate": self.estimate, "estimate_sd": self.estimate_sd,
                "unit": self.unit, "inputs": list(self.inputs),
                "params": to_jsonable(dict(self.params))}


@dataclass(frozen=True)
class SensorSet:
    """All sensors of one kind (gyros or accelerometers) and their joint statistics.

    Attributes
    ----------
    kind : str
        ``"gyro"`` or ``"accel"``.
    sensors : tuple of SensorCal
    noise_covariance : ndarray, shape (n, n)
        Per-sample noise covariance of the compensated outputs (SI²).
    groups : tuple of tuple of int
        Subsystems (0-based), each with one misalignment matrix.
    misalignment_matrices : tuple of ndarray
        M per group as the papers print it (H̃_g = M·H_g).
    allan : AllanTable or None
    tails : TailModel or None
        The residual's tail per window scale (:mod:`fdi.tails`, ``rimu.calibration/3``);
        None when not measured.
    drift : DriftModel or None
        The slow drift of the residual's whitened parity (:mod:`fdi.drift`,
        ``rimu.calibration/4``); None when not measured.
    validated_rate : ndarray, shape (3,), or None
        Gyros: per body axis, the largest rate (rad/s) the calibration's samples reached
        (:func:`fdi.envelope.covered_rate`); None when the calibration states no range.
    validated_specific_force : float or None
        Gyros: the largest specific force (m/s², felt by every IMU,
        :func:`fdi.envelope.covered_specific_force`) the calibration's samples reached;
        None when not stated (no accelerometers, or no range stated).
    validated_jolt : float or None
        Gyros: the largest change of specific force from one sample to the next (m/s², the
        smallest over the IMUs, :func:`fdi.envelope.covered_jolt`) the calibration's samples
        reached; None when not stated.
    """

    kind: str
    sensors: tuple[SensorCal, ...]
    noise_covariance: np.ndarray
    groups: tuple[tuple[int, ...], ...] = ()
    misalignment_matrices: tuple[np.ndarray, ...] = ()
    allan: AllanTable | None = None
    tails: TailModel | None = None
    drift: DriftModel | None = None
    validated_rate: np.ndarray | None = None
    validated_specific_force: float | None = None
    validated_jolt: float | None = None

    @property
    def n(self) -> int:
        """Number of sensors."""
        return len(self.sensors)

    @property
    def H(self) -> np.ndarray:
        """Calibrated axes H̃, shape (n, 3)."""
        return np.array([s.axis for s in self.sensors])

    @property
    def H_nominal(self) -> np.ndarray:
        """Nominal axes H, shape (n, 3)."""
        return np.array([s.axis_nominal for s in self.sensors])

    @property
    def scale_factors(self) -> np.ndarray:
        """SF per sensor, shape (n,), input per raw unit."""
        return np.array([s.scale_factor for s in self.sensors])

    @property
    def biases(self) -> np.ndarray:
        """Bias per sensor, shape (n,), SI."""
        return np.array([s.bias for s in self.sensors])

    @property
    def noise_sd(self) -> np.ndarray:
        """Per-sample white-noise standard deviation per sensor, shape (n,), SI."""
        return np.sqrt(np.diag(self.noise_covariance))


@dataclass(frozen=True)
class Calibration:
    """A complete calibration: what ``rimu calibrate`` writes and the monitor reads.

    Attributes
    ----------
    configuration : str
        Configuration name (``"tetrad"``, ``"cone6"``, a file).
    sets : dict of str to SensorSet
        ``"gyro"`` and/or ``"accel"``.
    sample_rate_hz : float
        Rate at which ``noise_covariance`` holds (per sample).
    earth_rate_dph, earth_rate_dph_sd : float or None
        Earth rate estimated from the outer-axis modulation, where done.
    latitude_deg : float or None
    extra : dict
        Anything else the calibration wants to keep (residual statistics per step,
        method, source session). Written as is under ``"extra"``; the entries code reads
        are typed in :attr:`extras`.
    effects : tuple of EffectTerm
        Terms of the extended model (empty: the plain model).
    adequacy : dict or None
        The model-adequacy verdict (``{"verdict": ..., ...}``, one of
        :data:`fdi.adequacy.VERDICTS`), None when not assessed.
    """

    configuration: str
    sets: Mapping[str, SensorSet]
    sample_rate_hz: float
    earth_rate_dph: float | None = None
    earth_rate_dph_sd: float | None = None
    latitude_deg: float | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)
    effects: tuple[EffectTerm, ...] = ()
    adequacy: Mapping[str, Any] | None = None

    schema: str = CALIBRATION_SCHEMA

    @property
    def extras(self) -> CalibrationExtras:
        """The typed entries of :attr:`extra` (:mod:`fdi.extras`), read from it on each access.

        Raises
        ------
        FileFormatError
            A typed entry of the wrong type (a loaded file was checked on load).
        """
        return extras_from_dict(self.extra, f"calibration of {self.configuration}")

    @property
    def gyro(self) -> SensorSet:
        """The gyro set (raises ConfigError when the file has none)."""
        return self.kind("gyro")

    def kind(self, kind: str) -> SensorSet:
        """The sensor set of one kind."""
        try:
            return self.sets[kind]
        except KeyError:
            raise ConfigError(f"calibration has no {kind} sensors") from None

    # -- writing -----------------------------------------------------------------------
    def fingerprint(self) -> str:
        """Short identity of the calibration: 16 hex digits of a sha256.

        Hashes the canonical JSON (sorted keys, no spaces, floats to 12 significant digits)
        of :meth:`to_dict` without :data:`FINGERPRINT_VOLATILE` and the ``extra`` keys in
        :data:`FINGERPRINT_VOLATILE_EXTRA`: a file saved, loaded and saved again (or
        migrated to a newer version) keeps its fingerprint; any change of a number the
        monitor or the thresholds read changes it. A calibration that cannot be written
        (a scale-factor unit without a file form) has none: ``""``.
        """
        import hashlib

        try:
            full = self.to_dict()
        except ConfigError:
            return ""
        doc = {k: v for k, v in full.items() if k not in FINGERPRINT_VOLATILE}
        if isinstance(doc.get("extra"), dict):
            doc["extra"] = {k: v for k, v in doc["extra"].items()
                            if k not in FINGERPRINT_VOLATILE_EXTRA}
        text = json.dumps(_canonical(doc), sort_keys=True, separators=(",", ":"),
                          allow_nan=True)
        return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary in the ``rimu.calibration/3`` layout (``/4`` with drift)."""
        drift = {kind: s.drift.to_dict() for kind, s in self.sets.items()
                 if s.drift is not None}
        schema = CALIBRATION_SCHEMA_DRIFT if drift else self.schema
        doc: dict[str, Any] = {"schema": schema, "configuration": self.configuration,
                               "sample_rate_hz": self.sample_rate_hz, "sensors": {},
                               "noise_covariance": {"unit": {},
                                                    "sample_rate_hz": self.sample_rate_hz},
                               "misalignment_matrices": {}, "allan": {}}
        doc.update(self._model_blocks(drift))
        for kind, s in self.sets.items():
            _add_set(doc, kind, s)
        if self.earth_rate_dph is not None:
            doc["earth_rate_dph"] = self.earth_rate_dph
            doc["earth_rate_dph_sd"] = self.earth_rate_dph_sd
        if self.latitude_deg is not None:
            doc["latitude_deg"] = self.latitude_deg
        doc["effects"] = [e.to_dict() for e in self.effects]
        if self.adequacy is not None:
            doc["adequacy"] = to_jsonable(dict(self.adequacy))
        doc["extra"] = to_jsonable(dict(self.extra))
        return doc

    def _model_blocks(self, drift: dict[str, Any]) -> dict[str, Any]:
        """The residual tails, parity drift and validated range of the sets that have them,
        in the file's order.

        Parameters
        ----------
        drift : dict
            Each set's drift model as written.

        Returns
        -------
        dict
            Only the blocks some set has.
        """
        out: dict[str, Any] = {}
        tails = {kind: s.tails.to_dict() for kind, s in self.sets.items()
                 if s.tails is not None}
        if tails:
            out["residual_tails"] = to_jsonable(tails)
        if drift:
            out["parity_drift"] = to_jsonable(drift)
        vr = {kind: _range_to_dict(s) for kind, s in self.sets.items()
              if s.validated_rate is not None}
        if vr:
            out["validated_range"] = vr
        return out

    def save(self, path: str | Path) -> None:
        """Write the calibration as JSON."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")


def _add_set(doc: dict[str, Any], kind: str, s: SensorSet) -> None:
    """Write one sensor set's sensors, noise, misalignment matrices, Allan table and parity
    matrices into the calibration document.

    Parameters
    ----------
    doc : dict
        :meth:`Calibration.to_dict`'s document, its per-kind blocks open.
    kind : str
    s : SensorSet
    """
    from fdi.parity import parity_matrix

    doc["sensors"][kind] = [_sensor_to_dict(c) for c in s.sensors]
    doc["noise_covariance"][kind] = s.noise_covariance.tolist()
    doc["noise_covariance"]["unit"][kind] = f"({_INPUT_SI[kind]})^2"
    doc["misalignment_matrices"][kind] = [
        {"sensors": [i + 1 for i in g], "M": np.atleast_2d(M).tolist()}
        for g, M in zip(s.groups, s.misalignment_matrices, strict=False)]
    if s.allan is not None:
        doc["allan"][kind] = {"tau_s": s.allan.tau_s.tolist(),
                              "adev": s.allan.adev.tolist(),
                              "unit": _INPUT_SI[kind]}
    par = {"nominal": parity_matrix(s.H_nominal).tolist(),
           "calibrated": parity_matrix(s.H).tolist()}
    doc["parity" if kind == "gyro" else "parity_accel"] = par


def _canonical(v: Any) -> Any:
    """Floats to 12 significant digits (a normalised axis may move its last bit on load)."""
    if isinstance(v, float):
        return float(f"{v:.12g}") if math.isfinite(v) else str(v)
    if isinstance(v, dict):
        return {str(k): _canonical(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_canonical(x) for x in v]
    return v


def _sensor_to_dict(c: SensorCal) -> dict[str, Any]:
    bf = input_unit_factor(c.bias_unit)
    if not (math.isfinite(c.scale_factor) and c.scale_factor > 0):
        # would divide by zero in a raw-per-input unit, and no loader accepts it back
        raise ConfigError(f"sensor {c.name}: scale factor {c.scale_factor!r} (SI) is not a "
                          "positive finite number; refusing to write it")
    return {
        "name": c.name,
        "axis": c.axis.tolist(),
        "axis_nominal": c.axis_nominal.tolist(),
        "misalignment_mrad": (1e3 * c.misalignment).tolist(),
        "misalignment_mrad_sd": (1e3 * np.asarray(c.misalignment_sd)).tolist(),
        "scale_factor": scale_factor_from_si(c.scale_factor, c.scale_factor_unit),
        "scale_factor_sd": scale_factor_sd_from_si(c.scale_factor, c.scale_factor_sd,
                                                   c.scale_factor_unit),
        "scale_factor_unit": c.scale_factor_unit,
        "bias": c.bias / bf,
        "bias_sd": c.bias_sd / bf,
        "bias_unit": c.bias_unit,
        "input_error_cov": np.asarray(c.input_error_cov).tolist(),
        "raw_unit": c.raw_unit,
        "residual_rms": None if not math.isfinite(c.residual_rms) else c.residual_rms,
        **({"timing_jitter_ms": c.timing_jitter / MS, "timing_jitter_ms_sd":
            c.timing_jitter_sd / MS} if c.timing_jitter or c.timing_jitter_sd else {}),
        **({} if c.bias_turn_on_sd is None else {"bias_turn_on_sd": c.bias_turn_on_sd / bf}),
    }


# -- reading ---------------------------------------------------------------------------
MAX_SCALE_FACTOR_SI = 1e6
"""Largest scale factor read (rad/s or m/s² per raw unit): no sensor's raw unit is worth a
million rad/s; a larger one is a unit mistake (the monitor would trust any value it gives)."""
MIN_SCALE_FACTOR_SI = 1e-15
"""Smallest scale factor read (a raw output of 10¹⁵ counts would be needed for 1 rad/s)."""
_UNIT = 1.0 + 1e-9          # entries of an orthonormal parity matrix, with rounding
CALIBRATION_NUMBER_RULES: tuple[NumberRule, ...] = (
    NumberRule("parity.*", -_UNIT, _UNIT, what="an entry of an orthonormal parity matrix"),
    NumberRule("parity_accel.*", -_UNIT, _UNIT,
               what="an entry of an orthonormal parity matrix"),
    NumberRule("latitude_deg", -90.0, 90.0, what="a latitude"),
    NumberRule("sensors.*.scale_factor", 0.0, lo_open=True, what="a scale factor"),
    NumberRule("residual_tails.*.scales.quantile", 0.0, what="a quantile of the statistic"),
    NumberRule("residual_tails.*.scales.quantile_upper", 0.0, lo_open=True,
               what="a quantile bound of the statistic"),
    NumberRule("residual_tails.*.scales.scale", 1.0, what="a window length"),
    NumberRule("residual_tails.*.scales.gpd.threshold", 0.0, what="a threshold"),
    NumberRule("parity_drift.*.blocks", 0.0, what="a count"),
    NumberRule("*.time_offset_ms", what="a time offset (ms)"),
)
"""Ranges of the calibration file's numbers beyond :data:`fdi.fileio.CONVENTION_RULES`
(``*_sd`` >= 0, covariance diagonals >= 0, Allan ``tau_s`` > 0 and ``adev`` >= 0, ...); every
other number, in ``extra`` too, must be finite. Checked on load (:func:`calibration_from_dict`),
so every command that reads a calibration refuses the same values."""

_WRITTEN_ONLY = ("parity", "parity_accel")
"""Top-level keys the writer adds for other tools (derived from the axes; not read back)."""


def load_calibration(path: str | Path) -> Calibration:
    """Read and validate a ``rimu.calibration/3`` (or ``/2``, ``/1``) file.

    Raises
    ------
    FileFormatError
        Missing file, bad JSON, wrong schema or version, missing, malformed or unknown
        field, unknown unit; the message names the file and the field.
    """
    return calibration_from_dict(read_json_object(path), str(path))


def calibration_from_dict(doc: Mapping[str, Any], path: str = "<calibration>") -> Calibration:
    """Build a :class:`Calibration` from its JSON dictionary (see :func:`load_calibration`)."""
    r = Fields(doc, path)
    version = r.schema(CALIBRATION_SCHEMAS)
    check_numbers(doc, path, CALIBRATION_NUMBER_RULES)
    rate = r.number("sample_rate_hz", positive=True)
    sensors = r.mapping("sensors")
    noise = r.mapping("noise_covariance")
    noise_rate = noise.number("sample_rate_hz", None, positive=True)
    if noise_rate is not None and not math.isclose(noise_rate, rate, rel_tol=1e-9):
        raise noise.error("sample_rate_hz", f"{noise_rate:g} Hz, but the file's "
                          f"sample_rate_hz is {rate:g} Hz (the covariance holds per sample "
                          "at one rate)")
    mm = r.mapping("misalignment_matrices", {})
    allan = r.mapping("allan", {})
    if not sensors.keys():
        raise r.error("sensors", "expected an object with 'gyro' and/or 'accel' lists")
    sets = {kind: _sensor_set(sensors, noise, mm, allan, kind)
            for kind in KINDS if kind in sensors}
    sensors.finish()
    noise.accept("unit")
    for sub in (noise, mm, allan):
        sub.finish(accept=sets)
    if version in (CALIBRATION_SCHEMA, CALIBRATION_SCHEMA_DRIFT):
        sets = _tails(r, sets)
        sets = _validated_range(r, sets)
    if version == CALIBRATION_SCHEMA_DRIFT:
        sets = _drift(r, sets)
    cal = Calibration(
        configuration=str(r.get("configuration", "")), sets=sets, sample_rate_hz=rate,
        earth_rate_dph=r.number("earth_rate_dph", None),
        earth_rate_dph_sd=r.number("earth_rate_dph_sd", None),
        latitude_deg=r.number("latitude_deg", None), extra=r.free("extra", {}),
        effects=_effects(r, sets) if version != "rimu.calibration/1" else (),
        adequacy=_adequacy(r) if version != "rimu.calibration/1" else None)
    r.finish(accept=_WRITTEN_ONLY)
    extras_from_dict(cal.extra, path)
    return cal


def _tails(r: Fields, sets: dict[str, SensorSet]) -> dict[str, SensorSet]:
    """``residual_tails``: the tail model per kind (``/3``, optional)."""
    return _parity_models(r, sets, "residual_tails", tail_model_from_fields, "tails")


def _drift(r: Fields, sets: dict[str, SensorSet]) -> dict[str, SensorSet]:
    """``parity_drift``: the drift model per kind (``/4``, optional)."""
    return _parity_models(r, sets, "parity_drift", drift_model_from_fields, "drift")


def _parity_models(r: Fields, sets: dict[str, SensorSet], key: str,
                   parse: Any, attr: str) -> dict[str, SensorSet]:
    """A per-kind model of the parity (``df`` dimensions) under ``key``, parsed by
    ``parse`` into ``SensorSet.<attr>``."""
    from dataclasses import replace

    t = r.mapping(key, None)
    if t is None:
        return sets
    out = dict(sets)
    for kind in sets:
        sub = t.mapping(kind, None)
        if sub is None:
            continue
        model = parse(sub)
        if model.df > sets[kind].n:
            raise sub.error("df", f"{model.df} parity dimensions for {sets[kind].n} {kind} "
                            "sensors")
        out[kind] = replace(sets[kind], **{attr: model})
    t.finish(accept=sets)
    return out


JOLT_UNIT = "m/s^2 per sample"
"""Unit of ``validated_range.jolt_max``."""


def _range_to_dict(s: SensorSet) -> dict[str, Any]:
    doc: dict[str, Any] = {"rate_abs_max": np.asarray(s.validated_rate, float).tolist(),
                           "rate_unit": "rad/s"}
    if s.validated_specific_force is not None:
        doc["specific_force_max"] = float(s.validated_specific_force)
        doc["specific_force_unit"] = "m/s^2"
    if s.validated_jolt is not None:
        doc["jolt_max"] = float(s.validated_jolt)
        doc["jolt_unit"] = JOLT_UNIT
    return doc


def _validated_range(r: Fields, sets: dict[str, SensorSet]) -> dict[str, SensorSet]:
    """``validated_range``: the rate, specific force and jolt the calibration covered
    (``/3``, optional, gyros)."""
    from dataclasses import replace

    v = r.mapping("validated_range", None)
    if v is None:
        return sets
    out = dict(sets)
    for kind in sets:
        sub = v.mapping(kind, None)
        if sub is None:
            continue
        if kind != "gyro":
            raise v.error(kind, "a validated range is stated for gyros only")
        for key, unit in (("rate_unit", "rad/s"), ("specific_force_unit", "m/s^2"),
                          ("jolt_unit", JOLT_UNIT)):
            if sub.get(key, unit) != unit:
                raise sub.error(key, f"expected {unit!r}, got {sub.get(key)!r}")
        a = sub.array("rate_abs_max", (3,))
        if np.isnan(a).any() or (a < 0).any():
            raise sub.error("rate_abs_max", "expected three rates >= 0")
        f = sub.number("specific_force_max", None, nonnegative=True)
        j = sub.number("jolt_max", None, nonnegative=True)
        sub.finish()
        out[kind] = replace(sets[kind], validated_rate=a, validated_specific_force=f,
                            validated_jolt=j)
    v.finish(accept=sets)
    return out


def _effects(r: Fields, sets: Mapping[str, SensorSet]) -> tuple[EffectTerm, ...]:
    """``effects``: the extended model's terms (sensor numbers within their kind)."""
    out = []
    for e in r.tables("effects", [], nonempty=False):
        kind = e.choice("kind", sorted(sets))
        sensor = e.integer("sensor", lo=1)
        if sensor > sets[kind].n:
            raise e.error("sensor", f"expected 1..{sets[kind].n} ({kind} sensors), got "
                          f"{sensor}")
        inputs = e.get("inputs", [])
        if not isinstance(inputs, list) or not all(isinstance(x, str) for x in inputs):
            raise e.error("inputs", f"expected a list of input names, got {inputs!r}")
        sd = e.number("estimate_sd")
        if not sd >= 0:
            raise e.error("estimate_sd", f"expected a standard deviation (>= 0), got {sd!r}")
        out.append(EffectTerm(name=e.string("name"), kind=kind, sensor=sensor - 1,
                              estimate=e.number("estimate"), estimate_sd=sd,
                              unit=e.string("unit"), inputs=tuple(inputs),
                              params=e.free("params", {})))
        e.finish()
    return tuple(out)


def _adequacy(r: Fields) -> dict[str, Any] | None:
    """``adequacy``: the verdict and its details (free-form beyond ``verdict``)."""
    a = r.mapping("adequacy", None)
    if a is None:
        return None
    a.choice("verdict", VERDICTS)
    doc = dict(a.doc)
    a.accept(*doc)
    a.finish()
    return doc


def _sensor_set(sensors: Fields, noise: Fields, mm: Fields, allan: Fields,
                kind: str) -> SensorSet:
    """One kind's sensors, noise covariance, misalignment matrices and Allan table."""
    cals = tuple(_sensor_from(e) for e in sensors.tables(kind))
    n = len(cals)
    cov = noise.array(kind, (n, n))
    _check_covariance(noise, cov, kind)
    groups, mats = [], []
    for g in mm.tables(kind, [], nonempty=False):
        sens = g.get("sensors")
        if not isinstance(sens, list) or not all(
                isinstance(i, int) and not isinstance(i, bool) for i in sens):
            raise g.error("sensors", f"expected a list of sensor numbers, got {sens!r}")
        if any(not 1 <= i <= n for i in sens):
            raise g.error("sensors", f"sensor numbers must be 1..{n}")
        groups.append(tuple(i - 1 for i in sens))
        mats.append(g.array("M", (len(sens), None)))
        g.finish()
    table = None
    al = allan.mapping(kind, None)
    if al is not None:
        taus = al.array("tau_s", (None,))
        table = AllanTable(taus, al.array("adev", (len(taus), n)))
        al.finish(accept=("unit",))
    return SensorSet(kind, cals, cov, tuple(groups), tuple(mats), table)


def _check_covariance(r: Fields, cov: np.ndarray, key: str) -> None:
    """A noise covariance must be symmetric positive definite (the monitor whitens by it)."""
    scale = float(np.max(np.abs(cov))) if cov.size else 0.0
    if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-12 * scale):
        raise r.error(key, "expected a symmetric matrix")
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise r.error(key, "expected a positive definite matrix") from None
    if not np.linalg.cond(cov) < 1e12:
        raise r.error(key, "nearly singular (condition number above 1e12)")


def _input_error_cov(e: Fields) -> np.ndarray:
    """``input_error_cov``: a symmetric positive semi-definite 3×3 (zeros when absent)."""
    c = e.array("input_error_cov", (3, 3), np.zeros((3, 3)))
    scale = float(np.max(np.abs(c)))
    if not np.allclose(c, c.T, rtol=1e-9, atol=1e-12 * scale):
        raise e.error("input_error_cov", "expected a symmetric matrix")
    if scale and float(np.linalg.eigvalsh(c).min()) < -1e-9 * scale:
        raise e.error("input_error_cov", "expected a positive semi-definite matrix (a "
                      "covariance)")
    return c


def _unit_axis(e: Fields, key: str) -> np.ndarray:
    a = e.array(key, (3,))
    if abs(np.linalg.norm(a) - 1.0) > 1e-6:
        raise e.error(key, f"expected a unit vector, norm is {np.linalg.norm(a)}")
    return a / np.linalg.norm(a)


def _scale_factor_si(e: Fields) -> tuple[float, float, str]:
    """(SF, SF sd) in SI and the file's unit; refused when out of range in SI."""
    sfu = e.string("scale_factor_unit")
    sf = e.number("scale_factor", positive=True)
    sfsd = e.number("scale_factor_sd")
    try:
        sf_si = scale_factor_to_si(sf, sfu)
        sfsd_si = scale_factor_sd_to_si(sf, sfsd, sfu)
    except ConfigError as exc:
        raise e.error("scale_factor_unit", str(exc)) from None
    except (OverflowError, ZeroDivisionError):
        sf_si = sfsd_si = math.inf
    if not (math.isfinite(sf_si) and math.isfinite(sfsd_si) and sf_si > 0):
        raise e.error("scale_factor", f"{sf!r} (sd {sfsd!r}) {sfu} is out of range in SI "
                      "units")
    if not MIN_SCALE_FACTOR_SI <= sf_si <= MAX_SCALE_FACTOR_SI:
        raise e.error("scale_factor", f"{sf!r} {sfu} is {sf_si:.3g} SI units per raw unit, "
                      f"outside [{MIN_SCALE_FACTOR_SI:g}, {MAX_SCALE_FACTOR_SI:g}]: a unit "
                      "mistake?")
    if not sfsd_si >= 0:
        raise e.error("scale_factor_sd", f"expected a standard deviation (>= 0), got {sfsd!r}")
    return sf_si, sfsd_si, sfu


def _bias_si(e: Fields) -> tuple[float, float, str]:
    """(bias, bias sd) in SI and the file's unit."""
    bu = e.string("bias_unit")
    try:
        bf = input_unit_factor(bu)
    except ConfigError as exc:
        raise e.error("bias_unit", str(exc)) from None
    bias = e.number("bias") * bf
    bias_sd = e.number("bias_sd") * bf
    if not (bias_sd >= 0 and math.isfinite(bias_sd * bias_sd)):
        raise e.error("bias_sd", f"expected a standard deviation (≥ 0, squarable), got "
                      f"{bias_sd / bf!r}")
    return bias, bias_sd, bu


def _raw_unit(e: Fields) -> str:
    """``raw_unit``, required: without it the unit check against the data would pass
    anything (``"raw"`` says "unknown" explicitly)."""
    return e.string("raw_unit", nonempty=False).strip()


def _turn_on_sd(e: Fields, bias_unit: str) -> float | None:
    """``bias_turn_on_sd`` in SI (None when absent: not measured)."""
    v = e.number("bias_turn_on_sd", None, nonnegative=True)
    if v is None:
        return None
    x = v * input_unit_factor(bias_unit)
    if not math.isfinite(x * x):
        raise e.error("bias_turn_on_sd", f"expected a standard deviation (>= 0, squarable), "
                      f"got {v!r} {bias_unit}")
    return x


def _sensor_from(e: Fields) -> SensorCal:
    axis, nom = _unit_axis(e, "axis"), _unit_axis(e, "axis_nominal")
    sf, sf_sd, sfu = _scale_factor_si(e)
    bias, bias_sd, bu = _bias_si(e)
    e.array("misalignment_mrad", (2,))              # derived from the axes; checked only
    c = SensorCal(
        name=str(e.get("name")), axis=axis, axis_nominal=nom, scale_factor=sf,
        scale_factor_sd=sf_sd, bias=bias, bias_sd=bias_sd,
        input_error_cov=_input_error_cov(e),
        misalignment_sd=e.array("misalignment_mrad_sd", (2,)) * 1e-3,
        raw_unit=_raw_unit(e), scale_factor_unit=sfu, bias_unit=bu,
        residual_rms=e.number("residual_rms", float("nan")),
        timing_jitter=e.number("timing_jitter_ms", 0.0, nonnegative=True) * MS,
        timing_jitter_sd=e.number("timing_jitter_ms_sd", 0.0, nonnegative=True) * MS,
        bias_turn_on_sd=_turn_on_sd(e, bu))
    e.finish()
    return c


# -- compatibility of a calibration with the data it is applied to (issue 10) ---------------
GENERIC_RAW_UNITS = frozenset({"", "raw"})
"""Raw-unit names that say nothing (accepted against any calibration)."""
IMPLAUSIBLE_ALPHA = 1e-9
"""Tail probability beyond which a fit statistic is refused rather than warned about."""


def check_compatible(cal: Calibration, n_sensors: int, raw_unit: Any, source: str, *,
                     kind: str = "gyro", names: Any = None,
                     cal_source: str | None = None) -> None:
    """Refuse data that the calibration cannot describe (sensor count, raw unit).

    Parameters
    ----------
    cal : Calibration
    n_sensors : int
        Sensors of ``kind`` in the data (log, flight folder, channel map, truth sidecar).
    raw_unit : str or sequence of str or None
        The data's raw unit (one for all sensors, or one per sensor); ``"raw"``, ``""`` and
        None say nothing and are accepted.
    source : str
        What the data is (file name), for the message.
    kind : str
        ``"gyro"`` or ``"accel"``.
    names : sequence of str, optional
        The data's sensor names (only used in the message).
    cal_source : str, optional
        The calibration's file, named in the message beside its configuration.

    Raises
    ------
    ConfigError
        One line naming ``source``, the calibration and what disagrees.
    """
    s = cal.kind(kind)
    where = (f"calibration {cal_source} ({cal.configuration})" if cal_source
             else f"calibration of {cal.configuration}")
    if int(n_sensors) != s.n:
        raise ConfigError(f"{source}: {int(n_sensors)} {kind} sensors, the {where} has {s.n}: "
                          "a calibration only applies to the sensor set it was made for")
    _check_names(s, names, source, where, kind, warn=False)
    _check_units(s, raw_unit, source, where, kind, names)
    _check_names(s, names, source, where, kind, warn=True)     # warned once all else passed


def _check_units(s: SensorSet, raw_unit: Any, source: str, where: str, kind: str,
                 names: Any) -> None:
    """The data's raw units against the calibration's (generic names pass)."""
    if raw_unit is None:
        return
    units = [raw_unit] * s.n if isinstance(raw_unit, str) else list(raw_unit)
    for i, (u, c) in enumerate(zip(units, s.sensors, strict=False)):
        got = "" if u is None else str(u).strip()
        want = str(c.raw_unit).strip()
        if got in GENERIC_RAW_UNITS or want in GENERIC_RAW_UNITS or got == want:
            continue
        who = names[i] if names is not None and i < len(names) else c.name
        raise ConfigError(f"{source}: {kind} sensor {i + 1} ({who}) is in {got!r}, the {where} "
                          f"expects raw outputs in {want!r}")


def _check_names(s: SensorSet, names: Any, source: str, where: str, kind: str, *,
                 warn: bool) -> None:
    """Sensors are matched by position: the same names in another order are refused (the
    columns were permuted), other names warned about in one line."""
    import logging

    if names is None:
        return
    got = [str(x) for x in names]
    want = [c.name for c in s.sensors]
    if got == want or len(got) != len(want):
        return
    if sorted(got) == sorted(want) and not warn:
        j = next(i for i, (a, b) in enumerate(zip(got, want, strict=True)) if a != b)
        raise ConfigError(f"{source}: {kind} sensor {j + 1} is {got[j]!r} where the {where} "
                          f"has {want[j]!r}: the same sensors in another order (a calibration "
                          "applies by position; reorder the columns)")
    if not warn or sorted(got) == sorted(want):
        return
    pairs = ", ".join(f"{a}={b}" for a, b in zip(got, want, strict=True) if a != b)
    logging.getLogger("rimu.calibration").warning(
        f"{source}: its {kind} sensor names differ from the {where}'s; matched by position: "
        f"{pairs[:200]}")


def check_plausible(cal: Calibration, source: str) -> None:
    """Refuse a calibration whose Earth-rate fit is beyond any plausible noise.

    The horizontal Earth rate the rate test recovers from the outer-axis modulation must be
    Ω·cos(latitude); a table-rate column in the wrong unit (rad/s read as °/s) scales every
    input rate and the recovered Earth rate with it. With sd the larger of the fit's sd and
    the per-step scatter, ``z² = ((h − Ω cos φ)/sd)²`` is refused above
    ``chi2.isf(IMPLAUSIBLE_ALPHA, 1)`` (≈ 37, about 6 σ). A fit without an Earth-rate
    record (no outer-axis steps, or accelerometers only) passes.

    Raises
    ------
    CalibrationError
        One line with the expected and recovered rates and z.
    """
    from scipy.stats import chi2

    from fdi.errors import CalibrationError
    from fdi.units import DPH, EARTH_RATE_DPH

    er = cal.extras.earth_rate_fit
    if er is None or er.horizontal is None or cal.latitude_deg is None:
        return
    h = er.horizontal / DPH
    sd = max(er.horizontal_sd, er.scatter_sd) / DPH
    want = EARTH_RATE_DPH * math.cos(math.radians(float(cal.latitude_deg)))
    if not (math.isfinite(h) and math.isfinite(sd) and sd > 0):
        return
    z = (h - want) / sd
    limit = float(chi2.isf(IMPLAUSIBLE_ALPHA, 1))
    if z * z > limit:
        raise CalibrationError(
            f"{source}: the rate test recovers a horizontal Earth rate of {h:.4g} ± {sd:.2g} "
            f"deg/h, expected {want:.4g} at latitude {float(cal.latitude_deg):g} deg (z = "
            f"{z:+.1f}, z^2 beyond chi2.isf(1e-9, 1) = {limit:.1f}): are the table-rate columns "
            "in deg/s and the latitude right?")


__all__ = sorted([*__all__, "GENERIC_RAW_UNITS", "IMPLAUSIBLE_ALPHA", "MAX_SCALE_FACTOR_SI",
                  "MIN_SCALE_FACTOR_SI", "check_compatible", "check_plausible"])
