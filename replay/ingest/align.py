"""Put the IMU streams of one log on one time base and account for every sample.

The base is the time stamps of a reference IMU (the one with most samples, or the one
named). Every other IMU is placed on it sample by sample:

- a sample stamped within ``tol`` of a base time is **kept** as it is;
- a base time between two samples of the IMU (closer together than ``gap_factor`` times
  the IMU's median interval) gets the linear interpolation of the two: **resampled**; the
  two samples count as ``used_for_resampling``;
- a base time with no such pair stays empty (``missing_on_base``: no sample, the monitor
  sees the sensor as silent);
- a sample of the IMU that serves no base time is **dropped**, with the reason.

Before that, each stream loses the samples whose time is not finite or does not increase
(duplicate or backwards stamps): dropped, with the reason. Per IMU,
``samples_in = kept + used_for_resampling + sum(dropped)``.

Implausible logs are refused, not ingested: rates beyond any gyro's range
(:data:`MAX_RATE_DPS`; with ``salvage`` those samples are dropped and counted instead) and
a time base faster or slower than any IMU (:data:`MAX_SAMPLE_RATE_HZ`,
:data:`MIN_SAMPLE_RATE_HZ`: seconds read as milliseconds or the reverse, a wrong time unit
in the map).

No time offset is applied: the IMUs are taken at their stamps (finding a lag between
them is the job of the in-flight calibration).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fdi.errors import ConfigError
from fdi.units import DPS
from replay.flight_data import AuxChannels, Flight
from replay.ingest.stream import ImuStream, LogRead

__all__ = ["INGEST_REPORT_SCHEMA", "MAX_RATE_DPS", "MAX_SAMPLE_RATE_HZ", "MIN_SAMPLE_RATE_HZ",
           "align_streams"]

INGEST_REPORT_SCHEMA = "rimu.ingest-report/1"
MAX_RATE_DPS = 1e5
"""No gyro measures beyond this (deg/s; the widest MEMS ranges are about 4000 deg/s): a
larger or non-finite-overflowing value is damage, not motion."""
MAX_SAMPLE_RATE_HZ = 2e4
"""No IMU log is sampled faster than this (Hz): a faster time base has a wrong time unit."""
MIN_SAMPLE_RATE_HZ = 1.0
"""Nor slower than this (Hz): milliseconds or microseconds read as seconds."""
_BEYOND = "rate beyond any gyro's range"
_AXES = ("x", "y", "z")


def _clean(s: ImuStream) -> tuple[ImuStream, dict[str, int]]:
    """Drop samples with non-finite or non-increasing time, or with a rate beyond any gyro's
    range (non-finite rates stay: the monitor sees them as invalid); count them by reason."""
    dropped: dict[str, int] = {}
    with np.errstate(invalid="ignore"):
        beyond = np.any(np.abs(s.gyro) > MAX_RATE_DPS * DPS, axis=1)
    if beyond.any():
        dropped[_BEYOND] = int(beyond.sum())
        s = s.take(~beyond)
    fin = np.isfinite(s.t)
    if not fin.all():
        dropped["non-finite time stamp"] = int((~fin).sum())
        s = s.take(fin)
    if s.size > 1:
        run_max = np.maximum.accumulate(s.t)
        keep = np.ones(s.size, bool)
        keep[1:] = s.t[1:] > run_max[:-1]
        if not keep.all():
            dropped["time stamp not increasing (duplicate or backwards)"] = \
                int((~keep).sum())
            s = s.take(keep)
    return s, dropped


def _median_dt(t: np.ndarray) -> float:
    d = np.diff(t)
    return float(np.median(d)) if d.size else float("nan")


def _placement(ts: np.ndarray, tb: np.ndarray, tol: float, max_gap: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """How each base time ``tb`` is filled from samples at ``ts``.

    Returns (i0, i1, w, how): values are ``(1-w)·x[i0] + w·x[i1]``; ``how`` is 0 for
    missing, 1 for an exact (kept) sample, 2 for an interpolated one.
    """
    n, m = ts.shape[0], tb.shape[0]
    i0 = np.zeros(m, int)
    i1 = np.zeros(m, int)
    w = np.zeros(m)
    how = np.zeros(m, np.int8)
    if n == 0:
        return i0, i1, w, how
    j = np.clip(np.searchsorted(ts, tb), 0, n - 1)
    jl = np.clip(j - 1, 0, n - 1)
    near_j = np.abs(ts[j] - tb) <= tol
    near_l = np.abs(ts[jl] - tb) <= tol
    exact_idx = np.where(near_j, j, jl)
    exact = near_j | near_l
    i0[exact] = i1[exact] = exact_idx[exact]
    how[exact] = 1
    if n > 1:
        a = np.clip(j - 1, 0, n - 2)
        b = a + 1
        span = ts[b] - ts[a]
        inside = (~exact) & (ts[a] < tb) & (tb < ts[b]) & (span <= max_gap)
        i0[inside], i1[inside] = a[inside], b[inside]
        w[inside] = (tb[inside] - ts[a[inside]]) / span[inside]
        how[inside] = 2
    return i0, i1, w, how


def _place(x: np.ndarray, i0: np.ndarray, i1: np.ndarray, w: np.ndarray,
           ok: np.ndarray) -> np.ndarray:
    """Interpolated values on the base (NaN where ``ok`` is False); x is (n,) or (n, k)."""
    ww = w if x.ndim == 1 else w[:, None]
    out = (1.0 - ww) * x[i0] + ww * x[i1] if x.shape[0] else \
        np.full((i0.shape[0], *x.shape[1:]), np.nan)
    out = np.asarray(out, float)
    out[~ok] = np.nan
    return out


def _pick_reference(streams: list[ImuStream], reference: str | None) -> int:
    names = [s.name for s in streams]
    if reference is None:
        return int(np.argmax([s.size for s in streams]))
    if reference not in names:
        raise ConfigError(f"reference IMU {reference!r} is not in the log (it has "
                          f"{', '.join(names)})")
    return names.index(reference)


def _time_base_ok(s: ImuStream) -> bool:
    """Whether a stream's time stamps can form a time base (two or more, a positive
    finite median interval)."""
    if s.size < 2:
        return False
    dt = _median_dt(s.t)
    return bool(np.isfinite(dt) and dt > 0)


def _drop_baseless(read: LogRead, streams: list[ImuStream], cleaned: list[Any],
                   reference: str | None, min_imus: int
                   ) -> tuple[list[ImuStream], list[Any], list[dict[str, Any]]]:
    """Salvage: the streams that can form a time base, their cleaning records, and a
    record of each stream dropped because it cannot (a log cut after its first sample).

    Raises
    ------
    ConfigError
        Fewer than ``min_imus`` streams remain, or ``reference`` names a dropped one.
    """
    keep = [i for i, s in enumerate(streams) if _time_base_ok(s)]
    dropped = [{"name": s.name, "source": s.source, "samples": int(s.size),
                "why": "cannot form a time base (fewer than two time stamps)"}
               for i, s in enumerate(streams) if i not in keep]
    named = ", ".join(f"{d['name']} ({d['source']}, {d['samples']} sample(s))"
                      for d in dropped)
    if len(keep) < min_imus:
        raise ConfigError(f"{read.path}: {len(keep)} IMU stream(s) can form a time base, "
                          f"{min_imus} needed; cannot form a time base from {named}")
    if reference is not None and reference in {d["name"] for d in dropped}:
        raise ConfigError(f"{read.path}: reference {reference} cannot form a time base "
                          f"(dropped with {named}); pick another with --reference")
    return [streams[i] for i in keep], [cleaned[i] for i in keep], dropped


def _check_base(read: LogRead, name: str, tb: np.ndarray, dt_b: float) -> None:
    """Refuse a reference stream that cannot be a time base: fewer than two time stamps,
    or a rate no IMU has (time stamps in another unit than read)."""
    if not np.isfinite(dt_b) or dt_b <= 0:
        raise ConfigError(f"{read.path}: reference {name} has "
                          f"{tb.shape[0]} time stamp(s); cannot form a time base (--salvage "
                          "drops the IMU streams that cannot and keeps the others)")
    if 1.0 / dt_b > MAX_SAMPLE_RATE_HZ:
        raise ConfigError(f"{read.path}: {name} is sampled every {dt_b:.3g} s "
                          f"({1.0 / dt_b:.3g} Hz), faster than any IMU (at most "
                          f"{MAX_SAMPLE_RATE_HZ:g} Hz): the time stamps are in another unit "
                          "than read (seconds taken as milliseconds?); set the time unit in "
                          "the --map")
    if 1.0 / dt_b < MIN_SAMPLE_RATE_HZ:
        raise ConfigError(f"{read.path}: {name} is sampled every {dt_b:.3g} s "
                          f"({1.0 / dt_b:.3g} Hz), slower than any IMU (at least "
                          f"{MIN_SAMPLE_RATE_HZ:g} Hz): the time stamps are in another unit "
                          "than read (milliseconds taken as seconds?); set the time unit in "
                          "the --map")


def _gaps(tb: np.ndarray, max_gap: float) -> list[dict[str, float]]:
    d = np.diff(tb)
    idx = np.flatnonzero(d > max_gap)
    return [{"t_s": float(tb[i]), "length_s": float(d[i])} for i in idx]


def _accounting(t: np.ndarray, dropped: dict[str, int], tb: np.ndarray, i0: np.ndarray,
                i1: np.ndarray, how: np.ndarray) -> tuple[int, int, dict[str, int]]:
    """Samples of one stream kept on the base, used for resampling, and dropped (why)."""
    used = np.zeros(t.shape[0], bool)
    used[i0[how == 1]] = True
    kept = int(used.sum())
    interp = np.zeros(t.shape[0], bool)
    interp[i0[how == 2]] = True
    interp[i1[how == 2]] = True
    interp &= ~used
    unused = t.shape[0] - kept - int(interp.sum())
    drop = dict(dropped)
    if unused:
        inside = (t >= tb[0]) & (t <= tb[-1]) & ~used & ~interp
        n_in = int(inside.sum())
        if n_in:
            drop["between base times (no base sample needs it)"] = n_in
        if unused - n_in:
            drop["outside the time base's span"] = unused - n_in
    return kept, int(interp.sum()), drop


def _aux_columns(s: Any, i0: np.ndarray, i1: np.ndarray, w: np.ndarray,
                 ok: np.ndarray) -> list[tuple[str, str, np.ndarray]]:
    """(kind, name, values on the base) of a stream's accelerometer axes and temperature."""
    cols = []
    if s.accel is not None:
        a = _place(s.accel, i0, i1, w, ok)
        cols.extend(("accel", f"{s.name}.{ax}", a[:, k]) for k, ax in enumerate(_AXES))
    if s.temperature is not None:
        cols.append(("temperature", s.name, _place(s.temperature, i0, i1, w, ok)))
    return cols


def align_streams(read: LogRead, *, reference: str | None = None, gap_factor: float = 2.5,
                  tol_fraction: float = 0.01, salvage: bool = False, min_imus: int = 1
                  ) -> tuple[Flight, dict[str, Any]]:
    """Put the streams of ``read`` on one time base.

    Parameters
    ----------
    read : LogRead
        At least one stream with samples.
    reference : str, optional
        Name of the IMU whose time stamps become the base (default: most samples).
    gap_factor : float
        Two samples farther apart than ``gap_factor`` × median interval are not
        interpolated between (a gap in the log).
    tol_fraction : float
        A sample within ``tol_fraction`` × the base's median interval of a base time is
        taken as on it (kept, not resampled).
    salvage : bool
        Drop (and count) samples with rates beyond any gyro's range instead of refusing,
        and drop (and name: ``report["dropped_imus"]``, one line in
        ``report["warnings"]``) the IMU streams that cannot form a time base (fewer than
        two time stamps: a log cut after their first sample).
    min_imus : int
        With ``salvage``, the fewest IMU streams that must remain.

    Returns
    -------
    flight : Flight
        ``kind="gyro"``, sensors ``imu1.x, imu1.y, imu1.z, imu2.x, ...`` in rad/s, IMU
        groups set, accelerometers (m/s²) and temperatures (°C) as aux channels.
    report : dict
        ``rimu.ingest-report/1``: the time base and, per IMU, the sample accounting.

    Raises
    ------
    ConfigError
        No stream has samples, ``reference`` names no IMU, rates beyond any gyro's range
        (without ``salvage``), a time base faster than any IMU, or (with ``salvage``)
        fewer than ``min_imus`` streams that can form a time base (naming the others).
    """
    cleaned = [_clean(s) for s in read.streams]
    if not salvage:
        _refuse_beyond_range(read, cleaned)
    streams = [c[0] for c in cleaned]
    if not streams or all(s.size == 0 for s in streams):
        raise ConfigError(f"{read.path}: no IMU samples to ingest")
    baseless: list[dict[str, Any]] = []
    if salvage:
        streams, cleaned, baseless = _drop_baseless(read, streams, cleaned, reference,
                                                    min_imus)
    r = _pick_reference(streams, reference)
    tb = streams[r].t
    dt_b = _median_dt(tb)
    _check_base(read, streams[r].name, tb, dt_b)
    tol = tol_fraction * dt_b
    gyro_cols, valid_cols, names, imu_groups = [], [], [], []
    aux_k, aux_n, aux_g, aux_v = [], [], [], []
    imus: list[dict[str, Any]] = []
    for s, (_, dropped) in zip(streams, cleaned, strict=True):
        dt_s = _median_dt(s.t) if s.size > 1 else dt_b
        i0, i1, w, how = _placement(s.t, tb, tol, gap_factor * max(dt_s, dt_b))
        ok = how > 0
        g = _place(s.gyro, i0, i1, w, ok)
        for k, ax in enumerate(_AXES):
            gyro_cols.append(g[:, k])
            valid_cols.append(ok)
            names.append(f"{s.name}.{ax}")
            imu_groups.append(s.name)
        for kind, name, values in _aux_columns(s, i0, i1, w, ok):
            aux_k.append(kind)
            aux_n.append(name)
            aux_g.append(s.name)
            aux_v.append(values)
        imus.append(_imu_record(s, dropped, _accounting(s.t, dropped, tb, i0, i1, how), how,
                                g[ok], dt_s))
    raw = np.column_stack(gyro_cols)
    valid = np.column_stack(valid_cols)
    aux = None
    if aux_k:
        av = np.column_stack(aux_v)
        aux = AuxChannels(tuple(aux_k), tuple(aux_n), tuple(aux_g), av, np.isfinite(av))
    fs = 1.0 / dt_b
    flight = Flight(t=np.asarray(tb, float), raw=raw, valid=valid, sample_rate_hz=fs,
                    sensor_names=tuple(names), raw_unit="rad/s", source=read.path,
                    kind="gyro", imu=tuple(imu_groups), aux=aux, events=read.events)
    report = _ingest_report(read, streams[r].name, tb, dt_b, tol, gap_factor, imus, baseless)
    return flight, report


def _refuse_beyond_range(read: LogRead, cleaned: list[tuple[Any, dict[str, int]]]) -> None:
    """Refuse a stream with rates beyond any gyro's range (a damaged log or a wrong unit).

    Parameters
    ----------
    read : LogRead
    cleaned : list of (stream, dropped)
        :func:`_clean` of each of ``read``'s streams.

    Raises
    ------
    ConfigError
        Naming the stream and the count.
    """
    for s, (_, dropped) in zip(read.streams, cleaned, strict=True):
        if dropped.get(_BEYOND):
            raise ConfigError(f"{read.path}: {s.name} ({s.source}): {dropped[_BEYOND]} of "
                              f"{s.size} samples hold rates beyond any gyro's range (over "
                              f"{MAX_RATE_DPS:g} deg/s): a damaged log or a wrong unit; "
                              "--salvage drops and counts them")


def _imu_record(s: Any, dropped: dict[str, int], accounting: tuple[int, int, dict[str, int]],
                how: np.ndarray, g_ok: np.ndarray, dt_s: float) -> dict[str, Any]:
    """One IMU's entry of the ingest report: its sample accounting.

    Parameters
    ----------
    s : stream
        The cleaned stream.
    dropped : dict of str to int
        Samples :func:`_clean` dropped, by reason.
    accounting : (int, int, dict)
        :func:`_accounting`: kept, used for resampling, dropped.
    how : ndarray of int
        Per base sample: 0 missing, 1 on a sample, 2 resampled.
    g_ok : ndarray
        Its gyro values on the base samples it covers.
    dt_s : float
        Its median interval (s).

    Returns
    -------
    dict
    """
    kept, n_interp, drop = accounting
    return {
        "name": s.name, "source": s.source, "device_id": s.device_id,
        "samples_in": int(s.size + sum(dropped.values())), "kept": kept,
        "used_for_resampling": n_interp, "dropped": drop,
        "resampled_on_base": int((how == 2).sum()),
        "missing_on_base": int((how == 0).sum()),
        "nonfinite_gyro_values": int((~np.isfinite(g_ok)).sum()),
        "median_dt_s": dt_s if np.isfinite(dt_s) else None,
        "accel": s.accel is not None, "temperature": s.temperature is not None,
        "error_count_max": (int(np.max(s.error_count)) if s.error_count is not None
                            and s.size else None),
        "notes": list(s.notes)}


def _ingest_report(read: LogRead, reference: str, tb: np.ndarray, dt_b: float, tol: float,
                   gap_factor: float, imus: list[dict[str, Any]],
                   baseless: list[dict[str, Any]]) -> dict[str, Any]:
    """The ``rimu.ingest-report/1`` document of an alignment.

    Parameters
    ----------
    read : LogRead
    reference : str
        The IMU whose time stamps are the base.
    tb : ndarray
        The time base (s).
    dt_b, tol : float
        Its median interval and the on-sample tolerance (s).
    gap_factor : float
    imus : list of dict
        :func:`_imu_record` of each IMU.
    baseless : list of dict
        IMU streams dropped for want of a time base.

    Returns
    -------
    dict
    """
    gaps = _gaps(tb, gap_factor * dt_b)
    return {
        "schema": INGEST_REPORT_SCHEMA, "source": read.path, "format": read.format,
        "salvaged": read.damage is not None,
        "damage": read.damage.to_dict() if read.damage is not None else None,
        "time_base": {"reference": reference, "samples": tb.shape[0],
                      "t_start_s": float(tb[0]), "t_end_s": float(tb[-1]),
                      "median_dt_s": dt_b, "sample_rate_hz": 1.0 / dt_b,
                      "tolerance_s": tol, "gap_factor": gap_factor,
                      "gaps": gaps[:50], "n_gaps": len(gaps)},
        "imus": imus, "meta": read.meta,
        "dropped_imus": baseless,
        "warnings": [f"dropped {len(baseless)} IMU stream(s) that cannot form a time base: "
                     + ", ".join(f"{d['name']} ({d['source']}, {d['samples']} sample(s))"
                                 for d in baseless)] if baseless else [],
        "events": {"count": len(read.events),
                   "by_category": {c: sum(e.category == c for e in read.events)
                                   for c in sorted({e.category for e in read.events})}}}
