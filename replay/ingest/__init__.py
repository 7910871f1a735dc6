"""Measured recordings in: readers of flight logs and bench files, one time base, a flight.

One module per format, each built on the library made for it: :mod:`.ardupilot`
(pymavlink ``DFReader``), :mod:`.px4` (pyulog), :mod:`.tabular` (``.mat`` through
scipy.io, CSV through numpy, R ``.rda`` through rdata, all through a ``rimu.ingest-map/1``
TOML map). Each returns a :class:`LogRead` of :class:`ImuStream` records;
:func:`align_streams` puts them on one time base as a
:class:`~replay.flight_data.Flight` and accounts for every sample.
"""

from replay.ingest.align import INGEST_REPORT_SCHEMA, align_streams
from replay.ingest.readers import FORMATS, detect_format, read_any
from replay.ingest.stream import Damage, ImuStream, LogRead

__all__ = [
    "FORMATS",
    "INGEST_REPORT_SCHEMA",
    "Damage",
    "ImuStream",
    "LogRead",
    "align_streams",
    "detect_format",
    "read_any",
]
