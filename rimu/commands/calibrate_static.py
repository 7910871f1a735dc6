"""``rimu calibrate static DIR --out CAL``: calibrate IMUs at rest against one of them.

One of the procedures of :mod:`rimu.commands.calibrate`; see
:mod:`calibration.inflight.static`. The file is a ``rimu.calibration/1`` calibration that
``rimu diagnose`` and ``rimu monitor-file`` read.
"""

from __future__ import annotations

import argparse

__all__ = ["HELP", "configure", "run"]

HELP = ("IMUs at rest against one of them (a flight folder recorded at rest): biases, "
        "alignment from gravity, shared disturbances and relative drift")


def configure(p: argparse.ArgumentParser) -> None:
    """The options of ``rimu calibrate static``."""
    p.add_argument("static", metavar="DIR",
                   help="flight folder (rimu.flight/1) recorded at rest: biases, alignment "
                        "from gravity and the shared disturbances, relative drift and whose "
                        "drift it is")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="calibration file to write (rimu.calibration/1 JSON)")
    p.add_argument("--reference", metavar="IMU",
                   help="reference IMU group (default: the first)")


def run(args: argparse.Namespace) -> int:
    """Run ``rimu calibrate static``."""
    from calibration.inflight.static import calibrate_static, static_text
    from replay.flight_io import load_flight_dir
    from rimu.commands.calibrate_inflight import covered_range_text
    from rimu.outputs import atomic_file, input_path, output_file

    out = output_file(args.out, "--out")
    input_path(args.static, "DIR", kind="dir")
    from fdi.progress import current

    current().stage("reading the flight folder")
    flight = load_flight_dir(args.static)
    current().stage("calibrating at rest (biases, alignment, drift, tails)")
    cal = calibrate_static(flight, reference=getattr(args, "reference", None))
    from replay.time_base import with_time_base

    cal = with_time_base(cal, flight)       # gaps, duplicates, empty rows: in the file too
    with atomic_file(out) as tmp:
        cal.save(tmp)
    print(static_text(cal.extras.static))
    rng = covered_range_text(cal)
    if rng is not None:
        print(rng)
    print(f"wrote {out}")
    return 0
