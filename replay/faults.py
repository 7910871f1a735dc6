"""Fault specifications for simulated flights: ``KIND:SENSOR:SIZE:ONSET[:DURATION]``.

A fault is injected into one sensor's *true input* (SI, before the scale factor), so that
its size reads in the same units as the calibration's noise and bias:

========  =========================  ===================================================
kind      SIZE                       effect on sensor i from ONSET (for DURATION s)
========  =========================  ===================================================
step      ``15sigma``, ``0.02dps``   a constant bias ``size`` (rad/s, m/s²) is added
ramp      ``0.05sigma/s``, ``1dps/s``  a bias growing at ``size`` per second
stuck     (empty, unused)            the raw output repeats the last value before onset
noise     ``3x``                     the white noise is multiplied by ``size``
scale     ``1%``, ``500ppm``         the scale factor changes: input ``x → (1+size)·x``
spike     ``50sigma``                ``size`` added to the one sample at ONSET
                                     (to every sample in the window with a DURATION)
dropout   (empty, unused)            no sample (``valid = False``)
========  =========================  ===================================================

Examples: ``step:3:15sigma:20`` (a 15σ step on sensor 3 at t = 20 s), ``ramp:2:0.05sigma/s:10``,
``stuck:1::30``, ``noise:4:3x:12``, ``scale:5:1%:40``, ``spike:2:50sigma:15``,
``dropout:6::25:2``. Sensors are numbered from 1. σ is the sensor's white-noise standard
deviation per sample from the calibration file (``sqrt(noise_covariance[i, i])``).

Physical units for bias-like sizes: ``sigma``, ``rad/s``, ``dps`` (°/s), ``dph`` (°/h) for
gyros; ``sigma``, ``mps2`` (m/s²), ``mg``, ``g`` for accelerometers; a ramp appends ``/s``.
:attr:`Fault.size` is stored in SI (rad/s, rad/s per s, m/s², ...), a multiplier (noise) or
a fraction (scale); 0 where unused.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from fdi.units import DPH, DPS, G0, MG

__all__ = ["FAULT_KINDS", "Fault", "fault_from_dict", "parse_fault"]

FAULT_KINDS = ("step", "ramp", "stuck", "noise", "scale", "spike", "dropout")
"""Fault kinds :func:`parse_fault` understands."""

_BIAS_UNITS: dict[str, dict[str, float]] = {
    "gyro": {"rad/s": 1.0, "rads": 1.0, "dps": DPS, "deg/s": DPS, "dph": DPH, "deg/h": DPH},
    "accel": {"mps2": 1.0, "m/s^2": 1.0, "m/s2": 1.0, "mg": MG, "g": G0},
}
_SIZE_UNITS = {
    "step": "a bias such as 15sigma, 0.02dps, 5dph, 0.1mps2, 2mg",
    "spike": "a bias such as 50sigma, 1dps, 2mg",
    "ramp": "a bias per second such as 0.05sigma/s, 0.01dps/s, 1mg/s",
    "noise": "a noise multiplier such as 3x",
    "scale": "a scale-factor change such as 1%, 500ppm",
    "stuck": "nothing (leave SIZE empty)",
    "dropout": "nothing (leave SIZE empty)",
}
_NUMBER = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
_NUM_UNIT = re.compile(r"^\s*" + _NUMBER + r"\s*([A-Za-z%/^0-9]*)\s*$")


@dataclass(frozen=True)
class Fault:
    """One fault to inject into a simulated flight.

    Attributes
    ----------
    kind : str
        One of :data:`FAULT_KINDS`.
    sensor : int
        1-based sensor number.
    size : float
        SI input units for ``step``/``spike`` (rad/s, m/s²), SI per second for ``ramp``,
        multiplier for ``noise``, fraction for ``scale``, 0 for ``stuck``/``dropout``.
    onset : float
        Start time (s, flight time).
    duration : float or None
        Length of the fault window (s); None: until the end of the flight (``spike``: one
        sample).
    spec : str
        The text the fault was parsed from (for reports).
    """

    kind: str
    sensor: int
    size: float
    onset: float
    duration: float | None = None
    spec: str = ""

    @property
    def end(self) -> float:
        """End time of the window (s); ``inf`` without a duration."""
        return math.inf if self.duration is None else self.onset + self.duration

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (``size`` in SI, see the class docstring)."""
        return {"kind": self.kind, "sensor": self.sensor, "size": self.size,
                "onset": self.onset, "duration": self.duration, "spec": self.spec}


def fault_from_dict(d: Mapping[str, Any], where: str = "fault") -> Fault:
    """Inverse of :meth:`Fault.to_dict`.

    Raises
    ------
    ConfigError
        Naming ``where`` and the bad key.
    """
    try:
        kind = str(d["kind"])
        sensor = int(d["sensor"])
        size = float(d["size"])
        onset = float(d["onset"])
        dur = d.get("duration")
        duration = None if dur is None else float(dur)
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise ConfigError(f"{where}: expected kind, sensor, size, onset, duration "
                          f"({type(exc).__name__}: {exc})") from None
    if kind not in FAULT_KINDS:
        raise ConfigError(f"{where}: unknown fault kind {kind!r}; expected one of "
                          f"{', '.join(FAULT_KINDS)}")
    if sensor < 1:
        raise ConfigError(f"{where}: sensor must be ≥ 1, got {sensor}")
    return Fault(kind, sensor, size, onset, duration, str(d.get("spec", "")))


def _fail(spec: str, msg: str) -> ConfigError:
    return ConfigError(f"fault {spec!r}: {msg}; expected KIND:SENSOR:SIZE:ONSET[:DURATION], "
                       f"e.g. step:3:15sigma:20")


def _number(spec: str, text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise _fail(spec, f"{what} {text!r} is not a number") from None
    if not math.isfinite(v):
        raise _fail(spec, f"{what} {text!r} is not finite")
    return v


def _size(spec: str, kind: str, text: str, sigma: float, sensor_kind: str) -> float:
    want = _SIZE_UNITS[kind]
    if kind in ("stuck", "dropout"):
        if text.strip():
            raise _fail(spec, f"SIZE {text!r} given, {kind} takes {want}")
        return 0.0
    m = _NUM_UNIT.match(text)
    if not m:
        raise _fail(spec, f"SIZE {text!r} not understood; {kind} takes {want}")
    value, unit = float(m.group(1)), m.group(2)
    if kind == "noise":
        if unit != "x":
            raise _fail(spec, f"SIZE {text!r}: {kind} takes {want}")
        if value < 0:
            raise _fail(spec, f"SIZE {text!r}: noise multiplier must be ≥ 0")
        return value
    if kind == "scale":
        if unit == "%":
            return value / 100.0
        if unit == "ppm":
            return value * 1e-6
        raise _fail(spec, f"SIZE {text!r}: {kind} takes {want}")
    per_s = kind == "ramp"
    if per_s:
        if not unit.endswith("/s"):
            raise _fail(spec, f"SIZE {text!r}: {kind} takes {want}")
        unit = unit[:-2]
    if unit == "sigma":
        return value * sigma
    units = _BIAS_UNITS[sensor_kind]
    if unit not in units:
        raise _fail(spec, f"SIZE {text!r}: unit {unit or '(none)'!r} unknown for "
                          f"{sensor_kind} sensors; {kind} takes {want} "
                          f"(units: sigma, {', '.join(units)})")
    return value * units[unit]


def parse_fault(spec: str, cal: Calibration, *, kind: str = "gyro") -> Fault:
    """Parse ``KIND:SENSOR:SIZE:ONSET[:DURATION]`` (see the module docstring).

    Parameters
    ----------
    spec : str
        E.g. ``"step:3:15sigma:20"``.
    cal : Calibration
        Gives the number of sensors and σ (white-noise sd per sample) for ``sigma`` sizes.
    kind : str
        Sensor set the fault applies to (``"gyro"`` or ``"accel"``).

    Returns
    -------
    Fault

    Raises
    ------
    ConfigError
        Naming the spec and what was expected.
    """
    text = str(spec).strip()
    parts = text.split(":")
    if len(parts) not in (4, 5):
        raise _fail(text, f"{len(parts)} field(s)")
    fkind = parts[0].strip().lower()
    if fkind not in FAULT_KINDS:
        raise _fail(text, f"unknown KIND {parts[0]!r} (one of {', '.join(FAULT_KINDS)})")
    sset = cal.kind(kind)
    try:
        sensor = int(parts[1])
    except ValueError:
        raise _fail(text, f"SENSOR {parts[1]!r} is not an integer") from None
    if not 1 <= sensor <= sset.n:
        raise _fail(text, f"SENSOR {sensor} out of range 1..{sset.n}")
    sigma = float(sset.noise_sd[sensor - 1])
    size = _size(text, fkind, parts[2], sigma, kind)
    onset = _number(text, parts[3], "ONSET")
    if onset < 0:
        raise _fail(text, f"ONSET {onset} is negative")
    duration = None
    if len(parts) == 5 and parts[4].strip():
        duration = _number(text, parts[4], "DURATION")
        if duration <= 0:
            raise _fail(text, f"DURATION {duration} must be positive")
    return Fault(fkind, sensor, size, onset, duration, text)
