"""The monitor on measured data: writes ``docs/field-results.md``, ``studies/field-results.json``
and ``docs/img/field_*.png``.

Run from the repository root (the data folder is read, never copied)::

    PYTHONPATH=. python studies/make_field_results.py [--data ../shared/data] [--baseline]

Everything is computed by :func:`studies.field.field_results` (the library calls behind
``rimu ingest``, ``rimu calibrate --in-flight``, ``rimu tune`` and ``rimu monitor-file``);
this script only writes tables and plots. ``--baseline`` stores the run as the "before"
figures as well; without it the baseline already in ``studies/field-results.json`` is kept
and the run becomes the "now" column.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fdi.fileio import to_jsonable  # noqa: E402
from studies.field import FAULT_S, FIELD_SCHEMA, field_results  # noqa: E402
from studies.field_claims import must_hold  # noqa: E402

JSON_PATH = ROOT / "studies" / "field-results.json"
MD_PATH = ROOT / "docs" / "field-results.md"
IMG = ROOT / "docs" / "img"


def data_dir(arg: str | None = None) -> Path:
    """The shared data folder: ``--data``, ``RIMU_SHARED_DATA``, or ``../shared/data``."""
    if arg:
        return Path(arg)
    env = os.environ.get("RIMU_SHARED_DATA")
    return Path(env) if env else ROOT / ".." / "shared" / "data"


def _public(res: Any) -> Any:
    if isinstance(res, dict):
        return {k: _public(v) for k, v in res.items() if not k.startswith("_")}
    if isinstance(res, list):
        return [_public(v) for v in res]
    return res


def _commit() -> str:
    try:
        return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


# -- plots ------------------------------------------------------------------------------
def _plots(res: dict[str, Any]) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    IMG.mkdir(parents=True, exist_ok=True)
    names = []
    fig, axs = plt.subplots(2, 1, figsize=(8, 5.5))
    for ax, (fl, s) in zip(axs, sorted(res["_series"].items()), strict=True):
        t, r, env = np.asarray(s["t"]), np.asarray(s["ratio"]), np.asarray(s["envelope"])
        gap = np.flatnonzero(np.diff(t) > 0.5) + 1            # no line across a gap
        t, r = np.insert(t, gap, np.nan), np.insert(r, gap, np.nan)
        env = np.insert(env, gap, 0)
        ax.semilogy(t, np.where(r > 0, r, np.nan), lw=0.6, color="C0",
                    label="largest statistic / threshold")
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        out = env != 0
        if out.any():
            ax.fill_between(t, 1e-3, 1e5, where=out, color="C3", alpha=0.2, step="mid",
                            label="out of envelope")
        for k, te in enumerate(s["episodes"]):
            ax.axvline(te, color="C1", lw=0.8, label="alarm" if k == 0 else None)
        ax.set_ylim(1e-2, 1e4)
        ax.set_ylabel("ratio")
        ax.set_title(f"flight {fl} from the start, thresholds of rimu tune at 1/h", fontsize=9)
        ax.legend(fontsize=7, loc="upper left")
    axs[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(IMG / "field_statistic.png", dpi=80)
    plt.close(fig)
    names.append("field_statistic.png")

    fig, axs = plt.subplots(1, 2, figsize=(8, 3.2), sharey=True)
    for ax, (fl, f) in zip(axs, sorted(res["flights"].items()), strict=True):
        rows = f["injection"]["rows"]
        for k, lab in enumerate(sorted({r["fault"] for r in rows})):
            rr = [r for r in rows if r["fault"] == lab]
            x = np.array([r["reaches_dps"] for r in rr], float)
            x = x * np.exp(np.linspace(-0.08, 0.08, x.size))          # spread the points
            y = np.array([r["delay_s"] if r["detected"] else FAULT_S * 1.3 for r in rr])
            ax.semilogx(x, y, "o", ms=3, alpha=0.6, color=f"C{k}", label=lab)
        ax.axvline(f["injection"]["detectable_dps"], color="k", ls="--", lw=0.8,
                   label="detectable (rimu tune)")
        ax.axhline(FAULT_S * 1.3, color="grey", lw=0.5)
        ax.set_title(f"flight {fl}: detection delay (top line: missed)", fontsize=9)
        ax.set_xlabel("fault size reached (deg/s)")
        ax.set_xticks([1, 2, 5, 10], ["1", "2", "5", "10"])
        ax.minorticks_off()
    axs[0].set_ylabel("delay (s)")
    axs[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(IMG / "field_delay.png", dpi=80)
    plt.close(fig)
    names.append("field_delay.png")

    fig, ax = plt.subplots(figsize=(6, 4))
    sets = [(f"flight {k}", f["holdout"]["rows"]) for k, f in sorted(res["flights"].items())]
    sets.append(("4x MPU9250", res["static_4x_mpu9250"]["rows"]))
    for k, (lab, rows) in enumerate(sets):
        for j, r in enumerate(rows):
            x = r["target_per_hour"] * (1.0 + 0.08 * (2 * k + j // len(res["targets_per_hour"])
                                                      - 2.5))
            lo, hi = r["ci95_per_hour"]
            y = max(r["per_hour"], 0.3)
            ax.errorbar([x], [y], yerr=[[y - max(lo, 0.3)], [hi - y]], fmt="o" if
                        r["resolved"] else "x", color=f"C{k}", ms=4, lw=0.8,
                        label=lab if j == 0 else None)
    tg = np.array(res["targets_per_hour"], float)
    ax.loglog(tg, tg, "k-", lw=0.8, label="target")
    ax.loglog(tg, 3 * tg, "k--", lw=0.6, label="3x target")
    ax.set_xlabel("target (alarms per hour)")
    ax.set_ylabel("held-out alarms per hour (0 drawn at 0.3)")
    ax.set_title("held out, outside the envelope (x: length does not resolve)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(IMG / "field_holdout.png", dpi=80)
    plt.close(fig)
    names.append("field_holdout.png")
    return names


# -- tables -----------------------------------------------------------------------------
def _f(x: Any, fmt: str = ".3g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(x, fmt)


def _holds_table(now: dict, before: dict | None) -> list[str]:
    mh_now = must_hold(now)
    if not before or before == now:
        col = "baseline (before issue 17)" if before else "holds"
        out = [f"| must hold (issue 17) | {col} |", "| --- | --- |"]
        return out + [f"| {c} | {'yes' if h else '**no**'}: {d} |" for c, h, d in mh_now]
    mh_before = {c: (h, d) for c, h, d in must_hold(before)}
    out = ["| must hold (issue 17) | before | now |", "| --- | --- | --- |"]
    for claim, h, d in mh_now:
        b = mh_before.get(claim)
        bt = f"{'yes' if b[0] else '**no**'}: {b[1]}" if b else "–"
        out.append(f"| {claim} | {bt} | {'yes' if h else '**no**'}: {d} |")
    return out


def _start_table(res: dict) -> list[str]:
    out = ["| flight | thresholds | data (s) | events | episodes (outside envelope) | "
           "excluded | isolations claimed | disagree | time in alarm | protection level "
           "median (deg/s) | envelope / flying |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for k, f in sorted(res["flights"].items()):
        for r in f["from_start"]:
            out.append(
                f"| {k} | {r['thresholds']} | {r['data_s']:.1f} | {r['events']} | "
                f"{r['episodes']} ({r['episodes_outside_envelope']}) | "
                f"{r['excluded'] or '–'} | {r['isolations_claimed']} | {r['disagree_events']} | "
                f"{r['time_in_alarm']:.2%} | {_f(r['protection_level_median_dps'], '.4g')} | "
                f"{r['envelope_s_in_flight']:.1f} s / {r['flying_s']:.1f} s "
                f"({r['envelope_fraction_of_flying']:.1%}: "
                f"{', '.join(r['envelope_reasons']) or 'none'}) |")
    return out


def _holdout_table(rows: list[dict]) -> list[str]:
    out = ["| direction | target (/h) | exposure (h) | expected | observed | 95 % interval "
           "(/h) | ratio | resolved | in envelope | excluded | time in alarm (implied) |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lo, hi = r["ci95_per_hour"]
        out.append(
            f"| {r['direction']} | {r['target_per_hour']:g} | {r['hours']:.4f} | "
            f"{r['expected']:.3g} | {r['observed']} | {lo:.3g} – {hi:.3g} | "
            f"{_f(r['ratio_to_target'])} | {'yes' if r['resolved'] else 'no'} | "
            f"{r['episodes_in_envelope']} | {r['excluded'] or '–'} | "
            f"{r['time_in_alarm']:.2e} ({r['time_in_alarm_implied']:.1e}) |")
    return out


def _injection_table(res: dict, key: str = "injection") -> list[str]:
    out = ["| flight | fault | runs | detected | missed (≥ detectable) | delay median / max "
           "(s) | false alarm in the window | runs with a wrong exclusion | first exclusion "
           "healthy | isolations claimed | disagree | unverified from first alarm |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for k, f in sorted(res["flights"].items()):
        rows = f[key]["rows"]
        for lab in sorted({r["fault"] for r in rows}, key=lambda s: (s[0], float(
                s.split()[1]))):
            rr = [r for r in rows if r["fault"] == lab]
            d = [r["delay_s"] for r in rr if r["detected"]]
            unv = [r["unverified_from_first_alarm"] for r in rr if r["detected"]]
            out.append(
                f"| {k} | {lab} | {len(rr)} | {len(d)} | "
                f"{sum(r['at_or_above_detectable'] and not r['detected'] for r in rr)} | "
                f"{_f(float(np.median(d)) if d else None, '.2f')} / "
                f"{_f(max(d) if d else None, '.2f')} | "
                f"{sum(r['false_alarm_in_window'] for r in rr)} | "
                f"{sum(bool(r['wrong_exclusions']) for r in rr)} | "
                f"{sum(r['first_exclusion_healthy'] for r in rr)} | "
                f"{sum(r['isolations_claimed'] > 0 for r in rr)} | "
                f"{sum(r['disagree'] for r in rr)} | "
                f"{'n/a' if all(u is None for u in unv) else sum(bool(u) for u in unv)} |")
    return out


def _markdown(doc: dict, images: list[str]) -> str:
    now, before = doc["current"], doc.get("baseline")
    runs = ([("before", before), ("now", now)] if before and before != now
            else [("baseline (before issue 17)" if before else "now", now)])
    L = ["# The monitor on measured data (issue 17)", "",
         "Written by `studies/make_field_results.py` from `studies.field.field_results` "
         f"(commit {now['commit']}, {now['elapsed_s']:.0f} s); the numbers are in "
         "`studies/field-results.json`, the slow test `tests/thresholds/test_field_results.py` "
         "recomputes them and checks the list below. *Before* (the baseline) is the run on "
         f"the code before issue 17 (commit {before['commit'] if before else '–'}); *now* is "
         "this run.", "",
         "Recordings: two ArduCopter flights with two IMUs on one board (41: heavy "
         "vibration, crash; 83: clean, cut at the end), read as `rimu ingest --salvage` reads "
         "them; four MPU9250 IMUs at rest for 16 min. The flights are calibrated in flight "
         "(`rimu calibrate --in-flight`), the bench set by `rimu calibrate --static` (its "
         "residual's tail and drift models and the range its samples covered); the monitor "
         "runs through `rimu monitor-file`'s chain; thresholds come from `rimu tune`'s "
         "library call, whose simulated correction flights stay inside each calibration's "
         "validated rate range (its smallest axis; at rest for the bench set).", "",
         "## Must hold", ""]
    L += _holds_table(now, before)
    L += ["", "Definitions (module docstring of `studies/field.py`): an *alarm episode* "
          "starts at a `detected` or `health` event (or an `isolated`/`disagree` event no "
          "detection opened); *time in alarm* is the share of samples with a window statistic "
          "above its threshold, and what the target implies is the thresholds' per-sample "
          "budget Σα; a target is *resolved* when the exposure T gives R·T ≥ −ln 0.05 / 3 "
          "≈ 1 expected alarm (zero alarms would then show the rate is below 3× the target "
          "at 95 %); intervals are exact Poisson (Garwood) 95 % intervals; *flying time* "
          "runs from the first to the last sample turning faster than 0.1 rad/s.", "",
          "Out-of-envelope periods: " + "; ".join(
              f"flight {k}: {f['from_start'][-1]['envelope_source']}"
              for k, f in sorted(now["flights"].items())) + ".", "",
          "## From the start of the log, as a user runs it", "",
          "Calibrated on the whole flight, monitored from its first sample, with the "
          "default thresholds of `rimu monitor-file` and with `rimu tune` at 1 per hour.", ""]
    for lab, r in runs:
        if r:
            L += [f"**{lab}**", "", *_start_table(r), ""]
    L += ["![statistic over time](img/field_statistic.png)", "",
          "## Held-out false alarms", "",
          "Each recording is cut in the middle; calibrated and tuned on one half, counted on "
          "the other outside the out-of-envelope periods, both ways round.", ""]
    for k, f in sorted(now["flights"].items()):
        L += [f"**flight {k}** ({runs[-1][0]}; cut at {f['holdout']['split_at_s']:.1f} s)", ""]
        L += [*_holdout_table(f["holdout"]["rows"]), *_refused(f["holdout"]), ""]
    st = now["static_4x_mpu9250"]
    L += [f"**4× MPU9250 at rest** ({runs[-1][0]}; {st['duration_s']:.0f} s at "
          f"{st['sample_rate_hz']:.1f} Hz, isolation on)", ""]
    L += [*_holdout_table(st["rows"]), *_refused(st), ""]
    w = st["whole_record_1_per_hour"]
    L += [f"Whole record, calibrated on itself, 1/h: {w['observed']} episodes, excluded "
          f"{w['excluded'] or 'none'}, time in alarm {w['time_in_alarm']:.2e} (implied "
          f"{w['time_in_alarm_implied']:.1e}).", ""]
    if before:
        L += ["Before, alarms at each target (observed / expected, both halves):", ""]
        L += ["| recording | " + " | ".join(f"{t:g}/h" for t in before["targets_per_hour"])
              + " |", "|---" * (1 + len(before["targets_per_hour"])) + "|"]
        sets = [(f"flight {k}", f["holdout"]["rows"]) for k, f in
                sorted(before["flights"].items())]
        sets.append(("4x MPU9250", before["static_4x_mpu9250"]["rows"]))
        for lab, rows in sets:
            cells = []
            for t in before["targets_per_hour"]:
                rr = [r for r in rows if r["target_per_hour"] == t]
                cells.append(f"{sum(r['observed'] for r in rr)} / "
                             f"{sum(r['expected'] for r in rr):.2g}")
            L.append(f"| {lab} | " + " | ".join(cells) + " |")
        L.append("")
    L += ["![held-out rate against target](img/field_holdout.png)", "",
          "## Injected faults", "",
          f"Steps of 2, 5 and 10 °/s and a ramp of 0.5 °/s per s, {FAULT_S:g} s long, "
          "added to one sensor's raw samples (`replay.scenario.apply_faults`, sizes through "
          "the calibration's scale factors) at three onsets in calm stretches of each flight "
          "(from 10 s before to 10 s after the onset in flight, inside the envelope, no "
          "gap, least specific-force variation; chosen from the data, not from the "
          "monitor), every sensor of both IMUs; each run monitored from the first sample "
          "(and, apart, from 10 s before the onset) with the thresholds of `rimu tune` at "
          "1/h. A fault counts as "
          f"detected by the first alarm within {FAULT_S:g} s of its onset that the same "
          "stretch without the fault does not raise (same sample, type and sensor: a false "
          "alarm, counted in its own column); *at or above detectable* "
          "compares the size the fault reaches with the smallest detectable size "
          "`rimu tune` states for the flight (any window scale).", ""]
    for k, f in sorted(now["flights"].items()):
        inj = f["injection"]
        L.append(f"- flight {k}: onsets {', '.join(f'{x:.1f}' for x in inj['onsets_s'])} s; "
                 f"detectable {inj['detectable_dps']:.2f} °/s (smallest over the scales)")
    L.append("")
    for lab, r in runs:
        if r:
            L += [f"**{lab}, monitor from the first sample of the log** (the Must-hold runs)",
                  "", *_injection_table(r), ""]
            L += [f"**{lab}, monitor started {r['flights']['41']['injection_local']['start']}**"
                  " (the isolation logic without what happened earlier in the flight)", "",
                  *_injection_table(r, "injection_local"), ""]
            s = r["summary"]
            L += ["Started before the onset, IMU2 faults whose first exclusion named an IMU1 "
                  "sensor: " + ", ".join(
                      f"flight {k} {v[0]} of {v[1]}" for k, v in
                      sorted(s["imu2_first_exclusion_names_imu1"].items()))
                  + "; runs that excluded a further healthy sensor: " + ", ".join(
                      f"flight {k} {v[0]} of {v[1]}" for k, v in
                      sorted(s["imu2_further_healthy_exclusion"].items())) + ".", ""]
    L += ["![detection delay against size](img/field_delay.png)", "",
          "## Time taken", ""]
    for k, v in now["timing_s"].items():
        if isinstance(v, dict):
            L.append(f"- {k}: " + ", ".join(f"{a} {b:.1f} s" for a, b in v.items()))
        else:
            L.append(f"- {k}: {v:.1f} s")
    L.append("")
    cross = JSON_PATH.with_name("cross_flight.json")
    if cross.exists():                  # issue 27's cross-flight tables, their own generator
        from studies.cross_flight import markdown as cross_markdown

        L += ["## Calibrated on one flight, monitored on another (issue 27)", "",
              cross_markdown(json.loads(cross.read_text(encoding="utf-8"))), ""]
    return "\n".join(L)


def _refused(rec: dict[str, Any]) -> list[str]:
    """One line per target ``rimu tune`` refused for the recording (alarms would merge)."""
    return ["", *(f"Not counted: {x['target_per_hour']:g}/h, {x['reason']}."
                  for x in rec.get("refused", []))] if rec.get("refused") else []


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", help="the shared data folder (default ../shared/data)")
    p.add_argument("--baseline", action="store_true",
                   help="store this run as the baseline ('before') too")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--markdown-only", action="store_true",
                   help="rewrite field-results.md from field-results.json (no computation)")
    args = p.parse_args(argv)
    if args.markdown_only:
        doc = json.loads(JSON_PATH.read_text(encoding="utf-8"))
        MD_PATH.write_text(_markdown(doc, []), encoding="utf-8")
        print(f"wrote {MD_PATH}")
        return 0
    t0 = time.perf_counter()
    res = field_results(data_dir(args.data), progress=not args.no_progress)
    res["elapsed_s"] = time.perf_counter() - t0
    res["commit"] = _commit()
    images = [] if args.no_plots else _plots(res)
    now = to_jsonable(_public(res))
    doc: dict[str, Any] = {"schema": FIELD_SCHEMA}
    if JSON_PATH.exists() and not args.baseline:
        old = json.loads(JSON_PATH.read_text(encoding="utf-8"))
        if old.get("baseline"):
            doc["baseline"] = old["baseline"]
    if args.baseline:
        doc["baseline"] = now
    doc["current"] = now
    JSON_PATH.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    MD_PATH.write_text(_markdown(doc, images), encoding="utf-8")
    print(f"wrote {JSON_PATH}, {MD_PATH}" + (f", {len(images)} plots" if images else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
