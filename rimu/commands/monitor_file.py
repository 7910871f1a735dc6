"""``rimu monitor-file DIR``: run the monitor over a flight directory and report."""

from __future__ import annotations

import argparse
import json

from rimu.argtypes import nonnegative_int, positive_float

HELP = "run the monitor over a flight sample directory; print events and a summary"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("flight", metavar="DIR", help="flight directory (rimu.flight/1)")
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--false-alarms-per-hour", type=positive_float(1e9), metavar="X",
                   help="false-alarm budget for computed thresholds (default 1e-3)")
    p.add_argument("--thresholds", metavar="FILE",
                   help="a rimu.thresholds/1 or rimu.tuning/1 (rimu tune) file (default: "
                        "computed from the calibration)")
    p.add_argument("--report", metavar="FILE", help="write the rimu.report/1 JSON here")
    p.add_argument("--max-events", type=nonnegative_int(), default=50,
                   help="events to print (default 50)")
    p.add_argument("--no-time-offsets", action="store_true",
                   help="do not move each IMU by the time offset its in-flight calibration "
                        "records (default: moved onto the reference's timing)")
    p.add_argument("--no-effects", action="store_true",
                   help="do not compensate the calibration's effect terms (default: the "
                        "terms whose inputs the flight carries are compensated: rate sign, "
                        "rate squared, specific force from its accelerometers, temperature)")


def run(args: argparse.Namespace) -> int:
    from fdi.calfile import check_compatible, load_calibration
    from replay.flight import load_flight_dir
    from replay.report import build_report, format_report
    from rimu.outputs import atomic_write_text, flight_folder_hint, input_path, output_file

    flight_folder_hint(args.flight, "DIR", "rimu monitor-file")
    input_path(args.flight, "DIR", kind="dir")
    input_path(args.cal, "--cal")
    if args.thresholds:
        input_path(args.thresholds, "--thresholds")
    if args.report:
        output_file(args.report, "--report")
    cal = load_calibration(args.cal)
    flight = load_flight_dir(args.flight)
    check_compatible(cal, flight.n, flight.raw_unit, str(args.flight), kind=flight.kind,
                     names=flight.sensor_names)
    from fdi.monitor import Monitor
    from replay.effect_inputs import flight_effect_inputs
    from rimu.commands.replay import compensated, effects_extra
    from thresholds.select import select

    choice = select(cal, kind=flight.kind, thresholds_file=args.thresholds,
                    false_alarms_per_hour=args.false_alarms_per_hour)
    thr, how = choice.thresholds, choice.to_dict()
    extra: dict = {"thresholds": how}
    if not args.no_time_offsets:
        from calibration.inflight.timing import apply_time_offsets, moved_aux_channels

        flight, shifted = apply_time_offsets(flight, cal)
        if shifted:
            extra["time_offsets_applied_ms"] = shifted
            moved = moved_aux_channels(flight, shifted)
            if moved:
                extra["time_offsets_aux_moved"] = moved
            print("moved onto the reference's timing: " + ", ".join(
                f"{g} {ms:+.3f} ms" for g, ms in shifted.items())
                + (f" (with {len(moved)} auxiliary channel(s): {', '.join(moved)})"
                   if moved else ""))
    force = temp = None
    avail: dict = {}
    if not args.no_effects and cal.effects:
        force, temp, avail = flight_effect_inputs(flight)
    mon = compensated(Monitor(cal, thr, kind=flight.kind), cal, flight.kind,
                      enabled=not args.no_effects, available=avail,
                      names=flight.sensor_names)
    result = mon.run(flight.t, flight.raw, flight.valid, force=force, temperature=temp)
    extra.update(effects_extra(mon, cal))               # with the missing-input counts
    report = build_report(result, flight, cal, extra=extra)
    print(format_report(report, max_events=args.max_events))
    if args.report:
        atomic_write_text(args.report, json.dumps(report, indent=1, allow_nan=False) + "\n")
        print(f"wrote {args.report}")
    return 0
