"""``rimu replay LOG``: decode a CAN log, run the monitor, report events and frame accounting."""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import time
from typing import TYPE_CHECKING, Any

from fdi.errors import ConfigError
from rimu.argtypes import nonnegative_int, positive_float

if TYPE_CHECKING:                   # numerical imports in the functions: --help stays light
    from fdi.calfile import Calibration

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
                   help="a rimu.thresholds/1 or rimu.tuning/1 (rimu tune) file")
    p.add_argument("--false-alarms-per-hour", type=positive_float(1e9), metavar="X",
                   help="compute thresholds for this false-alarm budget (default 1e-3 "
                        "per hour)")
    p.add_argument("--report", metavar="FILE", help="write the rimu.report/1 JSON here")
    p.add_argument("--max-events", type=nonnegative_int(), default=50,
                   help="events to print (default 50)")
    p.add_argument("--no-effects", action="store_true",
                   help="do not compensate the calibration's effect terms (default: those "
                        "read from the sensors' own outputs, rate sign and rate squared, are "
                        "compensated, and g-sensitivity and temperature terms when the "
                        "channel map has [[auxiliary]] specific-force or temperature "
                        "channels for the sensor)")


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


def make_monitor(cal: Calibration, args: argparse.Namespace, kind: str,
                 cmap: Any = None) -> tuple[Any, dict]:
    """The monitor the options ask for, and how its thresholds were chosen."""
    from fdi.monitor import Monitor
    from thresholds.select import select

    choice = select(cal, kind=kind, thresholds_file=args.thresholds,
                    false_alarms_per_hour=args.false_alarms_per_hour)
    thr, how = choice.thresholds, choice.to_dict()
    avail, lacking = {}, None
    if cmap is not None:
        from replay.effect_inputs import map_available, map_reasons

        avail, lacking = map_available(cmap), map_reasons(cmap)
    return compensated(Monitor(cal, thr, kind=kind), cal, kind,
                       enabled=not getattr(args, "no_effects", False), available=avail,
                       lacking=lacking), how


def compensated(mon: Any, cal: Calibration, kind: str, *, enabled: bool,
                available: Any = None, lacking: Any = None, names: Any = None) -> Any:
    """The monitor wrapped with the compensation of the calibration's effect terms
    (:class:`fdi.effects.Compensator`: ``available`` and ``lacking`` as there, from a
    channel map's auxiliary channels or a flight's); prints what is and is not compensated
    (sensors named ``names``, default the monitor's)."""
    from fdi.effects import Compensator
    from fdi.effects_monitor import CompensatedMonitor

    out = CompensatedMonitor(mon, Compensator(cal, kind, available=available or {},
                                              enabled=enabled, lacking=lacking))
    if cal.effects:
        print(out.compensator.summary(mon.sensor_names if names is None else names),
              flush=True)
    return out


def effects_extra(mon: Any, cal: Calibration) -> dict[str, Any]:
    """``{"effects": record}`` for a report when the calibration has effect terms."""
    comp = getattr(mon, "compensator", None)
    return {"effects": comp.to_dict()} if cal.effects and comp is not None else {}


def aux_record(cmap: Any, decoder: Any) -> dict[str, Any]:
    """The report's ``auxiliary`` block: the map's auxiliary channels and their frames."""
    st = decoder.aux_stats
    chans, c = [], 0
    for a in cmap.auxiliary:
        m = len(a.signals)
        chans.append({"name": a.name, "quantity": a.quantity, "message": a.message,
                      "signals": list(a.signals), "unit": a.unit,
                      "sensors": "all" if a.sensors is None else list(a.sensors),
                      "timeout_s": a.timeout_s, "values_received": st["received"][c:c + m]})
        c += m
    return {"channels": chans, "frames": {k: v for k, v in st.items() if k != "received"}}


def format_aux(rec: dict[str, Any]) -> str:
    """One line on the auxiliary channels of a report."""
    fr = rec["frames"]
    chans = ", ".join(f"{c['name']} {sum(c['values_received'])}" for c in rec["channels"])
    rej = ", ".join(f"{v} {k}" for k, v in sorted(fr["rejected"].items())) or "none"
    return (f"auxiliary channels (values received): {chans}; frames used {fr['used']}, "
            f"rejected {rej}, lost {fr['lost_frames']}")


def warn_silent_aux(rec: dict[str, Any], source: str) -> None:
    """Warn about auxiliary channels that never delivered a value."""
    silent = [ch["name"] for ch in rec["channels"] if not any(ch["values_received"])]
    if silent:
        logging.getLogger("rimu").warning(
            f"{source}: no frame at all from auxiliary channel(s) {', '.join(silent)}: the "
            "effect terms they feed got no input (counted in the report's effects block)")


def write_report(report: dict, path: str | None) -> None:
    """Write a report as JSON (no NaN), atomically."""
    if path:
        from rimu.outputs import atomic_write_text

        atomic_write_text(path, json.dumps(report, indent=1, allow_nan=False) + "\n")
        print(f"wrote {path}")


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


def has_display() -> bool:
    """Whether a viewer window can open here (a desktop session, or not Linux)."""
    import os
    import sys

    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def warn_reader_errors(frames: dict, source: str) -> None:
    """Reader errors of a log as warnings on stderr; unreadable lines of a text log as one
    line with their count and the first of them."""
    log = logging.getLogger("rimu")
    for e in frames["errors"]:
        if e.get("kind") != "garbage_line":
            log.warning(f"{source}: {e['where']}: {e['why']}")
    n = frames.get("rejected", {}).get("garbage_line", 0)
    first = next((e for e in frames["errors"] if e.get("kind") == "garbage_line"), None)
    if n and first is not None:
        log.warning(f"{source}: {n} unreadable line(s) skipped, the first at {first['where']} "
                    f"({first['why']}); --strict refuses a damaged log")


def run(args: argparse.Namespace) -> int:
    from replay.effect_inputs import stream_inputs
    from replay.live import Pacer, format_event
    from replay.logio import LogStream, resolve_map
    from replay.report import RunningReport, format_report
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
                              "'rerun FILE' where there is one")
        logging.getLogger("rimu").warning("--spawn: no display; writing the recording to "
                                          f"{args.rrd} only")
        spawn = False
    from fdi.calfile import load_calibration

    cal = load_calibration(args.cal)
    db, cmap = resolve_map(cal, dbc=args.dbc, channel_map=args.channel_map)
    stream = LogStream(args.log, cal, db, cmap, strict=args.strict,
                       progress=not args.no_progress,
                       check_sensor_set=args.channel_map is None)
    header = stream.header
    injector = None
    if args.inject:
        from dataclasses import replace

        from replay.scenario import load_scenario
        from replay.stream import ChunkInjector

        faults, seed = load_scenario(args.inject, cal, kind=cmap.kind)
        injector = ChunkInjector(faults, cal, kind=cmap.kind, seed=seed, n=cmap.n)
        truth = dict(header.truth)
        truth["injected"] = {"faults": [f.to_dict() for f in faults], "seed": int(seed),
                             "source": str(args.inject)}
        header = replace(header, faults=tuple(header.faults) + tuple(faults), truth=truth)
    mon, how = make_monitor(cal, args, cmap.kind, cmap)
    acc = RunningReport()
    names = header.sensor_names
    pacer = Pacer(lambda e: print(format_event(e, names), flush=True)) if args.realtime \
        else None
    timing = {"read_decode": 0.0, "monitor": 0.0}
    with contextlib.ExitStack() as stack:
        recorder = None
        if args.rrd or spawn:
            from replay.rerun_log import Recorder

            rrd = stack.enter_context(atomic_file(args.rrd)) if args.rrd else None
            recorder = Recorder(cal, names, cmap.kind, path=rrd, spawn=spawn,
                                has_truth=header.omega_true is not None,
                                thresholds=mon.thresholds)
            stack.callback(recorder.abort)      # on an error: stop writing the temp file
        clock = [time.perf_counter()]

        def on_samples(piece: Any) -> None:
            t1 = time.perf_counter()
            timing["read_decode"] += t1 - clock[0]
            if injector is not None:
                piece = injector.apply(piece)
            kw = stream_inputs(mon, cmap, piece.aux)
            if pacer is not None:
                result = pacer.run(mon, piece.t, piece.raw, piece.valid, **kw)
            else:
                result = mon.run(piece.t, piece.raw, piece.valid, **kw)
            acc.update(result, piece.omega_true)
            if recorder is not None:
                recorder.log(result, piece)
            clock[0] = time.perf_counter()
            timing["monitor"] += clock[0] - t1

        frames = stream.run(on_samples)
        timing["read_decode"] += time.perf_counter() - clock[0]
        warn_reader_errors(frames, str(args.log))
        silent = stream.silent_sensors()
        if silent and acc.samples:
            logging.getLogger("rimu").warning(
                f"{args.log}: no frame at all from sensor(s) {', '.join(silent)}: is the "
                "calibration for this log's sensor set?")
        if acc.samples == 0:
            raise ConfigError(f"{args.log}: no sample could be decoded ({frames['read']} "
                              f"frames read, rejected {frames['rejected']})")
        extra: dict[str, Any] = {"thresholds": how, "timing_s": timing,
                                 **effects_extra(mon, cal)}
        if cmap.auxiliary:
            extra["auxiliary"] = aux_record(cmap, stream.decoder)
            warn_silent_aux(extra["auxiliary"], str(args.log))
        if args.inject:
            extra["injected"] = str(args.inject)
        report = acc.build(header, cal, frames=frames, extra=extra)
        print(format_report(report, max_events=args.max_events))
        if cmap.auxiliary:
            print(format_aux(extra["auxiliary"]))
        if recorder is not None:
            tim = recorder.close()
            timing["rerun"] = tim["log_s"] + tim["flush_s"]
    if args.rrd:
        print(f"wrote {args.rrd} ({timing['rerun']:.2f} s)")
    write_report(report, args.report)
    return 0
