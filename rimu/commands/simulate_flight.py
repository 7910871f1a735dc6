"""``rimu simulate flight``: a manoeuvring flight with calibration error and injected faults."""

from __future__ import annotations

import argparse
from pathlib import Path

from fdi.errors import ConfigError
from fdi.units import DPH, MG
from rimu.argtypes import (
    DAY_S,
    MAX_SAMPLES,
    SEED_MAX,
    nonnegative_float,
    nonnegative_int,
    positive_float,
)

HELP = "simulate a flight (manoeuvres, true sensor model, faults) with a truth sidecar"

CAN_SUFFIXES = (".asc", ".blf", ".log")
"""``--out`` suffixes written as CAN logs (through ``replay.can_write.write_flight_log``)."""
MAP_SUFFIX = ".map.toml"
"""The channel map written beside a CAN log ``NAME.blf``: ``NAME.map.toml``."""


def map_path(log: Path) -> Path:
    """The channel map beside a CAN log: ``flight.blf`` → ``flight.map.toml``."""
    return log.with_suffix(MAP_SUFFIX)


def _check_effect_options(args: argparse.Namespace) -> None:
    """The effect options need --effects-from-cal, and it excludes --imus and --truth."""
    if not args.effects_from_cal:
        for opt, v in (("--temperature", args.temperature), ("--accel-noise", args.accel_noise)):
            if v is not None:
                raise ConfigError(f"rimu simulate flight: {opt} needs --effects-from-cal")
        return
    if getattr(args, "imus", None):
        raise ConfigError("rimu simulate flight: --effects-from-cal simulates the terms of a "
                          "calibration (--cal), not an IMU set (--imus)")
    if args.truth:
        raise ConfigError("rimu simulate flight: --effects-from-cal draws the true sensors "
                          "from the calibration (its terms' estimates are the true effects); "
                          "--truth's biases refer to the session's own temperatures: give "
                          "one or the other")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cal", metavar="FILE",
                   help="calibration file (rimu.calibration/3); required unless --imus")
    p.add_argument("--duration", required=True, type=positive_float(DAY_S), metavar="S",
                   help="flight length (s, at most one day)")
    p.add_argument("--seed", type=nonnegative_int(SEED_MAX), default=0,
                   help="random seed (default 0)")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                   help="KIND:SENSOR:SIZE:ONSET[:DURATION], repeatable; e.g. step:3:15sigma:20, "
                        "ramp:2:0.05sigma/s:10, stuck:1::30, noise:4:3x:12, scale:5:1%%:40, "
                        "spike:2:50sigma:15, dropout:6::25:2")
    p.add_argument("--truth", metavar="FILE",
                   help="true sensor parameters: a calibration session's truth sidecar "
                        "(default: drawn from the calibration's covariance)")
    p.add_argument("--rate", type=positive_float(1e5), metavar="HZ",
                   help="sample rate (default: the calibration's)")
    p.add_argument("--max-rate", type=positive_float(1e5), default=300.0, metavar="DPS",
                   help="largest body rate per axis in deg/s (default 300)")
    p.add_argument("--kind", default="gyro", choices=("gyro", "accel"))
    p.add_argument("--bias-instability", type=nonnegative_float(1e6), default=0.0, metavar="X",
                   help="in-run bias drift: stationary sd of a Gauss-Markov bias per sensor, "
                        "deg/h for gyros, mg for accelerometers (default 0: none)")
    p.add_argument("--bias-corr", type=positive_float(1e9), default=100.0, metavar="S",
                   help="correlation time of that bias (s, default 100)")
    p.add_argument("--out", required=True, metavar="DIR|FILE",
                   help="a flight directory, or a CAN log (.asc, .blf, .log); a CAN log gets "
                        "its channel map beside it (NAME.map.toml) for rimu replay --map")
    g = p.add_argument_group("effect terms (docs/effects-runtime.md)")
    g.add_argument("--effects-from-cal", action="store_true",
                   help="the true sensors carry the calibration's effect terms at their "
                        "estimates, and the flight carries the inputs they need (an "
                        "accelerometer triad, a board temperature) as auxiliary channels")
    g.add_argument("--temperature", metavar="START:END[:TAU]",
                   help="board temperature profile with --effects-from-cal: degC at the "
                        "start, degC approached, time constant in s (default: 10 degC below "
                        "to 10 degC above the terms' reference, TAU a third of the flight)")
    g.add_argument("--temperature-noise", type=nonnegative_float(100.0), default=0.05,
                   metavar="DEGC", help="sd of the temperature channel per sample "
                                        "(default 0.05)")
    g.add_argument("--accel-noise", type=nonnegative_float(1e3), metavar="MPS2",
                   help="sd of the accelerometer triad per sample in m/s^2 (default: the "
                        "calibration's accelerometer noise; needed when it has none)")
    from rimu.commands.simulate_imu_set import configure_options

    configure_options(p)


def _load_truth(path: str):
    try:
        from calibration.truth import load_truth
    except ImportError:
        raise ConfigError("--truth needs calibration.truth (not installed in this build)") from None
    return load_truth(path)


def run(args: argparse.Namespace) -> int:
    from rimu.commands.simulate_imu_set import check_imu_options

    check_imu_options(args)
    _check_effect_options(args)
    if getattr(args, "imus", None):
        from rimu.commands import simulate_imu_set

        return simulate_imu_set.run(args)
    if not args.cal:
        raise ConfigError("rimu simulate flight: --cal is required (or --imus K)")
    from fdi.calfile import load_calibration
    from replay.flight import save_flight_dir, simulate_flight
    from rimu.outputs import atomic_dir, input_path, output_dir, output_file

    out = Path(args.out)
    is_log = out.suffix.lower() in CAN_SUFFIXES
    if not is_log and out.suffix.lower() in (".trc", ".csv"):     # logs rimu reads, not writes
        raise ConfigError(f"--out {out}: rimu writes CAN logs as {', '.join(CAN_SUFFIXES)}, "
                          f"not {out.suffix}; give one of those or a folder name")
    if is_log:
        output_file(out, "--out", inputs=(args.cal, args.truth))
    else:
        output_dir(out, "--out", inputs=(args.cal, args.truth), schema="rimu.flight/1")
    input_path(args.cal, "--cal")
    if args.truth:
        input_path(args.truth, "--truth")
    cal = load_calibration(args.cal)
    faults, fs = _checked_request(args, cal)
    truth = _load_truth(args.truth) if args.truth else None
    plan = _effect_plan(cal, args, fs) if args.effects_from_cal else None
    if is_log:
        _check_frame_budget(out, cal.kind(args.kind).n, plan, fs, args.kind)
    unit = DPH if args.kind == "gyro" else MG
    flight = simulate_flight(cal, args.duration, seed=args.seed, faults=faults, truth=truth,
                             sample_rate_hz=args.rate, max_rate_dps=args.max_rate, kind=args.kind,
                             bias_instability=args.bias_instability * unit,
                             bias_correlation_s=args.bias_corr)
    if plan is not None:
        from replay.flight_effects import add_effects

        flight = add_effects(flight, plan, seed=args.seed)
    if is_log:
        try:
            from replay.can_write import write_flight_log
        except ImportError:
            raise ConfigError(f"{out}: writing CAN logs needs replay.can_write (not available "
                              f"in this build); give a directory instead") from None
        # the log and its truth sidecar, written together and renamed when all are done
        with atomic_dir(out.parent if str(out.parent) else Path("."), inside=True) as tmp:
            aux = write_flight_log(flight, tmp / out.name)
            _write_map(cal, args.kind, aux, tmp / map_path(out).name)
    else:
        with atomic_dir(out) as tmp:
            save_flight_dir(flight, tmp)
    print(f"wrote {out}: {flight.t.shape[0]} samples of {flight.n} {args.kind} sensors at "
          f"{flight.sample_rate_hz:g} Hz, {len(faults)} fault(s)")
    if plan is not None:
        print(plan.summary(flight.sensor_names))
    if is_log:
        _say_files(out, flight, args)
    elif plan is not None:
        print(f"  {out}: the flight folder, with the auxiliary channels in "
              f"{out / 'aux.csv'}; monitor it with: rimu monitor-file {out} --cal {args.cal}")
    return 0


def _checked_request(args: argparse.Namespace, cal) -> tuple[list, float]:
    """The faults (within the flight) and the sample rate (Hz), the flight's size bounded."""
    from replay.faults import parse_fault

    faults = [parse_fault(s, cal, kind=args.kind) for s in args.fault]
    for f in faults:
        if not f.onset < args.duration:
            raise ConfigError(f"--fault {f.spec}: onset {f.onset:g} s is not within the "
                              f"flight (0 to {args.duration:g} s)")
    fs = args.rate if args.rate is not None else cal.sample_rate_hz
    if args.duration * fs > MAX_SAMPLES:
        raise ConfigError(f"--duration {args.duration:g} s at {fs:g} Hz is "
                          f"{args.duration * fs:.3g} samples; at most {MAX_SAMPLES:.0e} are "
                          "simulated in memory at once")
    return faults, fs


def _effect_plan(cal, args, fs: float):
    """The calibration's effect terms the flight carries and their input channels."""
    from replay.flight_effects import parse_temperature_profile, plan_effects

    prof = (parse_temperature_profile(args.temperature, args.duration)
            if args.temperature is not None else None)
    return plan_effects(cal, args.kind, duration_s=args.duration, sample_rate_hz=fs,
                        temperature=prof, accel_noise_mps2=args.accel_noise,
                        temperature_noise_degC=args.temperature_noise)


def _check_frame_budget(out: Path, n: int, plan, fs: float, kind: str) -> None:
    """Refuse before simulating when one sample's frames do not fit in one period
    (:func:`replay.can_write.frames_fit`)."""
    from replay.can_write import FRAME_GAP_S as gap
    from replay.can_write import JITTER_S, frames_fit

    m = 0
    if plan is not None:
        m += 3 if plan.accel_noise_mps2 is not None and kind == "gyro" else 0
        m += 1 if plan.temperature is not None else 0
    if not frames_fit(n + m, fs):
        most = int((1.0 / fs - JITTER_S) / gap)
        raise ConfigError(f"{out}: at {fs:g} Hz one sample period holds at most {most} CAN "
                          f"frames of {gap * 1e6:.0f} us; this log needs {n} {kind} "
                          + (f"+ {m} auxiliary " if m else "") + "frames per sample: lower "
                          "--rate or write a flight folder")


def _write_map(cal, kind: str, aux, path: Path) -> None:
    """The shipped DBC's channel map of the calibration's sensors plus the auxiliary
    channels the log carries (``rimu.channel_map/1``)."""
    from replay.channel_map import default_channel_map, write_channel_map

    s = cal.kind(kind)
    cmap = default_channel_map(s.n, kind, axes=s.H_nominal,
                               names=tuple(c.name for c in s.sensors), auxiliary=tuple(aux))
    write_channel_map(cmap, path)


def _msgs(stem: str, k: int) -> str:
    """``RIMU_GYRO_01..06`` (or the one message)."""
    return f"{stem}_01" + (f"..{k:02d}" if k > 1 else "")


def _say_files(out: Path, flight, args) -> None:
    """Which file is which, and the replay command."""
    from replay.can_files import truth_path
    from replay.frames import imu_message_name

    n = flight.n
    frames = _msgs(imu_message_name(args.kind, 1)[:-3], n)
    aux = flight.aux
    extra = ""
    if aux is not None and aux.m:
        parts = []
        acc = sum(k == "accel" for k in aux.kinds) if args.kind == "gyro" else 0
        if acc:
            parts.append(f"specific force on {acc} axes ({_msgs('RIMU_ACCEL', acc)}, every "
                         "sample)")
        tmp = sum(k == "temperature" for k in aux.kinds)
        if tmp:
            parts.append(f"temperature ({_msgs('RIMU_TEMP', tmp)}, every 10th sample)")
        extra = "; auxiliary: " + ", ".join(parts) if parts else ""
    mp = map_path(out)
    print(f"  {out}: the CAN log (shipped rimu_imu.dbc: {frames}{extra})")
    print(f"  {truth_path(out)}: its truth sidecar (true parameters, faults"
          + (", effects simulated" if "effects_simulated" in flight.truth else "") + ")")
    print(f"  {mp}: its channel map (sensors"
          + (" and auxiliary channels" if extra else "") + ")")
    print(f"replay it with: rimu replay {out} --cal {args.cal} --map {mp}")
