"""A monitor that applies a calibration's effect terms (:mod:`fdi.effects`) on its input.

:class:`CompensatedMonitor` wraps a :class:`fdi.monitor.Monitor` with a
:class:`fdi.effects.Compensator`: ``step`` and ``run`` compute the correction from the raw
samples (and the specific force and temperature when given) and pass it to the monitor's
``correction`` input; everything else is the wrapped monitor's. With no term applied the
monitor is called exactly as without the wrapper (no correction argument), so switching the
effects off gives the old answers bit for bit.
"""

from __future__ import annotations

from typing import Any

from fdi.answer import Answer, BlockResult
from fdi.effects import Compensator
from fdi.monitor import Monitor

__all__ = ["CompensatedMonitor"]


class CompensatedMonitor:
    """A :class:`~fdi.monitor.Monitor` fed the run-time correction of the effect terms.

    Parameters
    ----------
    monitor : Monitor
    compensator : Compensator
        Built for the monitor's calibration and kind.
    """

    def __init__(self, monitor: Monitor, compensator: Compensator) -> None:
        self.monitor = monitor
        self.compensator = compensator

    def __getattr__(self, name: str) -> Any:
        return getattr(self.monitor, name)

    def step(self, t: float, raw: Any, valid: Any = None, *, force: Any = None,
             temperature: Any = None, **kw: Any) -> Answer:
        """One sample (see :meth:`fdi.monitor.Monitor.step`); ``force`` (3,) or (n, 3) in
        m/s², ``temperature`` scalar or (n,) in °C; other keywords go to the monitor."""
        if not self.compensator.active:
            return self.monitor.step(t, raw, valid, **kw)
        c = self.compensator.one(raw, force, temperature)
        return self.monitor.step(t, raw, valid, correction=c, **kw)

    def run(self, t: Any, raw: Any, valid: Any = None, *, force: Any = None,
            temperature: Any = None, **kw: Any) -> BlockResult:
        """N samples (see :meth:`fdi.monitor.Monitor.run`); ``force`` (N, 3) or (N, n, 3),
        ``temperature`` (N,) or (N, n)."""
        if not self.compensator.active:
            return self.monitor.run(t, raw, valid, **kw)
        c = self.compensator.block(raw, force, temperature)
        return self.monitor.run(t, raw, valid, correction=c, **kw)
