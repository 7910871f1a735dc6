"""``rimu diagnose DIR --cal CAL`` on a flight folder: what the parity residual holds.

``rimu diagnose`` hands flight folders (``manifest.json`` with schema ``rimu.flight/1``)
to :func:`run_flight`; see :mod:`calibration.inflight.diagnose` for the method.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from calibration.inflight.diagnose import DRIFT_EFFECT, diagnose_flight
from fdi.calfile import load_calibration
from replay.flight_io import load_flight_dir

__all__ = ["format_text", "run_flight"]


def format_text(doc: dict) -> str:
    """Readable report of a flight diagnosis."""
    lines = [f"diagnosis of {doc['source']} against {doc['reference']} "
             f"({doc['samples_used']} of {doc['samples']} samples; alpha {doc['alpha']:g}, "
             f"{doc['correction']}, {doc['candidates']} candidates)"]
    lines.extend(f"  warning: {w}" for w in doc.get("warnings", []))
    for s in doc["left_out"]:
        lines.append(f"  left out {s['t0_s']:.2f}-{s['t1_s']:.2f} s: {s['reason']}"
                     + (f" ({s['detail']})" if s.get("detail") else ""))
    if doc.get("calibration_kind") == "in-flight" and not doc.get("warnings"):
        lines.append("  (the same samples the in-flight calibration used)")
    lines += [_timing_line(tm) for tm in doc.get("timing", [])]
    if doc.get("time_offset_sign"):
        lines.append(f"  sign: {doc['time_offset_sign']}")
    if not doc["effects"]:
        lines.append("  no effect found")
    for e in doc["effects"]:
        lines += _effect_lines(e)
    b, a = doc["error_before"], doc["error_after"]
    for c, x, y in zip(b["channels"], b["rms"], a["rms"], strict=True):
        lines.append(f"  residual {c}: rms {x:.4g} -> {y:.4g} {b['unit']}")
    for n in doc["not_testable"]:
        lines.append(f"  not testable: {n['name']} ({n['imu']}): {n['reason']}")
    a = doc.get("drift_attribution")
    if a and any(e["name"] in (DRIFT_EFFECT, "slow_bias_change") for e in doc["effects"]):
        lines += _drift_lines(a)
    lines.append("  unexplained: " + ("yes" if doc["unexplained"] else "no"))
    lines.extend(f"    {d}" for d in doc["unexplained_detail"])
    return "\n".join(lines)


def _timing_line(tm: dict) -> str:
    """One IMU's time offset: what the calibration applied and what is left."""
    head = (f"  time offset {tm['imu']}: calibration {tm['calibration_ms']:+.3f} ± "
            f"{tm['calibration_sd_ms']:.3f} ms applied; " if tm["calibration_ms"] is not None
            else f"  time offset {tm['imu']}: none calibrated; ")
    if tm["left"]:
        return (head + f"left {tm['left_ms']:+.3f} ± {tm['left_sd_ms']:.3f} ms "
                f"(p={tm['p_value']:.2g}), total {tm['total_ms']:+.3f} ms, "
                f"{tm['apart_in_combined_sd']:.1f} combined sd from the calibration")
    return (head + f"nothing left ({tm['left_ms']:+.3f} ± {tm['left_sd_ms']:.3f}"
            f" ms, p={tm['p_value']:.2g})")


def _effect_lines(e: dict) -> list[str]:
    """The lines of one effect found (a value, or a matrix of them)."""
    lines = []
    est, sd = e["estimate"], e["estimate_sd"]
    if isinstance(est, list):
        val = "[" + ", ".join(f"{a:+.3g} ± {b:.2g}" for a, b in zip(est, sd, strict=True)) \
            + "]"
    else:
        val = f"{est:+.4g} ± {sd:.2g}"
    if e.get("matrix"):
        m = e["matrix"]
        lines.append(f"  {e['name']:<18s} {e['imu']}: [{m['unit']}] (p={e['p_value']:.2g})")
        lines.append("      " + " " * 16 + "".join(f"{c:>22s}" for c in m["cols"]))
        for rn, vr, sr in zip(m["rows"], m["values"], m["sd"], strict=True):
            lines.append(f"      {rn:<16s}" + "".join(
                f"{f'{v:+.3g} ± {q:.2g}':>22s}" for v, q in zip(vr, sr, strict=True)))
    else:
        lines.append(f"  {e['name']:<18s} {e['imu']}: {val} {e['unit']} "
                     f"(p={e['p_value']:.2g})")
    if e.get("detail"):
        lines.append(f"      {e['detail']}")
    return lines


def _drift_lines(a: dict) -> list[str]:
    """Whose drift it is (``drift_attribution``)."""
    return [f"  drift: {a['statement']}",
            "    shared by every IMU relative to the reference: [" + ", ".join(
                f"{c:+.4f} ± {q:.4f}" for c, q in zip(a["common"], a["common_sd"], strict=True))
            + f"] deg/s (p={a['common_p']:.2g}); relative to the reference: " + "; ".join(
                f"{g} [" + ", ".join(f"{d:+.4f}" for d in v["drift"]) + "]"
                for g, v in a["own"].items()) + " deg/s"]


def _monitor_picture(flight: Any, cal: Any, png: Path, *, title: str) -> Path:
    """The monitor over ``flight`` as ``rimu monitor-file`` runs it by default (thresholds
    from the calibration, time offsets, effects, envelope), drawn by
    :func:`replay.plots.plot_run` into ``png``."""
    from replay.chain import ChainOptions, chain_for_flight
    from replay.chain import run_flight as monitor_flight
    from replay.plots import plot_run, scale_labels

    chain = chain_for_flight(flight, cal, ChainOptions())
    _, report = monitor_flight(chain, flight)
    acc = chain.report
    return plot_run(acc.trace, png, report=report, title=title,
                    scale_names=scale_labels(chain.thresholds, acc.trace.scales))


def run_flight(path: str, cal_path: str, *, alpha: float = 0.01, as_json: bool = False,
               report_dir: str | None = None) -> int:
    """``rimu diagnose`` on a flight folder: print the report (or the JSON with ``as_json``);
    with ``report_dir`` also write ``report.md`` and ``diagnosis.json`` there."""
    from rimu.outputs import atomic_dir, input_path, output_dir

    input_path(cal_path, "--cal")
    out = output_dir(report_dir, "--report") if report_dir else None
    from fdi.progress import current

    current().stage("reading the flight folder")
    flight = load_flight_dir(path)
    cal = load_calibration(cal_path)
    current().stage("diagnosing (parity residual, effects)")
    doc = {**diagnose_flight(flight, cal, alpha=alpha),
           "time_base": flight.time_base.to_dict()}
    text = format_text(doc)
    js = json.dumps(doc, indent=1, allow_nan=False) + "\n"
    print(js if as_json else text, end="\n" if not as_json else "")
    if out is not None:
        from calibration.inflight.report import write_flight_plots

        with atomic_dir(out) as tmp:        # the page, its plots and the JSON: all or none
            current().stage("plots")
            pngs = write_flight_plots(flight, cal, tmp)
            current().stage("the monitor over the flight, for its picture")
            pngs.append(_monitor_picture(
                flight, cal, tmp / "monitor.png",
                title=f"rimu monitor-file {path} (defaults): rates, statistic / threshold "
                      "per window, events"))
            (tmp / "report.md").write_text("```\n" + text + "\n```\n\n" + "".join(
                f"![{p.stem}]({p.name})\n" for p in pngs), encoding="utf-8")
            (tmp / "diagnosis.json").write_text(js, encoding="utf-8")
        if not as_json:
            print(f"wrote {out / 'report.md'}, {out / 'diagnosis.json'} and "
                  f"{', '.join(p.name for p in pngs)}")
    return 0
