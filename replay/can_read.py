"""Read every frame of a CAN log with python-can: a reader per suffix, damage accounted.

:data:`CAN_READERS` maps a log suffix to the reader that reports damage and resumes where
it can (python-can's ``MESSAGE_READERS`` is the model; :mod:`replay.ingest.readers` does
the same for flight-controller logs):

- ``.log`` (candump) and ``.asc``: :mod:`replay.can_text` (a garbage line is counted and
  reading resumes with the next line);
- ``.blf``: :class:`replay.blf.ResyncBLFReader`, which skips a damaged container or object
  and resynchronises on the next valid one (each damage an error of kind ``resync`` with
  the bytes skipped; the frames lost show in the counter gaps); a file without the BLF
  signature is "not a BLF file".

Any other suffix, and any compressed (``.gz``) log, goes to python-can's own reader
(:func:`read_other`), which cannot resume: the error (where, why) is reported, the frames
read so far are kept. Each reader gathers (timestamp, id, payload) once over the file
(:mod:`replay.can_gather`) for the vectorised decoder (:mod:`replay.assemble`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from fdi.errors import FileFormatError, ReplayError
from replay.accounting import FrameAccounting
from replay.can_files import log_suffix
from replay.can_gather import FrameGather, gather_messages
from replay.can_text import read_asc, read_candump
from replay.raw_frames import RawFrames

__all__ = ["CAN_READERS", "PROGRESS_MIN_BYTES", "read_blf", "read_frames", "read_other",
           "reader_for"]

CanReader = Callable[[Path, FrameGather, FrameAccounting, bool, Any], None]
"""``reader(path, gather, acct, strict, progress_bar)``: every frame of the log into
``gather``, damage into ``acct`` (``strict``: :class:`~fdi.errors.ReplayError` instead)."""
PROGRESS_MIN_BYTES = 20_000_000
"""Logs larger than this (bytes) show a progress bar while they are read."""


def read_frames(path: str | Path, *, strict: bool = False, progress: bool = True,
                sink: Any = None, chunk_frames: int = 1 << 18,
                acct: FrameAccounting | None = None) -> tuple[RawFrames, FrameAccounting]:
    """Read every frame of a CAN log with python-can (see the module docstring).

    With ``sink``, frames go to ``sink(RawFrames)`` in blocks of about ``chunk_frames`` as
    they are read (the returned frames are then empty): memory stays bounded.

    Returns
    -------
    frames : RawFrames
        The frames read (``acct.read`` does not include them yet:
        :func:`~replay.assemble.decode_frames`
        counts them).
    acct : FrameAccounting
        Garbage lines (read and rejected) and reader errors so far.

    Raises
    ------
    FileFormatError
        The file cannot be opened or its suffix has no python-can reader.
    ReplayError
        ``strict`` and the reader failed or a line was garbage.
    """
    p = Path(path)
    if not p.is_file():
        raise FileFormatError(str(p), "no such file")
    acct = acct if acct is not None else FrameAccounting()
    g = FrameGather(sink, chunk_frames)
    bar = None
    if progress and p.stat().st_size > PROGRESS_MIN_BYTES:
        from fdi.progress import current

        # the command's progress (fdi.progress): a count of frames read
        bar = current().bar(None, f"reading {p.name}", unit="frames")
    try:
        reader_for(p)(p, g, acct, strict, bar)
    finally:
        if bar is not None:
            bar.close()
    g.spill(force=True)
    return g.frames(), acct


def read_blf(p: Path, g: FrameGather, acct: FrameAccounting, strict: bool, bar: Any) -> None:
    """A BLF file through :class:`replay.blf.ResyncBLFReader` (damage reported, resumed)."""
    from replay.blf import ResyncBLFReader

    reader = ResyncBLFReader(p)       # FileFormatError: not a BLF file
    try:
        gather_messages(iter(reader), g, bar)
    except Exception as exc:
        _reader_error(acct, p, g.handed + len(g.t), exc, strict)
    finally:
        with contextlib.suppress(Exception):
            reader.stop()
    for d in reader.damage:
        if strict:
            raise ReplayError(f"{p}: {d['where']}: {d['why']}")
        acct.errors.append(dict(d))
    if not reader.damage:
        _check_blf_complete(reader, p, g.handed + len(g.t), acct, strict)


def read_other(p: Path, g: FrameGather, acct: FrameAccounting, strict: bool,
               bar: Any) -> None:
    """Any other log through python-can's reader for its suffix (cannot resume)."""
    sfx = log_suffix(p)
    try:
        reader = can.LogReader(str(p))
    except (ValueError, NotImplementedError, ImportError) as exc:
        if isinstance(exc, ValueError) and sfx in can.io.player.MESSAGE_READERS:
            # a known format whose header is damaged (e.g. a BLF header size)
            _reader_error(acct, p, 0, exc, strict)
            reader = None
        else:
            raise FileFormatError(str(p), f"no CAN log reader for this file ({exc})") \
                from None
    except Exception as exc:
        _reader_error(acct, p, 0, exc, strict)
        reader = None
    if reader is not None:
        try:
            gather_messages(iter(reader), g, bar)
        except Exception as exc:
            _reader_error(acct, p, g.handed + len(g.t), exc, strict)
        else:
            _check_blf_complete(reader, p, g.handed + len(g.t), acct, strict)
        finally:
            try:
                reader.stop()
            except Exception:  # closing a broken file must not hide the report
                pass


def _reader_error(acct: FrameAccounting, p: Path, nframes: int, exc: Exception,
                  strict: bool) -> None:
    where = f"after frame {nframes}"
    why = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    if strict:
        raise ReplayError(f"{p}: {where}: reader failed ({why})")
    acct.errors.append({"where": where, "why": why, "kind": "reader_error"})


def _check_blf_complete(reader: Any, p: Path, nframes: int, acct: FrameAccounting,
                        strict: bool) -> None:
    """python-can's BLFReader stops silently on a truncated file: compare with the header."""
    if not isinstance(reader, can.BLFReader):
        return
    size = p.stat().st_size
    declared = int(getattr(reader, "file_size", 0) or 0)
    objects = int(getattr(reader, "object_count", 0) or 0)
    why = None
    if declared and size < declared:
        why = (f"truncated: the BLF header declares {declared} bytes, the file has {size} "
               f"({objects} objects declared)")
    elif objects and nframes < objects:
        why = f"the BLF header declares {objects} objects, {nframes} frames were read"
    if why is None:
        return
    if strict:
        raise ReplayError(f"{p}: after frame {nframes}: {why}")
    acct.errors.append({"where": f"after frame {nframes}", "why": why, "kind": "truncated"})


CAN_READERS: dict[str, CanReader] = {".asc": read_asc, ".blf": read_blf, ".log": read_candump}
"""Log suffix → the reader that reports damage and resumes (python-can's
``MESSAGE_READERS`` is the model); any other suffix goes to :func:`read_other`."""


def reader_for(path: Path) -> CanReader:
    """The reader of a log: :data:`CAN_READERS` by its suffix, :func:`read_other` for any
    other suffix and for a compressed (``.gz``) log."""
    if str(path).lower().endswith(".gz"):
        return read_other
    return CAN_READERS.get(path.suffix.lower(), read_other)
