"""``rimu monitor --interface IFACE --channel CH``: run the monitor on a live CAN bus."""

from __future__ import annotations

import argparse
import logging

from fdi.errors import ConfigError, ReplayError
from rimu.argtypes import positive_float, positive_int
from rimu.commands.replay import (
    add_monitor_options,
    aux_record,
    check_monitor_paths,
    effects_extra,
    format_aux,
    make_monitor,
    warn_silent_aux,
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
    import numpy as np

    from replay.flight import Flight
    from replay.live import StreamDecoder, format_event, run_live
    from replay.logio import resolve_map
    from replay.report import RunningReport, format_report

    check_monitor_paths(args)
    from fdi.calfile import load_calibration

    cal = load_calibration(args.cal)
    db, cmap = resolve_map(cal, dbc=args.dbc, channel_map=args.channel_map)
    mon, how = make_monitor(cal, args, cmap.kind, cmap)
    kw = {}
    if args.bitrate:
        kw["bitrate"] = args.bitrate
    if args.interface == "virtual":
        kw.update(preserve_timestamps=True, ignore_config=True)
    try:
        bus = can.Bus(interface=args.interface, channel=args.channel, **kw)
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
        raise ReplayError(f"cannot open {args.interface} bus {args.channel}: {exc}") from None
    dec = StreamDecoder(db, cmap, cal.sample_rate_hz)
    names = mon.sensor_names
    acc = RunningReport(median_exact_max=10_000)
    print(f"monitoring {args.interface}:{args.channel}, {cmap.n} {cmap.kind} sensors "
          f"(Ctrl-C to stop)", flush=True)
    try:
        _, frames = run_live(bus, dec, mon, duration_s=args.duration,
                             max_frames=args.max_frames, idle_timeout_s=args.idle_timeout,
                             on_event=lambda e: print(format_event(e, names), flush=True),
                             window=args.window, summary=acc)
    finally:
        bus.shutdown()
    if acc.samples == 0:
        logging.getLogger("rimu").warning(f"no sample decoded: frames {frames}")
        if args.report:
            raise ConfigError("no sample decoded; no report written")
        return 0
    s = cal.kind(cmap.kind)
    header = Flight(t=np.zeros(0), raw=np.zeros((0, s.n)), valid=np.zeros((0, s.n), bool),
                    sample_rate_hz=cal.sample_rate_hz, sensor_names=names,
                    source=f"{args.interface}:{args.channel}", kind=cmap.kind)
    extra = {"thresholds": how, "live": True, "window": args.window,
             **effects_extra(mon, cal)}
    if cmap.auxiliary:
        extra["auxiliary"] = aux_record(cmap, dec.block)
        warn_silent_aux(extra["auxiliary"], f"{args.interface}:{args.channel}")
    report = acc.build(header, cal, frames=frames, extra=extra)
    print(format_report(report, max_events=0))
    if cmap.auxiliary:
        print(format_aux(extra["auxiliary"]))
    write_report(report, args.report)
    return 0
