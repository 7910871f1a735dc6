"""Gathering python-can messages into :class:`~replay.raw_frames.RawFrames`, in one pass.

A reader's messages are appended to plain lists (:class:`FrameGather`), which become numpy
columns at the end or, with a sink, every ``chunk`` frames (bounded memory on long logs).
:func:`gather_messages` is the hot path every binary reader and the candump reader share.
"""

from __future__ import annotations

from collections.abc import Iterator
from itertools import islice
from typing import Any

import can
import numpy as np

from replay.raw_frames import FRAME_ERROR, FRAME_REMOTE, RawFrames, norm_channel

__all__ = ["FrameGather", "gather_messages"]

_STEP = 65536
"""Messages taken from a reader between two moves of the progress bar."""


class FrameGather:
    """Collects frames from python-can messages (one pass, plain lists).

    With a ``sink``, every ``chunk`` frames are handed to it as :class:`RawFrames` and
    forgotten (:meth:`spill`), so that memory stays bounded on long logs.
    """

    def __init__(self, sink: Any = None, chunk: int = 1 << 18) -> None:
        self.sink = sink
        self.chunk = int(chunk)
        self.handed = 0
        self.t: list[float] = []
        self.arb: list[int] = []
        self.ext: list[bool] = []
        self.ch: list[Any] = []
        self.data = bytearray()
        self.lengths: list[int] = []
        self.special: list[tuple[int, int]] = []

    def _reset(self) -> None:
        # in place: the reading loop holds bound methods of these lists
        for x in (self.t, self.arb, self.ext, self.ch, self.lengths, self.special):
            x.clear()
        del self.data[:]

    def add(self, msg: can.Message) -> None:
        """Append one message (the text-log path; the binary path inlines these appends,
        :func:`gather_messages`)."""
        if msg.is_error_frame or msg.is_remote_frame:
            self.special.append((len(self.t), FRAME_ERROR if msg.is_error_frame
                                 else FRAME_REMOTE))
        self.t.append(msg.timestamp)
        self.arb.append(msg.arbitration_id)
        self.ext.append(msg.is_extended_id)
        self.ch.append(msg.channel)
        self.data += msg.data
        self.lengths.append(len(msg.data))

    def spill(self, force: bool = False) -> None:
        """Hand the frames gathered so far to the sink (when ``chunk`` are there)."""
        if self.sink is not None and self.t and (force or len(self.t) >= self.chunk):
            fr = self.frames()
            self.handed += len(fr)
            self._reset()
            self.sink(fr)

    def frames(self) -> RawFrames:
        """The frames gathered (and not yet spilled), channels as numbers where they are."""
        M = len(self.t)
        ft = np.zeros(M, np.int8)
        for j, k in self.special:
            ft[j] = k
        ch = np.empty(M, dtype=object)
        ch[:] = self.ch
        uniq = set(self.ch)
        if uniq:
            norm = {c: norm_channel(c) for c in uniq}
            if any(norm[c] is not c for c in uniq):
                ch[:] = [norm[c] for c in self.ch]
        return RawFrames(t=np.array(self.t, dtype=float),
                         arbitration_id=np.array(self.arb, dtype=np.int64),
                         extended=np.array(self.ext, dtype=bool), channel=ch,
                         payload=np.frombuffer(self.data, np.uint8).copy(),
                         lengths=np.array(self.lengths, dtype=np.int64), frame_type=ft)


def gather_messages(it: Iterator[can.Message], g: FrameGather, bar: Any) -> None:
    """The hot path: one pass over python-can's messages, plain appends, in chunks (the
    progress bar moves between chunks)."""
    t_app, a_app, e_app, c_app, l_app = (g.t.append, g.arb.append, g.ext.append,
                                         g.ch.append, g.lengths.append)
    s_app = g.special.append
    buf = g.data
    step = min(_STEP, g.chunk) if g.sink is not None else _STEP
    while True:
        n0 = len(g.t)
        for msg in islice(it, step):
            if msg.is_error_frame or msg.is_remote_frame:
                s_app((len(g.t), FRAME_ERROR if msg.is_error_frame else FRAME_REMOTE))
            t_app(msg.timestamp)
            a_app(msg.arbitration_id)
            e_app(msg.is_extended_id)
            c_app(msg.channel)
            x = msg.data
            buf += x
            l_app(len(x))
        got = len(g.t) - n0
        if bar is not None:
            bar.update(got)
        g.spill()
        if got < step:
            return
