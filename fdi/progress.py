"""Progress of long work on stderr: one helper for every command (host side only).

:class:`Progress` shows nothing for work shorter than :data:`DELAY_S` (counted from the
first stage or bar: start-up and input checks do not count). After that, on a
terminal it redraws one status line (stage, bar, elapsed time, time left) a few times a
second and clears it at the end; elsewhere (a log file, a pipe, CI) it prints one line per
stage and, during a long stage or bar, one line every :data:`LINE_EVERY_S`, never two lines
within :data:`MIN_LINE_GAP_S` (the lines of a stage started too soon after the previous
line wait until the gap has passed, and are dropped when the stage is over by then).

The lines start with ``rimu: <command>:`` like the CLI's other messages. ``RIMU_PROGRESS=0``
in the environment turns it off (as ``--no-progress`` does where a command has it);
``RIMU_PROGRESS_DELAY_S`` changes :data:`DELAY_S`.

The CLI runs every command inside :func:`session`; code anywhere below it names its stages
and counts with :func:`current` (``current().stage("rate test")``,
``current().bar(total, "frames")``), which outside a session is a progress that shows
nothing: library calls stay silent. Nothing is shown before the first stage or bar: a
command names its first stage once its inputs are checked, so that a refusal stays one line.

Examples
--------
>>> with Progress("calibrate", enabled=False) as p:
...     p.stage("rate test")
...     bar = p.bar(8.0, "simulated flight", unit="h")
...     bar.update(0.15)
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import Any, TextIO

__all__ = ["DELAY_S", "LINE_EVERY_S", "MIN_LINE_GAP_S", "Bar", "Progress", "current",
           "fmt_amount", "session"]

DELAY_S = 3.0
"""Work shorter than this (s) shows no progress."""
LINE_EVERY_S = 10.0
"""A running stage or bar prints a line this often (s) where stderr is not a terminal."""
MIN_LINE_GAP_S = 1.0
"""Least time (s) between two progress lines where stderr is not a terminal."""
_TICK_S = 0.25


def fmt_amount(x: float) -> str:
    """A bar's count as people write it: ``0.15``, ``8``, ``12.5``, ``36000`` (4
    significant digits at most below 1000, whole numbers above)."""
    x = float(x)
    if abs(x) >= 1000 or x == int(x):
        return f"{x:.0f}"
    return f"{x:.4g}"


def _clock(s: float) -> str:
    s = max(0.0, float(s))
    m, sec = divmod(round(s), 60)
    return f"{m}:{sec:02d}" if m else f"{s:.1f} s" if s < 10 else f"{sec} s"


class Bar:
    """A counted part of a :class:`Progress` (made by :meth:`Progress.bar`)."""

    def __init__(self, owner: Progress, total: float | None, desc: str, unit: str) -> None:
        self._owner = owner
        self.total = None if total is None or not total > 0 else float(total)
        self.desc, self.unit = desc, unit
        self.n = 0.0
        self.t0 = time.monotonic()

    def update(self, n: float = 1.0) -> None:
        """Advance by ``n`` (in the bar's unit)."""
        with self._owner._lock:
            self.n += float(n)

    def close(self) -> None:
        """The bar is done (its stage goes on until the next :meth:`Progress.stage`)."""
        self._owner._close_bar(self)

    def __enter__(self) -> Bar:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def text(self, now: float, width: int = 20) -> str:
        """``simulated flight  40 % |████      | 3.2/8 h, 4.1 s, ~6 s left``."""
        el = now - self.t0
        u = f" {self.unit}" if self.unit else ""
        if self.total is None:
            return f"{self.desc}: {fmt_amount(self.n)}{u}, {_clock(el)}"
        f = min(max(self.n / self.total, 0.0), 1.0)
        full = int(f * width)
        bar = "█" * full + " " * (width - full)
        left = f", ~{_clock(el * (1 - f) / f)} left" if f > 0.01 and el > 1 else ""
        return (f"{self.desc} {100 * f:3.0f} % |{bar}| {fmt_amount(self.n)}/"
                f"{fmt_amount(self.total)}{u}, {_clock(el)}{left}")


class Progress:
    """Progress of one command's work (a context manager; see the module docstring).

    Parameters
    ----------
    command : str
        Names the lines (``rimu: calibrate: ...``).
    enabled : bool
        False shows nothing (``--no-progress``); so does ``RIMU_PROGRESS=0``.
    stream : file, optional
        Default ``sys.stderr`` (at construction).
    delay_s : float
        Nothing is shown before the work has lasted this long (s).
    tty : bool, optional
        Force terminal (True) or line (False) output; default ``stream.isatty()``.
    """

    def __init__(self, command: str, *, enabled: bool = True, stream: TextIO | None = None,
                 delay_s: float = DELAY_S, tty: bool | None = None) -> None:
        self.command = command
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = bool(enabled) and os.environ.get("RIMU_PROGRESS", "1") != "0"
        if tty is None:
            try:
                tty = bool(self.stream.isatty())
            except (AttributeError, ValueError):
                tty = False
        self.tty = tty
        self.delay_s = float(delay_s)
        env = os.environ.get("RIMU_PROGRESS_DELAY_S")
        if env and delay_s == DELAY_S:
            try:
                self.delay_s = max(0.0, float(env))
            except ValueError:
                pass                         # a bad setting keeps the default
        self.lines = 0                       # lines written (not a terminal)
        self._lock = threading.RLock()
        self._t0 = time.monotonic()
        self._t_work: float | None = None    # when the first stage or bar began
        self._stage: str | None = None
        self._stage_t0 = self._t0
        self._stage_said = False
        self._clocked = True
        self._bar: Bar | None = None
        self._last_line = -1e9
        self._drawn = 0                      # width of the terminal line drawn
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ----------------------------------------------------------------- public
    def __enter__(self) -> Progress:
        if self.enabled and self._thread is None:
            self._thread = threading.Thread(target=self._run, name="rimu-progress",
                                            daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close(failed=exc[0] is not None)

    def stage(self, text: str, *, clock: bool = True) -> None:
        """A new stage of the work begins (ends the previous one and its bar); ``clock``
        adds the time the stage has taken to its line."""
        with self._lock:
            self._stage, self._stage_t0, self._stage_said = text, time.monotonic(), False
            self._bar, self._clocked = None, clock
            if self._t_work is None:
                self._t_work = self._stage_t0
        self._tick()

    def clear(self) -> None:
        """Erase the terminal line (before printing something else to the terminal; it is
        drawn again on the next tick)."""
        with self._lock:
            if self.enabled and self.tty and self._drawn:
                self._write("\r" + " " * self._drawn + "\r")
                self._drawn = 0

    def bar(self, total: float | None, desc: str, *, unit: str = "") -> Bar:
        """A counted part of the current stage (``total`` None: a count without end)."""
        b = Bar(self, total, desc, unit)
        with self._lock:
            self._bar = b
            if self._t_work is None:
                self._t_work = b.t0
            if self._stage is None:
                self._stage, self._stage_t0, self._stage_said = desc, b.t0, False
        self._tick()
        return b

    def close(self, *, failed: bool = False) -> None:
        """Stop; clear the terminal line, or say how long the work took when lines were
        printed (not after a failure: its message is the last line)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        if not self.enabled:
            return
        with self._lock:
            if self.tty:
                if self._drawn:
                    self._write("\r" + " " * self._drawn + "\r")
                    self._drawn = 0
            elif (self.lines and not failed
                  and time.monotonic() - self._last_line >= MIN_LINE_GAP_S):
                self._line(f"done in {_clock(time.monotonic() - self._t0)}")
            self.enabled = False

    # --------------------------------------------------------------- internal
    def _close_bar(self, b: Bar) -> None:
        with self._lock:
            if self._bar is b:
                self._bar = None
                if self._stage == b.desc:         # the bar was the stage: no stage now
                    self._stage = None

    def _run(self) -> None:
        while not self._stop.wait(_TICK_S):
            self._tick()

    def _write(self, s: str) -> None:
        try:
            self.stream.write(s)
            self.stream.flush()
        except (OSError, ValueError):
            self.enabled = False             # stderr closed: the work goes on silently

    def _line(self, text: str) -> None:
        self._write(f"rimu: {self.command}: {text}\n")
        self.lines += 1
        self._last_line = time.monotonic()

    def _tick(self) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if self._t_work is None or now - self._t_work < self.delay_s:
            return
        with self._lock:
            if not self.enabled:
                return
            text = self._text(now)
            if text is None:
                return
            if self.tty:
                s = f"rimu {self.command}: {text}"
                pad = max(0, self._drawn - len(s))
                self._write("\r" + s + " " * pad)
                self._drawn = len(s)
                return
            if now - self._last_line < MIN_LINE_GAP_S:
                return
            if not self._stage_said or now - self._last_line >= LINE_EVERY_S:
                self._stage_said = True
                self._line(text)

    def _text(self, now: float) -> str | None:
        if self._bar is not None:
            t = self._bar.text(now)
            return t if self._stage in (None, self._bar.desc) else f"{self._stage}: {t}"
        if self._stage is None:
            return None
        if not self._clocked:
            return self._stage
        return f"{self._stage} ({_clock(now - self._stage_t0)})"


_QUIET = Progress("rimu", enabled=False)
_CURRENT: list[Progress] = []


def current() -> Progress:
    """The progress of the command running (:func:`session`), else one that shows nothing."""
    return _CURRENT[-1] if _CURRENT else _QUIET


class session:
    """Run a command's work under a :class:`Progress` that :func:`current` returns.

    Parameters
    ----------
    command : str
    enabled : bool
    **kw
        Further :class:`Progress` arguments.
    """

    def __init__(self, command: str, *, enabled: bool = True, **kw: Any) -> None:
        self.progress = Progress(command, enabled=enabled, **kw)

    def __enter__(self) -> Progress:
        _CURRENT.append(self.progress)
        return self.progress.__enter__()

    def __exit__(self, *exc: Any) -> None:
        try:
            self.progress.__exit__(*exc)
        finally:
            if _CURRENT and _CURRENT[-1] is self.progress:
                _CURRENT.pop()
