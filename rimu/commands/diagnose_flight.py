"""``rimu diagnose DIR --cal CAL`` on a flight folder: what the parity residual holds.

``rimu diagnose`` hands flight folders (``manifest.json`` with schema ``rimu.flight/1``)
to :func:`run_flight`; see :mod:`calibration.inflight.diagnose` for the method.
"""

from __future__ import annotations

import json

from calibration.inflight.diagnose import diagnose_flight
from fdi.calfile import load_calibration
from replay.flight_io import load_flight_dir

__all__ = ["format_text", "run_flight"]


def format_text(doc: dict) -> str:
    """Readable report of a flight diagnosis."""
    lines = [f"diagnosis of {doc['source']} against {doc['reference']} "
             f"({doc['samples_used']} of {doc['samples']} samples; alpha {doc['alpha']:g}, "
             f"{doc['correction']}, {doc['candidates']} candidates)"]
    for s in doc["left_out"]:
        lines.append(f"  left out {s['t0_s']:.2f}-{s['t1_s']:.2f} s: {s['reason']}")
    if not doc["effects"]:
        lines.append("  no effect found")
    for e in doc["effects"]:
        est, sd = e["estimate"], e["estimate_sd"]
        if isinstance(est, list):
            val = "[" + ", ".join(f"{a:+.3g} ± {b:.2g}" for a, b in zip(est, sd, strict=True)) \
                + "]"
        else:
            val = f"{est:+.4g} ± {sd:.2g}"
        lines.append(f"  {e['name']:<18s} {e['imu']}: {val} {e['unit']} (p={e['p_value']:.2g})")
        if e.get("detail"):
            lines.append(f"      {e['detail']}")
    b, a = doc["error_before"], doc["error_after"]
    for c, x, y in zip(b["channels"], b["rms"], a["rms"], strict=True):
        lines.append(f"  residual {c}: rms {x:.4g} -> {y:.4g} {b['unit']}")
    for n in doc["not_testable"]:
        lines.append(f"  not testable: {n['name']} ({n['imu']}): {n['reason']}")
    lines.append("  unexplained: " + ("yes" if doc["unexplained"] else "no"))
    lines.extend(f"    {d}" for d in doc["unexplained_detail"])
    return "\n".join(lines)


def run_flight(path: str, cal_path: str, *, alpha: float = 0.01, as_json: bool = False,
               report_dir: str | None = None) -> int:
    """``rimu diagnose`` on a flight folder: print the report (or the JSON with ``as_json``);
    with ``report_dir`` also write ``report.md`` and ``diagnosis.json`` there."""
    from rimu.outputs import atomic_dir, input_path, output_dir

    input_path(cal_path, "--cal")
    out = output_dir(report_dir, "--report") if report_dir else None
    flight = load_flight_dir(path)
    cal = load_calibration(cal_path)
    doc = diagnose_flight(flight, cal, alpha=alpha)
    text = format_text(doc)
    js = json.dumps(doc, indent=1, allow_nan=False) + "\n"
    print(js if as_json else text, end="\n" if not as_json else "")
    if out is not None:
        with atomic_dir(out) as tmp:        # both files or neither
            (tmp / "report.md").write_text("```\n" + text + "\n```\n", encoding="utf-8")
            (tmp / "diagnosis.json").write_text(js, encoding="utf-8")
        if not as_json:
            print(f"wrote {out / 'report.md'} and {out / 'diagnosis.json'}")
    return 0
