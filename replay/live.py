"""Live monitoring on a CAN bus, and the recorded-pace loop of ``rimu replay --realtime``.

:class:`StreamDecoder` is the offline decoder (:class:`~replay.assemble.BlockDecoder`: the
same checks, assembly and loss accounting) fed one frame at a time, so that a log played
onto a bus in time order gives the same samples (and the monitor the same events) as the
offline replay. Every frame read is used or rejected with a reason (a frame for a sample
already handed to the monitor is ``late``); every sample missing from the sample-counter
sequence is counted in ``lost_samples``, and frames missing from a rolling-counter sequence
in ``lost_frames``; the first good frame after a gap is used.

:func:`run_live` reads a ``can.BusABC`` until Ctrl-C, a duration, a frame count or an idle
timeout. It drains the bus in small batches (decoded together, vectorised), prints events as
they happen, keeps running summaries (:class:`~replay.report.RunningReport`) and only the
last ``window`` answers, so that memory stays constant however long it runs.

:class:`Pacer` feeds a monitor sample by sample at the recorded pace.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import can
import cantools
import numpy as np

from fdi.answer import Answer, BlockResult, Event
from fdi.blocks import block_from_answers
from replay.accounting import FrameAccounting
from replay.assemble import BlockDecoder, Samples
from replay.chain import MonitorChain, aux_extra, offsets_extra
from replay.channel_map import ChannelMap
from replay.effect_inputs import row_inputs
from replay.flight_data import Flight
from replay.logio import aux_channels
from replay.raw_frames import RawFrames, norm_channel

__all__ = ["STATUS_EVERY_S", "Pacer", "StreamDecoder", "block_from_answers", "format_event",
           "print_event", "report_bus", "run_live"]

STATUS_EVERY_S = 5.0
"""``rimu monitor`` says what the bus gave (frames, last sample time, or "waiting") this
often (s), on stderr (:mod:`fdi.progress`)."""

_Sample = tuple[float, np.ndarray, np.ndarray]


def print_event(e: Event, names: Sequence[str] = ()) -> None:
    """Print an event as it happens (on stdout, the progress line on a terminal erased
    first: :meth:`fdi.progress.Progress.clear`)."""
    from fdi.progress import current

    current().clear()
    print(format_event(e, names), flush=True)


def format_event(e: Event, names: Sequence[str] = ()) -> str:
    """One line for an event as it happens."""
    who = "-" if e.sensor is None else str(e.sensor)
    if e.sensor is not None and 1 <= e.sensor <= len(names):
        who += f" ({names[e.sensor - 1]})"
    st = ""
    if e.statistic is not None and math.isfinite(e.statistic):
        st = f"  {e.statistic:.4g} > {e.threshold:.4g}"
    return f"t={e.t:.3f} s  sensor {who:<8} {e.type:<10} {e.reason}{st}"


def _frames_of(messages: Sequence[can.Message]) -> RawFrames:
    fr = RawFrames.from_messages(list(messages))
    if len(fr):
        fr.channel[:] = [norm_channel(c) for c in fr.channel]
    return fr


def _as_list(s: Samples) -> list[_Sample]:
    return [(float(s.t[k]), s.raw[k], s.valid[k]) for k in range(s.t.size)]


class StreamDecoder:
    """Frame-by-frame (or batch) decoder and sample assembler (see the module docstring).

    Parameters
    ----------
    db : cantools Database
    cmap : ChannelMap
    sample_rate_hz : float
        For the default time tolerance (:data:`~replay.assemble.TIME_TOLERANCE_PERIODS`, 0.4
        sample periods) and gap counting.

    Attributes
    ----------
    acct : FrameAccounting
        Balanced after :meth:`flush`.
    t_first : float or None
        Time of the first data frame (log clock).
    """

    def __init__(self, db: cantools.database.can.Database, cmap: ChannelMap,
                 sample_rate_hz: float) -> None:
        self.cmap = cmap
        self.n = cmap.n
        self.acct = FrameAccounting()
        self.block = BlockDecoder(db, cmap, self.acct, sample_rate_hz=sample_rate_hz)

    @property
    def t_first(self) -> float | None:
        return self.block.t_first

    def feed(self, msg: can.Message) -> list[_Sample]:
        """Process one frame; returns the samples ``(t, raw, valid)`` now complete."""
        return self.feed_many((msg,))

    def feed_many(self, messages: Sequence[can.Message]) -> list[_Sample]:
        """Process a batch of frames (in arrival order) at once."""
        return _as_list(self.block.feed(_frames_of(messages)))

    def flush(self) -> list[_Sample]:
        """Hand over every pending sample (end of stream)."""
        return _as_list(self.block.flush())

    def feed_samples(self, messages: Sequence[can.Message]) -> Samples:
        """As :meth:`feed_many`, as :class:`~replay.assemble.Samples` (with the held
        auxiliary columns)."""
        return self.block.feed(_frames_of(messages))

    def flush_samples(self) -> Samples:
        """As :meth:`flush`, as :class:`~replay.assemble.Samples`."""
        return self.block.flush()


class Pacer:
    """Feed a monitor sample by sample at the recorded pace (``rimu replay --realtime``).

    Successive calls of :meth:`run` continue one clock: sample k is stepped no earlier than
    ``t_k − t_0`` after the first sample was.

    Parameters
    ----------
    on_event : callable, optional
        Called with each event as it happens.
    """

    def __init__(self, on_event: Callable[[Event], None] | None = None) -> None:
        self.on_event = on_event
        self._start: float | None = None
        self._t0 = 0.0

    def run(self, monitor: Any, t: np.ndarray, raw: np.ndarray, valid: np.ndarray, *,
            force: np.ndarray | None = None, temperature: np.ndarray | None = None,
            **more: np.ndarray | None) -> BlockResult:
        """Step ``monitor`` through the samples at their pace; returns their answers.

        ``force`` (N, ...) and ``temperature`` (N, ...): the effect terms' inputs of a
        :class:`~fdi.effects_monitor.CompensatedMonitor`, and any other per-sample input
        of ``step`` (N, ...), passed row by row when given.
        """
        answers = []
        inputs = {name: v for name, v in (("force", force), ("temperature", temperature),
                                          *more.items()) if v is not None}
        for k in range(len(t)):
            kw = row_inputs(inputs, k)
            if self._start is None:
                self._start, self._t0 = time.monotonic(), float(t[k])
            delay = (float(t[k]) - self._t0) - (time.monotonic() - self._start)
            if delay > 0:
                time.sleep(delay)
            ans = monitor.step(float(t[k]), raw[k], valid[k], **kw)
            if self.on_event is not None:
                for e in ans.events:
                    self.on_event(e)
            answers.append(ans)
        n = np.asarray(raw).shape[1] if np.ndim(raw) == 2 else 0
        return block_from_answers(answers, n, len(answers[0].statistics) if answers else 0)


def run_live(bus: can.BusABC, decoder: StreamDecoder, monitor: Any, *,
             duration_s: float | None = None, max_frames: int | None = None,
             idle_timeout_s: float | None = None, t_start: float = 0.0,
             on_event: Callable[[Event], None] | None = None,
             poll_s: float = 0.05, window: int | None = None, summary: Any = None,
             batch_frames: int = 512) -> tuple[BlockResult, dict[str, Any]]:
    """Monitor a live bus until Ctrl-C, ``duration_s``, ``max_frames`` or ``idle_timeout_s``.

    Sample time = frame time − the first frame's time + ``t_start`` (as the offline replay).
    Frames are taken from the bus in batches: the first waits up to ``poll_s``, the rest of
    the batch are those already queued (at most ``batch_frames``). Each batch's samples go
    through the monitoring chain (:class:`replay.chain.MonitorChain`: time offsets,
    compensation, envelope, report, recording) and the monitor, sample by sample.

    Parameters
    ----------
    monitor : MonitorChain, Monitor or CompensatedMonitor
        A bare monitor is run in a chain of its own (no time offsets, no report).
    window : int, optional
        Keep only the last ``window`` answers (None: all; a long run needs a window).
    summary : replay.report.RunningReport, optional
        Updated with every batch of answers (events, running summaries), besides the
        chain's own report.

    Returns
    -------
    result : BlockResult
        The answers kept (the last ``window``; also after Ctrl-C).
    frames : dict
        Frame accounting (:meth:`~replay.accounting.FrameAccounting.to_dict`).
    """

    chain = monitor if isinstance(monitor, MonitorChain) else MonitorChain(
        monitor, monitor.cal, cmap=decoder.cmap, time_offsets=False)
    answers: deque[Answer] = deque(maxlen=window)
    t0 = time.monotonic()
    last_rx = t0
    got = 0
    n = decoder.n
    header = Flight(t=np.zeros(0), raw=np.zeros((0, n)), valid=np.zeros((0, n), bool),
                    sample_rate_hz=float(chain.cal.sample_rate_hz),
                    sensor_names=chain.sensor_names, kind=chain.kind, source="<bus>")

    def keep(result: BlockResult | None) -> None:
        if result is None:
            return
        answers.extend(chain.last_answers)
        if summary is not None:
            summary.update(result)

    def consume(smp: Samples) -> None:
        if not smp.t.size:
            return
        piece = replace(header, t=smp.t - decoder.t_first + t_start, raw=smp.raw,
                        valid=smp.valid, aux=aux_channels(decoder.cmap, smp.aux))
        last_t[:] = [float(piece.t[-1])]
        keep(chain.feed(piece, stepwise=True, on_event=on_event))

    from fdi.progress import current

    prog = current()           # the command's progress: what the bus gave, every few s
    said = t0
    last_t: list[float] = []

    def status(now: float) -> None:
        if got == 0:
            prog.stage(f"waiting: no frame received in {now - t0:.0f} s", clock=False)
        else:
            idle = f"; none for {now - last_rx:.0f} s" if now - last_rx >= 1.0 else ""
            ts = f", last sample t={last_t[0]:.2f} s" if last_t else ", no sample decoded"
            prog.stage(f"{got} frames received{ts}{idle}", clock=False)

    try:
        while True:
            now = time.monotonic()
            if now - said >= STATUS_EVERY_S:
                said = now
                status(now)
            if duration_s is not None and now - t0 >= duration_s:
                break
            if max_frames is not None and got >= max_frames:
                break
            if idle_timeout_s is not None and now - last_rx >= idle_timeout_s:
                break
            msg = bus.recv(timeout=poll_s)
            if msg is None:
                continue
            batch = [msg]
            cap = batch_frames if max_frames is None else min(batch_frames, max_frames - got)
            while len(batch) < cap:
                m = bus.recv(timeout=0.0)
                if m is None:
                    break
                batch.append(m)
            got += len(batch)
            last_rx = time.monotonic()
            consume(decoder.feed_samples(batch))
    except KeyboardInterrupt:
        pass
    consume(decoder.flush_samples())
    keep(chain.finish(stepwise=True, on_event=on_event))
    return (block_from_answers(list(answers), n, int(chain.monitor.K)),
            decoder.acct.to_dict())


def report_bus(chain: MonitorChain, bus: Any, decoder: Any, *, source: str,
               on_event: Callable[[Event], None] | None = None, window: int | None = None,
               **stop: Any) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """Monitor a live bus (:func:`run_live`, ``stop``: its stop conditions) and
    build the report; returns ``(None, frames)`` when no sample was decoded."""
    _, frames = run_live(bus, decoder, chain, on_event=on_event, window=window, **stop)
    if chain.report is None or chain.report.samples == 0:
        return None, frames
    n = chain.n
    header = Flight(t=np.zeros(0), raw=np.zeros((0, n)), valid=np.zeros((0, n), bool),
                    sample_rate_hz=chain.cal.sample_rate_hz, sensor_names=chain.sensor_names,
                    source=source, kind=chain.kind)
    return chain.build_report(header, frames=frames, extra={
        "live": True, "window": window, **offsets_extra(chain),
        **aux_extra(chain, decoder.block, source)}), frames
