"""One monitoring chain for every source: a flight folder, a CAN log read in pieces, a live bus.

:class:`MonitorChain` runs, per block of samples handed to :meth:`MonitorChain.feed`:

1. fault injection (``rimu replay --inject``: :class:`replay.stream.ChunkInjector`);
2. the in-flight calibration's time offsets (:class:`replay.time_offsets.StreamAligner`:
   each IMU moved onto the reference's timing, causally; the answers of a stream come at
   most :attr:`MonitorChain.delay_s` plus one sample period later);
3. the run-time inputs of the calibration's effect terms (specific force, temperature)
   from the block's auxiliary channels (a flight's, or a channel map's);
4. :class:`ChainBlock`, what the operating envelope is decided from: the time, the
   calibrated rates and each IMU's accelerometer triad. With an ``envelope`` tracker
   (``update(t, rates, accel) -> (B,) int`` codes, :mod:`fdi.envelope`), its codes go to
   the monitor (``envelope=``); without one the monitor gets none. Where an IMU is read
   from samples ahead of its time, each code is the union with the next ``lead`` samples'
   and ``lead`` samples are held back for it (:mod:`replay.envelope_lead`): the answers
   then come ``lead`` sample periods later still;
5. the monitor with run-time compensation (:class:`fdi.effects_monitor.CompensatedMonitor`),
   over the block at once or sample by sample (live, ``--realtime``: events as they
   happen);
6. the report's running summaries (:class:`replay.report.RunningReport`) and the rerun
   recording (:class:`replay.rerun_log.Recorder`), both in constant memory.

The thresholds come from :func:`replay.threshold_choice.select` (a file made for another
calibration or sample rate is refused there). :func:`chain_for_flight` and
:func:`chain_for_map` build a chain for a flight folder and for a CAN source (log or bus);
:func:`run_flight` and :func:`run_log` run one over the whole source and return the report;
:func:`replay.live.run_live` and :func:`replay.live.report_bus` run one on a bus (the live
module builds on this one, never the other way).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fdi.answer import Answer, BlockResult, Event
from fdi.blocks import block_from_answers
from fdi.calfile import Calibration
from fdi.capability import capability_report
from fdi.effects import Compensator
from fdi.effects_monitor import CompensatedMonitor
from fdi.monitor import Monitor
from fdi.units import DPS
from replay.channel_map import ChannelMap, aux_assignment
from replay.effect_inputs import (
    flight_effect_inputs,
    map_available,
    map_effect_inputs,
    map_reasons,
    row_inputs,
    stream_inputs,
)
from replay.envelope import envelope_tracker
from replay.envelope_lead import LeadHold
from replay.flight_data import Flight, concat_flights
from replay.log_events import declared_intervals
from replay.report import RunningReport
from replay.time_offsets import StreamAligner, imu_groups, moved_aux_channels

__all__ = ["ChainBlock", "ChainOptions", "MonitorChain", "aux_extra", "aux_record",
           "chain_for_flight", "chain_for_map", "format_aux", "moved_aux", "offsets_extra",
           "report_log", "run_flight", "run_log"]


@dataclass(frozen=True, eq=False)
class ChainBlock:
    """One block of samples as the monitor is about to see it (after the time offsets).

    Attributes
    ----------
    t : ndarray, shape (B,)
        Sample times (s).
    rates : ndarray, shape (B, n)
        Calibrated outputs ``SF·u − b`` of the monitored sensors (rad/s for gyros; NaN where
        a sensor has no sample), before the effect-term correction.
    accel : ndarray, shape (B, k, 3), or None
        The accelerometer triad of each of the ``k`` IMUs that have one (m/s², NaN where
        missing); None without accelerometer channels.
    accel_imus : tuple of str
        The IMU (group) of each triad of ``accel``.
    piece : Flight
        The samples themselves (raw, valid, auxiliary channels, true rates when known).
    """

    t: np.ndarray
    rates: np.ndarray
    accel: np.ndarray | None
    accel_imus: tuple[str, ...]
    piece: Flight


class MonitorChain:
    """A monitor and everything around it, fed block by block (module docstring).

    Parameters
    ----------
    monitor : Monitor or CompensatedMonitor
    cal : Calibration
    cmap : ChannelMap, optional
        A CAN source's map: the effect terms' inputs come from its auxiliary channels
        (otherwise from each piece's own, as a flight folder keeps them).
    imu : sequence of str, optional
        IMU group of each sensor (default: from the sensor names, ``imu2.x`` → ``imu2``).
    aux_groups : sequence of str, optional
        IMU group of each auxiliary column of the pieces (default: the pieces' ``aux.imu``).
    time_offsets : bool
        Move each IMU by the calibration's time offset (default True).
    injector : ChunkInjector, optional
        Faults injected into each piece before anything else.
    report : RunningReport, optional
        Updated with every block (None: no report kept).
    envelope : object, optional
        ``update(t, rates, accel) -> (B,) int`` envelope codes per block (:class:`ChainBlock`
        fields); None: the monitor gets no envelope codes.
    thresholds_how : dict, optional
        Where the thresholds came from (:meth:`replay.threshold_choice.ThresholdChoice.to_dict`),
        for the report.
    turn_on : replay.turn_on.TurnOn, optional
        What was done about the turn-on bias (:func:`replay.turn_on.turn_on_for_flight`),
        for the report.
    firmware_prior : replay.firmware_prior.FirmwarePrior, optional
        The parameters held at the calibration's prior on a flight under another firmware,
        for the report.
    """

    def __init__(self, monitor: Any, cal: Calibration, *, cmap: ChannelMap | None = None,
                 imu: Sequence[str] = (), aux_groups: Sequence[str] | None = None,
                 time_offsets: bool = True, injector: Any = None,
                 report: RunningReport | None = None, envelope: Any = None,
                 thresholds_how: dict[str, Any] | None = None, turn_on: Any = None,
                 firmware_prior: Any = None) -> None:
        self.monitor = monitor
        self.turn_on = turn_on
        self.firmware_prior = firmware_prior
        self.cal = cal
        self.cmap = cmap
        self.kind = monitor.kind
        self.sensor_names = tuple(monitor.sensor_names)
        self.n = int(monitor.n)
        s = cal.kind(self.kind)
        self._sf, self._b = s.scale_factors, s.biases
        self.groups = imu_groups(self.sensor_names, imu)
        self.aligner = StreamAligner(cal, self.groups, aux_groups) if time_offsets else None
        if self.aligner is not None and not self.aligner.active:
            self.aligner = None
        self.injector = injector
        self.report = report
        self.envelope = envelope
        # a moved sample reaches ahead in time: its envelope code covers those samples
        # (replay.envelope_lead); the answers come that many sample periods later
        lead = self._lead_samples()
        self._hold = LeadHold(lead) if envelope is not None and lead > 0 else None
        self.thresholds_how = thresholds_how
        self.recorder: Any = None
        self.last_answers: list[Answer] = []
        comp = getattr(monitor, "compensator", None)
        self._needs_inputs = comp is not None and bool(
            comp.needs & {"specific_force", "temperature"})

    def _lead_samples(self) -> int:
        """Samples past its time a moved sample is made from (0: nothing moved ahead)."""
        if self.aligner is None:
            return 0
        fs = float(self.cal.sample_rate_hz)
        ahead = float(self.aligner.delay_s) * fs if fs > 0 else 0.0
        # a kernel wider than two samples (its half support) reads ahead whatever τ's sign
        extra = int(getattr(self.aligner, "hold_samples", 0) or 0)
        return (int(np.ceil(ahead - 1e-9)) if ahead > 0 else 0) + extra

    # -------------------------------------------------------------- what it does
    @property
    def thresholds(self) -> Any:
        """The monitor's thresholds."""
        return self.monitor.thresholds

    @property
    def time_offsets_ms(self) -> dict[str, float]:
        """``{IMU: τ in ms}`` of the IMUs moved (empty: none)."""
        return dict(self.aligner.applied) if self.aligner is not None else {}

    @property
    def delay_s(self) -> float:
        """Most time (s) a sample is held back for the time offsets (plus one period)."""
        return self.aligner.delay_s if self.aligner is not None else 0.0

    def compensation_summary(self) -> str | None:
        """What is and is not compensated (None when the calibration has no effect term)."""
        comp = getattr(self.monitor, "compensator", None)
        if not self.cal.effects or comp is None:
            return None
        return comp.summary(self.sensor_names)

    def extra(self) -> dict[str, Any]:
        """The report's records of how the chain ran (thresholds, effects, time offsets)."""
        out: dict[str, Any] = {}
        if self.thresholds_how is not None:
            out["thresholds"] = self.thresholds_how
        if self.turn_on is not None:
            out["turn_on_bias"] = self.turn_on.to_dict()
        if self.firmware_prior is not None:
            out["firmware_prior"] = self.firmware_prior.to_dict()
        if self.time_offsets_ms:
            out["time_offsets_applied_ms"] = self.time_offsets_ms
            out["time_offsets_delay_s"] = self.delay_s
        comp = getattr(self.monitor, "compensator", None)
        if self.cal.effects and comp is not None:
            out["effects"] = comp.to_dict()
        mon = getattr(self.monitor, "monitor", self.monitor)
        unit, name = (DPS, "deg/s") if self.kind == "gyro" else (1.0, "m/s^2")
        full = mon.cache.get((1 << mon.n) - 1)               # what the whole set can do
        out["isolation_capability"] = capability_report(full, mon.sensor_names, 1.0 / unit,
                                                        name)
        out["envelope_settings"] = (self.envelope.settings.to_dict()
                                    if self.envelope is not None
                                    and hasattr(self.envelope, "settings") else None)
        return out

    def record(self, path: Any = None, *, spawn: bool = False, has_truth: bool = False) -> Any:
        """Write a rerun recording of the run to ``path`` (and/or a viewer)."""
        from replay.rerun_log import Recorder

        self.recorder = Recorder(self.cal, self.sensor_names, self.kind, path=path,
                                 spawn=spawn, has_truth=has_truth,
                                 thresholds=self.thresholds)
        return self.recorder

    # -------------------------------------------------------------- feeding
    def feed(self, piece: Flight, *, stepwise: bool = False,
             on_event: Callable[[Event], None] | None = None, pacer: Any = None
             ) -> BlockResult | None:
        """Monitor the samples of ``piece`` (and those the time offsets held back).

        Parameters
        ----------
        piece : Flight
            The next samples of the source, in time order.
        stepwise : bool
            Step the monitor sample by sample (``on_event`` called as events happen;
            :attr:`last_answers` keeps the answers of the block).
        on_event : callable, optional
            Called with each event (stepwise).
        pacer : replay.live.Pacer, optional
            Step at the recorded pace (``rimu replay --realtime``).

        Returns
        -------
        BlockResult or None
            The answers to the samples monitored now (None: all held back).
        """
        if self.injector is not None and piece.t.shape[0]:
            piece = self.injector.apply(piece)
        if self.aligner is not None:
            piece = self.aligner.push(piece)
        return self._monitor(piece, stepwise, on_event, pacer)

    def feed_whole(self, flight: Flight) -> BlockResult | None:
        """Monitor a whole recorded flight in one block (the time offsets applied to all of
        it at once: the same samples as :meth:`feed` then :meth:`finish`)."""
        if self.injector is not None and flight.t.shape[0]:
            flight = self.injector.apply(flight)
        if self.aligner is not None:
            pieces = [p for p in (self.aligner.push(flight), self.aligner.flush())
                      if p is not None]
            flight = pieces[0] if len(pieces) == 1 else concat_flights(pieces)
        return self._monitor(flight, False, None, None, final=True)

    def finish(self, *, stepwise: bool = False,
               on_event: Callable[[Event], None] | None = None, pacer: Any = None
               ) -> BlockResult | None:
        """Monitor the samples still held back (end of the source)."""
        if self.aligner is None:
            return None
        return self._monitor(self.aligner.flush(), stepwise, on_event, pacer, final=True)

    def block(self, piece: Flight) -> ChainBlock:
        """What the envelope is decided from, for the samples of ``piece``."""
        raw = np.asarray(piece.raw, float)
        rates = np.where(np.asarray(piece.valid, bool), raw * self._sf - self._b, np.nan)
        imus, accel = self._accel(piece)
        return ChainBlock(t=np.asarray(piece.t, float), rates=rates, accel=accel,
                          accel_imus=imus, piece=piece)

    def _accel(self, piece: Flight) -> tuple[tuple[str, ...], np.ndarray | None]:
        """Each IMU's specific force (B, k, 3) m/s²: a flight's accelerometer triads
        (:func:`replay.envelope.flight_accel`), or a map's auxiliary channels resolved onto
        the body axes (:func:`replay.effect_inputs.map_effect_inputs`, the first sensor of
        each IMU that has one)."""
        if self.cmap is None:
            from replay.envelope import flight_accel

            acc = flight_accel(piece)
            if acc is None:
                return (), None
            imu = piece.aux.select("accel").imu
            return tuple(g for g in dict.fromkeys(imu) if imu.count(g) == 3), acc
        aux = getattr(piece.aux, "values", None)
        force, _ = map_effect_inputs(self.cmap, aux)
        if force is None:
            return (), None
        has = aux_assignment(self.cmap)["specific_force"]
        first: dict[str, int] = {}
        for i, g in enumerate(self.groups):
            if g and has[i] and g not in first:
                first[g] = i
        if not first:
            return (), None
        return tuple(first), force[:, list(first.values()), :]

    def _inputs(self, piece: Flight) -> dict[str, np.ndarray]:
        """``force`` / ``temperature`` of the compensated monitor for these samples."""
        if not self._needs_inputs:
            return {}
        if self.cmap is not None:
            return stream_inputs(self.monitor, self.cmap, piece.aux)
        force, temp, _ = flight_effect_inputs(piece)
        return {k: v for k, v in (("force", force), ("temperature", temp)) if v is not None}

    def _codes(self, piece: Flight | None, final: bool
               ) -> tuple[Flight | None, np.ndarray | None]:
        """The samples to monitor now and their envelope codes (None: no envelope): the
        operating envelope of these samples (fdi.envelope), context for the monitor, which
        suspends exclusion while outside; with samples moved ahead in time, each code
        covers the samples its sample is made from (replay.envelope_lead)."""
        new = piece is not None and piece.t.shape[0] > 0
        codes = None
        if self.envelope is not None and new:
            blk = self.block(piece)
            codes = np.asarray(self.envelope.update(blk.t, blk.rates, blk.accel))
        if self._hold is None:
            return (piece if new else None), codes
        if new:
            return self._hold.push(piece, codes, final=final)
        return self._hold.release() if final else (None, None)

    def _monitor(self, piece: Flight | None, stepwise: bool,
                 on_event: Callable[[Event], None] | None, pacer: Any, *,
                 final: bool = False) -> BlockResult | None:
        self.last_answers = []
        piece, codes = self._codes(piece, final)
        if piece is None or piece.t.shape[0] == 0:
            return None
        kw = self._inputs(piece)
        if codes is not None:
            kw["envelope"] = codes
        if pacer is not None:
            result = pacer.run(self.monitor, piece.t, piece.raw, piece.valid, **kw)
        elif stepwise:
            result = self._step(piece, kw, on_event)
        else:
            # the recording shows the parity vectors (the stepwise paths always have them)
            result = self.monitor.run(piece.t, piece.raw, piece.valid,
                                      parity=self.recorder is not None, **kw)
        if self.report is not None:
            self.report.update(result, piece.omega_true)
        if self.recorder is not None:
            self.recorder.log(result, piece)
        return result

    def _step(self, piece: Flight, kw: dict[str, np.ndarray],
              on_event: Callable[[Event], None] | None) -> BlockResult:
        mon = self.monitor
        answers = []
        for k in range(piece.t.shape[0]):
            ans = mon.step(float(piece.t[k]), piece.raw[k], piece.valid[k],
                           **row_inputs(kw, k))
            if on_event is not None:
                for e in ans.events:
                    on_event(e)
            answers.append(ans)
        self.last_answers = answers
        return block_from_answers(answers, self.n, int(mon.K), parity=True)

    # -------------------------------------------------------------- reporting
    def build_report(self, header: Flight, *, frames: dict[str, Any] | None = None,
                     extra: dict[str, Any] | None = None) -> dict[str, Any]:
        """The ``rimu.report/1`` dictionary of the run so far (:meth:`extra` and ``extra``
        added)."""
        if self.report is None:
            raise ValueError("this chain keeps no report")
        return self.report.build(header, self.cal, frames=frames,
                                 extra={**self.extra(), **(extra or {})})


def _compensated(mon: Monitor, cal: Calibration, kind: str, *, effects: bool,
                 available: Any, lacking: Any) -> CompensatedMonitor:
    return CompensatedMonitor(mon, Compensator(cal, kind, available=available or {},
                                               enabled=effects, lacking=lacking))


def _monitor(cal: Calibration, kind: str, *, thresholds_file: Any, calibration_file: Any,
             false_alarms_per_hour: Any, settings: Any, thresholds: Any = None,
             turn_on: Any = None, firmware: Any = None) -> tuple[Monitor, dict[str, Any]]:
    """The monitor and where its thresholds came from. The thresholds are chosen for
    ``cal`` (a file made for another calibration is refused); with a ``turn_on``
    (:class:`replay.turn_on.TurnOn`) the monitor runs on the biases it estimated at rest,
    or on thresholds raised for its nominal bias bound (:mod:`fdi.bias_bound`); with a
    ``firmware`` (:class:`replay.firmware_prior.FirmwarePrior`) on the calibration whose
    firmware-dependent parameters are widened to their prior."""
    from replay.threshold_choice import select

    if thresholds is not None:                          # given in the library (a Thresholds)
        thr, how = thresholds, {"source": "given", "false_alarms_per_hour":
                                float(thresholds.false_alarms_per_hour)}
    else:
        choice = select(cal, kind=kind, thresholds_file=thresholds_file,
                        false_alarms_per_hour=false_alarms_per_hour,
                        calibration_file=calibration_file)
        thr, how = choice.thresholds, choice.to_dict()
    mon_cal = cal
    if turn_on is not None and turn_on.method == "bound":
        from fdi.bias_bound import bounded_thresholds

        thr = bounded_thresholds(thr, cal, np.asarray(turn_on.bound, float), kind,
                                 turn_on.bound_source)
        how = {**how, "bias_bound": turn_on.bound_source}
    elif turn_on is not None:
        from replay.turn_on import apply_turn_on

        mon_cal = apply_turn_on(cal, turn_on)
    if firmware is not None:
        from replay.firmware_prior import apply_firmware_prior

        mon_cal = apply_firmware_prior(mon_cal, firmware, kind)
    return Monitor(mon_cal, thr, kind=kind, settings=settings), how


@dataclass(frozen=True)
class ChainOptions:
    """What the commands' options say about the chain.

    Attributes
    ----------
    thresholds_file : path or None
        ``--thresholds`` (refused when made for another calibration or sample rate).
    calibration_file : path or None
        ``--cal``, named in messages.
    false_alarms_per_hour : float or None
        Budget for thresholds computed from the calibration.
    effects : bool
        Compensate the calibration's effect terms (``--no-effects`` turns it off).
    time_offsets : bool
        Apply the in-flight calibration's time offsets (``--no-time-offsets``).
    settings : MonitorSettings or None
    envelope : bool or object
        True (default): the operating envelope is decided by an
        :class:`fdi.envelope.EnvelopeTracker` on the calibrated rates, each IMU's
        specific force and the log's declared events (:func:`default_envelope`); False or
        None: no envelope (``--no-envelope``); any other object: that tracker.
    report : bool
        Keep the report's running summaries.
    median_exact_max : int or None
        Protection levels kept for an exact median (a live run gives a small number).
    thresholds : Thresholds or None
        Thresholds given in the library (win over ``thresholds_file``).
    turn_on : str
        What to do about the turn-on bias on a flight (:data:`replay.turn_on.MODES`;
        ``--turn-on``): ``"auto"`` estimates it at rest before take-off on another flight
        than the calibration's, else covers a nominal bias bound.
    bias_bound_dps : float or None
        ``--bias-bound-dps``: the nominal bias bound per gyro (°/s) over the calibration's
        ``bias_turn_on_sd`` and the default.
    firmware_prior : bool
        On a flight whose log names another firmware than the calibration's, hold every
        IMU's relative scale, mounting and time offset at the calibration's prior
        (:mod:`replay.firmware_prior`; ``--keep-firmware-parameters`` turns it off).
    """

    thresholds_file: Any = None
    calibration_file: Any = None
    false_alarms_per_hour: float | None = None
    effects: bool = True
    time_offsets: bool = True
    settings: Any = None
    envelope: Any = True
    report: bool = True
    median_exact_max: int | None = None
    thresholds: Any = None
    turn_on: str = "auto"
    bias_bound_dps: float | None = None
    firmware_prior: bool = True


def _report(opts: ChainOptions) -> RunningReport | None:
    if not opts.report:
        return None
    if opts.median_exact_max is not None:
        return RunningReport(median_exact_max=opts.median_exact_max)
    return RunningReport()


def default_envelope(cal: Calibration, kind: str, groups: Sequence[str],
                     declared: Sequence[Any] = ()) -> Any:
    """The envelope tracker of a set: the calibrated axes, one rate estimate per IMU group
    (leave-one-out subsets when the sensors are not grouped in IMUs) and the declared
    intervals of the log (:func:`replay.envelope.envelope_tracker`, the chain's rule:
    IMU groups only when every sensor is in one of two or more)."""
    s = cal.kind(kind)
    return envelope_tracker(s.H, groups, s, declared, whole_imus=True)


def _envelope(choice: Any, cal: Calibration, kind: str, groups: Sequence[str],
              declared: Sequence[Any] = ()) -> Any:
    """The tracker an ``envelope`` option asks for (ChainOptions)."""
    if choice is True:
        return default_envelope(cal, kind, groups, declared)
    if choice is False or choice is None:
        return None
    return choice


def chain_for_flight(flight: Flight, cal: Calibration, opts: ChainOptions = ChainOptions()
                     ) -> MonitorChain:
    """A chain for a recorded flight (folder): effect inputs from its own channels; the
    turn-on bias estimated at rest before take-off or covered by a bound
    (:func:`replay.turn_on.turn_on_for_flight`, ``opts.turn_on``)."""
    from replay.firmware_prior import apply_firmware_prior, firmware_prior
    from replay.turn_on import apply_turn_on, turn_on_for_flight

    ton = turn_on_for_flight(flight, cal, kind=flight.kind, mode=opts.turn_on,
                             bias_bound_dps=opts.bias_bound_dps)
    fw = firmware_prior(cal, flight, flight.kind) if opts.firmware_prior else None
    mon, how = _monitor(cal, flight.kind, thresholds_file=opts.thresholds_file,
                        calibration_file=opts.calibration_file,
                        false_alarms_per_hour=opts.false_alarms_per_hour,
                        settings=opts.settings, thresholds=opts.thresholds, turn_on=ton,
                        firmware=fw)
    cal = apply_firmware_prior(apply_turn_on(cal, ton), fw, flight.kind)
    avail: dict[str, list[int]] = {}
    if opts.effects and cal.effects:
        _, _, avail = flight_effect_inputs(flight)
    comp = _compensated(mon, cal, flight.kind, effects=opts.effects, available=avail,
                        lacking=None)
    env = _envelope(opts.envelope, cal, flight.kind,
                    imu_groups(mon.sensor_names, flight.imu),
                    declared_intervals(getattr(flight, "events", ())))
    return MonitorChain(comp, cal, imu=flight.imu, time_offsets=opts.time_offsets,
                        report=_report(opts), envelope=env, thresholds_how=how,
                        turn_on=ton, firmware_prior=fw)


def _aux_groups(cmap: ChannelMap, groups: Sequence[str]) -> tuple[str, ...]:
    """IMU group of each auxiliary column of a map: the one group of all the sensors its
    entry applies to, else ``""`` (not moved with any IMU)."""
    of = dict(zip((sc.name for sc in cmap.sensors), groups, strict=True))
    out: list[str] = []
    for a in cmap.auxiliary:
        gs = {of.get(nm, "") for nm in (a.sensors or ())}
        g = gs.pop() if a.sensors and len(gs) == 1 else ""
        out.extend([g] * len(a.signals))
    return tuple(out)


def chain_for_map(cal: Calibration, cmap: ChannelMap, opts: ChainOptions = ChainOptions(),
                  *, injector: Any = None) -> MonitorChain:
    """A chain for a CAN source (log or bus) read through ``cmap``: effect inputs from the
    map's auxiliary channels, each moved with its IMU when all its sensors are of one."""
    mon, how = _monitor(cal, cmap.kind, thresholds_file=opts.thresholds_file,
                        calibration_file=opts.calibration_file,
                        false_alarms_per_hour=opts.false_alarms_per_hour,
                        settings=opts.settings, thresholds=opts.thresholds)
    comp = _compensated(mon, cal, cmap.kind, effects=opts.effects,
                        available=map_available(cmap), lacking=map_reasons(cmap))
    groups = imu_groups(mon.sensor_names)
    env = _envelope(opts.envelope, cal, cmap.kind, groups)
    return MonitorChain(comp, cal, cmap=cmap, aux_groups=_aux_groups(cmap, groups),
                        time_offsets=opts.time_offsets, injector=injector,
                        report=_report(opts), envelope=env, thresholds_how=how)


def moved_aux(chain: MonitorChain, source: Flight | None = None) -> list[str]:
    """The auxiliary channels moved with their IMU (a flight's ``kind:name``, a map's
    entry names)."""
    applied = chain.time_offsets_ms
    if not applied:
        return []
    if chain.cmap is None:
        return moved_aux_channels(source, applied) if source is not None else []
    groups = _aux_groups(chain.cmap, chain.groups)
    out, c = [], 0
    for a in chain.cmap.auxiliary:
        if groups[c] in applied:
            out.append(a.name)
        c += len(a.signals)
    return out


def run_flight(chain: MonitorChain, flight: Flight) -> tuple[BlockResult, dict[str, Any]]:
    """Monitor a whole flight; returns the answers and the report."""
    result = chain.feed_whole(flight)
    extra = {}
    moved = moved_aux(chain, flight)
    if moved:
        extra["time_offsets_aux_moved"] = moved
    return result, chain.build_report(flight, extra=extra)


def run_log(chain: MonitorChain, stream: Any, *, stepwise: bool = False,
            on_event: Callable[[Event], None] | None = None, pacer: Any = None
            ) -> tuple[dict[str, Any], dict[str, float]]:
    """Monitor a CAN log read in pieces (:class:`replay.logio.LogStream`).

    Returns
    -------
    frames : dict
        The frame accounting.
    timing : dict
        ``{"read_decode", "monitor"}`` seconds.
    """
    clock = [time.perf_counter()]
    timing = {"read_decode": 0.0, "monitor": 0.0}

    def on_samples(piece: Flight) -> None:
        t1 = time.perf_counter()
        timing["read_decode"] += t1 - clock[0]
        chain.feed(piece, stepwise=stepwise, on_event=on_event, pacer=pacer)
        clock[0] = time.perf_counter()
        timing["monitor"] += clock[0] - t1

    frames = stream.run(on_samples)
    t1 = time.perf_counter()
    timing["read_decode"] += t1 - clock[0]
    chain.finish(stepwise=stepwise, on_event=on_event, pacer=pacer)
    timing["monitor"] += time.perf_counter() - t1
    return frames, timing


# ------------------------------------------------------------------ sources
def aux_record(cmap: ChannelMap, decoder: Any) -> dict[str, Any]:
    """The report's ``auxiliary`` block: the map's auxiliary channels and their frames."""
    st = decoder.aux_stats
    chans, c = [], 0
    for a in cmap.auxiliary:
        m = len(a.signals)
        chans.append({"name": a.name, "quantity": a.quantity, "message": a.message,
                      "signals": list(a.signals), "unit": a.unit,
                      "sensors": "all" if a.sensors is None else list(a.sensors),
                      "timeout_s": a.timeout_s, "values_received": st["received"][c:c + m]})
        c += m
    return {"channels": chans, "frames": {k: v for k, v in st.items() if k != "received"}}


def format_aux(rec: dict[str, Any]) -> str:
    """One line on the auxiliary channels of a report."""
    fr = rec["frames"]
    chans = ", ".join(f"{c['name']} {sum(c['values_received'])}" for c in rec["channels"])
    rej = ", ".join(f"{v} {k}" for k, v in sorted(fr["rejected"].items())) or "none"
    return (f"auxiliary channels (values received): {chans}; frames used {fr['used']}, "
            f"rejected {rej}, lost {fr['lost_frames']}")


def _warn(text: str) -> None:
    logging.getLogger("rimu").warning(text)


def aux_extra(chain: MonitorChain, decoder: Any, source: str) -> dict[str, Any]:
    """The report's ``auxiliary`` block (and a warning on channels that never spoke)."""
    if chain.cmap is None or not chain.cmap.auxiliary:
        return {}
    rec = aux_record(chain.cmap, decoder)
    silent = [ch["name"] for ch in rec["channels"] if not any(ch["values_received"])]
    if silent:
        _warn(f"{source}: no frame at all from auxiliary channel(s) {', '.join(silent)}: the "
              "effect terms they feed got no input (counted in the report's effects block)")
    return {"auxiliary": rec}


def offsets_extra(chain: MonitorChain) -> dict[str, Any]:
    """The report's ``time_offsets_aux_moved`` entry (none when nothing was moved)."""
    moved = moved_aux(chain)
    return {"time_offsets_aux_moved": moved} if moved else {}


def report_log(chain: MonitorChain, stream: Any, header: Flight, *, stepwise: bool = False,
               on_event: Callable[[Event], None] | None = None, pacer: Any = None,
               extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Monitor a CAN log (:class:`replay.logio.LogStream`) and build its report.

    Reader errors and sensors or auxiliary channels that never delivered a frame are
    warned about (``rimu: warning:`` lines); the report carries the frame accounting, the
    timing (``timing_s``) and the auxiliary channels' record.

    Raises
    ------
    ConfigError
        No sample could be decoded.
    """
    from fdi.errors import ConfigError

    frames, timing = run_log(chain, stream, stepwise=stepwise, on_event=on_event,
                             pacer=pacer)
    src = str(stream.path)
    for e in frames["errors"]:
        if e.get("kind") != "garbage_line":
            _warn(f"{src}: {e['where']}: {e['why']}")
    n_bad = frames.get("rejected", {}).get("garbage_line", 0)
    bad = next((e for e in frames["errors"] if e.get("kind") == "garbage_line"), None)
    if n_bad and bad is not None:       # a damaged text log: counted, and said on stderr
        _warn(f"{src}: {n_bad} unreadable line(s) skipped, the first at {bad['where']} "
              f"({bad['why']}); --strict refuses a damaged log")
    samples = chain.report.samples if chain.report is not None else stream.samples
    silent = stream.silent_sensors()
    if silent and samples:
        _warn(f"{src}: no frame at all from sensor(s) {', '.join(silent)}: is the "
              "calibration for this log's sensor set?")
    if samples == 0:
        raise ConfigError(f"{src}: no sample could be decoded ({frames['read']} frames read, "
                          f"rejected {frames['rejected']})")
    return chain.build_report(header, frames=frames, extra={
        "timing_s": timing, **offsets_extra(chain), **aux_extra(chain, stream.decoder, src),
        **(extra or {})})
