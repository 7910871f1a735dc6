"""Cross-flight evidence (issue 27): calibrated and tuned on one flight, monitored on another.

For every ordered pair of flights of one vehicle, the first is calibrated in flight
(``rimu calibrate in-flight`` defaults) and tuned at 1 false alarm per hour (``rimu tune``),
and the second is monitored through ``rimu monitor-file``'s chain
(:func:`replay.chain.chain_for_flight`) twice: *before*, with the calibration's biases as
they are (``--turn-on off``, the chain before issue 27), and *after*, with the chain's
defaults (the turn-on bias estimated at rest before take-off, or a nominal bias bound).
Counted per pair, as the issue's must-hold states them:

- exclusions (``isolated`` / ``health`` events naming a sensor);
- alarm episodes inside the envelope (an episode starts at ``detected`` or ``health``, or
  an ``isolated`` / ``disagree`` no detection opened), the exposure inside the envelope,
  and over all pairs together the exact Poisson (Garwood) 95 % interval of the rate;
- the share of samples with an unverified axis;
- a 10 °/s step on every sensor at :data:`ONSETS` calm onsets of the monitored flight
  (inside the envelope, no alarm of the clean run within 2 s): detected when an alarm the
  clean run does not raise comes within :data:`DETECT_WITHIN_S`.

The parameter checks of :mod:`calibration.inflight.fits_flight` (every parameter of the
calibration against the monitored flight's own fit) are kept beside.

Run: ``python -c "from studies.cross_flight import main; main()"`` from the repository root
(recordings in ``../shared/data`` or ``$RIMU_SHARED_DATA``).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from fdi.units import DPS

TARGET_PER_HOUR = 1.0
STEP_DPS = 10.0
DETECT_WITHIN_S = 1.0
ONSETS = 2
EXCLUDING = ("isolated", "health")
ERLE = ("erle_pxf_dual_imu", ("pxf_copter_22-12-2014_41.BIN", "pxf_copter_31-3-2015_83.BIN"))


def shared_data() -> Path:
    """``../shared/data`` beside the repository (``RIMU_SHARED_DATA`` overrides)."""
    env = os.environ.get("RIMU_SHARED_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def load_log(path: str | Path) -> Any:
    """A log as ``rimu ingest LOG --salvage`` makes it (no folder written)."""
    from replay.ingest import align_streams, read_any
    from replay.ingest.readers import merge_reads

    flight, _ = align_streams(merge_reads([read_any(path, "auto", salvage=True)]))
    return flight


def _part(flight: Any, sl: slice) -> Any:
    aux = flight.aux.slice(sl) if flight.aux is not None else None
    om = flight.omega_true[sl] if flight.omega_true is not None else None
    return replace(flight, t=flight.t[sl], raw=flight.raw[sl], valid=flight.valid[sl],
                   omega_true=om, aux=aux)


def alarm_episodes(events: Sequence[Any]) -> list[Any]:
    """The events that start an alarm episode (module docstring), in time order."""
    out, open_ = [], False
    for e in events:
        if e.type == "detected":
            out.append(e)
            open_ = True
        elif e.type == "health":
            out.append(e)
        elif e.type in ("isolated", "disagree"):
            if not open_:
                out.append(e)
            open_ = open_ and e.type == "disagree"
    return out


def garwood(count: int, hours: float) -> tuple[float, float]:
    """Exact Poisson 95 % interval of a rate (per hour)."""
    lo = 0.0 if count == 0 else stats.chi2.ppf(0.025, 2 * count) / 2
    hi = stats.chi2.ppf(0.975, 2 * count + 2) / 2
    return lo / hours, hi / hours


def _run(flight: Any, cal: Any, thr: Any, turn_on: str) -> tuple[Any, Any]:
    from replay.chain import ChainOptions, chain_for_flight

    ch = chain_for_flight(flight, cal, ChainOptions(thresholds=thr, report=False,
                                                    turn_on=turn_on))
    return ch.feed_whole(flight), ch


def _inside(res: Any) -> np.ndarray:
    env = getattr(res, "envelope", None)
    return np.ones(res.t.shape[0], bool) if env is None else np.asarray(env) == 0


def _index(t: np.ndarray, te: float) -> int:
    return int(min(np.searchsorted(t, te - 1e-9), t.shape[0] - 1))


def _onsets(res: Any, count: int) -> list[float]:
    """Calm onsets: inside the envelope for 2 s either side, no alarm of the clean run
    within 2 s, the body turning (flying), spread over the flight."""
    t = np.asarray(res.t, float)
    ins = _inside(res)
    w = np.asarray(res.omega, float)
    flying = np.linalg.norm(np.nan_to_num(w), axis=1) > 5 * DPS
    alarm_t = np.array([e.t for e in alarm_episodes(res.events)])
    fs = 1.0 / float(np.median(np.diff(t)))
    pad = round(2.0 * fs)
    ok = np.zeros(t.shape[0], bool)
    for k in range(pad, t.shape[0] - pad):
        if not ins[k - pad:k + pad].all() or not flying[k]:
            continue
        if alarm_t.size and np.min(np.abs(alarm_t - t[k])) < 2.0:
            continue
        ok[k] = True
    idx = np.flatnonzero(ok)
    if not idx.size:
        return []
    return [float(t[idx[int(q * (idx.size - 1))]]) for q in np.linspace(0.25, 0.75, count)]


def _step_runs(flight: Any, cal: Any, thr: Any, clean: Any, onsets: Sequence[float]
               ) -> list[dict[str, Any]]:
    from replay.faults import Fault
    from replay.scenario import apply_faults

    known = {(round(e.t, 6), e.type, e.sensor) for e in clean.events}
    rows = []
    for onset in onsets:
        for i in range(1, flight.n + 1):
            f = Fault("step", i, STEP_DPS * DPS, onset, 10.0, f"step:{i}:{onset:g}")
            raw, valid = apply_faults(flight.t, flight.raw, flight.valid, [f], cal,
                                      kind=flight.kind)
            res, _ = _run(replace(flight, raw=raw, valid=valid), cal, thr, "auto")
            new = [e for e in res.events if (round(e.t, 6), e.type, e.sensor) not in known
                   and onset - 1e-9 <= e.t <= onset + 10.0
                   and e.type in ("detected", "isolated", "disagree", "health")]
            delay = float(new[0].t - onset) if new else math.inf
            excl = sorted({e.sensor for e in res.events if e.type in EXCLUDING
                           and e.sensor is not None and e.t >= onset - 1e-9})
            rows.append({"sensor": i, "onset_s": onset, "delay_s": delay,
                         "detected_within": bool(delay <= DETECT_WITHIN_S),
                         "excluded": excl, "wrong_exclusion": any(s != i for s in excl)})
    return rows


def _count(res: Any) -> dict[str, Any]:
    t = np.asarray(res.t, float)
    ins = _inside(res)
    fs = 1.0 / float(np.median(np.diff(t)))
    eps = [e for e in alarm_episodes(res.events) if ins[_index(t, e.t)]]
    unv = np.asarray(res.unverified)
    unv = unv.any(axis=1) if unv.ndim == 2 else unv.astype(bool)
    return {"alarms_in_envelope": len(eps), "alarm_times_s": [float(e.t) for e in eps],
            "hours_in_envelope": float(ins.sum()) / fs / 3600.0,
            "excluded": sorted({e.sensor for e in res.events
                                if e.type in EXCLUDING and e.sensor is not None}),
            "unverified_fraction": float(unv.mean()) if unv.size else math.nan}


def cross_pairs(flights: dict[str, Any], *, steps: bool = True) -> dict[str, Any]:
    """Every ordered pair of ``flights`` ({name: Flight} of one vehicle): the module
    docstring's counts, before and after, and the pooled rate with its interval."""
    from calibration.inflight import calibration_from_fit, fit_inflight
    from calibration.inflight.fits_flight import parameter_checks
    from thresholds.tune import tune

    cals = {k: calibration_from_fit(fit_inflight(f), f) for k, f in flights.items()}
    thrs = {k: tune(c, false_alarms_per_hour=TARGET_PER_HOUR).thresholds
            for k, c in cals.items()}
    own = {}
    for k, f in flights.items():
        from calibration.inflight.fits_flight import flight_calibration

        own[k] = flight_calibration(f)
    rows = []
    for a in flights:
        for b in flights:
            if a == b:
                continue
            row: dict[str, Any] = {"calibrated_on": a, "monitored": b}
            for label, mode in (("before", "off"), ("after", "auto")):
                res, ch = _run(flights[b], cals[a], thrs[a], mode)
                row[label] = _count(res)
                if label == "after":
                    row["turn_on"] = ch.turn_on.to_dict()
                    if steps:
                        ons = _onsets(res, ONSETS)
                        row["steps"] = _step_runs(flights[b], cals[a], thrs[a], res, ons)
            row["misfit"] = [c.to_dict() for c in parameter_checks(cals[a], own[b])
                             if not c.fits]
            rows.append(row)
    out: dict[str, Any] = {"target_per_hour": TARGET_PER_HOUR, "pairs": rows}
    for label in ("before", "after"):
        n = sum(r[label]["alarms_in_envelope"] for r in rows)
        h = sum(r[label]["hours_in_envelope"] for r in rows)
        lo, hi = garwood(n, h)
        out[label] = {"alarms": n, "hours": h, "rate_per_hour": n / h if h else math.nan,
                      "ci95_per_hour": [lo, hi],
                      "resolved": bool(TARGET_PER_HOUR * h >= -math.log(0.05) / 3)}
    return out


def erle_flights() -> dict[str, Any]:
    """Erle flights 41 and 83 from the shared data."""
    folder, names = ERLE
    return {n.split("_")[-1].split(".")[0]: load_log(shared_data() / folder / n)
            for n in names}


def table(doc: dict[str, Any]) -> str:
    """A markdown table of :func:`cross_pairs`."""
    lines = ["| calibrated on -> monitored | alarms in envelope (before -> after) | "
             "exposure s | excluded | unverified | 10 deg/s step within 1 s | misfit "
             "parameters |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in doc["pairs"]:
        b, a = r["before"], r["after"]
        st = r.get("steps", [])
        ok = sum(s["detected_within"] for s in st)
        lines.append(
            f"| {r['calibrated_on']} -> {r['monitored']} | {b['alarms_in_envelope']} -> "
            f"{a['alarms_in_envelope']} | {3600 * a['hours_in_envelope']:.0f} | "
            f"{b['excluded'] or '-'} -> {a['excluded'] or '-'} | "
            f"{100 * b['unverified_fraction']:.1f}% -> {100 * a['unverified_fraction']:.1f}% | "
            f"{ok} of {len(st)} | "
            f"{', '.join(sorted({m['imu'] + ' ' + m['parameter'] for m in r['misfit']}))} |")
    for label in ("before", "after"):
        p = doc[label]
        lines.append(f"\n{label}: {p['alarms']} alarms in {3600 * p['hours']:.0f} s inside "
                     f"the envelope over all pairs: {p['rate_per_hour']:.3g}/h, exact Poisson "
                     f"95 % interval {p['ci95_per_hour'][0]:.3g}-{p['ci95_per_hour'][1]:.3g}/h "
                     f"against {doc['target_per_hour']:g}/h "
                     f"({'resolved' if p['resolved'] else 'not resolved by this length'})")
    return "\n".join(lines)


def main() -> None:
    """Compute the erle pairs and print the table (and write ``studies/cross_flight.json``)."""
    doc = cross_pairs(erle_flights())
    Path(__file__).with_name("cross_flight.json").write_text(
        json.dumps(doc, indent=1, default=float) + "\n", encoding="utf-8")
    print(table(doc))


if __name__ == "__main__":
    main()
