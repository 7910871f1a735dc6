"""DataFlash FMT definitions: validation and repair (:func:`fmt_repairs`).

A DataFlash log defines each message type once, in an 89-byte FMT record (type id,
length, name, format characters, column names); it has no checksum, so one flipped byte
in a definition misframes every message of its type. :func:`fmt_repairs` checks every
definition and repairs a damaged field from what is intact, or frames the type without
reading it; :mod:`replay.ingest.ardupilot` applies the repairs before pymavlink indexes the
log (``docs/edges.md``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["EVENT_TYPES", "FMT_ID", "FMT_LEN", "HEAD", "IMU_TYPES", "fmt_check", "fmt_repairs"]

HEAD = b"\xa3\x95"
"""The two sync bytes that start every DataFlash message."""
IMU_TYPES = ("IMU", "IMU2", "IMU3")
"""DataFlash message types that carry IMU samples."""
EVENT_TYPES = ("ERR", "EV", "MSG")
"""DataFlash message types read as events."""
FMT_ID = 0x80
FMT_LEN = 89
_CHAR_SIZE = {"a": 64, "b": 1, "B": 1, "g": 2, "h": 2, "H": 2, "i": 4, "I": 4, "f": 4,
              "n": 4, "N": 16, "Z": 64, "c": 2, "C": 2, "e": 4, "E": 4, "L": 4, "d": 8,
              "M": 1, "q": 8, "Q": 8}
"""Bytes of each DataFlash format character (pymavlink's ``FORMAT_TO_STRUCT``)."""
_FILL = ((64, "Z"), (16, "N"), (8, "Q"), (4, "I"), (2, "H"), (1, "B"))
Fields = tuple[int, int, bytes, bytes, bytes]
_READ_NAMES = (*IMU_TYPES, *EVENT_TYPES)
_IMU_NEEDS = ("GyrX", "GyrY", "GyrZ")


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
    pat = HEAD + bytes([mtype])
    n = hit = 0
    k = data.find(pat)
    while k >= 0 and n < 2000:
        n += 1
        e = k + length
        hit += e >= len(data) or data[e:e + 2] == HEAD
        k = data.find(pat, k + 1)
    return hit, n


def _fmt_records(data: bytes) -> list[int]:
    """Start of every FMT record: the FMT id after the sync bytes, or a record where the
    89-byte run of FMT records expects one with at most one of its header bytes damaged."""
    recs = []
    k = data.find(HEAD + bytes([FMT_ID]))
    while k >= 0:
        recs.append(k)
        k = data.find(HEAD + bytes([FMT_ID]), k + 1)
    known = set(recs)
    for k in list(recs):
        for q in (k - FMT_LEN, k + FMT_LEN):
            if q < 0 or q in known or q + FMT_LEN > len(data):
                continue
            one_sync = data[q + 2] == FMT_ID and (data[q] == HEAD[0]) != (
                data[q + 1] == HEAD[1])
            one_id = data[q:q + 2] == HEAD and data[q + 2] != FMT_ID and not _fmt_problems(
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
            and data[k:k + 3] == HEAD + bytes([FMT_ID])}
    # the headers are counted only when a definition is damaged or has no message (a
    # flipped type id leaves a consistent definition whose id never appears)
    idle = any(data.find(HEAD + bytes([f[0]])) < 0 for f in good.values())
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


def _id_counts(data: bytes) -> np.ndarray:
    """How many message headers (sync bytes) carry each type id, shape (256,); read in
    16 MiB pieces (a log may be larger than memory likes)."""
    out = np.zeros(256, np.int64)
    step = 1 << 24
    for a in range(0, len(data), step):
        b = np.frombuffer(data[a:a + step + 2], np.uint8)
        if b.shape[0] < 3:
            break
        at = np.flatnonzero((b[:-2] == HEAD[0]) & (b[1:-1] == HEAD[1]))
        out += np.bincount(b[at + 2], minlength=256)
    return out


def _record(mtype: int, length: int, name: bytes, fmt: bytes, cols: bytes) -> bytes:
    return (HEAD + bytes([FMT_ID, mtype, length]) + name.ljust(4, b"\0")[:4]
            + fmt.ljust(16, b"\0")[:16] + cols.ljust(64, b"\0")[:64])


def _defined(good: dict[int, Fields]) -> set[int]:
    return {f[0] for f in good.values()} | {FMT_ID}


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


def fmt_check(path: str) -> tuple[dict[int, bytes], list[str]]:
    """:func:`fmt_repairs` of the file at ``path`` (nothing when it cannot be mapped)."""
    import mmap

    try:
        with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as m:
            return fmt_repairs(m)                # type: ignore[arg-type]
    except (OSError, ValueError):
        return {}, []
