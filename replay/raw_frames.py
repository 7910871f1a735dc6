"""Raw CAN frames as a log reader or a bus gives them, in columns: :class:`RawFrames`.

A block of frames is held as numpy columns (time, id, format, channel, frame type) and one
concatenated payload buffer, so that the decoder (:mod:`replay.assemble`) checks and
decodes them a slot at a time, vectorised. :func:`norm_channel` gives python-can's channel
names (``"can0"``, ``"vcan0"``, ``"0"``) the channel numbers of a channel map.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["FRAME_DATA", "FRAME_ERROR", "FRAME_REMOTE", "RawFrames", "norm_channel"]

FRAME_DATA, FRAME_ERROR, FRAME_REMOTE = 0, 1, 2
"""Frame types (:attr:`RawFrames.frame_type`): data, error, remote (RTR)."""


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


_CH = re.compile(r"^v?can(\d+)$")


def norm_channel(c: Any) -> Any:
    """``"can0"``, ``"vcan0"``, ``"0"`` → 0; anything else unchanged."""
    if isinstance(c, str):
        m = _CH.match(c)
        if m:
            return int(m.group(1))
        if c.isdigit():
            return int(c)
    return c
