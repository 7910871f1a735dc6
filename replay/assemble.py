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

Auxiliary channels of the map (temperature, specific force: the effect terms' inputs,
:class:`~replay.channel_map.AuxChannel`) are decoded beside, with the same frame checks
(length, CRC, order, rolling counter: a repeat is rejected, any forward step accepted,
status, J1939 'not available'), but they take no part in the assembly: their frames never
hold a sample back, and their losses are counted apart (:attr:`BlockDecoder.aux_stats`,
not in ``lost_frames``/``lost_samples``). Each frame still ends used or rejected in the
accounting. :class:`AuxHold` keeps each auxiliary column's history and gives every handed
over sample the latest value not later than its time (``Samples.aux``, in °C or m/s²),
NaN before the first value and once the latest is older than the entry's ``timeout_s``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, replace

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
    "AuxHold",
    "BlockDecoder",
    "RawFrames",
    "Samples",
    "Slot",
    "assemble_samples",
    "aux_columns",
    "build_aux_slots",
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


def _checked_layout(msg: cantools.database.can.Message, crc_signal: str | None,
                    source: object) -> MessageLayout:
    """The message's layout, checked for the block decoder: a CRC signal is the last byte,
    payloads are at most 8 bytes and not multiplexed."""
    lay = message_layout(msg)
    if crc_signal is not None:
        cs = lay.signals[crc_signal]
        if cs.length != 8 or cs.big_endian or cs.shift != 8 * (msg.length - 1):
            raise ConfigError(f"channel map {source}: CRC signal {crc_signal} of "
                              f"{msg.name} must be the last byte")
    if not lay.vectorisable:
        raise ConfigError(f"message {msg.name}: payloads over 8 bytes or multiplexed "
                          "messages are not supported by the block decoder")
    return lay


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
        lay = _checked_layout(msg, first.crc_signal, cmap.source)
        slots.append(Slot(key=key, channel=ch, layout=lay, sensors=tuple(idx),
                          signals=tuple(cmap.sensors[i].signal for i in idx),
                          counter=checks[0], crc=checks[1], sample_counter=checks[2],
                          status=checks[3], message=msg))
    return slots


def aux_columns(cmap: ChannelMap) -> list[tuple[int, int]]:
    """The auxiliary columns: (entry, signal) indices, entry by entry, in signal order."""
    return [(k, j) for k, a in enumerate(cmap.auxiliary) for j in range(len(a.signals))]


def build_aux_slots(db: cantools.database.can.Database, cmap: ChannelMap,
                    taken: set[int] | None = None) -> list[Slot]:
    """Group the auxiliary columns into slots (one per message, source address, channel).

    A slot's ``sensors`` are the column numbers (:func:`aux_columns`); it has no sample
    counter.

    Raises
    ------
    ConfigError
        A message or signal not in the DBC, entries of one message naming different check
        signals, or a message a monitored sensor already uses (``taken``).
    """
    groups: dict[tuple[int, object], list[int]] = {}
    msgs: dict[tuple[int, object], cantools.database.can.Message] = {}
    cols = aux_columns(cmap)
    for c, (k, j) in enumerate(cols):
        a = cmap.auxiliary[k]
        where = f"channel map {cmap.source}: auxiliary {k + 1} ({a.name})"
        try:
            msg = db.get_message_by_name(a.message)
        except KeyError:
            raise ConfigError(f"{where}: message {a.message!r} is not in the DBC") from None
        names = {sg.name for sg in msg.signals}
        for what in (a.signals[j], a.counter_signal, a.crc_signal, a.status_signal):
            if what is not None and what not in names:
                raise ConfigError(f"{where}: signal {what!r} is not in message {a.message}")
        key = (_message_key(msg, a.source_address, cmap.j1939), a.channel)
        if taken and key[0] in taken:
            raise ConfigError(f"{where}: message {a.message} also carries monitored sensors; "
                              "an auxiliary channel needs a message of its own")
        groups.setdefault(key, []).append(c)
        msgs[key] = msg
    slots = []
    for (key, ch), idx in groups.items():
        entries = [cmap.auxiliary[cols[c][0]] for c in idx]
        checks = (entries[0].counter_signal, entries[0].crc_signal, entries[0].status_signal)
        for a in entries[1:]:
            if (a.counter_signal, a.crc_signal, a.status_signal) != checks:
                raise ConfigError(f"channel map {cmap.source}: auxiliary channels "
                                  f"{entries[0].name} and {a.name} share message {a.message} "
                                  "but name different counter/CRC/status signals")
        msg = msgs[(key, ch)]
        lay = _checked_layout(msg, checks[1], cmap.source)
        slots.append(Slot(key=key, channel=ch, layout=lay, sensors=tuple(idx),
                          signals=tuple(cmap.auxiliary[cols[c][0]].signals[cols[c][1]]
                                        for c in idx),
                          counter=checks[0], crc=checks[1], sample_counter=None,
                          status=checks[2], message=msg))
    return slots


class AuxHold:
    """Sample-and-hold of the auxiliary columns onto sample times.

    Each column keeps its decoded values (converted to °C or m/s² along the signal's axis)
    with their frame times, in time order; :meth:`at` gives, for each sample time, the latest
    value not later than it, NaN before the first value and when that value is older than
    the column's ``timeout_s`` (stale). A J1939 'not available' value is held as NaN.

    Parameters
    ----------
    cmap : ChannelMap
    keep_s : float
        History kept before the latest sample handed over (:meth:`trim`).
    """

    def __init__(self, cmap: ChannelMap, keep_s: float = 1.0) -> None:
        self.columns = aux_columns(cmap)
        self.m = len(self.columns)
        aux = cmap.auxiliary
        self.timeout_s = np.array([aux[k].timeout_s for k, _ in self.columns], float)
        conv = [aux[k].to_si for k, _ in self.columns]
        self.factor = np.array([f for f, _ in conv], float)
        self.offset = np.array([o for _, o in conv], float)
        self.keep_s = float(max(keep_s, float(self.timeout_s.max()) if self.m else 0.0))
        self._t = [np.zeros(0) for _ in range(self.m)]
        self._v = [np.zeros(0) for _ in range(self.m)]
        self.received = np.zeros(self.m, np.int64)
        """Values received per column (finite or not)."""

    def add(self, col: int, t: np.ndarray, value: np.ndarray) -> None:
        """Append decoded values (decoded unit) of column ``col`` at times ``t`` (ascending,
        not earlier than the column's last)."""
        if t.size == 0:
            return
        v = np.asarray(value, float) * self.factor[col] + self.offset[col]
        self._t[col] = np.concatenate([self._t[col], np.asarray(t, float)])
        self._v[col] = np.concatenate([self._v[col], v])
        self.received[col] += t.size

    def at(self, ts: np.ndarray) -> np.ndarray:
        """Held values at sample times ``ts``, shape (S, m): °C or m/s², NaN where none."""
        ts = np.asarray(ts, float)
        out = np.full((ts.size, self.m), np.nan)
        for c in range(self.m):
            tc = self._t[c]
            if tc.size == 0:
                continue
            k = np.searchsorted(tc, ts, side="right") - 1
            has = k >= 0
            kk = np.where(has, k, 0)
            fresh = has & (ts - tc[kk] <= self.timeout_s[c])
            out[:, c] = np.where(fresh, self._v[c][kk], np.nan)
        return out

    def trim(self, t_done: float) -> None:
        """Forget values older than ``keep_s`` before ``t_done`` (keeping the one held)."""
        for c in range(self.m):
            tc = self._t[c]
            k = int(np.searchsorted(tc, t_done - self.keep_s, side="right")) - 1
            if k > 0:
                self._t[c], self._v[c] = tc[k:], self._v[c][k:]


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


@dataclass
class _SlotState:
    """What one slot's checks carry from one block of frames to the next."""

    max_t: float = -np.inf           # latest time of a frame past the length/CRC checks
    counter: int | None = None       # rolling counter of the last frame past the order check
    sample: int | None = None        # its sample counter
    t: float | None = None           # its time


def _with_prev(prev: float | int | None, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x`` shifted by one with ``prev`` in front, and where that predecessor exists."""
    has = np.ones(x.size, bool)
    out = np.empty(x.size, np.float64 if x.dtype.kind == "f" else np.int64)
    if x.size:
        out[1:] = x[:-1]
        if prev is None:
            has[0] = False
            out[0] = x[0]
        else:
            out[0] = prev
    return out, has


def _counter_check(slot: Slot, st: _SlotState, t: np.ndarray, le: np.ndarray, be: np.ndarray,
                   max_counter_delta: int, fs: float, acct: FrameAccounting) -> np.ndarray:
    """Rolling-counter and sample-counter check of frames past the order check.

    A frame whose rolling counter advanced by d is accepted when d ≤ ``max_counter_delta``
    (d − 1 frames lost), or when a larger d agrees, modulo the rolling counter's range, with
    how far the sample counter advanced (without one: with the time elapsed, in sample
    periods) — a gap longer than the counter's range — and that advance minus one is lost
    (``lost_frames``). The first frame after a gap is used,
    not discarded. A counter that did not move is ``counter_repeat``; one that disagrees is
    ``counter_jump`` (a corrupt or foreign frame). Returns the mask of accepted frames.
    """
    lay = slot.layout
    sc = (lay.signals[slot.sample_counter].raw(le, be).astype(np.int64)
          if slot.sample_counter is not None else None)
    keep = np.ones(t.size, bool)
    if t.size == 0:
        return keep
    if sc is not None:
        s_prev, has_s = _with_prev(st.sample, sc)
        ds = (sc - s_prev) % 65536
    if slot.counter is not None:
        cs = lay.signals[slot.counter]
        mod = 1 << cs.length
        c = cs.raw(le, be).astype(np.int64)
        c_prev, has = _with_prev(st.counter, c)
        d = (c - c_prev) % mod
        small = (d >= 1) & (d <= max_counter_delta)
        if sc is not None:
            n_est = ds
            agree = (ds >= 1) & (ds < 32768) & ((ds - d) % mod == 0)
        else:
            t_prev, _ = _with_prev(st.t, t)
            n_est = np.rint((t - t_prev) * fs).astype(np.int64)
            agree = (n_est >= 1) & ((n_est - d) % mod == 0)
        ok = small | ((d >= 1) & agree)
        gap = np.where(small, d, n_est) - 1
        repeat = has & (d == 0)
        jump = has & ~ok & ~repeat
        acct.reject("counter_repeat", int(np.count_nonzero(repeat)))
        acct.reject("counter_jump", int(np.count_nonzero(jump)))
        acct.lost_frames += int(np.sum(gap[has & ok]))
        keep = ~(repeat | jump)
        st.counter = int(c[-1])
    elif sc is not None:
        fwd = has_s & (ds >= 1) & (ds < 32768)
        acct.lost_frames += int(np.sum(ds[fwd] - 1))
    if sc is not None:
        st.sample = int(sc[-1])
    st.t = float(t[-1])
    return keep


def _decode_slot(slot: Slot, frames: RawFrames, idx: np.ndarray, j1939: bool,
                 max_counter_delta: int, acct: FrameAccounting,
                 st: _SlotState | None = None, fs: float = 100.0,
                 keep_unavailable: bool = False) -> _SlotFrames:
    """Checks and decoding of one slot's frames. ``keep_unavailable``: J1939 frames whose
    every value is 'not available' are counted as rejected but still returned (all values
    NaN, ``valid`` False), so that an auxiliary hold ends there."""
    st = st if st is not None else _SlotState()
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
    if idx.size:
        prev_max = np.maximum.accumulate(np.concatenate([[st.max_t], t]))[:-1]
        ooo = t < prev_max
        st.max_t = float(max(st.max_t, t.max()))
        if ooo.any():
            acct.reject("out_of_order", int(np.count_nonzero(ooo)))
            keep = ~ooo
            idx, block, t = idx[keep], block[keep], t[keep]
    le, be = lay.words(block)
    keep = _counter_check(slot, st, t, le, be, max_counter_delta, fs, acct)
    if not keep.all():
        idx, t, le, be = idx[keep], t[keep], le[keep], be[keep]
    if slot.status is not None and idx.size:
        stt = lay.signals[slot.status].raw(le, be)
        good = stt == 0
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
        if not keep_unavailable:
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
    aux : ndarray, shape (S, m) or None
        The map's auxiliary columns (:func:`aux_columns`) held onto the samples
        (:class:`AuxHold`: °C or m/s² along the signal's axis; NaN where none or stale);
        None when the map has no auxiliary channel.
    """

    t: np.ndarray
    raw: np.ndarray
    valid: np.ndarray
    sample_index: np.ndarray
    aux: np.ndarray | None = None

    @classmethod
    def empty(cls, n: int, m_aux: int | None = None) -> Samples:
        """No sample, ``n`` sensors (``m_aux`` auxiliary columns; None: no aux)."""
        return cls(np.zeros(0), np.zeros((0, n)), np.zeros((0, n), bool),
                   np.zeros(0, np.int64), None if m_aux is None else np.zeros((0, m_aux)))

    @classmethod
    def concat(cls, parts: list[Samples], n: int) -> Samples:
        """Samples of several blocks, in order."""
        m_aux = next((p.aux.shape[1] for p in parts if p.aux is not None), None)
        parts = [p for p in parts if p.t.size]
        if not parts:
            return cls.empty(n, m_aux)
        if len(parts) == 1:
            return parts[0]
        return cls(np.concatenate([p.t for p in parts]),
                   np.concatenate([p.raw for p in parts]),
                   np.concatenate([p.valid for p in parts]),
                   np.concatenate([p.sample_index for p in parts]),
                   None if parts[0].aux is None else np.concatenate([p.aux for p in parts]))


@dataclass
class _Rows:
    """Decoded frames waiting for their sample to be complete (time order)."""

    t: np.ndarray
    slot: np.ndarray         # slot number
    cluster: np.ndarray      # sample index
    values: np.ndarray       # (R, m_max)
    valid: np.ndarray        # (R, m_max)

    @classmethod
    def empty(cls, m: int) -> _Rows:
        return cls(np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64),
                   np.zeros((0, m)), np.zeros((0, m), bool))

    def take(self, sel: np.ndarray) -> _Rows:
        return _Rows(self.t[sel], self.slot[sel], self.cluster[sel], self.values[sel],
                     self.valid[sel])

    @classmethod
    def cat(cls, a: _Rows, b: _Rows) -> _Rows:
        if a.t.size == 0:
            return b
        if b.t.size == 0:
            return a
        return cls(np.concatenate([a.t, b.t]), np.concatenate([a.slot, b.slot]),
                   np.concatenate([a.cluster, b.cluster]),
                   np.concatenate([a.values, b.values]), np.concatenate([a.valid, b.valid]))


def _sibling_keys(db: cantools.database.can.Database, slots: list[Slot],
                  j1939: bool) -> dict[int, str]:
    """Frame keys of the DBC messages named like a mapped one but for digits."""
    import re

    if j1939:
        return {}
    shape = {re.sub(r"\d+", "#", s.message.name) for s in slots}
    used = {s.message.name for s in slots}
    out = {}
    for m in db.messages:
        if m.name not in used and re.sub(r"\d+", "#", m.name) in shape:
            out[_message_key(m, None, False)] = m.name
    return out


class BlockDecoder:
    """Vectorised decoding of a stream of frame blocks, with state carried between blocks.

    Each :meth:`feed` takes the next block of frames (in file order) and returns the samples
    that are complete; :meth:`flush` returns the rest at the end. The per-slot checks
    (order, counters) compare each block's first frame with the previous block's last, and
    the assembly continues the sample numbering, so that any split of a log into blocks
    gives the samples and the accounting of one block holding the whole log, as long as
    no frame arrives after two later samples have been seen (such a frame is ``late``).

    A sample is handed over when every slot has delivered, or when a frame of a sample two
    indices on (time assembly: any later sample) shows it cannot grow any more.

    Lost samples (``FrameAccounting.lost_samples``): gaps in the sample-counter sequence of
    the samples handed over (time assembly: gaps of more than one sample period).

    Parameters
    ----------
    db : cantools Database
    cmap : ChannelMap
    acct : FrameAccounting, optional
        Updated in place (``read`` grows with every frame fed; ``used`` as samples are
        handed over, so that ``balanced()`` holds after :meth:`flush`).
    sample_rate_hz : float
        Nominal sample rate (default assembly tolerance 0.4 periods; gap counting).
    """

    def __init__(self, db: cantools.database.can.Database, cmap: ChannelMap,
                 acct: FrameAccounting | None = None, *, sample_rate_hz: float) -> None:
        self.cmap = cmap
        self.n = cmap.n
        self.acct = acct if acct is not None else FrameAccounting()
        self.fs = float(sample_rate_hz)
        self.slots = build_slots(db, cmap)
        self.aux_slots = build_aux_slots(db, cmap, {sl.key for sl in self.slots})
        self.hold = AuxHold(cmap) if cmap.auxiliary else None
        self._aux_known = np.array(sorted({s.key for s in self.aux_slots}), np.int64)
        self._aux_state = [_SlotState() for _ in self.aux_slots]
        self.aux_acct = FrameAccounting()
        """Checks of the auxiliary frames (their rejections are also in ``acct``; their
        ``lost_frames`` and ``values_not_available`` only here)."""
        self.by_counter = cmap.uses_sample_counter
        self.tol = (cmap.time_tolerance_s if cmap.time_tolerance_s is not None
                    else 0.4 / self.fs)
        self._known = np.array(sorted({s.key for s in self.slots}), np.int64)
        self._siblings = _sibling_keys(db, self.slots, cmap.j1939)
        self.siblings_seen: set[str] = set()
        """DBC messages like the mapped ones (same name but for digits: ``RIMU_GYRO_05``
        beside ``RIMU_GYRO_01``..``04``) that the log carries but the map does not use:
        a sign that the log has more sensors than the calibration."""
        self.delivered = np.zeros(len(self.slots), np.int64)
        """Frames each slot delivered past the checks."""
        self._state = [_SlotState() for _ in self.slots]
        self._m = max((len(s.sensors) for s in self.slots), default=1)
        self._pending = _Rows.empty(self._m)
        self._last_c: int | None = None
        self._last_u = 0
        self._last_t: float | None = None
        self._cluster = -1
        self._emitted: int | None = None
        self._emitted_t: float | None = None
        self.t_first: float | None = None
        """Earliest finite data-frame time of the first block with one (log clock)."""

    @property
    def pending_frames(self) -> int:
        """Frames decoded but not yet handed over in a sample."""
        return int(self._pending.t.size)

    def feed(self, frames: RawFrames) -> Samples:
        """Decode the next block of frames; returns the samples now complete."""
        rows = self._decode(frames)
        return self._assemble(rows, final=False)

    def flush(self) -> Samples:
        """Hand over every pending sample (end of the stream)."""
        return self._assemble(_Rows.empty(self._m), final=True)

    # -- decoding --------------------------------------------------------------------
    def _decode(self, frames: RawFrames) -> _Rows:
        parts = self._match_and_check(frames)
        R = sum(p.idx.size for p in parts)
        if R == 0:
            return _Rows.empty(self._m)
        t = np.concatenate([p.t for p in parts])
        slot_of = np.concatenate([np.full(p.idx.size, k, np.int64)
                                  for k, p in enumerate(parts)])
        vals = np.full((R, self._m), np.nan)
        ok = np.zeros((R, self._m), bool)
        r = 0
        for p in parts:
            m = p.values.shape[1]
            vals[r:r + p.idx.size, :m] = p.values
            ok[r:r + p.idx.size, :m] = p.valid
            r += p.idx.size
        order = np.argsort(t, kind="stable")
        t, slot_of, vals, ok = t[order], slot_of[order], vals[order], ok[order]
        sc = (np.concatenate([p.sample_counter for p in parts])[order].astype(np.int64)
              if self.by_counter else None)
        rows = _Rows(t, slot_of, self._number(t, sc), vals, ok)
        if self._emitted is not None:
            late = rows.cluster <= self._emitted
            if late.any():
                self.acct.reject("late", int(np.count_nonzero(late)))
                rows = rows.take(~late)
        return rows

    def _match_and_check(self, frames: RawFrames) -> list[_SlotFrames]:
        """Frame-level rejections, matching to slots and the per-slot checks."""
        acct, cmap = self.acct, self.cmap
        M = len(frames)
        acct.read += M
        ft = frames.frame_type
        alive = ft == FRAME_DATA
        acct.reject("error_frame", int(np.count_nonzero(ft == FRAME_ERROR)))
        acct.reject("remote_frame", int(np.count_nonzero(ft == FRAME_REMOTE)))
        bad_t = alive & ~np.isfinite(frames.t)
        acct.reject("nonfinite_time", int(np.count_nonzero(bad_t)))
        alive &= ~bad_t
        if self.t_first is None and alive.any():
            self.t_first = float(frames.t[alive].min())
        keys = frame_keys(frames.arbitration_id, frames.extended, cmap.j1939)
        is_known = alive & np.isin(keys, self._known)
        unknown = alive & ~is_known
        if self.aux_slots:
            is_aux = alive & ~is_known & np.isin(keys, self._aux_known)
            unknown &= ~is_aux
            self._decode_aux(frames, keys, is_aux)
        acct.reject("unknown_id", int(np.count_nonzero(unknown)))
        if self._siblings and unknown.any():
            self.siblings_seen.update(self._siblings[k] for k in np.unique(keys[unknown]).tolist()
                                      if k in self._siblings)
        claimed = np.zeros(M, bool)
        parts = []
        for k, slot in enumerate(self.slots):
            sel = is_known & (keys == slot.key) & ~claimed
            if slot.channel is not None:
                sel &= frames.channel == slot.channel
            claimed |= sel
            parts.append(_decode_slot(slot, frames, np.flatnonzero(sel), cmap.j1939,
                                      cmap.max_counter_delta, acct, self._state[k], self.fs))
        acct.reject("other_channel", int(np.count_nonzero(is_known & ~claimed)))
        self.delivered += np.array([p.idx.size for p in parts], np.int64)
        return parts

    def _decode_aux(self, frames: RawFrames, keys: np.ndarray, is_aux: np.ndarray) -> None:
        """Check and decode the auxiliary frames into :attr:`hold`; count each frame used
        or rejected in ``acct`` (losses and missing values in :attr:`aux_acct` only)."""
        sub = self.aux_acct
        before = Counter(sub.rejected)
        claimed = np.zeros(len(frames), bool)
        used = 0
        for k, slot in enumerate(self.aux_slots):
            sel = is_aux & (keys == slot.key) & ~claimed
            if slot.channel is not None:
                sel &= frames.channel == slot.channel
            claimed |= sel
            # any forward step of a rolling counter is accepted (auxiliary rates are not
            # the sample rate); a repeat is rejected
            p = _decode_slot(slot, frames, np.flatnonzero(sel), self.cmap.j1939, 1 << 30,
                             sub, self._aux_state[k], self.fs, keep_unavailable=True)
            used += int(np.count_nonzero(p.valid.any(axis=1)))    # the rest: rejected
            for j, col in enumerate(slot.sensors):
                self.hold.add(col, p.t, p.values[:, j])
        other = int(np.count_nonzero(is_aux & ~claimed))
        sub.reject("other_channel", other)
        sub.read += int(np.count_nonzero(is_aux))
        sub.used += used
        self.acct.used += used
        for reason, cnt in (sub.rejected - before).items():
            self.acct.reject(reason, cnt)

    @property
    def aux_stats(self) -> dict:
        """Auxiliary frames: read, used, rejected by reason, lost (rolling counters),
        values not available (J1939), values received per column."""
        d = self.aux_acct.to_dict()
        return {"read": d["read"], "used": d["used"], "rejected": d["rejected"],
                "lost_frames": d["lost_frames"],
                "values_not_available": d["values_not_available"],
                "received": [] if self.hold is None else self.hold.received.tolist()}

    def _number(self, t: np.ndarray, sc: np.ndarray | None) -> np.ndarray:
        """Sample index of each decoded frame (time order), continuing the numbering."""
        if sc is not None:
            prev = sc[0] if self._last_c is None else self._last_c
            d = np.diff(np.concatenate([[prev], sc]))
            d = (d + 32768) % 65536 - 32768
            cluster = self._last_u + np.cumsum(d)
            self._last_c, self._last_u = int(sc[-1]), int(cluster[-1])
        else:
            prev_t = -np.inf if self._last_t is None else self._last_t
            new = np.diff(np.concatenate([[prev_t], t])) > self.tol
            cluster = self._cluster + np.cumsum(new)
            self._last_t, self._cluster = float(t[-1]), int(cluster[-1])
        return cluster.astype(np.int64)

    # -- assembly --------------------------------------------------------------------
    def _assemble(self, rows: _Rows, *, final: bool) -> Samples:
        hold = getattr(self, "hold", None)
        m_aux = None if hold is None else hold.m
        allr = _Rows.cat(self._pending, rows)
        if allr.t.size == 0:
            self._pending = allr
            return Samples.empty(self.n, m_aux)
        ns = len(self.slots)
        # a slot twice in one sample: keep the earliest (pending rows come first)
        key = allr.cluster * ns + allr.slot
        o2 = np.argsort(key, kind="stable")
        ks = key[o2]
        dup = np.zeros(allr.t.size, bool)
        dup[o2[1:]] = ks[1:] == ks[:-1]
        if dup.any():
            self.acct.reject("duplicate", int(np.count_nonzero(dup)))
            allr = allr.take(~dup)
        ids, inv, counts = np.unique(allr.cluster, return_inverse=True, return_counts=True)
        if final:
            n_out = ids.size
        else:
            top = ids[-1]
            ready = (counts == ns) | (ids < (top - 1 if self.by_counter else top))
            n_out = int(np.argmin(ready)) if not ready.all() else ids.size
        out_sel = inv < n_out
        out = allr.take(out_sel)
        self._pending = allr.take(~out_sel)
        if n_out == 0:
            return Samples.empty(self.n, m_aux)
        inv_o = inv[out_sel]
        ids_o = ids[:n_out]
        ts = np.full(n_out, np.inf)
        np.minimum.at(ts, inv_o, out.t)
        raw = np.full((n_out, self.n), np.nan)
        valid = np.zeros((n_out, self.n), bool)
        for k, slot in enumerate(self.slots):
            sel = out.slot == k
            if not sel.any():
                continue
            rr = inv_o[sel]
            for j, sensor in enumerate(slot.sensors):
                raw[rr, sensor] = out.values[sel, j]
                valid[rr, sensor] = out.valid[sel, j]
        self.acct.used += int(out.t.size)
        self._count_lost(ids_o, ts)
        self._emitted, self._emitted_t = int(ids_o[-1]), float(ts[-1])
        aux = None
        if hold is not None:
            aux = hold.at(ts)
            hold.trim(float(ts.max()))
        return Samples(t=ts, raw=raw, valid=valid, sample_index=ids_o, aux=aux)

    def _count_lost(self, ids: np.ndarray, ts: np.ndarray) -> None:
        if self.by_counter:
            prev = ids[0] - 1 if self._emitted is None else self._emitted
            gaps = np.diff(np.concatenate([[prev], ids])) - 1
        else:
            prev = ts[0] if self._emitted_t is None else self._emitted_t
            gaps = np.rint(np.diff(np.concatenate([[prev], ts])) * self.fs) - 1
        self.acct.lost_samples += int(np.sum(np.clip(gaps, 0, None)))


def assemble_samples(parts: list[tuple[Slot, _SlotFrames]], n: int, *, by_counter: bool,
                     tolerance_s: float, acct: FrameAccounting) -> Samples:
    """Assemble decoded slot frames of a whole log into samples (one block, then flushed).

    Kept for callers of the one-block API; :class:`BlockDecoder` does the work.
    """
    if not parts or sum(p.idx.size for _, p in parts) == 0:
        return Samples.empty(n)
    t = np.concatenate([p.t for _, p in parts])
    slot_of = np.concatenate([np.full(p.idx.size, k, np.int64) for k, (_, p) in enumerate(parts)])
    m = max(p.values.shape[1] for _, p in parts)
    vals = np.full((t.size, m), np.nan)
    ok = np.zeros((t.size, m), bool)
    r = 0
    for _, p in parts:
        vals[r:r + p.idx.size, :p.values.shape[1]] = p.values
        ok[r:r + p.idx.size, :p.values.shape[1]] = p.valid
        r += p.idx.size
    order = np.argsort(t, kind="stable")
    t, slot_of, vals, ok = t[order], slot_of[order], vals[order], ok[order]
    if by_counter:
        c = np.concatenate([p.sample_counter for _, p in parts])[order].astype(np.int64)
        d = (np.diff(c) + 32768) % 65536 - 32768
        cluster = np.concatenate([[0], np.cumsum(d)])
    else:
        cluster = np.concatenate([[0], np.cumsum(np.diff(t) > tolerance_s)]).astype(np.int64)
    dec = BlockDecoder.__new__(BlockDecoder)
    dec.n, dec.acct, dec.by_counter, dec.fs = n, acct, by_counter, 1.0 / max(tolerance_s, 1e-12)
    dec.slots = [s for s, _ in parts]
    dec._m = m
    dec._pending = _Rows(t, slot_of, cluster - cluster.min(), vals, ok)
    dec._emitted = dec._emitted_t = None
    return dec._assemble(_Rows.empty(m), final=True)


def decode_frames(frames: RawFrames, db: cantools.database.can.Database, cmap: ChannelMap,
                  acct: FrameAccounting, *, sample_rate_hz: float) -> Samples:
    """Match, check, decode and assemble every frame of a whole log (one block).

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
        ``sample_index`` counted from 0.
    """
    dec = BlockDecoder(db, cmap, acct, sample_rate_hz=sample_rate_hz)
    s = Samples.concat([dec.feed(frames), dec.flush()], cmap.n)
    if s.sample_index.size:
        s = replace(s, sample_index=s.sample_index - s.sample_index.min())
    return s
