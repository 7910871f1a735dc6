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
both (at the next header of a known format); rimu refuses the log unless asked to
salvage, and then keeps every message that starts where the previous trusted one ends:
each damaged stretch (byte range, what is wrong there, the messages dropped and the IMU
samples lost, from each IMU's own time steps) is reported, and the samples after it are
kept. The message just before a break in framing is distrusted too (DataFlash has no
checksum: its body may hold the first corrupt bytes) unless the break is exactly one
message whose sync bytes alone are damaged.
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
from replay.ingest.ardupilot_events import ERR_SUBSYSTEMS, EV_IDS, ardupilot_events
from replay.ingest.dataflash_damage import (
    damage_record,
    first_damage,
    trusted_counts,
)

# the framing walk, re-exported under the name the tests reach it by
from replay.ingest.dataflash_damage import scan as _scan  # noqa: F401
from replay.ingest.dataflash_fmt import (
    EVENT_TYPES,
    FMT_ID,
    FMT_LEN,
    HEAD,
    IMU_TYPES,
    fmt_check,
    fmt_repairs,
)
from replay.ingest.stream import ImuStream, LogRead

__all__ = ["ERR_SUBSYSTEMS", "EVENT_TYPES", "EV_IDS", "IMU_TYPES", "ardupilot_events",
           "fmt_repairs", "looks_like_dataflash", "read_ardupilot"]


def looks_like_dataflash(path: str | Path) -> bool:
    """True when the file starts with a DataFlash message header (``A3 95 80``: FMT)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(3) == HEAD + b"\x80"
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


def _patched_reader(path: str, patches: dict[int, bytes]) -> Any:
    """pymavlink's reader over a copy-on-write mapping of the file with ``patches``
    applied before it indexes (the file itself is not changed)."""
    import mmap

    from pymavlink import DFReader

    class Patched(DFReader.DFReader_binary):
        def __init__(self) -> None:              # DFReader_binary.__init__, patched map
            DFReader.DFReader.__init__(self)
            self.filehandle = open(path, "rb")      # closed by pymavlink
            self.filehandle.seek(0, 2)
            self.data_len = self.filehandle.tell()
            self.filehandle.seek(0)
            self.data_map = mmap.mmap(self.filehandle.fileno(), self.data_len,
                                      access=mmap.ACCESS_COPY)
            for off, rec in patches.items():
                self.data_map[off:off + len(rec)] = rec
            self.HEAD1, self.HEAD2 = HEAD
            self.unpackers = {}
            self.formats = {FMT_ID: DFReader.DFFormat(FMT_ID, "FMT", FMT_LEN, "BBnNZ",
                                                       "Type,Length,Name,Format,Columns")}
            self._zero_time_base = False
            self.prev_type = None
            self.init_arrays()
            self.init_clock()
            self.prev_type = None
            self._rewind(keep_messages=True)

    return Patched()


def _open(path: str) -> Any:
    from pymavlink import DFReader

    patches, warnings = fmt_check(path)
    try:
        with _quiet():
            r = _patched_reader(path, patches) if patches else DFReader.DFReader_binary(path)
        r.fmt_warnings = warnings
        return r
    except OSError as exc:
        raise FileFormatError(path, f"cannot read ({exc.strerror})") from None
    except Exception as exc:        # pymavlink raises many kinds on a non-DataFlash file
        raise FileFormatError(path, f"not a readable DataFlash log ({type(exc).__name__}: "
                                    f"{exc})") from None


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


def _in_order(r: Any, wanted: list[str], limit: int) -> Any:
    """(start, message) of the ``wanted`` types in file order, through pymavlink's index."""
    while True:
        m = r.recv_match(type=wanted)
        if m is None or r.offset > limit:
            return
        yield int(r.offset) - int(r.formats[r.name_to_id[m.get_type()]].len), m


def _at(r: Any, wanted: list[str], trusted: dict[int, int]) -> Any:
    """(start, message) of the ``wanted`` types among the trusted messages (start: type id),
    each parsed by pymavlink where it starts (past damage its index does not reach)."""
    ids = {r.name_to_id[t] for t in wanted}
    for start in sorted(trusted):
        if trusted[start] not in ids:
            continue
        r.offset = start
        r.remaining = int(r.data_len) - start
        try:
            m = r._parse_next()
        except Exception:                 # a damaged body pymavlink cannot unpack
            continue
        if m is not None and r.offset - int(r.formats[trusted[start]].len) == start:
            yield start, m


def _collect(r: Any, types: list[str], fields: dict[str, tuple[str | None, ...]],
             limit: int, raw_events: list[list[Any]] | None = None,
             trusted: dict[int, int] | None = None
             ) -> dict[tuple[str, int], dict[str, list[float]]]:
    """The IMU messages before byte ``limit`` (with ``trusted``, {start: type id}, only
    those messages, wherever they are), as columns per (type, instance), ``"off"`` holding
    each one's start; the ``EVENT_TYPES`` messages go to ``raw_events`` as [time before s,
    time after s, type, fields] (the last IMU time before it and the first after it, or
    its own time)."""
    cols: dict[tuple[str, int], dict[str, list[float]]] = {}
    ev_types = [e for e in EVENT_TYPES if e in r.name_to_id] if raw_events is not None \
        else []
    last_imu = float("nan")
    waiting: list[list[Any]] = []
    with _quiet():
        source = (_in_order(r, types + ev_types, limit) if trusted is None
                  else _at(r, types + ev_types, trusted))
        for start, m in source:
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
                                             "temp", "err", "off")})
            c["off"].append(start)
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
    if r.fmt_warnings and not salvage:
        raise FileFormatError(p, f"{r.fmt_warnings[0]}; --salvage repairs it or skips the "
                                 "type it defines, with a warning")
    damage = first_damage(r)
    counts = {t: int(r.counts[r.name_to_id[t]]) for t in (*IMU_TYPES, *EVENT_TYPES)
              if t in r.name_to_id}
    stretches: list[dict[str, Any]] = []
    trusted: dict[int, int] = {}
    if damage is not None:
        stretches, trusted, counts = trusted_counts(r, counts)
    types = [t for t in IMU_TYPES if counts.get(t, 0) > 0]
    if not types:
        raise FileFormatError(p, f"no IMU messages ({', '.join(IMU_TYPES)}) in the log")
    fields = {t: _imu_fields(p, r.formats[r.name_to_id[t]], t) for t in types}
    meta = _meta(r, counts, types)
    raw_events: list[list[Any]] = []
    if damage is None:
        cols = _collect(r, types, fields, r.data_len, raw_events)
        return LogRead(p, "ardupilot", tuple(_streams(cols, fields)), None, meta,
                       events=ardupilot_events(raw_events))
    cols = _collect(r, types, fields, r.data_len + 1, raw_events, trusted)
    streams = _streams(cols, fields)
    dmg = damage_record(p, damage, stretches, streams, cols)
    if not salvage:
        raise dmg.error()
    return LogRead(p, "ardupilot", tuple(streams), dmg, meta,
                   events=ardupilot_events(raw_events))


def _meta(r: Any, counts: dict[str, int], types: list[str]) -> dict[str, Any]:
    """The reader's meta: message counts, bytes, events, and the warnings (repaired FMT
    definitions, IMU types declared without a sample)."""
    meta: dict[str, Any] = {"messages": {t: counts[t] for t in types},
                            "bytes": int(r.data_len)}
    meta["events"] = {e: counts[e] for e in EVENT_TYPES if e in counts}
    empty = [t for t in IMU_TYPES if t in r.name_to_id and t not in types]
    warnings = list(r.fmt_warnings) + [
        f"the log's format declares {t} but holds no {t} sample (that IMU logged nothing)"
        for t in empty]
    if warnings:
        meta["warnings"] = warnings
    return meta
