"""From raw CAN frames to sensor samples: match, check, decode (vectorised), assemble.

Pipeline (:func:`decode_frames`, :class:`BlockDecoder`), every frame ends in exactly one
bucket of the :class:`~replay.accounting.FrameAccounting`:

1. error / remote frames, non-finite timestamps are rejected;
2. each frame is matched to a *slot* (:mod:`replay.slots`): one DBC message (for J1939: its
   PGN and the sensor's source address) on one bus channel, carrying the values of one or
   more sensors; no match is ``unknown_id`` (or ``other_channel``);
3. per slot, in vectorised numpy (:mod:`replay.slot_checks`): length, CRC-8 SAE J1850,
   timestamp order, rolling counter, status, then the signal values (J1939 raw values
   ≥ 0xFB00 for 16-bit signals, ≥ 0xFB for 8-bit, are 'error'/'not available': the value
   is missing, never scaled);
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
accounting. The :class:`~replay.aux_hold.AuxHold` gives every handed over sample the
latest value of each auxiliary column (``Samples.aux``, in °C or m/s²).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace

import cantools
import numpy as np

from replay.accounting import FrameAccounting
from replay.aux_hold import AuxHold
from replay.channel_map import ChannelMap
from replay.raw_frames import FRAME_DATA, FRAME_ERROR, FRAME_REMOTE, RawFrames
from replay.slot_checks import SlotFrames, SlotState, decode_slot
from replay.slots import build_aux_slots, build_slots, frame_keys, sibling_keys

__all__ = ["TIME_TOLERANCE_PERIODS", "BlockDecoder", "Samples", "decode_frames"]

TIME_TOLERANCE_PERIODS = 0.4
"""Default assembly tolerance of time assembly, in sample periods (a map's
``time_tolerance_s`` overrides it): frames closer than this belong to one sample."""
_ANY_FORWARD_STEP = 1 << 30
"""``max_counter_delta`` of the auxiliary slots: any forward step of a rolling counter is
accepted (auxiliary rates are not the sample rate); a repeat is rejected."""


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
        Nominal sample rate (default assembly tolerance :data:`TIME_TOLERANCE_PERIODS`; gap
        counting).
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
        self._aux_state = [SlotState() for _ in self.aux_slots]
        self.aux_acct = FrameAccounting()
        """Checks of the auxiliary frames (their rejections are also in ``acct``; their
        ``lost_frames`` and ``values_not_available`` only here)."""
        self.by_counter = cmap.uses_sample_counter
        self.tol = (cmap.time_tolerance_s if cmap.time_tolerance_s is not None
                    else TIME_TOLERANCE_PERIODS / self.fs)
        self._known = np.array(sorted({s.key for s in self.slots}), np.int64)
        self._siblings = sibling_keys(db, self.slots, cmap.j1939)
        self.siblings_seen: set[str] = set()
        """DBC messages like the mapped ones (same name but for digits: ``RIMU_GYRO_05``
        beside ``RIMU_GYRO_01``..``04``) that the log carries but the map does not use:
        a sign that the log has more sensors than the calibration."""
        self.delivered = np.zeros(len(self.slots), np.int64)
        """Frames each slot delivered past the checks."""
        self._state = [SlotState() for _ in self.slots]
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

    def _match_and_check(self, frames: RawFrames) -> list[SlotFrames]:
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
            parts.append(decode_slot(slot, frames, np.flatnonzero(sel), cmap.j1939,
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
            p = decode_slot(slot, frames, np.flatnonzero(sel), self.cmap.j1939,
                            _ANY_FORWARD_STEP, sub, self._aux_state[k], self.fs,
                            keep_unavailable=True)
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
        hold = self.hold
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
        Nominal sample rate (sets the default assembly tolerance,
        :data:`TIME_TOLERANCE_PERIODS`).

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
