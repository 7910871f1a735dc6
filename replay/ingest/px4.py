"""PX4 ULog files, read with pyulog.

Per IMU instance (``multi_id`` 0, 1, 2, ...): ``sensor_gyro`` (``x, y, z`` rad/s,
``temperature`` °C, ``device_id``, ``error_count``) and the ``sensor_accel`` instance with
the same index (``x, y, z`` m/s²), each with its own ``timestamp_sample`` (µs since boot;
``timestamp`` when absent). The accelerometer is placed on the gyro's times by linear
interpolation (counted in the stream's notes). A log without ``sensor_gyro`` but with
``vehicle_imu`` gives rates from its delta angles: ``delta_angle / delta_angle_dt``
(the mean rate over each integration interval, stamped at the interval's end).

Events (:class:`~replay.log_events.LogEvent`), where the topics exist:
``vehicle_status.failure_detector_status`` bits roll, pitch, ext (flight termination) and
motor as category ``crash`` (PX4's failure detector: the attitude is beyond its limits or
the vehicle is terminated), the other bits and ``vehicle_status.failsafe`` as ``info``;
``estimator_status.filter_fault_flags`` (instance 0) as ``estimator``; each span from the
first sample with the bits set to the first sample where they clear. The log's text
messages (``logged_messages``) as ``info``, and the firmware it was recorded under (its
info fields, :func:`replay.firmware.px4_firmware_text`) as one ``info`` event at the
log's start.

Damage: pyulog stops silently where the file is cut (or where a corrupt header claims more
bytes than the file has), and flags other corruption (``file_corruption``) while
resynchronising over it. rimu watches pyulog's reads to find where it stopped short, and
for flagged corruption finds the offset by reading prefixes of the file; it then refuses
the log unless asked to salvage. Salvaged, a cut file keeps the samples before the cut; a
corrupt one keeps every sample pyulog recovers after resynchronising, and reports each
damaged stretch (the bytes pyulog skipped or re-read, from its reads) and the IMU samples
lost there (from each stream's time steps).

Declared but silent: pyulog keeps only the subscriptions that logged data, so an IMU
instance the log subscribed to (an ``ADD_LOGGED_MSG`` for ``sensor_gyro`` or
``vehicle_imu``) that logged no sample would vanish without a word; the reader finds the
subscriptions in the bytes (:func:`declared_instances`) and warns about each one
(``meta["warnings"]``, printed by ``rimu ingest``).
"""

from __future__ import annotations

import contextlib
import errno
import io
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np

from fdi.errors import ConfigError, FileFormatError
from fdi.units import TIME_UNITS
from replay.firmware import ULOG_INFO_SOURCE, px4_firmware_text
from replay.ingest.stream import Damage, ImuStream, LogRead
from replay.log_events import LogEvent, flag_intervals

__all__ = ["FAILURE_DETECTOR_BITS", "PX4_TOPICS", "TOPICS", "declared_instances",
           "looks_like_ulog", "px4_events", "read_px4"]

TOPICS = ("sensor_gyro", "sensor_accel", "vehicle_imu", "vehicle_status", "estimator_status")
"""ULog topics the reader loads."""
FAILURE_DETECTOR_BITS = {1: "roll", 2: "pitch", 4: "alt", 8: "ext", 16: "arm_esc",
                         32: "battery", 64: "imbalanced_prop", 128: "motor"}
"""``vehicle_status.failure_detector_status`` bits (PX4 ``vehicle_status.msg``)."""
_FD_CRASH = 1 | 2 | 8 | 128
PX4_TOPICS = ("auto", "sensor_gyro", "vehicle_imu")
"""Values of ``topic``: where the rates come from."""
_MAGIC = b"ULog\x01\x12\x35"


def looks_like_ulog(path: str | Path) -> bool:
    """True when the file starts with the ULog magic bytes."""
    try:
        with open(path, "rb") as fh:
            return fh.read(7) == _MAGIC
    except OSError:
        return False


class _TrackedBytes(io.BytesIO):
    """The file's bytes, remembering pyulog's last two reads (start, asked, got)."""

    def __init__(self, data: bytes) -> None:
        super().__init__(data)
        self.reads: list[tuple[int, int, int]] = []

    def read(self, size: int | None = -1) -> bytes:
        start = self.tell()
        out = super().read(size)
        if size is not None and size >= 0:
            self.reads = [*self.reads[-1:], (start, size, len(out))]
        return out

    def seek(self, pos: int, whence: int = 0) -> int:
        """As a file does: a seek before the start is an OSError (BytesIO raises
        ValueError, which pyulog catches and retries forever)."""
        base = {0: 0, 1: self.tell(), 2: len(self.getbuffer())}[whence]
        if base + pos < 0:
            raise OSError(errno.EINVAL, "seek before the start of the file")
        return super().seek(pos, whence)


class _AllReads(_TrackedBytes):
    """The file's bytes, remembering every read pyulog makes (start, bytes got)."""

    def __init__(self, data: bytes) -> None:
        super().__init__(data)
        self.log: list[tuple[int, int]] = []

    def read(self, size: int | None = -1) -> bytes:
        start = self.tell()
        out = super().read(size)
        self.log.append((start, len(out)))
        return out


_CLEAN_RUN = 8
"""Contiguous reads (headers and bodies) after which pyulog is back on the message chain."""


def _damaged_stretches(data: bytes, lo: int) -> list[dict[str, Any]]:
    """Byte ranges pyulog skipped, re-read or dropped while resynchronising.

    ``lo``: the longest prefix pyulog reads without a corruption flag (±16 bytes). The first
    stretch starts at the header of the first message not inside that prefix and ends
    where pyulog's reads run :data:`_CLEAN_RUN` times contiguously again (a dropped
    message with a corrupt id: the message itself). Later breaks in the chain of reads
    (pyulog seeking to resynchronise) are further stretches.
    """
    from pyulog import ULog

    fh = _AllReads(data)
    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            ULog(fh, list(TOPICS))
    except Exception:
        return [{"start": int(lo), "end": len(data), "bytes": len(data) - int(lo),
                 "what": "pyulog could not read past this offset"}]
    log = [(a, n) for a, n in fh.log if n > 0]
    n = len(log)

    def clean_from(j: int) -> bool:
        run = log[j:j + _CLEAN_RUN]
        return len(run) == _CLEAN_RUN and run[0][1] == 3 and all(
            run[i + 1][0] == run[i][0] + run[i][1] for i in range(_CLEAN_RUN - 1))

    out: list[dict[str, Any]] = []
    k = 0
    while k < n - 1:
        a, m = log[k]
        nxt = log[k + 1]
        first = not out and m == 3 and nxt[0] == a + 3 and a + 3 + nxt[1] > lo
        broken = out and nxt[0] != a + m
        if not (first or broken):
            k += 1
            continue
        s0 = a
        j = k + 2 if first else k + 1
        while j < n and not (log[j][0] > s0 and clean_from(j)):
            j += 1
        e = log[j][0] if j < n else len(data)
        if out and s0 <= out[-1]["end"]:
            out[-1]["end"] = max(out[-1]["end"], e)
        else:
            out.append({"start": int(s0), "end": int(e),
                        "what": "corrupt ULog data (pyulog resynchronised after it)"})
        k = j
    for x in out:
        x["bytes"] = x["end"] - x["start"]
    return out


_TYPES = frozenset(b"BFIMPQARDLCSO")
"""ULog message types (pyulog reads these; anything else is no message)."""
_MAX_MSG = 10000
"""Largest message size pyulog accepts as plausible."""


def _next_chain(data: bytes, start: int) -> int | None:
    """The first offset at or after ``start`` where :data:`_CLEAN_RUN` ULog messages of
    known types and plausible sizes follow each other (or run exactly to the end)."""
    n = len(data)
    for q in range(start, n - 3):
        pos, ok = q, 0
        while ok < _CLEAN_RUN and pos + 3 <= n:
            size = data[pos] | (data[pos + 1] << 8)
            if data[pos + 2] not in _TYPES or size == 0 or size > _MAX_MSG \
                    or pos + 3 + size > n:
                break
            pos += 3 + size
            ok += 1
        if ok == _CLEAN_RUN or (ok > 0 and pos == n):
            return q
    return None


def _splice_resync(p: str, data: bytes, hdr: int, topic: str
                   ) -> tuple[list[ImuStream], list[dict[str, Any]]] | None:
    """Skip a corrupt header pyulog stopped at: cut ``[hdr, q)`` (q the next chain of valid
    messages, :func:`_next_chain`) and read again, repeatedly. Returns the streams and the
    stretches cut (original byte offsets), or None when no valid message follows."""
    from pyulog import ULog

    cuts: list[tuple[int, int]] = []
    buf = data
    shift = 0                                   # bytes cut before the current damage
    streams: list[ImuStream] | None = None
    for _ in range(64):
        q = _next_chain(buf, hdr + 3)
        if q is None:
            break
        cuts.append((hdr + shift, q + shift))
        shift += q - hdr
        buf = buf[:hdr] + buf[q:]
        fh = _TrackedBytes(buf)
        sink = io.StringIO()
        try:
            with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
                u = ULog(fh, list(TOPICS))
            streams, _ = _streams(u, topic)
        except Exception:
            return None
        short = _short_read(fh)
        if short is None:
            break
        hdr = short[0]
    if streams is None:
        return None
    return streams, [{"start": a, "end": b, "bytes": b - a,
                      "what": "corrupt ULog message header (its size runs past the next "
                              "messages); skipped to the next chain of valid messages"}
                     for a, b in cuts]


def _lost_in_time(streams: list[ImuStream], t_cut: float) -> dict[str, int]:
    """IMU samples missing from each stream at the damage: the gap in its time steps that
    spans ``t_cut`` (the last sample time before the damage), in sample periods."""
    lost = {}
    for s in streams:
        if s.size < 3:
            lost[s.name] = 0
            continue
        dt = float(np.median(np.diff(s.t)))
        i = int(np.searchsorted(s.t, t_cut, side="right"))
        if 0 < i < s.size and dt > 0:
            lost[s.name] = max(0, round(float(s.t[i] - s.t[i - 1]) / dt) - 1)
        else:
            lost[s.name] = 0
    return lost


def _short_read(fh: _TrackedBytes) -> tuple[int, str] | None:
    """Where pyulog stopped early: a message header or body cut short (truncation, or a
    corrupt header whose size runs past the end)."""
    if not fh.reads:
        return None
    start, asked, got = fh.reads[-1]
    if got >= asked or (got == 0 and asked == 3):
        return None                  # a clean end: the next header read found nothing
    if asked == 3:
        return start, f"file ends inside a message header ({got} of 3 bytes)"
    hdr = fh.reads[0][0] if len(fh.reads) > 1 else start
    return hdr, (f"message at this offset says {asked} bytes, the file has {got} after its "
                 f"header (truncated, or a corrupt header)")


def _load(p: str) -> Any:
    from pyulog import ULog

    try:
        data = Path(p).read_bytes()
    except OSError as exc:
        raise FileFormatError(p, f"cannot read ({exc.strerror})") from None
    fh = _TrackedBytes(data)
    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            return ULog(fh, list(TOPICS)), fh, data
    except Exception as exc:        # pyulog raises ULogException, struct.error, ...
        raise FileFormatError(p, f"not a readable ULog file ({type(exc).__name__}: "
                                 f"{exc})") from None


def _times(d: dict[str, np.ndarray]) -> np.ndarray:
    key = "timestamp_sample" if "timestamp_sample" in d else "timestamp"
    return np.asarray(d[key], float) * TIME_UNITS["us"]


def _xyz(d: dict[str, np.ndarray], a: str = "x", b: str = "y", c: str = "z") -> np.ndarray:
    return np.column_stack([d[a], d[b], d[c]]).astype(float)


def _interp(ts: np.ndarray, tq: np.ndarray, x: np.ndarray) -> np.ndarray:
    out = np.column_stack([np.interp(tq, ts, x[:, k], left=np.nan, right=np.nan)
                           for k in range(x.shape[1])])
    return out


def _streams(u: Any, topic: str) -> tuple[list[ImuStream], dict[str, Any]]:
    by = {(d.name, d.multi_id): d.data for d in u.data_list}
    gyros = sorted(i for (n, i) in by if n == "sensor_gyro") if topic != "vehicle_imu" \
        else []
    meta: dict[str, Any] = {"topics": {f"{n}[{i}]": len(d["timestamp"])
                                       for (n, i), d in sorted(by.items())}}
    streams = []
    if gyros:
        for k, i in enumerate(gyros):
            g = by[("sensor_gyro", i)]
            t = _times(g)
            notes = []
            acc = None
            a = by.get(("sensor_accel", i))
            if a is not None and len(a["timestamp"]) > 1:
                acc = _interp(_times(a), t, _xyz(a))
                notes.append(f"sensor_accel[{i}] interpolated onto sensor_gyro[{i}] times "
                             f"({int(np.isfinite(acc[:, 0]).sum())} of {t.size} samples "
                             f"inside its span)")
            temp = np.asarray(g["temperature"], float) if "temperature" in g else None
            if temp is not None and not np.any(temp != 0):
                temp = None
                notes.append(f"sensor_gyro[{i}].temperature is 0 throughout: not logged")
            dev = np.asarray(g.get("device_id", [0]))
            streams.append(ImuStream(
                name=f"imu{k + 1}", t=t, gyro=_xyz(g), accel=acc, temperature=temp,
                source=f"sensor_gyro[{i}]", device_id=int(dev[0]) if dev.size else None,
                error_count=(np.asarray(g["error_count"], float) if "error_count" in g
                             else None), notes=tuple(notes)))
        return streams, meta
    if topic == "sensor_gyro":
        return streams, meta
    imus = sorted(i for (n, i) in by if n == "vehicle_imu")
    for k, i in enumerate(imus):
        v = by[("vehicle_imu", i)]
        t = _times(v)
        dt = np.asarray(v["delta_angle_dt"], float) * TIME_UNITS["us"]
        dt[dt <= 0] = np.nan
        rate = _xyz(v, "delta_angle[0]", "delta_angle[1]", "delta_angle[2]") / dt[:, None]
        dvdt = np.asarray(v["delta_velocity_dt"], float) * TIME_UNITS["us"]
        dvdt[dvdt <= 0] = np.nan
        acc = _xyz(v, "delta_velocity[0]", "delta_velocity[1]", "delta_velocity[2]") \
            / dvdt[:, None]
        streams.append(ImuStream(
            name=f"imu{k + 1}", t=t, gyro=rate, accel=acc, source=f"vehicle_imu[{i}]",
            device_id=int(v["gyro_device_id"][0]) if len(t) else None,
            notes=("rates are delta_angle / delta_angle_dt (mean over each interval)",)))
    return streams, meta


def _cut_time(p: str, data: bytes) -> tuple[int, float]:
    """(byte offset, last readable sample time) before the first corrupt data.

    Bisects on the longest prefix of the file that pyulog reads without a corruption flag.
    """
    from pyulog import ULog

    lo, hi = 0, len(data)
    sink = io.StringIO()
    while hi - lo > 16:
        mid = (lo + hi) // 2
        try:
            with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
                u = ULog(_TrackedBytes(data[:mid]), list(TOPICS))
            ok = not u.file_corruption
        except Exception:
            ok = False
        if ok:
            lo = mid
        else:
            hi = mid
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            u = ULog(_TrackedBytes(data[:lo]), list(TOPICS))
        last = max((float(_times(d.data)[-1]) for d in u.data_list
                    if len(d.data["timestamp"])), default=-np.inf)
    except Exception:
        last = -np.inf
    return hi, last


_ADD_LOGGED = re.compile(rb"(..)A(.)..(sensor_gyro|vehicle_imu)", re.DOTALL)
"""An ``ADD_LOGGED_MSG`` of an IMU topic: uint16 size, ``'A'``, uint8 multi_id, uint16
msg_id, the topic name (ULog file format)."""


def declared_instances(data: bytes) -> set[tuple[str, int]]:
    """(topic, multi_id) of every IMU subscription in the bytes of a ULog file.

    A match counts only when the message's size field equals 3 + the name's length (the
    whole message is the name), so sample bytes that happen to hold the text do not.
    """
    out = set()
    for m in _ADD_LOGGED.finditer(data):
        (size,) = struct.unpack("<H", m.group(1))
        if size == 3 + len(m.group(3)):
            out.add((m.group(3).decode(), m.group(2)[0]))
    return out


def _silent_warnings(data: bytes, meta: dict[str, Any], streams: list[ImuStream]) -> None:
    """``meta["warnings"]`` for each declared IMU instance of the topic read that logged
    nothing."""
    if not streams:
        return
    topic = streams[0].source.split("[")[0]
    read = {s.source for s in streams}
    empty = sorted(i for t, i in declared_instances(data)
                   if t == topic and f"{t}[{i}]" not in read)
    if empty:
        meta.setdefault("warnings", []).extend(
            f"the log subscribes to {topic}[{i}] but holds no {topic}[{i}] sample (that "
            "IMU logged nothing)" for i in empty)


def read_px4(path: str | Path, *, salvage: bool = False, topic: str = "auto") -> LogRead:
    """Read the IMU instances of a PX4 ULog file.

    Parameters
    ----------
    path : str or Path
    topic : str
        ``"sensor_gyro"`` (with ``sensor_accel``), ``"vehicle_imu"`` (rates and specific
        forces from the delta angles and velocities), or ``"auto"``: ``sensor_gyro`` when
        the log has it, else ``vehicle_imu``.
    salvage : bool
        On a corrupt file, return the samples before the damage (with
        :attr:`LogRead.damage` set) instead of raising.

    Raises
    ------
    FileFormatError
        Unreadable file, no ``sensor_gyro`` or ``vehicle_imu`` data, or corruption
        (without ``salvage``) naming the byte offset.
    """
    if topic not in PX4_TOPICS:
        raise ConfigError(f"PX4 topic {topic!r} is not one of {', '.join(PX4_TOPICS)}")
    p = str(path)
    u, fh, data = _load(p)
    streams, meta = _imu_streams(p, u, topic)
    _silent_warnings(data, meta, streams)
    meta["start_timestamp_us"] = int(u.start_timestamp)
    meta["dropouts"] = len(u.dropouts)
    if u.file_corruption:
        dmg = _corruption(p, data, streams)
    else:
        streams, dmg = _cut(p, fh, data, streams, topic, salvage)
    if dmg is not None and not salvage:
        raise dmg.error()
    if not streams or all(s.size == 0 for s in streams):
        what = "sensor_gyro or vehicle_imu" if topic == "auto" else topic
        raise FileFormatError(p, f"no {what} data in the log")
    events = px4_events(u)
    if dmg is not None and streams:
        last = max((float(s.t[-1]) for s in streams if s.size), default=np.inf)
        events = tuple(e for e in events if e.t_s <= last)
    return LogRead(p, "px4", tuple(streams), dmg, meta, events=events)


def _imu_streams(p: str, u: Any, topic: str) -> tuple[list[ImuStream], dict[str, Any]]:
    """The IMU streams of a parsed log and the reader's meta (``topic`` set)."""
    try:
        streams, meta = _streams(u, topic)
    except KeyError as exc:        # a damaged format definition lost a field
        raise FileFormatError(p, f"an IMU topic lacks the field {exc.args[0]!r} "
                                 "(corrupt format definition?)",
                              field=str(exc.args[0])) from None
    meta["topic"] = streams[0].source.split("[")[0] if streams else None
    return streams, meta


def _corruption(p: str, data: bytes, streams: list[ImuStream]) -> Damage:
    """The damage of a log pyulog flagged as corrupt (it resynchronised over it)."""
    offset, last = _cut_time(p, data)
    stretches = _damaged_stretches(data, max(0, offset - 16))
    lost = _lost_in_time(streams, last)
    for x in stretches:
        x["lost"] = {"imu_samples": lost if x is stretches[0] else {}}
    before = sum(int(np.sum(s.t <= last)) for s in streams)
    return Damage(p, "corrupt ULog data (pyulog skipped bytes it could not read)",
                  offset=offset, samples_before=before, stretches=tuple(stretches),
                  samples_after=sum(s.size for s in streams) - before)


def _cut(p: str, fh: Any, data: bytes, streams: list[ImuStream], topic: str,
         salvage: bool) -> tuple[list[ImuStream], Damage | None]:
    """Where pyulog stopped short (a cut file or a header claiming more bytes than the
    file has): the damage, and with ``salvage`` the streams read on after a spliced
    resync where one is found."""
    short = _short_read(fh)
    if short is None:
        return streams, None
    before = sum(s.size for s in streams)
    fixed = _splice_resync(p, data, short[0], topic) if salvage else None
    if fixed is None:
        return streams, Damage(p, short[1], offset=short[0], samples_before=before)
    last = max((float(s.t[-1]) for s in streams if s.size), default=-np.inf)
    streams, stretches = fixed
    lost = _lost_in_time(streams, last)
    for x in stretches:
        x["lost"] = {"imu_samples": lost if x is stretches[0] else {}}
    return streams, Damage(p, short[1], offset=short[0], samples_before=before,
                           stretches=tuple(stretches),
                           samples_after=sum(s.size for s in streams) - before)


def _bits(code: int) -> str:
    return "+".join(n for b, n in FAILURE_DETECTOR_BITS.items() if code & b) or str(code)


def px4_events(u: Any) -> tuple[LogEvent, ...]:
    """Events of a parsed ULog (module docstring), sorted by time."""
    by = {(d.name, d.multi_id): d.data for d in u.data_list}
    out: list[LogEvent] = []
    vs = by.get(("vehicle_status", 0))
    if vs is not None and len(vs.get("timestamp", ())):
        t = np.asarray(vs["timestamp"], float) * TIME_UNITS["us"]
        if "failure_detector_status" in vs:
            fd = np.asarray(vs["failure_detector_status"])
            src = "vehicle_status.failure_detector_status"
            for t0, t1, c in flag_intervals(t, fd, _FD_CRASH):
                out.append(LogEvent(t0, t1, src, f"failure detector: {_bits(c)}", c, "crash"))
            for t0, t1, c in flag_intervals(t, fd, ~_FD_CRASH):
                out.append(LogEvent(t0, t1, src, f"failure detector: {_bits(c)}", c))
        if "failsafe" in vs:
            for t0, t1, c in flag_intervals(t, np.asarray(vs["failsafe"])):
                out.append(LogEvent(t0, t1, "vehicle_status.failsafe", "failsafe", c))
    es = by.get(("estimator_status", 0))
    if es is not None and "filter_fault_flags" in es and len(es.get("timestamp", ())):
        t = np.asarray(es["timestamp"], float) * TIME_UNITS["us"]
        for t0, t1, c in flag_intervals(t, np.asarray(es["filter_fault_flags"])):
            out.append(LogEvent(t0, t1, "estimator_status.filter_fault_flags",
                                f"estimator filter fault flags {c:#x}", c, "estimator"))
    for m in getattr(u, "logged_messages", ()):
        ts = float(m.timestamp) * TIME_UNITS["us"]
        out.append(LogEvent(ts, ts, "logged_message", str(m.message).strip()))
    fw = px4_firmware_text(getattr(u, "msg_info_dict", None) or {})
    if fw:                          # the firmware the log was recorded under (replay.firmware)
        ts = float(getattr(u, "start_timestamp", 0) or 0) * TIME_UNITS["us"]
        out.append(LogEvent(ts, ts, ULOG_INFO_SOURCE, fw))
    return tuple(sorted(out, key=lambda e: e.t_s))
