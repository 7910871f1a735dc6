"""The firmware a flight log was recorded under, read from the log's own words.

What an in-flight calibration fits splits into what belongs to the sensor and its mounting
and what belongs to the firmware that samples, filters and logs it: the time offset of one
IMU's stream against another's, its filtering, and the scale its driver applies. When the
firmware changes between two flights of one airframe those may change with it (the shared
erle PXF flights 41 and 83, three months and two firmware builds apart: IMU2's time offset
−9.65 ms against +0.15 ms, its scale factors 3–6 % apart), and a calibration made under
one build does not carry to a flight under another. The monitor says so
(:func:`firmware_change`) beside the parameters that do not fit.

Where a log names its firmware:

- **ArduPilot** (DataFlash): the ``MSG`` the vehicle writes at boot,
  ``"ArduCopter V3.3-dev (0a326f5a)"`` (vehicle, version, git hash); the reader keeps every
  ``MSG`` as a :class:`~replay.log_events.LogEvent` of source ``"MSG"``.
- **PX4** (ULog): the info fields ``sys_name``, ``ver_sw_release``, ``ver_sw`` and
  ``ver_hw``; the reader keeps them as one event of source :data:`ULOG_INFO_SOURCE`
  (:func:`px4_firmware_text`).

Logs that name none (CSV, MATLAB, the Xsens DOT exports) give ``""``: nothing is compared.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

from replay.log_events import LogEvent

__all__ = ["ULOG_INFO_SOURCE", "calibration_firmwares", "firmware_change", "firmware_of",
           "px4_firmware_text"]

ULOG_INFO_SOURCE = "ulog.info"
"""Source of the event that carries a PX4 log's firmware (its info fields)."""

_ARDUPILOT = re.compile(
    r"^(?:Ardu[A-Za-z]+|APM:[A-Za-z]+|Blimp|AntennaTracker)\s+V?\d+\.\d+[\w.\-]*"
    r"(?:\s+\([0-9A-Fa-f]{6,40}\))?")
"""The boot message of an ArduPilot vehicle: ``ArduCopter V4.1.0 (f2af3c7e)``."""


def _release(v: Any) -> str:
    """PX4's ``ver_sw_release`` (0xAABBCCTT: major, minor, patch, type) as ``v1.11.2``;
    ``""`` when it is not a positive integer."""
    try:
        n = int(v)
    except (TypeError, ValueError):
        return ""
    if n <= 0:
        return ""
    return f"v{(n >> 24) & 0xFF}.{(n >> 16) & 0xFF}.{(n >> 8) & 0xFF}"


def px4_firmware_text(info: Mapping[str, Any]) -> str:
    """A PX4 log's firmware from its info fields: ``"PX4 v1.11.2 8583f1da CUBEPILOT_CUBEORANGE"``
    (system, release, the first 8 digits of the git hash, hardware); ``""`` when the log
    has neither a release nor a hash."""
    release = _release(info.get("ver_sw_release"))
    sha = str(info.get("ver_sw", "") or "").strip()[:8]
    if not release and not sha:
        return ""
    parts = [str(info.get("sys_name", "") or "PX4").strip(), release, sha,
             str(info.get("ver_hw", "") or "").strip()]
    return " ".join(p for p in parts if p)


def firmware_of(events: Sequence[LogEvent]) -> str:
    """The firmware a flight's events name (module docstring), ``""`` when none does.

    The first ArduPilot boot message or PX4 info event wins; a log holding two different
    boot messages (a reboot into another build within one log) gives both, joined by
    ``" | "``.
    """
    seen: list[str] = []
    for e in events:
        text = str(e.text).strip()
        if e.source == ULOG_INFO_SOURCE and text:
            found = text
        elif e.source == "MSG":
            m = _ARDUPILOT.match(text)
            if m is None:
                continue
            found = m.group(0)
        else:
            continue
        if found not in seen:
            seen.append(found)
    return " | ".join(seen)


def firmware_change(calibrated: str, flight: str) -> str | None:
    """One warning line when the calibration's firmware and the flight's are both known and
    differ, else None."""
    if not calibrated or not flight or calibrated == flight:
        return None
    return (f"the calibration was made under firmware {calibrated!r} and this flight runs "
            f"{flight!r}: what belongs to the firmware (time offsets, filtering, driver "
            f"scale) may not carry; calibrate on a flight of this firmware "
            f"(rimu calibrate in-flight)")


def calibration_firmwares(cal: Any) -> tuple[str, ...]:
    """The firmware builds a calibration's flights name (``extra.inflight``): that of its
    flight, or of each flight calibrated together, in order, without repeats; ``()`` when
    none names one."""
    names: list[str] = []
    extras = getattr(cal, "extras", None)
    alignment = getattr(extras, "inflight_alignment", None)
    for fv in (alignment.flights if alignment is not None else ()):
        if fv.flight is not None and fv.flight.firmware and fv.flight.firmware not in names:
            names.append(fv.flight.firmware)
    inflight = getattr(extras, "inflight", None)
    own = inflight.flight if inflight is not None else None
    if not names and own is not None and own.firmware:
        names.append(own.firmware)
    return tuple(names)
