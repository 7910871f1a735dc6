"""Write a flight as a CAN log with python-can's writers (the suffix picks the writer).

Each sample of a :class:`~replay.flight.Flight` becomes one frame per sensor of the shipped
DBC (:mod:`replay.frames`: raw float32, sample counter, status, rolling counter, CRC-8 SAE
J1850), encoded by cantools and written by ``can.Logger(path)`` (the suffix picks ``.asc``,
``.blf``, ``.log``, ``.csv``, ``.trc``; python-can's ``MESSAGE_WRITERS``). Timestamps are
realistic epoch times (BLF loses precision for small ones): sample k's frames go out at
``t0_epoch_s + t_k + i·frame_gap_s + U(0, jitter_s)`` for sensor i = 0..n-1 (the first
sensor without jitter: it transmits at the sampling instant). A sensor without a sample
(``valid`` False) sends no frame.

The truth sidecar is ``<log>.truth.json`` (``rimu.flight-truth/1``, written by
:func:`replay.flight.write_truth_sidecar`, true rates in ``<log>.truth_rates.npy``) with an
extra ``"can_log"`` record: ``{"file", "format", "dbc", "t0_epoch_s", "t_start_s",
"frame_gap_s", "jitter_s", "frames"}``. :mod:`replay.can_read` reads the frames back.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import can
import numpy as np

from fdi.errors import ConfigError
from replay.can_files import log_suffix, truth_path
from replay.channel_map import AUX_TIMEOUT_S, AuxChannel
from replay.frames import encode_imu_frames, imu_message_name, load_dbc

__all__ = [
    "DEFAULT_T0_EPOCH_S",
    "FRAME_GAP_S",
    "JITTER_S",
    "LOG_SUFFIXES",
    "frames_fit",
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


_AXIS_OF = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _aux_to_write(flight: Any, temperature_every: int) -> list[tuple[int, str, int, AuxChannel]]:
    """The flight's auxiliary channels a CAN log carries: (aux column, message, every,
    AuxChannel) — accelerometer axes (gyro flights) as ``RIMU_ACCEL_ii``, temperatures as
    ``RIMU_TEMP_ii``, each applied to its IMU group's sensors (else to all)."""
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
    if log_suffix(p) not in LOG_SUFFIXES:
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
    truth["can_log"] = {"file": p.name, "format": log_suffix(p),
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


