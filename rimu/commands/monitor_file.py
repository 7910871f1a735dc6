"""``rimu monitor-file DIR``: run the monitor over a flight directory and report."""

from __future__ import annotations

import argparse
import logging
from typing import Any

from fdi.errors import ConfigError
from rimu.argtypes import nonnegative_float, nonnegative_int, positive_float

HELP = "run the monitor over a flight sample directory; print events and a summary"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("flight", metavar="DIR", help="flight directory (rimu.flight/1)")
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--false-alarms-per-hour", type=positive_float(1e9), metavar="X",
                   help="false-alarm budget for computed thresholds (default 1e-3)")
    p.add_argument("--thresholds", metavar="FILE",
                   help="a rimu.thresholds or rimu.tuning (rimu tune) file made for this "
                        "calibration and sample rate (default: computed from the "
                        "calibration)")
    p.add_argument("--report", metavar="FILE",
                   help="write the rimu.report/1 JSON here, and its picture beside it "
                        "(FILE with .png: rates, statistic / threshold per window, events)")
    p.add_argument("--max-events", type=nonnegative_int(), default=50,
                   help="events to print (default 50)")
    p.add_argument("--no-time-offsets", action="store_true",
                   help="do not move each IMU by the time offset its in-flight calibration "
                        "records (default: moved onto the reference's timing)")
    p.add_argument("--no-envelope", action="store_true",
                   help="do not mark samples out of the operating envelope (default: shocks, "
                        "saturation, tumbles and the log's declared crash events are marked; "
                        "the monitor excludes nothing there and restarts its windows after; "
                        "docs/envelope.md)")
    p.add_argument("--turn-on", choices=("auto", "rest", "bound", "off"), default="auto",
                   help="the turn-on bias on a flight other than the calibration's: auto "
                        "(default) estimates it while the vehicle is at rest before take-off "
                        "and otherwise covers a nominal bias bound in the thresholds; rest, "
                        "bound, off (as calibrated); replay.turn_on")
    p.add_argument("--bias-bound-dps", type=nonnegative_float(1e4), default=None,
                   metavar="DPS",
                   help="nominal turn-on bias bound per gyro (deg/s) when no rest stretch is "
                        "found (default: 3 x the calibration's bias_turn_on_sd, else 1)")
    p.add_argument("--keep-firmware-parameters", action="store_true",
                   help="on a flight whose log names another firmware than the calibration's, "
                        "keep every IMU's relative scale, mounting and time offset as "
                        "calibrated (default: held at the calibration's prior tolerance; "
                        "replay.firmware_prior)")
    p.add_argument("--no-parameter-check", action="store_true",
                   help="do not fit this flight to check every parameter of an in-flight "
                        "calibration made on another flight (default: checked, and each "
                        "parameter that does not fit is warned about)")
    p.add_argument("--no-effects", action="store_true",
                   help="do not compensate the calibration's effect terms (default: the "
                        "terms whose inputs the flight carries are compensated: rate sign, "
                        "rate squared, specific force from its accelerometers, temperature)")
    p.add_argument("--baseline", metavar="NAMES",
                   help="also run the autopilots' own rules on the same samples and report "
                        "when each would have flagged and whom it blamed, beside rimu's "
                        "answer: a comma-separated list of px4, px4-others, ardupilot, or "
                        "all (docs/baselines.md)")
    p.add_argument("--baseline-plot", metavar="FILE",
                   help="with --baseline: a PNG of the IMU rates, rimu's detections and "
                        "exclusions and each baseline's flags and blames on one time axis")


def _baselines(args: argparse.Namespace, names: tuple[str, ...], flight: Any, cal: Any,
               report: dict[str, Any]) -> None:
    """The autopilot rules on the flight's samples: text, the report's block, the plot."""
    from replay.baselines import baselines_record, format_baselines, run_baselines
    from rimu.outputs import atomic_file

    triads, results = run_baselines(flight, names, cal)
    rec = baselines_record(triads, results, flight, report)
    report["baselines"] = rec
    print(format_baselines(rec, max_events=min(args.max_events, 10)))
    if args.baseline_plot:
        from replay.baselines.plot import plot_baselines

        with atomic_file(args.baseline_plot) as tmp:
            plot_baselines(tmp, triads, results, report, faults=flight.faults)
        print(f"wrote {args.baseline_plot}")


def run(args: argparse.Namespace) -> int:
    from fdi.calfile import check_compatible, load_calibration
    from replay.chain import ChainOptions, chain_for_flight, run_flight
    from replay.flight import load_flight_dir
    from replay.report import format_report
    from rimu.commands.replay import describe_chain, picture_path, write_report
    from rimu.outputs import flight_folder_hint, input_path, output_file

    flight_folder_hint(args.flight, "DIR", "rimu monitor-file")
    input_path(args.flight, "DIR", kind="dir")
    input_path(args.cal, "--cal")
    if args.thresholds:
        input_path(args.thresholds, "--thresholds")
    if args.report:
        output_file(args.report, "--report")
        output_file(picture_path(args.report), "--report (its picture)")
    from replay.baselines import parse_baselines

    baselines = parse_baselines(args.baseline)
    if args.baseline_plot:
        if not baselines:
            raise ConfigError("--baseline-plot needs --baseline NAMES")
        output_file(args.baseline_plot, "--baseline-plot")
    from fdi.progress import current
    cal = load_calibration(args.cal)
    flight = load_flight_dir(args.flight)
    check_compatible(cal, flight.n, flight.raw_unit, str(args.flight), kind=flight.kind,
                     names=flight.sensor_names, cal_source=args.cal)
    from calibration.inflight.timing import other_flight_warning

    warning = other_flight_warning(cal, flight)
    if warning:
        logging.getLogger("rimu").warning(warning)
    misfits: list[str] = []
    if not args.no_parameter_check:
        from calibration.inflight.fits_flight import flight_mismatch

        misfits = flight_mismatch(cal, flight)[1]       # every parameter, not only the offset
        for w in misfits:
            logging.getLogger("rimu").warning(w)
    chain = chain_for_flight(flight, cal, ChainOptions(
        thresholds_file=args.thresholds, calibration_file=args.cal,
        false_alarms_per_hour=args.false_alarms_per_hour, effects=not args.no_effects,
        time_offsets=not args.no_time_offsets, envelope=not args.no_envelope,
        turn_on=args.turn_on, bias_bound_dps=args.bias_bound_dps,
        firmware_prior=not args.keep_firmware_parameters))
    describe_chain(chain, flight)
    if chain.turn_on is not None and chain.turn_on.method != "calibrated":
        print(chain.turn_on.text(chain.sensor_names))
    if chain.firmware_prior is not None:
        print(chain.firmware_prior.text())
    current().stage(f"monitoring {flight.t.shape[0]} samples")
    _, report = run_flight(chain, flight)
    report["time_base"] = flight.time_base.to_dict()     # the gaps it monitored across
    if misfits:                 # what of the calibration does not fit this flight (firmware too)
        report["calibration_misfit"] = misfits
    print(format_report(report, max_events=args.max_events))
    from replay.report import decoding_hint

    hint = decoding_hint(report)
    if hint:
        logging.getLogger("rimu").warning(hint)
    if baselines:
        current().stage("baselines")
        _baselines(args, baselines, flight, cal, report)
    write_report(report, args.report, chain)
    return 0
