"""A calibration carried to a flight under another firmware: what may belong to the firmware
held at the calibration's own prior.

An in-flight calibration measures, for every IMU against the reference, a relative scale,
mounting, non-orthogonality and time offset. Across power-ups of one firmware they last
(:mod:`replay.turn_on`: only the turn-on bias is estimated again). Across firmware builds
they need not: the driver may scale, filter and time-stamp a stream differently. On the
shared erle PXF flights 41 and 83 (ArduCopter builds ``0a326f5a`` and ``bd817897``, three
months apart) the calibration of 41 leaves, on 83, IMU2's relative scale off by −5.8, −3.7
and −3.5 % (x, y, z; 2–3 times the prior's 3 %, 30 times the fit's own σ) and its time
offset off by 9.8 ms (−9.65 ms on 41, +0.15 ms on 83); carried as if it held, the monitor
raised 15 alarms on 41 (calibrated on 83) and marked half the flight unverified.

So when the flight's log names a firmware and the calibration's flights name others
(:func:`replay.firmware.calibration_firmwares`), the monitor holds those parameters of
every IMU but the reference at the tolerance the calibration states for what a flight does
not excite (``extra.inflight.prior``: rotation ±2°, scale ±3 %, non-orthogonality ±2 %,
time offset ±1 sample, read as 1σ): the calibrated values stay the mean, their covariance
grows by the prior's (ARAIM's nominal bias bound in spirit: the thresholds and the
protection level then hold for any change within the stated tolerance, not for the value
that no longer fits). In the monitor's error model (:mod:`fdi.reconstruction`) sensor i
with unit axis h gets ``input_error_cov += σ_s²·hhᵀ + (σ_r² + σ_n²)·(I − hhᵀ)`` (scale
along its axis; rotation and non-orthogonality across it) and its timing sd
``τ_i ← √(τ_i² + σ_τ²)`` (a time-offset error δτ errs by ``hᵀω̇·δτ``, the jitter term's
form). The price is sensitivity in manoeuvres, stated by the thresholds and protection
level; the cure is a calibration on a flight of this firmware.

A calibration without an in-flight prior (turntable, static) or a log that names no
firmware (CSV, MATLAB, the Xsens DOT exports) gives nothing to compare: no change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.units import DEG, MS

__all__ = ["FirmwarePrior", "apply_firmware_prior", "firmware_prior"]


@dataclass(frozen=True)
class FirmwarePrior:
    """The parameters a calibration made under another firmware holds at its prior.

    Attributes
    ----------
    calibrated : tuple of str
        The firmware builds the calibration's flights name.
    flight : str
        The build the monitored flight's log names.
    imus : tuple of str
        The IMU groups whose parameters are widened (every one but the reference).
    misalignment_sd, nonorthogonality_sd : float
        rad (1σ).
    scale_sd : float
        Fraction (1σ).
    time_offset_sd_s : float
        s (1σ).
    """

    calibrated: tuple[str, ...]
    flight: str
    imus: tuple[str, ...]
    misalignment_sd: float
    scale_sd: float
    nonorthogonality_sd: float
    time_offset_sd_s: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (deg, %, ms), for the report's ``firmware_prior``."""
        return {"calibration_firmware": list(self.calibrated), "flight_firmware": self.flight,
                "imus": list(self.imus),
                "misalignment_deg_sd": self.misalignment_sd / DEG,
                "scale_percent_sd": 100.0 * self.scale_sd,
                "nonorthogonality_deg_sd": self.nonorthogonality_sd / DEG,
                "time_offset_ms_sd": self.time_offset_sd_s / MS}

    def text(self) -> str:
        """One line for the command's output."""
        return (f"firmware {self.flight!r}, calibrated under "
                f"{' | '.join(repr(c) for c in self.calibrated)}: {', '.join(self.imus)} "
                f"relative scale, mounting and time offset held at the calibration's prior "
                f"(±{100 * self.scale_sd:.3g} %, ±{self.misalignment_sd / DEG:.3g}°, "
                f"±{self.time_offset_sd_s / MS:.3g} ms, 1σ): less sensitive in manoeuvres "
                f"until calibrated on a flight of this firmware")


def firmware_prior(cal: Calibration, flight: Any, kind: str = "gyro") -> FirmwarePrior | None:
    """The widening a flight under another firmware needs (None: the same firmware, none
    named, or a calibration with no in-flight prior)."""
    from replay.firmware import calibration_firmwares
    from replay.time_offsets import flight_identity

    alignment = cal.extras.inflight_alignment
    if alignment is None or not alignment.prior or kind not in cal.sets:
        return None
    builds = calibration_firmwares(cal)
    here = str(flight_identity(flight)["firmware"])
    if not builds or not here or here in builds:
        return None
    inflight = cal.extras.inflight
    reference = inflight.reference if inflight is not None else ""
    groups = sorted({c.name.rsplit(".", 1)[0] for c in cal.kind(kind).sensors
                     if "." in c.name} - {reference})
    if not groups:
        return None
    p = alignment.prior
    fs = float(cal.sample_rate_hz)

    def sd(key: str, scale: float, default: float) -> float:
        v = p.get(key)
        return float(v) * scale if v is not None and math.isfinite(float(v)) else default

    return FirmwarePrior(
        calibrated=builds, flight=here, imus=tuple(groups),
        misalignment_sd=sd("misalignment_mrad_sd", 1e-3, math.radians(2.0)),
        scale_sd=sd("scale_sd", 1.0, 0.03),
        nonorthogonality_sd=sd("nonorthogonality_mrad_sd", 1e-3, 0.02),
        time_offset_sd_s=sd("time_offset_ms_sd", MS, 1.0 / fs if fs > 0 else 0.0))


def apply_firmware_prior(cal: Calibration, fp: FirmwarePrior | None,
                         kind: str = "gyro") -> Calibration:
    """``cal`` with the sensors of ``fp.imus`` widened by the prior (module docstring);
    ``cal`` itself when ``fp`` is None."""
    if fp is None:
        return cal
    s = cal.kind(kind)
    across = fp.misalignment_sd**2 + fp.nonorthogonality_sd**2
    sensors = []
    for c, h in zip(s.sensors, np.asarray(s.H, float), strict=True):
        if c.name.rsplit(".", 1)[0] not in fp.imus:
            sensors.append(c)
            continue
        norm = float(np.linalg.norm(h))
        u = h / norm if norm > 0 else np.zeros(3)
        P = np.outer(u, u)
        add = fp.scale_sd**2 * P + across * (np.eye(3) - P)
        sensors.append(replace(c, input_error_cov=np.asarray(c.input_error_cov, float) + add,
                               timing_jitter=math.hypot(c.timing_jitter, fp.time_offset_sd_s)))
    return replace(cal, sets={**cal.sets, kind: replace(s, sensors=tuple(sensors))})
