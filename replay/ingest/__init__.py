"""Measured recordings in: readers of flight logs and bench files, one time base, a flight.

One module per format, each built on the library made for it: :mod:`.ardupilot`
(pymavlink ``DFReader``), :mod:`.px4` (pyulog), :mod:`.tabular` (``.mat`` through
scipy.io, CSV through numpy, R ``.rda`` through rdata, all through a ``rimu.ingest-map/1``
TOML map), each an entry of the format registry (:mod:`.registry`, which third parties
extend through the ``rimu.log_readers`` entry points). Each returns a :class:`LogRead` of
:class:`ImuStream` records;
:func:`align_streams` puts them on one time base as a
:class:`~replay.flight_data.Flight` and accounts for every sample.
"""

from fdi.lazy import attach

_EXPORTS = {
    "FORMATS": "replay.ingest.registry",
    "INGEST_REPORT_SCHEMA": "replay.ingest.align",
    "Damage": "replay.ingest.stream",
    "ImuStream": "replay.ingest.stream",
    "LogFormat": "replay.ingest.registry",
    "LogRead": "replay.ingest.stream",
    "align_streams": "replay.ingest.align",
    "detect_format": "replay.ingest.readers",
    "log_formats": "replay.ingest.registry",
    "read_any": "replay.ingest.readers",
    "register_format": "replay.ingest.registry",
}
"""Public name → module defining it (imported on first use, PEP 562)."""
__all__ = [
    "FORMATS",
    "INGEST_REPORT_SCHEMA",
    "Damage",
    "ImuStream",
    "LogFormat",
    "LogRead",
    "align_streams",
    "detect_format",
    "log_formats",
    "read_any",
    "register_format",
]

__getattr__, __dir__ = attach(__name__, _EXPORTS)
