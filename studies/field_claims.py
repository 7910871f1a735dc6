"""Issue 17's Must-hold list, read from :func:`studies.field.field_results`.

:func:`summarise` gives the figures the list speaks of, :func:`must_hold` the verdict of each
claim with what was seen (``tests/thresholds/test_field_results.py`` asserts one claim per
test; ``studies/make_field_results.py`` prints them). Definitions: the module docstring of
:mod:`studies.field`.
"""

from __future__ import annotations

from typing import Any

from studies.field import FAULT_S

__all__ = ["must_hold", "summarise"]


def summarise(res: dict[str, Any]) -> dict[str, Any]:
    """The figures the issue's Must-hold list speaks of, from :func:`field_results`."""
    fl = res["flights"]
    inj = [r for f in fl.values() for r in f["injection"]["rows"]]
    imu2 = {k: [r for r in f["injection_local"]["rows"] if r["imu"] == "imu2"]
            for k, f in fl.items()}
    at1 = [r for f in fl.values() for r in f["holdout"]["rows"] if r["target_per_hour"] == 1.0]
    tuned = {k: f["from_start"][1] for k, f in fl.items()}
    return {
        "from_start_excluded": {k: r["excluded"] for k, r in tuned.items()},
        "from_start_events": {k: r["events"] for k, r in tuned.items()},
        "injected_runs": len(inj),
        "injected_missed_at_or_above_detectable": sum(
            r["at_or_above_detectable"] and not r["detected"] for r in inj),
        "injected_with_wrong_exclusion": sum(bool(r["wrong_exclusions"]) for r in inj),
        "injected_first_exclusion_healthy": sum(r["first_exclusion_healthy"] for r in inj),
        "imu2_first_exclusion_names_imu1": {
            k: [sum(r["first_exclusion_other_imu"] for r in v), len(v)]
            for k, v in imu2.items()},
        "imu2_further_healthy_exclusion": {
            k: [sum(len(r["wrong_exclusions_after_onset"]) > int(r["first_exclusion_healthy"])
                    for r in v), len(v)] for k, v in imu2.items()},
        "step10_delay_max_s": max((r["delay_s"] for r in inj
                                   if r["fault"] == "step 10 deg/s" and r["detected"]),
                                  default=None),
        "holdout_alarms_at_1_per_hour": sum(r["observed"] for r in at1),
    }


def _holdout_ok(row: dict[str, Any]) -> bool:
    """Within 3× of the target: the count at most 3× the expected one, and the rate not
    shown below a third of the target (the interval's upper end reaches target/3)."""
    return (row["observed"] <= 3.0 * row["expected"]
            and row["ci95_per_hour"][1] >= row["target_per_hour"] / 3.0)


def must_hold(res: dict[str, Any]) -> list[tuple[str, bool, str]]:
    """Issue 17's Must-hold list on :func:`field_results`: (claim, holds, what was seen).

    The injection claims hold for both sets of runs (monitor from the first sample, and
    started before the onset). The simulated guarantees (the monitor's Monte Carlo tests)
    are checked by those tests, not here.
    """
    fl = res["flights"]
    starts = [(k, r) for k, f in fl.items() for r in f["from_start"]]
    inj = [(k, r) for k, f in fl.items() for key in ("injection", "injection_local")
           for r in f.get(key, {"rows": []})["rows"]]
    out: list[tuple[str, bool, str]] = []

    bad = [f"{k} ({r['thresholds']}): {r['excluded']}" for k, r in starts if r["excluded"]]
    out.append(("from the start of 41 and 83: no healthy sensor excluded", not bad,
                "; ".join(bad) or "none excluded"))
    claims = sum(r["isolations_claimed"] for _, r in starts) + sum(
        r["isolations_claimed"] for _, r in inj)
    out.append(("two-IMU set: no isolation claimed (from the start and with injected "
                "faults)", claims == 0, f"{claims} isolation events"))
    wrong = [r for _, r in inj if r["wrong_exclusions"]]
    out.append(("injected faults: no healthy sensor excluded", not wrong,
                f"{len(wrong)} of {len(inj)} runs excluded a healthy sensor"))
    due = [r for _, r in inj if r["at_or_above_detectable"]]
    missed = [r for r in due if not r["detected"]]
    stated = ", ".join(f"{k}: {f['injection']['detectable_dps']:.3g} deg/s"
                       for k, f in fl.items())
    out.append((f"injected faults at or above the detectable size: detected within "
                f"{FAULT_S:g} s", bool(due) and not missed,
                f"{len(missed)} missed of {len(due)}" if due else
                f"no injected fault reaches the detectable size rimu tune states ({stated}): "
                f"nothing shown"))
    s10 = [r for _, r in inj if r["fault"] == "step 10 deg/s"]
    late = [r for r in s10 if not r["detected"] or r["delay_s"] > 1.0]
    out.append(("10 deg/s step on any axis of either IMU: detected within 1 s",
                bool(s10) and not late, f"{len(late)} of {len(s10)} late or missed"))
    det = [r for _, r in inj if r["detected"]]
    unv = [r for r in det if r["unverified_from_first_alarm"] is not True]
    na = all(r["unverified_from_first_alarm"] is None for r in det)
    out.append(("the faulted direction is unverified from the first alarm on",
                bool(det) and not unv,
                "the answer has no unverified axes" if na and det
                else f"{len(unv)} of {len(det)} detected runs not marked ("
                f"{sum(bool(r.get('at_or_above_detectable')) for r in unv)} of them at or "
                "above the detectable size; below it a detection clears when its evidence "
                "falls back under the clearing level)"))
    env = [(k, r) for k, r in starts if r["thresholds"].startswith("rimu tune")]
    over = [f"{k}: {r['envelope_fraction_of_flying']:.1%}" for k, r in env
            if not r["envelope_fraction_of_flying"] <= 0.10]
    noreason = [k for k, r in env if r["envelope_s_in_flight"] > 0 and not r["envelope_reasons"]]
    out.append(("out-of-envelope periods: at most 10 % of flying time, each with a reason",
                not over and not noreason,
                ", ".join(f"{k}: {r['envelope_fraction_of_flying']:.1%}" for k, r in env)
                + (f"; no reason on {noreason}" if noreason else "")))
    rows = [(k, r) for k, f in fl.items() for r in f["holdout"]["rows"]] + [
        ("4x mpu9250", r) for r in res["static_4x_mpu9250"]["rows"]]
    res_rows = [(k, r) for k, r in rows if r["resolved"]]
    off = [f"{k} {r['target_per_hour']:g}/h: {r['observed']} vs {r['expected']:.2f}"
           for k, r in res_rows if not _holdout_ok(r)]
    refused = sorted({f"{x['target_per_hour']:g}/h" for f in [*fl.values()]
                      for x in f["holdout"].get("refused", [])}
                     | {f"{x['target_per_hour']:g}/h"
                        for x in res["static_4x_mpu9250"].get("refused", [])})
    out.append(("held out, outside the envelope: false alarms within 3x of the target "
                "where the length resolves it", bool(res_rows) and not off,
                f"{len(off)} of {len(res_rows)} resolved rows off"
                + (": " + "; ".join(off) if off else "")
                + (f" (refused by rimu tune as alarms that would merge: "
                   f"{', '.join(refused)})" if refused else "")))
    n1 = sum(r["observed"] for k, r in rows if k in fl and r["target_per_hour"] == 1.0)
    out.append(("held out at 1/h: at most one alarm over all real flights together",
                n1 <= 1, f"{n1} alarms"))
    st = res["static_4x_mpu9250"]
    srows = [r for r in st["rows"] if r["resolved"]]
    busy = [f"{r['target_per_hour']:g}/h: {r['time_in_alarm']:.2e} vs "
            f"{r['time_in_alarm_implied']:.2e}" for r in srows
            if not r["time_in_alarm"] <= 3.0 * r["time_in_alarm_implied"]]
    excl = sorted({s for r in st["rows"] + [st["whole_record_1_per_hour"]]
                   for s in r["excluded"]})
    out.append(("4x MPU9250: time in alarm at most 3x what the target implies, no exclusion",
                bool(srows) and not busy and not excl,
                ("; ".join(busy) or "time in alarm within 3x")
                + (f"; excluded {excl}" if excl else "; none excluded")))
    return out
