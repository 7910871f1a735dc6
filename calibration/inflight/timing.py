"""Apply the time offsets of an in-flight calibration to a recorded flight.

The one timing model lives in :mod:`replay.time_offsets` (the whole-flight
:func:`apply_time_offsets` and the causal :class:`~replay.time_offsets.StreamAligner` that
``rimu replay`` and ``rimu monitor`` use); this module re-exports the whole-flight functions
where the calibration code has always found them.

Sign of every offset rimu prints: the in-flight fit models IMU ``j`` as
``y_j(t) = A_j · y_ref(t + τ_j) + c_j``: IMU ``j``'s sample at t matches the reference's at
``t + τ_j``, so IMU ``j`` sees the motion ``|τ_j|`` late when ``τ_j < 0``. An offset belongs
to the flight it was fitted on (the lag between two IMUs' samples depends on the logger's
scheduling and on the motion): the calibration records that flight's identity
(:func:`flight_identity`) and :func:`other_flight_warning` says when it is applied to
another.
"""

from __future__ import annotations

from fdi.calfile import Calibration
from replay.flight_data import Flight
from replay.time_offsets import (
    apply_time_offsets,
    flight_identity,
    moved_aux_channels,
    time_offsets_s,
)

__all__ = ["apply_time_offsets", "flight_identity", "moved_aux_channels", "other_flight_warning",
           "time_offsets_s"]


def other_flight_warning(cal: Calibration, flight: Flight) -> str | None:
    """A warning when ``cal``'s time offsets were fitted on another flight than ``flight``
    (None when they were fitted on this one, when the calibration has no offsets, or
    when it does not record its flight)."""
    inflight = cal.extras.inflight
    known = inflight.flight if inflight is not None else None
    if not time_offsets_s(cal) or known is None or not known.fingerprint:
        return None
    here = flight_identity(flight)
    if here["fingerprint"] == known.fingerprint:
        return None
    return (f"the calibration's time offsets were fitted on another flight "
            f"({known.source or '?'}, {known.samples or '?'} samples) than this "
            f"one ({here['source']}, {here['samples']} samples): an offset belongs to its "
            f"flight, so what is left here may be the difference between the two")
