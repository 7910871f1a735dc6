"""A BLF reader that survives damage: one damaged object costs about one frame.

python-can's :class:`can.BLFReader` stops at the first damaged object: a flipped byte in
one compressed container loses the rest of the file. :class:`ResyncBLFReader` keeps
python-can's parsing of CAN objects and adds, around it:

- **the file**: a file with neither the ``LOGG`` file signature nor any ``LOBJ`` object is
  "not a BLF file" (:class:`~fdi.errors.FileFormatError`), not an empty log; a damaged file
  header is recorded and reading starts at the first object;
- **containers** (``LOBJ`` type 10): a container header is trusted only when its size
  lands on the next ``LOBJ`` (or the end of the file). A damaged header (signature, type,
  size, compression method) is recorded and the container's body is taken up to the next
  valid container header, so the body is still read;
- **inflation**: a zlib stream is inflated with :func:`zlib.decompressobj` in small steps,
  so every byte produced before a deflate error is kept; a wrong Adler-32 alone drops
  nothing (the objects are validated one by one instead);
- **objects**: the uncompressed stream (objects run across containers) is walked object by
  object; each header is validated (signature, header size for its version, timestamp unit,
  size bounds for its type, channel, DLC and identifier bits of CAN frames, and that its
  size lands on the next ``LOBJ``). A damaged object is skipped and the walk resynchronises
  at the next valid object header (confirmed by the one after it): one damaged object costs
  one frame, its bytes are counted.

A flip inside *compressed* bytes puts deflate out of step: the bytes after it are decoded
with a wrong bit alignment or wrong back-references, and python-can's writer puts 128 KiB
of objects (about 2700 frames) in one deflate stream. So a damaged stream is first
**repaired by search** (:mod:`replay.blf_repair`): the first invalid object (or, when
every object is valid but the Adler-32 is wrong, the first time stamp that goes back,
or the first CAN frame whose key or pair of successive keys is rare in the file) locates
the damaged byte within a few hundred compressed bytes, the 255 other values of each
candidate byte are tried, and a repair is accepted only when the whole stream then
inflates with the right Adler-32 and declared size. When no single byte repairs it (within
a bounded budget), the frames decoded before the damage are kept and the stream is
resynchronised where valid objects come out again. ``docs/edges.md`` ("Damaged logs")
gives the measured loss.

Each damage is recorded in :attr:`ResyncBLFReader.damage` as ``{"where": "byte N", "why":
..., "kind": "resync" | "truncated" | "repaired", "skipped_bytes": k}`` (the first 50;
a ``repaired`` record names the container, the byte and its damaged and repaired values:
every frame is read, but the file was damaged, so ``--strict`` refuses it;
:attr:`ResyncBLFReader.n_damage` counts all); the frames lost with it show in the frame
counters (rolling and sample counter gaps).
"""

from __future__ import annotations

import struct
import zlib
from collections import Counter, deque
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path
from typing import Any, cast

import can
from can.io.blf import (
    CAN_ERROR_EXT,
    CAN_ERROR_EXT_STRUCT,
    CAN_FD_MESSAGE,
    CAN_FD_MESSAGE_64,
    CAN_FD_MSG_64_STRUCT,
    CAN_FD_MSG_STRUCT,
    CAN_MESSAGE,
    CAN_MESSAGE2,
    CAN_MSG_EXT,
    CAN_MSG_STRUCT,
    FILE_HEADER_SIZE,
    FILE_HEADER_STRUCT,
    GLOBAL_MARKER,
    GLOBAL_MARKER_STRUCT,
    LOG_CONTAINER,
    LOG_CONTAINER_STRUCT,
    NO_COMPRESSION,
    OBJ_HEADER_BASE_STRUCT,
    ZLIB_DEFLATE,
    systemtime_to_timestamp,
)
from can.io.generic import BinaryIOMessageReader

from fdi.errors import FileFormatError
from replay.blf_repair import (
    INVALID,
    REPAIR_AFTER,
    REPAIR_BUDGET,
    REPAIR_CHECK,
    REPAIR_FILE_BUDGET,
    UNKNOWN,
    NextObject,
    repair_stream,
    trailer_repair,
    walk,
)

__all__ = ["MAX_CONTAINER_BYTES", "MAX_OBJECT_BYTES", "ResyncBLFReader"]

MAX_CONTAINER_BYTES = 64 << 20
"""Largest plausible log container (writers use about 128 kB)."""
MAX_OBJECT_BYTES = 1 << 20
"""Largest plausible object inside a container (CAN objects are 48–120 bytes; text and
other objects may be longer)."""
MAX_DAMAGE_RECORDS = 50
"""Damage records kept in :attr:`ResyncBLFReader.damage` (all are counted)."""

_HDR = OBJ_HEADER_BASE_STRUCT.size
_CHDR = _HDR + LOG_CONTAINER_STRUCT.size
_SCAN = 1 << 16
_INFLATE_STEP = 2048
_HEADER_SIZE = {1: 32, 2: 40}
"""Object header size (base + v1 or v2 part) by header version."""
_MIN_BODY = {
    CAN_MESSAGE: CAN_MSG_STRUCT.size,
    CAN_MESSAGE2: CAN_MSG_STRUCT.size,
    CAN_ERROR_EXT: CAN_ERROR_EXT_STRUCT.size,
    CAN_FD_MESSAGE: CAN_FD_MSG_STRUCT.size,
    CAN_FD_MESSAGE_64: CAN_FD_MSG_64_STRUCT.size,
    GLOBAL_MARKER: GLOBAL_MARKER_STRUCT.size,
}
"""Least body size (bytes after the object header) of the object types python-can reads."""
_MAX_BODY = {
    CAN_MESSAGE: CAN_MSG_STRUCT.size,
    CAN_MESSAGE2: CAN_MSG_STRUCT.size + 8,
    CAN_ERROR_EXT: CAN_ERROR_EXT_STRUCT.size + 8,
    CAN_FD_MESSAGE: CAN_FD_MSG_STRUCT.size + 8,
}
"""Largest body size of the fixed-size CAN object types (a little slack for writers)."""
_MAX_CHANNEL = 256
_MAX_TYPE = 0xFF
"""Largest object type (Vector's types are below 200)."""
_INCOMPLETE = -1


def _object_size(data: bytes, pos: int) -> int | None:
    """Size of a plausible object whose header starts at ``pos`` (``LOBJ`` there).

    Returns the object size, :data:`_INCOMPLETE` when the header looks valid but the object
    runs past the end of ``data``, or None when the header (or a CAN frame's fields) is
    not a valid object's.
    """
    if len(data) - pos < _HDR:
        return _INCOMPLETE
    sig, hsize, version, size, kind = OBJ_HEADER_BASE_STRUCT.unpack_from(data, pos)
    if (
        sig != b"LOBJ"
        or _HEADER_SIZE.get(version) != hsize
        or kind == LOG_CONTAINER
        or (kind > _MAX_TYPE)
    ):
        return None
    body = size - hsize
    if not _MIN_BODY.get(kind, 0) <= body <= _MAX_BODY.get(kind, MAX_OBJECT_BYTES):
        return None
    if len(data) - pos < hsize + min(body, 16):
        return _INCOMPLETE
    if struct.unpack_from("<L", data, pos + _HDR)[0] not in (1, 2):  # timestamp unit
        return None
    if kind in (CAN_MESSAGE, CAN_MESSAGE2):
        channel, _, dlc, can_id, _ = CAN_MSG_STRUCT.unpack_from(data, pos + hsize)
        if (
            channel > _MAX_CHANNEL
            or dlc > 15
            or can_id & 0x60000000
            or (not can_id & CAN_MSG_EXT and can_id > 0x7FF)
        ):
            return None
    return size if pos + size <= len(data) else _INCOMPLETE


def _can_like(data: bytes, pos: int) -> bool:
    """Whether the valid object at ``pos`` has a type python-can does not read but the
    exact layout of a CAN frame object (a flipped type byte, most likely)."""
    _, hsize, _, size, kind = OBJ_HEADER_BASE_STRUCT.unpack_from(data, pos)
    if kind in _MIN_BODY or size - hsize != CAN_MSG_STRUCT.size:
        return False
    channel, _, dlc, can_id, _ = CAN_MSG_STRUCT.unpack_from(data, pos + hsize)
    return (
        channel <= _MAX_CHANNEL
        and dlc <= 8
        and not can_id & 0x60000000
        and (bool(can_id & CAN_MSG_EXT) or can_id <= 0x7FF)
    )


def _lands(data: bytes, end: int) -> bool:
    """Whether an object ending at ``end`` is followed by the next ``LOBJ`` (after up to 7
    padding bytes) or by the end of ``data``."""
    if end + 8 > len(data) and b"LOBJ" not in data[end:]:
        return not data[end:].strip(b"\x00") or len(data) - end < 4
    return data.find(b"LOBJ", end, end + 12) >= 0


def _next_object(data: bytes, pos: int) -> int:
    """Where the object after the valid object at ``pos`` starts (after up to 8 padding
    bytes); :data:`~replay.blf_repair.INVALID` when the object is invalid or does not land
    on the next ``LOBJ``; :data:`~replay.blf_repair.UNKNOWN` when ``data`` ends before
    this can be told (the walk of :mod:`replay.blf_repair`)."""
    if not b"LOBJ".startswith(data[pos : pos + 4]):
        return INVALID
    size = _object_size(data, pos)
    if size is None:
        return INVALID
    end = pos + size
    if size == _INCOMPLETE or end + 12 > len(data):
        return UNKNOWN
    k = data.find(b"LOBJ", end, end + 12)
    return k if k >= 0 else INVALID


_TIME_AFTER = 512
"""Output bytes after an object whose successor goes back in time where the damaged byte
is looked for (the successor's time stamp may be the damaged one)."""


_TIME_CHECK = 16384
"""Output bytes past the first time stamp that goes back that a candidate must inflate to
valid objects in time order: a damage that copies wrong time stamps into many objects
(measured: 365 of 416 altered objects) leaves many of them, and a candidate that only
puts the first one in order is rejected at the next."""


def _next_in_time(data: bytes, pos: int) -> int:
    """:func:`_next_object`, and :data:`~replay.blf_repair.INVALID` also when the next
    object's time stamp (in the same unit) is earlier than this one's: the walk that
    locates a damaged value when every object is valid (only a repair search uses it; a
    log whose objects are out of time order just finds no repair)."""
    nxt = _next_object(data, pos)
    if nxt < 0:
        return nxt
    if len(data) < nxt + 32:
        return UNKNOWN
    unit0, t0 = struct.unpack_from("<L4xQ", data, pos + 16)
    unit1, t1 = struct.unpack_from("<L4xQ", data, nxt + 16)
    return INVALID if unit0 == unit1 and t1 < t0 else nxt


_KEY_RARE = 16
"""A CAN frame's key is rare when it was seen at least this many times less often than
the typical key of the reference frames (the median count of a key)."""
_KEY_TYPICAL = 4
"""Least median count of a key for the reference to tell a rare key (a short reference
tells nothing)."""
_KEY_CONTAINERS = 2
"""Intact containers of the file whose keys are the reference (the last ones read
before the damaged one, else the next ones after it)."""
_KEY_LOOKAHEAD = 4
"""Containers after the damaged one read, at most, to find intact ones."""
_KEY_UNIT = 128
"""Uncompressed bytes of a reference container (inflated and walked for its keys) or of
the damaged one (walked) per work unit of the repair budget (about the search's cost)."""
_KEY_AFTER = 128
"""Output bytes after the start of the first frame with a rare key where the damaged byte
is looked for (its key fields end 44 bytes after it)."""
_KEY_CHECK = 4096
"""Output bytes past the first frame with a rare key that a candidate must inflate to
valid objects whose keys are not rare (a damage copied by back-references alters the keys
of many frames after it)."""


Key = tuple[int, int, int, int]
"""A CAN frame's (channel, identifier, DLC, flags)."""


def _frame_key(data: bytes, pos: int) -> Key | None:
    """(channel, identifier, DLC, flags) of the classic CAN frame object at ``pos``
    (a valid object), or None for another object."""
    _, hsize, _, _, kind = OBJ_HEADER_BASE_STRUCT.unpack_from(data, pos)
    if kind not in (CAN_MESSAGE, CAN_MESSAGE2):
        return None
    channel, flags, dlc, can_id, _ = CAN_MSG_STRUCT.unpack_from(data, pos + hsize)
    return channel, can_id, dlc, flags


def _frame_keys(data: bytes, first: int) -> list[tuple[int, Key]]:
    """(offset, key) of the CAN frame objects among the valid objects of ``data`` from
    the object at ``first`` (the last one too when it is whole)."""
    out = []
    pos = first
    while True:
        nxt = _next_object(data, pos)
        if nxt == INVALID:
            return out
        size = _object_size(data, pos)
        if size is not None and size > 0:
            key = _frame_key(data, pos)
            if key is not None:
                out.append((pos, key))
        if nxt < 0:
            return out
        pos = nxt


def _typical(counts: Counter) -> int:
    """The median count of the keys (or pairs of keys) of ``counts``."""
    values = sorted(counts.values())
    return values[len(values) // 2] if values else 0


def _rare_key(
    frames: list[tuple[int, Key]], keys: Counter, pairs: Counter
) -> tuple[set[Key], set[tuple[Key, Key]]] | None:
    """The keys and the pairs of successive keys that are not rare, when a frame of
    ``frames`` has a rare key or follows its predecessor's key in a rare pair; else None.

    A key (a pair) is rare when it was seen, in the reference counts ``keys`` (``pairs``)
    and the frames before it, :data:`_KEY_RARE` times less often than the median key
    (pair), and that median is at least :data:`_KEY_TYPICAL`. Every key and pair of the
    frames before the first rare one is kept as not rare.
    """
    keys, pairs = Counter(keys), Counter(pairs)
    tk = tp = 0
    prev: Key | None = None
    for i, (_, key) in enumerate(frames):
        pair = (prev, key) if prev is not None else None
        if i % 32 == 0 or keys[key] == 0 or (pair is not None and pairs[pair] == 0):
            tk, tp = _typical(keys), _typical(pairs)
        rare = tk >= _KEY_TYPICAL and _KEY_RARE * keys[key] < tk
        if pair is not None and tp >= _KEY_TYPICAL and _KEY_RARE * pairs[pair] < tp:
            rare = True
        if rare:
            before = frames[:i]
            ok_keys = {k for k, c in keys.items() if _KEY_RARE * c >= tk}
            ok_keys.update(k for _, k in before)
            ok_pairs = {q for q, c in pairs.items() if _KEY_RARE * c >= tp}
            ok_pairs.update((a[1], b[1]) for a, b in pairwise(before))
            return ok_keys, ok_pairs
        keys[key] += 1
        if pair is not None:
            pairs[pair] += 1
        prev = key
    return None


def _known_keys(keys: set[Key], pairs: set[tuple[Key, Key]]) -> NextObject:
    """:func:`_next_object`, and :data:`~replay.blf_repair.INVALID` also when the object
    is a CAN frame whose key is not in ``keys``, or whose key and the next frame's are not
    a pair of ``pairs``: the walk that locates a damage that changed a frame's channel,
    identifier, DLC or flags, and checks a candidate."""

    def next_known(data: bytes, pos: int) -> int:
        nxt = _next_object(data, pos)
        if nxt < 0:
            return nxt
        key = _frame_key(data, pos)
        if key is None:
            return nxt
        if key not in keys:
            return INVALID
        if len(data) < nxt + _HDR + 40:  # the next frame's key (a version 2 header)
            return UNKNOWN
        if _object_size(data, nxt) is None:
            return nxt
        after = _frame_key(data, nxt)
        return INVALID if after is not None and (key, after) not in pairs else nxt

    return next_known


def _ends_early(payload: bytes) -> bool:
    """Whether the zlib stream in ``payload`` ends before it (bytes other than padding
    follow its Adler-32)."""
    d = zlib.decompressobj()
    try:
        d.decompress(payload)
    except zlib.error:
        return False
    return d.eof and bool(d.unused_data.strip(b"\x00"))


def _inflate(payload: bytes) -> tuple[bytes, str | None, bool]:
    """Inflate a zlib stream, keeping every byte produced before an error.

    Returns
    -------
    data : bytes
        The bytes inflated (all of them up to the error).
    error : str or None
        What went wrong (None: a clean stream).
    gap : bool
        True when the output stops before the end of the stream (a deflate error or a cut
        stream); False when only the Adler-32 check failed (all bytes were produced).
    """
    d = zlib.decompressobj()
    out: list[bytes] = []
    for i in range(0, len(payload), _INFLATE_STEP):
        chunk = payload[i : i + _INFLATE_STEP]
        saved = d.copy()
        try:
            out.append(d.decompress(chunk))
        except zlib.error:
            d = saved
            for j in range(len(chunk)):
                try:
                    out.append(d.decompress(chunk[j : j + 1]))
                except zlib.error as exc:
                    why = str(exc).partition(": ")[2] or str(exc)
                    check = "incorrect data check" in why
                    return b"".join(out), f"{why} at compressed byte {i + j}", not check
        if d.eof:
            break
    if not d.eof:
        out.append(d.flush())
        return b"".join(out), "the compressed stream ends early", True
    return b"".join(out), None, False


class ResyncBLFReader(can.BLFReader):
    """python-can's BLF reader with resynchronisation (see the module docstring).

    Parameters
    ----------
    path : str or Path

    Raises
    ------
    FileFormatError
        The file is not a BLF file (no ``LOGG`` header, no ``LOBJ`` object).
    """

    def __init__(self, path: str | Path, **kwargs: Any) -> None:
        self.path = str(path)
        BinaryIOMessageReader.__init__(self, path, mode="rb")
        self.damage: list[dict[str, Any]] = []
        self.n_damage = 0
        self.skipped_bytes = 0
        self._sync = False
        self._cpos = 0
        self._repair_left = REPAIR_FILE_BUDGET
        self._repair_note = ""
        self._clean: deque[int] = deque(maxlen=_KEY_CONTAINERS)
        self._after = 0
        self._tail = b""
        self._tail_at = 0
        self._pos = 0
        self.file_size = self.uncompressed_size = self.object_count = 0
        self.start_timestamp = self.stop_timestamp = 0.0
        f = self.file
        f.seek(0, 2)
        self._size = f.tell()
        f.seek(0)
        head = f.read(FILE_HEADER_STRUCT.size)
        whole = len(head) == FILE_HEADER_STRUCT.size
        if whole:
            h = FILE_HEADER_STRUCT.unpack(head)
            self.start_timestamp = systemtime_to_timestamp(cast("Any", h[14:22]))
            self.stop_timestamp = systemtime_to_timestamp(cast("Any", h[22:30]))
        if whole and head[:4] == b"LOGG":
            self.file_size, self.uncompressed_size, self.object_count = h[10], h[11], h[12]
            self._start = self._first_container(int(h[1]))
            return
        k = self._scan(0)
        if k is None:
            if head[:4] == b"LOGG":
                self._record(0, "truncated file header, no object", len(head))
                self._start = self._size
                return
            self.file.close()
            raise FileFormatError(
                self.path, "not a BLF file (no 'LOGG' header and no 'LOBJ' object)"
            )
        self._record(0, "damaged file header; reading from the first object", k)
        self._start = k

    def _first_container(self, hsize: int) -> int:
        """Where the first container starts: after the declared header size when a
        container header is there, else after the standard 144-byte header, else at the
        first container header found (a damaged header size is recorded)."""
        f = self.file
        for start in (hsize, FILE_HEADER_SIZE):
            if not FILE_HEADER_STRUCT.size <= start <= (1 << 20) or start >= self._size:
                continue
            f.seek(start)
            if self._container_score(f.read(_CHDR))[0] >= 5:
                if start != hsize:
                    self._record(
                        4, f"damaged file header (header size {hsize}); read from byte {start}", 0
                    )
                return start
        k = self._scan(FILE_HEADER_STRUCT.size, container=True)
        if k is None:
            k = self._scan(FILE_HEADER_STRUCT.size)
        start = self._size if k is None else k
        self._record(
            4,
            f"damaged file header (header size {hsize}); read from the first object (byte {start})",
            max(0, start - FILE_HEADER_SIZE),
        )
        return start

    # ----------------------------------------------------------------- bookkeeping
    def _record(self, where: int, why: str, skipped: int, kind: str = "resync") -> None:
        self.skipped_bytes += skipped
        self.n_damage += 1
        if len(self.damage) < MAX_DAMAGE_RECORDS:
            self.damage.append(
                {"where": f"byte {where}", "why": why, "kind": kind, "skipped_bytes": int(skipped)}
            )

    def _scan(self, start: int, container: bool = False) -> int | None:
        """Position of the next ``LOBJ`` at or after ``start`` (``container``: the next
        plausible container header); None at the end of the file."""
        f = self.file
        pos = start
        while True:
            f.seek(pos)
            buf = f.read(_SCAN + _CHDR)
            if len(buf) < 4:
                return None
            k = buf.find(b"LOBJ")
            while k >= 0:
                if not container or self._container_header(buf[k : k + _CHDR]) is not None:
                    return pos + k
                k = buf.find(b"LOBJ", k + 1)
            if len(buf) < _SCAN + _CHDR:
                return None
            pos += _SCAN

    @staticmethod
    def _container_score(head: bytes) -> tuple[int, int]:
        """(how many of the six fields of a container header hold a valid value, the
        declared size): signature, header size, header version, object type, size bounds,
        compression method. One flipped byte spoils at most one field."""
        if len(head) < _CHDR:
            return 0, 0
        sig, hsize, version, size, kind = OBJ_HEADER_BASE_STRUCT.unpack_from(head)
        method, _ = LOG_CONTAINER_STRUCT.unpack_from(head, _HDR)
        score = (
            (sig == b"LOBJ")
            + (hsize == _HDR)
            + (version == 1)
            + (kind == LOG_CONTAINER)
            + (_CHDR <= size <= MAX_CONTAINER_BYTES)
            + (method in (NO_COMPRESSION, ZLIB_DEFLATE))
        )
        return score, int(size)

    @classmethod
    def _container_header(cls, head: bytes) -> int | None:
        """The size of a plausible container header with a valid signature (None: not
        one); at most one other field may be damaged."""
        score, size = cls._container_score(head)
        return size if head[:4] == b"LOBJ" and score >= 5 else None

    def _lands_on_container(self, end: int) -> int | None:
        """Where the container after one that ends at ``end`` starts (after up to 7
        padding bytes), when a container-like header is there (one field may be damaged)."""
        f = self.file
        f.seek(end)
        after = f.read(8 + _CHDR)
        for pad in range(8):
            if after[:pad].strip(b"\x00"):
                break
            if self._container_score(after[pad : pad + _CHDR])[0] >= 5:
                return end + pad
        return None

    def _next_container(self, pos0: int) -> tuple[int, int, bool, bool]:
        """(body end, next container position, size trusted, cut by the end of the
        file) of the container at ``pos0``. Its declared size is trusted when it lands on
        the next container's header (or on the end of the file with no container
        after it); else the body ends at the next plausible container header."""
        f = self.file
        f.seek(pos0)
        score, size = self._container_score(f.read(_CHDR))
        if score >= 4 and _CHDR <= size <= MAX_CONTAINER_BYTES:
            end = pos0 + size
            if end < self._size:
                k = self._lands_on_container(end)
                if k is not None:
                    return end, k, True, False
                f.seek(end)
                if not f.read(8).strip(b"\x00") and end + 8 >= self._size:
                    return end, self._size, True, False
            elif self._scan(pos0 + 1, container=True) is None:
                return self._size, self._size, True, end > self._size
        nxt = self._scan(pos0 + 1, container=True)
        nxt = self._size if nxt is None else nxt
        return nxt, nxt, False, False

    def _read_container(self, pos0: int) -> tuple[bytes, int, bool]:
        """The uncompressed bytes of the container at ``pos0``, where the next one starts,
        and whether the bytes stop short (a gap follows them)."""
        f = self.file
        end, nxt, trusted, cut = self._next_container(pos0)
        f.seek(pos0)
        raw = f.read(end - pos0)
        if not trusted:
            self._record(
                pos0,
                "damaged container header (its size does not reach the "
                f"next container); its body is taken up to the next container "
                f"(byte {nxt})",
                0,
            )
        elif self._container_score(raw[:_CHDR])[0] < 6 and len(raw) >= _CHDR:
            self._record(
                pos0,
                "damaged container header field (its size is confirmed by the next container)",
                0,
            )
        if len(raw) < _CHDR:
            self._record(pos0, "truncated container header at the end", len(raw), "truncated")
            return b"", nxt, True
        method, declared = LOG_CONTAINER_STRUCT.unpack_from(raw, _HDR)
        payload = raw[_CHDR:]
        looks_zlib = (
            len(payload) >= 2
            and payload[0] & 0x0F == 8
            and ((payload[0] << 8) | payload[1]) % 31 == 0
        )
        if method not in (NO_COMPRESSION, ZLIB_DEFLATE):
            guess = ZLIB_DEFLATE if looks_zlib else NO_COMPRESSION
            self._record(
                pos0,
                f"damaged compression method {method}; read as "
                f"{'zlib' if guess == ZLIB_DEFLATE else 'uncompressed'}",
                0,
            )
            method = guess
        if method == NO_COMPRESSION:
            if cut:
                self._record(
                    pos0,
                    "truncated: the last container ends early (its frames up to the cut are kept)",
                    0,
                    "truncated",
                )
            return payload, nxt, cut
        self._after = nxt
        data, gap = self._inflate_container(pos0, payload, declared if trusted else None, cut)
        return data, nxt, gap

    def _inflate_container(
        self, pos0: int, payload: bytes, declared: int | None, cut: bool
    ) -> tuple[bytes, bool]:
        """The inflated bytes of the zlib stream of the container at ``pos0`` and whether
        they stop short; a damaged stream is repaired when one byte can be found that
        makes it whole (:mod:`replay.blf_repair`), else recorded."""
        data, err, gap = _inflate(payload)
        if err is None and declared in (None, len(data)):
            self._clean.append(pos0)
            return data, gap
        if err is None and not _ends_early(payload):  # the header's size is damaged
            self._record(
                pos0, f"container declares {declared} uncompressed bytes, {len(data)} inflated", 0
            )
            return data, gap
        if not cut:
            fixed = self._repair(pos0, payload, data, err, declared)
            if fixed is not None:
                return fixed, False
        if err is not None:
            if cut:
                why = (
                    f"truncated: the last container ends early ({err}); the "
                    f"{len(data)} bytes inflated before the cut are kept"
                )
            else:
                why = (
                    f"damaged compressed container ({err}); the {len(data)} bytes "
                    f"inflated before it are kept{self._repair_note}"
                )
            self._record(pos0, why, 0, "truncated" if cut else "resync")
        else:
            self._record(
                pos0,
                f"container declares {declared} uncompressed bytes, {len(data)} inflated "
                f"(the stream ends early){self._repair_note}",
                0,
            )
        return data, gap

    def _repair(
        self, pos0: int, payload: bytes, data: bytes, err: str | None, declared: int | None
    ) -> bytes | None:
        """The container's bytes with its one damaged compressed byte repaired (recorded
        as a ``repaired`` damage), or None (:attr:`_repair_note` says why)."""
        self._repair_note = ""
        prefix = self._tail if not self._sync and self._tail.startswith(b"LOBJ") else b""
        joined = prefix + data
        first = 0 if prefix else self._resync(joined, 0)
        whole = not walk(joined, first, _next_object)[1] and declared in (None, len(data))
        walker, after, check, said = _next_object, REPAIR_AFTER, REPAIR_CHECK, ""
        ref_cost = 0  # work units spent on the reference keys
        if whole and err is not None and "incorrect data check" in err:
            # every object valid, the size right: only the Adler-32 disagrees
            fix = trailer_repair(payload, data)
            if fix is not None:
                what = "the Adler-32 trailer; the inflated bytes are intact"
                self._record_repair(pos0, *fix, what)
                return data
            if walk(joined, first, _next_in_time)[1]:
                # a time stamp that goes back locates the damage
                walker, after, check = _next_in_time, _TIME_AFTER, _TIME_CHECK
                said = "; its objects are all valid but a time stamp goes back"
            elif self._repair_left <= 0:
                self._repair_note = "; no repair searched (the file's repair budget is spent)"
                return None
            else:
                known, ref_cost = self._key_walker(joined, first)
                self._repair_left -= ref_cost
                if known is None:
                    self._repair_note = (
                        "; its objects are all valid, in time order and their keys seen in "
                        "the file, so the damage changed values, not objects, and is not "
                        "searched for"
                    )
                    return None
                # a frame whose key is rare in the file locates the damage
                walker, after, check = known, _KEY_AFTER, _KEY_CHECK
                said = "; its objects are all valid but a frame's key is rare in the file"
        budget = min(REPAIR_BUDGET - ref_cost, self._repair_left)
        if budget <= 0:
            self._repair_note = "; no repair searched (the file's repair budget is spent)"
            return None
        found, trials, cost = repair_stream(
            payload, data, prefix, first, walker, declared, budget, after, check
        )
        self._repair_left -= cost
        if found is None:
            spent = "the search's budget spent" if cost >= budget else "every candidate tried"
            self._repair_note = f"{said}; no one-byte repair found ({trials} trials, {spent})"
            return None
        self._record_repair(
            pos0,
            found.offset,
            found.old,
            found.new,
            f"its zlib stream ({'Adler-32' if declared is None else 'Adler-32 and size'} "
            f"checked; {trials} trials)",
        )
        return found.data

    def _key_walker(self, joined: bytes, first: int) -> tuple[NextObject | None, int]:
        """The walk that stops at the first CAN frame of ``joined`` (from the object at
        ``first``) whose (channel, identifier, DLC, flags) key is rare in the file's
        intact containers and the frames before it (:func:`_rare_key`), or None when no
        key is rare; and the work units spent (:data:`_KEY_UNIT`)."""
        keys: Counter = Counter()
        pairs: Counter = Counter()
        cost = len(joined) // _KEY_UNIT

        def count(data: bytes) -> None:
            nonlocal cost
            cost += len(data) // _KEY_UNIT
            frames = [k for _, k in _frame_keys(data, self._resync(data, 0))]
            keys.update(frames)
            pairs.update(pairwise(frames))

        for pos in self._clean:
            data = self._intact(pos)[0]
            if data is not None:
                count(data)
        pos, n = self._after, len(self._clean)
        for _ in range(_KEY_LOOKAHEAD):
            if n >= _KEY_CONTAINERS or pos >= self._size:
                break
            data, nxt = self._intact(pos)
            if data is not None:
                count(data)
                n += 1
            pos = max(nxt, pos + 1)
        found = _rare_key(_frame_keys(joined, first), keys, pairs)
        if found is None:
            return None, cost
        known = _known_keys(*found)
        return (known if walk(joined, first, known)[1] else None), cost

    def _intact(self, pos0: int) -> tuple[bytes | None, int]:
        """(the uncompressed bytes of the container at ``pos0`` when its header and zlib
        stream are whole, else None; where the next container starts), read without a
        damage record (the reference keys of :meth:`_key_walker`)."""
        end, nxt, trusted, cut = self._next_container(pos0)
        f = self.file
        f.seek(pos0)
        raw = f.read(end - pos0)
        if not trusted or cut or self._container_score(raw[:_CHDR])[0] < 6:
            return None, nxt
        method, declared = LOG_CONTAINER_STRUCT.unpack_from(raw, _HDR)
        if method == NO_COMPRESSION:
            return raw[_CHDR:], nxt
        data, err, _ = _inflate(raw[_CHDR:])
        return (data if err is None and len(data) == declared else None), nxt

    def _record_repair(self, pos0: int, offset: int, old: int, new: int, what: str) -> None:
        """One ``repaired`` damage record: the container, the byte, both values."""
        self._record(
            pos0,
            f"repaired: compressed byte {offset} of the container (file byte "
            f"{pos0 + _CHDR + offset}) read 0x{old:02x}; 0x{new:02x} makes whole {what}",
            0,
            "repaired",
        )

    def __iter__(self) -> Iterator[can.Message]:
        pos = self._start
        while pos < self._size:
            data, nxt, gap = self._read_container(pos)
            self._cpos = pos
            yield from self._feed(data)
            if gap:
                self._flush_tail("the bytes after it are lost")
                self._sync = True
            pos = max(nxt, pos + 1)
        self._flush_tail("at the end of the file")
        self._check_times()
        self.stop()

    def _check_times(self) -> None:
        """The file header's start and stop times against the last object: a damaged
        start time shifts every timestamp (recorded, the frames are kept)."""
        last = getattr(self, "_last_t", None)
        if last is None or not self.start_timestamp or not self.stop_timestamp:
            return
        off = last - self.stop_timestamp
        if abs(off) > 1.0:
            self._record(
                40,
                f"file header start/stop times disagree with the objects by "
                f"{off:+.3f} s: every timestamp may be shifted",
                0,
            )

    # ----------------------------------------------------------------- objects
    def _flush_tail(self, why: str) -> None:
        """Drop the object cut by a gap or the end of the file (counted)."""
        if self._tail.strip(b"\x00"):
            self._record(self._cpos, f"object cut short ({why})", len(self._tail), "truncated")
        self._tail = b""

    def _resync(self, data: bytes, start: int) -> int:
        """Position of the next valid object header at or after ``start`` (confirmed by
        the object after it), or of a plausible header cut by the end of ``data``."""
        k = data.find(b"LOBJ", start)
        while k >= 0:
            size = _object_size(data, k)
            if size == _INCOMPLETE:
                return k
            if size is not None and _lands(data, k + size):
                j = data.find(b"LOBJ", k + size, k + size + 12)
                if j < 0 or _object_size(data, j) is not None:
                    return k
            k = data.find(b"LOBJ", k + 1)
        return max(start, len(data) - 3)

    def _feed(self, chunk: bytes) -> Iterator[can.Message]:
        """Walk the objects of ``chunk`` (after the tail of the previous containers)."""
        data = self._tail + chunk if self._tail else chunk
        pos = 0
        if self._sync:
            pos = self._resync(data, 0)
            if pos:
                self.skipped_bytes += pos
            self._sync = False
        run = pos
        n = len(data)
        while True:
            k = data.find(b"LOBJ", pos, pos + 8)
            if k < 0 and n - pos < 8 and not (n - pos >= 4 and data[pos:].strip(b"\x00")):
                break  # padding or a split header
            size = _object_size(data, k) if k >= 0 else None
            if size == _INCOMPLETE:
                pos = k
                break
            if size is not None and _lands(data, k + size):
                if _can_like(data, k):
                    self._record(
                        self._cpos,
                        f"object of type {data[k + 12]} with a CAN "
                        "frame's layout skipped (a damaged object type)",
                        size,
                    )
                pos = k + size
                continue
            yield from self._messages(data[run:pos])
            nxt = self._resync(data, pos + 1)
            why = "damaged object header" if k >= 0 else "no object header"
            self._record(
                self._cpos,
                f"{why} at uncompressed offset {pos - len(self._tail)}"
                f"; resynchronised at the next valid object",
                nxt - pos,
            )
            pos = run = nxt
            if pos >= n - 3:
                break
        yield from self._messages(data[run:pos])
        self._tail = data[pos:]

    def _messages(self, objects: bytes) -> Iterator[can.Message]:
        """python-can's parsing of a run of validated objects."""
        if objects:
            try:
                for msg in self._parse_data(objects):
                    self._last_t = msg.timestamp
                    yield msg
            except struct.error:
                return
