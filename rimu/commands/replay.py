"""``rimu replay LOG``: decode a CAN log, run the monitor, report events and frame accounting."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from fdi.calfile import Calibration, load_calibration
from fdi.errors import ConfigError

HELP = "replay a CAN log through the monitor; print events, a summary and frame accounting"


def add_monitor_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``rimu replay`` and ``rimu monitor``."""
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--dbc", metavar="FILE",
                   help="DBC file (default: the map's, else rimu's shipped rimu_imu.dbc)")
    p.add_argument("--map", metavar="FILE", dest="channel_map",
                   help="channel map TOML (rimu.channel_map/1): which message/signal is "
                        "sensor i (default: the shipped DBC's RIMU_GYRO_ii messages)")
    p.add_argument("--thresholds", metavar="FILE",
                   help="a rimu.thresholds/1 or rimu.tuning/1 (rimu tune) file")
    p.add_argument("--false-alarms-per-hour", type=float, metavar="X",
                   help="compute thresholds for this false-alarm budget (default 1e-3 "
                        "per hour)")
    p.add_argument("--report", metavar="FILE", help="write the rimu.report/1 JSON here")
    p.add_argument("--max-events", type=int, default=50, help="events to print (default 50)")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="LOG", help="CAN log (.log candump, .asc, .blf, .csv, .trc, "
                                              "...: python-can picks the reader by suffix)")
    add_monitor_options(p)
    p.add_argument("--inject", metavar="FILE",
                   help="fault scenario TOML (rimu.scenario/1) injected into the decoded "
                        "samples")
    p.add_argument("--rrd", metavar="FILE", help="write a rerun recording (headless)")
    p.add_argument("--spawn", action="store_true", help="open the rerun viewer")
    p.add_argument("--realtime", action="store_true",
                   help="feed the monitor sample by sample at the recorded pace, printing "
                        "events as they happen")
    p.add_argument("--strict", action="store_true",
                   help="fail (exit 2) on a reader error, a garbage line or any corrupt frame")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def make_monitor(cal: Calibration, args: argparse.Namespace, kind: str) -> tuple[Any, dict]:
    """The monitor the options ask for, and how its thresholds were chosen."""
    from fdi.monitor import Monitor
    from thresholds.select import select

    choice = select(cal, kind=kind, thresholds_file=args.thresholds,
                    false_alarms_per_hour=args.false_alarms_per_hour)
    thr, how = choice.thresholds, choice.to_dict()
    return Monitor(cal, thr, kind=kind), how


def write_report(report: dict, path: str | None) -> None:
    """Write a report as JSON (no NaN)."""
    if path:
        Path(path).write_text(json.dumps(report, indent=1, allow_nan=False) + "\n",
                              encoding="utf-8")
        print(f"wrote {path}")


def run(args: argparse.Namespace) -> int:
    from replay.live import block_from_answers, format_event
    from replay.logio import read_log, resolve_map
    from replay.report import build_report, format_report

    cal = load_calibration(args.cal)
    _, cmap = resolve_map(cal, dbc=args.dbc, channel_map=args.channel_map)
    t0 = time.perf_counter()
    flight, frames = read_log(args.log, cal, dbc=args.dbc, channel_map=cmap,
                              strict=args.strict, progress=not args.no_progress,
                              kind=cmap.kind)
    t_read = time.perf_counter() - t0
    for e in frames["errors"]:
        if e.get("kind") != "garbage_line":
            print(f"rimu: warning: {args.log}: {e['where']}: {e['why']}")
    if args.inject:
        from replay.scenario import inject, load_scenario

        faults, seed = load_scenario(args.inject, cal, kind=cmap.kind)
        flight = inject(flight, faults, cal, seed=seed, source=str(args.inject))
    if flight.t.size == 0:
        raise ConfigError(f"{args.log}: no sample could be decoded ({frames['read']} frames "
                          f"read, rejected {frames['rejected']})")
    mon, how = make_monitor(cal, args, cmap.kind)
    t1 = time.perf_counter()
    if args.realtime:
        answers = []
        start = time.monotonic()
        for k in range(flight.t.size):
            delay = (flight.t[k] - flight.t[0]) - (time.monotonic() - start)
            if delay > 0:
                time.sleep(delay)
            ans = mon.step(float(flight.t[k]), flight.raw[k], flight.valid[k])
            for e in ans.events:
                print(format_event(e, flight.sensor_names), flush=True)
            answers.append(ans)
        result = block_from_answers(answers, flight.n, len(answers[0].statistics))
    else:
        result = mon.run(flight.t, flight.raw, flight.valid)
    t_mon = time.perf_counter() - t1
    extra = {"thresholds": how, "timing_s": {"read_decode": t_read, "monitor": t_mon}}
    if args.inject:
        extra["injected"] = str(args.inject)
    report = build_report(result, flight, cal, frames=frames, extra=extra)
    print(format_report(report, max_events=args.max_events))
    if args.rrd or args.spawn:
        from replay.rerun_log import record

        tim = record(result, flight, cal, path=args.rrd, spawn=args.spawn,
                     thresholds=mon.thresholds)
        report["timing_s"]["rerun"] = tim["log_s"] + tim["flush_s"]
        if args.rrd:
            print(f"wrote {args.rrd} ({tim['log_s'] + tim['flush_s']:.2f} s)")
    write_report(report, args.report)
    return 0
