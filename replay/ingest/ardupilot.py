"""ArduPilot DataFlash ``.BIN`` logs, read with pymavlink's ``DFReader``.

IMU messages: ``IMU``, ``IMU2``, ``IMU3`` (one message type per IMU, older logs) or one
``IMU`` message with an instance field ``I`` (newer logs). Fields used: the sample time
``TimeUS`` (µs) or ``TimeMS`` (ms), ``GyrX..Z`` (rad/s), ``AccX..Z`` (m/s²), the
temperature ``Temp`` or ``T`` (°C; a column that is 0 throughout is taken as not logged),
the error counters ``ErrG``/``EG``. Values are what ArduPilot logged: body frame, after its
board rotation and its own calibration.

Events: ``ERR`` (subsystem and code: crash check, EKF check, EKF/INAV failsafe, ...),
``EV`` (arming, landing, flips) and ``MSG`` (text) become :class:`~replay.log_events.LogEvent`
records. Old logs give these messages no time field; an event then starts at the time of
the last IMU sample before it in the file (the log is written in time order) and an
interval ends at the first IMU sample after its closing message (logging pauses while
disarmed, so the two can be far apart: the span is taken wide). Category ``crash``: a
crash check (``ERR`` 12, code 1 crash or 2 loss of control) until the next ``EV`` ARMED
or the end of the log, a thrust-loss check (25) until its code 0, a flip from ``EV``
FLIP_START to FLIP_END. Category ``estimator``: an EKF check (16, code 2 bad variance) or
EKF/INAV failsafe (17) until the same subsystem logs code 0, an EKF primary change (24,
an instant). Everything else is ``info``.

Damage is found from pymavlink's own index of message offsets: a message that runs past
the end of the file (truncated log) or bytes between two messages that belong to none
(corruption) is reported with its byte offset. pymavlink resynchronises silently over
both; rimu refuses the log unless asked to salvage, and then keeps the samples that end
before the first damaged byte.
"""

from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path
from typing import Any

import numpy as np

from fdi.errors import FileFormatError
from fdi.units import TIME_UNITS
from replay.ingest.stream import Damage, ImuStream, LogRead
from replay.log_events import LogEvent

__all__ = ["ERR_SUBSYSTEMS", "EVENT_TYPES", "EV_IDS", "IMU_TYPES", "ardupilot_events",
           "looks_like_dataflash", "read_ardupilot"]

IMU_TYPES = ("IMU", "IMU2", "IMU3")
"""DataFlash message types that carry IMU samples."""
EVENT_TYPES = ("ERR", "EV", "MSG")
"""DataFlash message types read as events."""
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
_HEAD = b"\xa3\x95"


def looks_like_dataflash(path: str | Path) -> bool:
    """True when the file starts with a DataFlash message header (``A3 95 80``: FMT)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(3) == _HEAD + b"\x80"
    except OSError:
        return False


@contextlib.contextmanager
def _quiet() -> Any:
    """Silence pymavlink while it indexes: Python prints and its compiled indexer's
    ``fprintf(stderr, "bad header ...")`` (a file-descriptor-level redirect)."""
    sink = io.StringIO()
    saved = []
    try:
        for fd in (1, 2):
            try:
                saved.append((fd, os.dup(fd)))
            except OSError:
                continue
        with open(os.devnull, "wb") as null:
            for fd, _ in saved:
                os.dup2(null.fileno(), fd)
            with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
                yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)


def _open(path: str) -> Any:
    from pymavlink import DFReader

    try:
        with _quiet():
            return DFReader.DFReader_binary(path)
    except OSError as exc:
        raise FileFormatError(path, f"cannot read ({exc.strerror})") from None
    except Exception as exc:        # pymavlink raises many kinds on a non-DataFlash file
        raise FileFormatError(path, f"not a readable DataFlash log ({type(exc).__name__}: "
                                    f"{exc})") from None


def _first_damage(r: Any) -> tuple[int, str] | None:
    """(offset, what) of the first truncated or unaccounted byte, from pymavlink's index."""
    starts, lens, names = [], [], []
    for mtype, offs in enumerate(r.offsets):
        if not offs:
            continue
        fmt = r.formats.get(mtype)
        if fmt is None:
            return int(offs[0]), f"message type {mtype} has no FMT definition"
        starts.append(np.asarray(offs, np.int64))
        lens.append(np.full(len(offs), fmt.len, np.int64))
        names.append(np.full(len(offs), mtype))
    if not starts:
        return (0, "no DataFlash message found")
    o = np.concatenate(starts)
    order = np.argsort(o, kind="stable")
    o = o[order]
    ln = np.concatenate(lens)[order]
    ty = np.concatenate(names)[order]
    end = o + ln
    if o[0] != 0:
        return 0, f"{o[0]} bytes before the first message do not belong to any message"
    bad = np.flatnonzero(o[1:] != end[:-1])
    if bad.size:
        # DataFlash has no checksum: the message before lost framing may hold the first
        # corrupt bytes in its body, so the damage starts where that message starts.
        k = int(bad[0])
        name = r.formats[int(ty[k])].name
        if o[k + 1] < end[k]:
            return int(o[k]), (f"corrupt bytes: a {r.formats[int(ty[k + 1])].name} "
                               f"header inside the {name} message")
        return int(o[k]), (f"corrupt bytes: {int(o[k + 1] - end[k])} bytes after this "
                           f"{name} message belong to no message")
    if end[-1] > r.data_len:
        return int(o[-1]), (f"file ends inside a {r.formats[int(ty[-1])].name} message "
                            f"(truncated: {int(end[-1] - r.data_len)} bytes missing)")
    if end[-1] < r.data_len:
        return int(end[-1]), f"{int(r.data_len - end[-1])} trailing bytes are no message"
    return None


def _column(fmt: Any, *names: str) -> str | None:
    for n in names:
        if n in fmt.columns:
            return n
    return None


def _imu_fields(p: str, fmt: Any, t: str) -> tuple[str | None, ...]:
    """Columns of an IMU message type: time, instance, temperature, error count, accel."""
    accel = "AccX" if all(c in fmt.columns for c in ("AccX", "AccY", "AccZ")) else None
    f = (_column(fmt, "TimeUS", "TimeMS"), _column(fmt, "I"), _column(fmt, "Temp", "T"),
         _column(fmt, "ErrG", "EG"), accel)
    if f[0] is None or not all(c in fmt.columns for c in ("GyrX", "GyrY", "GyrZ")):
        raise FileFormatError(p, f"{t} message has columns {fmt.columns}; expected "
                                 f"TimeUS or TimeMS and GyrX, GyrY, GyrZ", field=t)
    return f


def _own_time(m: Any) -> float | None:
    """An event's own time (TimeUS/TimeMS, s) when it has one."""
    for col, unit in (("TimeUS", "us"), ("TimeMS", "ms")):
        v = getattr(m, col, None)
        if isinstance(v, int | float) and not isinstance(v, bool):
            return float(v) * TIME_UNITS[unit]
    return None


def _collect(r: Any, types: list[str], fields: dict[str, tuple[str | None, ...]],
             limit: int, raw_events: list[list[Any]] | None = None
             ) -> dict[tuple[str, int], dict[str, list[float]]]:
    """The IMU messages before byte ``limit``, as columns per (type, instance); the
    ``EVENT_TYPES`` messages go to ``raw_events`` as [time before s, time after s, type,
    fields] (the last IMU time before it and the first after it, or its own time)."""
    cols: dict[tuple[str, int], dict[str, list[float]]] = {}
    ev_types = [e for e in EVENT_TYPES if e in r.name_to_id] if raw_events is not None \
        else []
    last_imu = float("nan")
    waiting: list[list[Any]] = []
    with _quiet():
        while True:
            m = r.recv_match(type=types + ev_types)
            if m is None or r.offset > limit:
                break
            t = m.get_type()
            if t in EVENT_TYPES:
                own = _own_time(m)
                rec = [own if own is not None else last_imu,
                       own if own is not None else float("nan"), t, m.to_dict()]
                raw_events.append(rec)
                if own is None:
                    waiting.append(rec)
                continue
            tcol, icol, tempcol, ecol, acol = fields[t]
            inst = int(getattr(m, icol)) if icol else 0
            c = cols.setdefault((t, inst), {k: [] for k in
                                            ("t", "gx", "gy", "gz", "ax", "ay", "az",
                                             "temp", "err")})
            c["t"].append(getattr(m, tcol))
            last_imu = float(getattr(m, tcol)) * TIME_UNITS["us" if tcol == "TimeUS" else "ms"]
            for rec in waiting:
                rec[1] = last_imu
            waiting.clear()
            c["gx"].append(m.GyrX)
            c["gy"].append(m.GyrY)
            c["gz"].append(m.GyrZ)
            if acol:
                c["ax"].append(m.AccX)
                c["ay"].append(m.AccY)
                c["az"].append(m.AccZ)
            if tempcol:
                c["temp"].append(getattr(m, tempcol))
            if ecol:
                c["err"].append(getattr(m, ecol))
    return cols


def _streams(cols: dict[tuple[str, int], dict[str, list[float]]],
             fields: dict[str, tuple[str | None, ...]]) -> list[ImuStream]:
    """One :class:`ImuStream` per (type, instance), in IMU, IMU2, IMU3 / instance order."""
    streams = []
    for k, (t, inst) in enumerate(sorted(cols, key=lambda ti: (IMU_TYPES.index(ti[0]),
                                                               ti[1]))):
        c = cols[(t, inst)]
        tcol = fields[t][0]
        ts = np.asarray(c["t"], float) * TIME_UNITS["us" if tcol == "TimeUS" else "ms"]
        notes = []
        temp = np.asarray(c["temp"], float) if c["temp"] else None
        if temp is not None and not np.any(temp != 0):
            temp = None
            notes.append(f"{t}.{fields[t][2]} is 0 throughout: temperature not logged")
        acc = np.column_stack([c["ax"], c["ay"], c["az"]]).astype(float) if c["ax"] else None
        src = f"{t}[I={inst}]" if fields[t][1] else t
        streams.append(ImuStream(
            name=f"imu{k + 1}", t=ts, gyro=np.column_stack([c["gx"], c["gy"], c["gz"]])
            .astype(float), accel=acc, temperature=temp, source=src,
            error_count=np.asarray(c["err"], float) if c["err"] else None,
            notes=tuple(notes)))
    return streams


def read_ardupilot(path: str | Path, *, salvage: bool = False) -> LogRead:
    """Read the IMU samples of a DataFlash log.

    Parameters
    ----------
    path : str or Path
    salvage : bool
        On a truncated or corrupt log, return the samples before the damage (with
        :attr:`LogRead.damage` set) instead of raising.

    Returns
    -------
    LogRead
        One stream per IMU (``imu1`` = ``IMU`` or instance 0, ``imu2`` = ``IMU2`` or
        instance 1, ...).

    Raises
    ------
    FileFormatError
        Unreadable file; no IMU message; damage (without ``salvage``), naming the byte
        offset and what is wrong there.
    """
    p = str(path)
    r = _open(p)
    types = [t for t in IMU_TYPES if t in r.name_to_id and r.counts[r.name_to_id[t]] > 0]
    if not types:
        raise FileFormatError(p, f"no IMU messages ({', '.join(IMU_TYPES)}) in the log")
    damage = _first_damage(r)
    limit = damage[0] if damage is not None else r.data_len
    fields = {t: _imu_fields(p, r.formats[r.name_to_id[t]], t) for t in types}
    raw_events: list[list[Any]] = []
    cols = _collect(r, types, fields, limit, raw_events)
    streams = _streams(cols, fields)
    events = ardupilot_events(raw_events)
    meta: dict[str, Any] = {"messages": {t: int(r.counts[r.name_to_id[t]]) for t in types},
                            "bytes": int(r.data_len)}
    dmg = None
    if damage is not None:
        dmg = Damage(p, damage[1], offset=damage[0],
                     samples_before=sum(s.size for s in streams))
        if not salvage:
            raise dmg.error()
    meta["events"] = {e: int(r.counts[r.name_to_id[e]]) for e in EVENT_TYPES
                      if e in r.name_to_id}
    return LogRead(p, "ardupilot", tuple(streams), dmg, meta, events=events)


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
