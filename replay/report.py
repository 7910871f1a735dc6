"""The monitoring report ``rimu.report/1`` (``rimu monitor-file``, ``rimu replay``).

Layout (keys other tools read; keep them stable)::

    {"schema": "rimu.report/1", "source": ..., "configuration": ..., "kind": "gyro",
     "samples": N, "duration_s": ..., "sample_rate_hz": ..., "sensor_names": [...],
     "truth": true|false,
     "events": [{"t", "sensor", "type", "reason", "statistic", "threshold", "scale",
                 "magnitude", "false_alarm"}, ...],          # in time order
     "faults": [{"spec", "kind", "sensor", "onset", "size", "detected", "detection_delay_s",
                 "detection_delay_samples", "isolated", "isolated_sensor",
                 "isolation_delay_s", "isolation_correct"}, ...],   # with truth only
     "summary": {"events", "isolated_sensors", "healthy_at_end", "capability_at_end",
                 "false_alarms", "detection_delay_s", "isolation_delay_s",
                 "isolation_correct", "rate_error_rms_dps", "rate_error_rms_axis_dps",
                 "rate_available_fraction", "protection_level_median_dps",
                 "integrity_breaches"},
     "frames": {...}}                                           # replay only

Definitions:

- A *false alarm* is a ``detected``/``isolated``/``health`` event before the onset of any
  injected fault, or on a sensor that has no fault begun by then. Without truth (a recorded
  flight without sidecar) ``false_alarms`` is None: it cannot be known.
- A fault's *detection* is the first ``detected``/``isolated``/``health`` event at or after
  its onset that does not name the sensor of another injected fault (a wrong isolation of a
  healthy sensor still shows the fault was noticed, and counts as a false alarm too); the
  delay is event time − onset (0: caught in the onset sample). Its *isolation* is the
  first ``isolated``/``health`` event at or after the onset that does not name the sensor of
  another injected fault; it is correct when it names the faulted sensor.
- ``rate_error_rms_dps`` is the RMS over samples and axes of ω̂ − ω_true (°/s), over the
  samples where ω̂ is finite; ``rate_available_fraction`` the share of such samples.
- ``integrity_breaches``: samples where |ω̂ − ω_true| (vector norm) exceeds the protection
  level the monitor gave with that ω̂ (with truth only); ``protection_level_median_dps``
  the median protection level over the samples with a finite one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.units import DPS
from replay.flight_data import Flight

__all__ = ["ALARM_TYPES", "REPORT_SCHEMA", "build_report", "format_report", "format_summary"]

REPORT_SCHEMA = "rimu.report/1"
ALARM_TYPES = ("detected", "isolated", "health")
"""Event types that raise an alarm (``readmitted`` does not)."""
_ISOLATING = ("isolated", "health")
_EPS = 1e-9


def _num(x: Any) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _event_dict(e: Any) -> dict[str, Any]:
    if isinstance(e, Mapping):
        return dict(e)
    return e.to_dict()


def _has_truth(flight: Flight) -> bool:
    return bool(flight.faults) or flight.omega_true is not None or bool(flight.truth)


def _is_false_alarm(ev: Mapping[str, Any], faults: Sequence[Any]) -> bool:
    if ev["type"] not in ALARM_TYPES:
        return False
    begun = [f for f in faults if f.onset <= ev["t"] + _EPS]
    if not begun:
        return True
    s = ev.get("sensor")
    return s is not None and s not in {f.sensor for f in begun}


def _fault_outcome(f: Any, events: Sequence[Mapping[str, Any]], fs: float,
                   faults: Sequence[Any]) -> dict[str, Any]:
    others = {g.sensor for g in faults if g.sensor != f.sensor}
    det = next((e for e in events if e["type"] in ALARM_TYPES and e["t"] >= f.onset - _EPS
                and e.get("sensor") not in others), None)
    iso = next((e for e in events if e["type"] in _ISOLATING and e["t"] >= f.onset - _EPS
                and e.get("sensor") not in others), None)
    d = None if det is None else max(0.0, det["t"] - f.onset)
    di = None if iso is None else max(0.0, iso["t"] - f.onset)
    return {"spec": f.spec, "kind": f.kind, "sensor": f.sensor, "onset": f.onset,
            "size": f.size, "duration": f.duration,
            "detected": det is not None, "detection_delay_s": d,
            "detection_delay_samples": None if d is None else round(d * fs),
            "detected_by": None if det is None else det["reason"],
            "isolated": iso is not None,
            "isolated_sensor": None if iso is None else iso.get("sensor"),
            "isolation_delay_s": di,
            "isolation_correct": None if iso is None else iso.get("sensor") == f.sensor}


def build_report(result: Any, flight: Flight, cal: Calibration, *,
                 frames: Mapping[str, Any] | None = None, kind: str | None = None,
                 extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The ``rimu.report/1`` dictionary of one monitoring run.

    Parameters
    ----------
    result : fdi.answer.BlockResult
        What ``Monitor.run`` returned for the flight's samples.
    flight : Flight
        The samples (with truth where known).
    cal : Calibration
    frames : dict, optional
        Frame accounting of a CAN replay (``{"read", "used", "rejected": {...}}``).
    kind : str, optional
        Sensor set; defaults to the flight's.
    extra : dict, optional
        Further top-level entries (thresholds file, settings).

    Returns
    -------
    dict
        JSON-ready (see the module docstring).
    """
    kind = kind or flight.kind
    fs = float(flight.sample_rate_hz)
    truth = _has_truth(flight)
    events = sorted((_event_dict(e) for e in result.events),
                    key=lambda e: float(e["t"]))          # stable: keeps in-sample order
    faults = list(flight.faults)
    for e in events:
        e["false_alarm"] = _is_false_alarm(e, faults) if truth else None
    outcomes = [_fault_outcome(f, events, fs, faults) for f in faults] if truth else []

    healthy = np.asarray(result.healthy, bool)
    isolated = sorted({int(e["sensor"]) for e in events
                       if e["type"] in _ISOLATING and e.get("sensor") is not None})
    healthy_end = healthy[-1].tolist() if healthy.shape[0] else [True] * flight.n
    cap = np.asarray(result.capability)
    summary: dict[str, Any] = {
        "events": len(events),
        "isolated_sensors": isolated,
        "healthy_at_end": healthy_end,
        "capability_at_end": str(cap[-1]) if cap.shape[0] else None,
        "false_alarms": (sum(bool(e["false_alarm"]) for e in events) if truth else None),
        "detection_delay_s": [o["detection_delay_s"] for o in outcomes],
        "isolation_delay_s": [o["isolation_delay_s"] for o in outcomes],
        "isolation_correct": [o["isolation_correct"] for o in outcomes],
        "rate_error_rms_dps": None,
        "rate_error_rms_axis_dps": None,
    }
    omega = np.asarray(result.omega, float)
    ok = np.all(np.isfinite(omega), axis=1) if omega.size else np.zeros(0, bool)
    summary["rate_available_fraction"] = float(ok.mean()) if ok.size else 0.0
    pl = np.asarray(getattr(result, "protection_level", np.zeros(0)), float)
    summary["protection_level_median_dps"] = None
    summary["integrity_breaches"] = None
    if pl.shape == ok.shape and ok.any():
        fin = ok & np.isfinite(pl)
        if fin.any():
            summary["protection_level_median_dps"] = float(np.median(pl[fin]) / DPS)
    if flight.omega_true is not None and ok.any():
        err = (omega[ok] - flight.omega_true[ok]) / DPS
        summary["rate_error_rms_dps"] = float(np.sqrt(np.mean(err ** 2)))
        summary["rate_error_rms_axis_dps"] = np.sqrt(np.mean(err ** 2, axis=0)).tolist()
        if pl.shape == ok.shape:
            norm = np.linalg.norm(omega - flight.omega_true, axis=1)
            summary["integrity_breaches"] = int(np.sum(ok & (norm > pl)))
    report: dict[str, Any] = {
        "schema": REPORT_SCHEMA, "source": flight.source, "configuration": cal.configuration,
        "kind": kind, "samples": int(flight.t.shape[0]), "duration_s": flight.duration_s,
        "sample_rate_hz": fs, "sensor_names": list(flight.sensor_names), "truth": truth,
        "events": events, "faults": outcomes, "summary": summary,
    }
    if frames is not None:
        report["frames"] = dict(frames)
    if extra:
        report.update(dict(extra))
    return report


def _fmt(x: Any, unit: str = "", prec: str = ".4g") -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return f"{x:{prec}}{unit}"
    return f"{x}{unit}"


def format_report(report: Mapping[str, Any], *, max_events: int = 50) -> str:
    """Readable text of a report: events (the first ``max_events``) and the summary."""
    lines = [f"{report.get('source', '')}: {report['samples']} samples, "
             f"{report['duration_s']:.6g} s at {report['sample_rate_hz']:g} Hz, "
             f"{len(report['sensor_names'])} {report.get('kind', 'gyro')} sensors"]
    ev = report["events"]
    lines.append(f"events: {len(ev)}")
    for e in ev[:max_events]:
        s = "-" if e.get("sensor") is None else str(e["sensor"])
        stat = ""
        if e.get("statistic") is not None:
            stat = f"  {_fmt(e['statistic'])} > {_fmt(e.get('threshold'))}"
        fa = "  FALSE ALARM" if e.get("false_alarm") else ""
        lines.append(f"  t={e['t']:.3f} s  sensor {s:>2}  {e['type']:<10} {e['reason']}{stat}"
                     f"{fa}")
    if len(ev) > max_events:
        lines.append(f"  ... {len(ev) - max_events} more")
    for o in report.get("faults", []):
        lines.append(f"fault {o['spec'] or o['kind']}: detected {_fmt(o['detected'])} "
                     f"after {_fmt(o['detection_delay_s'], ' s')}, isolated sensor "
                     f"{_fmt(o['isolated_sensor'])} after {_fmt(o['isolation_delay_s'], ' s')}"
                     f" (correct: {_fmt(o['isolation_correct'])})")
    s = report["summary"]
    lines.append(f"isolated sensors: {s['isolated_sensors'] or 'none'}; capability at end: "
                 f"{s['capability_at_end']}")
    lines.append(f"false alarms: {_fmt(s['false_alarms'])}")
    lines.append(f"rate error RMS: {_fmt(s['rate_error_rms_dps'], ' deg/s')} "
                 f"(rates delivered in {100 * s['rate_available_fraction']:.1f} % of samples)")
    if s.get("protection_level_median_dps") is not None:
        lines.append(f"protection level median: {_fmt(s['protection_level_median_dps'], ' deg/s')}"
                     f"; integrity breaches: {_fmt(s.get('integrity_breaches'))}")
    if "frames" in report:
        fr = report["frames"]
        lines.append(f"frames: read {fr.get('read')}, used {fr.get('used')}, rejected "
                     f"{fr.get('rejected')}")
    return "\n".join(lines)


def format_summary(report: Mapping[str, Any], *, max_events: int = 50) -> str:
    """Same as :func:`format_report` (the name the demo and replay commands use)."""
    return format_report(report, max_events=max_events)
