"""Names of CAN log files: the suffix that picks a reader or writer, the truth sidecar.

A log's format is its suffix, looked through a ``.gz`` compression (``f.log.gz`` is a
candump log, as python-can reads and writes it); a rimu-written log's truth sidecar is
``<log>.truth.json`` beside it.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["log_suffix", "truth_path"]


def truth_path(log: str | Path) -> Path:
    """The truth sidecar of a log: ``<log>.truth.json``."""
    return Path(str(log) + ".truth.json")


def log_suffix(path: Path) -> str:
    """The suffix that names a log's format, lower case (``f.ASC.gz`` → ``.asc``)."""
    sfx = path.suffixes
    if sfx and sfx[-1].lower() == ".gz" and len(sfx) > 1:
        return sfx[-2].lower()
    return path.suffix.lower()
