"""Cross-flight evidence (issue 27): calibrated and tuned on one flight, monitored on another.

For every ordered pair of flights of one vehicle, the first is calibrated in flight
(``rimu calibrate in-flight`` defaults) and tuned at 1 false alarm per hour (``rimu tune``),
and the second is monitored through ``rimu monitor-file``'s chain
(:func:`replay.chain.chain_for_flight`) twice: *before*, with the calibration's biases and
firmware-dependent parameters as they are (``--turn-on off --keep-firmware-parameters``,
the chain before issue 27), and *after*, with the chain's defaults (the turn-on bias
estimated at rest before take-off, or a nominal bias bound; on a flight under another
firmware build the relative scale, mounting and time offset held at the calibration's
prior, :mod:`replay.firmware_prior`).
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

The fourteen four-IMU Xsens DOT flights (:func:`xsens_cases`): the units may have been
power-cycled between paths and no path starts at rest, so a calibration of one path says
nothing of the next path's turn-on biases. Each path is monitored with the calibration of
the other paths of its group (horizontal or vertical) calibrated together
(``rimu calibrate in-flight F1 F2 ...``: the shared parts joint, the run-to-run spread of
the turn-on bias measured, which the chain's nominal bias bound then covers), tuned at
1/h. The 10 °/s step goes on every gyro axis of every IMU at each onset.

Run: ``python -m studies.cross_flight [--groups erle,xsens] [--out studies/cross_flight.json]``
from the repository root (recordings in ``../shared/data`` or ``$RIMU_SHARED_DATA``); about
1 min for erle and 20 min for the Xsens set (``rimu tune`` per calibration).
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

from fdi.units import DPS
from studies.per_calibration import garwood
from thresholds.per_draw import alarm_episodes

TARGET_PER_HOUR = 1.0
STEP_DPS = 10.0
DETECT_WITHIN_S = 1.0
ONSETS = 2
EXCLUDING = ("isolated", "health")
ERLE = ("erle_pxf_dual_imu", ("pxf_copter_22-12-2014_41.BIN", "pxf_copter_31-3-2015_83.BIN"))
XSENS = "ansfl_4x_xsens_dot"
XSENS_MAP = Path(__file__).resolve().parents[1] / "docs" / "examples" / "xsens_dot.toml"


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


def _run(flight: Any, cal: Any, thr: Any, turn_on: str) -> tuple[Any, Any]:
    """The chain on ``flight``: its defaults with ``turn_on="auto"``; ``"off"`` is the chain
    before issue 27 (biases as calibrated, firmware-dependent parameters as calibrated)."""
    from replay.chain import ChainOptions, chain_for_flight

    ch = chain_for_flight(flight, cal, ChainOptions(thresholds=thr, report=False,
                                                    turn_on=turn_on,
                                                    firmware_prior=turn_on != "off"))
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


def _pair(name_cal: str, name_mon: str, flight: Any, cal: Any, thr: Any, own: Any,
          steps: bool) -> dict[str, Any]:
    from calibration.inflight.fits_flight import calibration_firmware, parameter_checks
    from replay.time_offsets import flight_identity

    row: dict[str, Any] = {"calibrated_on": name_cal, "monitored": name_mon}
    for label, mode in (("before", "off"), ("after", "auto")):
        res, ch = _run(flight, cal, thr, mode)
        row[label] = _count(res)
        if label == "after":
            row["turn_on"] = ch.turn_on.to_dict()
            row["events"] = [{"t_s": float(e.t), "type": e.type, "reason": e.reason,
                              "sensor": e.sensor} for e in res.events
                             if e.type in ("detected", "isolated", "health", "disagree")]
            if steps:
                ons = _onsets(res, ONSETS)
                row["steps"] = _step_runs(flight, cal, thr, res, ons)
    row["misfit"] = ([c.to_dict() for c in parameter_checks(cal, own) if not c.fits]
                     if own is not None else [])
    row["firmware"] = {"calibration": calibration_firmware(cal),
                       "flight": str(flight_identity(flight)["firmware"])}
    return row


def _firmware(row: dict[str, Any]) -> str:
    """``same``, ``changed`` or ``-`` (a log names none) for the table."""
    fw = row.get("firmware") or {}
    a, b = fw.get("calibration", ""), fw.get("flight", "")
    return "-" if not a or not b else "same" if a == b else "changed"



def merged(docs: Sequence[dict[str, Any]], key: str) -> dict[str, Any]:
    """The pairs of several runs of one set (``--only`` parts) pooled as one run's."""
    return _pooled([r for d in docs for r in d[key]["pairs"]])


def _pooled(rows: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {"target_per_hour": TARGET_PER_HOUR, "pairs": rows}
    for label in ("before", "after"):
        n = sum(r[label]["alarms_in_envelope"] for r in rows)
        h = sum(r[label]["hours_in_envelope"] for r in rows)
        lo, hi = garwood(n, h)
        out[label] = {"alarms": n, "hours": h, "rate_per_hour": n / h if h else math.nan,
                      "ci95_per_hour": [lo, hi],
                      "resolved": bool(TARGET_PER_HOUR * h >= -math.log(0.05) / 3)}
    return out


def cross_pairs(flights: dict[str, Any], *, steps: bool = True) -> dict[str, Any]:
    """Every ordered pair of ``flights`` ({name: Flight} of one vehicle): the module
    docstring's counts, before and after, and the pooled rate with its interval."""
    from calibration.inflight import calibration_from_fit, fit_inflight
    from calibration.inflight.fits_flight import flight_calibration
    from thresholds.tune import tune

    cals = {k: calibration_from_fit(fit_inflight(f), f) for k, f in flights.items()}
    thrs = {k: tune(c, false_alarms_per_hour=TARGET_PER_HOUR).thresholds
            for k, c in cals.items()}
    own = {k: flight_calibration(f) for k, f in flights.items()}
    rows = [_pair(a, b, flights[b], cals[a], thrs[a], own[b], steps)
            for a in flights for b in flights if a != b]
    return _pooled(rows)


def calibrate_together(flights: Sequence[Any], fits: Sequence[Any] | None = None) -> Any:
    """``rimu calibrate in-flight F1 F2 ...`` on flights in memory (its library calls:
    each flight fitted, :func:`calibration.inflight.multi.combine_fits`, the file)."""
    from calibration.inflight import calibration_from_fit, fit_inflight
    from calibration.inflight.calfile import flight_values
    from calibration.inflight.multi import combine_fits
    from replay.time_base import with_time_base

    fits = list(fits) if fits is not None else [fit_inflight(f) for f in flights]
    if len(fits) == 1:
        return with_time_base(calibration_from_fit(fits[0], flights[0]), flights[0])
    joint = combine_fits(fits)
    base = flights[joint.base]
    values = tuple(flight_values(f, fl) for f, fl in zip(fits, flights, strict=True))
    cal = calibration_from_fit(joint.fit, base, turn_on_sd=joint.turn_on_sd, flights=values)
    return with_time_base(cal, base)


def xsens_flights() -> dict[str, dict[str, Any]]:
    """The Xsens DOT paths as ``rimu ingest IMU_1.csv ... --map docs/examples/xsens_dot.toml``
    reads them: {"H": {"H1": Flight, ...}, "V": {...}}."""
    from replay.ingest import align_streams, read_any
    from replay.ingest.readers import merge_reads

    root = shared_data() / XSENS
    out: dict[str, dict[str, Any]] = {}
    for grp in ("Horizontal", "Vertical"):
        paths = sorted((root / grp).glob("path_*"), key=lambda p: int(p.name.split("_")[1]))
        out[grp[0]] = {}
        for p in paths:
            reads = [read_any(p / f"IMU_{k}.csv", "csv", map_path=XSENS_MAP)
                     for k in range(1, 5)]
            out[grp[0]][f"{grp[0]}{p.name.split('_')[1]}"] = align_streams(merge_reads(reads))[0]
    return out


def xsens_cases(groups: dict[str, dict[str, Any]] | None = None, *, steps: bool = True,
                only: Sequence[str] | None = None, log: Any = print) -> dict[str, Any]:
    """Each Xsens path monitored with the other paths of its group calibrated together
    and tuned at 1/h (module docstring); ``only`` limits the monitored paths."""
    from calibration.inflight import fit_inflight
    from calibration.inflight.fits_flight import flight_calibration
    from thresholds.tune import tune

    groups = xsens_flights() if groups is None else groups
    rows = []
    for flights in groups.values():
        if only is not None and not set(only) & set(flights):
            continue
        fits = {k: fit_inflight(f) for k, f in flights.items()}
        for mon in flights:
            if only is not None and mon not in only:
                continue
            src = [k for k in flights if k != mon]
            cal = calibrate_together([flights[k] for k in src], [fits[k] for k in src])
            thr = tune(cal, false_alarms_per_hour=TARGET_PER_HOUR).thresholds
            own = flight_calibration(flights[mon])
            rows.append(_pair("+".join(src), mon, flights[mon], cal, thr, own, steps))
            if log is not None:
                a = rows[-1]["after"]
                log(f"{mon}: {a['alarms_in_envelope']} alarms, excluded {a['excluded']}, "
                    f"unverified {100 * a['unverified_fraction']:.1f} %")
    return _pooled(rows)


def erle_flights() -> dict[str, Any]:
    """Erle flights 41 and 83 from the shared data."""
    folder, names = ERLE
    return {n.split("_")[-1].split(".")[0]: load_log(shared_data() / folder / n)
            for n in names}


def table(doc: dict[str, Any]) -> str:
    """A markdown table of :func:`cross_pairs`."""
    lines = ["| calibrated on -> monitored | alarms in envelope (before -> after) | "
             "exposure s | excluded | unverified | 10 deg/s step within 1 s | firmware | "
             "misfit parameters |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in doc["pairs"]:
        b, a = r["before"], r["after"]
        st = r.get("steps", [])
        ok = sum(s["detected_within"] for s in st)
        src = r["calibrated_on"]
        if "+" in src:
            src = f"{src.count('+') + 1} other paths together"
        lines.append(
            f"| {src} -> {r['monitored']} | {b['alarms_in_envelope']} -> "
            f"{a['alarms_in_envelope']} | {3600 * a['hours_in_envelope']:.0f} | "
            f"{b['excluded'] or '-'} -> {a['excluded'] or '-'} | "
            f"{100 * b['unverified_fraction']:.1f}% -> {100 * a['unverified_fraction']:.1f}% | "
            f"{ok} of {len(st)} | {_firmware(r)} | "
            f"{', '.join(sorted({m['imu'] + ' ' + m['parameter'] for m in r['misfit']}))} |")
    for label in ("before", "after"):
        p = doc[label]
        lines.append(f"\n{label}: {p['alarms']} alarms in {3600 * p['hours']:.0f} s inside "
                     f"the envelope over all pairs: {p['rate_per_hour']:.3g}/h, exact Poisson "
                     f"95 % interval {p['ci95_per_hour'][0]:.3g}-{p['ci95_per_hour'][1]:.3g}/h "
                     f"against {doc['target_per_hour']:g}/h "
                     f"({'resolved' if p['resolved'] else 'not resolved by this length'})")
    return "\n".join(lines)


BEGIN = "<!-- cross-flight: generated by studies/cross_flight.py -->"
END = "<!-- end cross-flight -->"
TITLES = {"erle": "erle PXF, two IMUs, 50 Hz: each flight calibrated on the other",
          "xsens": "Xsens DOT, four IMUs, 120 Hz: each path monitored with the other paths "
                   "of its group (horizontal, vertical) calibrated together"}


def verdicts(doc: dict[str, Any]) -> list[str]:
    """The issue's cross-flight must-hold, part by part, on one set of pairs (after)."""
    rows = doc["pairs"]
    n = len(rows)
    excl = [r["monitored"] for r in rows if r["after"]["excluded"]]
    many = [r["monitored"] for r in rows if r["after"]["alarms_in_envelope"] > 1]
    unv = [r["monitored"] for r in rows if r["after"]["unverified_fraction"] > 0.10]
    st = [x for r in rows for x in r.get("steps", [])]
    ok = sum(x["detected_within"] for x in st)
    p = doc["after"]
    lo, hi = p["ci95_per_hour"]
    pooled = (f"{p['alarms']} alarms in {3600 * p['hours']:.0f} s: {p['rate_per_hour']:.3g}/h, "
              f"exact Poisson 95 % interval {lo:.3g}-{hi:.3g}/h against "
              f"{doc['target_per_hour']:g}/h")
    if lo > doc["target_per_hour"]:
        pooled += ": **not met** (the interval lies above the target)"
    elif p["resolved"]:
        pooled += " (resolved): **met**"
    else:
        pooled += " (the length does not resolve the target; none above it)"

    def part(bad: list[str]) -> str:
        return "**met**" if not bad else f"**not met** ({len(bad)} of {n}: {', '.join(bad)})"

    return [f"- no exclusion: {part(excl)}",
            f"- at most one alarm inside the envelope per pair: {part(many)}",
            f"- over all pairs together: {pooled}",
            f"- at most 10 % of the samples unverified: {part(unv)}",
            f"- a 10 °/s step detected within 1 s: {ok} of {len(st)} runs "
            + ("(**met**)" if st and ok == len(st) else "(**not met**)" if st else "(not run)")]


def markdown(doc: dict[str, Any]) -> str:
    """The generated block of docs/next-flight.md and docs/field-results.md."""
    wall = f", {doc['wall_s']:.0f} s" if "wall_s" in doc else ""
    out = [BEGIN, f"Measured with `python -m studies.cross_flight` "
           f"(commit {doc.get('commit', '?')}{wall}). Before: "
           "`--turn-on off --keep-firmware-parameters` (the calibration as it is); after: "
           "the chain's defaults. Alarms are counted inside the envelope; unverified is the "
           "share of all samples with an unverified axis."]
    for key in ("erle", "xsens"):
        if key not in doc:
            continue
        own = doc[key].get("commit")
        when = [] if own is None else ["", f"(this group: commit {own}, merged with --merge)"]
        out += ["", f"**{TITLES[key]}**", *when, "", table(doc[key]), "", *verdicts(doc[key])]
    out.append(END)
    return "\n".join(out)


def write_doc(path: str | Path, block: str) -> None:
    """Replace the generated block in ``path`` (appended when the file has none)."""
    p = Path(path)
    text = p.read_text(encoding="utf-8")
    if BEGIN in text and END in text:
        a, b = text.index(BEGIN), text.index(END) + len(END)
        text = text[:a] + block + text[b:]
    else:
        text = text.rstrip("\n") + "\n\n" + block + "\n"
    p.write_text(text, encoding="utf-8")


def main(argv: Sequence[str] | None = None) -> None:
    """Compute the pairs, print the tables and write the JSON."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m studies.cross_flight")
    ap.add_argument("--groups", default="erle,xsens")
    ap.add_argument("--out", default=str(Path(__file__).with_name("cross_flight.json")))
    ap.add_argument("--no-steps", action="store_true")
    ap.add_argument("--only", help="Xsens: monitor only these paths (comma-separated, H1,V3)")
    ap.add_argument("--doc", action="append", default=[],
                    help="write the generated block into this markdown file (repeatable)")
    ap.add_argument("--from-json", action="store_true",
                    help="only rewrite the --doc blocks from --out")
    ap.add_argument("--merge", action="store_true",
                    help="keep the groups of --out that this run does not compute")
    a = ap.parse_args(argv)
    if a.from_json:
        doc = json.loads(Path(a.out).read_text(encoding="utf-8"))
        for d in a.doc:
            write_doc(d, markdown(doc))
        return
    import subprocess
    import time

    t0 = time.monotonic()
    groups = a.groups.split(",")
    doc: dict[str, Any] = {}
    if a.merge and Path(a.out).exists():
        kept = json.loads(Path(a.out).read_text(encoding="utf-8"))
        for k in TITLES:
            if k in kept and k not in groups:       # each kept group keeps its own commit
                doc[k] = {"commit": kept.get("commit", "?"), "wall_s": kept.get("wall_s"),
                          **kept[k]}
    try:
        doc["commit"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], check=True,
                                       capture_output=True, text=True,
                                       cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        doc["commit"] = "?"
    if "erle" in groups:
        doc["erle"] = cross_pairs(erle_flights(), steps=not a.no_steps)
        print(table(doc["erle"]))
    if "xsens" in groups:
        doc["xsens"] = xsens_cases(steps=not a.no_steps,
                                   only=a.only.split(",") if a.only else None)
        print(table(doc["xsens"]))
    doc["wall_s"] = time.monotonic() - t0
    Path(a.out).write_text(json.dumps(doc, indent=1, default=float) + "\n", encoding="utf-8")
    for d in a.doc:
        write_doc(d, markdown(doc))


if __name__ == "__main__":
    main()
