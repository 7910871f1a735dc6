"""Text CAN logs (candump ``.log``, Vector ``.asc``) read with every damaged line accounted.

What python-can (measured on 4.6.1) does with damaged text logs, and what rimu adds:

- ``.log`` (candump): a line it cannot parse raises ``ValueError`` and ends its generator;
  rimu counts the line as a ``garbage_line`` and resumes with the next line.
- ``.asc``: lines that do not look like frames are skipped silently; rimu tracks the lines
  between frames and counts those that are not header, comment or known event lines as
  ``garbage_line``; a frame line that raises is a ``garbage_line`` too and reading resumes.

A garbage line is a frame read and rejected in the accounting; the first ones are listed
under its ``errors`` with their line number and text.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can

from fdi.errors import ReplayError
from replay.accounting import FrameAccounting
from replay.can_gather import FrameGather, gather_messages

__all__ = ["read_asc", "read_candump"]

_MAX_ERRORS = 50
"""Garbage lines listed under the accounting's ``errors`` (all are counted)."""


class _Lines:
    """A text file's line iterator that counts lines and keeps the ones since a mark."""

    def __init__(self, f: Any) -> None:
        self._f = f
        self.lineno = 0
        self.last = ""
        self.pending: list[str] | None = []

    def __iter__(self) -> _Lines:
        return self

    def __next__(self) -> str:
        line = next(self._f)
        self.lineno += 1
        self.last = line
        if self.pending is not None:
            self.pending.append(line)
        return line

    def readline(self) -> str:
        try:
            return next(self)
        except StopIteration:
            return ""

    def close(self) -> None:
        self._f.close()


class _ResumableASCReader(can.ASCReader):
    """python-can's ASCReader whose header is parsed once (so iteration can resume)."""

    _header_done = False

    def _extract_header(self) -> None:
        if not self._header_done:
            self._header_done = True
            super()._extract_header()


_ASC_NON_FRAME = re.compile(
    r"^\s*($|//|date\s|base\s|(no\s+)?internal\s+events|begin\s+triggerblock|"
    r"end\s+triggerblock|\d+(\.\d+)?\s+(start of measurement|can\s+\d+\s+status|"
    r"\d+\s+statistic|statistic))", re.IGNORECASE)


def _consume_lines(it: Iterator[can.Message], g: FrameGather, lines: _Lines,
                   acct: FrameAccounting, bar: Any) -> None:
    """Text logs: as :func:`~replay.can_gather.gather_messages`, and every line python-can
    passed over without a frame is reported (unless it is a known non-frame line)."""
    for msg in it:
        pend = lines.pending
        if len(pend) > 1:
            first = lines.lineno - len(pend) + 1
            for k, line in enumerate(pend[:-1]):
                if not _ASC_NON_FRAME.match(line):
                    _garbage(acct, first + k, line, "not a frame line (skipped by python-can)")
        pend.clear()
        g.add(msg)
        if bar is not None and not len(g.t) & 0xFFFF:
            bar.update(0x10000)
        if len(g.t) >= g.chunk and g.sink is not None:
            g.spill()


def _garbage(acct: FrameAccounting, lineno: int, line: str, why: str) -> None:
    acct.read += 1
    acct.reject("garbage_line")
    if len(acct.errors) < _MAX_ERRORS:
        acct.errors.append({"where": f"line {lineno}", "why": why,
                            "text": line.strip()[:80], "kind": "garbage_line"})


def _read_text(p: Path, sfx: str, g: FrameGather, acct: FrameAccounting, strict: bool,
               bar: Any) -> None:
    with p.open("r", encoding="utf-8", errors="replace", newline=None) as f:
        lines = _Lines(f)
        if sfx == ".log":
            reader = can.CanutilsLogReader(lines)
            lines.pending = None  # candump: every non-blank line is a frame or raises
        else:
            reader = _ResumableASCReader(lines)
        while True:
            try:
                if sfx == ".asc":
                    _consume_lines(iter(reader), g, lines, acct, bar)
                else:
                    gather_messages(iter(reader), g, bar)
                break
            except Exception as exc:
                line = lines.last
                if strict:
                    raise ReplayError(f"{p}:{lines.lineno}: unreadable line "
                                      f"({type(exc).__name__}: {exc})") from None
                _garbage(acct, lines.lineno, line, f"{type(exc).__name__}: {exc}")
                if lines.pending:
                    # the failing line is counted; lines before it were skipped
                    first = lines.lineno - len(lines.pending) + 1
                    for k, skipped in enumerate(lines.pending[:-1]):
                        if not _ASC_NON_FRAME.match(skipped):
                            _garbage(acct, first + k, skipped,
                                     "not a frame line (skipped by python-can)")
                    lines.pending.clear()
        if sfx == ".asc" and lines.pending:
            for k, line in enumerate(lines.pending):
                if not _ASC_NON_FRAME.match(line):
                    if strict:
                        raise ReplayError(f"{p}:{lines.lineno - len(lines.pending) + k + 1}:"
                                          " not a frame line")
                    _garbage(acct, lines.lineno - len(lines.pending) + k + 1, line,
                             "not a frame line (skipped by python-can)")


def read_candump(p: Path, g: FrameGather, acct: FrameAccounting, strict: bool,
                 bar: Any) -> None:
    """A candump ``.log`` into ``g``: a line python-can cannot parse is a ``garbage_line``
    (``strict``: :class:`~fdi.errors.ReplayError`) and reading resumes after it."""
    _read_text(p, ".log", g, acct, strict, bar)


def read_asc(p: Path, g: FrameGather, acct: FrameAccounting, strict: bool, bar: Any) -> None:
    """A Vector ``.asc`` into ``g``: lines python-can skipped or could not parse that are not
    known non-frame lines are ``garbage_line`` (``strict``: :class:`~fdi.errors.ReplayError`)."""
    _read_text(p, ".asc", g, acct, strict, bar)
