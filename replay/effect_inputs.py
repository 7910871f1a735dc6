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
"""

from __future__ import annotations

import warnings

import numpy as np

from replay.flight_data import Flight

__all__ = ["flight_effect_inputs"]

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
    N, n = flight.raw.shape
    groups = list(flight.imu) if flight.imu else [""] * n
    avail: dict[str, list[int]] = {"specific_force": [], "temperature": []}
    force = temperature = None
    tri = _triads(flight)
    if tri:
        if len(tri) == 1:
            fallback = next(iter(tri.values()))
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)        # all-NaN samples
                fallback = np.nanmean(np.stack(list(tri.values())), axis=0)
        force = np.empty((N, n, 3))
        for i in range(n):
            force[:, i] = tri.get(groups[i], fallback)
            avail["specific_force"].append(i)
    aux = flight.aux
    if aux is not None and "temperature" in aux.kinds:
        chans = [j for j, k in enumerate(aux.kinds) if k == "temperature"]
        temperature = np.full((N, n), np.nan)
        for i in range(n):
            pick = [j for j in chans if groups[i] and groups[i] in (aux.imu[j], aux.names[j])]
            pick = pick or [j for j in chans if aux.names[j] == flight.sensor_names[i]]
            if not pick and len(chans) == 1 and not (groups[i] and aux.imu[chans[0]]):
                pick = chans                # the one channel, unless it is another IMU's
            if pick:
                j = pick[0]
                temperature[:, i] = np.where(aux.valid[:, j], aux.values[:, j], np.nan)
                avail["temperature"].append(i)
    return force, temperature, avail
