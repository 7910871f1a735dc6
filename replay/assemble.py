"""From raw CAN frames to sensor samples: match, check, decode (vectorised), assemble.

Pipeline (:func:`decode_frames`), every frame ends in exactly one bucket of the
:class:`~replay.accounting.FrameAccounting`:

1. error / remote frames, non-finite timestamps are rejected;
2. each frame is matched to a *slot*: one DBC message (for J1939: its PGN and the sensor's
   source address) on one bus channel, carrying the values of one or more sensors;
   no match is ``unknown_id`` (or ``other_channel``);
3. per slot, in vectorised numpy: length, CRC-8 SAE J1850, timestamp order, rolling
   counter, status, then the signal values (J1939 raw values ≥ 0xFB00 for 16-bit signals,
   ≥ 0xFB for 8-bit, are 'error'/'not available': the value is missing, never scaled);
4. assembly into samples: by the DBC's sample counter when every slot has one (unwrapped
   over all frames in time order), otherwise by time (frames closer than the tolerance
   belong to one sample). A second frame of one slot in one sample is a ``duplicate``.
   A sample's time is its earliest frame's; a sensor without a value in a sample is
   missing (``valid = False``, raw NaN), never zero.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cantools
import numpy as np

from fdi.errors import ConfigError
from replay.accounting import FrameAccounting
from replay.channel_map import ChannelMap
from replay.crc import crc8_j1850_block
from replay.frames import MessageLayout, message_layout

__all__ = [
    "FRAME_DATA",
    "FRAME_ERROR",
    "FRAME_REMOTE",
    "RawFrames",
    "Samples",
    "Slot",
    "assemble_samples",
    "build_slots",
    "decode_frames",
    "j1939_not_available",
]

FRAME_DATA, FRAME_ERROR, FRAME_REMOTE = 0, 1, 2


@dataclass
class RawFrames:
    """Frames as read from a log, in file order.

    Attributes
    ----------
    t : ndarray, shape (M,)
        Timestamps (s, as the reader gives them).
    arbitration_id : ndarray of int64, shape (M,)
    extended : ndarray of bool, shape (M,)
    channel : ndarray of object, shape (M,)
    payload : ndarray of uint8, shape (sum of lengths,)
        All payloads, concatenated in frame order.
    lengths : ndarray of int64, shape (M,)
        Payload length of each frame (bytes).
    frame_type : ndarray of int8, shape (M,)
        :data:`FRAME_DATA`, :data:`FRAME_ERROR` or :data:`FRAME_REMOTE`.
    """

    t: np.ndarray
    arbitration_id: np.ndarray
    extended: np.ndarray
    channel: np.ndarray
    payload: np.ndarray
    lengths: np.ndarray
    frame_type: np.ndarray
    _offsets: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def offsets(self) -> np.ndarray:
        """Start of each frame's payload in :attr:`payload`, shape (M,)."""
        if self._offsets is None:
            off = np.zeros(len(self), np.int64)
            np.cumsum(self.lengths[:-1], out=off[1:])
            self._offsets = off
        return self._offsets

    def block(self, idx: np.ndarray, length: int) -> np.ndarray:
        """Payloads of frames ``idx`` (all of ``length`` bytes) as an (K, length) block."""
        if idx.size == 0:
            return np.zeros((0, length), np.uint8)
        pos = self.offsets[idx][:, None] + np.arange(length)
        return self.payload[pos]

    def data(self, i: int) -> bytes:
        """Payload of frame ``i``."""
        o = int(self.offsets[i])
        return self.payload[o:o + int(self.lengths[i])].tobytes()

    @classmethod
    def from_messages(cls, messages: list) -> RawFrames:
        """Build from a list of :class:`can.Message` (tests, live batches)."""
        ft = [FRAME_ERROR if m.is_error_frame else FRAME_REMOTE if m.is_remote_frame
              else FRAME_DATA for m in messages]
        ch = np.empty(len(messages), dtype=object)
        ch[:] = [m.channel for m in messages]
        data = [bytes(m.data or b"") for m in messages]
        return cls(t=np.array([m.timestamp for m in messages], dtype=float),
                   arbitration_id=np.array([m.arbitration_id for m in messages], np.int64),
                   extended=np.array([m.is_extended_id for m in messages], bool),
                   channel=ch, payload=np.frombuffer(b"".join(data), np.uint8),
                   lengths=np.array([len(d) for d in data], np.int64),
                   frame_type=np.array(ft, np.int8))


@dataclass(frozen=True)
class Slot:
    """One message (one source address, one channel) carrying some sensors' values.

    Attributes
    ----------
    key : int
        Frame key (:func:`frame_keys`).
    channel : object
        Bus channel filter (None: any).
    layout : MessageLayout
    sensors : tuple of int
        0-based sensor indices, and ``signals`` their signal names.
    signals : tuple of str
    counter, crc, sample_counter, status : str or None
        Signal names of the checks.
    """

    key: int
    channel: object
    layout: MessageLayout
    sensors: tuple[int, ...]
    signals: tuple[str, ...]
    counter: str | None
    crc: str | None
    sample_counter: str | None
    status: str | None
    message: cantools.database.can.Message


_EXT = 1 << 40
_J1939 = 1 << 41


def _pgn(arb: np.ndarray) -> np.ndarray:
    pf = (arb >> 16) & 0xFF
    ps = (arb >> 8) & 0xFF
    dp = (arb >> 24) & 0x3
    return (dp << 16) | (pf << 8) | np.where(pf >= 240, ps, 0)


def frame_keys(arb: np.ndarray, extended: np.ndarray, j1939: bool) -> np.ndarray:
    """Matching key of each frame: id and format, or J1939 (PGN, source address)."""
    a = np.asarray(arb, np.int64)
    ext = np.asarray(extended, bool)
    if j1939:
        return np.where(ext, _J1939 | (_pgn(a) << 8) | (a & 0xFF), a)
    return a | np.where(ext, _EXT, 0)


def _message_key(msg: cantools.database.can.Message, sa: int | None, j1939: bool) -> int:
    fid = int(msg.frame_id)
    if j1939:
        if not msg.is_extended_frame:
            raise ConfigError(f"J1939 map: DBC message {msg.name} is not an extended frame")
        pgn = int(_pgn(np.array([fid], np.int64))[0])
        return _J1939 | (pgn << 8) | (fid & 0xFF if sa is None else sa)
    return fid | (_EXT if msg.is_extended_frame else 0)


def build_slots(db: cantools.database.can.Database, cmap: ChannelMap) -> list[Slot]:
    """Group the map's sensors into slots (one per message, source address and channel).

    Raises
    ------
    ConfigError
        A message or signal the map names is not in the DBC, or the slot's sensors
        disagree on their check signals.
    """
    groups: dict[tuple[int, object], list[int]] = {}
    msgs: dict[tuple[int, object], cantools.database.can.Message] = {}
    for i, s in enumerate(cmap.sensors):
        try:
            msg = db.get_message_by_name(s.message)
        except KeyError:
            raise ConfigError(f"channel map {cmap.source}: sensor {i + 1} ({s.name}): "
                              f"message {s.message!r} is not in the DBC") from None
        names = {sg.name for sg in msg.signals}
        for what in (s.signal, s.counter_signal, s.crc_signal, s.sample_counter_signal,
                     s.status_signal):
            if what is not None and what not in names:
                raise ConfigError(f"channel map {cmap.source}: sensor {i + 1} ({s.name}): "
                                  f"signal {what!r} is not in message {s.message}")
        k = (_message_key(msg, s.source_address, cmap.j1939), s.channel)
        groups.setdefault(k, []).append(i)
        msgs[k] = msg
    slots = []
    for (key, ch), idx in groups.items():
        first = cmap.sensors[idx[0]]
        checks = (first.counter_signal, first.crc_signal, first.sample_counter_signal,
                  first.status_signal)
        for i in idx[1:]:
            s = cmap.sensors[i]
            if (s.counter_signal, s.crc_signal, s.sample_counter_signal,
                    s.status_signal) != checks:
                raise ConfigError(f"channel map {cmap.source}: sensors {idx[0] + 1} and "
                                  f"{i + 1} share message {s.message} but name different "
                                  "counter/CRC/sample/status signals")
        msg = msgs[(key, ch)]
        lay = message_layout(msg)
        if first.crc_signal is not None:
            cs = lay.signals[first.crc_signal]
            if cs.length != 8 or cs.big_endian or cs.shift != 8 * (msg.length - 1):
                raise ConfigError(f"channel map {cmap.source}: CRC signal "
                                  f"{first.crc_signal} of {msg.name} must be the last byte")
        if not lay.vectorisable:
            raise ConfigError(f"message {msg.name}: payloads over 8 bytes or multiplexed "
                              "messages are not supported by the block decoder")
        slots.append(Slot(key=key, channel=ch, layout=lay, sensors=tuple(idx),
                          signals=tuple(cmap.sensors[i].signal for i in idx),
                          counter=checks[0], crc=checks[1], sample_counter=checks[2],
                          status=checks[3], message=msg))
    return slots


def j1939_not_available(raw: np.ndarray, length: int) -> np.ndarray:
    """J1939 'error' / 'not available' raw values (SAE J1939-71 ranges).

    8-bit: ≥ 0xFB; 16-bit: ≥ 0xFB00; 32-bit: ≥ 0xFB000000 (generally ≥ 0xFB·2^(len−8)).
    Fields shorter than 8 bits are not checked here.
    """
    if length < 8:
        return np.zeros(raw.shape, bool)
    return np.asarray(raw, np.int64) >= (0xFB << (length - 8))


@dataclass
class _SlotFrames:
    idx: np.ndarray          # global frame indices (file order)
    t: np.ndarray
    sample_counter: np.ndarray | None
    values: np.ndarray       # (K, m)
    valid: np.ndarray        # (K, m)


def _decode_slot(slot: Slot, frames: RawFrames, idx: np.ndarray, j1939: bool,
                 max_counter_delta: int, acct: FrameAccounting) -> _SlotFrames:
    lay = slot.layout
    ok = frames.lengths[idx] == lay.length
    acct.reject("wrong_length", int(np.count_nonzero(~ok)))
    idx = idx[ok]
    block = frames.block(idx, lay.length)
    if slot.crc is not None and idx.size:
        good = crc8_j1850_block(block[:, :-1]) == block[:, -1]
        acct.reject("crc", int(np.count_nonzero(~good)))
        idx, block = idx[good], block[good]
    t = frames.t[idx]
    if idx.size > 1:
        prev_max = np.maximum.accumulate(t)
        ooo = np.zeros(idx.size, bool)
        ooo[1:] = t[1:] < prev_max[:-1]
        if ooo.any():
            acct.reject("out_of_order", int(np.count_nonzero(ooo)))
            keep = ~ooo
            idx, block, t = idx[keep], block[keep], t[keep]
    le, be = lay.words(block)
    if slot.counter is not None and idx.size > 1:
        cs = lay.signals[slot.counter]
        c = cs.raw(le, be)
        mod = 1 << cs.length
        d = np.diff(c) % mod
        keep = np.ones(idx.size, bool)
        keep[1:] = (d >= 1) & (d <= max_counter_delta)
        acct.reject("counter_repeat", int(np.count_nonzero(d == 0)))
        acct.reject("counter_jump", int(np.count_nonzero(d > max_counter_delta)))
        acct.lost_frames += int(np.sum(d[(d > 1) & (d <= max_counter_delta)] - 1))
        idx, t, le, be = idx[keep], t[keep], le[keep], be[keep]
    if slot.status is not None and idx.size:
        st = lay.signals[slot.status].raw(le, be)
        good = st == 0
        acct.reject("status", int(np.count_nonzero(~good)))
        idx, t, le, be = idx[good], t[good], le[good], be[good]
    m = len(slot.sensors)
    values = np.full((idx.size, m), np.nan)
    valid = np.ones((idx.size, m), bool)
    for j, name in enumerate(slot.signals):
        s = lay.signals[name]
        r = s.raw(le, be)
        if j1939 and not s.is_float:
            na = j1939_not_available(r, s.length)
            valid[:, j] = ~na
        values[:, j] = s.physical(r)
    values[~valid] = np.nan
    if j1939:
        none = ~valid.any(axis=1)
        acct.reject("j1939_not_available", int(np.count_nonzero(none)))
        keep = ~none
        acct.values_not_available += int(np.count_nonzero(~valid[keep]))
        idx, t, le, be = idx[keep], t[keep], le[keep], be[keep]
        values, valid = values[keep], valid[keep]
    sc = None
    if slot.sample_counter is not None:
        sc = lay.signals[slot.sample_counter].raw(le, be)
    return _SlotFrames(idx=idx, t=t, sample_counter=sc, values=values, valid=valid)


@dataclass(frozen=True)
class Samples:
    """Assembled samples.

    Attributes
    ----------
    t : ndarray, shape (S,)
        Sample times: the earliest frame of each sample (log clock, s).
    raw : ndarray, shape (S, n)
        Decoded values; NaN where missing.
    valid : ndarray of bool, shape (S, n)
    sample_index : ndarray of int64, shape (S,)
        Unwrapped sample counter (counter assembly) or cluster number (time assembly).
    """

    t: np.ndarray
    raw: np.ndarray
    valid: np.ndarray
    sample_index: np.ndarray


def assemble_samples(parts: list[tuple[Slot, _SlotFrames]], n: int, *, by_counter: bool,
                     tolerance_s: float, acct: FrameAccounting) -> Samples:
    """Assemble decoded slot frames into samples (see the module docstring)."""
    ns = len(parts)
    if ns == 0 or sum(p.idx.size for _, p in parts) == 0:
        return Samples(np.zeros(0), np.zeros((0, n)), np.zeros((0, n), bool),
                       np.zeros(0, np.int64))
    t = np.concatenate([p.t for _, p in parts])
    slot_of = np.concatenate([np.full(p.idx.size, k, np.int64) for k, (_, p) in enumerate(parts)])
    row_in = np.concatenate([np.arange(p.idx.size) for _, p in parts])
    order = np.argsort(t, kind="stable")
    t, slot_of, row_in = t[order], slot_of[order], row_in[order]
    if by_counter:
        c = np.concatenate([p.sample_counter for _, p in parts])[order].astype(np.int64)
        d = np.diff(c)
        d = (d + 32768) % 65536 - 32768
        u = np.concatenate([[0], np.cumsum(d)])
        cluster = u - u.min()
    else:
        cluster = np.concatenate([[0], np.cumsum(np.diff(t) > tolerance_s)]).astype(np.int64)
    # duplicates: a slot twice in one sample -> keep the earliest (a stable sort of the
    # combined key keeps time order within equal keys; the data are nearly sorted already)
    key = cluster * ns + slot_of
    o2 = np.argsort(key, kind="stable")
    ks = key[o2]
    dup = np.zeros(t.size, bool)
    dup[o2[1:]] = ks[1:] == ks[:-1]
    acct.reject("duplicate", int(np.count_nonzero(dup)))
    keep = ~dup
    t, slot_of, row_in, cluster = t[keep], slot_of[keep], row_in[keep], cluster[keep]
    acct.used += int(t.size)
    ids, inv = np.unique(cluster, return_inverse=True)
    S = ids.size
    ts = np.full(S, np.inf)
    np.minimum.at(ts, inv, t)
    raw = np.full((S, n), np.nan)
    valid = np.zeros((S, n), bool)
    for k, (slot, p) in enumerate(parts):
        sel = slot_of == k
        rows = inv[sel]
        src = row_in[sel]
        for j, sensor in enumerate(slot.sensors):
            raw[rows, sensor] = p.values[src, j]
            valid[rows, sensor] = p.valid[src, j]
    return Samples(t=ts, raw=raw, valid=valid, sample_index=ids)


def decode_frames(frames: RawFrames, db: cantools.database.can.Database, cmap: ChannelMap,
                  acct: FrameAccounting, *, sample_rate_hz: float) -> Samples:
    """Match, check, decode and assemble every frame (see the module docstring).

    Parameters
    ----------
    frames : RawFrames
    db : cantools Database
    cmap : ChannelMap
    acct : FrameAccounting
        Updated in place: ``read`` grows by ``len(frames)``, every frame is used or rejected.
    sample_rate_hz : float
        Nominal sample rate (sets the default assembly tolerance, 0.4 sample periods).

    Returns
    -------
    Samples
    """
    M = len(frames)
    acct.read += M
    slots = build_slots(db, cmap)
    ft = frames.frame_type
    alive = ft == FRAME_DATA
    acct.reject("error_frame", int(np.count_nonzero(ft == FRAME_ERROR)))
    acct.reject("remote_frame", int(np.count_nonzero(ft == FRAME_REMOTE)))
    bad_t = alive & ~np.isfinite(frames.t)
    acct.reject("nonfinite_time", int(np.count_nonzero(bad_t)))
    alive &= ~bad_t
    keys = frame_keys(frames.arbitration_id, frames.extended, cmap.j1939)
    known_keys = np.array(sorted({s.key for s in slots}), np.int64)
    is_known = alive & np.isin(keys, known_keys)
    acct.reject("unknown_id", int(np.count_nonzero(alive & ~is_known)))
    claimed = np.zeros(M, bool)
    parts = []
    for slot in slots:
        sel = is_known & (keys == slot.key)
        if slot.channel is not None:
            sel &= frames.channel == slot.channel
        sel &= ~claimed
        claimed |= sel
        idx = np.flatnonzero(sel)
        parts.append((slot, _decode_slot(slot, frames, idx, cmap.j1939,
                                         cmap.max_counter_delta, acct)))
    acct.reject("other_channel", int(np.count_nonzero(is_known & ~claimed)))
    tol = cmap.time_tolerance_s if cmap.time_tolerance_s is not None else 0.4 / sample_rate_hz
    return assemble_samples(parts, cmap.n, by_counter=cmap.uses_sample_counter,
                            tolerance_s=tol, acct=acct)
