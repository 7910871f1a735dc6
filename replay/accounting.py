"""Frame accounting: every frame read is used or rejected for a named reason.

``read = used + sum(rejected.values())`` always holds (:meth:`FrameAccounting.balanced`).
A *frame* here is a record the log reader produced or a text line that should have been one
(a garbage line in a ``.log``/``.asc`` file counts as a frame read and rejected). A reader
that stops on a corrupt or truncated file is not a frame: it is listed under ``errors``
with where and why.

Rejection reasons (:data:`REASONS`):

``unknown_id``           the frame's id (or J1939 PGN + source address) is not in the map
``other_channel``        known id on a bus channel the map does not listen to
``error_frame``          a CAN error frame
``remote_frame``         a remote (RTR) frame
``wrong_length``         payload length differs from the DBC's
``crc``                  CRC-8 SAE J1850 mismatch
``counter_repeat``       rolling counter did not advance (repeated frame)
``counter_jump``         rolling counter advanced by more than ``max_counter_delta``
``out_of_order``         timestamp earlier than the previous frame of the same message
``status``               the sensor's status field says it is not OK
``j1939_not_available``  every mapped value in the frame is J1939 'error'/'not available'
``nonfinite_time``       timestamp NaN or infinite
``duplicate``            a second frame for the same sensor and sample
``late``                 (live) a frame for a sample already passed to the monitor
``garbage_line``         a text-log line the reader could not parse
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

__all__ = ["REASONS", "FrameAccounting"]

REASONS = (
    "unknown_id", "other_channel", "error_frame", "remote_frame", "wrong_length", "crc",
    "counter_repeat", "counter_jump", "out_of_order", "status", "j1939_not_available",
    "nonfinite_time", "duplicate", "late", "garbage_line",
)


@dataclass
class FrameAccounting:
    """Mutable frame counts of one replay (see the module docstring).

    Attributes
    ----------
    read : int
        Frames (and garbage lines) read.
    used : int
        Frames whose value reached a sample.
    rejected : Counter
        Rejected frames by reason.
    values_not_available : int
        Individual J1939 values marked missing (a frame with some values available is
        still *used*).
    errors : list of dict
        Reader failures: ``{"where": "...", "why": "..."}``.
    lost_frames : int
        Frames the rolling counters say were never received (counter steps > 1 that
        were accepted); informational, not part of the balance.
    lost_samples : int
        Samples missing from the sequence handed to the monitor (gaps in the sample
        counter; without one, gaps of more than one sample period); not part of the balance.
    """

    read: int = 0
    used: int = 0
    rejected: Counter = field(default_factory=Counter)
    values_not_available: int = 0
    errors: list[dict[str, Any]] = field(default_factory=list)
    lost_frames: int = 0
    lost_samples: int = 0

    def reject(self, reason: str, count: int = 1) -> None:
        """Count ``count`` frames rejected for ``reason`` (one of :data:`REASONS`)."""
        if reason not in REASONS:
            raise ValueError(f"unknown rejection reason {reason!r}")
        if count:
            self.rejected[reason] += int(count)

    @property
    def n_rejected(self) -> int:
        """Total rejected frames."""
        return int(sum(self.rejected.values()))

    def balanced(self) -> bool:
        """True when read = used + rejected."""
        return self.read == self.used + self.n_rejected

    def to_dict(self) -> dict[str, Any]:
        """The report's ``"frames"`` block."""
        return {"read": int(self.read), "used": int(self.used),
                "rejected": {k: int(v) for k, v in sorted(self.rejected.items()) if v},
                "values_not_available": int(self.values_not_available),
                "lost_frames": int(self.lost_frames),
                "lost_samples": int(self.lost_samples),
                "errors": list(self.errors),
                "balanced": self.balanced()}
