"""rimu against the autopilots' rules on the same samples: injected faults on every axis of
every IMU of real multi-IMU flights (and simulated sets), and the clean flights.

Run (writes the JSON and the generated table of docs/baselines.md)::

    python -m studies.baselines_campaign --out studies/baselines.json --doc docs/baselines.md \
        [--jobs 2] [--groups erle,sim3,sim4,xsens]

What it does, per *case* (a flight monitored with a calibration of another flight of the
same vehicle where the recordings allow):

- the clean flight through rimu (:func:`replay.chain.chain_for_flight`, the chain of
  ``rimu monitor-file``, thresholds computed for :data:`FALSE_ALARMS_PER_HOUR`) and through
  each baseline (:mod:`replay.baselines`): alarms counted the same way for all, the number
  of alarm events (rimu: ``detected``/``isolated``/``health`` events; a rule: its
  ``flagged`` events, a change of blame included) and the IMUs excluded or blamed;
- every fault of :data:`FAULTS` on every axis of every IMU at each onset of
  :data:`ONSET_FRACTIONS` (one fault per run, injected into the raw samples by
  :func:`replay.scenario.inject`), through rimu and every baseline: detection (the first
  alarm at or after the onset) and its delay, the first IMU excluded or blamed at or after
  the onset and whether it is the faulted IMU, and wrong exclusions (an IMU other than the
  faulted one excluded or blamed at or after the onset).

Cases (:func:`build_cases`): the two erle PXF flights (two IMUs, 50 Hz), each calibrated on
the other; the fourteen four-IMU Xsens DOT flights (120 Hz), each calibrated on the next
path of its group (the units may have been power-cycled between paths); simulated three- and
four-IMU sets (:func:`replay.imu_set.simulate_imu_set`), calibrated on the first half of
the flight and monitored on the second. Nothing here is tuned to the data: the sizes and
onsets are fixed physical values, rimu runs with its defaults, the rules with the
autopilots' defaults.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from fdi.units import DPS
from replay.baselines import run_baselines
from replay.faults import Fault
from replay.flight_data import AuxChannels, Flight
from replay.report import ALARM_TYPES

__all__ = ["FAULTS", "ONSET_FRACTIONS", "SCHEMA", "Case", "build_cases", "main",
           "markdown", "run_campaign", "run_case", "summarise"]

SCHEMA = "rimu.baselines-campaign/1"
FALSE_ALARMS_PER_HOUR = 1.0
"""rimu's thresholds: computed from the calibration for this budget (per hour)."""
RULES = ("px4", "px4-others", "ardupilot")
FAULTS: tuple[tuple[str, str, float, float | None], ...] = (
    # (label, kind, size in SI, duration s or None: to the end)
    ("step 2 deg/s", "step", 2.0 * DPS, None),
    ("step 5 deg/s", "step", 5.0 * DPS, None),
    ("step 10 deg/s", "step", 10.0 * DPS, None),
    ("ramp 1 deg/s/s", "ramp", 1.0 * DPS, None),
    ("stuck", "stuck", 0.0, None),
    ("noise x10 for 5 s", "noise", 10.0, 5.0),
)
"""The injected faults: fixed physical sizes (not scaled to any flight's noise, except the
noise burst, which multiplies the calibration's own white noise)."""
ONSET_FRACTIONS = (0.35, 0.6)
"""Onsets: at these fractions of the monitored samples."""
SHARED = Path(os.environ.get("RIMU_SHARED_DATA",
                             Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))


@dataclass(frozen=True, eq=False)
class Case:
    """A flight to monitor and the calibration rimu monitors it with.

    Attributes
    ----------
    name : str
    group : str
        ``"erle"`` (two IMUs), ``"xsens"`` (four), ``"sim3"``, ``"sim4"``.
    flight : Flight
    cal : Any
        rimu's calibration (of ``cal_source``).
    cal_source : str
    """

    name: str
    group: str
    flight: Flight
    cal: Any
    cal_source: str


# ------------------------------------------------------------------ flights
def read_erle(name: str) -> Flight:
    """An erle PXF log as ``rimu ingest`` reads it."""
    from replay.ingest import align_streams, read_any

    files = {"83": "pxf_copter_31-3-2015_83.BIN", "41": "pxf_copter_22-12-2014_41.BIN"}
    flight, _ = align_streams(read_any(SHARED / "erle_pxf_dual_imu" / files[name],
                                       salvage=True))
    return flight


def read_xsens(folder: Path) -> Flight:
    """One path of the four Xsens DOT units (IMU_1..4.csv: time s, Gyr deg/s, Acc m/s²) as
    a gyro flight of four IMU groups (the study's reader; the product's ingest is helper
    ``inflight``'s)."""
    tables = []
    for k in range(1, 5):
        path = folder / f"IMU_{k}.csv"
        with open(path, encoding="utf-8") as fh:
            cols = fh.readline().strip().split(",")
        tables.append((cols, np.loadtxt(path, delimiter=",", skiprows=1)))
    n = min(a.shape[0] for _, a in tables)
    # one time base: the median of the four units' stamps (one unit's repeated or skipped
    # stamp, as Vertical/path_4/IMU_1 has, does not move it)
    t = np.median(np.column_stack([a[:n, c.index("time")] for c, a in tables]), axis=1)
    gyr = [a[:n, [c.index(f"Gyr_{x}") for x in "XYZ"]] * DPS for c, a in tables]
    acc = [a[:n, [c.index(f"Acc_{x}") for x in "XYZ"]] for c, a in tables]
    raw = np.concatenate(gyr, axis=1)
    names = tuple(f"imu{k}.{c}" for k in range(1, 5) for c in "xyz")
    imu = tuple(f"imu{k}" for k in range(1, 5) for _ in range(3))
    av = np.concatenate(acc, axis=1)
    aux = AuxChannels(("accel",) * 12, names, imu, av, np.isfinite(av))
    return Flight(t=t, raw=raw, valid=np.isfinite(raw), sample_rate_hz=120.0,
                  sensor_names=names, raw_unit="rad/s", source=str(folder), kind="gyro",
                  imu=imu, aux=aux)


def calibrate(flight: Flight) -> Any:
    """rimu's in-flight calibration with its defaults (what ``rimu calibrate in-flight``
    runs)."""
    from calibration.inflight import calibration_from_fit, fit_inflight

    return calibration_from_fit(fit_inflight(flight), flight)


def _part(f: Flight, a: int, b: int) -> Flight:
    return replace(f, t=f.t[a:b], raw=f.raw[a:b], valid=f.valid[a:b],
                   omega_true=None if f.omega_true is None else f.omega_true[a:b],
                   aux=None if f.aux is None else f.aux.slice(slice(a, b)), truth={},
                   faults=())


def build_cases(groups: Sequence[str] = ("erle", "sim3", "sim4", "xsens"), *,
                log: Any = None) -> tuple[list[Case], list[dict[str, Any]]]:
    """The cases of the study and the ones that could not be run (with the reason: a
    calibration refused, or one that failed with an exception other than rimu's own,
    named by its type, which is a finding about the product)."""
    cases, skipped = [], []

    def note(msg: str) -> None:
        if log is not None:
            log(msg)

    if "erle" in groups:
        if not (SHARED / "erle_pxf_dual_imu").is_dir():
            skipped.append({"case": "erle", "why": f"no {SHARED / 'erle_pxf_dual_imu'}"})
        else:
            fl = {n: read_erle(n) for n in ("41", "83")}
            for mon, src in (("41", "83"), ("83", "41")):
                try:
                    cases.append(Case(f"erle {mon} (cal {src})", "erle", fl[mon],
                                      calibrate(fl[src]), f"erle {src}"))
                except Exception as exc:  # a refusal or a crash: no rimu answer
                    skipped.append({"case": f"erle {mon}", "why": _why(exc)})
            note("erle cases built")
    for k in (3, 4):
        if f"sim{k}" not in groups:
            continue
        from replay.imu_set import ImuSetSpec, simulate_imu_set

        f = simulate_imu_set(ImuSetSpec(imus=k, duration_s=240.0, sample_rate_hz=100.0,
                                        seed=20 + k, max_rate_dps=200.0))
        n = f.t.shape[0] // 2
        cases.append(Case(f"sim{k} second half (cal first half)", f"sim{k}",
                          _part(f, n, None), calibrate(_part(f, 0, n)),
                          f"sim{k} first half"))
        note(f"sim{k} case built")
    if "xsens" in groups:
        root = SHARED / "ansfl_4x_xsens_dot"
        if not root.is_dir():
            skipped.append({"case": "xsens", "why": f"no {root}"})
        else:
            for grp in ("Horizontal", "Vertical"):
                paths = sorted((root / grp).glob("path_*"),
                               key=lambda p: int(p.name.split("_")[1]))
                fl = [read_xsens(p) for p in paths]
                for i, p in enumerate(paths):
                    j = (i + 1) % len(paths)
                    name = f"xsens {grp[0]}{p.name.split('_')[1]}"
                    try:
                        cal = calibrate(fl[j])
                    except Exception as exc:  # a refusal or a crash: no rimu answer
                        skipped.append({"case": name, "why": f"calibration on "
                                        f"{paths[j].name}: {_why(exc)}"})
                        continue
                    cases.append(Case(f"{name} (cal {grp[0]}{paths[j].name.split('_')[1]})",
                                      "xsens", fl[i], cal, f"xsens {grp} {paths[j].name}"))
            note("xsens cases built")
    return cases, skipped


def _why(exc: Exception) -> str:
    from fdi.errors import RimuError

    text = str(exc).replace(str(SHARED) + "/", "")
    return text if isinstance(exc, RimuError) else f"{type(exc).__name__} (a crash): {text}"


# ------------------------------------------------------------------ one run
def _rimu(case: Case, flight: Flight, thr: Any) -> dict[str, Any]:
    from replay.chain import ChainOptions, chain_for_flight, run_flight

    chain = chain_for_flight(flight, case.cal, ChainOptions(thresholds=thr))
    _, report = run_flight(chain, flight)
    return report


def _imu_of(names: Sequence[str], imus: Sequence[str], sensor: Any) -> str | None:
    if sensor is None:
        return None
    nm = names[int(sensor) - 1]
    g = nm.rpartition(".")[0]
    return g if g in imus else None


def _rimu_outcome(rep: dict[str, Any], imus: Sequence[str], imu: str | None,
                  onset: float) -> dict[str, Any]:
    names = rep["sensor_names"]
    ev = rep["events"]
    alarms = [e for e in ev if e["type"] in ALARM_TYPES]
    excl = [e for e in ev if e["type"] in ("isolated", "health") and e.get("sensor")]
    out = {"alarms": len(alarms),
           "excluded": sorted({_imu_of(names, imus, e["sensor"]) or "?" for e in excl})}
    if imu is None:
        return out
    after = [e for e in alarms if e["t"] >= onset - 1e-9]
    ex_after = [e for e in excl if e["t"] >= onset - 1e-9]
    first_ex = ex_after[0] if ex_after else None
    blamed = _imu_of(names, imus, first_ex["sensor"]) if first_ex else None
    out.update({
        "detected": bool(after),
        "delay_s": after[0]["t"] - onset if after else None,
        "blamed": blamed,
        "blame_delay_s": first_ex["t"] - onset if first_ex else None,
        "blame_correct": None if blamed is None else blamed == imu,
        "wrong_exclusions": sum(_imu_of(names, imus, e["sensor"]) != imu for e in ex_after),
        "wrong_exclusion_before_onset": any(e["t"] < onset - 1e-9 for e in excl),
    })
    return out


def _rule_outcome(res: Any, imu: str | None, onset: float) -> dict[str, Any]:
    flags = [e for e in res.events if e.type == "flagged"]
    out = {"alarms": len(flags), "excluded": sorted({e.imu for e in flags if e.imu})}
    if imu is None:
        return out
    after = [e for e in flags if e.t >= onset - 1e-9]
    named = [e for e in after if e.imu is not None]
    k = int(np.searchsorted(res.t, onset - 1e-9))
    out.update({
        "detected": bool(after),
        "delay_s": after[0].t - onset if after else None,
        "blamed": named[0].imu if named else None,
        "blame_delay_s": named[0].t - onset if named else None,
        "blame_correct": None if not named else named[0].imu == imu,
        "wrong_exclusions": sum(e.imu != imu for e in named),
        "wrong_exclusion_before_onset": any(e.imu is not None and e.t < onset - 1e-9
                                            for e in flags),
        "flagged_at_onset": bool(res.flagged[k - 1]) if k > 0 else False,
    })
    return out


def run_case(case: Case, faults: Iterable[tuple[str, str, float, float | None]] = FAULTS,
             onsets: Sequence[float] = ONSET_FRACTIONS, *, sensors: Sequence[int] | None = None,
             rules: Sequence[str] = RULES, log: Any = None) -> dict[str, Any]:
    """The clean flight and every injected run of one case.

    ``sensors``: 1-based sensors to fault (default: every axis of every IMU).
    """
    from replay.scenario import inject
    from replay.threshold_choice import select

    thr = select(case.cal, false_alarms_per_hour=FALSE_ALARMS_PER_HOUR).thresholds
    f = case.flight
    imus = tuple(dict.fromkeys(f.imu))
    rep = _rimu(case, f, thr)
    tri, res = run_baselines(f, rules, case.cal)
    clean = {"rimu": _rimu_outcome(rep, imus, None, math.inf),
             "duration_s": float(f.t[-1] - f.t[0]), "samples": int(f.t.shape[0]),
             "baseline_samples": tri.how}
    clean.update({nm: _rule_outcome(r, None, math.inf) for nm, r in res.items()})
    runs = []
    N = f.t.shape[0]
    sensors = list(sensors) if sensors is not None else list(range(1, f.n + 1))
    t0 = time.perf_counter()
    for label, kind, size, dur in faults:
        for frac in onsets:
            onset = float(f.t[int(frac * N)])
            for s in sensors:
                spec = f"{kind}:{s}:{label}:{onset:.3f}"
                inj = inject(f, (Fault(kind, s, size, onset, dur, spec),), case.cal,
                             seed=s + 1000 * int(100 * frac))
                imu = f.imu[s - 1]
                rrep = _rimu(case, inj, thr)
                _, rr = run_baselines(inj, rules, case.cal)
                row = {"fault": label, "sensor": s, "axis": f.sensor_names[s - 1],
                       "imu": imu, "onset_s": onset,
                       "rimu": _rimu_outcome(rrep, imus, imu, onset)}
                row.update({nm: _rule_outcome(r, imu, onset) for nm, r in rr.items()})
                runs.append(row)
        if log is not None:
            log(f"  {case.name}: {label} done ({time.perf_counter() - t0:.0f} s)")
    return {"case": case.name, "group": case.group, "cal_source": case.cal_source,
            "imus": list(imus), "sample_rate_hz": float(f.sample_rate_hz), "clean": clean,
            "runs": runs}


# ------------------------------------------------------------------ summary
MONITORS = ("rimu", *RULES)


def _rate(k: int, n: int) -> dict[str, Any]:
    from thresholds.evaluate import wilson_interval

    return {"k": k, "n": n, "p": k / n if n else None,
            "ci95": list(wilson_interval(k, n)) if n else None}


def _cells(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    labels = list(dict.fromkeys(r["fault"] for r in runs))
    for lab in labels:
        rs = [r for r in runs if r["fault"] == lab]
        row: dict[str, Any] = {"fault": lab, "runs": len(rs)}
        for m in MONITORS:
            o = [r[m] for r in rs if m in r]
            if not o:
                continue
            d = np.array([x["delay_s"] for x in o if x["detected"]])
            row[m] = {"detected": _rate(sum(x["detected"] for x in o), len(o)),
                      "right_blame": _rate(sum(bool(x["blame_correct"]) for x in o), len(o)),
                      "wrong_exclusions": sum(x["wrong_exclusions"] for x in o),
                      "runs_with_wrong_exclusion": sum(x["wrong_exclusions"] > 0 for x in o),
                      "delay_s_median": float(np.median(d)) if d.size else None,
                      "delay_s_p90": float(np.quantile(d, 0.9)) if d.size else None}
        out.append(row)
    return out


def _must_hold(cases: list[dict[str, Any]]) -> dict[str, Any]:
    """The issue's claims against the autopilots, measured (met or not, with figures)."""
    runs = [r for c in cases for r in c["runs"]]
    def later_than(rule: str) -> list[dict[str, Any]]:
        return [r for r in runs if r[rule]["detected"]
                and (not r["rimu"]["detected"]
                     or r["rimu"]["delay_s"] > r[rule]["delay_s"] + 1e-9)]

    later = later_than("px4")
    later_others = later_than("px4-others")
    px4_det = sum(r["px4"]["detected"] for r in runs)
    blame = {m: sum(bool(r[m]["blame_correct"]) for r in runs) for m in MONITORS}
    per_cell_blame = []
    for c in cases:
        for cell in _cells(c["runs"]):
            best = max(cell[m]["right_blame"]["k"] for m in RULES if m in cell)
            if cell["rimu"]["right_blame"]["k"] < best:
                per_cell_blame.append({"case": c["case"], "fault": cell["fault"],
                                       "rimu": cell["rimu"]["right_blame"]["k"],
                                       "best_rule": best, "runs": cell["runs"]})
    clean_rows = [{"case": c["case"], **{m: c["clean"][m]["alarms"] for m in MONITORS}}
                  for c in cases]
    clean_bad = [r for r in clean_rows if any(r["rimu"] > r[m] for m in ("px4", "ardupilot"))]
    out: dict[str, Any] = {
        "detects_no_later_than_px4": {
            "runs": len(runs), "px4_detected": px4_det, "rimu_later_or_missed": len(later),
            "met": not later,
            "px4_others_detected": sum(r["px4-others"]["detected"] for r in runs),
            "rimu_later_or_missed_than_px4_others": len(later_others),
            "examples": [{k: r[k] for k in ("fault", "axis", "onset_s")} | {
                "case": _case_of(cases, r), "rimu_delay_s": r["rimu"]["delay_s"],
                "px4_delay_s": r["px4"]["delay_s"]} for r in later[:8]]},
        "right_blame_at_least_as_often": {
            "runs": len(runs), "right_blames": blame,
            "met": all(blame["rimu"] >= blame[m] for m in RULES) and not per_cell_blame,
            "cells_where_a_rule_blames_right_more_often": per_cell_blame},
        "clean_alarms_no_more": {
            "per_flight": clean_rows, "met": not clean_bad,
            "flights_where_rimu_raises_more": [r["case"] for r in clean_bad],
            "totals": {m: sum(r[m] for r in clean_rows) for m in MONITORS}},
    }
    four = [c for c in cases if c["group"] in ("xsens", "sim4")]
    for grp in ("xsens", "sim4"):
        cs = [c for c in four if c["group"] == grp]
        if not cs:
            continue
        rs = [r for c in cs for r in c["runs"]]
        s5 = [r for r in rs if r["fault"] == "step 5 deg/s"]
        s2 = [r for r in rs if r["fault"] == "step 2 deg/s"]
        ok5 = sum(bool(r["rimu"]["blame_correct"]) and r["rimu"]["blame_delay_s"] <= 1.0
                  for r in s5)
        ok2 = sum(r["rimu"]["detected"] and r["rimu"]["delay_s"] <= 5.0 for r in s2)
        wrong = sum(r["rimu"]["wrong_exclusions"] > 0 for r in rs)
        out[f"four_imu_{grp}"] = {
            "flights": len(cs),
            "step5_excluded_right_within_1s": _rate(ok5, len(s5)),
            "step2_detected_within_5s": _rate(ok2, len(s2)),
            "runs_with_wrong_exclusion": wrong, "runs": len(rs),
            "met": bool(s5) and ok5 >= 0.95 * len(s5) and ok2 == len(s2) and wrong == 0}
    return out


def _case_of(cases: list[dict[str, Any]], run: dict[str, Any]) -> str:
    return next(c["case"] for c in cases if any(r is run for r in c["runs"]))


def summarise(cases: list[dict[str, Any]], skipped: list[dict[str, Any]] = (),
              *, meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """The campaign's JSON: per case its clean-flight alarms and fault cells, per group the
    pooled cells, and the must-hold verdicts."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for c in cases:
        groups.setdefault(c["group"], []).append(c)
    return {"schema": SCHEMA, **(meta or {}),
            "definitions": {
                "alarm": "rimu: an event of type detected/isolated/health; a rule: a flagged "
                         "event (a fault declared, or the IMU blamed changes)",
                "detection": "the first alarm at or after the onset",
                "blame": "the first IMU excluded (rimu: isolated/health event, its sensor's "
                         "IMU) or blamed (a rule) at or after the onset",
                "wrong_exclusion": "an IMU other than the faulted one excluded or blamed at "
                                   "or after the onset"},
            "faults": [list(f) for f in FAULTS],
            "onset_fractions": list(ONSET_FRACTIONS), "skipped": list(skipped),
            "groups": {g: {"cases": [c["case"] for c in cs],
                           "cells": _cells([r for c in cs for r in c["runs"]]),
                           "clean": {m: sum(c["clean"][m]["alarms"] for c in cs)
                                     for m in MONITORS},
                           "clean_hours": sum(c["clean"]["duration_s"] for c in cs) / 3600.0}
                       for g, cs in groups.items()},
            "must_hold": _must_hold(cases), "cases": cases}


def _p(x: dict[str, Any]) -> str:
    return "-" if x["p"] is None else f"{100 * x['p']:.0f} %"


def _d(x: Any) -> str:
    return "-" if x is None else f"{x:.2f}"


def markdown(ev: dict[str, Any]) -> str:
    """The generated part of docs/baselines.md."""
    names = {"erle": "erle PXF, two IMUs, 50 Hz (each flight calibrated on the other)",
             "xsens": "Xsens DOT, four IMUs, 120 Hz (each path calibrated on the next)",
             "sim3": "simulated, three IMUs, 100 Hz (calibrated on the first half)",
             "sim4": "simulated, four IMUs, 100 Hz (calibrated on the first half)"}
    lines = [f"Measured on {ev.get('commit', '?')} ({ev.get('date', '?')}); "
             f"`python -m studies.baselines_campaign` ({ev.get('wall_s', 0):.0f} s). "
             "Detection: share of runs with an alarm at or after the onset, median delay; "
             "right blame: share of runs whose first exclusion or blame after the onset names "
             "the faulted IMU; wrong: runs with an exclusion or blame of another IMU after "
             "the onset.", ""]
    for g, G in ev["groups"].items():
        lines += [f"### {names.get(g, g)}", "",
                  f"Cases: {', '.join(G['cases'])}. Clean flights ({G['clean_hours']:.3f} h): "
                  + ", ".join(f"{m} {G['clean'][m]} alarm(s)" for m in MONITORS) + ".", "",
                  "Each cell: detected (median delay s) / right blame / runs with a wrong "
                  "exclusion.", "",
                  "| fault | runs | " + " | ".join(MONITORS) + " |",
                  "|---|---|" + "---|" * len(MONITORS)]
        for c in G["cells"]:
            cells = []
            for m in MONITORS:
                x = c[m]
                cells.append(f"{_p(x['detected'])} ({_d(x['delay_s_median'])}) / "
                             f"{_p(x['right_blame'])} / {x['runs_with_wrong_exclusion']}")
            lines.append(f"| {c['fault']} | {c['runs']} | " + " | ".join(cells) + " |")
        lines.append("")
    mh = ev["must_hold"]
    a, b, c = (mh["detects_no_later_than_px4"], mh["right_blame_at_least_as_often"],
               mh["clean_alarms_no_more"])
    lines += ["### The must-holds against the autopilots", "",
              f"- rimu detects no later than the PX4 rule on every injected fault: "
              f"**{'met' if a['met'] else 'not met'}** — of {a['runs']} runs, PX4 detected "
              f"{a['px4_detected']}; rimu was later or missed in {a['rimu_later_or_missed']} "
              f"(against the px4-others variant: {a['rimu_later_or_missed_than_px4_others']} "
              f"of {a['px4_others_detected']}).",
              f"- rimu blames the right IMU at least as often as either rule: "
              f"**{'met' if b['met'] else 'not met'}** — right blames over all runs: "
              + ", ".join(f"{m} {b['right_blames'][m]}" for m in MONITORS)
              + f"; cells where a rule blames right more often: "
              f"{len(b['cells_where_a_rule_blames_right_more_often'])}.",
              f"- on clean flights rimu raises no more alarms than either rule: "
              f"**{'met' if c['met'] else 'not met'}** — totals "
              + ", ".join(f"{m} {c['totals'][m]}" for m in MONITORS)
              + (f"; rimu raises more on {', '.join(c['flights_where_rimu_raises_more'])}"
                 if c["flights_where_rimu_raises_more"] else "") + "."]
    for grp in ("xsens", "sim4"):
        f = mh.get(f"four_imu_{grp}")
        if f is None:
            continue
        lines.append(f"- four IMUs ({grp}, {f['flights']} flights not used for calibration): "
                     f"**{'met' if f['met'] else 'not met'}** — 5 °/s step excluded to the "
                     f"right IMU within 1 s in {f['step5_excluded_right_within_1s']['k']} of "
                     f"{f['step5_excluded_right_within_1s']['n']} runs (need ≥ 95 %); 2 °/s "
                     f"detected within 5 s in {f['step2_detected_within_5s']['k']} of "
                     f"{f['step2_detected_within_5s']['n']}; runs with a wrong exclusion: "
                     f"{f['runs_with_wrong_exclusion']} of {f['runs']}.")
    if ev.get("skipped"):
        lines += ["", "Not run: " + "; ".join(f"{s['case']}: {s['why']}"
                                               for s in ev["skipped"]) + "."]
    return "\n".join(lines) + "\n"


BEGIN = "<!-- baselines-campaign: generated by studies/baselines_campaign.py -->"
END = "<!-- end baselines-campaign -->"


def write_doc(doc: Path, text: str) -> None:
    """Put ``text`` between the generated markers of ``doc`` (appended when absent)."""
    s = doc.read_text(encoding="utf-8") if doc.exists() else ""
    block = f"{BEGIN}\n{text}{END}\n"
    if BEGIN in s and END in s:
        a, b = s.index(BEGIN), s.index(END) + len(END) + 1
        s = s[:a] + block + s[b:]
    else:
        s = s.rstrip("\n") + "\n\n## Measured: rimu against the rules\n\n" + block
    doc.write_text(s, encoding="utf-8")


def run_campaign(groups: Sequence[str], *, log: Any = None, jobs: int = 1) -> dict[str, Any]:
    """Build the cases and run them all; the summary (:func:`summarise`)."""
    t0 = time.perf_counter()
    cases, skipped = build_cases(groups, log=log)
    if jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(jobs) as pool:
            out = list(pool.map(run_case, cases))
    else:
        out = []
        for c in cases:
            out.append(run_case(c, log=log))
            if log is not None:
                log(f"{c.name}: {len(out[-1]['runs'])} runs ({time.perf_counter() - t0:.0f} s)")
    import subprocess

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, cwd=Path(__file__).parent, check=False
                                ).stdout.strip()
    except OSError:
        commit = "?"
    return summarise(out, skipped, meta={
        "commit": commit or "?", "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "wall_s": time.perf_counter() - t0, "rules": list(RULES),
        "false_alarms_per_hour": FALSE_ALARMS_PER_HOUR})


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="studies/baselines.json")
    p.add_argument("--doc", default="docs/baselines.md")
    p.add_argument("--groups", default="erle,sim3,sim4,xsens")
    p.add_argument("--jobs", type=int, default=1, help="cases run in parallel processes")
    a = p.parse_args(argv)
    ev = run_campaign([g.strip() for g in a.groups.split(",") if g.strip()],
                      log=lambda m: print(m, file=sys.stderr, flush=True), jobs=a.jobs)
    Path(a.out).write_text(json.dumps(ev, separators=(",", ":"), allow_nan=False) + "\n",
                           encoding="utf-8")
    if a.doc:
        write_doc(Path(a.doc), markdown(ev))
    print(markdown(ev))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
