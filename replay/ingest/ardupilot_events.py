"""Events of a DataFlash log: ``ERR``, ``EV`` and ``MSG`` messages as
:class:`~replay.log_events.LogEvent` records (:func:`ardupilot_events`; the categories and
spans: :mod:`replay.ingest.ardupilot`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from replay.log_events import LogEvent

__all__ = ["ERR_SUBSYSTEMS", "EV_IDS", "ardupilot_events"]

ERR_SUBSYSTEMS = {
    1: "MAIN", 2: "RADIO", 3: "COMPASS", 4: "OPTFLOW", 5: "FAILSAFE_RADIO",
    6: "FAILSAFE_BATT", 7: "FAILSAFE_GPS", 8: "FAILSAFE_GCS", 9: "FAILSAFE_FENCE",
    10: "FLIGHT_MODE", 11: "GPS", 12: "CRASH_CHECK", 13: "FLIP", 14: "AUTOTUNE",
    15: "PARACHUTE", 16: "EKFCHECK", 17: "FAILSAFE_EKFINAV", 18: "BARO", 19: "CPU",
    20: "FAILSAFE_ADSB", 21: "TERRAIN", 22: "NAVIGATION", 23: "FAILSAFE_TERRAIN",
    24: "EKF_PRIMARY", 25: "THRUST_LOSS_CHECK"}
"""ArduCopter ``ERR.Subsys`` numbers (ArduCopter ``defines.h``)."""
EV_IDS = {
    10: "ARMED", 11: "DISARMED", 15: "AUTO_ARMED", 16: "TAKEOFF",
    17: "LAND_COMPLETE_MAYBE", 18: "LAND_COMPLETE", 19: "LOST_GPS", 21: "FLIP_START",
    22: "FLIP_END", 25: "SET_HOME", 28: "NOT_LANDED", 60: "EKF_ALT_RESET",
    62: "EKF_YAW_RESET"}
"""ArduCopter ``EV.Id`` numbers (``DATA_*`` in ``defines.h``) that rimu names."""
_CRASH = 12
_UNTIL_CLEARED = {16: "estimator", 17: "estimator", 25: "crash"}
_ERR_TEXT = {(12, 1): "crash", (12, 2): "loss of control", (16, 2): "bad variance",
             (16, 0): "variance cleared", (13, 2): "abandoned"}


def _int(d: dict[str, Any], key: str) -> int:
    v = d.get(key, 0)
    try:
        return int(v)
    except (TypeError, ValueError):
        return 0


def ardupilot_events(raw: list[list[Any]]) -> tuple[LogEvent, ...]:
    """Events from [time before s, time after s, type, fields] of ``ERR``/``EV``/``MSG``
    messages in log order (module docstring).

    A missing time before (an event ahead of the first IMU sample) takes the time after,
    a missing time after (no IMU sample follows) the time before.
    """
    items = []
    for tb, ta, typ, d in raw:
        tb = tb if np.isfinite(tb) else ta
        ta = ta if np.isfinite(ta) else tb
        if not np.isfinite(tb):
            tb = ta = 0.0
        items.append((float(tb), float(ta), typ, d))

    def until(k: int, match: Any) -> float:
        """Time after the first later message that ``match``es, else inf."""
        return next((ta for _, ta, ty, e in items[k + 1:] if match(ty, e)), float("inf"))

    out: list[LogEvent] = []
    for k, (t, _, typ, d) in enumerate(items):
        if typ == "MSG":
            out.append(LogEvent(t, t, "MSG", str(d.get("Message", "")).strip()))
        elif typ == "EV":
            i = _int(d, "Id")
            name = EV_IDS.get(i, f"id {i}")
            if i == 21:      # FLIP_START: to the FLIP_END after it
                end = until(k, lambda ty, e: ty == "EV" and _int(e, "Id") == 22)
                out.append(LogEvent(t, max(end, t), "EV", f"EV {name}", i, "crash"))
            else:
                out.append(LogEvent(t, t, "EV", f"EV {name}", i))
        elif typ == "ERR":
            sub, code = _int(d, "Subsys"), _int(d, "ECode")
            name = ERR_SUBSYSTEMS.get(sub, f"subsystem {sub}")
            what = _ERR_TEXT.get((sub, code), "")
            text = f"ERR {name} {code}" + (f": {what}" if what else "")
            if sub == _CRASH and code != 0:
                end = until(k, lambda ty, e: ty == "EV" and _int(e, "Id") == 10)
                out.append(LogEvent(t, max(end, t), "ERR", text, code, "crash"))
            elif sub in _UNTIL_CLEARED and code != 0:
                end = until(k, lambda ty, e, sub=sub: ty == "ERR" and _int(e, "Subsys") == sub
                            and _int(e, "ECode") == 0)
                out.append(LogEvent(t, max(end, t), "ERR", text, code, _UNTIL_CLEARED[sub]))
            elif sub == 24:
                out.append(LogEvent(t, t, "ERR", f"ERR EKF_PRIMARY {code}: primary core "
                                                 f"changed to {code}", code, "estimator"))
            else:
                out.append(LogEvent(t, t, "ERR", text, code))
    return tuple(out)
