"""``rimu replay LOG``: decode a CAN log, run the monitor, report events and frame accounting."""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
from pathlib import Path
from typing import Any

from fdi.errors import ConfigError
from rimu.argtypes import nonnegative_int, positive_float

HELP = "replay a CAN log through the monitor; print events, a summary and frame accounting"


def add_monitor_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``rimu replay`` and ``rimu monitor``."""
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--dbc", metavar="FILE",
                   help="DBC file (default: the map's, else rimu's shipped rimu_imu.dbc)")
    p.add_argument("--map", metavar="FILE", dest="channel_map",
                   help="channel map TOML (rimu.channel_map/1): which message/signal is "
                        "sensor i, and optional [[auxiliary]] temperature and accelerometer "
                        "channels for the effect terms (default: the shipped DBC's "
                        "RIMU_GYRO_ii messages, no auxiliary channel)")
    p.add_argument("--thresholds", metavar="FILE",
                   help="a rimu.thresholds or rimu.tuning (rimu tune) file, made for this "
                        "calibration and sample rate")
    p.add_argument("--false-alarms-per-hour", type=positive_float(1e9), metavar="X",
                   help="compute thresholds for this false-alarm budget (default 1e-3 "
                        "per hour)")
    p.add_argument("--report", metavar="FILE",
                   help="write the rimu.report/1 JSON here, and its picture beside it "
                        "(FILE with .png: rates, statistic / threshold per window, events)")
    p.add_argument("--max-events", type=nonnegative_int(), default=50,
                   help="events to print (default 50)")
    p.add_argument("--no-effects", action="store_true",
                   help="do not compensate the calibration's effect terms (default: those "
                        "read from the sensors' own outputs, rate sign and rate squared, are "
                        "compensated, and g-sensitivity and temperature terms when the "
                        "channel map has [[auxiliary]] specific-force or temperature "
                        "channels for the sensor)")
    p.add_argument("--no-time-offsets", action="store_true",
                   help="do not move each IMU by the time offset its in-flight calibration "
                        "records (default: moved onto the reference's timing, the answers "
                        "held back by the largest negative offset)")
    p.add_argument("--no-envelope", action="store_true",
                   help="do not mark samples out of the operating envelope (default: shocks, "
                        "saturation, tumbles and the log's declared crash events are marked; "
                        "the monitor excludes nothing there and restarts its windows after; "
                        "docs/envelope.md)")


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


def chain_options(args: argparse.Namespace, **more: Any) -> Any:
    """The monitoring chain's options (:class:`replay.chain.ChainOptions`) from the
    shared options."""
    from replay.chain import ChainOptions

    return ChainOptions(thresholds_file=args.thresholds, calibration_file=args.cal,
                        false_alarms_per_hour=args.false_alarms_per_hour,
                        effects=not args.no_effects,
                        time_offsets=not args.no_time_offsets,
                        envelope=not args.no_envelope, **more)


def describe_chain(chain: Any, flight: Any = None) -> None:
    """Print what the chain compensates and which IMUs (and auxiliary channels, of
    ``flight`` or the chain's map) it moves in time."""
    from replay.chain import moved_aux

    text = chain.compensation_summary()
    if text:
        print(text, flush=True)
    if chain.time_offsets_ms:
        moved = moved_aux(chain, flight)
        print("moved onto the reference's timing: " + ", ".join(
            f"{g} {ms:+.3f} ms" for g, ms in chain.time_offsets_ms.items())
            + (f" (with {len(moved)} auxiliary channel(s): {', '.join(moved)})"
               if moved else "")
            + (f"; answers held back up to {1e3 * chain.delay_s:.3f} ms plus one sample"
               if chain.delay_s > 0 else ""), flush=True)


def picture_path(report_path: str | os.PathLike) -> Path:
    """The PNG written beside a ``--report`` JSON: ``r.json`` → ``r.png``."""
    p = Path(report_path)
    q = p.with_suffix(".png")
    return q if q != p else p.with_name(p.name + ".png")


def write_report(report: dict, path: str | None, chain: Any = None) -> None:
    """Write a report as JSON (no NaN), atomically; with the ``chain`` that made it, also
    its picture (:func:`picture_path`, :func:`replay.plots.plot_run`)."""
    if path:
        from rimu.outputs import atomic_file, atomic_write_text

        atomic_write_text(path, json.dumps(report, indent=1, allow_nan=False) + "\n")
        print(f"wrote {path}")
        acc = getattr(chain, "report", None)
        if acc is not None:
            from replay.plots import plot_run, scale_labels

            png = picture_path(path)
            with atomic_file(png) as tmp:
                plot_run(acc.trace, tmp, report=report,
                         scale_names=scale_labels(chain.thresholds, acc.trace.scales))
            print(f"wrote {png} (rates with unverified spans, statistic / threshold per "
                  "window, envelope periods, events)")


def check_monitor_paths(args: argparse.Namespace) -> None:
    """Inputs and outputs of ``replay``/``monitor`` checked before any work."""
    from rimu.outputs import input_path, output_file

    input_path(args.cal, "--cal")
    for opt, val in (("--dbc", args.dbc), ("--map", args.channel_map),
                     ("--thresholds", args.thresholds)):
        if val:
            input_path(val, opt)
    if args.report:
        output_file(args.report, "--report")
        output_file(picture_path(args.report), "--report (its picture)")


def has_display() -> bool:
    """Whether a viewer window can open here (a desktop session, or not Linux)."""
    import os
    import sys

    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def run(args: argparse.Namespace) -> int:
    from replay.chain import chain_for_map, format_aux, report_log
    from replay.live import Pacer, print_event
    from replay.logio import LogStream, resolve_map
    from replay.report import format_report
    from rimu.outputs import atomic_file, input_path, output_file

    input_path(args.log, "LOG")
    check_monitor_paths(args)
    if args.inject:
        input_path(args.inject, "--inject")
    if args.rrd:
        output_file(args.rrd, "--rrd")
    spawn = args.spawn
    if spawn and not has_display():
        if not args.rrd:
            raise ConfigError("--spawn: no display to open the rerun viewer on (DISPLAY is "
                              "not set); write the recording with --rrd FILE and open it with "
                              "'rerun FILE' where there is one, or 'rerun FILE --web-viewer' "
                              "and a browser")
        logging.getLogger("rimu").warning("--spawn: no display; writing the recording to "
                                          f"{args.rrd} only")
        spawn = False
    from fdi.calfile import load_calibration  # here: --help imports nothing numerical

    cal = load_calibration(args.cal)
    db, cmap = resolve_map(cal, dbc=args.dbc, channel_map=args.channel_map)
    stream = LogStream(args.log, cal, db, cmap, strict=args.strict,
                       progress=not args.no_progress,
                       check_sensor_set=args.channel_map is None, cal_source=args.cal)
    header, injector = stream.header, None
    if args.inject:
        from replay.stream import scenario_injector

        injector, header = scenario_injector(args.inject, cal, header, kind=cmap.kind,
                                             n=cmap.n)
    chain = chain_for_map(cal, cmap, chain_options(args), injector=injector)
    describe_chain(chain)
    names = header.sensor_names
    pacer = Pacer(lambda e: print_event(e, names)) if args.realtime \
        else None
    with contextlib.ExitStack() as stack:
        if args.rrd or spawn:
            rrd = stack.enter_context(atomic_file(args.rrd)) if args.rrd else None
            recorder = chain.record(rrd, spawn=spawn, has_truth=header.omega_true is not None)
            stack.callback(recorder.abort)      # on an error: stop writing the temp file
        report = report_log(chain, stream, header, pacer=pacer,
                            extra={"injected": str(args.inject)} if args.inject else None)
        print(format_report(report, max_events=args.max_events))
        from replay.report import decoding_hint

        if hint := decoding_hint(report):
            logging.getLogger("rimu").warning(hint)
        if "auxiliary" in report:
            print(format_aux(report["auxiliary"]))
        if chain.recorder is not None:
            tim = chain.recorder.close()
            report["timing_s"]["rerun"] = tim["log_s"] + tim["flush_s"]
    if args.rrd:
        print(f"wrote {args.rrd} ({report['timing_s']['rerun']:.2f} s)")
    write_report(report, args.report, chain)
    return 0
