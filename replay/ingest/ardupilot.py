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


_FMT_ID = 0x80
_FMT_LEN = 89
_CHAR_SIZE = {"a": 64, "b": 1, "B": 1, "g": 2, "h": 2, "H": 2, "i": 4, "I": 4, "f": 4,
              "n": 4, "N": 16, "Z": 64, "c": 2, "C": 2, "e": 4, "E": 4, "L": 4, "d": 8,
              "M": 1, "q": 8, "Q": 8}
"""Bytes of each DataFlash format character (pymavlink's ``FORMAT_TO_STRUCT``)."""
_FILL = ((64, "Z"), (16, "N"), (8, "Q"), (4, "I"), (2, "H"), (1, "B"))


def _cstr(b: bytes) -> bytes:
    return b.split(b"\0", 1)[0]


def _fmt_fields(data: bytes, k: int) -> tuple[int, int, bytes, bytes, bytes]:
    """(type, length, name, format, columns) of the FMT record at ``k``."""
    return (data[k + 3], data[k + 4], _cstr(data[k + 5:k + 9]), _cstr(data[k + 9:k + 25]),
            _cstr(data[k + 25:k + 89]))


def _fmt_problems(fields: tuple[int, int, bytes, bytes, bytes]) -> list[str]:
    """What is wrong with one FMT definition (empty: consistent)."""
    _, length, name, fmt, cols = fields
    out = []
    if not (name and name.isalnum() and name.upper() == name and name.isascii()):
        out.append("name")
    chars = fmt.decode("latin-1")
    if any(c not in _CHAR_SIZE for c in chars):
        out.append("format")
    elif length != 3 + sum(_CHAR_SIZE[c] for c in chars):
        out.append("length")
    names = cols.decode("latin-1").split(",") if cols else []
    if cols and (len(names) != len(chars) or not all(
            c.replace("_", "").isalnum() and c.isascii() for c in names)):
        out.append("columns")
    return out


def _frames_at(data: bytes, mtype: int, length: int) -> tuple[int, int]:
    """(messages of id ``mtype`` followed by a header ``length`` bytes on, messages of
    that id): how well a length frames a type."""
    pat = _HEAD + bytes([mtype])
    n = hit = 0
    k = data.find(pat)
    while k >= 0 and n < 2000:
        n += 1
        e = k + length
        hit += e >= len(data) or data[e:e + 2] == _HEAD
        k = data.find(pat, k + 1)
    return hit, n


def _fmt_records(data: bytes) -> list[int]:
    """Start of every FMT record: the FMT id after the sync bytes, or a record where the
    89-byte run of FMT records expects one with at most one of its header bytes damaged."""
    recs = []
    k = data.find(_HEAD + bytes([_FMT_ID]))
    while k >= 0:
        recs.append(k)
        k = data.find(_HEAD + bytes([_FMT_ID]), k + 1)
    known = set(recs)
    for k in list(recs):
        for q in (k - _FMT_LEN, k + _FMT_LEN):
            if q < 0 or q in known or q + _FMT_LEN > len(data):
                continue
            one_sync = data[q + 2] == _FMT_ID and (data[q] == _HEAD[0]) != (
                data[q + 1] == _HEAD[1])
            one_id = data[q:q + 2] == _HEAD and data[q + 2] != _FMT_ID and not _fmt_problems(
                _fmt_fields(data, q))
            if one_sync or one_id:
                recs.append(q)
                known.add(q)
    return sorted(recs)


def _placeholder(nbytes: int) -> str:
    """A format of ``nbytes`` bytes (at most 16 characters) to frame a type not read."""
    out = ""
    for size, c in _FILL:
        while nbytes >= size and len(out) < 16:
            out += c
            nbytes -= size
    return out


def fmt_repairs(data: bytes) -> tuple[dict[int, bytes], list[str]]:
    """Validate every FMT definition of a DataFlash log and repair the damaged ones.

    A definition is consistent when its name is upper-case letters and digits, its
    format characters are known, its length is 3 + their sizes, and its columns are
    one identifier per format character. One damaged field is repaired from what is
    intact (DataFlash has no checksum; ArduPilot writes one definition per type, so there
    is rarely a second copy of the same one):

    - damaged sync bytes (the record sits in the run of FMT records);
    - a length that does not frame its messages: the length its format gives;
    - a type id whose messages never appear: the id, without a definition, whose
      messages that length frames;
    - a damaged name: the name rimu reads (``IMU``, ``IMU2``, ``IMU3``, ``ERR``, ``EV``,
      ``MSG``) one byte away from it and not defined elsewhere;
    - the format or the columns (an IMU type whose columns lack the gyro fields
      included): those of a sibling definition with the same layout (``IMU`` and
      ``IMU2``).

    When that is not enough, the type is framed with the length that frames its
    messages and not read; its name is in the warning. Nothing is misframed.

    Returns
    -------
    patches : dict
        Byte offset → the repaired 89-byte FMT record.
    warnings : list of str
        One line per damaged definition: what was wrong and what was done.
    """
    recs = _fmt_records(data)
    fields = {k: _fmt_fields(data, k) for k in recs}
    good = {k: f for k, f in fields.items() if not _fmt_problems(f)
            and data[k:k + 3] == _HEAD + bytes([_FMT_ID])}
    # the headers are counted only when a definition is damaged or has no message (a
    # flipped type id leaves a consistent definition whose id never appears)
    idle = any(data.find(_HEAD + bytes([f[0]])) < 0 for f in good.values())
    seen = _id_counts(data) if idle or len(good) < len(recs) else np.zeros(256, np.int64)
    patches: dict[int, bytes] = {}
    warnings: list[str] = []

    def fix(k: int, rec: Fields, what: str) -> None:
        patches[k] = _record(*rec)
        good[k] = rec
        warnings.append(f"damaged FMT definition at byte {k} ({what})")

    for k in recs:
        if k not in good:
            fix(k, *_repair_one(data, fields[k], good))
    for k, t in _retargets(data, good, seen).items():
        f = good[k]
        fix(k, (t, *f[1:]), f"type id {f[0]} has no message: {f[2].decode()} is type {t}")
    for k, f in list(good.items()):
        got = _imu_columns(f, good)
        if got is not None:
            fix(k, *got)
    return patches, warnings


Fields = tuple[int, int, bytes, bytes, bytes]
_READ_NAMES = (*IMU_TYPES, *EVENT_TYPES)
_IMU_NEEDS = ("GyrX", "GyrY", "GyrZ")


def _id_counts(data: bytes) -> np.ndarray:
    """How many message headers (sync bytes) carry each type id, shape (256,); read in
    16 MiB pieces (a log may be larger than memory likes)."""
    out = np.zeros(256, np.int64)
    step = 1 << 24
    for a in range(0, len(data), step):
        b = np.frombuffer(data[a:a + step + 2], np.uint8)
        if b.shape[0] < 3:
            break
        at = np.flatnonzero((b[:-2] == _HEAD[0]) & (b[1:-1] == _HEAD[1]))
        out += np.bincount(b[at + 2], minlength=256)
    return out


def _record(mtype: int, length: int, name: bytes, fmt: bytes, cols: bytes) -> bytes:
    return (_HEAD + bytes([_FMT_ID, mtype, length]) + name.ljust(4, b"\0")[:4]
            + fmt.ljust(16, b"\0")[:16] + cols.ljust(64, b"\0")[:64])


def _defined(good: dict[int, Fields]) -> set[int]:
    return {f[0] for f in good.values()} | {_FMT_ID}


def _retargets(data: bytes, good: dict[int, Fields], seen: np.ndarray) -> dict[int, int]:
    """{record: type id} for consistent definitions whose type id byte is damaged: an id
    with three or more messages but no definition, whose messages the length of exactly
    one definition without any message frames."""
    defined = _defined(good)
    orphans = [int(t) for t in np.flatnonzero(seen >= 3) if int(t) not in defined]
    idle = {k: f for k, f in good.items() if not seen[f[0]] and f[1] >= 3}
    out: dict[int, int] = {}
    for t in orphans[:16]:
        claims = []
        for k, f in idle.items():
            hit, n = _frames_at(data, t, f[1])
            if n >= 3 and hit >= 0.9 * n:
                claims.append(k)
        if len(claims) > 1:             # e.g. IMU3 declared, never logged: same length
            claims = [k for k in claims if _brackets(good, k, t)]
        if len(claims) == 1 and claims[0] not in out:
            out[claims[0]] = t
    return out


def _brackets(good: dict[int, Fields], k: int, t: int) -> bool:
    """Whether the type ids of the records before and after record ``k`` (in file order)
    bracket ``t`` (writers put their FMT records in type id order)."""
    keys = sorted(good)
    i = keys.index(k)
    lo = good[keys[i - 1]][0] if i > 0 else -1
    hi = good[keys[i + 1]][0] if i + 1 < len(keys) else 256
    return lo < t < hi


def _sibling(good: dict[int, Fields], f: Fields, *, length: int | None = None,
             fmt: bytes | None = None, cols: bytes | None = None) -> Fields | None:
    """A consistent definition of another type with the given length and format or
    columns (``IMU`` and ``IMU2`` share theirs)."""
    for g in good.values():
        if g[0] != f[0] and (length is None or g[1] == length) and (
                (fmt is not None and g[3] == fmt) or (cols is not None and g[4] == cols)):
            return g
    return None


def _imu_columns(f: Fields, good: dict[int, Fields]) -> tuple[Fields, str] | None:
    """An IMU type whose columns lack the gyro or time fields: a sibling's columns
    (same length and format) when they differ in one name."""
    name = f[2].decode("latin-1")
    cols = f[4].decode("latin-1").split(",")
    if name not in IMU_TYPES or (all(c in cols for c in _IMU_NEEDS) and (
            "TimeUS" in cols or "TimeMS" in cols)):
        return None
    g = _sibling(good, f, length=f[1], fmt=f[3])
    if g is None:
        return None
    other = g[4].decode("latin-1").split(",")
    if len(other) != len(cols) or sum(a != b for a, b in zip(cols, other, strict=True)) != 1:
        return None
    return (*f[:4], g[4]), f"columns: {name} takes the columns of {g[2].decode()}"


def _name_fix(name: bytes, good: dict[int, Fields]) -> bytes | None:
    """The name rimu reads one byte away from a damaged ``name``, when not defined."""
    taken = {g[2] for g in good.values()}
    raw = name.ljust(4, b"\0")
    hits = [n.encode() for n in _READ_NAMES if n.encode() not in taken and sum(
        a != b for a, b in zip(raw, n.encode().ljust(4, b"\0"), strict=True)) == 1]
    return hits[0] if len(hits) == 1 else None


def _repair_one(data: bytes, f: Fields, good: dict[int, Fields]) -> tuple[Fields, str]:
    """The repaired fields of a damaged FMT record and what was done (see
    :func:`fmt_repairs`)."""
    mtype, length, name, fmt, cols = f
    probs = _fmt_problems(f)
    what = ", ".join(probs) if probs else "sync bytes"
    if not probs:
        return f, what
    chars = fmt.decode("latin-1")
    calc = 3 + sum(_CHAR_SIZE[c] for c in chars) if "format" not in probs else None
    hit_decl, n = _frames_at(data, mtype, length)
    frames_decl = n > 0 and hit_decl >= 0.9 * n
    if probs == ["length"] and calc is not None:
        hit_calc, _ = _frames_at(data, mtype, calc)
        if hit_calc >= hit_decl:
            return (mtype, calc, name, fmt, cols), f"{what}: length {length} -> {calc}"
        g = _sibling(good, f, length=length, cols=cols)
        if g is not None:                # a format character of a sibling's size damaged
            return (mtype, length, name, g[3], cols), f"{what}: format of {g[2].decode()}"
    if probs == ["format"]:
        g = _sibling(good, f, length=length, cols=cols)
        if g is not None:
            return (mtype, length, name, g[3], cols), f"{what}: format of {g[2].decode()}"
    if probs == ["columns"]:
        g = _sibling(good, f, length=length, fmt=fmt)
        if g is not None:
            return (mtype, length, name, fmt, g[4]), f"{what}: columns of {g[2].decode()}"
    if probs == ["name"]:
        fixed = _name_fix(name, good)
        if fixed is not None:
            return (mtype, length, fixed, fmt, cols), f"{what}: {fixed.decode()}"
    # not readable: frame the type with the length that frames its messages, do not read it
    n_bytes = length if frames_decl or calc is None else calc
    n_bytes = max(n_bytes, 3)
    label = name.decode("latin-1") if "name" not in probs else f"type {mtype}"
    return ((mtype, n_bytes, f"X{mtype:03d}".encode(), _placeholder(n_bytes - 3).encode(),
             b""), f"{what}: {label} messages framed ({n_bytes} bytes) but not read")


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
            self.HEAD1, self.HEAD2 = _HEAD
            self.unpackers = {}
            self.formats = {_FMT_ID: DFReader.DFFormat(_FMT_ID, "FMT", _FMT_LEN, "BBnNZ",
                                                       "Type,Length,Name,Format,Columns")}
            self._zero_time_base = False
            self.prev_type = None
            self.init_arrays()
            self.init_clock()
            self.prev_type = None
            self._rewind(keep_messages=True)

    return Patched()


def _fmt_check(path: str) -> tuple[dict[int, bytes], list[str]]:
    """:func:`fmt_repairs` of the file at ``path`` (nothing when it cannot be mapped)."""
    import mmap

    try:
        with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as m:
            return fmt_repairs(m)                # type: ignore[arg-type]
    except (OSError, ValueError):
        return {}, []


def _open(path: str) -> Any:
    from pymavlink import DFReader

    patches, warnings = _fmt_check(path)
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


def _scan(r: Any, data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Starts, lengths and type ids of the messages of ``data``, found by walking the
    framing and resynchronising after damage (pymavlink's indexer stops at the first
    unknown message id: one flipped id byte hid the rest of the log).

    A message is the sync bytes and a type with a FMT definition, its length that type's.
    When no message header follows it, the walk resumes at the next byte after its start
    where a header is itself followed by a header or the end of the file (a message whose
    id byte was flipped to a longer type does not swallow the messages after it; the
    message before the break is distrusted by :func:`_stretches`). A message that runs past
    the end of the file is the last one (the truncation is reported there).
    """
    lens = {int(k): int(f.len) for k, f in r.formats.items()}
    n = len(data)
    h0, h1 = _HEAD

    def header(q: int) -> int:
        """The length of the message whose header starts at q, or 0."""
        if q + 3 <= n and data[q] == h0 and data[q + 1] == h1:
            return lens.get(data[q + 2], 0)
        return 0

    def good(q: int) -> int:
        """The length of the message at q when it is followed by a header or the end."""
        ln = header(q)
        if ln < 3:
            return 0
        e = q + ln
        return ln if e >= n or header(e) else 0

    starts: list[int] = []
    out_len: list[int] = []
    types: list[int] = []
    pos = 0
    while pos + 3 <= n:
        ln = header(pos)
        if ln >= 3:
            starts.append(pos)
            out_len.append(ln)
            types.append(data[pos + 2])
            if pos + ln >= n or header(pos + ln):
                pos += ln
                continue
        q = data.find(_HEAD, pos + 1)
        while q != -1 and not good(q):
            q = data.find(_HEAD, q + 1)
        if q == -1:
            break
        pos = q
    return (np.asarray(starts, np.int64), np.asarray(out_len, np.int64),
            np.asarray(types, np.int64))


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


def _stretches(r: Any, data: bytes) -> tuple[list[dict[str, Any]], dict[int, int]]:
    """Every damaged stretch of the log and the starts of the messages to trust.

    pymavlink resynchronises on the next header of a known format; a message is trusted
    when it starts where the previous trusted one ends. Where framing breaks, the bytes up
    to the next message are a damaged stretch; the message before the break is distrusted
    too (DataFlash has no checksum: its body may hold the first corrupt bytes), unless the
    break is exactly one message whose sync bytes alone are damaged.
    """
    o, ln, ty = _scan(r, data)
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
    return out, {int(o[i]): int(ty[i]) for i in keep}


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
    damage = _first_damage(r)
    counts = {t: int(r.counts[r.name_to_id[t]]) for t in (*IMU_TYPES, *EVENT_TYPES)
              if t in r.name_to_id}
    stretches: list[dict[str, Any]] = []
    trusted: dict[int, int] = {}
    if damage is not None:
        stretches, trusted, counts = _trusted_counts(r, counts)
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
    dmg = _damage(p, damage, stretches, streams, cols)
    if not salvage:
        raise dmg.error()
    return LogRead(p, "ardupilot", tuple(streams), dmg, meta,
                   events=ardupilot_events(raw_events))


def _trusted_counts(r: Any, counts: dict[str, int]
                    ) -> tuple[list[dict[str, Any]], dict[int, int], dict[str, int]]:
    """The damaged stretches, the trusted messages ({start: type id}) and the count of
    each type among them. pymavlink's index stops at the first unknown message id: count
    from rimu's own walk of the framing (:func:`_scan`), which resynchronises after the
    damage."""
    data = bytes(r.data_map[:int(r.data_len)])          # with repaired FMT records
    stretches, trusted = _stretches(r, data)
    found = np.bincount(np.fromiter(trusted.values(), np.int64, len(trusted)),
                        minlength=256)
    return stretches, trusted, {t: int(found[r.name_to_id[t]]) for t in counts}


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


def _damage(p: str, damage: tuple[int, str], stretches: list[dict[str, Any]],
            streams: list[ImuStream], cols: dict[tuple[str, int], dict[str, list[float]]]
            ) -> Damage:
    """The log's damage record: the first stretch (or pymavlink's first damage), the IMU
    samples lost in each stretch, and the samples before and after the first."""
    offsets = {s.name: np.asarray(cols[key]["off"], np.int64) for s, key in zip(
        streams, sorted(cols, key=lambda ti: (IMU_TYPES.index(ti[0]), ti[1])), strict=True)}
    _lost_samples(stretches, streams, offsets)
    first = stretches[0] if stretches else {"start": damage[0], "what": damage[1]}
    before = sum(int(np.sum(o < first["start"])) for o in offsets.values())
    return Damage(p, first["what"], offset=int(first["start"]), samples_before=before,
                  stretches=tuple(stretches),
                  samples_after=sum(s.size for s in streams) - before)


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
