"""Flights from CAN logs: read a log whole (:func:`read_log`) or in pieces (:class:`LogStream`).

The frames are read by the reader of the log's suffix (:func:`replay.can_read.read_frames`),
decoded and assembled into samples (:mod:`replay.assemble`) with the DBC and channel map
:func:`resolve_map` gives, and turned into a :class:`~replay.flight.Flight` with the truth
sidecar of a rimu-written log (:mod:`replay.can_write`). Every frame is accounted for
(:class:`~replay.accounting.FrameAccounting`); a ``strict`` replay fails on any
:data:`CORRUPTION_REASONS`.

Flight time of a decoded sample is its earliest frame's timestamp minus the log's first
frame timestamp, plus the sidecar's ``t_start_s`` when there is one (0 otherwise).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fdi.calfile import Calibration, check_compatible
from fdi.errors import ConfigError, FileFormatError, ReplayError
from replay.accounting import FrameAccounting
from replay.assemble import BlockDecoder, Samples, decode_frames
from replay.can_files import truth_path
from replay.can_read import read_frames
from replay.can_write import write_flight_log
from replay.channel_map import (
    ChannelMap,
    check_against_calibration,
    default_channel_map,
    load_channel_map,
)
from replay.frames import load_dbc
from replay.raw_frames import FRAME_DATA, RawFrames

__all__ = [
    "CORRUPTION_REASONS",
    "LogStream",
    "aux_channels",
    "read_log",
    "resolve_map",
    "samples_to_flight",
    "write_flight_log",
]
# write_flight_log lives in replay.can_write; it stays importable from here, the path
# docs/effects-runtime.md shows

CORRUPTION_REASONS = frozenset({"wrong_length", "crc", "counter_repeat", "counter_jump",
                                "out_of_order", "duplicate", "garbage_line",
                                "nonfinite_time"})
"""Rejection reasons that make a ``strict`` replay fail."""


def resolve_map(cal: Calibration, *, dbc: str | Path | None = None,
                channel_map: ChannelMap | str | Path | None = None,
                kind: str = "gyro") -> tuple[Any, ChannelMap]:
    """The DBC and channel map a replay uses (defaults: the shipped DBC and its map).

    Raises
    ------
    ConfigError, FileFormatError
    """
    if channel_map is None:
        s = cal.kind(kind)
        cmap = default_channel_map(s.n, kind, axes=s.H_nominal,
                                   names=tuple(c.name for c in s.sensors))
    elif isinstance(channel_map, ChannelMap):
        cmap = channel_map
    else:
        cmap = load_channel_map(channel_map)
    check_against_calibration(cmap, cal)
    check_compatible(cal, cmap.n, [sc.unit for sc in cmap.sensors],
                     f"channel map {cmap.source}", kind=cmap.kind,
                     names=[sc.name for sc in cmap.sensors])
    db = load_dbc(dbc if dbc is not None else cmap.dbc)
    return db, cmap


def samples_to_flight(samples: Samples, cal: Calibration, cmap: ChannelMap, *,
                      t_first_frame: float, source: str) -> Any:
    """Turn assembled samples into a :class:`~replay.flight.Flight`, with the log's truth.

    Flight time = frame time − first frame time + sidecar ``t_start_s``. True rates are
    taken at ``round(t·fs)`` of the sidecar's sample grid.
    """
    from replay.flight_data import Flight
    from replay.flight_io import read_truth_sidecar

    s = cal.kind(cmap.kind)
    fs = float(cal.sample_rate_hz)
    faults: tuple = ()
    truth: dict[str, Any] = {}
    rates = None
    tp = truth_path(source)
    t_start = 0.0
    if tp.is_file():
        faults, truth, rates_all = read_truth_sidecar(tp)
        t_start = float(truth.get("can_log", {}).get("t_start_s", 0.0))
        fs = float(truth.get("sample_rate_hz", fs))
    t = samples.t - t_first_frame + t_start
    if tp.is_file() and rates_all is not None and t.size:
        k = np.clip(np.rint(t * fs).astype(np.int64), 0, rates_all.shape[0] - 1)
        rates = rates_all[k]
    return Flight(t=t, raw=samples.raw, valid=samples.valid, sample_rate_hz=fs,
                  sensor_names=tuple(c.name for c in s.sensors),
                  raw_unit=s.sensors[0].raw_unit if s.n else "raw", omega_true=rates,
                  faults=tuple(faults), truth=truth, source=str(source), kind=cmap.kind,
                  aux=aux_channels(cmap, samples.aux))


def aux_channels(cmap: ChannelMap, aux: np.ndarray | None) -> Any:
    """The held auxiliary columns of a map as a flight's
    :class:`~replay.flight_data.AuxChannels` (specific-force columns as ``accel``, along
    their own axis; names ``<entry>`` or ``<entry>.<signal>``), or None without any."""
    from replay.flight_data import AuxChannels

    if aux is None or not cmap.auxiliary:
        return None
    kinds, names = [], []
    for a in cmap.auxiliary:
        for sig in a.signals:
            kinds.append("accel" if a.quantity == "specific_force" else "temperature")
            names.append(a.name if len(a.signals) == 1 else f"{a.name}.{sig}")
    return AuxChannels(tuple(kinds), tuple(names), ("",) * len(kinds), aux,
                       np.isfinite(aux))


def read_log(path: str | Path, cal: Calibration, *, dbc: str | Path | None = None,
             channel_map: ChannelMap | str | Path | None = None, strict: bool = False,
             progress: bool = True, kind: str = "gyro") -> tuple[Any, dict[str, Any]]:
    """Read a CAN log into a flight, accounting for every frame.

    Parameters
    ----------
    path : str or Path
        Any log python-can reads (suffix picks the reader).
    cal : Calibration
        Gives the sensors (order, names, nominal axes checked against the map) and rate.
    dbc : path, optional
        Overrides the map's DBC (default: the shipped ``rimu_imu.dbc``).
    channel_map : ChannelMap or path, optional
        Default: the shipped DBC's map for the calibration's sensors.
    strict : bool
        Raise :class:`ReplayError` on a reader failure, a garbage line or any corrupt
        frame (:data:`CORRUPTION_REASONS`); otherwise report them and keep going.
    progress : bool
        tqdm progress bar on long logs (> 20 MB).
    kind : str
        Sensor kind when no map is given.

    Returns
    -------
    flight : replay.flight.Flight
    frames : dict
        ``{"read", "used", "rejected": {reason: count}, "values_not_available",
        "lost_frames", "errors": [{"where", "why", "kind"}], "balanced"}``
        (:meth:`~replay.accounting.FrameAccounting.to_dict`).
    """
    db, cmap = resolve_map(cal, dbc=dbc, channel_map=channel_map, kind=kind)
    frames, acct = read_frames(path, strict=strict, progress=progress)
    samples = decode_frames(frames, db, cmap, acct, sample_rate_hz=cal.sample_rate_hz)
    if strict:
        _refuse_corruption(acct, path)
    ok = frames.frame_type == FRAME_DATA
    finite = ok & np.isfinite(frames.t)
    t_first = float(frames.t[finite].min()) if finite.any() else 0.0
    flight = samples_to_flight(samples, cal, cmap, t_first_frame=t_first, source=str(path))
    return flight, acct.to_dict()


def _refuse_corruption(acct: FrameAccounting, source: str | Path) -> None:
    """A strict replay's end: :class:`ReplayError` naming the corrupt frames by reason."""
    bad = {k: v for k, v in acct.rejected.items() if k in CORRUPTION_REASONS and v}
    if bad:
        raise ReplayError(f"{source}: corrupt frames: "
                          + ", ".join(f"{v} {k}" for k, v in sorted(bad.items())))


def _check_log_set(truth: dict[str, Any], cal: Calibration, cmap: ChannelMap, source: str,
                   cal_source: str | None) -> None:
    """The sensor count and raw unit a rimu-written log's sidecar records, against the
    calibration (one line naming both when they disagree)."""
    rec = truth.get("can_log")
    if not isinstance(rec, dict) or truth.get("kind", cmap.kind) != cmap.kind:
        return
    names, unit = rec.get("sensor_names"), rec.get("raw_unit")
    if not isinstance(names, list) or not isinstance(unit, str):
        return
    if not cmap.source.startswith("<") and len(names) != cmap.n:
        return                       # a map that picks a subset of the log's sensors
    check_compatible(cal, len(names), unit, source, kind=cmap.kind, names=names,
                     cal_source=cal_source)


class LogStream:
    """A CAN log read, decoded and handed over in pieces: bounded memory on long logs.

    The log is read once; every ``chunk_frames`` frames are decoded
    (:class:`~replay.assemble.BlockDecoder`, checks and sample numbering carried across
    pieces) and the samples now complete are handed to ``on_samples`` as a
    :class:`~replay.flight.Flight` piece (with the sidecar's true rates, memory-mapped).
    The result equals :func:`read_log` except that a frame arriving after two later samples
    have been seen is ``late`` rather than merged.

    Parameters
    ----------
    path : str or Path
    cal : Calibration
    db, cmap
        From :func:`resolve_map`.
    strict, progress : bool
        As :func:`read_log`.
    chunk_frames : int
        Frames per piece.
    check_sensor_set : bool
        Refuse a log that carries messages like the mapped ones for more sensors than the
        calibration has (e.g. ``RIMU_GYRO_05`` and ``_06`` with a 4-sensor calibration);
        for the default map, where the calibration chose the sensors.
    cal_source : str, optional
        The calibration's file, named in the messages of a refused log.

    Raises
    ------
    ConfigError
        The truth sidecar says the log is of another sensor set than the calibration's
        (sensor count, or the raw unit the log's writer recorded), as ``rimu monitor-file``
        refuses such a flight folder (:func:`fdi.calfile.check_compatible`).

    Attributes
    ----------
    header : Flight
        The log's metadata (names, rate, source, faults and truth of the sidecar), no
        samples; ``omega_true`` is an empty (0, 3) array when the sidecar has true rates.
    """

    def __init__(self, path: str | Path, cal: Calibration, db: Any, cmap: ChannelMap, *,
                 strict: bool = False, progress: bool = True,
                 chunk_frames: int = 1 << 16, check_sensor_set: bool = False,
                 cal_source: str | None = None) -> None:
        from replay.flight_data import Flight
        from replay.flight_io import read_truth_sidecar

        self.path = Path(path)
        if not self.path.is_file():
            raise FileFormatError(str(self.path), "no such file")
        self.cal, self.db, self.cmap = cal, db, cmap
        self.strict, self.progress = strict, progress
        self.chunk_frames = int(chunk_frames)
        self.check_sensor_set = check_sensor_set
        s = cal.kind(cmap.kind)
        self.fs = float(cal.sample_rate_hz)
        self.t_start = 0.0
        self._rates = None
        faults: tuple = ()
        truth: dict[str, Any] = {}
        tp = truth_path(self.path)
        if tp.is_file():
            faults, truth, self._rates = read_truth_sidecar(tp, mmap=True)
            self.t_start = float(truth.get("can_log", {}).get("t_start_s", 0.0))
            self.fs = float(truth.get("sample_rate_hz", self.fs))
            sig = truth.get("sigma")
            if isinstance(sig, list) and truth.get("kind", cmap.kind) == cmap.kind:
                check_compatible(cal, len(sig), None, f"{self.path} (truth sidecar {tp.name})",
                                 kind=cmap.kind, cal_source=cal_source)
            _check_log_set(truth, cal, cmap, f"{self.path} (truth sidecar {tp.name})",
                           cal_source)
        self.header = Flight(
            t=np.zeros(0), raw=np.zeros((0, s.n)), valid=np.zeros((0, s.n), bool),
            sample_rate_hz=self.fs, sensor_names=tuple(c.name for c in s.sensors),
            raw_unit=s.sensors[0].raw_unit if s.n else "raw",
            omega_true=None if self._rates is None else np.zeros((0, 3)),
            faults=tuple(faults), truth=truth, source=str(self.path), kind=cmap.kind)
        self.acct = FrameAccounting()
        self.decoder = BlockDecoder(db, cmap, self.acct, sample_rate_hz=cal.sample_rate_hz)
        self.samples = 0

    def _piece(self, smp: Samples) -> Any:
        t = smp.t - float(self.decoder.t_first or 0.0) + self.t_start
        rates = None
        if self._rates is not None:
            k = np.clip(np.rint(t * self.fs).astype(np.int64), 0, self._rates.shape[0] - 1)
            rates = np.asarray(self._rates[k], float)
        return replace(self.header, t=t, raw=smp.raw, valid=smp.valid, omega_true=rates,
                       aux=aux_channels(self.cmap, smp.aux))

    def run(self, on_samples: Any) -> dict[str, Any]:
        """Read the whole log, calling ``on_samples(flight_piece)``; returns the accounting.

        Raises
        ------
        FileFormatError, ReplayError
            As :func:`read_log` (``strict``: after the first piece with corrupt frames).
        """
        def sink(frames: RawFrames) -> None:
            smp = self.decoder.feed(frames)
            self._check_strict()
            self._check_sensor_set()
            if smp.t.size:
                self.samples += smp.t.size
                on_samples(self._piece(smp))

        read_frames(self.path, strict=self.strict, progress=self.progress, sink=sink,
                    chunk_frames=self.chunk_frames, acct=self.acct)
        self._check_sensor_set()
        smp = self.decoder.flush()
        self._check_strict()
        if smp.t.size:
            self.samples += smp.t.size
            on_samples(self._piece(smp))
        return self.acct.to_dict()

    def _check_sensor_set(self) -> None:
        seen = self.decoder.siblings_seen
        if self.check_sensor_set and seen:
            n = self.cmap.n
            raise ConfigError(
                f"{self.path}: the log also carries {', '.join(sorted(seen))}, which the "
                f"{n}-sensor calibration of {self.cal.configuration} has no {self.cmap.kind} "
                "sensor for: a calibration only applies to the sensor set it was made for "
                "(give --map to replay a subset on purpose)")

    def silent_sensors(self) -> list[str]:
        """Names of the sensors that delivered no frame at all."""
        names = self.header.sensor_names
        out = []
        for k, slot in enumerate(self.decoder.slots):
            if self.decoder.delivered[k] == 0:
                out.extend(names[i] for i in slot.sensors)
        return out

    def _check_strict(self) -> None:
        if self.strict:
            _refuse_corruption(self.acct, self.path)
