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


def _index(r: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Starts, lengths and type ids of the messages pymavlink indexed, in file order
    (types without a FMT definition left out: they are no message)."""
    starts, lens, names = [], [], []
    for mtype, offs in enumerate(r.offsets):
        fmt = r.formats.get(mtype)
        if not offs or fmt is None:
            continue
        starts.append(np.asarray(offs, np.int64))
        lens.append(np.full(len(offs), fmt.len, np.int64))
        names.append(np.full(len(offs), mtype))
    if not starts:
        z = np.zeros(0, np.int64)
        return z, z, z
    o = np.concatenate(starts)
    order = np.argsort(o, kind="stable")
    return o[order], np.concatenate(lens)[order], np.concatenate(names)[order]


def _an(name: str) -> str:
    """``name`` with its indefinite article (``an IMU``, ``a GPS``)."""
    return f"{'an' if name[:1] in 'AEIOU' else 'a'} {name}"


def _damaged_header(r: Any, data: bytes, a: int, b: int) -> str | None:
    """The type name when bytes ``[a, b)`` are exactly one message whose sync bytes are
    damaged (one of the two intact, a known type whose length is ``b - a``), else None."""
    if b - a < 3 or not (data[a] == _HEAD[0] or data[a + 1] == _HEAD[1]):
        return None
    fmt = r.formats.get(data[a + 2])
    return fmt.name if fmt is not None and fmt.len == b - a else None


def _stretches(r: Any, data: bytes) -> tuple[list[dict[str, Any]], set[int]]:
    """Every damaged stretch of the log and the starts of the messages to trust.

    pymavlink resynchronises on the next header of a known format; a message is trusted
    when it starts where the previous trusted one ends. Where framing breaks, the bytes up
    to the next message are a damaged stretch; the message before the break is distrusted
    too (DataFlash has no checksum: its body may hold the first corrupt bytes), unless the
    break is exactly one message whose sync bytes alone are damaged.
    """
    o, ln, ty = _index(r)
    n_data = int(r.data_len)
    out: list[dict[str, Any]] = []
    keep: list[int] = []                 # indices into o of trusted messages
    pos = 0

    def add(a: int, b: int, what: str) -> None:
        if out and a <= out[-1]["end"]:
            out[-1]["end"] = max(out[-1]["end"], b)
            out[-1]["what"] += "; " + what
        else:
            out.append({"start": int(a), "end": int(b), "what": what})

    for i in range(o.shape[0]):
        a, e = int(o[i]), int(o[i] + ln[i])
        if a == pos:
            keep.append(i)
            pos = e
            continue
        name = r.formats[int(ty[i])].name
        if a > pos:
            hdr = _damaged_header(r, data, pos, a) if keep or pos == 0 else None
            if hdr is not None:
                add(pos, a, f"one {hdr} message with damaged sync bytes")
            elif keep:
                j = keep.pop()
                prev = r.formats[int(ty[j])].name
                add(int(o[j]), a, f"{a - pos} bytes after {_an(prev)} message belong to "
                                  f"no message (that {prev} message is distrusted)")
            else:
                add(pos, a, f"{a - pos} bytes before the first message belong to no message")
        else:                            # a header inside the previous message
            j = keep.pop()
            prev = r.formats[int(ty[j])].name
            add(int(o[j]), a, f"{_an(name)} header inside {_an(prev)} message")
        keep.append(i)
        pos = e
    if keep and pos > n_data:
        j = keep.pop()
        add(int(o[j]), n_data, f"file ends inside {_an(r.formats[int(ty[j])].name)} "
                               f"message (truncated: {pos - n_data} bytes missing)")
    elif pos < n_data and keep:
        add(pos, n_data, f"{n_data - pos} trailing bytes are no message")
    for x in out:
        x["bytes"] = x["end"] - x["start"]
        inside = (o >= x["start"]) & (o < x["end"])
        kept = np.zeros(o.shape[0], bool)
        kept[keep] = True
        dropped = ty[inside & ~kept]
        x["dropped_messages"] = {r.formats[int(k)].name: int(np.sum(dropped == k))
                                 for k in np.unique(dropped)}
    return out, {int(o[i]) for i in keep}


def _lost_samples(stretches: list[dict[str, Any]], streams: list[ImuStream],
                  offsets: dict[str, np.ndarray]) -> None:
    """Add ``lost`` (IMU samples per stream) to each stretch, from the stream's own time
    steps on either side of it (or, at the end of the log, the messages dropped there)."""
    for x in stretches:
        lost = {}
        for s in streams:
            off = offsets[s.name]
            before = np.flatnonzero(off < x["start"])
            after = np.flatnonzero(off >= x["end"])
            if before.size and after.size and s.size > 2:
                dt = float(np.median(np.diff(s.t)))
                gap = float(s.t[after[0]] - s.t[before[-1]])
                lost[s.name] = max(0, round(gap / dt) - 1) if dt > 0 else 0
            else:
                lost[s.name] = int(x["dropped_messages"].get(s.source.split("[")[0], 0)) \
                    if not s.source.endswith("]") else None
        x["lost"] = {"imu_samples": lost}


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
             limit: int, trusted: set[int] | None = None
             ) -> dict[tuple[str, int], dict[str, list[float]]]:
    """The IMU messages before byte ``limit`` (and, with ``trusted``, only those whose
    start is in it), as columns per (type, instance); ``"off"`` holds each one's start."""
    cols: dict[tuple[str, int], dict[str, list[float]]] = {}
    with _quiet():
        while True:
            m = r.recv_match(type=types)
            if m is None or r.offset > limit:
                break
            t = m.get_type()
            start = int(r.offset) - int(r.formats[r.name_to_id[t]].len)
            if trusted is not None and start not in trusted:
                continue
            tcol, icol, tempcol, ecol, acol = fields[t]
            inst = int(getattr(m, icol)) if icol else 0
            c = cols.setdefault((t, inst), {k: [] for k in
                                            ("t", "gx", "gy", "gz", "ax", "ay", "az",
                                             "temp", "err", "off")})
            c["off"].append(start)
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
    fields = {t: _imu_fields(p, r.formats[r.name_to_id[t]], t) for t in types}
    meta: dict[str, Any] = {"messages": {t: int(r.counts[r.name_to_id[t]]) for t in types},
                            "bytes": int(r.data_len)}
    empty = [t for t in IMU_TYPES if t in r.name_to_id and t not in types]
    if empty:
        meta["warnings"] = [f"the log's format declares {t} but holds no {t} sample (that "
                            f"IMU logged nothing)" for t in empty]
    if damage is None:
        cols = _collect(r, types, fields, r.data_len)
        return LogRead(p, "ardupilot", tuple(_streams(cols, fields)), None, meta)
    try:
        data = Path(p).read_bytes()[:int(r.data_len)]
    except OSError as exc:
        raise FileFormatError(p, f"cannot read ({exc.strerror})") from None
    stretches, trusted = _stretches(r, data)
    cols = _collect(r, types, fields, r.data_len + 1, trusted)
    streams = _streams(cols, fields)
    offsets = {s.name: np.asarray(cols[key]["off"], np.int64) for s, key in zip(
        streams, sorted(cols, key=lambda ti: (IMU_TYPES.index(ti[0]), ti[1])), strict=True)}
    _lost_samples(stretches, streams, offsets)
    first = stretches[0] if stretches else {"start": damage[0], "what": damage[1]}
    before = sum(int(np.sum(o < first["start"])) for o in offsets.values())
    dmg = Damage(p, first["what"], offset=int(first["start"]), samples_before=before,
                 stretches=tuple(stretches),
                 samples_after=sum(s.size for s in streams) - before)
    if not salvage:
        raise dmg.error()
    return LogRead(p, "ardupilot", tuple(streams), dmg, meta)
