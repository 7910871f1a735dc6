"""``rimu monitor --interface IFACE --channel CH``: run the monitor on a live CAN bus."""

from __future__ import annotations

import argparse
import logging

from fdi.errors import ConfigError, ReplayError
from rimu.argtypes import positive_float, positive_int
from rimu.commands.replay import (
    add_monitor_options,
    chain_options,
    check_monitor_paths,
    describe_chain,
    write_report,
)

DEFAULT_WINDOW = 6000
"""Answers the live monitor keeps (one minute at 100 Hz); memory stays constant."""

HELP = "monitor a live CAN bus (socketcan, virtual, ...); print events as they happen"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--interface", required=True,
                   help="python-can interface: socketcan, virtual, pcan, kvaser, ...")
    p.add_argument("--channel", required=True, help="bus channel: can0, vcan0, a name, ...")
    p.add_argument("--bitrate", type=positive_int(20_000_000),
                   help="bit rate, where the interface sets it")
    add_monitor_options(p)
    p.add_argument("--duration", type=positive_float(1e9), metavar="S",
                   help="stop after S seconds")
    p.add_argument("--max-frames", type=positive_int(), metavar="N", help="stop after N frames")
    p.add_argument("--idle-timeout", type=positive_float(1e9), metavar="S",
                   help="stop after S seconds without a frame")
    p.add_argument("--window", type=positive_int(10_000_000), default=DEFAULT_WINDOW,
                   metavar="N", help=f"answers kept in memory (default {DEFAULT_WINDOW}); "
                   "events and the report's summaries cover the whole run")


def run(args: argparse.Namespace) -> int:
    import can

    from replay.chain import chain_for_map, format_aux
    from replay.live import StreamDecoder, print_event, report_bus
    from replay.logio import resolve_map
    from replay.report import format_report

    check_monitor_paths(args)
    from fdi.calfile import load_calibration

    cal = load_calibration(args.cal)
    db, cmap = resolve_map(cal, dbc=args.dbc, channel_map=args.channel_map)
    chain = chain_for_map(cal, cmap, chain_options(args, median_exact_max=10_000))
    describe_chain(chain)
    kw = {}
    if args.bitrate:
        kw["bitrate"] = args.bitrate
    if args.interface == "virtual":
        kw.update(preserve_timestamps=True, ignore_config=True)
    try:
        bus = can.Bus(interface=args.interface, channel=args.channel, **kw)
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
        raise ReplayError(f"cannot open {args.interface} bus {args.channel}: {exc}") from None
    names = chain.sensor_names
    print(f"monitoring {args.interface}:{args.channel}, {cmap.n} {cmap.kind} sensors "
          f"(Ctrl-C to stop)", flush=True)
    try:
        report, frames = report_bus(
            chain, bus, StreamDecoder(db, cmap, cal.sample_rate_hz),
            source=f"{args.interface}:{args.channel}", window=args.window,
            on_event=lambda e: print_event(e, names),
            duration_s=args.duration, max_frames=args.max_frames,
            idle_timeout_s=args.idle_timeout)
    finally:
        bus.shutdown()
    if report is None:
        logging.getLogger("rimu").warning(f"no sample decoded: frames {frames}")
        if args.report:
            raise ConfigError("no sample decoded; no report written")
        return 0
    print(format_report(report, max_events=0))
    from replay.report import decoding_hint

    if hint := decoding_hint(report):
        logging.getLogger("rimu").warning(hint)
    if "auxiliary" in report:
        print(format_aux(report["auxiliary"]))
    write_report(report, args.report, chain)
    return 0
