"""``rimu diagnose DIR --cal CAL`` on a flight folder: what the parity residual holds.

``rimu diagnose`` hands flight folders (``manifest.json`` with schema ``rimu.flight/1``)
to :func:`run`; see :mod:`calibration.inflight.diagnose` for the method.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from calibration.inflight.diagnose import diagnose_flight
from fdi.calfile import load_calibration
from replay.flight_io import load_flight_dir

HELP = "trace the parity residual of a flight folder to its causes (effects, before/after)"

__all__ = ["HELP", "configure", "format_text", "run"]


def configure(p: argparse.ArgumentParser) -> None:
    """Options (the same names as the turntable ``rimu diagnose``)."""
    p.add_argument("path", metavar="DIR", help="flight folder (rimu.flight/1)")
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--json", metavar="FILE", help="write the diagnosis as JSON ('-': stdout)")
    p.add_argument("--report", metavar="FILE", help="write the readable report here")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="family-wise significance level (default 0.01)")


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


def run(args: argparse.Namespace) -> int:
    """Run the flight diagnosis; print the report, write JSON and report files."""
    flight = load_flight_dir(args.path)
    cal = load_calibration(args.cal)
    doc = diagnose_flight(flight, cal, alpha=getattr(args, "alpha", 0.01))
    text = format_text(doc)
    js = json.dumps(doc, indent=1, allow_nan=False) + "\n"
    if getattr(args, "json", None) == "-":
        print(js, end="")
    else:
        print(text)
        if getattr(args, "json", None):
            Path(args.json).write_text(js, encoding="utf-8")
            print(f"wrote {args.json}")
    if getattr(args, "report", None):
        Path(args.report).write_text(text + "\n", encoding="utf-8")
    return 0
