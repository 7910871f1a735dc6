"""``rimu inspect LOG``: what a log holds (IMU streams, rates, durations, gaps, declared
events, damage) before anything is written (like pyulog's ``ulog_info``)."""

from __future__ import annotations

import argparse
import json

from rimu.commands.ingest import add_format_option

HELP = ("list a log's IMU streams, rates, durations, gaps, declared events and damage "
        "(writes nothing)")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="the log(s): ArduPilot .BIN, PX4 .ulg, .mat, CSV, R .rda")
    add_format_option(p)
    p.add_argument("--map", metavar="MAP.toml", dest="map_path",
                   help="rimu.ingest-map/1 TOML (CSV and R data; optional for .mat)")
    p.add_argument("--px4-topic", default="auto",
                   choices=("auto", "sensor_gyro", "vehicle_imu"),
                   help="PX4 logs: which topic's samples (default auto)")
    p.add_argument("--json", action="store_true", help="print the rimu.inventory/1 JSON")


def run(args: argparse.Namespace) -> int:
    from fdi.fileio import to_jsonable
    from fdi.progress import current
    from replay.ingest.inventory import format_inventory, inventory
    from rimu.outputs import input_path

    for log in args.logs:
        input_path(log, "LOG")
    if args.map_path:
        input_path(args.map_path, "--map")
    invs = []
    for log in args.logs:
        current().stage(f"reading {log}")
        invs.append(inventory(log, args.format, map_path=args.map_path,
                              px4_topic=args.px4_topic))
    if args.json:
        doc = invs[0] if len(invs) == 1 else {"schema": "rimu.inventory-list/1",
                                               "logs": invs}
        print(json.dumps(to_jsonable(doc), indent=1, allow_nan=False))
    else:
        print("\n\n".join(format_inventory(i) for i in invs))
    return 0
