"""``rimu ingest LOG``: read a flight log or bench recording into a ``rimu.flight/1`` folder."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = ("read a flight log or bench recording (ArduPilot .BIN, PX4 .ulg, .mat, CSV, R .rda) "
        "into a flight folder")

FORMATS = ("auto", "ardupilot", "px4", "mat", "csv", "rda")
"""``--format`` (:data:`replay.ingest.readers.FORMATS`; kept here so that ``--help`` does
not import the readers; a test checks they agree)."""
REPORT_FILE = "ingest_report.json"
"""The accounting file written beside the flight (``rimu.ingest-report/1``)."""


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="the log; several files recorded together (one IMU each, e.g. "
                        "imu1.mat imu2.mat) are joined as imu1, imu2, ...")
    p.add_argument("--format", default="auto", choices=FORMATS,
                   help="log format (default auto: from the content, else the suffix)")
    p.add_argument("--map", metavar="MAP.toml", dest="map_path",
                   help="rimu.ingest-map/1 TOML: columns, units, time base and IMU of each "
                        "column (CSV and R data; optional for .mat)")
    p.add_argument("--out", required=True, metavar="DIR", help="flight folder to write")
    p.add_argument("--px4-topic", default="auto",
                   choices=("auto", "sensor_gyro", "vehicle_imu"),
                   help="PX4 logs: rates from sensor_gyro (+ sensor_accel) or from "
                        "vehicle_imu delta angles (default auto: sensor_gyro if logged)")
    p.add_argument("--reference", metavar="IMU",
                   help="IMU whose time stamps are the time base (default: most samples)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress on stderr (shown when the work takes over 3 s)")
    p.add_argument("--salvage", action="store_true",
                   help="on a truncated or corrupt log, write the samples before the damage "
                        "(default: refuse, exit 2)")


def run(args: argparse.Namespace) -> int:
    from fdi.fileio import to_jsonable
    from replay.envelope import describe_summary, uncalibrated_summary
    from replay.flight_io import save_flight_dir
    from replay.ingest import align_streams, read_any
    from replay.ingest.readers import merge_reads
    from rimu.outputs import atomic_dir, distinct_inputs, input_path, output_dir

    for log in args.logs:
        input_path(log, "LOG")
    distinct_inputs(args.logs, "LOG")
    if args.map_path:
        input_path(args.map_path, "--map")
    out = output_dir(args.out, "--out", inputs=(*args.logs, args.map_path),
                     schema="rimu.flight/1")
    from fdi.progress import current

    prog = current()                    # stages shown once the work has taken 3 s
    reads = []
    for log in args.logs:
        prog.stage(f"reading {Path(log).name}")
        reads.append(read_any(log, args.format, map_path=args.map_path,
                              salvage=args.salvage, px4_topic=args.px4_topic))
    read = merge_reads(reads)
    prog.stage("aligning the streams on one time base")
    flight, report = align_streams(read, reference=args.reference, salvage=args.salvage)
    envelope = uncalibrated_summary(flight)
    if envelope is not None:
        report["envelope"] = envelope
    prog.stage(f"writing {out}")
    with atomic_dir(out) as tmp:        # the flight and its report: all or nothing
        save_flight_dir(flight, tmp)
        (tmp / REPORT_FILE).write_text(json.dumps(to_jsonable(report), indent=1) + "\n",
                                       encoding="utf-8")
    tb = report["time_base"]
    print(f"wrote {out}: {flight.t.shape[0]} samples of {len(report['imus'])} IMU(s) "
          f"({flight.n} gyro axes) at {tb['sample_rate_hz']:.4g} Hz, "
          f"{tb['t_end_s'] - tb['t_start_s']:.1f} s, {tb['n_gaps']} gap(s)")
    for rd in reads:
        for w in rd.meta.get("warnings", []):
            print(f"  warning: {rd.path}: {w}")
    for w in report["warnings"]:
        print(f"  warning: {read.path}: {w}")
    for imu in report["imus"]:
        dropped = sum(imu["dropped"].values())
        print(f"  {imu['name']} ({imu['source']}): {imu['samples_in']} in, {imu['kept']} kept, "
              f"{imu['resampled_on_base']} resampled, {dropped} dropped, "
              f"{imu['missing_on_base']} missing on the base")
    if flight.events:
        cats = {c: sum(e.category == c for e in flight.events)
                for c in ("crash", "estimator", "info")}
        print(f"  log events: {len(flight.events)} ({cats['crash']} crash, "
              f"{cats['estimator']} estimator, {cats['info']} info) in manifest.json 'events'")
        for e in flight.events:
            if e.category != "info":
                end = "end of log" if e.t_end_s == float("inf") else f"{e.t_end_s:.2f} s"
                print(f"    {e.t_s:.2f} s to {end}: {e.text} ({e.category})")
    if envelope is not None:
        print(f"  envelope (uncalibrated rates): {describe_summary(envelope)}")
    if read.damage is not None:
        d = read.damage
        if d.stretches:
            print(f"  salvaged: {len(d.stretches)} damaged stretch(es) skipped, reading "
                  f"resumed after each")
            for x in d.stretches:
                print("    " + damage_line(x))
        else:
            where = f" at byte offset {d.offset}" if d.offset is not None else ""
            print(f"  salvaged: {d.message}{where}; samples after it not read")
    return 0


def damage_line(x: dict) -> str:
    """One readable line of a damaged stretch (see :class:`replay.ingest.stream.Damage`)."""
    if "start" in x:
        where = f"bytes {x['start']}-{x['end']} ({x['bytes']} bytes)"
    elif x.get("last_line", x.get("line")) != x.get("line"):
        where = f"lines {x['line']}-{x['last_line']}"
    else:
        where = f"line {x.get('line')}"
    lost = x.get("lost", {})
    parts = []
    if lost.get("imu_samples"):
        parts.append(", ".join(f"{k} {'?' if v is None else v}"
                               for k, v in lost["imu_samples"].items()) + " IMU samples")
    if lost.get("lines"):
        parts.append(f"{lost['lines']} line(s)")
    return f"{where}: {x['what']}; lost " + ("; ".join(parts) if parts else "nothing")
