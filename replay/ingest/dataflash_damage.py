"""Damage in a DataFlash log: where its framing breaks, what is trusted, what is lost.

From pymavlink's index (:func:`first_damage`: a message that runs past the end of the
file, bytes that belong to no message) and from rimu's own walk of the framing, which
resynchronises after damage (:func:`scan`, :func:`_stretches`): each damaged stretch with
the messages dropped and the IMU samples lost there (:func:`damage_record`). The reader is
:mod:`replay.ingest.ardupilot` (its module docstring says what is kept).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from replay.ingest.dataflash_fmt import HEAD, IMU_TYPES
from replay.ingest.stream import Damage, ImuStream

__all__ = ["damage_record", "first_damage", "scan", "trusted_counts"]


def first_damage(r: Any) -> tuple[int, str] | None:
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


def scan(r: Any, data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
    h0, h1 = HEAD

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
        q = data.find(HEAD, pos + 1)
        while q != -1 and not good(q):
            q = data.find(HEAD, q + 1)
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
    if b - a < 3 or not (data[a] == HEAD[0] or data[a + 1] == HEAD[1]):
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
    o, ln, ty = scan(r, data)
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


def trusted_counts(r: Any, counts: dict[str, int]
                    ) -> tuple[list[dict[str, Any]], dict[int, int], dict[str, int]]:
    """The damaged stretches, the trusted messages ({start: type id}) and the count of
    each type among them. pymavlink's index stops at the first unknown message id: count
    from rimu's own walk of the framing (:func:`scan`), which resynchronises after the
    damage."""
    data = bytes(r.data_map[:int(r.data_len)])          # with repaired FMT records
    stretches, trusted = _stretches(r, data)
    found = np.bincount(np.fromiter(trusted.values(), np.int64, len(trusted)),
                        minlength=256)
    return stretches, trusted, {t: int(found[r.name_to_id[t]]) for t in counts}


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


def damage_record(p: str, damage: tuple[int, str], stretches: list[dict[str, Any]],
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
