"""Apply the time offsets of an in-flight calibration to a recorded flight.

The one timing model lives in :mod:`replay.time_offsets` (the whole-flight
:func:`apply_time_offsets` and the causal :class:`~replay.time_offsets.StreamAligner` that
``rimu replay`` and ``rimu monitor`` use); this module re-exports the whole-flight functions
where the calibration code has always found them.
"""

from __future__ import annotations

from replay.time_offsets import apply_time_offsets, moved_aux_channels, time_offsets_s

__all__ = ["apply_time_offsets", "moved_aux_channels", "time_offsets_s"]
