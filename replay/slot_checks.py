"""The checks of one slot's frames, and the decoding of the values that pass them.

:func:`decode_slot` takes the frames matched to one slot (:mod:`replay.slots`) through,
in this order and vectorised: payload length, CRC-8 SAE J1850 (the last byte), timestamp
order, rolling counter and sample counter (:func:`counter_check`), status; then decodes the
slot's signals (J1939 'error' / 'not available' raw values, :func:`j1939_not_available`,
are missing, never scaled). Every frame that fails a check is counted rejected with its
reason in the :class:`~replay.accounting.FrameAccounting`; what a check carries from one
block of frames to the next is a :class:`SlotState`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from replay.accounting import FrameAccounting
from replay.crc import crc8_j1850_block
from replay.raw_frames import RawFrames
from replay.slots import Slot

__all__ = ["SlotFrames", "SlotState", "counter_check", "decode_slot", "j1939_not_available"]


def j1939_not_available(raw: np.ndarray, length: int) -> np.ndarray:
    """J1939 'error' / 'not available' raw values (SAE J1939-71 ranges).

    8-bit: ≥ 0xFB; 16-bit: ≥ 0xFB00; 32-bit: ≥ 0xFB000000 (generally ≥ 0xFB·2^(len−8)).
    Fields shorter than 8 bits are not checked here.
    """
    if length < 8:
        return np.zeros(raw.shape, bool)
    return np.asarray(raw, np.int64) >= (0xFB << (length - 8))


@dataclass
class SlotFrames:
    """One slot's frames past the checks, decoded (K frames, m values each)."""

    idx: np.ndarray          # global frame indices (file order)
    t: np.ndarray
    sample_counter: np.ndarray | None
    values: np.ndarray       # (K, m)
    valid: np.ndarray        # (K, m)


@dataclass
class SlotState:
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


def counter_check(slot: Slot, st: SlotState, t: np.ndarray, le: np.ndarray, be: np.ndarray,
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


def decode_slot(slot: Slot, frames: RawFrames, idx: np.ndarray, j1939: bool,
                max_counter_delta: int, acct: FrameAccounting, st: SlotState, fs: float,
                keep_unavailable: bool = False) -> SlotFrames:
    """Checks and decoding of one slot's frames ``idx`` (file order).

    ``st`` is updated; ``fs`` (Hz) converts time gaps to samples (:func:`counter_check`).
    ``keep_unavailable``: J1939 frames whose every value is 'not available' are counted as
    rejected but still returned (all values NaN, ``valid`` False), so that an auxiliary
    hold ends there.
    """
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
    keep = counter_check(slot, st, t, le, be, max_counter_delta, fs, acct)
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
    return SlotFrames(idx=idx, t=t, sample_counter=sc, values=values, valid=valid)

