"""``rimu calibrate --static DIR --out CAL``: calibrate IMUs at rest against one of them.

Reached through ``rimu calibrate`` (its ``--static`` option); see
:mod:`calibration.inflight.static`. The file is a ``rimu.calibration/1`` calibration that
``rimu diagnose`` and ``rimu monitor-file`` read.
"""

from __future__ import annotations

import argparse

__all__ = ["configure_options", "run"]


def configure_options(p: argparse.ArgumentParser) -> None:
    """The option ``rimu calibrate`` adds for ``--static`` (``--reference`` is shared with
    ``--in-flight``)."""
    p.add_argument("--static", metavar="DIR",
                   help="calibrate the IMUs of a flight folder recorded at rest against one "
                        "of them: biases, alignment from gravity and the shared disturbances, "
                        "relative drift and whose drift it is")


def run(args: argparse.Namespace) -> int:
    """Run ``rimu calibrate --static``."""
    from calibration.inflight.static import calibrate_static, static_text
    from replay.flight_io import load_flight_dir
    from rimu.commands.calibrate_inflight import covered_range_text
    from rimu.outputs import atomic_file, input_path, output_file

    out = output_file(args.out, "--out")
    input_path(args.static, "--static", kind="dir")
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
