"""A BLF reader that survives damage: resynchronises on the next valid object.

python-can's :class:`can.BLFReader` stops at the first damaged object: a flipped byte in
one compressed container loses the rest of the file. :class:`ResyncBLFReader` keeps
python-can's parsing of the objects inside a container and adds, around it:

- a file with neither the ``LOGG`` file signature nor any ``LOBJ`` object is "not a BLF
  file" (:class:`~fdi.errors.FileFormatError`), not an empty log; a damaged file header is
  recorded and reading starts at the first object;
- a container whose header is implausible, or whose zlib stream fails (wrong data check,
  invalid stream), is skipped, and reading goes on at the next container; when the object
  header itself is damaged, the file is scanned for the next ``LOBJ`` signature;
- inside the data, an object that cannot be parsed (or whose size does not move the parser
  on, python-can issue #1584) is skipped up to the next ``LOBJ`` signature; the object cut
  by a skipped container is dropped (its bytes are counted).

Each damage is recorded in :attr:`ResyncBLFReader.damage` as ``{"where": "byte N", "why":
..., "kind": "resync" | "truncated", "skipped_bytes": k}``; the frames lost with it show
in the frame counters (rolling and sample counter gaps).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any, cast

import can
from can.io.blf import (
    FILE_HEADER_SIZE,
    FILE_HEADER_STRUCT,
    LOG_CONTAINER,
    LOG_CONTAINER_STRUCT,
    NO_COMPRESSION,
    OBJ_HEADER_BASE_STRUCT,
    ZLIB_DEFLATE,
    BLFParseError,
    systemtime_to_timestamp,
)
from can.io.generic import BinaryIOMessageReader

from fdi.errors import FileFormatError

__all__ = ["MAX_CONTAINER_BYTES", "ResyncBLFReader"]

MAX_CONTAINER_BYTES = 64 << 20
"""Largest plausible log container (writers use about 128 kB)."""
_HDR = OBJ_HEADER_BASE_STRUCT.size
_SCAN = 1 << 16


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
        self.skipped_bytes = 0
        self._sync = False
        self._cpos = 0
        self._tail = b""
        self._pos = 0
        self.file_size = self.uncompressed_size = self.object_count = 0
        self.start_timestamp = self.stop_timestamp = 0.0
        head = self.file.read(FILE_HEADER_STRUCT.size)
        whole = len(head) == FILE_HEADER_STRUCT.size
        if whole:
            h = FILE_HEADER_STRUCT.unpack(head)
            self.start_timestamp = systemtime_to_timestamp(cast("Any", h[14:22]))
            self.stop_timestamp = systemtime_to_timestamp(cast("Any", h[22:30]))
        if whole and head[:4] == b"LOGG":
            self.file_size, self.uncompressed_size, self.object_count = h[10], h[11], h[12]
            hsize = h[1]
            if not FILE_HEADER_STRUCT.size <= hsize <= (1 << 20):
                self._record(4, f"damaged file header (header size {hsize}); read from "
                             f"byte {FILE_HEADER_SIZE}", 0)
                hsize = FILE_HEADER_SIZE
            self.file.seek(hsize)
            return
        k = self._scan(0)
        if k is None:
            if head[:4] == b"LOGG":
                self._record(0, "truncated file header, no object", len(head))
                self.file.seek(0, 2)
                return
            self.file.close()
            raise FileFormatError(self.path, "not a BLF file (no 'LOGG' header and no "
                                  "'LOBJ' object)")
        self._record(0, "damaged file header; reading from the first object", k)
        self.file.seek(k)

    def _record(self, where: int, why: str, skipped: int, kind: str = "resync") -> None:
        self.skipped_bytes += skipped
        if len(self.damage) < 50:
            self.damage.append({"where": f"byte {where}", "why": why, "kind": kind,
                                "skipped_bytes": int(skipped)})

    def _scan(self, start: int) -> int | None:
        """Position of the next ``LOBJ`` at or after ``start`` (None: end of file)."""
        f = self.file
        f.seek(start)
        pos = start
        carry = b""
        while True:
            block = f.read(_SCAN)
            if not block:
                return None
            buf = carry + block
            k = buf.find(b"LOBJ")
            if k >= 0:
                return pos - len(carry) + k
            carry = buf[-3:]
            pos += len(block)

    def __iter__(self) -> Iterator[can.Message]:
        f = self.file
        while True:
            pos0 = f.tell()
            head = f.read(_HDR)
            if not head:
                break
            if len(head) < _HDR:
                self._record(pos0, "truncated object header at the end", len(head),
                             "truncated")
                break
            sig, _, _, size, kind = OBJ_HEADER_BASE_STRUCT.unpack(head)
            if sig != b"LOBJ" or size < _HDR or size > MAX_CONTAINER_BYTES or (
                    kind == LOG_CONTAINER and size < _HDR + LOG_CONTAINER_STRUCT.size):
                nxt = self._scan(pos0 + 1)
                end = nxt if nxt is not None else f.seek(0, 2)
                self._record(pos0, "damaged object header; resynchronised at the next "
                             "object" if nxt is not None else "damaged object header; no "
                             "object after it", end - pos0)
                self._sync = True
                self._tail = b""
                if nxt is None:
                    break
                f.seek(nxt)
                continue
            body = f.read(size - _HDR)
            cut = len(body) < size - _HDR
            f.read(size % 4)
            if kind != LOG_CONTAINER or len(body) < LOG_CONTAINER_STRUCT.size:
                if cut:
                    self._record(pos0, "truncated object at the end of the file",
                                 _HDR + len(body), "truncated")
                    break
                continue
            method, _ = LOG_CONTAINER_STRUCT.unpack_from(body)
            payload = body[LOG_CONTAINER_STRUCT.size:]
            try:
                if method == NO_COMPRESSION:
                    data = payload
                elif method == ZLIB_DEFLATE:
                    data = zlib.decompressobj().decompress(payload)
                else:
                    raise ValueError(f"unknown compression method {method}")
            except (zlib.error, ValueError) as exc:
                self._record(pos0, f"damaged container skipped ({exc})", size)
                self._sync = True
                self._tail = b""
                if cut:
                    break
                continue
            self._cpos = pos0
            yield from self._parse_container(data)
            if cut:
                self._record(pos0, "truncated: the last container ends early (its frames up "
                             "to the cut are kept)", _HDR + len(body), "truncated")
                break
        self.stop()

    def _parse_container(self, data: bytes) -> Iterator[can.Message]:
        if self._sync:
            k = data.find(b"LOBJ")
            if k < 0:
                self._record(self._cpos, "container without an object start after a "
                             "damaged one",
                             len(data))
                return
            if k:
                self.skipped_bytes += k
            data = data[k:]
            self._sync = False
        elif self._tail:
            data = self._tail + data
        while True:
            self._pos = 0
            last = -1
            try:
                for msg in self._parse_data(data):
                    if self._pos == last:
                        raise BLFParseError("object size does not advance")
                    last = self._pos
                    yield msg
                break
            except struct.error:
                break
            except BLFParseError as exc:
                k = data.find(b"LOBJ", self._pos + 1)
                end = len(data) if k < 0 else k
                why = str(exc) or "no object signature"
                self._record(self._cpos, f"damaged object inside the container skipped ({why})",
                             end - self._pos)
                if k < 0:
                    self._pos = len(data)
                    break
                data = data[k:]
        self._tail = data[self._pos:]
