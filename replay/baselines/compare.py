"""The autopilot baselines beside rimu's answer, on the same samples.

:func:`run_baselines` runs the named rules (:data:`BASELINES`) on a flight's IMU triads;
:func:`fault_outcome` says, for one injected fault, when a rule first flagged at or after
its onset and whom it first blamed (the same definitions as rimu's report,
:mod:`replay.report`: the first flag at or after the onset is the detection, the first
blame at or after it the isolation, correct when it names the IMU of the faulted sensor);
:func:`baselines_record` makes the report's ``"baselines"`` block (``rimu.baselines/1``)
with rimu's answer to each fault beside each rule's, and :func:`format_baselines` its
text.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from replay.baselines.ardupilot import ardupilot_consistency
from replay.baselines.common import BaselineResult, Triads, triads_from_flight
from replay.baselines.px4 import px4_selector, px4_selector_others
from replay.flight_data import Flight

__all__ = ["BASELINES", "BASELINES_SCHEMA", "BaselineRun", "baseline_run", "baselines_record",
           "fault_outcome",
           "format_baselines", "parse_baselines", "rimu_fault_outcome", "run_baselines"]

BASELINES_SCHEMA = "rimu.baselines/1"
"""Format of the report's ``"baselines"`` block."""

BASELINES: dict[str, Callable[[Triads], BaselineResult]] = {
    "px4": px4_selector,
    "px4-others": px4_selector_others,
    "ardupilot": ardupilot_consistency,
}
"""The rules by name (``--baseline px4,ardupilot``)."""


def parse_baselines(text: str | Sequence[str] | None) -> tuple[str, ...]:
    """``"px4,ardupilot"`` → ``("px4", "ardupilot")`` (``"all"``: every rule).

    Raises
    ------
    ConfigError
        An unknown name (the known ones listed).
    """
    if not text:
        return ()
    items = text.split(",") if isinstance(text, str) else list(text)
    names = [s.strip().lower() for s in items if s.strip()]
    if names == ["all"]:
        return tuple(BASELINES)
    bad = [s for s in names if s not in BASELINES]
    if bad:
        raise ConfigError(f"--baseline {bad[0]!r}: unknown; expected a comma-separated list "
                          f"of {', '.join(BASELINES)} (or all)")
    return tuple(dict.fromkeys(names))


def run_baselines(flight: Flight, names: Sequence[str], cal: Calibration | None = None
                  ) -> tuple[Triads, dict[str, BaselineResult]]:
    """The IMU triads of ``flight`` and each named rule's answer over them."""
    tri = triads_from_flight(flight, cal)
    return tri, {nm: BASELINES[nm](tri) for nm in names}


def fault_outcome(res: BaselineResult, triads: Triads, fault: Any,
                  others: Sequence[Any] = ()) -> dict[str, Any]:
    """One rule's answer to one injected fault.

    Detection: the first ``flagged`` event at or after the onset that does not blame the
    IMU of another injected fault; isolation: the first such event that blames an IMU.
    A rule still flagged from before the onset detects the fault only when it flags anew
    (a new blame), as rimu's report counts only events at or after the onset.
    """
    imu = triads.imu_of_sensor(int(fault.sensor))
    other = {triads.imus[j] for j in (triads.imu_of_sensor(int(g.sensor)) for g in others)
             if j >= 0 and j != imu}
    after = [e for e in res.events if e.type == "flagged" and e.t >= fault.onset - 1e-9
             and e.imu not in other]
    det = after[0] if after else None
    iso = next((e for e in after if e.imu is not None), None)
    name = triads.imus[imu] if imu >= 0 else None
    return {"detected": det is not None,
            "detection_delay_s": None if det is None else max(0.0, det.t - fault.onset),
            "blamed": None if iso is None else iso.imu,
            "isolation_delay_s": None if iso is None else max(0.0, iso.t - fault.onset),
            "blame_correct": None if iso is None else iso.imu == name,
            "flagged_at_onset": bool(_flag_at(res, fault.onset))}


def _flag_at(res: BaselineResult, t: float) -> bool:
    import numpy as np

    k = int(np.searchsorted(res.t, t - 1e-9))
    return bool(res.flagged[k - 1]) if k > 0 else False


def rimu_fault_outcome(outcome: Mapping[str, Any], triads: Triads) -> dict[str, Any]:
    """rimu's report entry of a fault (:mod:`replay.report`) in the baselines' terms: the
    sensor it isolated read as its IMU."""
    s = outcome.get("isolated_sensor")
    j = triads.imu_of_sensor(int(s)) if s is not None else -1
    want = triads.imu_of_sensor(int(outcome["sensor"]))
    return {"detected": bool(outcome["detected"]),
            "detection_delay_s": outcome["detection_delay_s"],
            "blamed": triads.imus[j] if j >= 0 else None,
            "isolation_delay_s": outcome["isolation_delay_s"],
            "blame_correct": None if j < 0 else j == want}


def baselines_record(triads: Triads, results: Mapping[str, BaselineResult],
                     flight: Flight, report: Mapping[str, Any] | None = None, *,
                     max_events: int | None = 200) -> dict[str, Any]:
    """The report's ``"baselines"`` block: each rule's record and, per injected fault,
    each rule's answer beside rimu's (``report``: rimu's ``rimu.report/1``)."""
    faults = list(flight.faults)
    rimu = list(report.get("faults", [])) if report is not None else []
    per_fault = []
    for k, f in enumerate(faults):
        j = triads.imu_of_sensor(int(f.sensor))
        row: dict[str, Any] = {"spec": f.spec or f.kind, "kind": f.kind, "sensor": f.sensor,
                               "imu": triads.imus[j] if j >= 0 else None,
                               "onset_s": float(f.onset)}
        if k < len(rimu):
            row["rimu"] = rimu_fault_outcome(rimu[k], triads)
        for nm, r in results.items():
            row[nm] = fault_outcome(r, triads, f, [g for g in faults if g is not f])
        per_fault.append(row)
    return {"schema": BASELINES_SCHEMA, "samples": triads.how, "imus": list(triads.imus),
            "definitions": {
                "flag": "the rule declares a fault (PX4: the selector's accumulated error "
                        "above its threshold, or a validator failure; ArduPilot: an IMU "
                        "inconsistent with the primary within the last 10 s)",
                "detection": "the first flag event at or after a fault's onset",
                "blame": "the first flag event at or after the onset that names an IMU; "
                         "correct when it is the IMU of the faulted sensor"},
            "results": [r.to_dict(max_events=max_events) for r in results.values()],
            "faults": per_fault}


def _fmt_s(x: Any) -> str:
    return "-" if x is None else f"{x:.3g} s"


def format_baselines(rec: Mapping[str, Any], *, max_events: int = 10) -> str:
    """Readable text of a ``"baselines"`` block."""
    lines = [f"baselines on the same samples ({rec['samples']}; IMUs "
             f"{', '.join(rec['imus'])}):"]
    for r in rec["results"]:
        s = r["summary"]
        first = ("never" if s["first_flag_s"] is None else
                 f"first at t={s['first_flag_s']:.3f} s blaming "
                 f"{s['first_blamed'] or 'nobody'}")
        lines.append(f"  {r['name']}: {r['rule']}")
        lines.append(f"    flagged {s['flag_events']} time(s), {first}; blamed "
                     f"{', '.join(s['blamed_imus']) or 'nobody'}; flagged "
                     f"{100 * s['flagged_fraction']:.1f} % of the samples")
        for e in r["events"][:max_events]:
            v = "" if e["value"] is None else f"  {e['value']:.4g} {e['unit']}"
            lines.append(f"    t={e['t']:.3f} s  {e['type']:<8} {e['imu'] or '-':>6}  "
                         f"{e['reason']}{v}")
        if r["events_total"] > max_events:
            lines.append(f"    ... {r['events_total'] - max_events} more")
    for row in rec["faults"]:
        parts = []
        for nm in ["rimu", *[r["name"] for r in rec["results"]]]:
            o = row.get(nm)
            if o is None:
                continue
            det = f"detected after {_fmt_s(o['detection_delay_s'])}" if o["detected"] \
                else "not detected"
            blame = (f"blamed {o['blamed']} ({'right' if o['blame_correct'] else 'WRONG'})"
                     if o["blamed"] is not None else "blamed nobody")
            parts.append(f"{nm} {det}, {blame}")
        lines.append(f"  fault {row['spec']} ({row['imu']}): " + "; ".join(parts))
    return "\n".join(lines)


@dataclass(frozen=True)
class BaselineRun:
    """One rule's answer to one campaign run (``rimu evaluate --baseline``), counted as
    :mod:`thresholds.campaign` counts rimu's: the first flag before the onset is a false
    alarm and the exposure runs until it (or the onset); the first flag at or after the
    onset is the detection, the first blame at or after it the isolation.

    Attributes
    ----------
    name : str
    false_alarm : bool
    exposure_s : float
        Healthy time observed (s).
    detected : bool
    delay_s : float
        Detection delay (s; NaN if none).
    blamed : int
        0-based IMU first blamed at or after the onset (−1: none).
    blame_correct : bool or None
        The IMU blamed is the faulted sensor's (None: nobody blamed, or a healthy run).
    """

    name: str
    false_alarm: bool
    exposure_s: float
    detected: bool
    delay_s: float
    blamed: int
    blame_correct: bool | None


def baseline_run(res: BaselineResult, triads: Triads, *, onset_s: float, duration_s: float,
                 sensor: int = 0) -> BaselineRun:
    """A :class:`BaselineRun` of ``res`` (``sensor``: the 1-based faulted sensor, 0 for a
    healthy run; ``onset_s`` inf for a healthy run)."""
    import math

    first = res.first_flag()
    t_first = first.t if first is not None else math.inf
    fa = t_first < onset_s - 1e-12
    exposure = min(t_first, onset_s, duration_s)
    det = res.first_flag(onset_s) if math.isfinite(onset_s) else None
    iso = res.first_blame(onset_s) if math.isfinite(onset_s) else None
    blamed = res.imus.index(iso.imu) if iso is not None and iso.imu is not None else -1
    want = triads.imu_of_sensor(sensor) if sensor else -1
    return BaselineRun(res.name, bool(fa), float(exposure), det is not None,
                       float(det.t - onset_s) if det is not None else math.nan, blamed,
                       None if blamed < 0 or want < 0 else blamed == want)
