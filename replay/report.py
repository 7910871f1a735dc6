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
     "frames": {...},                                           # replay only
     "units": {"t": "s", "statistic": ..., "threshold": ..., "magnitude": "rad/s", ...}}

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
from replay.plots import RunTrace

__all__ = ["ALARM_TYPES", "REPORT_SCHEMA", "RunningReport", "build_report", "decoding_hint",
           "event_units", "format_report", "format_summary"]

REPORT_SCHEMA = "rimu.report/1"
ALARM_TYPES = ("detected", "isolated", "health")
"""Event types that raise an alarm (``readmitted`` does not)."""
_ISOLATING = ("isolated", "health")
_EPS = 1e-9


def event_units(kind: str) -> dict[str, str]:
    """Units of the events' numeric fields (the report's ``"units"`` block)."""
    return {"t": "s", "scale": "samples (window length)",
            "statistic": "1 (chi-square of the noise-normalised parity; a health check's "
                         "own measure otherwise)",
            "threshold": "1 (same measure as statistic)",
            "magnitude": "rad/s" if kind == "gyro" else "m/s^2"}


def _sensor(e: Mapping[str, Any], names: Sequence[str]) -> str:
    """``3 (x2)``: the 1-based number with the sensor's name."""
    k = e.get("sensor")
    if k is None:
        return "-"
    return f"{k} ({names[k - 1]})" if isinstance(k, int) and 1 <= k <= len(names) else str(k)


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


class _Median:
    """Median of a stream of positive numbers in bounded memory.

    Exact (all values kept) up to ``exact_max`` values (default :data:`EXACT_MAX`); beyond,
    a histogram of 200 log-spaced bins per decade over 1e-9 … 1e6 takes over (the median is
    then the centre of its bin: within 0.6 % of the exact value).
    """

    EXACT_MAX = 1 << 20
    EDGES = np.logspace(-9.0, 6.0, 15 * 200 + 1)

    def __init__(self, exact_max: int = EXACT_MAX) -> None:
        self.exact_max = int(exact_max)
        self._vals: list[np.ndarray] = []
        self._n = 0
        self._hist: np.ndarray | None = None

    def add(self, x: np.ndarray) -> None:
        x = np.asarray(x, float)
        x = x[np.isfinite(x)]
        if x.size == 0:
            return
        self._n += x.size
        if self._hist is None:
            self._vals.append(x.copy())
            if self._n > self.exact_max:
                self._hist = np.zeros(self.EDGES.size - 1, np.int64)
                for v in self._vals:
                    self._bin(v)
                self._vals = []
        else:
            self._bin(x)

    def _bin(self, x: np.ndarray) -> None:
        k = np.clip(np.searchsorted(self.EDGES, x, side="right") - 1, 0, self.EDGES.size - 2)
        self._hist += np.bincount(k, minlength=self.EDGES.size - 1)

    def median(self) -> float | None:
        if self._n == 0:
            return None
        if self._hist is None:
            return float(np.median(np.concatenate(self._vals)))
        k = int(np.searchsorted(np.cumsum(self._hist), (self._n + 1) / 2.0))
        return float(np.sqrt(self.EDGES[k] * self.EDGES[k + 1]))


class RunningReport:
    """The report's running summaries over a monitoring run fed in pieces (bounded memory).

    :meth:`update` takes each piece of the monitor's answers (``Monitor.run`` over a block
    of samples, or a few live answers) with the true rates of those samples when known; it
    keeps the events, the last health and capability, counts and sums, never the answers,
    and a binned :class:`~replay.plots.RunTrace` for the run's picture (``trace``).
    :meth:`build` makes the ``rimu.report/1`` dictionary (:func:`build_report` is one
    update and a build).

    Parameters
    ----------
    median_exact_max : int
        Protection levels kept for an exact median; beyond, a histogram (0.6 %). A live
        monitor gives a small number so that its memory stops growing early.
    """

    def __init__(self, median_exact_max: int = _Median.EXACT_MAX) -> None:
        self.events: list[Any] = []
        self.samples = 0
        self.healthy_end: list[bool] | None = None
        self.capability_end: str | None = None
        self.n_ok = 0
        self._pl = _Median(median_exact_max)
        self._err_sq = np.zeros(3)
        self._n_err = 0
        self._breaches: int | None = None
        self.n_out = 0                                # samples out of the envelope
        self.periods: list[dict[str, Any]] = []       # envelope excursions, in time order
        self._open: dict[str, Any] | None = None      # the excursion still going on
        self.n_unverified = 0
        self._unv_axis = np.zeros(3, np.int64)
        self.n_verified = 0
        self.trace = RunTrace()

    def update(self, result: Any, omega_true: np.ndarray | None = None) -> None:
        """Add one piece of answers (``BlockResult``) and the true rates of its samples."""
        N = int(np.asarray(result.t).shape[0])
        self.events.extend(result.events)
        if N == 0:
            return
        self.trace.update(result)
        self.samples += N
        healthy = np.asarray(result.healthy, bool)
        self.healthy_end = healthy[-1].tolist()
        self.capability_end = str(np.asarray(result.capability)[-1])
        omega = np.asarray(result.omega, float)
        ok = np.all(np.isfinite(omega), axis=1)
        self.n_ok += int(np.count_nonzero(ok))
        pl = np.asarray(getattr(result, "protection_level", np.zeros(0)), float)
        pl_ok = pl.shape == ok.shape
        if pl_ok:
            ver = ok & np.isfinite(pl)            # a protection level only where verified
            self.n_verified += int(np.count_nonzero(ver))
            self._pl.add(pl[ver] / DPS)
        self._envelope(np.asarray(result.t, float), getattr(result, "envelope", None))
        unv = getattr(result, "unverified", None)
        if unv is not None and np.shape(unv) == (N, 3):
            unv = np.asarray(unv, bool)
            self.n_unverified += int(np.count_nonzero(unv.any(axis=1)))
            self._unv_axis += unv.sum(axis=0)
        if omega_true is not None and ok.any():
            tru = np.asarray(omega_true, float)
            err = (omega[ok] - tru[ok]) / DPS
            self._err_sq += np.sum(err ** 2, axis=0)
            self._n_err += int(np.count_nonzero(ok))
            if pl_ok:
                norm = np.linalg.norm(omega - tru, axis=1)
                self._breaches = (self._breaches or 0) + int(np.sum(ok & (norm > pl)))

    def _envelope(self, t: np.ndarray, codes: Any) -> None:
        """Count the samples out of the envelope and follow its excursions across pieces
        (an excursion open at a piece's end goes on in the next piece)."""
        N = t.shape[0]
        if codes is None or np.shape(codes) != (N,) or N == 0:
            return
        c = np.asarray(codes, np.int64)
        out = c != 0
        self.n_out += int(np.count_nonzero(out))
        if self._open is not None and not out[0]:
            self._done(self._open)
            self._open = None
        edges = np.flatnonzero(np.diff(np.concatenate([[0], out.astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if a == 0 and self._open is not None:
                p = self._open
            else:
                p = {"t0_s": float(t[a]), "code": 0, "samples": 0}
            p["t1_s"] = float(t[b - 1])
            p["code"] |= int(np.bitwise_or.reduce(c[a:b]))
            p["samples"] += int(b - a)
            if b == N:
                self._open = p
            else:
                self._open = None
                self._done(p)

    def _done(self, p: dict[str, Any]) -> None:
        self.periods.append(p)

    def _periods(self) -> list[dict[str, Any]]:
        """The excursions so far (the open one included), with their reasons."""
        from fdi.envelope import reason_names

        ps = self.periods + ([self._open] if self._open is not None else [])
        return [{"t0_s": p["t0_s"], "t1_s": p["t1_s"], "samples": p["samples"],
                 "reasons": list(reason_names(p["code"]))} for p in ps]

    def _summary(self, events: list[dict[str, Any]], outcomes: list[dict[str, Any]],
                 truth: bool, n: int) -> dict[str, Any]:
        """The report's ``summary``: events, isolations, delays, rate error, integrity."""
        isolated = sorted({int(e["sensor"]) for e in events
                           if e["type"] in _ISOLATING and e.get("sensor") is not None})
        in_env, out_env = _alarms_by_envelope(events)
        rms, rms_axis, breaches = self._rate_error()
        return {
            "events": len(events),
            "isolated_sensors": isolated,
            "healthy_at_end": (self.healthy_end if self.healthy_end is not None
                               else [True] * n),
            "capability_at_end": self.capability_end,
            "false_alarms": (sum(bool(e["false_alarm"]) for e in events) if truth else None),
            "detection_delay_s": [o["detection_delay_s"] for o in outcomes],
            "isolation_delay_s": [o["isolation_delay_s"] for o in outcomes],
            "isolation_correct": [o["isolation_correct"] for o in outcomes],
            "rate_error_rms_dps": rms,
            "rate_error_rms_axis_dps": rms_axis,
            "rate_available_fraction": self._fraction(self.n_ok),
            "protection_level_median_dps": self._pl.median(),
            "verified_fraction": self._fraction(self.n_verified),
            "integrity_breaches": breaches,
            "envelope_out_fraction": self._fraction(self.n_out),
            "envelope_periods": self._periods(),
            "alarms_in_envelope": in_env,
            "alarms_out_of_envelope": out_env,
            "unverified_fraction": self._fraction(self.n_unverified),
            "unverified_axis_fraction": ((self._unv_axis / self.samples).tolist()
                                         if self.samples else [0.0, 0.0, 0.0]),
        }

    def _fraction(self, count: int) -> float:
        """``count`` as a fraction of the samples so far (0 before any).

        Parameters
        ----------
        count : int

        Returns
        -------
        float
        """
        return count / self.samples if self.samples else 0.0

    def _rate_error(self) -> tuple[float | None, list[float] | None, int | None]:
        """RMS rate error over all axes and per axis (deg/s) and the integrity breaches;
        None each without truth.

        Returns
        -------
        (float or None, list of float or None, int or None)
        """
        if not self._n_err:
            return None, None, None
        return (float(np.sqrt(self._err_sq.sum() / (3 * self._n_err))),
                np.sqrt(self._err_sq / self._n_err).tolist(), self._breaches)

    def build(self, flight: Flight, cal: Calibration, *,
              frames: Mapping[str, Any] | None = None, kind: str | None = None,
              extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The ``rimu.report/1`` dictionary (see :func:`build_report`); ``flight`` gives
        the source, names, rate, faults and truth (its arrays are not read)."""
        kind = kind or flight.kind
        fs = float(flight.sample_rate_hz)
        truth = _has_truth(flight)
        events = sorted((_event_dict(e) for e in self.events),
                        key=lambda e: float(e["t"]))      # stable: keeps in-sample order
        faults = list(flight.faults)
        for e in events:
            e["false_alarm"] = _is_false_alarm(e, faults) if truth else None
        outcomes = [_fault_outcome(f, events, fs, faults) for f in faults] if truth else []
        summary = self._summary(events, outcomes, truth, flight.n)
        report: dict[str, Any] = {
            "schema": REPORT_SCHEMA, "source": flight.source,
            "configuration": cal.configuration, "kind": kind, "samples": self.samples,
            "duration_s": self.samples / fs if fs > 0 else 0.0,
            "sample_rate_hz": fs, "sensor_names": list(flight.sensor_names), "truth": truth,
            "events": events, "faults": outcomes, "summary": summary,
            "units": event_units(kind),
        }
        if frames is not None:
            report["frames"] = dict(frames)
        if extra:
            report.update(dict(extra))
        return report


def _alarms_by_envelope(events: list[dict[str, Any]]) -> tuple[int, int]:
    """Detections inside and outside the envelope.

    Parameters
    ----------
    events : list of dict
        The report's events.

    Returns
    -------
    (int, int)
    """
    return (sum(1 for e in events if e["type"] == "detected" and not e.get("envelope")),
            sum(1 for e in events if e["type"] == "detected" and e.get("envelope")))


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
    acc = RunningReport()
    om = flight.omega_true
    acc.update(result, om if om is not None and len(om) == len(result.t) else None)
    return acc.build(flight, cal, frames=frames, kind=kind, extra=extra)


def _fmt(x: Any, unit: str = "", prec: str = ".4g") -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return f"{x:{prec}}{unit}"
    return f"{x}{unit}"


def _time_base_text(tb: Mapping[str, Any]) -> str:
    """What the monitor ran across: gaps, duplicate time stamps, empty rows (or none)."""
    parts = []
    if tb.get("gaps"):
        parts.append(f"monitored across {tb['gaps']} gap(s) longer than "
                     f"{tb.get('gap_periods', 2.5):g} sample periods ({tb['gap_total_s']:.4g} s "
                     f"without samples, longest {tb['gap_longest_s']:.4g} s, first at t = "
                     f"{tb['gap_first_t_s']:.6g} s)")
    if tb.get("duplicate_time_stamps"):
        parts.append(f"{tb['duplicate_time_stamps']} duplicate time stamp(s)")
    if tb.get("empty_rows"):
        parts.append(f"{tb['empty_rows']} row(s) without any finite value")
    return "; ".join(parts) if parts else "regular (no gap, no duplicate, no empty row)"


def decoding_hint(report: Mapping[str, Any]) -> str | None:
    """A warning when the run looks like a decoding error rather than a flight: more than
    half the sensors isolated by the parity (not for non-finite or stale values), or more
    than half the samples out of the envelope with saturation among the reasons (one wrong
    DBC factor, map unit or raw unit scales every sensor alike); None otherwise."""
    s = report.get("summary", {})
    n = len(report.get("sensor_names", ()))
    health = {e.get("sensor") for e in report.get("events", ()) if e.get("type") == "health"}
    iso = [k for k in s.get("isolated_sensors") or () if k not in health]   # parity's own
    out = float(s.get("envelope_out_fraction") or 0.0)
    ranged = any("saturation" in p.get("reasons", ()) for p in s.get("envelope_periods") or ())
    why = []
    if n and len(iso) > n / 2:
        why.append(f"{len(iso)} of {n} sensors isolated")
    if out > 0.5 and ranged:
        why.append(f"{100 * out:.0f} % of the samples out of the envelope, saturation among "
                   "the reasons")
    if not why:
        return None
    return (f"{' and '.join(why)}: a scale error common to every sensor (a DBC factor, the "
            "channel map's unit, the raw unit, a calibration of another set) is more likely "
            "than faults in all of them; check the decoded rates against the calibration")


def format_report(report: Mapping[str, Any], *, max_events: int = 50) -> str:
    """Readable text of a report: events (the first ``max_events``) and the summary."""
    tb = report.get("time_base")
    span = (f"{tb['span_s']:.6g} s of time stamps" if tb else f"{report['duration_s']:.6g} s")
    lines = [f"{report.get('source', '')}: {report['samples']} samples, "
             f"{span} at {report['sample_rate_hz']:g} Hz, "
             f"{len(report['sensor_names'])} {report.get('kind', 'gyro')} sensors"]
    if tb:
        lines.append("time stamps: " + _time_base_text(tb))
    ev = report["events"]
    lines.append(f"events: {len(ev)}")
    names = list(report.get("sensor_names", []))
    for e in ev[:max_events]:
        s = _sensor(e, names)
        stat = ""
        if e.get("statistic") is not None:
            stat = f"  {_fmt(e['statistic'])} > {_fmt(e.get('threshold'))}"
        fa = "  FALSE ALARM" if e.get("false_alarm") else ""
        lines.append(f"  t={e['t']:.3f} s  sensor {s:>6}  {e['type']:<10} {e['reason']}{stat}"
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
                     f" (verified answers: {100 * s.get('verified_fraction', 0.0):.1f} % of "
                     f"samples); integrity breaches: {_fmt(s.get('integrity_breaches'))}")
    lines.extend(_envelope_lines(s))
    cap = report.get("isolation_capability")
    if cap:
        lines.append(_capability_line(cap))
    if "frames" in report:
        fr = report["frames"]
        lines.append(f"frames: read {fr.get('read')}, used {fr.get('used')}, rejected "
                     f"{fr.get('rejected')}")
    return "\n".join(lines)


def _envelope_lines(s: Mapping[str, Any]) -> list[str]:
    """The envelope and the unverified answers, one line each."""
    out = []
    periods = s.get("envelope_periods")
    if periods is not None:
        why: dict[str, int] = {}
        for p in periods:
            for r in p["reasons"]:
                why[r] = why.get(r, 0) + 1
        reasons = ", ".join(f"{k} {v}" for k, v in why.items())
        out.append(f"out of the envelope: {100 * s.get('envelope_out_fraction', 0.0):.1f} % of "
                   f"the samples in {len(periods)} period(s){f' ({reasons})' if reasons else ''}"
                   f"; alarms {s.get('alarms_in_envelope', 0)} inside the envelope, "
                   f"{s.get('alarms_out_of_envelope', 0)} outside it (no exclusion there)")
    if "unverified_fraction" in s:
        ax = s.get("unverified_axis_fraction") or [0.0, 0.0, 0.0]
        out.append(f"unverified rates: {100 * s['unverified_fraction']:.1f} % of the samples "
                   f"(x {100 * ax[0]:.1f} %, y {100 * ax[1]:.1f} %, z {100 * ax[2]:.1f} %)")
    return out


def _capability_line(cap: Mapping[str, Any]) -> str:
    """What the full set can isolate: the pairs it cannot tell apart at a useful size."""
    det = [d for d in cap.get("detectable", {}).values() if d is not None]
    top = max(det) if det else None
    unit = cap.get("unit", "")
    hard = [p for p in cap.get("pairs", []) if p.get("isolable_from") is None
            or (top is not None and p["isolable_from"] > 10 * top)]
    text = f"isolation capability of the full set: {cap.get('capability')}"
    if top is not None:
        text += f" (detectable from {_fmt(top)} {unit}"
        if hard:
            text += "; told apart only from: " + ", ".join(
                f"{'/'.join(p['names'])} {_fmt(p['isolable_from'])} {unit}"
                if p.get("isolable_from") is not None else f"{'/'.join(p['names'])} never"
                for p in hard[:6]) + (" ..." if len(hard) > 6 else "")
        text += ")"
    return text


def format_summary(report: Mapping[str, Any], *, max_events: int = 50) -> str:
    """Same as :func:`format_report` (the name the demo and replay commands use)."""
    return format_report(report, max_events=max_events)
