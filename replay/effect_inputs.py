"""The run-time inputs of the effect terms (:mod:`fdi.effects`) from a flight's channels.

A flight keeps accelerometers and temperatures beside its monitored sensors
(:class:`replay.flight_data.AuxChannels`). For monitored sensor i:

- **specific force** (m/s², MB frame): the accelerometer triad of sensor i's IMU group
  (channels ``accel:<imu>.x``, ``.y``, ``.z``, the triad's axes taken as the MB axes); when
  the sensor has no group or its group no triad, the one triad of the flight, or the mean of
  the triads valid at each sample when there are several;
- **temperature** (°C): the temperature channel of sensor i's IMU group, else one named
  after the sensor, else the flight's only temperature channel unless that one belongs to
  another IMU.

A sample the channel lacks is NaN (the term then contributes 0 there and is counted).

A CAN stream (``rimu replay``, ``rimu monitor``) has the channel map's auxiliary channels
instead (:class:`replay.channel_map.AuxChannel`, held onto the samples by
:class:`replay.aux_hold.AuxHold`): :func:`map_available` says which sensors have which input
(from the map alone, before any frame), :func:`map_effect_inputs` turns the held columns
into the specific force and temperature of each sensor. A sensor's specific force is the
least-squares solution ``f = A⁺·a`` over the accelerometer axes ``A`` (one unit body axis per
row) that apply to it and have a value at that sample; NaN where those do not span three
dimensions (a stale or missing axis of a triad).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from replay.channel_map import ChannelMap, aux_assignment
from replay.flight_data import Flight

__all__ = ["flight_effect_inputs", "map_available", "map_effect_inputs", "map_reasons",
           "row_inputs", "stream_inputs"]

_AXES = ("x", "y", "z")


def _triads(flight: Flight) -> dict[str, np.ndarray]:
    """Complete accelerometer triads by group, each (N, 3)."""
    aux = flight.aux
    if aux is None:
        return {}
    cols: dict[str, dict[str, int]] = {}
    for j, (k, name, imu) in enumerate(zip(aux.kinds, aux.names, aux.imu, strict=True)):
        if k != "accel":
            continue
        prefix, _, ax = name.rpartition(".")
        if ax not in _AXES:
            continue
        cols.setdefault(imu or prefix, {})[ax] = j
    return {g: np.where(aux.valid[:, [c[a] for a in _AXES]],
                        aux.values[:, [c[a] for a in _AXES]], np.nan)
            for g, c in cols.items() if all(a in c for a in _AXES)}


def _flight_force(flight: Flight, groups: list[str]) -> np.ndarray | None:
    """Specific force (N, n, 3) of each sensor from its IMU's accelerometer triad (the mean
    of the triads for a sensor of no IMU with one); None without triads."""
    tri = _triads(flight)
    if not tri:
        return None
    if len(tri) == 1:
        fallback = next(iter(tri.values()))
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)            # all-NaN samples
            fallback = np.nanmean(np.stack(list(tri.values())), axis=0)
    N, n = flight.raw.shape
    force = np.empty((N, n, 3))
    for i in range(n):
        force[:, i] = tri.get(groups[i], fallback)
    return force


def _flight_temperature(flight: Flight, groups: list[str]
                        ) -> tuple[np.ndarray | None, list[int]]:
    """Temperature (N, n) of each sensor (NaN where invalid) and the sensors that have a
    channel: its IMU's (or its own) channel, else the one channel of the flight unless that
    is another IMU's."""
    aux = flight.aux
    if aux is None or "temperature" not in aux.kinds:
        return None, []
    N, n = flight.raw.shape
    chans = [j for j, k in enumerate(aux.kinds) if k == "temperature"]
    temperature = np.full((N, n), np.nan)
    have = []
    for i in range(n):
        pick = [j for j in chans if groups[i] and groups[i] in (aux.imu[j], aux.names[j])]
        pick = pick or [j for j in chans if aux.names[j] == flight.sensor_names[i]]
        if not pick and len(chans) == 1 and not (groups[i] and aux.imu[chans[0]]):
            pick = chans                    # the one channel, unless it is another IMU's
        if pick:
            j = pick[0]
            temperature[:, i] = np.where(aux.valid[:, j], aux.values[:, j], np.nan)
            have.append(i)
    return temperature, have


def flight_effect_inputs(flight: Flight) -> tuple[np.ndarray | None, np.ndarray | None,
                                                  dict[str, list[int]]]:
    """Specific force and temperature per monitored sensor, and who has them.

    Returns
    -------
    force : ndarray, shape (N, n, 3), or None
        m/s² (NaN where the sensor has none at that sample); None without accelerometers.
    temperature : ndarray, shape (N, n), or None
        °C; None without temperature channels.
    available : dict
        ``{"specific_force": [sensors], "temperature": [sensors]}`` (0-based) that have a
        channel (:class:`fdi.effects.Compensator`'s ``available``).
    """
    n = flight.raw.shape[1]
    groups = list(flight.imu) if flight.imu else [""] * n
    force = _flight_force(flight, groups)
    temperature, with_temperature = _flight_temperature(flight, groups)
    avail = {"specific_force": list(range(n)) if force is not None else [],
             "temperature": with_temperature}
    return force, temperature, avail


def map_available(cmap: ChannelMap) -> dict[str, list[int]]:
    """``{"specific_force": [sensors], "temperature": [sensors]}`` (0-based) that the map's
    auxiliary channels give an input (:class:`fdi.effects.Compensator`'s ``available``)."""
    asg = aux_assignment(cmap)
    return {q: [i for i, ks in enumerate(asg[q]) if ks] for q in ("specific_force",
                                                                    "temperature")}


def map_reasons(cmap: ChannelMap) -> dict[str, str]:
    """What a term lacking an input is told, per input: which map, and what it lacks."""
    which = ("the default channel map (give --map with [[auxiliary]] channels)"
             if cmap.source.startswith("<") else f"the channel map {cmap.source}")
    return {"specific_force": f"{which} names no specific-force (accelerometer) channel "
                              "for this sensor",
            "temperature": f"{which} names no temperature channel for this sensor"}


def _columns(cmap: ChannelMap) -> dict[int, list[int]]:
    """Auxiliary entry → its column numbers (:func:`replay.slots.aux_columns` order)."""
    out: dict[int, list[int]] = {}
    c = 0
    for k, a in enumerate(cmap.auxiliary):
        out[k] = list(range(c, c + len(a.signals)))
        c += len(a.signals)
    return out


def _solve_force(A: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``f = A⁺·a`` per row over the finite columns of ``a`` (N, m); NaN where the finite
    axes do not span three dimensions."""
    N, m = a.shape
    f = np.full((N, 3), np.nan)
    ok = np.isfinite(a)
    if N == 0:
        return f
    codes = ok @ (1 << np.arange(m, dtype=np.int64)) if m < 62 else None
    if codes is None:                                    # pragma: no cover (62+ axes)
        codes = np.unique(ok, axis=0, return_inverse=True)[1]
    for code in np.unique(codes):
        rows = codes == code
        cols = ok[np.flatnonzero(rows)[0]]
        if cols.sum() < 3:
            continue
        Ak = A[cols]
        if np.linalg.matrix_rank(Ak, tol=1e-6) < 3:
            continue
        f[rows] = a[np.ix_(rows, cols)] @ np.linalg.pinv(Ak).T
    return f


def map_effect_inputs(cmap: ChannelMap, aux: np.ndarray | None
                      ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Specific force and temperature of each monitored sensor from the held auxiliary
    columns.

    Parameters
    ----------
    cmap : ChannelMap
    aux : ndarray, shape (N, m), or None
        ``Samples.aux``: the columns of :func:`replay.slots.aux_columns`, °C or m/s²
        along each signal's axis, NaN where none or stale.

    Returns
    -------
    force : ndarray, shape (N, n, 3), or None
        m/s², body frame; NaN where the sensor has none at that sample. None when the map
        has no specific-force channel.
    temperature : ndarray, shape (N, n), or None
        °C; NaN where none. None when the map has no temperature channel.
    """
    if aux is None or not cmap.auxiliary:
        return None, None
    aux = np.asarray(aux, float)
    N, n = aux.shape[0], cmap.n
    asg = aux_assignment(cmap)
    cols = _columns(cmap)
    force = temperature = None
    if any(asg["specific_force"]):
        force = np.full((N, n, 3), np.nan)
        solved: dict[tuple[int, ...], np.ndarray] = {}
        for i, ks in enumerate(asg["specific_force"]):
            if not ks:
                continue
            if ks not in solved:
                A = np.vstack([cmap.auxiliary[k].axes for k in ks])
                c = [col for k in ks for col in cols[k]]
                solved[ks] = _solve_force(A, aux[:, c])
            force[:, i] = solved[ks]
    if any(asg["temperature"]):
        temperature = np.full((N, n), np.nan)
        for i, ks in enumerate(asg["temperature"]):
            if ks:
                temperature[:, i] = aux[:, cols[ks[0]][0]]
    return force, temperature


def stream_inputs(monitor: Any, cmap: ChannelMap | None, aux: Any) -> dict[str, np.ndarray]:
    """``force`` / ``temperature`` keyword arguments of a compensated monitor
    (:class:`fdi.effects_monitor.CompensatedMonitor`) for the samples whose held auxiliary
    columns are ``aux`` ((N, m) array, or :class:`~replay.flight_data.AuxChannels`); empty
    when the monitor applies no term that reads them."""
    comp = getattr(monitor, "compensator", None)
    if comp is None or cmap is None or aux is None \
            or not comp.needs & {"specific_force", "temperature"}:
        return {}
    force, temp = map_effect_inputs(cmap, getattr(aux, "values", aux))
    kw = {}
    if force is not None:
        kw["force"] = force
    if temp is not None:
        kw["temperature"] = temp
    return kw


def row_inputs(inputs: dict[str, np.ndarray], k: int) -> dict[str, np.ndarray]:
    """Row ``k`` of :func:`stream_inputs`' arrays (the keyword arguments of one ``step``)."""
    return {name: v[k] for name, v in inputs.items()}
