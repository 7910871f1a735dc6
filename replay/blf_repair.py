"""Repair by search of one damaged byte in a zlib-compressed BLF container.

A flipped byte inside a deflate stream puts the decoder out of step, and the
back-references after it copy the wrong bytes: most of the container is lost
(``docs/edges.md``, "Damaged logs"). When a container's stream fails, :func:`repair_stream`
looks for the one byte (at an unknown position, with an unknown value) that makes it whole:

1. **locate**: the objects of the inflated bytes are walked from the first object to the
   first invalid one (its offset *B*) or to the end of what was inflated before a zlib
   error. The stream is inflated again byte by byte around *B*, recording how many bytes
   had come out before each input byte; the damaged byte is one whose output starts at or
   before ``B + REPAIR_AFTER``, and not earlier than ``B - REPAIR_BEFORE`` (measured:
   the damage starts at most 773 bytes before the object that breaks, nearly always inside
   it; a damaged dynamic-Huffman block header produces no output, so its bytes all sit at
   the offset where the block starts and are in the window when the break is there);
2. **try**: the candidate positions are taken from the last one backwards; at each, the
   inflater is restored (:meth:`zlib.Decompress.copy`) and the 255 other byte values are
   fed with the bytes after them, a few at a time; a candidate is rejected at the first
   zlib error or invalid object, so a wrong one costs a few microseconds;
3. **prove**: a candidate whose objects are valid ``REPAIR_CHECK`` bytes past *B* is
   inflated to the end. It is accepted only when the stream ends exactly at the end of
   the container with a correct Adler-32 (zlib checks it; a wrong candidate passes with
   probability 2^-32) and, when the container header is trusted, with the uncompressed
   size it declares. The other values at the accepted position are tried too and must not
   give a different output (else the repair is ambiguous and refused).

The cost is bounded per container, :data:`REPAIR_BUDGET`, and per file,
:data:`REPAIR_FILE_BUDGET`, in work units counted from the work done (one per trial, one
per :data:`_WALK_UNIT` bytes of output checked, one per :data:`_INFLATE_UNIT` compressed
bytes inflated to the end; about 10 µs each), so the bound and the result do not depend
on the machine's speed; when it runs out, the reader keeps what inflated before the
damage and resynchronises after it, as it does without repair.

A stream whose objects are all valid and whose size is right but whose Adler-32 is wrong
(a flip that changed only frame values) cannot be located by its objects. When the stored
Adler-32 differs from the computed one in exactly one byte, the trailer itself is the
damaged byte (:func:`trailer_repair`). Else, when a time stamp goes back, the object
walk is run with the time order as one more check (the reader's ``_next_in_time``) and
the search above runs around it, with a longer check past it (a damage that copies wrong
time stamps into many objects leaves many out of order). Else, when a CAN frame's
(channel, identifier, DLC, flags) key, or the pair of its key and its predecessor's, is
rare in the file's intact containers (read before it, else after it) and the frames
before it, the walk stops at the first such frame and the search runs around it, every
key and pair of the check past it being one seen often (a damage that copies a wrong
identifier into many frames through back-references; the reader's ``_known_keys``).
Else the stream is not searched: the damage can be anywhere in the container.
(Locating a single changed output byte from the Adler-32 itself, which the sums A and B
allow, was tried and dropped: it spends the 32 bits of the check on the location, and a
wrong "repair" was accepted in 1 of 60 flips.)
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass

__all__ = [
    "INVALID",
    "REPAIR_AFTER",
    "REPAIR_BEFORE",
    "REPAIR_BUDGET",
    "REPAIR_CHECK",
    "REPAIR_FILE_BUDGET",
    "UNKNOWN",
    "Inflater",
    "NextObject",
    "Repair",
    "repair_stream",
    "trailer_repair",
    "walk",
]

REPAIR_BUDGET = 100_000
"""Work units per container (module docstring): about 1 s (measured: a repair takes a
median of 1800 trials, at most 8200 in 150 repairs; the window holds about 600 positions,
150 000 trials, in a python-can container)."""
REPAIR_FILE_BUDGET = 10 * REPAIR_BUDGET
"""Work units per file: a file with many damaged containers is read in bounded time
(about 10 s of search at most)."""
_WALK_UNIT = 128
"""Bytes of a candidate's output checked object by object per work unit."""
_STEP_OUT = 512
"""Most output bytes inflated between two checks of a candidate (a wrong value may
decode to long matches: a few input bytes can give kilobytes)."""
_INFLATE_UNIT = 1024
"""Compressed bytes of a candidate inflated to the end per work unit (about 4 kB of
output)."""
REPAIR_BEFORE = 2048
"""Output bytes before the first invalid object where the damaged byte is looked for."""
REPAIR_AFTER = 64
"""Output bytes after the start of the first invalid object where it is looked for."""
REPAIR_CHECK = 256
"""Output bytes past the first invalid object that a candidate must inflate to valid
objects before it is inflated to the end."""
_GROUP = 32
"""Candidate positions restored from one checkpoint of the inflater."""
_FIRST_FEED = 16
"""Input bytes fed after a candidate value before the first check (doubled after each)."""

Inflater = type(zlib.decompressobj())
"""The type of zlib's decompression objects (the :mod:`zlib` module does not name it)."""

NextObject = Callable[[bytes, int], int]
"""``next_object(data, pos)``: where the object after the valid object at ``pos``
starts; :data:`INVALID` when the object at ``pos`` is invalid or does not land on the
next one; :data:`UNKNOWN` when ``data`` ends before this can be told."""
INVALID = -1
UNKNOWN = -2


@dataclass(frozen=True)
class Repair:
    """One damaged byte of a container's compressed stream, found and undone.

    Attributes
    ----------
    offset : int
        Offset of the byte in the compressed stream (after the container header).
    old, new : int
        The damaged value read and the value that makes the stream whole.
    data : bytes
        The container's uncompressed bytes after the repair.
    trials : int
        Candidate values tried.
    cost : int
        Work units spent.
    """

    offset: int
    old: int
    new: int
    data: bytes
    trials: int
    cost: int


def walk(data: bytes, pos: int, next_object: NextObject) -> tuple[int, bool]:
    """Follow the valid objects of ``data`` from the object at ``pos``.

    Returns
    -------
    stop : int
        The object where the walk stopped.
    broken : bool
        True when it stopped at an invalid object; False when ``data`` ends first.
    """
    while True:
        nxt = next_object(data, pos)
        if nxt < 0:
            return pos, nxt == INVALID
        pos = nxt


def trailer_repair(payload: bytes, data: bytes) -> tuple[int, int, int] | None:
    """(offset, old, new) of the stored Adler-32 byte that differs from the Adler-32 of
    ``data``, when exactly one byte differs (the trailer is the damaged byte); else None."""
    if len(payload) < 6:
        return None
    stored = payload[-4:]
    computed = zlib.adler32(data).to_bytes(4, "big")
    diff = [i for i in range(4) if stored[i] != computed[i]]
    if len(diff) != 1:
        return None
    i = diff[0]
    return len(payload) - 4 + i, stored[i], computed[i]


@dataclass
class _Search:
    """The state of one search: the damaged stream and what is known of it."""

    payload: bytes
    joined: bytes  # the bytes before the container (an object cut by it) + its output
    off: int  # where the container's output starts in ``joined``
    starts: list[int]  # valid object starts in ``joined``, ascending
    brk: int  # offset in the container's output of the first invalid object
    expected: int | None
    next_object: NextObject
    budget: int
    trials: int = 0
    cost: int = 0
    done: bool = False
    check: int = REPAIR_CHECK

    def chain_start(self, out_len: int) -> int:
        """The last valid object start at or before output offset ``out_len``."""
        limit = self.off + out_len
        lo, hi = 0, len(self.starts)
        while lo < hi:
            mid = (lo + hi) // 2
            if self.starts[mid] <= limit:
                lo = mid + 1
            else:
                hi = mid
        return self.starts[max(lo - 1, 0)]

    def trial(self, state: Inflater, p: int, value: int, out_len: int) -> bytes | None:
        """The container's output with byte ``p`` set to ``value`` (the inflater
        ``state`` had produced ``out_len`` bytes before it), or None when rejected."""
        self.trials += 1
        self.cost += 1
        t = state.copy()
        first = self.chain_start(out_len)
        base = min(first, self.off + out_len)
        buf = self.joined[base : self.off + out_len]
        pos, goal = first - base, self.off + self.brk + self.check - base
        feed, i, step, n = bytes([value]), p + 1, _FIRST_FEED, len(self.payload)
        try:
            while not t.eof and len(buf) < goal:
                if not feed:
                    if i >= n:
                        break
                    feed, i, step = self.payload[i : i + step], i + step, 2 * step
                got = t.decompress(feed, _STEP_OUT)
                feed = t.unconsumed_tail
                buf += got
                self.cost += len(got) // _WALK_UNIT
                pos, broken = walk(buf, pos, self.next_object)
                if broken:
                    return None
            if not t.eof:
                self.cost += (n - i) // _INFLATE_UNIT  # charged before: zlib may raise
                buf += t.decompress(feed + self.payload[i:])
        except zlib.error:
            return None
        if not t.eof or t.unused_data:
            return None
        data = self.joined[self.off : base] + buf if base >= self.off else buf[self.off - base :]
        if self.expected is not None and len(data) != self.expected:
            return None
        return data


def _locate(
    payload: bytes, brk: int, after: int
) -> tuple[list[int], list[tuple[int, Inflater]], int, int]:
    """Inflate ``payload`` byte by byte around the break at output offset ``brk``.

    Returns
    -------
    out_len : list of int
        Bytes output before each input byte ``p`` of the window, as ``out_len[p - lo]``.
    checkpoints : list of (int, Decompress)
        The inflater before input byte ``p`` for ``p = lo, lo + _GROUP, ...``.
    lo, hi : int
        The window of candidate positions ``lo <= p < hi``.
    """
    d = zlib.decompressobj()
    n_out, p = 0, 0
    step = 256
    # fast forward, in steps, to a little before the window
    while p < len(payload):
        probe = d.copy()
        try:
            got = len(probe.decompress(payload[p : p + step]))
        except zlib.error:
            break
        if n_out + got > brk - REPAIR_BEFORE or probe.eof:
            break
        d, n_out, p = probe, n_out + got, p + step
    lo = p
    out_len: list[int] = []
    checkpoints: list[tuple[int, Inflater]] = []
    while p < len(payload) and n_out <= brk + after:
        if (p - lo) % _GROUP == 0:
            checkpoints.append((p, d.copy()))
        out_len.append(n_out)
        try:
            n_out += len(d.decompress(payload[p : p + 1]))
        except zlib.error:
            p += 1
            break
        p += 1
        if d.eof:
            break
    return out_len, checkpoints, lo, p


def _search_group(
    s: _Search, start: int, state: Inflater, out_len: list[int], hi: int, lo: int
) -> Repair | None:
    """Try the positions ``start .. start + _GROUP`` (below ``hi``), the last first;
    sets ``s.done`` when the search is over (a repair, an ambiguity, the budget)."""
    end = min(start + _GROUP, hi)
    states = []
    for p in range(start, end):
        states.append(state.copy())
        if p + 1 < end:
            try:
                state.decompress(s.payload[p : p + 1])
            except zlib.error:
                break
    for k in range(len(states) - 1, -1, -1):
        found = _search_position(s, states[k], start + k, out_len[start + k - lo])
        if s.done:
            return found
    return None


def _search_position(s: _Search, state: Inflater, p: int, out_len: int) -> Repair | None:
    """Try every other value of byte ``p``: the repair when exactly one output comes out
    whole (``s.done`` set also when two differ or the budget is spent)."""
    old = s.payload[p]
    found: Repair | None = None
    for v in range(256):
        if v == old:
            continue
        if s.cost >= s.budget:
            s.done = True
            return found  # a repair found, the rest of its values not all tried
        data = s.trial(state, p, v, out_len)
        if data is None:
            continue
        s.done = True
        if found is not None and data != found.data:
            return None  # two different repairs: ambiguous
        if found is None:
            found = Repair(p, old, v, data, 0, 0)
    return found


def repair_stream(
    payload: bytes,
    data: bytes,
    prefix: bytes,
    first: int,
    next_object: NextObject,
    expected: int | None,
    budget: int = REPAIR_BUDGET,
    after: int = REPAIR_AFTER,
    check: int = REPAIR_CHECK,
) -> tuple[Repair | None, int, int]:
    """Find the one byte of a damaged zlib stream that makes it whole (module docstring).

    Parameters
    ----------
    payload : bytes
        The container's compressed stream (zlib header to Adler-32).
    data : bytes
        What it inflated to before the damage stopped it (or all of it).
    prefix : bytes
        The bytes before the container's output that belong to its first object (an
        object cut by the previous container), or empty.
    first : int
        Where the first valid object starts in ``prefix + data``.
    next_object : callable
        The object walk (:data:`NextObject`).
    expected : int or None
        The uncompressed size the container declares (None: not trusted).
    budget : int
        Most work units (module docstring).
    after : int
        Output bytes after the start of the first invalid object where the damaged byte
        is looked for (:data:`REPAIR_AFTER`; more when ``next_object`` judges an object by
        the one after it).
    check : int
        Output bytes past the first invalid object that a candidate must inflate to valid
        objects before it is inflated to the end (:data:`REPAIR_CHECK`).

    Returns
    -------
    repair : Repair or None
        The repair, or None (no damage located, none found within the budget, or two
        different ones).
    trials : int
        Candidate values tried.
    cost : int
        Work units spent (at or above ``budget``: the budget ran out).
    """
    joined = prefix + data
    starts = [first]
    pos = first
    while True:
        nxt = next_object(joined, pos)
        if nxt < 0:
            break
        starts.append(nxt)
        pos = nxt
    brk = max(pos - len(prefix), 0)
    s = _Search(payload, joined, len(prefix), starts, brk, expected, next_object, budget)
    s.check = check
    out_len, checkpoints, lo, hi = _locate(payload, brk, after)
    for start, state in reversed(checkpoints):
        found = _search_group(s, start, state, out_len, hi, lo)
        if s.done:
            if found is None:
                return None, s.trials, s.cost
            repair = Repair(found.offset, found.old, found.new, found.data, s.trials, s.cost)
            return repair, s.trials, s.cost
    return None, s.trials, s.cost
