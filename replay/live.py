"""Live monitoring on a CAN bus: frame-by-frame decoding and assembly, ``Monitor.step`` per sample.

:class:`StreamDecoder` applies the same checks and assembly rules as the offline block
decoder (:mod:`replay.assemble`), one frame at a time, so that a log played onto a bus in
time order gives the same samples (and the monitor the same events) as the offline replay:

- per slot: length, CRC, timestamp order (against the latest good frame), rolling counter
  (against the previous frame that reached the counter check), status, J1939 'not available';
- assembly by sample counter (unwrapped against the last accepted frame) or, without one,
  by time (a frame more than the tolerance after the previous accepted frame opens a new
  sample); a slot seen twice in a pending sample is a ``duplicate``, a frame for a sample
  already handed to the monitor is ``late``.

A pending sample is handed over as soon as every slot has delivered, or when a frame of a
later sample index (time assembly: a frame after the gap) shows it can no longer grow; at the
end (:meth:`StreamDecoder.flush`) whatever is pending is handed over in order.

:func:`run_live` reads a ``can.BusABC`` until Ctrl-C, a duration, a frame count or an idle
timeout, prints events as they happen and returns the answers as a
:class:`~fdi.answer.BlockResult` plus the frame accounting.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import can
import cantools
import numpy as np

from fdi.answer import Answer, BlockResult, Event
from replay.accounting import FrameAccounting
from replay.assemble import Slot, build_slots, frame_keys, j1939_not_available
from replay.channel_map import ChannelMap
from replay.crc import crc8_j1850
from replay.logio import _norm_channel

__all__ = ["StreamDecoder", "block_from_answers", "format_event", "run_live"]


def block_from_answers(answers: Sequence[Answer], n: int, K: int) -> BlockResult:
    """Stack per-sample answers into a :class:`~fdi.answer.BlockResult`."""
    N = len(answers)
    if N == 0:
        return BlockResult(t=np.zeros(0), omega=np.zeros((0, 3)), omega_sd=np.zeros((0, 3)),
                           healthy=np.zeros((0, n), bool), statistics=np.zeros((0, K)),
                           thresholds=np.zeros((0, K)), protection_level=np.zeros(0),
                           capability=np.zeros(0, dtype="<U11"), events=[],
                           parity=np.zeros((0, max(n - 3, 1))))
    return BlockResult(
        t=np.array([a.t for a in answers], float),
        omega=np.array([a.omega for a in answers], float),
        omega_sd=np.array([a.omega_sd for a in answers], float),
        healthy=np.array([a.healthy for a in answers], bool),
        statistics=np.array([a.statistics for a in answers], float),
        thresholds=np.array([a.thresholds for a in answers], float),
        protection_level=np.array([a.protection_level for a in answers], float),
        capability=np.array([a.capability for a in answers]),
        events=[e for a in answers for e in a.events],
        parity=np.array([a.parity for a in answers], float))


def format_event(e: Event, names: Sequence[str] = ()) -> str:
    """One line for an event as it happens."""
    who = "-" if e.sensor is None else str(e.sensor)
    if e.sensor is not None and 1 <= e.sensor <= len(names):
        who += f" ({names[e.sensor - 1]})"
    st = ""
    if e.statistic is not None and math.isfinite(e.statistic):
        st = f"  {e.statistic:.4g} > {e.threshold:.4g}"
    return f"t={e.t:.3f} s  sensor {who:<8} {e.type:<10} {e.reason}{st}"


@dataclass
class _SlotState:
    max_t: float = -math.inf
    last_counter: int | None = None


@dataclass
class _Pending:
    index: int
    t: float
    raw: np.ndarray
    valid: np.ndarray
    slots: set[int] = field(default_factory=set)


class StreamDecoder:
    """Frame-by-frame decoder and sample assembler (see the module docstring).

    Parameters
    ----------
    db : cantools Database
    cmap : ChannelMap
    sample_rate_hz : float
        For the default time tolerance (0.4 sample periods).
    """

    def __init__(self, db: cantools.database.can.Database, cmap: ChannelMap,
                 sample_rate_hz: float) -> None:
        self.cmap = cmap
        self.slots: list[Slot] = build_slots(db, cmap)
        self.n = cmap.n
        self.acct = FrameAccounting()
        self._by_key: dict[int, list[int]] = {}
        for k, s in enumerate(self.slots):
            self._by_key.setdefault(s.key, []).append(k)
        self._state = [_SlotState() for _ in self.slots]
        self.by_counter = cmap.uses_sample_counter
        self.tol = (cmap.time_tolerance_s if cmap.time_tolerance_s is not None
                    else 0.4 / sample_rate_hz)
        self._pending: list[_Pending] = []
        self._emitted_upto: int | None = None
        self._last_c: int | None = None
        self._last_u = 0
        self._last_t: float | None = None
        self._cluster = -1
        self.t_first: float | None = None

    # -- per frame ---------------------------------------------------------------------
    def feed(self, msg: can.Message) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """Process one frame; returns the samples ``(t, raw, valid)`` now complete."""
        a = self.acct
        a.read += 1
        if msg.is_error_frame:
            a.reject("error_frame")
            return []
        if msg.is_remote_frame:
            a.reject("remote_frame")
            return []
        t = float(msg.timestamp)
        if not math.isfinite(t):
            a.reject("nonfinite_time")
            return []
        if self.t_first is None:
            self.t_first = t
        key = int(frame_keys(np.array([msg.arbitration_id], np.int64),
                             np.array([msg.is_extended_id]), self.cmap.j1939)[0])
        cands = self._by_key.get(key)
        if not cands:
            a.reject("unknown_id")
            return []
        ch = _norm_channel(msg.channel)
        k = next((j for j in cands if self.slots[j].channel is None
                  or self.slots[j].channel == ch), None)
        if k is None:
            a.reject("other_channel")
            return []
        return self._slot_frame(k, t, bytes(msg.data))

    def _slot_frame(self, k: int, t: float, data: bytes
                    ) -> list[tuple[float, np.ndarray, np.ndarray]]:
        a = self.acct
        slot = self.slots[k]
        st = self._state[k]
        lay = slot.layout
        if len(data) != lay.length:
            a.reject("wrong_length")
            return []
        if slot.crc is not None and crc8_j1850(data[:-1]) != data[-1]:
            a.reject("crc")
            return []
        if t < st.max_t:
            a.reject("out_of_order")
            return []
        st.max_t = t
        le, be = lay.words(np.frombuffer(data, np.uint8).reshape(1, -1))
        if slot.counter is not None:
            cs = lay.signals[slot.counter]
            c = int(cs.raw(le, be)[0])
            prev, st.last_counter = st.last_counter, c
            if prev is not None:
                d = (c - prev) % (1 << cs.length)
                if d == 0:
                    a.reject("counter_repeat")
                    return []
                if d > self.cmap.max_counter_delta:
                    a.reject("counter_jump")
                    return []
                a.lost_frames += d - 1
        if slot.status is not None and int(lay.signals[slot.status].raw(le, be)[0]) != 0:
            a.reject("status")
            return []
        vals = np.full(len(slot.sensors), np.nan)
        ok = np.ones(len(slot.sensors), bool)
        for j, name in enumerate(slot.signals):
            s = lay.signals[name]
            r = s.raw(le, be)
            if self.cmap.j1939 and not s.is_float and j1939_not_available(r, s.length)[0]:
                ok[j] = False
                continue
            vals[j] = s.physical(r)[0]
        if self.cmap.j1939:
            if not ok.any():
                a.reject("j1939_not_available")
                return []
            a.values_not_available += int(np.count_nonzero(~ok))
        return self._assemble(k, t, vals, ok, le, be)

    def _assemble(self, k: int, t: float, vals: np.ndarray, ok: np.ndarray,
                  le: np.ndarray, be: np.ndarray) -> list[tuple[float, np.ndarray, np.ndarray]]:
        slot = self.slots[k]
        out: list[tuple[float, np.ndarray, np.ndarray]] = []
        if self.by_counter:
            c = int(slot.layout.signals[slot.sample_counter].raw(le, be)[0])
            if self._last_c is None:
                u = 0
            else:
                d = (c - self._last_c + 32768) % 65536 - 32768
                u = self._last_u + d
            self._last_c, self._last_u = c, u
            # a later sample index closes the pending samples before u - 1
            out += self._emit(lambda p: p.index < u - 1)
        else:
            if self._last_t is None or t - self._last_t > self.tol:
                out += self._emit(lambda p: True)
                self._cluster += 1
            self._last_t = t
            u = self._cluster
        if self._emitted_upto is not None and u <= self._emitted_upto:
            self.acct.reject("late")
            return out
        p = next((q for q in self._pending if q.index == u), None)
        if p is None:
            p = _Pending(u, t, np.full(self.n, np.nan), np.zeros(self.n, bool))
            self._pending.append(p)
            self._pending.sort(key=lambda q: q.index)
        if k in p.slots:
            self.acct.reject("duplicate")
            return out
        p.slots.add(k)
        p.t = min(p.t, t)
        for j, sensor in enumerate(slot.sensors):
            p.raw[sensor] = vals[j]
            p.valid[sensor] = ok[j]
        self.acct.used += 1
        # hand over complete samples at the head of the queue
        while self._pending and len(self._pending[0].slots) == len(self.slots):
            out += self._pop()
        return out

    def _pop(self) -> list[tuple[float, np.ndarray, np.ndarray]]:
        p = self._pending.pop(0)
        self._emitted_upto = p.index
        return [(p.t, p.raw, p.valid)]

    def _emit(self, cond: Callable[[_Pending], bool]
              ) -> list[tuple[float, np.ndarray, np.ndarray]]:
        out = []
        while self._pending and cond(self._pending[0]):
            out += self._pop()
        return out

    def flush(self) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """Hand over every pending sample (end of stream)."""
        return self._emit(lambda p: True)


def run_live(bus: can.BusABC, decoder: StreamDecoder, monitor: Any, *,
             duration_s: float | None = None, max_frames: int | None = None,
             idle_timeout_s: float | None = None, t_start: float = 0.0,
             on_event: Callable[[Event], None] | None = None,
             poll_s: float = 0.05) -> tuple[BlockResult, dict[str, Any]]:
    """Monitor a live bus until Ctrl-C, ``duration_s``, ``max_frames`` or ``idle_timeout_s``.

    Sample time = frame time − the first frame's time + ``t_start`` (as the offline replay).

    Returns
    -------
    result : BlockResult
        The answers so far (also after Ctrl-C).
    frames : dict
        Frame accounting (:meth:`~replay.accounting.FrameAccounting.to_dict`).
    """
    answers: list[Answer] = []
    t0 = time.monotonic()
    last_rx = t0

    def consume(samples: list[tuple[float, np.ndarray, np.ndarray]]) -> None:
        for t, raw, valid in samples:
            ans = monitor.step(t - decoder.t_first + t_start, raw, valid)
            answers.append(ans)
            if on_event is not None:
                for e in ans.events:
                    on_event(e)

    try:
        while True:
            now = time.monotonic()
            if duration_s is not None and now - t0 >= duration_s:
                break
            if max_frames is not None and decoder.acct.read >= max_frames:
                break
            if idle_timeout_s is not None and now - last_rx >= idle_timeout_s:
                break
            msg = bus.recv(timeout=poll_s)
            if msg is None:
                continue
            last_rx = time.monotonic()
            consume(decoder.feed(msg))
    except KeyboardInterrupt:
        pass
    consume(decoder.flush())
    K = len(answers[0].statistics) if answers else 0
    return block_from_answers(answers, decoder.n, K), decoder.acct.to_dict()
