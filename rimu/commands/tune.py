"""``rimu tune --cal CAL --false-alarms-per-hour X --out FILE``: thresholds for a rate."""

from __future__ import annotations

import argparse

from fdi.errors import ConfigError
from rimu.argtypes import SEED_MAX, nonnegative_float, nonnegative_int, positive_float

MAX_FALSE_ALARMS_PER_HOUR = 3.6e6
"""Largest false-alarm budget (one per millisecond): beyond it thresholds mean nothing."""
MAX_SCALE = 1 << 20
"""Longest window, in samples."""
MAX_SIMULATE_HOURS = 1e4
"""Most healthy flight hours simulated per correction pass."""
MAX_DRIFT_HORIZON_S = 1e8
"""Longest drift horizon (about three years)."""
MAX_RATE_DPS = 1e5
"""Largest body rate of the correction flights a user may ask for (°/s)."""

HELP = ("tune thresholds for a false-alarm rate; print them and the detectable fault size "
        "per window scale")


def _scales(text: str) -> tuple[int, ...]:
    out = []
    for part in text.replace(",", " ").split():
        try:
            v = float(part)
        except ValueError:
            raise ConfigError(f"unknown scale {part!r}: expected window lengths in samples, "
                              f"e.g. --scales 1,2,4,8") from None
        if not (1 <= v <= MAX_SCALE and v == int(v)):      # NaN and inf fail the first test
            raise ConfigError(f"unknown scale {part!r}: expected a whole window length in "
                              f"samples, 1 to {MAX_SCALE}")
        out.append(int(v))
    return tuple(out)


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--false-alarms-per-hour", required=True, metavar="X",
                   type=positive_float(MAX_FALSE_ALARMS_PER_HOUR),
                   help="target rate of false alarms per hour of healthy operation (at "
                        "most what the monitor can count as separate alarms: 3.6 x the "
                        "sample rate in Hz with the default clear_samples, e.g. 180 at "
                        "50 Hz)")
    p.add_argument("--scales", metavar="LIST",
                   help="window lengths in samples, e.g. 1,2,4,...,128 (default 1 ... 128)")
    p.add_argument("--kind", default="gyro", choices=("gyro", "accel"))
    p.add_argument("--simulate-hours", type=nonnegative_float(MAX_SIMULATE_HOURS), default=8.0,
                   metavar="H",
                   help="healthy flight hours simulated per correction pass, shared by 20 drawn "
                        "calibration errors (default 8; "
                        "0: analytic only)")
    p.add_argument("--seed", type=nonnegative_int(SEED_MAX), default=0,
                   help="seed of the correction flights")
    p.add_argument("--drift-horizon-s", type=nonnegative_float(MAX_DRIFT_HORIZON_S),
                   default=None, metavar="S",
                   help="how long after its data the calibration must hold, for the parity "
                        "drift term (s; default: the span of the calibration data; only "
                        "for a calibration with a drift model)")
    p.add_argument("--max-rate-dps", type=nonnegative_float(MAX_RATE_DPS), default=None,
                   metavar="DPS",
                   help="largest body rate of the simulated correction flights (deg/s; "
                        "default: inside the calibration's validated rate range, at most "
                        "300; 0: at rest)")
    p.add_argument("--flight", metavar="DIR",
                   help="a flight folder (rimu.flight/1) of this set: also state the "
                        "detectable sizes over that flight's own profile (median, p90 over "
                        "its samples; the thresholds rise with the rate in flight)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="write the rimu.tuning/1 file here (for --thresholds)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from fdi.calfile import load_calibration
    from rimu.outputs import atomic_file, input_path, output_file
    from thresholds.tune import tune

    input_path(args.cal, "--cal")
    if args.flight:
        input_path(args.flight, "--flight", kind="dir")
    out = output_file(args.out, "--out", inputs=(args.cal,))
    scales = _scales(args.scales) if args.scales else 7
    cal = load_calibration(args.cal)
    if args.drift_horizon_s is not None and cal.kind(args.kind).drift is None:
        from fdi.errors import ConfigError

        raise ConfigError(f"--drift-horizon-s: {args.cal} has no {args.kind} drift model "
                          "(parity_drift), so there is no drift term to project; calibrate "
                          "with --drift-model or leave the option out")
    tu = tune(cal, false_alarms_per_hour=args.false_alarms_per_hour, kind=args.kind,
              scales=scales, simulate_hours=args.simulate_hours, seed=args.seed,
              progress=not args.no_progress, drift_horizon_s=args.drift_horizon_s,
              max_rate_dps=args.max_rate_dps)
    th = tu.thresholds
    corr = tu.assumptions["simulation_correction"]
    print(f"thresholds for {th.false_alarms_per_hour:g} false alarms/h, {th.n} {th.kind} "
          f"sensors at {th.sample_rate_hz:g} Hz (correction {corr['factor']:.3g}: "
          f"{corr['note']}; flights up to {corr['max_rate_dps']:.3g} deg/s, "
          f"{corr['max_rate_source']})")
    qf = tu.assumptions["rate_error_factor"]
    last = corr["passes"][-1] if corr["passes"] else None
    print(f"per calibration: rate term x{qf['factor']:.3g} (the p95 calibration error of "
          f"the covariance, worst-direction gain {qf['worst_direction_gain_quantile']:.3g}); "
          f"{corr['criterion']}"
          + (f" (last pass, at correction {last['correction_before']:.3g}: mean "
             f"{last['rate_per_hour']:.3g}/h, p95 {last['quantile_per_hour']:.3g}/h against "
             f"{last['target_per_hour']:g}/h)" if last else ""))
    d0 = tu.detectable[0]
    print(f"{'scale':>6} {'window_s':>9} {'alpha':>10} {'chi2 thr':>9} {'var f':>6} "
          f"{'detectable (99 %)':>18} {'sigma':>7}")
    for w, a, t, f, d in zip(th.scales, th.alpha, th.threshold, th.variance_factor,
                             tu.detectable, strict=True):
        print(f"{w:6d} {w / th.sample_rate_hz:9.3f} {a:10.3e} {t:9.2f} {f:6.2f} "
              f"{d.size_unit_value:12.4g} {d.unit:5s} {d.size_sigma:7.2f}")
    names = [c.name for c in cal.kind(args.kind).sensors]
    who = f"{d0.sensor} ({names[d0.sensor - 1]})" if 1 <= d0.sensor <= len(names) else d0.sensor
    print(f"detectable sizes: one full window, at rest, worst sensor {who}"
          + ("" if args.flight else "; in flight the thresholds rise with the rate: "
             "--flight DIR states the sizes over a flight's own profile"))
    if args.flight:
        from fdi.calfile import check_compatible
        from replay.flight import load_flight_dir
        from thresholds.profile import flight_detectable, profile_lines

        flight = load_flight_dir(args.flight)
        check_compatible(cal, flight.n, flight.raw_unit, str(args.flight), kind=flight.kind,
                         names=flight.sensor_names, cal_source=args.cal)
        prof = flight_detectable(cal, th, flight, kind=args.kind)
        for line in profile_lines(prof):
            print(line)
        tu.assumptions["detectable_in_flight"] = prof.to_dict()
    print(f"noise model: {th.noise_model} (residual tails of the calibration, per scale):")
    for c in tu.choices:
        print(f"  {c.text()}")
    dr = tu.assumptions["drift"]
    if dr["model"] is not None:
        print(f"parity drift over {dr['horizon_s']:g} s after the calibration data "
              f"(random walk beyond tau {dr['longest_resolved_tau_s']:.3g} s): variance "
              f"factor + w*{dr['offset_variance_whitened']:.3g}; a drift of "
              f"{dr['offset_sd_worst_sensor_unit_value']:.3g} {dr['unit']} (1 sd, sensor "
              f"{dr['worst_sensor']}) is taken as healthy, and the detectable sizes above "
              f"include it")
    with atomic_file(out) as tmp:
        tu.save(tmp)
    print(f"wrote {out}")
    return 0
