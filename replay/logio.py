"""CAN logs of flights: write them with python-can's writers, read them back with its readers.

Writing (:func:`write_flight_log`): each sample of a :class:`~replay.flight.Flight` becomes
one frame per sensor of the shipped DBC (:mod:`replay.frames`: raw float32, sample counter,
status, rolling counter, CRC-8 SAE J1850), encoded by cantools and written by
``can.Logger(path)`` (the suffix picks ``.asc``, ``.blf``, ``.log``, ``.csv``, ``.trc``).
Timestamps are realistic epoch times (BLF loses precision for small ones): sample k's
frames go out at ``t0_epoch_s + t_k + i·frame_gap_s + U(0, jitter_s)`` for sensor i = 0..n-1
(the first sensor without jitter: it transmits at the sampling instant). A sensor without a
sample (``valid`` False) sends no frame.

The truth sidecar is ``<log>.truth.json`` (``rimu.flight-truth/1``, written by
:func:`replay.flight.write_truth_sidecar`, true rates in ``<log>.truth_rates.npy``) with an
extra ``"can_log"`` record: ``{"file", "format", "dbc", "t0_epoch_s", "t_start_s",
"frame_gap_s", "jitter_s", "frames"}``.

Reading (:func:`read_frames`, :func:`read_log`): python-can's reader for the suffix, once
over the file, gathering (timestamp, id, payload) for the vectorised decoder
(:mod:`replay.assemble`). What python-can does with damaged files, measured on 4.6.1:

- ``.log`` (candump): a line it cannot parse raises ``ValueError`` and ends its generator;
  rimu counts the line as a ``garbage_line`` and resumes with the next line.
- ``.asc``: lines that do not look like frames are skipped silently; rimu tracks the lines
  between frames and counts those that are not header, comment or known event lines as
  ``garbage_line``; a frame line that raises is a ``garbage_line`` too and reading resumes.
- ``.blf``: read by :class:`replay.blf.ResyncBLFReader`, which skips a damaged container or
  object and resynchronises on the next valid one (each damage an error of kind ``resync``
  with the bytes skipped; the frames lost show in the counter gaps); a file without the BLF
  signature is "not a BLF file";
- other binary formats cannot resume: the error (where, why) is reported, the frames read
  so far are kept.

Flight time of a decoded sample is its earliest frame's timestamp minus the log's first
frame timestamp, plus the sidecar's ``t_start_s`` when there is one (0 otherwise).
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterator
from dataclasses import replace
from itertools import islice
from pathlib import Path
from typing import Any

import can
import numpy as np

from fdi.calfile import Calibration, check_compatible
from fdi.errors import ConfigError, FileFormatError, ReplayError
from replay.accounting import FrameAccounting
from replay.assemble import (
    FRAME_DATA,
    FRAME_ERROR,
    FRAME_REMOTE,
    BlockDecoder,
    RawFrames,
    Samples,
    decode_frames,
)
from replay.channel_map import (
    ChannelMap,
    check_against_calibration,
    default_channel_map,
    load_channel_map,
)
from replay.frames import encode_imu_frames, imu_message_name, load_dbc

__all__ = [
    "CORRUPTION_REASONS",
    "DEFAULT_T0_EPOCH_S",
    "FRAME_GAP_S",
    "JITTER_S",
    "LOG_SUFFIXES",
    "LogStream",
    "aux_channels",
    "frames_fit",
    "read_frames",
    "read_log",
    "resolve_map",
    "samples_to_flight",
    "truth_path",
    "write_flight_log",
]

LOG_SUFFIXES = (".asc", ".blf", ".log", ".csv", ".trc")
"""CAN log suffixes rimu writes through python-can."""
DEFAULT_T0_EPOCH_S = 1_767_225_600.0
"""2026-01-01T00:00:00Z: the epoch time of a simulated log's first sample."""
FRAME_GAP_S = 130e-6
"""Spacing (s) of a simulated log's frames within one sample (about one 8-byte frame at
500 kbit/s)."""
JITTER_S = 60e-6
"""Most random delay (s) added to a simulated sample's frames."""
CORRUPTION_REASONS = frozenset({"wrong_length", "crc", "counter_repeat", "counter_jump",
                                "out_of_order", "duplicate", "garbage_line",
                                "nonfinite_time"})
"""Rejection reasons that make a ``strict`` replay fail."""
_MAX_ERRORS = 50
_CHUNK = 65536


def truth_path(log: str | Path) -> Path:
    """The truth sidecar of a log: ``<log>.truth.json``."""
    return Path(str(log) + ".truth.json")


def _suffix(path: Path) -> str:
    sfx = path.suffixes
    if sfx and sfx[-1].lower() == ".gz" and len(sfx) > 1:
        return sfx[-2].lower()
    return path.suffix.lower()


# -- writing -----------------------------------------------------------------------------
_AXIS_OF = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _aux_to_write(flight: Any, temperature_every: int) -> list[tuple[int, str, int, Any]]:
    """The flight's auxiliary channels a CAN log carries: (aux column, message, every,
    AuxChannel) — accelerometer axes (gyro flights) as ``RIMU_ACCEL_ii``, temperatures as
    ``RIMU_TEMP_ii``, each applied to its IMU group's sensors (else to all)."""
    from replay.channel_map import AUX_TIMEOUT_S, AuxChannel

    aux = getattr(flight, "aux", None)
    if aux is None:
        return []
    names = tuple(flight.sensor_names)
    groups = tuple(flight.imu) if getattr(flight, "imu", ()) else ()
    out = []
    n_acc = n_temp = 0
    for j, (kind, name, imu) in enumerate(zip(aux.kinds, aux.names, aux.imu, strict=True)):
        members = tuple(nm for nm, g in zip(names, groups, strict=True) if imu and g == imu) \
            if groups else ()
        if kind == "accel" and getattr(flight, "kind", "gyro") == "gyro":
            ax = name.rpartition(".")[2]
            if ax not in _AXIS_OF:
                continue
            n_acc += 1
            msg = imu_message_name("accel", n_acc)
            out.append((j, msg, 1, AuxChannel(
                name=f"accel:{name}", quantity="specific_force", message=msg,
                signals=("RAW",), unit="m/s^2", axes=np.array([_AXIS_OF[ax]]),
                sensors=members or None, timeout_s=AUX_TIMEOUT_S["specific_force"],
                counter_signal="COUNTER", crc_signal="CRC", status_signal="STATUS")))
        elif kind == "temperature":
            n_temp += 1
            if n_temp > 12:
                raise ConfigError("the shipped DBC carries temperatures 1..12 "
                                  "(RIMU_TEMP_01..12), the flight has more")
            if not members and name in names:
                members = (name,)
            msg = f"RIMU_TEMP_{n_temp:02d}"
            period = temperature_every / float(flight.sample_rate_hz)
            out.append((j, msg, temperature_every, AuxChannel(
                name=f"temperature:{name}", quantity="temperature", message=msg,
                signals=("RAW",), unit="degC", sensors=members or None,
                timeout_s=max(AUX_TIMEOUT_S["temperature"], 3 * period),
                counter_signal="COUNTER", crc_signal="CRC", status_signal="STATUS")))
    return out


def frames_fit(n_frames: int, sample_rate_hz: float, frame_gap_s: float = FRAME_GAP_S,
               jitter_s: float = JITTER_S) -> bool:
    """Whether one sample's ``n_frames`` frames, ``frame_gap_s`` apart plus up to
    ``jitter_s``, fit in one sample period (what :func:`write_flight_log` needs)."""
    return n_frames * frame_gap_s + jitter_s < 1.0 / sample_rate_hz


def write_flight_log(flight: Any, path: str | Path, *, dbc: str | Path | None = None,
                     t0_epoch_s: float = DEFAULT_T0_EPOCH_S, frame_gap_s: float = FRAME_GAP_S,
                     jitter_s: float = JITTER_S, seed: int = 0, channel: int = 0,
                     auxiliary: bool = True, temperature_every: int = 10) -> tuple:
    """Write a flight as a CAN log (python-can writer picked by suffix) + truth sidecar.

    Parameters
    ----------
    flight : replay.flight.Flight
    path : str or Path
        ``.asc``, ``.blf``, ``.log`` (candump), ``.csv`` or ``.trc``.
    dbc : path, optional
        A DBC with the shipped DBC's ``RIMU_<KIND>_ii`` messages (default: the shipped one).
    t0_epoch_s : float
        Epoch time of ``t = 0``.
    frame_gap_s, jitter_s : float
        Sensor i's frame leaves ``i·frame_gap_s + U(0, jitter_s)`` after the sampling
        instant (sensor 1: no jitter). ``n·frame_gap_s + jitter_s`` must stay under one period.
    seed : int
        Seed of the jitter.
    channel : int
    auxiliary : bool
        Also write the flight's auxiliary channels (``flight.aux``): accelerometer axes of a
        gyro flight as ``RIMU_ACCEL_ii`` (m/s², every sample) and temperatures as
        ``RIMU_TEMP_ii`` (°C, every ``temperature_every``-th sample), after the sensors'
        frames of the sample.
    temperature_every : int
        Temperature frames go out every this many samples.

    Returns
    -------
    tuple of replay.channel_map.AuxChannel
        The auxiliary channels written, for a channel map
        (``default_channel_map(..., auxiliary=...)``); empty when none.

    Raises
    ------
    ConfigError
        Unknown suffix, more sensors than the DBC carries, frames that would overlap.
    """
    p = Path(path)
    if _suffix(p) not in LOG_SUFFIXES:
        raise ConfigError(f"{p}: unknown CAN log suffix; expected one of "
                          f"{', '.join(LOG_SUFFIXES)}")
    db = load_dbc(dbc)
    N, n = flight.raw.shape
    fs = float(flight.sample_rate_hz)
    extra = _aux_to_write(flight, int(temperature_every)) if auxiliary else []
    nf = n + len(extra)
    if not frames_fit(nf, fs, frame_gap_s, jitter_s):
        raise ConfigError(f"{nf} frames of {frame_gap_s * 1e6:.0f} µs do not fit in one "
                          f"{1e3 / fs:.2f} ms sample period")
    kind = getattr(flight, "kind", "gyro")
    rng = np.random.default_rng([seed, 7])
    valid = np.asarray(flight.valid, bool)
    t = np.asarray(flight.t, float)
    times, ids, payloads = [], [], []
    for i in range(n):
        msg = db.get_message_by_name(imu_message_name(kind, i + 1))
        k = np.flatnonzero(valid[:, i])
        jit = rng.uniform(0.0, jitter_s, k.size) if i > 0 else np.zeros(k.size)
        times.append(t0_epoch_s + t[k] + i * frame_gap_s + jit)
        ids.append(np.full(k.size, msg.frame_id, np.int64))
        payloads.extend(encode_imu_frames(msg, flight.raw[k, i], k, np.arange(k.size)))
    for j, (col, name, every, _) in enumerate(extra):
        msg = db.get_message_by_name(name)
        ok = np.asarray(flight.aux.valid[:, col], bool) & (np.arange(N) % every == 0)
        k = np.flatnonzero(ok)
        times.append(t0_epoch_s + t[k] + (n + j) * frame_gap_s
                     + rng.uniform(0.0, jitter_s, k.size))
        ids.append(np.full(k.size, msg.frame_id, np.int64))
        payloads.extend(encode_imu_frames(msg, flight.aux.values[k, col], k,
                                          np.arange(k.size)))
    ts = np.concatenate(times)
    fid = np.concatenate(ids)
    order = np.argsort(ts, kind="stable")
    p.parent.mkdir(parents=True, exist_ok=True)
    with can.Logger(str(p)) as writer:
        for j in order.tolist():
            writer.on_message_received(can.Message(
                timestamp=float(ts[j]), arbitration_id=int(fid[j]), is_extended_id=False,
                data=payloads[j], channel=channel, dlc=8))
    from replay.flight_io import write_truth_sidecar

    truth = dict(flight.truth)
    truth["can_log"] = {"file": p.name, "format": _suffix(p),
                        "dbc": "rimu_imu.dbc" if dbc is None else str(dbc),
                        "t0_epoch_s": t0_epoch_s, "t_start_s": float(t[0]) if N else 0.0,
                        "frame_gap_s": frame_gap_s, "jitter_s": jitter_s,
                        "frames": int(ts.size), "raw_unit": str(flight.raw_unit),
                        "sensor_names": list(flight.sensor_names)}
    if extra:
        truth["can_log"]["auxiliary"] = [
            {"name": a.name, "quantity": a.quantity, "message": a.message,
             "every_samples": every, "sensors": "all" if a.sensors is None else list(a.sensors)}
            for _, _, every, a in extra]
    write_truth_sidecar(replace(flight, truth=truth), truth_path(p))
    return tuple(a for _, _, _, a in extra)


# -- reading raw frames --------------------------------------------------------------------
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


class _Gather:
    """Collects frames from python-can messages (one pass, plain lists).

    With a ``sink``, every ``chunk`` frames are handed to it as :class:`RawFrames` and
    forgotten (:meth:`spill`), so that memory stays bounded on long logs.
    """

    def __init__(self, sink: Any = None, chunk: int = 1 << 18) -> None:
        self.sink = sink
        self.chunk = int(chunk)
        self.handed = 0
        self.t: list[float] = []
        self.arb: list[int] = []
        self.ext: list[bool] = []
        self.ch: list[Any] = []
        self.data = bytearray()
        self.lengths: list[int] = []
        self.special: list[tuple[int, int]] = []

    def _reset(self) -> None:
        # in place: the reading loop holds bound methods of these lists
        for x in (self.t, self.arb, self.ext, self.ch, self.lengths, self.special):
            x.clear()
        del self.data[:]

    def add(self, msg: can.Message) -> None:
        """Append one message (the text-log path; the binary path inlines these appends,
        :func:`_consume_plain`)."""
        if msg.is_error_frame or msg.is_remote_frame:
            self.special.append((len(self.t), FRAME_ERROR if msg.is_error_frame
                                 else FRAME_REMOTE))
        self.t.append(msg.timestamp)
        self.arb.append(msg.arbitration_id)
        self.ext.append(msg.is_extended_id)
        self.ch.append(msg.channel)
        self.data += msg.data
        self.lengths.append(len(msg.data))

    def spill(self, force: bool = False) -> None:
        """Hand the frames gathered so far to the sink (when ``chunk`` are there)."""
        if self.sink is not None and self.t and (force or len(self.t) >= self.chunk):
            fr = self.frames()
            self.handed += len(fr)
            self._reset()
            self.sink(fr)

    def frames(self) -> RawFrames:
        M = len(self.t)
        ft = np.zeros(M, np.int8)
        for j, k in self.special:
            ft[j] = k
        ch = np.empty(M, dtype=object)
        ch[:] = self.ch
        uniq = set(self.ch)
        if uniq:
            norm = {c: _norm_channel(c) for c in uniq}
            if any(norm[c] is not c for c in uniq):
                ch[:] = [norm[c] for c in self.ch]
        return RawFrames(t=np.array(self.t, dtype=float),
                         arbitration_id=np.array(self.arb, dtype=np.int64),
                         extended=np.array(self.ext, dtype=bool), channel=ch,
                         payload=np.frombuffer(self.data, np.uint8).copy(),
                         lengths=np.array(self.lengths, dtype=np.int64), frame_type=ft)


_CH = re.compile(r"^v?can(\d+)$")


def _norm_channel(c: Any) -> Any:
    """``"can0"``, ``"vcan0"``, ``"0"`` → 0; anything else unchanged."""
    if isinstance(c, str):
        m = _CH.match(c)
        if m:
            return int(m.group(1))
        if c.isdigit():
            return int(c)
    return c


def _consume(it: Iterator[can.Message], g: _Gather, lines: _Lines | None,
             acct: FrameAccounting, bar: Any) -> None:
    """Gather python-can's messages into ``g``; with ``lines`` (text logs) also account
    for the lines python-can skipped."""
    if lines is None:
        _consume_plain(it, g, bar)
    else:
        _consume_lines(it, g, lines, acct, bar)


def _consume_plain(it: Iterator[can.Message], g: _Gather, bar: Any) -> None:
    """The hot path: one pass over python-can's messages, plain appends, in chunks (the
    progress bar moves between chunks)."""
    t_app, a_app, e_app, c_app, l_app = (g.t.append, g.arb.append, g.ext.append,
                                         g.ch.append, g.lengths.append)
    s_app = g.special.append
    buf = g.data
    step = min(_CHUNK, g.chunk) if g.sink is not None else _CHUNK
    while True:
        n0 = len(g.t)
        for msg in islice(it, step):
            if msg.is_error_frame or msg.is_remote_frame:
                s_app((len(g.t), FRAME_ERROR if msg.is_error_frame else FRAME_REMOTE))
            t_app(msg.timestamp)
            a_app(msg.arbitration_id)
            e_app(msg.is_extended_id)
            c_app(msg.channel)
            x = msg.data
            buf += x
            l_app(len(x))
        got = len(g.t) - n0
        if bar is not None:
            bar.update(got)
        g.spill()
        if got < step:
            return


def _consume_lines(it: Iterator[can.Message], g: _Gather, lines: _Lines,
                   acct: FrameAccounting, bar: Any) -> None:
    """Text logs: as :func:`_consume_plain`, and every line python-can passed over
    without a frame is reported (unless it is a known non-frame line)."""
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


def read_frames(path: str | Path, *, strict: bool = False, progress: bool = True,
                sink: Any = None, chunk_frames: int = 1 << 18,
                acct: FrameAccounting | None = None) -> tuple[RawFrames, FrameAccounting]:
    """Read every frame of a CAN log with python-can (see the module docstring).

    With ``sink``, frames go to ``sink(RawFrames)`` in blocks of about ``chunk_frames`` as
    they are read (the returned frames are then empty): memory stays bounded.

    Returns
    -------
    frames : RawFrames
        The frames read (``acct.read`` does not include them yet: :func:`decode_frames`
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
    sfx = _suffix(p)
    acct = acct if acct is not None else FrameAccounting()
    g = _Gather(sink, chunk_frames)
    bar = None
    if progress and p.stat().st_size > 20_000_000:
        from tqdm import tqdm

        bar = tqdm(desc=f"reading {p.name}", unit=" frames", unit_scale=True, leave=False)
    try:
        gz = str(p).lower().endswith(".gz")
        if sfx in (".log", ".asc") and not gz:
            _read_text(p, sfx, g, acct, strict, bar)
        elif sfx == ".blf" and not gz:
            _read_blf(p, g, acct, strict, bar)
        else:
            _read_binary(p, sfx, g, acct, strict, bar)
    finally:
        if bar is not None:
            bar.close()
    g.spill(force=True)
    return g.frames(), acct


def _read_blf(p: Path, g: _Gather, acct: FrameAccounting, strict: bool, bar: Any) -> None:
    """A BLF file through :class:`replay.blf.ResyncBLFReader` (damage reported, resumed)."""
    from replay.blf import ResyncBLFReader

    reader = ResyncBLFReader(p)       # FileFormatError: not a BLF file
    try:
        _consume(iter(reader), g, None, acct, bar)
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


def _read_binary(p: Path, sfx: str, g: _Gather, acct: FrameAccounting, strict: bool,
                 bar: Any) -> None:
    """Any other log through python-can's reader for its suffix (cannot resume)."""
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
            _consume(iter(reader), g, None, acct, bar)
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


def _read_text(p: Path, sfx: str, g: _Gather, acct: FrameAccounting, strict: bool,
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
                _consume(iter(reader), g, lines if sfx == ".asc" else None, acct, bar)
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


# -- reading a flight ------------------------------------------------------------------------
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
        bad = {k: v for k, v in acct.rejected.items() if k in CORRUPTION_REASONS and v}
        if bad:
            raise ReplayError(f"{path}: corrupt frames: "
                              + ", ".join(f"{v} {k}" for k, v in sorted(bad.items())))
    ok = frames.frame_type == FRAME_DATA
    finite = ok & np.isfinite(frames.t)
    t_first = float(frames.t[finite].min()) if finite.any() else 0.0
    flight = samples_to_flight(samples, cal, cmap, t_first_frame=t_first, source=str(path))
    return flight, acct.to_dict()


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
        if not self.strict:
            return
        bad = {k: v for k, v in self.acct.rejected.items() if k in CORRUPTION_REASONS and v}
        if bad:
            raise ReplayError(f"{self.path}: corrupt frames: "
                              + ", ".join(f"{v} {k}" for k, v in sorted(bad.items())))
