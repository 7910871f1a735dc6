"""What a log holds, before anything is written (``rimu inspect LOG``; like pyulog's
``ulog_info``).

:func:`inventory` reads a log with the reader of its format (:func:`replay.ingest.read_any`,
in salvage mode so that a damaged log is described, not refused) and returns, per IMU
stream: where its samples come from, how many, the rate (from the median time step), the
time span and duration, the gaps (time steps over :data:`GAP_FACTOR` times the median),
duplicate or backward time stamps, what else it carries (accelerometer, temperature,
device id, error counter) and the samples marked physically implausible; then the log's
declared events (by category, with the first ones) and its damage (stretches, samples
lost). Nothing is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["GAP_FACTOR", "INVENTORY_SCHEMA", "format_inventory", "inventory"]

INVENTORY_SCHEMA = "rimu.inventory/1"
GAP_FACTOR = 1.5
"""A time step over this many median steps is a gap."""
_EVENTS_SHOWN = 10


def _stream(s: Any, implausible: dict[str, Any]) -> dict[str, Any]:
    t = np.asarray(s.t, float)
    n = int(t.shape[0])
    d: dict[str, Any] = {"name": s.name, "source": s.source, "samples": n,
                         "accel": s.accel is not None, "temperature": s.temperature is not None,
                         "device_id": s.device_id, "error_count": s.error_count is not None,
                         "notes": list(s.notes)}
    if n:
        d["t_start_s"], d["t_end_s"] = float(t[0]), float(t[-1])
        d["duration_s"] = float(t[-1] - t[0])
    dt = np.diff(t)
    fwd = dt[dt > 0]
    step = float(np.median(fwd)) if fwd.size else float("nan")
    d["sample_rate_hz"] = 1.0 / step if np.isfinite(step) and step > 0 else None
    gaps = np.flatnonzero(dt > GAP_FACTOR * step) if np.isfinite(step) else np.zeros(0, int)
    d["gaps"] = {"count": int(gaps.size),
                 "missing_samples": int(sum(max(0, round(dt[k] / step) - 1) for k in gaps)),
                 "longest_s": float(dt[gaps].max()) if gaps.size else 0.0,
                 "first": [{"t_s": float(t[k]), "length_s": float(dt[k])} for k in gaps[:5]]}
    d["duplicate_stamps"] = int(np.count_nonzero(dt == 0))
    d["backward_stamps"] = int(np.count_nonzero(dt < 0))
    fin = np.isfinite(np.asarray(s.gyro, float)).all(axis=1)
    d["non_finite_samples"] = int(n - np.count_nonzero(fin))
    d["implausible"] = implausible.get(s.name, {})
    return d


def inventory(path: str | Path, fmt: str = "auto", *, map_path: str | Path | None = None,
              px4_topic: str = "auto") -> dict[str, Any]:
    """The inventory of one log (module docstring), JSON-ready.

    Parameters
    ----------
    path : str or Path
    fmt : str
        :data:`replay.ingest.readers.FORMATS`.
    map_path : str or Path, optional
        ``rimu.ingest-map/1`` TOML (CSV, R data; optional for .mat).
    px4_topic : str

    Returns
    -------
    dict
        ``{"schema", "path", "format", "bytes", "imus": [...], "events": {...},
        "damage": ... or None, "warnings": [...]}``.

    Raises
    ------
    FileFormatError
        A file its reader cannot read at all (not a log of the format, no IMU samples).
    """
    from replay.ingest import read_any

    read = read_any(path, fmt, map_path=map_path, salvage=True, px4_topic=px4_topic)
    meta = dict(read.meta)
    imus = [_stream(s, meta.get("implausible", {})) for s in read.streams]
    cats: dict[str, int] = {}
    for e in read.events:
        cats[e.category] = cats.get(e.category, 0) + 1
    events = {"count": len(read.events), "by_category": cats,
              "first": [{"t_s": float(e.t_s), "t_end_s": float(e.t_end_s),
                         "category": e.category, "text": e.text}
                        for e in sorted(read.events, key=lambda e: (e.category == "info",
                                                                    e.t_s))[:_EVENTS_SHOWN]]}
    dmg = None
    if read.damage is not None:
        dmg = {"what": read.damage.message, "offset": read.damage.offset,
               "line": read.damage.line,
               "stretches": [dict(x) for x in read.damage.stretches]}
    return {"schema": INVENTORY_SCHEMA, "path": str(path), "format": read.format,
            "bytes": Path(path).stat().st_size, "imus": imus, "events": events,
            "damage": dmg, "warnings": list(meta.get("warnings", []))}


def _rate(x: float | None) -> str:
    return f"{x:.4g} Hz" if x else "rate unknown"


def format_inventory(inv: dict[str, Any]) -> str:
    """The inventory as text (what ``rimu inspect`` prints)."""
    lines = [f"{inv['path']}: {inv['format']} log, {inv['bytes']} bytes, "
             f"{len(inv['imus'])} IMU stream(s)"]
    for d in inv["imus"]:
        lines += _stream_lines(d)
    lines += _event_lines(inv["events"])
    if inv["damage"] is not None:
        st = inv["damage"]["stretches"]
        lines.append(f"  damaged: {inv['damage']['what']}"
                     + (f"; {len(st)} damaged stretch(es): rimu ingest needs --salvage"
                        if st else "; rimu ingest needs --salvage"))
    for w in inv["warnings"]:
        lines.append(f"  warning: {w}")
    return "\n".join(lines)


def _stream_lines(d: dict[str, Any]) -> list[str]:
    """One IMU stream of the inventory: what it carries, its span, and its issues.

    Parameters
    ----------
    d : dict
        One of the inventory's ``imus``.

    Returns
    -------
    list of str
    """
    carries = [k for k in ("accel", "temperature", "error_count") if d[k]]
    if d["device_id"] is not None:
        carries.append(f"device id {d['device_id']}")
    span = (f"{d['t_start_s']:.3f}-{d['t_end_s']:.3f} s ({d['duration_s']:.1f} s)"
            if d["samples"] else "no sample")
    issues = _stream_issues(d)
    return [f"  {d['name']} ({d['source']}): {d['samples']} samples at "
            f"{_rate(d['sample_rate_hz'])}, {span}; gyro"
            + (f" + {', '.join(carries)}" if carries else ""),
            "    " + ("; ".join(issues) if issues else "no gap, duplicate or "
                                                       "backward time stamp")]


def _stream_issues(d: dict[str, Any]) -> list[str]:
    """Gaps, duplicate and backward stamps, non-finite and implausible samples of a stream.

    Parameters
    ----------
    d : dict
        One of the inventory's ``imus``.

    Returns
    -------
    list of str
        Empty when it has none.
    """
    g = d["gaps"]
    issues = []
    if g["count"]:
        issues.append(f"{g['count']} gap(s) ({g['missing_samples']} samples missing, "
                      f"longest {g['longest_s']:.3f} s at t="
                      f"{max(g['first'], key=lambda x: x['length_s'])['t_s']:.3f} s"
                      + (" among the first 5" if g["count"] > 5 else "") + ")")
    if d["duplicate_stamps"]:
        issues.append(f"{d['duplicate_stamps']} duplicate time stamp(s)")
    if d["backward_stamps"]:
        issues.append(f"{d['backward_stamps']} backward time stamp(s)")
    if d["non_finite_samples"]:
        issues.append(f"{d['non_finite_samples']} non-finite sample(s)")
    for q, v in d["implausible"].items():
        issues.append(f"{v['samples']} implausible {q} sample(s)")
    return issues


def _event_lines(ev: dict[str, Any]) -> list[str]:
    """The declared events of the inventory: counts by category and the first ones.

    Parameters
    ----------
    ev : dict
        The inventory's ``events``.

    Returns
    -------
    list of str
    """
    if not ev["count"]:
        return ["  declared events: none"]
    by = ", ".join(f"{n} {c}" for c, n in sorted(ev["by_category"].items()))
    lines = [f"  declared events: {ev['count']} ({by})"]
    for e in ev["first"]:
        span = (f"{e['t_s']:.2f}-{e['t_end_s']:.2f} s" if e["t_end_s"] > e["t_s"]
                else f"{e['t_s']:.2f} s")
        lines.append(f"    {span:>17}  {e['category']:9s} {e['text']}")
    if ev["count"] > len(ev["first"]):
        lines.append(f"    ... {ev['count'] - len(ev['first'])} more")
    return lines
