"""ArduPilot DataFlash ``.BIN`` logs, read with pymavlink's ``DFReader``.

IMU messages: ``IMU``, ``IMU2``, ``IMU3`` (one message type per IMU, older logs) or one
``IMU`` message with an instance field ``I`` (newer logs). Fields used: the sample time
``TimeUS`` (µs) or ``TimeMS`` (ms), ``GyrX..Z`` (rad/s), ``AccX..Z`` (m/s²), the
temperature ``Temp`` or ``T`` (°C; a column that is 0 throughout is taken as not logged),
the error counters ``ErrG``/``EG``. Values are what ArduPilot logged: body frame, after its
board rotation and its own calibration.

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

__all__ = ["IMU_TYPES", "looks_like_dataflash", "read_ardupilot"]

IMU_TYPES = ("IMU", "IMU2", "IMU3")
"""DataFlash message types that carry IMU samples."""
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


def _collect(r: Any, types: list[str], fields: dict[str, tuple[str | None, ...]],
             limit: int) -> dict[tuple[str, int], dict[str, list[float]]]:
    """The IMU messages before byte ``limit``, as columns per (type, instance)."""
    cols: dict[tuple[str, int], dict[str, list[float]]] = {}
    with _quiet():
        while True:
            m = r.recv_match(type=types)
            if m is None or r.offset > limit:
                break
            t = m.get_type()
            tcol, icol, tempcol, ecol, acol = fields[t]
            inst = int(getattr(m, icol)) if icol else 0
            c = cols.setdefault((t, inst), {k: [] for k in
                                            ("t", "gx", "gy", "gz", "ax", "ay", "az",
                                             "temp", "err")})
            c["t"].append(getattr(m, tcol))
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
    cols = _collect(r, types, fields, limit)
    streams = _streams(cols, fields)
    meta: dict[str, Any] = {"messages": {t: int(r.counts[r.name_to_id[t]]) for t in types},
                            "bytes": int(r.data_len)}
    dmg = None
    if damage is not None:
        dmg = Damage(p, damage[1], offset=damage[0],
                     samples_before=sum(s.size for s in streams))
        if not salvage:
            raise dmg.error()
    return LogRead(p, "ardupilot", tuple(streams), dmg, meta)
